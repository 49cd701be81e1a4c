"""``swarm-sitl bench --scale N,N,...``: how the lockstep swarm's cost grows with the number of followers.

For each N, a generated swarm (``swarm-sitl new --followers N --graph layered --formation grid
--trajectory helix``) flies ``duration_s`` twice: in ``sim`` (one process, the same physics and
control without transport: the floor) and as a lockstep ``run`` across 2N + 1 processes. Printed,
and written to ``OUT/scale.csv`` and ``OUT/scale.png``:

- ``startup_s``: spawning to every process ready; ``run_x``: simulated over wall seconds of the
  run phase; ``e2e_x``: the same with the start-up counted;
- ``cpu_per_sim_s``: CPU seconds of every process (threads included) per simulated second, each
  node's from when it was ready (the supervisor's whole), next to ``sim``'s, and their ratio
  (``overhead``: what the transport costs);
- the CPU split per process kind (vehicles, controllers, leader, supervisor: this process, which
  routes zenoh) per simulated second;
- with ``--scale-realtime S``: each N again in real time for S seconds, late ticks and when
  setpoints go out (median, p99), up to the first N with over 10 % late ticks or a failed run
  (named: where the machine saturates);
- with ``--empty``: each N again as a swarm of the same processes exchanging the same messages
  with no work (``empty_swarm``): its speed and CPU per simulated second (``empty_x``,
  ``empty_cpu_per_sim_s``), what the process structure alone costs on this machine, and the
  run's CPU over the empty swarm's and ``sim``'s together (``over_empty_sim``: what the run
  costs beyond the bare transport and the laws; 1 would be nothing);
- the nodes' run-phase CPU split between their main threads (the loops) and their other threads
  (zenoh's runtime), exact per thread;
- with ``--split N,...``: each of these N-follower runs again with every process profiled, and
  each process kind's main-thread CPU by activity (physics and laws, MAVLink, zenoh, waking up,
  logs, the loop; ``cost_split``), printed and written to ``OUT/splitN.csv``; with ``--empty`` as
  well, what the run spends beyond the empty swarm's and ``sim``'s, per kind and activity
  (``cpu_gap``), printed and written to ``OUT/gap.csv``;
- where a controller's start-up goes (medians over controllers, ``sim_vehicles.runtime.lifeline.mark``):
  ``main`` (interpreter and imports), ``zenoh`` (session opened), ``ready`` (MAVLink link, vehicle
  parameters, kernels loaded, subscriptions declared), and the last vehicle's age at ready.
"""

import csv
import json
import math
import os
import resource
import statistics
import time
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import yaml

from swarm_sitl.bench.cost_split import ACTIVITIES, activity_split
from swarm_sitl.bench.cpu_gap import NODE_KINDS, print_gap, write_gap
from swarm_sitl.bench.empty_swarm import EmptySwarmError, measure_empty
from swarm_sitl.bench.speed import late_ticks, sim_in_process_s
from swarm_sitl.config.generator import generate
from swarm_sitl.config.load import parse_config
from swarm_sitl.config.schema import SwarmConfig
from swarm_sitl.rundir.layout import procs_dir
from swarm_sitl.running.run import RunRequest, run_swarm
from swarm_sitl.running.supervisor import RunFailedError

COLUMNS = (
    "followers",
    "edges",
    "startup_s",
    "run_x",
    "e2e_x",
    "sim_x",
    "cpu_per_sim_s",
    "sim_cpu_per_sim_s",
    "overhead",
    "empty_x",
    "empty_cpu_per_sim_s",
    "over_empty_sim",
    "cpu_vehicles",
    "cpu_controllers",
    "cpu_leader",
    "cpu_supervisor",
    "cpu_main_threads",
    "cpu_other_threads",
    "ctrl_main_s",
    "ctrl_zenoh_s",
    "ctrl_ready_s",
    "vehicle_ready_s",
    # per process kind, CPU s per simulated s: the nodes' main and other threads (run phase), and
    # the empty swarm's processes of that kind (the router: the supervisor's counterpart)
    *(f"{t}_{k}" for k in NODE_KINDS for t in ("main", "other")),
    *(f"empty_{k}" for k in (*NODE_KINDS, "router")),
)


def scale_config(n: int, duration_s: float, start: str = "fork") -> SwarmConfig:
    data = yaml.safe_load(generate(n, "layered", "grid", "helix", 0, duration_s))
    data["run"] = {"start": start}
    return parse_config(data, f"layered{n}")


def _cpu_s(who: int) -> float:
    r = resource.getrusage(who)
    return r.ru_utime + r.ru_stime


def _process_stats(run_dir: Path) -> dict[str, list[dict[str, Any]]]:
    kinds: dict[str, list[dict[str, Any]]] = {"vehicle": [], "controller": [], "leader": []}
    for path in sorted(procs_dir(run_dir).glob("*.stats.json")):
        kind = path.name.split("_")[0].split(".")[0]
        try:
            process = json.loads(path.read_text()).get("process")
        except (OSError, ValueError):
            continue
        if kind in kinds and isinstance(process, dict):
            kinds[kind].append(process)
    return kinds


def _run_phase(kinds: dict[str, list[dict[str, Any]]], figure: str) -> float:
    """A CPU figure (``lifeline.process_figures``) summed over every node, from ready to exit."""
    return sum(
        p.get(figure, math.nan) - p["marks"].get("ready", {}).get(figure, 0.0)
        for procs in kinds.values()
        for p in procs
    )


def _median_mark(procs: list[dict[str, Any]], name: str) -> float:
    ages = [p["marks"][name]["age_s"] for p in procs if name in p.get("marks", {})]
    return statistics.median(ages) if ages else float("nan")


def measure(
    n: int, duration_s: float, work: Path, start: str = "fork", empty: bool = False
) -> dict[str, float]:
    cfg = scale_config(n, duration_s, start)
    sim_wall, sim_cpu = sim_in_process_s(cfg)
    self0 = _cpu_s(resource.RUSAGE_SELF)
    t0 = time.monotonic()
    res = run_swarm(RunRequest(cfg, work / f"n{n}"))
    e2e = time.monotonic() - t0
    sup_cpu = _cpu_s(resource.RUSAGE_SELF) - self0
    kinds = _process_stats(work / f"n{n}")
    # each node's CPU after it was ready: the run phase, start-up apart
    per_kind = {
        k: sum(p["cpu_s"] - p["marks"].get("ready", {"cpu_s": 0.0})["cpu_s"] for p in v) / duration_s
        for k, v in kinds.items()
    }
    all_cpu = sup_cpu + sum(per_kind.values()) * duration_s
    ctrl = kinds["controller"]
    empty_x = empty_cpu = math.nan
    empty_kinds = dict.fromkeys((*NODE_KINDS, "router"), math.nan)
    if empty:
        try:
            e = measure_empty(cfg, cfg.n_control_steps)
        except EmptySwarmError as err:  # the lockstep figures stand; this row's empty ones are NaN
            print(f"{n:>3} {err}", flush=True)
        else:
            empty_x, empty_cpu = duration_s / e.wall_s, e.cpu_total_s / duration_s
            named = {"vehicle": "vehicles", "controller": "controllers"}  # (EmptyRun's keys)
            empty_kinds = {k: e.cpu_s[named.get(k, k)] / duration_s for k in empty_kinds}
    threads = {t: _run_phase(kinds, f"{t}_s") / duration_s for t in ("main_thread", "other_threads")}
    by_kind = {
        f"{t}_{k}": _run_phase({k: kinds[k]}, f"{thread}_s") / duration_s
        for k in NODE_KINDS
        for t, thread in (("main", "main_thread"), ("other", "other_threads"))
    }
    return {
        "followers": n,
        "edges": len(cfg.graph.edges),
        "startup_s": res.startup_wall_s,
        "run_x": duration_s / res.run_wall_s,
        "e2e_x": duration_s / e2e,
        "sim_x": duration_s / sim_wall,
        "cpu_per_sim_s": all_cpu / duration_s,
        "sim_cpu_per_sim_s": sim_cpu / duration_s,
        "overhead": all_cpu / sim_cpu,
        "empty_x": empty_x,
        "empty_cpu_per_sim_s": empty_cpu,
        "over_empty_sim": all_cpu / (empty_cpu * duration_s + sim_cpu),
        "cpu_vehicles": per_kind["vehicle"],
        "cpu_controllers": per_kind["controller"],
        "cpu_leader": per_kind["leader"],
        "cpu_supervisor": sup_cpu / duration_s,
        "cpu_main_threads": threads["main_thread"],
        "cpu_other_threads": threads["other_threads"],
        "ctrl_main_s": _median_mark(ctrl, "main"),
        "ctrl_zenoh_s": _median_mark(ctrl, "zenoh"),
        "ctrl_ready_s": _median_mark(ctrl, "ready"),
        "vehicle_ready_s": max(
            (p["marks"]["ready"]["age_s"] for p in kinds["vehicle"] if "ready" in p.get("marks", {})),
            default=float("nan"),
        ),
        **by_kind,
        **{f"empty_{k}": v for k, v in empty_kinds.items()},
    }


SATURATED_LATE = 0.10  #: a real-time run with more late ticks than this: the machine is saturated


def measure_realtime(n: int, duration_s: float, work: Path, start: str = "fork") -> dict[str, float]:
    """Late ticks and when setpoints go out after their tick's instant, in real time."""
    cfg = scale_config(n, duration_s, start)
    run_dir = work / f"rt{n}"
    run_swarm(RunRequest(cfg, run_dir, lockstep=False))
    late, total, done = late_ticks(cfg, run_dir)
    return {
        "followers": n,
        "late_share": late / total,
        "out_median_ms": float(np.median(done)) * 1e3,
        "out_p99_ms": float(np.percentile(done, 99)) * 1e3,
    }


def measure_split(n: int, duration_s: float, work: Path, start: str = "fork") -> dict[str, dict[str, float]]:
    """Per process kind, the main thread's CPU by activity (``cost_split``), in shares, from a
    lockstep run with every process profiled."""
    cfg = scale_config(n, duration_s, start)
    folder = work / f"profile{n}"
    before = os.environ.get("SWARM_SITL_PROFILE")
    os.environ["SWARM_SITL_PROFILE"] = str(folder)
    try:
        run_swarm(RunRequest(cfg, work / f"split{n}"))
    finally:
        if before is None:
            del os.environ["SWARM_SITL_PROFILE"]
        else:
            os.environ["SWARM_SITL_PROFILE"] = before
    out = {}
    for kind in ("vehicle", "controller", "leader"):
        seconds = activity_split(sorted(folder.glob(f"{kind}*.prof")))
        total = sum(seconds.values())
        out[kind] = {a: (v / total if total > 0 else math.nan) for a, v in seconds.items()}
    return out


def _print_split(
    n: int, split: dict[str, dict[str, float]], row: dict[str, float] | None, path: Path
) -> None:
    print(f"where the CPU goes at {n} followers (lockstep):")
    if row is not None:
        main, other = row["cpu_main_threads"], row["cpu_other_threads"]
        print(
            f"  nodes' main threads (the loops) {main:.2f}, their other threads (zenoh's runtime) "
            f"{other:.2f}, supervisor (the zenoh router) {row['cpu_supervisor']:.2f} CPU s per simulated s"
        )
    print(
        "  main threads by activity, % of each kind's"
        " (a profiled run: cProfile leans towards Python-heavy work)"
    )
    print(f"  {'':<10} " + " ".join(f"{a:>16}" for a in ACTIVITIES))
    for kind, shares in split.items():
        print(f"  {kind:<10} " + " ".join(f"{100 * shares[a]:>15.1f}%" for a in ACTIVITIES))
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["kind", *ACTIVITIES])
        for kind, shares in split.items():
            w.writerow([kind, *(f"{shares[a]:.4f}" for a in ACTIVITIES)])


def _plot(rows: list[dict[str, float]], path: Path) -> None:
    n = [r["followers"] for r in rows]
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4.2))
    a.loglog(n, [r["cpu_per_sim_s"] for r in rows], "o-", label="lockstep run, every process")
    a.loglog(n, [r["sim_cpu_per_sim_s"] for r in rows], "s-", label="sim (no transport)")
    if not any(math.isnan(r["empty_cpu_per_sim_s"]) for r in rows):
        a.loglog(n, [r["empty_cpu_per_sim_s"] for r in rows], "v:", label="empty swarm (no work)")
    for key, label in (("cpu_vehicles", "vehicles"), ("cpu_controllers", "controllers")):
        a.loglog(n, [r[key] for r in rows], ".--", label=label)
    a.set_xlabel("followers")
    a.set_ylabel("CPU seconds per simulated second")
    a.legend(fontsize=8)
    a.grid(True, which="both", alpha=0.3)
    b.plot(n, [r["startup_s"] for r in rows], "o-", label="start-up [s]")
    b.plot(n, [r["run_x"] for r in rows], "s-", label="run phase, x real time")
    b.plot(n, [r["e2e_x"] for r in rows], "^-", label="end to end, x real time")
    if not any(math.isnan(r["empty_x"]) for r in rows):
        b.plot(n, [r["empty_x"] for r in rows], "v:", label="empty swarm, x real time")
    b.axhline(1.0, color="k", lw=0.6)
    b.set_xscale("log", base=2)
    b.set_yscale("log")
    b.set_xlabel("followers")
    b.legend(fontsize=8)
    b.grid(True, alpha=0.3)
    fig.suptitle("swarm-sitl bench --scale: lockstep, layered graph, grid, helix")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def run_scale(
    ns: list[int],
    duration_s: float,
    out: Path | None,
    start: str = "fork",
    realtime_s: float = 0.0,
    splits: list[int] | None = None,
    empty: bool = False,
) -> int:
    """Lockstep for every N, then (``realtime_s`` > 0) real time for every N up to the first that
    saturates the machine, then where the CPU goes at each N of ``splits`` (with ``empty``: beyond
    the empty swarm's and ``sim``'s, ``cpu_gap``)."""
    out = out or Path("runs") / f"bench-scale-{time.strftime('%Y%m%d-%H%M%S')}"
    out.mkdir(parents=True, exist_ok=True)
    print(
        f"bench --scale: generated layered swarms, {duration_s:g} s lockstep runs (2N+1 processes) "
        f"against sim; processes started by {start}; CPU in seconds per simulated second"
    )
    head = (
        f"{'N':>3} {'edges':>5} {'start s':>7} {'run x':>6} {'e2e x':>6} {'sim x':>6} "
        f"{'cpu/s':>6} {'sim':>6} {'ovh':>5} | {'empty x':>7} {'cpu/s':>6} {'run/(e+s)':>9} | "
        f"{'veh':>5} {'ctrl':>5} {'lead':>5} {'sup':>5} | "
        f"ctrl main/zenoh/ready s, vehicle ready s"
    )
    print(head)
    rows = []
    runs = out / "runs"  # each N's run directory is kept: its logs say where a failed run stopped
    failed = []
    realtime: list[dict[str, float]] = []
    for n in ns:
        try:
            r = measure(n, duration_s, runs, start, empty)
        except RunFailedError as e:  # the others are still measured; the exit code says it
            failed.append(n)
            print(f"{n:>3} the run failed: {e} (run directory {runs / f'n{n}'})", flush=True)
            continue
        rows.append(r)
        if empty and math.isnan(r["empty_x"]):  # asked for and not measured: the exit code says it
            failed.append(n)
        print(
            f"{n:>3} {r['edges']:>5} {r['startup_s']:>7.2f} {r['run_x']:>6.2f} {r['e2e_x']:>6.2f} "
            f"{r['sim_x']:>6.1f} {r['cpu_per_sim_s']:>6.2f} {r['sim_cpu_per_sim_s']:>6.3f} "
            f"{r['overhead']:>5.1f} | {r['empty_x']:>7.2f} {r['empty_cpu_per_sim_s']:>6.2f} "
            f"{r['over_empty_sim']:>9.2f} | "
            f"{r['cpu_vehicles']:>5.2f} {r['cpu_controllers']:>5.2f} "
            f"{r['cpu_leader']:>5.2f} {r['cpu_supervisor']:>5.2f} | {r['ctrl_main_s']:.2f}/"
            f"{r['ctrl_zenoh_s']:.2f}/{r['ctrl_ready_s']:.2f}, {r['vehicle_ready_s']:.2f}",
            flush=True,
        )
    if realtime_s > 0:
        print(
            f"real time, {realtime_s:g} s runs: late ticks (skipped, or setpoint out after the next "
            f"tick's instant) and when setpoints go out after their tick's instant"
        )
        for n in ns:
            try:
                rt = measure_realtime(n, realtime_s, runs, start)
            except RunFailedError as e:
                failed.append(n)
                print(f"{n:>3} the real-time run failed: {e}", flush=True)
                print(f"    saturated at {n} followers (the run failed): larger N not run")
                break
            realtime.append(rt)
            print(
                f"{n:>3} late {100 * rt['late_share']:6.2f} %   setpoint out median "
                f"{rt['out_median_ms']:.2f} ms, p99 {rt['out_p99_ms']:.2f} ms",
                flush=True,
            )
            if rt["late_share"] > SATURATED_LATE:
                print(
                    f"    saturated at {n} followers (over {100 * SATURATED_LATE:g} % late): larger N not run"
                )
                break
        with open(out / "realtime.csv", "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=["followers", "late_share", "out_median_ms", "out_p99_ms"])
            w.writeheader()
            w.writerows(realtime)
    gaps: list[dict[str, Any]] = []
    for split_n in splits or []:
        try:
            split = measure_split(split_n, duration_s, runs, start)
        except RunFailedError as e:
            failed.append(split_n)
            print(f"{split_n:>3} the profiled run failed: {e}", flush=True)
        else:
            row = next((r for r in rows if r["followers"] == split_n), None)
            _print_split(split_n, split, row, out / f"split{split_n}.csv")
            if row is not None and empty and not math.isnan(row["empty_x"]):
                gaps.extend(print_gap(row, split))
    if gaps:
        write_gap(gaps, out / "gap.csv")
    with open(out / "scale.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=COLUMNS)
        w.writeheader()
        w.writerows(rows)
    if rows:
        _plot(rows, out / "scale.png")
    print(f"wrote {out / 'scale.csv'} and {out / 'scale.png'}")
    return 1 if failed else 0
