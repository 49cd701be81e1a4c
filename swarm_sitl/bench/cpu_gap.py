"""Where a run's CPU goes beyond the empty swarm's and ``sim``'s: ``bench --scale N,... --empty
--split N,...``.

The floor of a run of processes is the empty swarm (``empty_swarm``: the same processes and
messages with no work) plus ``sim`` (the work with no transport). What a run spends beyond that
floor, per process kind, in CPU seconds per simulated second:

- ``run``: the kind's main threads (the loops) and other threads (zenoh's runtime), run phase,
  exact per thread (``cost_split.thread_split``); the router's is the supervisor's process;
- ``empty``: the empty swarm's processes of that kind;
- ``sim``: ``sim``'s CPU, shared among the kinds as the run's own ``physics and laws`` time is
  (the same compiled steps: the plant and attitude loop on a vehicle, the estimator and position
  loop on a controller, the trajectory on the leader);
- ``gap`` = run - empty - sim;
- the run's main-thread CPU by activity (``cost_split.activity_split``'s shares of a profiled run,
  applied to the unprofiled run's main-thread CPU) and its other threads.

Summed over the kinds, the gap is exactly five parts: the physics and laws beyond ``sim``'s, the
MAVLink around the frames, the logs, the loops and the rest, and the transport beyond the empty
swarm's (zenoh, waking up, the nodes' other threads and the router, less the empty swarm's whole
CPU): an empty swarm's process does nothing but move its messages.
"""

import csv
import math
from pathlib import Path
from typing import Any

from swarm_sitl.bench.cost_split import ACTIVITIES

NODE_KINDS = ("vehicle", "controller", "leader")
#: the activities an empty swarm's process also has: moving messages and waiting for them
TRANSPORT = ("zenoh", "waking up")
PARTS = ("physics and laws beyond sim", "MAVLink", "logs", "loop and other", "transport beyond empty")


def cpu_gap(row: dict[str, float], shares: dict[str, dict[str, float]]) -> dict[str, dict[str, float]]:
    """Per kind (and ``router``, and ``total``): ``run``, ``empty``, ``sim``, ``gap``, each activity
    of the main threads, ``other threads``; the ``total``'s also has the five ``PARTS``. ``row``:
    a ``scale.measure`` row with the empty swarm measured; ``shares``: ``scale.measure_split``'s."""
    laws = {k: shares[k]["physics and laws"] * row[f"main_{k}"] for k in NODE_KINDS}
    all_laws = sum(laws.values())
    sim = row["sim_cpu_per_sim_s"]
    out: dict[str, dict[str, float]] = {}
    for k in NODE_KINDS:
        main, other = row[f"main_{k}"], row[f"other_{k}"]
        kind = {a: shares[k][a] * main for a in ACTIVITIES}
        kind["other threads"] = other
        kind["run"] = main + other
        kind["empty"] = row[f"empty_{k}"]
        kind["sim"] = sim * laws[k] / all_laws if all_laws > 0 else math.nan
        out[k] = kind
    router = dict.fromkeys((*ACTIVITIES, "other threads"), 0.0)
    router.update(run=row["cpu_supervisor"], empty=row["empty_router"], sim=0.0)
    router["zenoh"] = row["cpu_supervisor"]  # (the supervisor's own CPU is the router's, mostly)
    out["router"] = router
    for kind in out.values():
        kind["gap"] = kind["run"] - kind["empty"] - kind["sim"]
    total = {key: sum(kind[key] for kind in out.values()) for key in out["vehicle"]}
    total["physics and laws beyond sim"] = total["physics and laws"] - total["sim"]
    moved = sum(total[a] for a in TRANSPORT) + total["other threads"]
    total["transport beyond empty"] = moved - total["empty"]
    out["total"] = total
    return out


def print_gap(row: dict[str, float], shares: dict[str, dict[str, float]]) -> list[dict[str, Any]]:
    """Print ``cpu_gap`` at ``row``'s N; return its rows for ``write_gap``."""
    n = int(row["followers"])
    gap = cpu_gap(row, shares)
    t = gap["total"]
    print(
        f"beyond the floor at {n} followers, CPU s per simulated s: run {t['run']:.3f} = empty swarm "
        f"{t['empty']:.3f} + sim {t['sim']:.3f} + gap {t['gap']:.3f} "
        f"(run / (empty + sim) = {t['run'] / (t['empty'] + t['sim']):.2f})"
    )
    cols = ("run", "empty", "sim", "gap", *ACTIVITIES, "other threads")
    print(f"  {'':<10} " + " ".join(f"{c[:12]:>12}" for c in cols))
    for kind, figures in gap.items():
        print(f"  {kind:<10} " + " ".join(f"{figures[c]:>12.3f}" for c in cols))
    print("  the gap is: " + ", ".join(f"{p} {t[p]:.3f}" for p in PARTS))
    return [{"followers": n, "kind": kind, **figures} for kind, figures in gap.items()]


def write_gap(rows: list[dict[str, Any]], path: Path) -> None:
    fields = list(dict.fromkeys(key for r in rows for key in r))
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=fields)
        w.writeheader()
        w.writerows(rows)
