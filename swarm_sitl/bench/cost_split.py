"""Where a process's CPU goes, by activity: what ``swarm-sitl bench --scale --split N`` prints.

Two measurements, each for what it can see:

- ``thread_split``: of each process's run-phase CPU, its main thread (the loop) against its other
  threads (zenoh's runtime: sending, receiving, routing), exact (``/proc/<pid>/task/*/schedstat``,
  noted by ``sim_vehicles.runtime.lifeline.mark`` at ready and at exit);
- ``activity_split``: the main thread's time by activity, from the cProfile each process writes
  under ``SWARM_SITL_PROFILE`` (timed by the thread's CPU clock), in a separate profiled run:

  - ``physics and laws``: the plant, attitude loop and failsafe (``sim_vehicles``), the estimator
    and controller (``swarm_sitl``), compiled kernels and the Python that calls them;
  - ``MAVLink``: frames, conversions, signing, the vehicle's endpoint and the controller's link;
  - ``zenoh``: the bus (``bus*.py``) and the zenoh calls it makes (puts, payloads);
  - ``waking up``: the calls that block until something comes (``select``, ``sleep``, and the
    lockstep vehicle's blocking ``recvfrom``): the CPU of going to sleep and waking (a poll(2)
    that only looks, ``udp_arrival.Waiting``, is its caller's);
  - ``logs``: row logs, events, the ``.tlog``;
  - ``loop and other``: the per-tick loops themselves and everything else.

  A function of a library or a builtin (a socket call, ``numpy``) is counted in the activity of
  whoever called it, in proportion. cProfile adds a fixed cost per Python call, so the split leans
  towards Python-heavy activities; the main-thread share from the unprofiled run is exact.
"""

import pstats
from collections import defaultdict
from collections.abc import Iterable
from pathlib import Path

ACTIVITIES = ("physics and laws", "MAVLink", "zenoh", "waking up", "logs", "loop and other")

_BY_FILE = (  # (activity, path fragments), first match wins
    ("logs", ("sim_vehicles/runtime/row_log.py", "sim_vehicles/runtime/event_log.py", "swarm_sitl/rundir/")),
    (
        "physics and laws",
        (
            "sim_vehicles/plant/",
            "sim_vehicles/common/",
            "sim_vehicles/vehicle/lockstep_tick.py",  # the plant's period, then two frames packed
            "swarm_sitl/laws/",
            "swarm_sitl/nodes/neighbour_inbox.py",
        ),
    ),
    (
        "MAVLink",
        (
            "sim_vehicles/mavlink/",
            "sim_vehicles/vehicle/",
            "swarm_sitl/link/",
            "swarm_sitl/faults/mavlink.py",
            "/pymavlink/",
        ),
    ),
    ("zenoh", ("swarm_sitl/bus/", "swarm_sitl/faults/edges.py")),
)
#: the vehicle endpoint's loop and scheduling (the rest of ``vehicle.endpoint`` is MAVLink)
_VEHICLE_LOOP = ("run_lockstep", "run_realtime", "step", "heartbeat_tick")
#: ... and the modules that are all loop: the run loops, the flight modes' checks
_VEHICLE_LOOP_FILES = ("sim_vehicles/vehicle/loops.py", "sim_vehicles/vehicle/modes.py")
_WAITS = ("select.select", "time.sleep", "'epoll' objects")
#: helpers shared by the link and the bus (``udp_arrival.Waiting``: a poll(2) that does not block)
_SHARED = ("sim_vehicles/runtime/udp_arrival.py",)
_BLOCKING_RECV = ("run_lockstep",)  #: callers whose ``recvfrom`` blocks for the next datagram


def activity_of(func: tuple[str, int, str]) -> str | None:
    """The activity of a profiled function ``(file, line, name)``; None: its caller's."""
    path, _, name = func
    if path == "~":
        if any(w in name for w in _WAITS):
            return "waking up"
        if "zenoh" in name or "of 'builtins." in name:  # zenoh's classes are in ``builtins``
            return "zenoh"
        return None
    path = path.replace("\\", "/")
    if path.endswith(_SHARED):
        return None  # its caller's: the vehicle link's or the bus's
    if path.endswith(_VEHICLE_LOOP_FILES) or (
        path.endswith("sim_vehicles/vehicle/endpoint.py") and name in _VEHICLE_LOOP
    ):
        return "loop and other"
    for activity, fragments in _BY_FILE:
        if any(f in path for f in fragments):
            return activity
    if "/swarm_sitl/" in path or "/sim_vehicles/" in path:
        return "loop and other"
    return None  # a library's Python (numpy, contextlib, ...): its caller's


def activity_split(profiles: Iterable[Path]) -> dict[str, float]:
    """Seconds of main-thread CPU per activity over the profiles given (one process kind)."""
    paths = [str(p) for p in profiles]
    out: dict[str, float] = dict.fromkeys(ACTIVITIES, 0.0)
    if not paths:
        return out
    stats = pstats.Stats(paths[0])
    for p in paths[1:]:
        stats.add(p)
    table = stats.stats  # type: ignore[attr-defined]
    memo: dict[tuple[str, int, str], dict[str, float]] = {}

    def shares(func: tuple[str, int, str], depth: int = 0) -> dict[str, float]:
        """How ``func``'s own time divides between activities (by its callers if it has none)."""
        if func in memo:
            return memo[func]
        act = activity_of(func)
        if act is not None:
            result = {act: 1.0}
        else:
            callers = table[func][4] if func in table else {}
            total = sum(c[2] for c in callers.values())
            result = defaultdict(float)
            if depth > 20 or total <= 0:
                result["loop and other"] = 1.0
            else:
                for caller, c in callers.items():
                    if func[0] == "~" and "recvfrom" in func[2] and caller[2] in _BLOCKING_RECV:
                        result["waking up"] += c[2] / total
                        continue
                    for a, w in shares(caller, depth + 1).items():
                        result[a] += w * c[2] / total
            result = dict(result)
        memo[func] = result
        return result

    for func, (_cc, _nc, tt, _ct, _callers) in table.items():
        for a, w in shares(func).items():
            out[a] += tt * w
    return out
