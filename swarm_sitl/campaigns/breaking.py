"""Where the formation breaks: the largest swept value up to which every seed holds the bound."""

from typing import Any


def passing_values(rows: list[dict[str, Any]], key: str) -> dict[float, bool]:
    """Per value of ``key``: whether every run at it passed."""
    out: dict[float, bool] = {}
    for r in rows:
        v = float(r[key])
        out[v] = out.get(v, True) and bool(r["passed"])
    return out


def breaking_point(rows: list[dict[str, Any]], key: str) -> tuple[float | None, float | None]:
    """``(held, broke)``: the largest value of ``key`` such that every seed passed at it and at
    every smaller value, and the next value (the first at which a seed failed); ``None`` for
    held if the first value fails, for broke if none does."""
    held: float | None = None
    for v, ok in sorted(passing_values(rows, key).items()):
        if not ok:
            return held, v
        held = v
    return held, None
