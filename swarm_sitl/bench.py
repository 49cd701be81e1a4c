"""``swarm-sitl bench``: speed figures, printed. Ratios are measured in one run on one machine."""

import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from swarm_sitl.assembly import build_autopilot
from swarm_sitl.config import load_config


def _vehicle_step_cost_us(cfg_path: str, n_steps: int = 200_000, per_call: int = 10) -> tuple[float, float]:
    """CPU microseconds per 1 kHz attitude-loop + plant step: one long call, and calls of ``per_call``."""
    cfg = load_config(cfg_path)
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
            subprocess.run(
                [
                    sys.executable,
                    "-m",
                    "swarm_sitl",
                    "sim",
                    cfg_path,
                    "--quiet",
                    "--out",
                    str(Path(tmp) / f"r{r}"),
                ],
                check=True,
                stdout=subprocess.DEVNULL,
            )
            out.append(time.monotonic() - t0)
    return out


def run_bench(cfg_path: str, repeats: int = 3) -> int:
    cfg = load_config(cfg_path)
    print(
        f"bench on {cfg_path}: {cfg.n_followers} followers, {cfg.duration_s:g} s, control "
        f"{cfg.rates.control_hz:g} Hz, attitude loop {cfg.rates.attitude_hz:g} Hz"
    )
    # one untimed run so the compiled kernels are in the on-disk cache
    _sim_wall_s(cfg_path, 1)
    walls = _sim_wall_s(cfg_path, repeats)
    best, med = min(walls), statistics.median(walls)
    print(
        f"  swarm-sitl sim (new process, startup included): best {best:.2f} s, median {med:.2f} s "
        f"of {repeats} -> {cfg.duration_s / best:.1f}x real time (target: >= 20x, i.e. < "
        f"{cfg.duration_s / 20:.1f} s)"
    )
    long_us, short_us = _vehicle_step_cost_us(cfg_path)
    print(
        f"  vehicle plant + attitude loop, CPU per 1 kHz step: {long_us:.2f} us in long calls, "
        f"{short_us:.2f} us in calls of 10 steps as the sim makes them (target: < 10 us)"
    )
    return 0 if np.isfinite(best) else 1
