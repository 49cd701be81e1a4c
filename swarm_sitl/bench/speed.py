"""``swarm-sitl bench``: speed figures, printed. Ratios are measured in one run on one machine.

- ``sim`` of a config as a new process (start-up included), and its cost per simulated second;
- the same config as a lockstep ``run`` across processes: cost per simulated second next to
  ``sim``'s, and how many times faster than real time (start-up reported apart);
- a larger config in real time, with staggered ticks (the default) and with aligned ones: the
  share of control ticks that are late (skipped, or whose setpoint goes out after the next tick's
  instant) and the distribution of when setpoints go out;
- one vehicle's plant and attitude loop, CPU per 1 kHz step; and beside the config a
  ``paper_quad.yaml``, ``sim``'s cost per follower-tick on that rotor-level quadrotor against the
  config's vehicle, and its step's cost.

``swarm-sitl bench --against DIR`` instead compares this checkout's lockstep ``run`` with another
source tree's (for example ``git worktree add /tmp/old REV``), runs alternated, each side's run
phase as its own CLI reports it.
"""

import os
import re
import resource
import statistics
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

from sim_vehicles.runtime.row_log import read_rows
from swarm_sitl.config.load import load_config
from swarm_sitl.config.schema import SwarmConfig
from swarm_sitl.nodes.assembly import build_autopilot
from swarm_sitl.rundir.layout import controller_rows_path
from swarm_sitl.running.children import child_env, module_argv
from swarm_sitl.running.run import RunRequest, run_swarm
from swarm_sitl.running.sim import run_sim
from swarm_sitl.running.supervisor import RunFailedError


def _vehicle_step_cost_us(
    cfg: SwarmConfig, n_steps: int = 200_000, per_call: int = 10
) -> tuple[float, float]:
    """CPU microseconds per 1 kHz attitude-loop + plant step: one long call, and calls of ``per_call``."""
    ap = build_autopilot(cfg, 1)
    ap.advance(10)  # compile / load cache
    t0 = time.process_time()
    ap.advance(n_steps)
    long_call = (time.process_time() - t0) / n_steps * 1e6
    calls = n_steps // per_call
    t0 = time.process_time()
    for _ in range(calls):
        ap.advance(per_call)
    short_calls = (time.process_time() - t0) / (calls * per_call) * 1e6
    return long_call, short_calls


def _sim_wall_s(cfg_path: str, repeats: int) -> list[float]:
    """Wall seconds of ``swarm-sitl sim CONFIG`` as a fresh process (startup included)."""
    out = []
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(repeats):
            t0 = time.monotonic()
            done = subprocess.run(
                [
                    *module_argv("swarm_sitl"),
                    "sim",
                    cfg_path,
                    "--quiet",
                    "--out",
                    str(Path(tmp) / f"r{r}"),
                ],
                stdout=subprocess.DEVNULL,
                stderr=subprocess.PIPE,
                text=True,
                env=child_env(),
            )
            if done.returncode != 0:
                last = (done.stderr.strip().splitlines() or [""])[-1]
                raise RunFailedError(f"swarm-sitl sim exited with code {done.returncode}: {last}")
            out.append(time.monotonic() - t0)
    return out


def sim_in_process_s(cfg: SwarmConfig) -> tuple[float, float]:
    """Wall and CPU seconds of ``sim`` of ``cfg`` in this process, its kernels loaded first."""
    run_sim(cfg, n_steps=2)  # kernels loaded
    t0, c0 = time.monotonic(), time.process_time()
    run_sim(cfg)
    return time.monotonic() - t0, time.process_time() - c0


def late_ticks(cfg: SwarmConfig, run_dir: Path) -> tuple[int, int, np.ndarray]:
    """``(late, expected, done_s of every recorded tick)`` over all controllers of a real-time run."""
    n = cfg.n_control_steps + 1
    late, done = 0, []
    for f in cfg.followers:
        cols, rows = read_rows(controller_rows_path(run_dir, f.id))
        c = cols.index("done_s")
        late += (n - len(rows)) + int(np.sum(rows[:, c] > cfg.control_dt_s))
        done.append(rows[:, c])
    return late, n * cfg.n_followers, np.concatenate(done)


def run_bench(cfg_path: str, scale_cfg_path: str, repeats: int = 3, realtime_s: float = 20.0) -> int:
    cfg = load_config(cfg_path)
    print(
        f"bench on {cfg_path}: {cfg.n_followers} followers, {cfg.duration_s:g} s, control "
        f"{cfg.rates.control_hz:g} Hz, attitude loop {cfg.rates.attitude_hz:g} Hz"
    )
    _sim_wall_s(cfg_path, 1)  # one untimed run so the compiled kernels are in the on-disk cache
    walls = _sim_wall_s(cfg_path, repeats)
    best, med = min(walls), statistics.median(walls)
    print(
        f"  swarm-sitl sim (new process, startup included): best {best:.2f} s, median {med:.2f} s "
        f"of {repeats} -> {cfg.duration_s / best:.1f}x real time (target: >= 20x, i.e. < "
        f"{cfg.duration_s / 20:.1f} s)"
    )
    sim_s, _ = sim_in_process_s(cfg)
    sim_cost = sim_s / cfg.duration_s
    with tempfile.TemporaryDirectory() as tmp:
        lock = [run_swarm(RunRequest(cfg, Path(tmp) / f"l{r}")) for r in range(repeats)]
    lock_best = min(r.run_wall_s for r in lock)
    lock_cost = lock_best / cfg.duration_s
    print(
        f"  cost per simulated second: sim {sim_cost * 1e3:.1f} ms; lockstep run across "
        f"{2 * cfg.n_followers + 1} processes {lock_cost * 1e3:.1f} ms (best of {repeats}; median "
        f"{statistics.median(r.run_wall_s for r in lock) / cfg.duration_s * 1e3:.1f} ms) = "
        f"{lock_cost / sim_cost:.1f}x sim"
    )
    print(
        f"  lockstep run: {cfg.duration_s:g} s in {lock_best:.2f} s -> {cfg.duration_s / lock_best:.1f}x "
        f"real time (target: >= 10x); start-up before the first tick "
        f"{min(r.startup_wall_s for r in lock):.1f} s"
    )
    big = load_config(scale_cfg_path).model_copy(update={"duration_s": realtime_s})
    dt_ms = big.control_dt_s * 1e3
    for ticks in ("staggered", "aligned"):  # the default first, then all controllers at one instant
        run = big.model_copy(update={"run": big.run.model_copy(update={"realtime_ticks": ticks})})
        with tempfile.TemporaryDirectory() as tmp:
            run_swarm(RunRequest(run, Path(tmp), lockstep=False))
            late, total, done = late_ticks(run, Path(tmp))
        print(
            f"  real time, {scale_cfg_path} ({big.n_followers} followers, {realtime_s:g} s, period "
            f"{dt_ms:g} ms, {ticks} ticks): {late} of {total} ticks late = {100 * late / total:.2f} % "
            f"(target: < 1 %); setpoint out after the tick's instant: median "
            f"{np.median(done) * 1e3:.2f} ms, p99 {np.percentile(done, 99) * 1e3:.2f} ms, "
            f"max {done.max() * 1e3:.1f} ms"
        )
    long_us, short_us = _vehicle_step_cost_us(cfg)
    print(
        f"  vehicle plant + attitude loop, CPU per 1 kHz step: {long_us:.2f} us in long calls, "
        f"{short_us:.2f} us in calls of 10 steps as the sim makes them (target: < 10 us)"
    )
    quad_path = Path(cfg_path).with_name("paper_quad.yaml")
    if quad_path.is_file():  # the rotor-level quadrotor beside the paper's vehicle
        quad = load_config(quad_path)
        quad_s, _ = sim_in_process_s(quad)
        here, there = follower_tick_us(cfg, sim_s), follower_tick_us(quad, quad_s)
        print(
            f"  sim, CPU per follower-tick: {cfg.vehicle.model} {here:.1f} us, {quad.vehicle.model} "
            f"({quad_path.name}) {there:.1f} us = {there / here:.2f}x (target: <= 1.5x)"
        )
        long_us, short_us = _vehicle_step_cost_us(quad)
        print(
            f"  {quad.vehicle.model}'s rotors, mixer and PX4 loops with its plant, CPU per 1 kHz step: "
            f"{long_us:.2f} us in long calls, {short_us:.2f} us in calls of 10 steps"
        )
    return 0 if np.isfinite(best) else 1


def follower_tick_us(cfg: SwarmConfig, sim_s: float) -> float:
    """``sim``'s wall time per follower per control tick [us]: a vehicle's period and its law's tick."""
    return sim_s / (cfg.n_followers * (cfg.n_control_steps + 1)) * 1e6


_RUN_WALL = re.compile(r"simulated in ([0-9.]+) s wall")


def _lockstep_run_wall_s(cfg_path: str, tree: Path, out: Path) -> tuple[float, float]:
    """The run phase (start signal to last tick) of ``swarm-sitl run CONFIG`` in lockstep, with the
    packages of source tree ``tree``, as that CLI prints it; and the CPU seconds of every process
    of that run, start-up included."""
    cpu0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    env = child_env()
    env["PYTHONPATH"] = os.pathsep.join([str(tree), env.get("PYTHONPATH", "")])
    done = subprocess.run(
        [*module_argv("swarm_sitl"), "run", cfg_path, "--quiet", "--out", str(out)],
        capture_output=True,
        text=True,
        env=env,
        cwd=tree,
    )
    m = _RUN_WALL.search(done.stdout)
    if done.returncode != 0 or m is None:
        last = (done.stderr.strip().splitlines() or [""])[-1]
        raise RunFailedError(f"run from {tree} exited with code {done.returncode}: {last}")
    cpu1 = resource.getrusage(resource.RUSAGE_CHILDREN)  # the CLI waited for every process it ran
    return float(m.group(1)), (cpu1.ru_utime + cpu1.ru_stime) - (cpu0.ru_utime + cpu0.ru_stime)


def compare_trees(cfg_path: str, other: Path, pairs: int) -> int:
    """Lockstep ``run`` of ``cfg_path`` from this checkout and from ``other``, alternated ``pairs``
    times after one untimed run of each (compiled kernels cached); prints both and their ratio."""
    here = Path(__file__).resolve().parents[2]
    other = other.resolve()
    cfg = Path(cfg_path).resolve()
    got: dict[Path, list[tuple[float, float]]] = {here: [], other: []}
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(pairs + 1):
            order = (here, other) if r % 2 == 0 else (other, here)
            for j, tree in enumerate(order):
                w = _lockstep_run_wall_s(str(cfg), tree, Path(tmp) / f"r{r}_{j}")
                if r > 0:
                    got[tree].append(w)
    print(f"lockstep run of {cfg_path}, {pairs} pairs alternated:")
    for what, col in (("run phase wall, as each CLI prints it", 0), ("CPU of every process", 1)):
        new, old = [x[col] for x in got[here]], [x[col] for x in got[other]]
        print_pairs(what, ("this checkout", new), (str(other), old), "this / other")
    return 0


_RUN_WALL = re.compile(r"simulated in ([0-9.]+) s wall")


def cpu_now() -> tuple[float, float]:
    """This process's children's CPU and its own, to take a run's CPU as a difference (``ended``)."""
    c = resource.getrusage(resource.RUSAGE_CHILDREN)
    return c.ru_utime + c.ru_stime, time.process_time()


def ended(returncode: int, printed: str, stderr: str, cpu0: tuple[float, float]) -> tuple[float, float]:
    """A ``run`` that has ended: its run phase's wall time as the CLI printed it, and the CPU of
    every process since ``cpu0`` (``cpu_now`` before it started); ``RunFailedError`` (its last
    line) if it failed."""
    found = _RUN_WALL.search(printed)
    if returncode != 0 or found is None:
        last = (stderr.strip().splitlines() or [""])[-1]
        raise RunFailedError(f"run exited with code {returncode}: {last}")
    children, own = cpu_now()
    return float(found.group(1)), children - cpu0[0] + own - cpu0[1]


def print_pairs(what: str, a: tuple[str, list[float]], b: tuple[str, list[float]], ratio: str) -> None:
    """Two series of alternated runs (``(name, seconds)``), their bests, medians and ratios."""
    (na, xa), (nb, xb) = a, b
    ratios = [x / y for x, y in zip(xa, xb, strict=True)]
    print(
        f"  {what}: {na} best {min(xa):.2f} s, median {statistics.median(xa):.2f} s; "
        f"{nb} best {min(xb):.2f} s, median {statistics.median(xb):.2f} s"
    )
    print(
        f"    {ratio}: median of pair ratios {statistics.median(ratios):.3f}, ratio of bests "
        f"{min(xa) / min(xb):.3f} (pairs: {', '.join(f'{x:.3f}' for x in ratios)})"
    )
