"""Where the formation breaks: the gentlest to the harshest swept value, the last up to which
every seed holds the bound. Most keys grow harsher as they grow (a loss, a delay, a gust); a link
model's parameter that declares it hurts more as it gets smaller (``link_model.HARSHER_WHEN_SMALLER``:
a radio's range, its rate and queue, a bursty link's way back to good) is read from the largest
value down."""

from typing import Any

from swarm_sitl.campaigns.grid import link_model_key, params_of
from swarm_sitl.faults.link_model import harsher_when_smaller


def harsher_smaller(key: str) -> bool:
    """Whether a swept ``key`` hurts more as it gets smaller (its model's parameter says so)."""
    model_param = link_model_key(key)
    if model_param is None:
        return False
    params = params_of(model_param[0])
    return model_param[1] in params.model_fields and harsher_when_smaller(params, model_param[1])


def passing_values(rows: list[dict[str, Any]], key: str) -> dict[float, bool]:
    """Per value of ``key``: whether every run at it passed."""
    out: dict[float, bool] = {}
    for r in rows:
        v = float(r[key])
        out[v] = out.get(v, True) and bool(r["passed"])
    return out


def breaking_point(rows: list[dict[str, Any]], key: str) -> tuple[float | None, float | None]:
    """``(held, broke)``: the harshest value of ``key`` such that every seed passed at it and at
    every gentler value, and the next value (the first at which a seed failed); ``None`` for
    held if the first value fails, for broke if none does."""
    held: float | None = None
    values = sorted(passing_values(rows, key).items(), reverse=harsher_smaller(key))
    for v, ok in values:
        if not ok:
            return held, v
        held = v
    return held, None


def toward(key: str) -> str:
    """How the breaking point reads for ``key``: ``up to`` a value, or ``down to`` it."""
    return "down to" if harsher_smaller(key) else "up to"
