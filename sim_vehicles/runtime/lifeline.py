"""The life of a long-running process of the bench.

- ``hold_on()``: die with the parent. A child started by a supervisor asks the kernel for SIGTERM
  when its parent goes away, so a supervisor killed with SIGKILL leaves no orphan (Linux; elsewhere
  a no-op). The supervisor puts its pid in ``SWARM_SITL_PARENT_PID``; the child calls it first thing.
- ``settle_heap()``: once set-up is done, move everything allocated so far (numba's and llvmlite's
  large object graphs among it) out of the garbage collector's sight. Without it the collector's
  periodic full passes over that graph cost a lockstep run about a quarter of its CPU.
- ``batch_scheduling()``: a lockstep process asks the kernel to schedule it for throughput
  (``SCHED_BATCH``, Linux; elsewhere a no-op). In lockstep the processes hand each tick to one
  another: a controller's setpoint wakes its vehicle, the vehicle's sample wakes the controller.
  Under the default policy the woken process preempts the sender in the middle of its ``sendto``,
  and both pay an extra context switch and refill their caches. A batch process is not preempted
  when another wakes, so a sender finishes its tick first. Threads started afterwards (zenoh's)
  inherit the policy. Real-time processes keep the default policy: there latency matters.
- ``mark(name)`` and ``process_figures()``: where a process's start-up and CPU went. ``mark``
  notes the process's age (seconds since the kernel created it), its CPU seconds (every
  thread's; the main thread's and the others' apart) at a named point (``main``: the interpreter
  and the imports done; ``zenoh``: its session open; ``ready``); ``process_figures`` gives them
  with the totals, for a stats file.
- ``profiled(name, body)``: a debugging aid. With ``SWARM_SITL_PROFILE=DIR`` set, run ``body`` under
  cProfile timed by this thread's CPU clock (sleeping, waiting and being preempted cost nothing, so
  the figures are what the loop itself spends) and write ``DIR/<name>.prof``.
"""

import ctypes
import gc
import math
import os
import signal
import sys
import time
from collections.abc import Callable
from typing import TypeVar

T = TypeVar("T")

ENV = "SWARM_SITL_PARENT_PID"
_PR_SET_PDEATHSIG = 1


def hold_on() -> None:
    parent = os.environ.get(ENV)
    if not parent or not sys.platform.startswith("linux"):
        return
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0)
    except (OSError, AttributeError):
        return
    if str(os.getppid()) != parent:  # the parent died before we asked
        os.kill(os.getpid(), signal.SIGTERM)


def batch_scheduling() -> bool:
    """``SCHED_BATCH`` for this thread and the threads it starts; whether the kernel took it."""
    if not hasattr(os, "sched_setscheduler") or not hasattr(os, "SCHED_BATCH"):
        return False
    try:
        os.sched_setscheduler(0, os.SCHED_BATCH, os.sched_param(0))
    except OSError:
        return False
    return True


_LOADED = time.monotonic()
_MARKS: dict[str, dict[str, float]] = {}


def process_age_s() -> float:
    """Seconds since the kernel created this process (Linux ``/proc``, 10 ms resolution); elsewhere
    since this module was imported."""
    try:
        with open("/proc/self/stat") as f:
            start_ticks = int(f.read().rsplit(")", 1)[1].split()[19])  # field 22, starttime
        with open("/proc/uptime") as f:
            uptime_s = float(f.read().split()[0])
        return uptime_s - start_ticks / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return time.monotonic() - _LOADED


def thread_cpu_s() -> tuple[float, float]:
    """CPU seconds of this process's main thread and of all its other threads together, exact
    (Linux ``schedstat``: time on a CPU; a thread that has ended is no longer counted); NaN
    elsewhere."""
    main = others = 0.0
    try:
        tids = os.listdir("/proc/self/task")
    except OSError:
        return math.nan, math.nan
    for tid in tids:
        try:
            with open(f"/proc/self/task/{tid}/schedstat") as f:
                s = int(f.read().split()[0]) / 1e9
        except (OSError, ValueError, IndexError):  # a thread that has just ended
            continue
        if int(tid) == os.getpid():
            main += s
        else:
            others += s
    return main, others


def _figures() -> dict[str, float]:
    main, others = thread_cpu_s()
    return {
        "age_s": process_age_s(),
        "cpu_s": time.process_time(),
        "unix_s": time.time(),
        "main_thread_s": main,
        "other_threads_s": others,
    }


def mark(name: str) -> None:
    if name not in _MARKS:
        _MARKS[name] = _figures()


def process_figures() -> dict[str, object]:
    """``cpu_s`` (every thread), ``age_s``, the main thread's and the other threads' CPU
    (``thread_cpu_s``) now, and the ``marks`` noted so far (each with the same figures)."""
    now = _figures()
    del now["unix_s"]
    return {**now, "marks": dict(_MARKS)}


def settle_heap() -> None:
    gc.collect()
    gc.freeze()


def profiled(name: str, body: Callable[[], T]) -> T:
    folder = os.environ.get("SWARM_SITL_PROFILE")
    if not folder:
        return body()
    import cProfile

    prof = cProfile.Profile(time.thread_time_ns, 1e-9)
    try:
        return prof.runcall(body)
    finally:
        os.makedirs(folder, exist_ok=True)
        prof.dump_stats(os.path.join(folder, name.replace(" ", "_") + ".prof"))
