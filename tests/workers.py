"""Which pytest-xdist worker runs what, and at which priority (``tests/conftest.py`` plugs it in).

The system tests that are marked neither ``lockstep`` nor ``light`` fly swarms in real time (and so
do the tests marked ``realtime``): their processes must get the CPU when their clocks say so. A
``light`` test flies one vehicle (or a few) in real time for a client that mostly waits on it
(MAVSDK's flows, a pymavlink script's round trips): a niced vehicle answers such a client in time
(checked: those tests, niced, beside two niced workers running the rest, five times over), so it
runs beside the others, on any worker, as a ``lockstep`` test does, and its waiting is not in the
real-time worker's chain. Only the first worker,
``gw0``, takes them, one at a time, in the order collected, at the normal priority. Every other
worker lowers its own priority (``nice``) at its first test, and so do the processes its tests
start: the unit and integration tests and the lockstep system tests take the CPU the real-time
runs leave idle (most of it: a real-time run mostly waits for its clock) without making a
real-time run late. ``gw0`` with no real-time test left takes the others' work, and gives way as
they did (at its first such test), so the rest of the run shares the CPU evenly.

One real-time worker, not two: two real-time swarms at once, both at the normal priority, made
each other late (one swarm's start, a burst of processes, against the other's ticks: a follower
whose tick came a period late skipped it). So there is one worker more than cores (``-n auto``):
on two cores, ``gw0`` with the real-time flights and two niced workers with the rest.
``PYTEST_XDIST_AUTO_NUM_WORKERS`` sets the count, as pytest-xdist documents; ``-n 0`` runs
everything in one process at the normal priority, and ``-n 1`` everything on ``gw0``.
"""

from __future__ import annotations

import os

from xdist.scheduler import LoadGroupScheduling

#: the xdist groups of the system tests that run in real time: ``realtime-0000``, ... (one test each)
REALTIME_GROUP = "realtime"
#: the workers that run them, at the normal priority
REALTIME_WORKERS = ("gw0",)
#: how much the other workers lower their priority: under contention a niced process gets about
#: 110 / 1024 of a normal one's share of a core (Linux CFS weights), so a real-time run is not late
OTHERS_NICE = 10


def worker_count() -> int:
    """One worker per core plus the real-time one, whose flights leave most of a core idle."""
    pinned = os.environ.get("PYTEST_XDIST_AUTO_NUM_WORKERS")
    if pinned:
        return int(pinned)
    return len(os.sched_getaffinity(0)) + len(REALTIME_WORKERS)


_NICED: list[bool] = []


def give_way() -> None:
    """This process (and what it starts) lowers its priority to the other workers', once."""
    if not _NICED:
        _NICED.append(True)
        os.nice(OTHERS_NICE)


def before_test(realtime: bool) -> None:
    """Called before each test in a worker (not with ``-n 0``): a worker gives way at its first
    test that does not fly in real time, and keeps the normal priority until then. The other
    workers so give way at their first test; the real-time one once it has none left
    (``RealtimeOnTheirWorkers`` gives it others only then), so the rest of the run shares the CPU
    evenly; and a worker that takes real-time tests because the real-time one is gone (xdist
    shuts down workers beyond the number of groups, in a run of a few tests) flies them at the
    normal priority."""
    if os.environ.get("PYTEST_XDIST_WORKER") is not None and not realtime:
        give_way()


def is_realtime(scope: str) -> bool:
    return scope.startswith(REALTIME_GROUP + "-")


class RealtimeOnTheirWorkers(LoadGroupScheduling):
    """``--dist loadgroup``, but a real-time test goes to a real-time worker, in the order collected,
    and to no other worker while one is there (were both to die, xdist gives their work back and
    any worker takes it); a real-time worker takes other work when no real-time test is left."""

    def _assign_work_unit(self, node) -> None:  # type: ignore[no-untyped-def]
        ours = node.gateway.id in REALTIME_WORKERS
        realtime_alive = any(n.gateway.id in REALTIME_WORKERS for n in self.nodes)
        pending = [s for s in self.workqueue if is_realtime(s)]
        others = [s for s in self.workqueue if not is_realtime(s)]
        if ours and pending:
            self.workqueue.move_to_end(min(pending), last=False)
        elif realtime_alive and others:
            self.workqueue.move_to_end(others[0], last=False)
        elif realtime_alive:
            return  # only real-time tests are left: this worker waits to be shut down
        super()._assign_work_unit(node)
