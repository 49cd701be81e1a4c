"""A violating plan made minimal: its entries dropped, its severities lowered, its windows
shortened, each step kept only while the plan still violates.

1. Drop each entry in turn (plan order); keep it dropped if the rest still violates. What is left
   is minimal by entries: removing any one of them makes the requirement hold.
2. Lower each loss, delay, downtime or searched parameter of a link model by bisection, to
   ``1/128`` of its space's range, toward the range's milder end (``space.SpaceEntry.searched``:
   the end of lower severity): from the mildest value at which the same plan was seen to hold
   under every seed (``held``: the search's evaluations), else the range's mild end. Each probe
   flies the plan under the seeds the space allows, its own first, ``width`` at a time
   (``check_many``), until one violates: the least severity at which *a* seed breaks, with that
   seed (a campaign's "a seed breaks at").
3. Shorten each window by bisection on its end, to a control period.

``check_many(plans) -> robustnesses`` flies plans (``evaluate``); every plan flown is one
evaluation, counted.
"""

import copy
import json
import math
from collections.abc import Callable, Sequence
from typing import Any

Plan = dict[str, Any]
Path = tuple[str, ...]  #: where a value is in a plan entry (``("loss",)``, ``("bursty", "p")``)
Ranges = Callable[[dict[str, Any]], list[tuple[Path, tuple[float, float]]]]
RESOLUTION = 128  #: a severity is lowered to this fraction of its range


def at(f: dict[str, Any], path: Path) -> Any:
    """The value of a plan entry at ``path`` (None: not there)."""
    node: Any = f
    for part in path:
        if not isinstance(node, dict) or part not in node:
            return None
        node = node[part]
    return node


def _set(f: dict[str, Any], path: Path, value: float) -> None:
    node = f
    for part in path[:-1]:
        node = node[part]
    node[path[-1]] = value


def _without(plan: Plan, j: int, path: Path) -> str:
    """The plan but entry ``j``'s value at ``path``, as text (plans that differ only there match)."""
    p = copy.deepcopy(plan)
    _set(p["plan"][j], path, 0.0)
    p.pop("seed")
    return json.dumps(p, sort_keys=True)


def held_below(
    plan: Plan, j: int, path: Path, held: Sequence[Plan], seeds: Sequence[int], mild: float = -math.inf
) -> float | None:
    """A value of entry ``j`` at ``path``, milder than the plan's (nearer ``mild``, the range's
    mild end), at which the same plan held under every seed in ``seeds`` (the least mild of each
    seed's such values, the fault being taken to hurt more away from ``mild``), if ``held`` shows
    one for each."""
    same = _without(plan, j, path)
    ours = at(plan["plan"][j], path)
    toward = 1.0 if mild <= ours else -1.0  # values grow in severity as toward * v grows
    top: dict[int, float] = {}
    for h in held:
        if len(h["plan"]) != len(plan["plan"]):
            continue
        v = at(h["plan"][j], path)
        if not isinstance(v, int | float) or isinstance(v, bool):
            continue
        if toward * v < toward * ours and _without(h, j, path) == same:
            s = h["seed"]
            top[s] = v if s not in top or toward * v > toward * top[s] else top[s]
    wanted = set(seeds) | {plan["seed"]}
    if not wanted <= set(top):
        return None
    return min((top[s] for s in wanted), key=lambda v: toward * v)


def shrink(
    plan: Plan,
    check_many: Callable[[list[Plan]], list[float]],
    ranges: Ranges,
    period_s: float,
    seeds: Sequence[int] = (),
    held: Sequence[Plan] = (),
    steps: int = 6,
    width: int = 1,
) -> tuple[Plan, float, int]:
    """``plan`` (violating) made minimal; returns it, its robustness and the evaluations spent.
    ``ranges(entry)``: where each of the entry's searched severities is and its space's range,
    the mild end first (none: a cut, nothing to lower);
    ``seeds``: those a plan may have; ``held``: plans seen to hold."""
    spent = 0
    best = copy.deepcopy(plan)
    best_r = float("nan")

    def worst(p: Plan, all_seeds: bool) -> tuple[Plan, float] | None:
        """The most violating of ``p`` under its seed (or under each allowed), if any violates."""
        nonlocal spent
        order = [p["seed"], *sorted(set(seeds) - {p["seed"]})] if all_seeds else [p["seed"]]
        for at in range(0, len(order), width):
            tries = [{**p, "seed": s} for s in order[at : at + width]]
            rs = check_many(tries)
            spent += len(tries)
            k = min(range(len(rs)), key=lambda i: rs[i])
            if rs[k] < 0:
                return tries[k], rs[k]
        return None

    j = 0
    while j < len(best["plan"]) and len(best["plan"]) > 1:
        got = worst({**best, "plan": best["plan"][:j] + best["plan"][j + 1 :]}, False)
        if got is not None:
            best, best_r = got
        else:
            j += 1
    for j in range(len(best["plan"])):
        for path, (mild, severe) in ranges(best["plan"][j]):
            below = held_below(best, j, path, held, seeds, mild)
            lo, hi = (mild if below is None else below), at(best["plan"][j], path)
            while abs(hi - lo) > abs(severe - mild) / RESOLUTION:
                mid = (lo + hi) / 2
                trial = copy.deepcopy(best)
                _set(trial["plan"][j], path, mid)
                got = worst(trial, True)
                if got is not None:
                    (best, best_r), hi = got, mid
                else:
                    lo = mid
    for j, f in enumerate(best["plan"]):
        if "until_s" not in f:
            continue
        lo, hi = f.get("from_s", 0.0) + period_s, f["until_s"]
        for _ in range(steps):
            if hi - lo <= period_s:
                break
            mid = (lo + hi) / 2
            trial = copy.deepcopy(best)
            trial["plan"][j]["until_s"] = mid
            got = worst(trial, False)
            if got is not None:
                (best, best_r), hi = got, mid
            else:
                lo = mid
    if best_r != best_r:  # nothing was changed: the plan as found, flown once more for its figure
        spent += 1
        best_r = check_many([best])[0]
    return best, best_r, spent
