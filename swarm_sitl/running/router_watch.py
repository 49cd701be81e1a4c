"""Whether the run's zenoh router is there (``zenoh.mode: client``: a ``swarm-sitl router`` or a
zenohd of the user's), seen from the supervisor's own session.

Every node is a client of the router, and zenoh reconnects a client by itself when its router
comes back on the same endpoint (in a few seconds: its retry period), declaring its subscriptions
and liveliness token again. In real time the swarm rides through: each controller carries its
neighbours' last estimates, then leaves them out when they are stale, as with any silent edge,
and takes them again when they come. The estimates sent while the router was away are not sent
again, so a lockstep run, whose ticks wait for every one of them, cannot resume: it ends at
once with one line naming the router (rather than after the stall timeout, naming a node).

The supervisor looks every ``WATCH_EVERY_S`` (a call of some 30 us); the router's loss and return
are events (``router_lost``, ``router_back``) in ``procs/router.events``, at run seconds.
"""

import time

import zenoh

from sim_vehicles.runtime.event_log import EventLog
from swarm_sitl.running.supervisor import RunFailedError

WATCH_EVERY_S = 0.1


class RouterWatch:
    """The router(s) at ``endpoints`` as ``session`` (a client) sees them."""

    def __init__(self, session: zenoh.Session, endpoints: list[str], events: EventLog, lockstep: bool):
        self.session = session
        self.endpoints = ", ".join(endpoints)
        self.events = events
        self.lockstep = lockstep
        self.present = True
        self._next = 0.0

    def routers(self) -> int:
        return len(list(self.session.info.routers_zid()))

    def check(self, run_s: float) -> None:
        """Record a change; in lockstep, a loss ends the run (``RunFailedError``)."""
        now = time.monotonic()
        if now < self._next:
            return
        self._next = now + WATCH_EVERY_S
        present = self.routers() > 0
        if present == self.present:
            return
        self.present = present
        if not present:
            self.events.add(round(run_s, 3), "router_lost", router=self.endpoints)
            if self.lockstep:
                raise RunFailedError(
                    f"the zenoh router at {self.endpoints} went away {run_s:.1f} s after the start: a "
                    "lockstep run cannot resume without the messages sent meanwhile; a real-time run rides "
                    "through a router restart"
                )
        else:
            self.events.add(round(run_s, 3), "router_back", router=self.endpoints)

    def close(self) -> None:
        self.events.close()
