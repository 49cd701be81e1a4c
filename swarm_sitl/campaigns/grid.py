"""What a campaign varies: ``KEY=VALUES`` specs, and one point's config.

A key is either a dotted path into the config (``duration_s``, ``gains.k_p``, ``run.settle_s``,
``followers.0.offset_m.2``: list items by index) or a link shorthand that puts one fault-plan entry
on every edge of the graph or every vehicle's MAVLink link:

- ``link.loss``, ``link.corrupt``, ``link.duplicate``, ``link.reorder`` (probabilities),
  ``link.delay_s``, ``link.jitter_s`` (seconds; jitter goes with a delay): an entry ``into: i``
  for every follower i, so every edge of the graph meets it;
- ``link.MODEL.PARAM``, a parameter of a link model the plan writes as a mapping (``link.bursty.p``,
  ``link.range.range_m``, ``link.bandwidth.rate_bps``, ...: ``faults.link_models``' registry), or of
  a user's own named by its entry (``link.my_link.py:DutyCycle.duty``, a file relative to where
  the campaign is started, or ``link.package.module:Name.param``): one entry ``all_edges: true``
  with that model, its other parameters from the other keys of the campaign (a required one must
  be swept too, with one value if it is to stay fixed) or their defaults;
- ``mavlink.loss``, ``mavlink.corrupt``: an entry ``mavlink: i`` for every follower, both ways.

A value of 0 puts no entry (the plan's values are positive), and so does ``link.bursty.p=0``.
VALUES is ``START:STOP:STEP`` (inclusive of STOP when the steps land on it) or a comma list
``0,0.1,0.5``.
"""

import math
from pathlib import Path
from typing import Any

from pydantic import BaseModel

from sim_vehicles.common.entry import absolute_entry
from swarm_sitl.faults.link_model import LinkModelError, declared, resolve_link_model
from swarm_sitl.faults.link_models import LINK_MODELS, keys_of_form

#: ``link.HOW``: the probabilities of the registry's models, and a delay with its jitter
LINK_HOW = (*keys_of_form("p"), "delay_s", "jitter_s")
#: ``mavlink.HOW``: the probabilities that may act on a vehicle's link in lockstep (a campaign's runs)
MAVLINK_HOW = tuple(k for k in keys_of_form("p") if declared(LINK_MODELS[k], "mavlink_in_lockstep"))
#: a model's parameter at which 0 puts no entry (a bursty link that never turns bad); 0 elsewhere is
#: the model's own value (validated: a range or a rate of 0 is refused)
NO_ENTRY_AT_ZERO = {"bursty": "p"}
MAX_POINTS = 100_000


class SweepSpecError(ValueError):
    """A campaign spec that cannot be used; the message is one line naming the key."""


def parse_values(key: str, text: str) -> list[float]:
    """``START:STOP:STEP`` or ``a,b,c`` as a list of floats (sorted, each once)."""
    text = text.strip()
    try:
        if ":" in text:
            parts = [float(p) for p in text.split(":")]
            if len(parts) != 3:
                raise SweepSpecError(f"sweep {key}: a range is START:STOP:STEP, got {text!r}")
            start, stop, step = parts
            if not step > 0 or not math.isfinite(step):
                raise SweepSpecError(f"sweep {key}: the step of {text!r} must be positive")
            if stop < start:
                raise SweepSpecError(f"sweep {key}: the range {text!r} is empty (STOP < START)")
            n = math.floor((stop - start) / step + 1e-9) + 1
            if n > MAX_POINTS:
                raise SweepSpecError(f"sweep {key}: {text!r} has {n} values, more than {MAX_POINTS}")
            values = [round(start + k * step, 12) for k in range(n)]
        else:
            values = [float(p) for p in text.split(",") if p.strip()]
    except ValueError as e:
        if isinstance(e, SweepSpecError):
            raise
        raise SweepSpecError(f"sweep {key}: {text!r} is not START:STOP:STEP or a list of numbers") from None
    if not values:
        raise SweepSpecError(f"sweep {key}: no values in {text!r}")
    if not all(math.isfinite(v) for v in values):
        raise SweepSpecError(f"sweep {key}: {text!r} has a value that is not finite")
    return sorted(set(values))


def parse_vary(spec: str) -> tuple[str, list[float]]:
    """``KEY=VALUES`` as ``(key, values)``."""
    key, sep, values = spec.partition("=")
    key = key.strip()
    if not sep or not key:
        raise SweepSpecError(f"sweep: {spec!r} is not KEY=VALUES (e.g. link.loss=0:0.9:0.1)")
    return key, parse_values(key, values)


def _set_path(data: dict[str, Any], key: str, value: float) -> None:
    """Set the dotted path ``key`` of the config's data, which must exist already."""
    parts = key.split(".")
    node: Any = data
    for depth, part in enumerate(parts):
        last = depth == len(parts) - 1
        where = ".".join(parts[: depth + 1])
        if isinstance(node, list):
            if not part.isdigit() or int(part) >= len(node):
                raise SweepSpecError(f"sweep {key}: {where}: no item {part} (the list has {len(node)})")
            idx: Any = int(part)
        elif isinstance(node, dict):
            if part not in node:
                known = ", ".join(sorted(str(k) for k in node)) or "none"
                raise SweepSpecError(f"sweep {key}: no setting {where!r} in the config (there: {known})")
            idx = part
        else:
            raise SweepSpecError(f"sweep {key}: {'.'.join(parts[:depth])} is a value, not a section")
        if last:
            if isinstance(node[idx], dict | list):
                raise SweepSpecError(f"sweep {key}: {where} is a section, not a value")
            node[idx] = value
        else:
            node = node[idx]


def link_model_key(key: str) -> tuple[str, str] | None:
    """``(model, param)`` of a ``link.MODEL.PARAM`` key (``model``: a registered key or a user's
    entry), None for any other key."""
    head, _, how = key.partition(".")
    if head != "link":
        return None
    if ":" in how:  # a user's entry: its parameter follows the class name's last dot
        model, dot, param = how.rpartition(".")
        return (model, param) if dot and ":" not in param else (how, "")
    model, dot, param = how.partition(".")
    return (model, param) if dot else None


def params_of(model: str) -> type[BaseModel]:
    """The ``Params`` of ``model``: a registered key, or a user's entry (imported and held to the
    link-model contract)."""
    if ":" in model:
        try:
            return resolve_link_model(model).Params
        except LinkModelError as e:
            raise SweepSpecError(f"sweep link.{model}: {e}") from None
    return LINK_MODELS[model].Params


def check_key(key: str) -> None:
    """A shorthand key's own check (a config path is checked against the config)."""
    head, _, how = key.partition(".")
    model_param = link_model_key(key)
    if model_param is not None:
        model, param = model_param
        mapped = keys_of_form("params")  # (read when asked: a model registered since counts)
        if ":" not in model and model not in mapped:
            raise SweepSpecError(
                f"sweep {key}: link.MODEL.PARAM is a model of {', '.join(mapped)}, or a link model of "
                "your own by its entry (link.my_link.py:Name.param)"
            )
        fields = params_of(model).model_fields
        if param not in fields:
            known = ", ".join(f"link.{model}.{f}" for f in fields) or "none"
            raise SweepSpecError(f"sweep {key}: {model} has no parameter {param!r} ({known})")
    elif head == "link" and how not in LINK_HOW:
        known = ", ".join("link." + h for h in LINK_HOW)
        raise SweepSpecError(f"sweep {key}: link.* is one of {known}, or link.MODEL.PARAM")
    if head == "mavlink" and how not in MAVLINK_HOW:
        known = ", ".join("mavlink." + h for h in MAVLINK_HOW)
        raise SweepSpecError(f"sweep {key}: mavlink.* is one of {known}")
    if head == "faults":
        raise SweepSpecError(
            f"sweep {key}: vary the plan with link.* or mavlink.* (the seed is --seeds), "
            "or give a base plan with --faults"
        )


def user_models(keys: list[str]) -> list[str]:
    """The entries of the users' link models that ``keys`` vary (``link.ENTRY.PARAM``), each once."""
    found = [mp[0] for mp in map(link_model_key, keys) if mp is not None and ":" in mp[0]]
    return list(dict.fromkeys(found))


def point_data(
    base: dict[str, Any], point: dict[str, float], seed: int, shipped: dict[str, str] | None = None
) -> dict[str, Any]:
    """The config data of one run: ``base`` (a config's ``data()``) with ``point``'s values
    and the run's seed; link shorthands add their entries after the base plan's. ``shipped``: the
    entry a run names a user's link model by (its copy shipped beside the point's config) in place
    of the one the key spells."""
    import copy

    data = copy.deepcopy(base)
    followers = [f["id"] for f in data["followers"]]
    link: dict[str, float] = {}
    mav: dict[str, float] = {}
    models: dict[str, dict[str, float]] = {}
    for key, value in point.items():
        check_key(key)
        head, _, how = key.partition(".")
        model_param = link_model_key(key)
        if model_param is not None:
            model, param = model_param
            models.setdefault(model, {})[param] = value
        elif head == "link":
            link[how] = value
        elif head == "mavlink":
            mav[how] = value
        else:
            _set_path(data, key, value)
    entries: list[dict[str, Any]] = []
    for how in ("loss", "corrupt", "duplicate", "reorder"):
        if link.get(how):
            entries += [{"into": i, how: link[how]} for i in followers]
    if link.get("jitter_s") and not link.get("delay_s"):
        link["delay_s"] = 1e-9  # a jitter alone: a delay of nothing plus the jitter
    if link.get("delay_s"):
        extra = {"jitter_s": link["jitter_s"]} if link.get("jitter_s") else {}
        entries += [{"into": i, "delay_s": link["delay_s"], **extra} for i in followers]
    for model, params in models.items():
        required = [n for n, f in params_of(model).model_fields.items() if f.is_required()]
        missing = [n for n in required if n not in params]
        if missing:
            raise SweepSpecError(
                f"sweep link.{model}.{next(iter(params))}: a {model} link needs "
                f"{', '.join(f'link.{model}.{n}' for n in missing)} too (one value to hold it)"
            )
        if not params.get(NO_ENTRY_AT_ZERO.get(model, ""), 1.0):
            continue
        if ":" in model:  # a file relative to where the campaign started: its runs fly elsewhere
            entry = (shipped or {}).get(model) or absolute_entry(model, Path.cwd())
            entries.append({"all_edges": True, "model": {"entry": entry, "params": params}})
        else:
            entries.append({"all_edges": True, model: params})
    for how in MAVLINK_HOW:
        if mav.get(how):
            entries += [{"mavlink": i, how: mav[how]} for i in followers]
    faults = data.setdefault("faults", {})
    faults["plan"] = [*faults.get("plan", []), *entries]
    data["seed"] = seed  # the run's: every random stream the base does not pin (config.seeds)
    return data


def grid(vary: list[tuple[str, list[float]]]) -> list[dict[str, float]]:
    """Every combination of the swept values, the first key varying slowest."""
    points: list[dict[str, float]] = [{}]
    for key, values in vary:
        points = [{**p, key: v} for p in points for v in values]
    if len(points) > MAX_POINTS:
        raise SweepSpecError(f"sweep: {len(points)} points, more than {MAX_POINTS}")
    return points
