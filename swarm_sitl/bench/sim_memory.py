"""``bench --sim-memory S,S,...``: ``sim``'s peak resident memory against its duration.

``sim`` of the config for each duration, one process each (``swarm-sitl sim --quiet``), its peak
resident memory read from the kernel when it ends (``wait4``'s ``ru_maxrss``), and its wall time;
printed with each peak over the first's. ``sim`` spools its rows to disk a block at a time
(``rundir.spool``): the target is a peak that does not grow with the duration (the issue's: the
paper's run for 60 s and for 3600 s within 10 %).
"""

import os
import subprocess
import tempfile
import time
from pathlib import Path

from swarm_sitl.running.children import child_env, module_argv


def _sim(cfg_path: str, duration_s: float, out: Path) -> tuple[float, float, int]:
    """One ``sim``: its peak resident memory [MB], its wall time [s] and its exit code."""
    argv = [*module_argv("swarm_sitl"), "sim", cfg_path, "--duration", f"{duration_s:g}", "--quiet"]
    argv += ["--out", str(out)]
    t0 = time.monotonic()
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=child_env())
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    return usage.ru_maxrss / 1024, time.monotonic() - t0, proc.returncode  # (Linux: ru_maxrss in kB)


def sim_memory(cfg_path: str, durations_s: list[float]) -> int:
    """``sim`` of ``cfg_path`` for each of ``durations_s``; prints each's peak memory and wall."""
    print(f"sim of {cfg_path}: peak resident memory by duration (one process each)")
    first = None
    with tempfile.TemporaryDirectory() as tmp:
        for n, d in enumerate(durations_s):
            peak, wall, code = _sim(cfg_path, d, Path(tmp) / f"r{n}")
            first = first or peak
            said = "" if code == 0 else f" (exit {code})"
            ratio = f"({peak / first:.3f} of the first)"
            print(f"  {d:>8g} s: peak {peak:7.1f} MB {ratio}, {wall:7.1f} s wall{said}")
    print("  target: the peak does not grow with the duration (60 s and 3600 s within 10 %)")
    return 0
