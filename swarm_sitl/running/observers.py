"""What the supervisor's loop does as a run goes, declared once: each thing it watches or feeds
is an ``Observer`` (a call and how often), and ``supervise`` runs them in their order until every
process that must finish has, then the loop ends.

A run's observers (``run.run_swarm``): the process fault plan acting on time, the supervisor's
check of its children, the real-time tick watch, the router watch, the start signal put again
for late subscribers, the progress line and the page's live feed. Each is told the run's time
(seconds since the start epoch, on the UNIX clock every host shares) and the monotonic instant.
"""

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from swarm_sitl.running.supervisor import SUPERVISE_EVERY_S, Supervisor


@dataclass
class Observer:
    """``act(run_s, now_mono_s)`` at most every ``every_s`` (0: at every pass of the loop, which
    comes every ``SUPERVISE_EVERY_S``)."""

    act: Callable[[float, float], None]
    every_s: float = 0.0
    due_mono_s: float = 0.0  #: the next instant it acts at or after


def supervise(sup: Supervisor, observers: Sequence[Observer], epoch_unix_s: float) -> None:
    """Run ``observers`` in their order, each when it is due, until ``sup`` says every process
    that must finish has; what an observer raises ends the run."""
    while not sup.finished():
        for o in observers:
            now = time.monotonic()
            if now >= o.due_mono_s:
                o.act(time.time() - epoch_unix_s, now)
                o.due_mono_s = now + o.every_s
        time.sleep(SUPERVISE_EVERY_S)
