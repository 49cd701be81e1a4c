"""The estimates a node has heard and may use, per in-neighbour and tick: ``EstimateTable``.

A node's bus files each estimate here once it may be used (at once, or when a fault plan's stage
lets it through, ``faults.in_edges``); the loop asks for one tick's estimate or the newest. The
zenoh bus (``node_bus.ZenohNodeBus``) is one; ``sim`` keeps one per follower, so both read the same
table by the same rules.
"""

from typing import Protocol

from swarm_sitl.bus.codec import Message


class Estimates(Protocol):
    """What a tick reads estimates from: an ``EstimateTable``, or a node's bus."""

    def estimate(self, src: int, step: int) -> Message | None: ...
    def latest(self, src: int) -> Message | None: ...


def newest_for_tick(estimates: Estimates, src: int, k: int) -> Message | None:
    """Lockstep: what tick ``k`` uses from ``src``: its estimate of tick ``k - 1``, or (a fault
    plan hid or held it) the newest it may use then, none of tick ``k`` or later."""
    m = estimates.estimate(src, k - 1)
    if m is None:
        m = estimates.latest(src)
        if m is not None and m.step >= k:
            return None
    return m


class EstimateTable:
    def __init__(self) -> None:
        self.dropped = 0  #: payloads dropped and counted (did not decode, or not what the sender sends)
        self._estimates: dict[int, dict[int, Message]] = {}
        self._latest: dict[int, Message] = {}

    def counts(self, step: int) -> bool:
        """Whether an estimate of ``step`` is counted in the edge's figures (all of them here)."""
        return True

    def file(self, m: Message) -> None:
        """Make ``m`` available to the loop (``estimate``, ``latest``)."""
        self._estimates.setdefault(m.src, {})[m.step] = m
        cur = self._latest.get(m.src)
        if cur is None or m.step >= cur.step:
            self._latest[m.src] = m

    def estimate(self, src: int, step: int) -> Message | None:
        """``src``'s estimate of ``step``, if it has been filed."""
        return self._estimates.get(src, {}).get(step)

    def latest(self, src: int) -> Message | None:
        """The newest estimate of ``src`` filed."""
        return self._latest.get(src)

    def forget_before(self, step: int) -> None:
        """Drop the estimates of ticks before ``step``. A table is in arrival order, which is tick
        order on a reliable link, so this looks only at what it drops (and at one more), however
        far the sources have run ahead; one that came out of order goes once those before it have."""
        for table in self._estimates.values():
            while table:
                k = next(iter(table))
                if k >= step:
                    break
                del table[k]
