"""One point of a campaign: a lockstep run of a config, and the metrics of its row.

``run_point`` is the unit of work wherever it runs (a thread here, a Dask worker on another host):
it takes the point's whole config as YAML text, runs it with ``swarm-sitl run`` in a directory of
its own, and returns the row's metrics; nothing else crosses.
"""

import contextlib
import math
import shutil
import signal
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from swarm_sitl.running import warm_commands

#: the metrics of a row, in the table's order
METRICS = (
    "passed",  #: 1: the run completed and every follower held the bound after settling; else 0
    "max_error_m",  #: the largest formation error of any follower after ``run.settle_s`` [m]
    "final_error_m",  #: the largest formation error of any follower at the end [m]
    "recovered_s",  #: from the plan's last window's end until every follower is in the bound for good [s]
    "delivered_min",  #: the least delivered fraction of any graph edge
    "delivered_mean",  #: the mean delivered fraction over the graph's edges
    "failsafe_s",  #: time the vehicles spent in their setpoint-loss failsafe, summed [s]
    "failure",  #: one line naming what failed, or empty
    "wall_s",  #: the run's wall time [s]
)
EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_BOUND = 0, 1, 2, 3
#: the runs under way in this process (a campaign interrupted here ends them: ``stop_running``)
RUNNING: set[warm_commands.Command] = set()


def stop_running() -> None:
    """End the runs under way as Ctrl-C would (each writes its run directory and exits)."""
    for proc in list(RUNNING):
        with contextlib.suppress(ProcessLookupError):
            proc.send_signal(signal.SIGINT)


class PointError(RuntimeError):
    """A point that could not run at all (its config refused, the command missing): one line."""


#: a point past its wall budget is interrupted (its run writes what it recorded), then killed this
#: long after if it has not ended [s]
INTERRUPT_GRACE_S = 30.0


def run_command(cfg_path: Path, run_dir: Path) -> list[str]:
    """The command that flies a point: a lockstep ``swarm-sitl run`` (forked from a warm server
    where it can be: ``running.warm_commands``)."""
    return [*warm_commands.CLI, "run", str(cfg_path), "--out", str(run_dir), "--quiet"]


def _timed_out(timeout_s: float, wall_s: float) -> dict[str, Any]:
    row: dict[str, Any] = dict.fromkeys(METRICS, math.nan)
    row.update(passed=0, failure=f"timed out after {timeout_s:g} s (the point's wall budget)")
    row["wall_s"] = round(wall_s, 3)
    return row


def run_point(
    config_yaml: str,
    name: str,
    keep_dir: str | None = None,
    plugins: dict[str, bytes] | None = None,
    timeout_s: float | None = None,
) -> dict[str, Any]:
    """Run the config ``config_yaml`` in lockstep and return its metrics (``METRICS``). The run
    directory is ``keep_dir`` if given (kept), else a temporary one (removed). ``plugins``: the
    files its plug-in entries name (``plugins/my_law.py``, relative to the config), shipped with
    the point and written beside it (``rundir.plugins.pack``). A run past ``timeout_s`` of wall
    time is interrupted and its row failed ``timed out``."""
    work = Path(tempfile.mkdtemp(prefix=f"sweep-{name}-"))
    said = Path(tempfile.mkdtemp(prefix=f"sweep-{name}-said-"))  # its stdout and stderr, apart
    try:
        cfg_path = work / f"{name}.yaml"
        cfg_path.write_text(config_yaml)
        for rel, body in (plugins or {}).items():
            (work / rel).parent.mkdir(parents=True, exist_ok=True)
            (work / rel).write_bytes(body)
        run_dir = Path(keep_dir) if keep_dir else work / "run"
        if keep_dir:
            shutil.rmtree(run_dir, ignore_errors=True)
        cmd = run_command(cfg_path, run_dir)
        t0 = time.monotonic()
        proc = warm_commands.start(cmd, said / "stdout", said / "stderr")
        RUNNING.add(proc)
        try:
            try:
                proc.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                proc.send_signal(signal.SIGINT)  # the run writes what it recorded
                try:
                    proc.wait(timeout=INTERRUPT_GRACE_S)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait()
                assert timeout_s is not None
                return _timed_out(timeout_s, time.monotonic() - t0)
        finally:
            RUNNING.discard(proc)
        r = subprocess.CompletedProcess(
            proc.args,
            proc.wait(),  # (ended: its code)
            (said / "stdout").read_text(errors="replace"),
            (said / "stderr").read_text(errors="replace"),
        )
        wall = time.monotonic() - t0
        if r.returncode == EXIT_USAGE or not (run_dir / "summary.json").is_file():
            last = (r.stderr.strip().splitlines() or [f"exit {r.returncode}"])[-1]
            raise PointError(f"point {name}: {last}")
        if r.returncode not in (EXIT_OK, EXIT_BOUND, EXIT_FAILED):
            raise (
                KeyboardInterrupt
                if r.returncode in (130, 143, 129)
                else PointError(f"point {name}: swarm-sitl run exited {r.returncode}")
            )
        failure = ""
        if r.returncode == EXIT_FAILED:
            failure = (r.stderr.strip().splitlines() or ["failed"])[-1].removeprefix("swarm-sitl: ")
        return metrics_of(run_dir, failure, wall)
    finally:
        shutil.rmtree(work, ignore_errors=True)
        shutil.rmtree(said, ignore_errors=True)


def _bound_and_windows(run_dir: Path) -> tuple[float, float, list[float]]:
    import yaml

    cfg = yaml.safe_load((run_dir / "config.yaml").read_text())
    run = cfg.get("run", {})
    ends = [
        float(e["until_s"]) for e in cfg.get("faults", {}).get("plan", []) if e.get("until_s") is not None
    ]
    return float(run.get("max_formation_error_m") or math.inf), float(run.get("settle_s", 20.0)), ends


def metrics_of(run_dir: Path, failure: str, wall_s: float) -> dict[str, Any]:
    """A finished run directory's metrics."""
    import json

    from swarm_sitl.rundir.load import load_run

    rec = load_run(run_dir)
    summary = json.loads((run_dir / "summary.json").read_text())
    events_path = run_dir / "events.jsonl"
    lines = events_path.read_text().splitlines() if events_path.is_file() else []
    events = [json.loads(x) for x in lines if x]
    bound, settle_s, ends = _bound_and_windows(run_dir)
    t = None
    worst: np.ndarray | None = None
    for a in rec.followers.values():
        e = np.linalg.norm(a["pos_err_m"], axis=1)
        t = a["t_s"]
        worst = e if worst is None else np.fmax(worst, e)
    assert t is not None and worst is not None
    finite = np.isfinite(worst)
    after = finite & (t >= settle_s)
    max_err = float(worst[after].max()) if after.any() else math.nan
    final = float(worst[finite][-1]) if finite.any() else math.nan
    recovered = recovered_after(t, worst, bound, max(ends)) if ends and finite.any() else math.nan
    fractions = [
        min(1.0, st["delivered"] / st["received"])
        for name, st in summary.get("links", {}).items()
        if "->" in name and st.get("received")
    ]
    held = all(r.get("holds", False) for r in summary.get("spec", {}).values())
    passed = failure == "" and bool(after.any()) and max_err <= bound and held
    return {
        "passed": int(passed),
        "max_error_m": max_err,
        "final_error_m": final,
        "recovered_s": recovered,
        "delivered_min": min(fractions) if fractions else math.nan,
        "delivered_mean": float(np.mean(fractions)) if fractions else math.nan,
        "failsafe_s": failsafe_s(events, float(t[-1])),
        "failure": failure,
        "wall_s": round(wall_s, 3),
        **{  # each requirement's robustness (the config's spec:), NaN where nothing was recorded
            f"spec.{name}": math.nan if r.get("robustness") is None else float(r["robustness"])
            for name, r in summary.get("spec", {}).items()
        },
    }


def recovered_after(t: np.ndarray, worst: np.ndarray, bound: float, end_s: float) -> float:
    """From ``end_s`` (the plan's last window's end) to the first sample from which the error
    ``worst`` stays within ``bound`` to the end (NaN samples skipped): 0 if it never left it,
    NaN if it is out at the end."""
    finite = np.isfinite(worst)
    over = np.nonzero(finite & (t >= end_s) & (worst > bound))[0]
    if over.size == 0:
        return 0.0
    if over[-1] == np.nonzero(finite)[0][-1]:  # still out at the end: never recovered
        return math.nan
    return float(t[over[-1] + 1] - end_s)


def failsafe_s(events: list[dict[str, Any]], end_s: float) -> float:
    """The vehicles' time in their setpoint-loss failsafe, summed; one still in it counts to
    ``end_s``."""
    from swarm_sitl.rundir.events import failsafe_windows

    windows = failsafe_windows(events).values()
    return round(
        sum((end_s if end == math.inf else end) - start for each in windows for start, end in each), 6
    )
