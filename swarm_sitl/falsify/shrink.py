"""A violating plan made minimal: its entries dropped, its severities lowered, its windows
shortened, each step kept only while the plan still violates.

1. Drop each entry in turn (plan order); keep it dropped if the rest still violates. What is left
   is minimal by entries: removing any one of them makes the requirement hold.
2. Lower each loss, delay or downtime by bisection, to ``1/128`` of its space's range: from below, the
   highest value at which the same plan was seen to hold under every seed (``held``: the search's
   evaluations), else the range's low end. Each probe flies the plan under the seeds the space
   allows, its own first, ``width`` at a time (``check_many``), until one violates: the least
   severity at which *a* seed breaks, with that seed (a campaign's "a seed breaks at").
3. Shorten each window by bisection on its end, to a control period.

``check_many(plans) -> robustnesses`` flies plans (``evaluate``); every plan flown is one
evaluation, counted.
"""

import copy
import json
from collections.abc import Callable, Sequence
from typing import Any

Plan = dict[str, Any]
RESOLUTION = 128  #: a severity is lowered to this fraction of its range


def _key(f: dict[str, Any]) -> str | None:
    """The severity of a plan entry shrinking lowers: a loss, a delay, a downtime (None: a cut)."""
    for key in ("loss", "delay_s", "restart_after_s"):
        if key in f:
            return key
    return None


def _without(plan: Plan, j: int, key: str) -> str:
    """The plan but entry ``j``'s ``key``, as text (plans that differ only there match)."""
    p = copy.deepcopy(plan)
    del p["plan"][j][key]
    p.pop("seed")
    return json.dumps(p, sort_keys=True)


def held_below(plan: Plan, j: int, key: str, held: Sequence[Plan], seeds: Sequence[int]) -> float | None:
    """A value of entry ``j``'s ``key`` below the plan's at which the same plan held under every
    seed in ``seeds`` (the least of each seed's highest such value, a loss or delay being taken to
    hurt more as it grows), if ``held`` shows one for each."""
    same = _without(plan, j, key)
    top: dict[int, float] = {}
    for h in held:
        if len(h["plan"]) != len(plan["plan"]) or key not in h["plan"][j]:
            continue
        v = h["plan"][j][key]
        if v < plan["plan"][j][key] and _without(h, j, key) == same:
            top[h["seed"]] = max(top.get(h["seed"], v), v)
    wanted = set(seeds) | {plan["seed"]}
    return min(top[s] for s in wanted) if wanted <= set(top) else None


def shrink(
    plan: Plan,
    check_many: Callable[[list[Plan]], list[float]],
    ranges: Callable[[dict[str, Any]], tuple[float, float] | None],
    period_s: float,
    seeds: Sequence[int] = (),
    held: Sequence[Plan] = (),
    steps: int = 6,
    width: int = 1,
) -> tuple[Plan, float, int]:
    """``plan`` (violating) made minimal; returns it, its robustness and the evaluations spent.
    ``ranges(entry)``: the space's range of the entry's severity (None: a cut, none to lower);
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
    for j, f in enumerate(best["plan"]):
        key = _key(f)
        rng = ranges(f)
        if key is None or rng is None:
            continue
        below = held_below(best, j, key, held, seeds)
        lo, hi = (rng[0] if below is None else below), f[key]
        while hi - lo > (rng[1] - rng[0]) / RESOLUTION:
            mid = (lo + hi) / 2
            trial = copy.deepcopy(best)
            trial["plan"][j][key] = mid
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
