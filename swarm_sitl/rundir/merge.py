"""Merge what the processes of a run recorded into one ``Recording`` (the layout ``sim`` writes).

Inputs in ``RUN_DIR/procs/``: ``controller_<i>.rows`` (one row per tick: the tick, the vehicle
sample it used, the command and the law's record, ``layout.controller_columns``) and
``vehicle_<i>.truth`` (the vehicle's true state at every LOCAL_POSITION_NED it sent). Row ``k`` of
follower ``i`` takes the true state at the sample's ``time_boot_ms``; without a truth file (a
vehicle that is not ours) it takes the sample itself (float32 as received, no body rates). A
follower whose controller recorded nothing (``run --external``: a controller the bench does not
run) gets its vehicle's true state at each tick from the truth file alone, and no command. Ticks
nobody recorded stay NaN.
"""

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from sim_vehicles.common.state import POS, QUAT, STATE_SIZE, VEL
from sim_vehicles.runtime.counter_file import read_counter, read_named_counts
from sim_vehicles.runtime.row_log import RowLogError, read_rows
from swarm_sitl.config.schema import SwarmConfig
from swarm_sitl.faults.counts import EdgeStats, stats_from_counts
from swarm_sitl.rundir.events import merge_events
from swarm_sitl.rundir.layout import (
    SAMPLE_COLUMNS,
    TRUTH_COLUMNS,
    controller_columns,
    controller_incarnations,
    controller_stats_path,
    leader_stats_path,
    lost_events_path,
    published_path,
    read_start,
    router_events_path,
    supervisor_events_path,
    vehicle_events_path,
    vehicle_stats_path,
    vehicle_truth_path,
)
from swarm_sitl.rundir.plugins import recorded_law
from swarm_sitl.rundir.recording import COMMAND_WIDTH, FollowerSeries, Recording, leader_series


def _rows(path: Path, columns: list[str]) -> np.ndarray:
    """The rows of a row log with exactly ``columns`` (none if it is missing, unreadable, or of
    other columns)."""
    width = len(columns)
    if not path.is_file():
        return np.empty((0, width))
    try:
        cols, rows = read_rows(path)
    except RowLogError:
        return np.empty((0, width))
    return rows if cols == columns else np.empty((0, width))


def merge_run(cfg: SwarmConfig, run_dir: Path) -> Recording:
    n = cfg.n_control_steps
    dt = cfg.control_dt_s
    law = recorded_law(run_dir)  # what the run flew (never imported from a run directory)
    record_fields = law["record_fields"] if law is not None else cfg.law_class().record_fields
    plain = controller_columns(record_fields)  # (a run recorded before ``in_age_s`` was)
    at = {name: j for j, name in enumerate(plain)}
    sample = slice(at[SAMPLE_COLUMNS[0]], at[SAMPLE_COLUMNS[-1]] + 1)
    command = slice(sample.stop, sample.stop + COMMAND_WIDTH)
    record = slice(command.stop, len(plain))
    graph = cfg.build_graph()
    followers = {}
    offsets = {}
    for f in cfg.followers:
        i = f.id
        n_in = len(graph.in_neighbours(i))
        columns = controller_columns(record_fields, n_in)
        ages = slice(len(plain), len(columns))
        series = FollowerSeries(n + 1, record_fields, n_in)
        parts = []
        for p in controller_incarnations(run_dir, i, ".rows"):
            rows = _rows(p, columns)
            if not len(rows):  # an older run's rows: no ages (NaN)
                old = _rows(p, plain)
                rows = np.hstack([old, np.full((len(old), n_in), np.nan)])
            parts.append(rows)
        width = len(columns)
        ctrl = np.concatenate(parts) if parts else np.empty((0, width))
        truth = _rows(vehicle_truth_path(run_dir, i), TRUTH_COLUMNS)
        if not len(ctrl):
            _truth_only(series, truth, _boot_offset_s(run_dir, i), dt, n)
        by_ms: dict[int, int] = {}
        for j, ms in enumerate(np.round(truth[:, 0] * 1000).astype(np.int64)):
            by_ms.setdefault(int(ms), j)
        for row in ctrl:
            k = int(row[at["k"]])
            if not 0 <= k <= n:
                continue
            row_of_truth = by_ms.get(round(row[at["sample_boot_s"]] * 1000))
            if row_of_truth is not None:
                state = truth[row_of_truth, 1:]
            else:
                state = np.full(STATE_SIZE, np.nan)
                s = row[sample]
                state[POS], state[VEL], state[QUAT] = s[0:3], s[3:6], s[6:10]
            series.record_vehicle(k, row[at["t_s"]], state, row[at["sample_t_s"]])
            series.command[k] = row[command]
            series.record[k] = row[record]
            series.in_age_s[k] = row[ages]
        followers[i] = series.arrays()
        offsets[i] = np.asarray(f.offset_m, dtype=float)
    t_s = np.arange(n + 1) * dt
    trajectory = cfg.trajectory()
    return Recording(leader_series(trajectory, t_s), followers, offsets).with_errors(trajectory)


def _boot_offset_s(run_dir: Path, i: int) -> float:
    """Run time minus vehicle ``i``'s boot time: 0 in lockstep, from its boot instant and the
    run's epoch in real time (NaN if either is unknown)."""
    start = read_start(run_dir)
    if start is None:
        return math.nan
    if start.get("lockstep"):
        return 0.0
    boot = _stats(vehicle_stats_path(run_dir, i)).get("boot_unix_s")
    return float(boot) - float(start["epoch_unix_s"]) if isinstance(boot, int | float) else math.nan


def _truth_only(series: FollowerSeries, truth: np.ndarray, offset_s: float, dt: float, n: int) -> None:
    """Each tick's true state from the truth rows alone: the last row at or before the tick."""
    if not len(truth) or not math.isfinite(offset_s):
        return
    t_run = truth[:, 0] + offset_s
    for k in range(n + 1):
        j = int(np.searchsorted(t_run, k * dt + 1e-9, side="right")) - 1
        if j >= 0 and k * dt - t_run[j] <= dt:
            series.record_vehicle(k, k * dt, truth[j, 1:], float(t_run[j]))


def _stats(path: Path) -> dict[str, Any]:
    try:
        s = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    return s if isinstance(s, dict) else {}


def _killed_stats(path: Path) -> dict[str, Any]:
    """What a killed incarnation counted under the plan (its ``.counts``), as its ``.stats.json``
    would have said it; its report, refusals and delay distributions died with it."""
    counts = read_named_counts(path) or {}
    out: dict[str, Any] = {"in_edges": {}, "mavlink": {}}
    for name in counts:
        parts = name.split(" ", 2)  # "in 3 received", "mavlink up lost"
        if len(parts) != 3 or parts[0] not in ("in", "mavlink") or parts[2] != EdgeStats.FIELDS[0]:
            continue  # not a count this version writes: left out
        head, who, _ = parts
        st = stats_from_counts(counts, f"{head} {who}")
        if st is not None:  # in the order a .stats.json has them (sorted)
            out["in_edges" if head == "in" else "mavlink"][who] = dict(sorted(st.items()))
    return out


def _add(into: dict[str, Any], more: dict[str, Any]) -> None:
    """Counts added, ``max_*`` figures maxed, anything else (a delay distribution) the latest."""
    for key, v in more.items():
        if key not in into:
            into[key] = v
        elif key.startswith("max_") and isinstance(v, int | float):
            into[key] = max(into[key], v)
        elif isinstance(v, int | float) and not isinstance(v, bool):
            into[key] = into[key] + v
        else:
            into[key] = v


#: report fields that count what the machine's load did, not what the run did: a setpoint resent
#: after a wall-clock timeout. They stay in ``procs/`` and the controller's log, out of the summary,
#: which a lockstep run keeps byte for byte the same.
WALL_CLOCK_ONLY = ("resends",)


def inputs_and_links(cfg: SwarmConfig, run_dir: Path) -> tuple[dict[str, Any], dict[str, Any]]:
    """What each controller reported of its inputs (``NodeReport``), and per edge what its
    receiver counted under the fault plan (``faults.edges.EdgeStats``; edges without a fault on
    them deliver what arrives), summed over a restarted controller's incarnations. A controller
    that did not finish reports nothing."""
    inputs: dict[str, Any] = {}
    links: dict[str, Any] = {}
    published = {node: _published(run_dir, node) for node in range(cfg.n_followers + 1)}
    for f in cfg.followers:
        for path in controller_incarnations(run_dir, f.id, ".stats.json", killed=".counts"):
            s = _stats(path) if path.suffix == ".json" else _killed_stats(path)
            if "report" in s:
                report = {k: v for k, v in s["report"].items() if k not in WALL_CLOCK_ONLY}
                _add(inputs.setdefault(str(f.id), {}), report)
            for src, st in s.get("in_edges", {}).items():
                _add(links.setdefault(f"{src}->{f.id}", {}), st)
            for way, st in s.get("mavlink", {}).items():
                _add(links.setdefault(f"mavlink {f.id} {way}", {}), st)
    for src, dst in cfg.graph_edges():  # what each sender published, in all its incarnations
        if f"{src}->{dst}" in links and published[src] is not None:
            links[f"{src}->{dst}"]["sent"] = published[src]
    return inputs, links


def _published(run_dir: Path, node: int) -> int | None:
    """Messages node ``node`` published, summed over its incarnations (killed ones too: the
    counter files outlive them); from the stats of the incarnations that finished where there are
    no counters (an older run directory); None if neither says."""
    counts = []
    for n in range(1000):
        c = read_counter(published_path(run_dir, node, n))
        stats = _stats(
            leader_stats_path(run_dir, n) if node == 0 else controller_stats_path(run_dir, node, n)
        )
        if c is None and not stats:
            break
        counts.append(c if c is not None else stats.get("published", 0))
    return sum(counts) if counts else None


#: what a vehicle refused (``sim_vehicles.vehicle.port.EndpointStats``): the summary's part of
#: its counts (the others count heartbeats, which follow the wall clock)
VEHICLE_REFUSALS = ("rx_bad", "rx_refused", "rx_invalid", "rx_unhandled", "handler_errors")


def vehicle_refusals(cfg: SwarmConfig, run_dir: Path) -> dict[str, Any]:
    """Per vehicle that reported (ours, and not killed), what it received and refused."""
    out: dict[str, Any] = {}
    for f in cfg.followers:
        s = _stats(vehicle_stats_path(run_dir, f.id))
        if s:
            out[str(f.id)] = {k: s.get(k, 0) for k in VEHICLE_REFUSALS}
            if any(s.get("rx_unsigned", {}).values()):  # by port: a tool that did not sign
                out[str(f.id)]["rx_unsigned"] = s["rx_unsigned"]
            if s.get("last_handler_error"):
                out[str(f.id)]["last_handler_error"] = s["last_handler_error"]
    return out


def run_events(cfg: SwarmConfig, run_dir: Path) -> list[dict[str, Any]]:
    """The plan's fault intervals and every process's events, in time order."""
    files = [p for f in cfg.followers for p in controller_incarnations(run_dir, f.id, ".events")]
    files += [vehicle_events_path(run_dir, f.id) for f in cfg.followers]
    files += [supervisor_events_path(run_dir), router_events_path(run_dir), lost_events_path(run_dir)]
    start = read_start(run_dir)
    realtime = start is not None and not start.get("lockstep", True)
    return merge_events(cfg, files, start["epoch_unix_s"] if start is not None and realtime else None)
