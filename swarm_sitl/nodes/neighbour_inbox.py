"""Which in-neighbour estimates a controller's tick uses, and riding through the ones that stop.

A tick uses, from each in-neighbour, the newest estimate it has (it is carried to the tick by its
age, ``follower_law``) while that estimate is at most ``staleness_s`` old. Past it, the neighbour
is left out of the estimator's sums, as at ``k = 0``, until a newer estimate comes; with no live
in-edge at all the estimator runs on its own states. Each change is an event (``events``):
``neighbour_lost`` and ``neighbour_regained`` with the estimate's age, ``no_live_in_edge``.

With every estimate on time this is exactly what a tick used before there were faults: the
in-neighbours' estimates of tick ``k - 1``.
"""

import math
from collections.abc import Callable

from sim_vehicles.runtime.event_log import EventLog
from swarm_sitl.bus.codec import Message
from swarm_sitl.laws.contract import Received


class NeighbourInbox:
    def __init__(self, follower: int, sources: list[int], staleness_s: float, events: EventLog):
        self.follower = follower
        self.sources = list(sources)
        self.staleness_s = staleness_s
        self.events = events
        self._last: dict[int, Message] = {}
        self._live: dict[int, bool] = dict.fromkeys(self.sources, False)
        self.stale_ticks = dict.fromkeys(self.sources, 0)  #: ticks each was left out, once heard
        self.max_age_s = dict.fromkeys(self.sources, 0.0)  #: oldest estimate used [s]
        #: per in-neighbour (``sources``' order), the age of the newest estimate it has at the last
        #: tick gathered, used or not [s]; NaN until it has one (``recording``'s ``in_age_s``)
        self.ages = [math.nan] * len(self.sources)

    def gather(self, t_s: float, newest: Callable[[int], Message | None]) -> dict[int, Received]:
        """The law's inbox at tick ``t_s`` (``laws.contract.Received``: each in-neighbour's newest
        usable message, with its age); ``newest(src)``: the newest message the bus has from it."""
        out: dict[int, Received] = {}
        last, ages, live, max_age = self._last, self.ages, self._live, self.max_age_s
        for j, s in enumerate(self.sources):
            m = newest(s)
            prev = last.get(s)
            if m is None or (prev is not None and prev.step > m.step):
                if prev is None:
                    continue  # never heard from: left out, as at k = 0
                m = prev
            else:
                last[s] = m
            age = t_s - m.t_s
            ages[j] = age
            if age <= self.staleness_s:
                out[s] = Received(m.values, m.t_s, age)
                if age > max_age[s]:
                    max_age[s] = age
                if not live[s]:
                    live[s] = True
                    if self.stale_ticks[s]:
                        self.events.add(
                            t_s, "neighbour_regained", follower=self.follower, neighbour=s, age_s=age
                        )
            else:
                self.stale_ticks[s] += 1
                if self._live[s]:
                    self._live[s] = False
                    self.events.add(t_s, "neighbour_lost", follower=self.follower, neighbour=s, age_s=age)
                    if not any(self._live.values()):
                        self.events.add(t_s, "no_live_in_edge", follower=self.follower)
        return out
