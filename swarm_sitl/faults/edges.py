"""A fault plan acting on a node's in-edges: ``FaultyBus`` wraps a ``ZenohNodeBus``.

Every estimate the wrapped bus decodes comes here first (its ``deliver``). The plan's fate for it
(``plan.fate``: lost, corrupted, delayed, duplicated) decides whether and when the loop may
use it (``in_edges``); the wrapped bus files it then. Nothing in the loop or the laws knows about
faults: a lost estimate is one the loop does not get, and it rides through on the last one it has
(``neighbour_inbox``).

Why at the receiver. Zenoh's reliable transport turns packet loss into delays, not lost
messages, so loss is injected where messages are received. In lockstep the estimate still crosses
zenoh and the receiver waits for it as always (``settled``: it has *arrived*), then the plan hides
it, holds it or lets it through. A tick therefore never waits for a message that will not come,
and what the loop sees depends only on the plan, its seed and the steps of the messages: the same
plan gives the same run, bit for bit.

Process faults, in lockstep. A node the plan kills at tick ``k`` kills itself (SIGKILL) when it
is about to publish tick ``k``; a receiver counts the ticks its in-neighbour is down as settled
(nothing will come), and rides through. A restarted node resumes at its restart tick, and a node
publishes a tick at or after a neighbour's restart only once that neighbour's new incarnation has
declared itself ready (its liveliness token: its subscriptions are in place), so it misses
nothing it needs. The leader's window ignores a follower while it is down (``progress``).

The plan's fate for each message, and when it is filed, is the stage ``in_edges.InEdges`` (which
``sim`` runs too); this wrapper feeds it what zenoh brings and carries out the process faults.
"""

import contextlib
import math
import os
import signal
import time
from collections.abc import Callable
from typing import Any

from sim_vehicles.runtime.counter_file import NamedCounts
from swarm_sitl.bus.clock import POLL_S, RunClock, StallError, wait_until
from swarm_sitl.bus.codec import Message, Status
from swarm_sitl.bus.node_bus import ZenohNodeBus
from swarm_sitl.faults.in_edges import InEdges
from swarm_sitl.faults.plan import FaultPlan, down_at

#: longest block between two looks at the out-neighbours' progress before a planned kill (the
#: bus's descriptor wakes it when a status comes) [s]
DELIVERY_POLL_S = 0.05


class FaultyBus:
    """``inner`` under the plan's faults on the edges into ``node`` (a ``NodeBus``)."""

    def __init__(
        self,
        inner: ZenohNodeBus,
        plan: FaultPlan,
        node: int,
        graph_edges: list[tuple[int, int]],
        clock: RunClock,
        end_s: float,
        stall_timeout_s: float = math.inf,
        resume_tick: int = 0,
    ):
        """``resume_tick``: this incarnation's first tick (a node restarted by the plan)."""
        self.inner = inner
        self.node = node
        self.clock = clock
        self.end_s = end_s
        self.stall_timeout_s = stall_timeout_s
        sources = sorted({s for s, d in graph_edges if d == node})
        self.dests = dests = sorted({d for s, d in graph_edges if s == node})
        # lockstep process faults: who is down when, what this node waits for before publishing
        outages = clock.planned_outages(plan)
        self.outages = {n: o for n, o in outages.items() if n in sources or n in dests}
        self.own_outages = outages.get(node, [])
        self._coming_back = {n for n, o in self.outages.items() if any(back is not None for _, back in o)}
        #: (from step, out-neighbour, what it must have done): its first tick after its restart
        #: (a status at or past that tick: its subscriptions are in place), or, after our own
        #: restart, its liveliness token seen (the new session knows where it is)
        #: An out-neighbour that came back before this incarnation started, or at the same tick,
        #: may have sent its status at its first tick before this session could hear it (a put
        #: keeps no history): it is waiting on us, so its liveliness token is enough.
        self._gates: list[tuple[int, int, bool]] = []
        for d in dests:
            self._gates += [
                (back, d, back > resume_tick) for _, back in self.outages.get(d, []) if back is not None
            ]
        for _, back in self.own_outages:
            if back is not None:
                self._gates += [(back, d, False) for d in dests]
        self.faults = InEdges(inner, plan, node, graph_edges, clock, end_s, self.outages)
        inner.deliver = self.faults.admit
        #: what the node keeps before the plan kills it (its rows: a planned kill in lockstep loses
        #: nothing it recorded, so the run is ``sim``'s under the same plan)
        self.before_kill: Callable[[], None] | None = None

    @property
    def stats(self) -> dict[int, Any]:
        """Per in-neighbour, what its edge carried (``counts.EdgeStats``)."""
        return self.faults.stats

    # -- NodeBus -------------------------------------------------------------------------------------
    @property
    def dropped(self) -> int:
        return self.inner.dropped

    def poll(self) -> None:
        self.inner.poll()
        self.faults.take_early()
        self.faults.release()

    def fileno(self) -> int:
        return self.inner.fileno()

    def settled(self, src: int, step: int) -> bool:
        if self.faults.arrived.get(src, -1) >= step:
            return True
        down = self.outages.get(src)
        return down is not None and down_at(down, step)

    def estimate(self, src: int, step: int) -> Message | None:
        return self.inner.estimate(src, step)

    def latest(self, src: int) -> Message | None:
        return self.inner.latest(src)

    def publish(self, msg: Message) -> None:
        self.faults.published(msg)
        if self.own_outages and down_at(self.own_outages, msg.step):
            # the plan kills this node here, as a crash would (what it keeps, ``before_kill``, kept
            # first), once what it published before has reached its readers
            self._await_delivery(msg.step)
            if self.before_kill is not None:
                self.before_kill()
            os.kill(os.getpid(), signal.SIGKILL)
        if self._gates:
            self._await_readers(msg.step)
        self.inner.publish(msg)

    def _await_delivery(self, step: int) -> None:
        """Before a planned kill at ``step``: every out-neighbour has done tick ``step`` (which
        took this node's estimate of ``step - 1``), is down by the plan then, or is gone; or the
        stall timeout. Zenoh sends a put from its own thread: killed at once, the node lost the
        estimates still queued there, and a reader waited for one of a tick before the kill (seen
        on a loaded machine). So the kill loses what the plan says, the ticks from ``step`` on,
        and the run is the same every time."""
        inner = self.inner

        def delivered() -> bool:
            gone = inner.lost()
            return all(
                inner.progress(d) >= step or d in gone or down_at(self.outages.get(d, []), step)
                for d in self.dests
            )

        with contextlib.suppress(StallError):  # a reader that is stuck does not keep this node alive
            wait_until(
                delivered,
                inner.poll,
                [inner.fileno()],
                self.stall_timeout_s,
                lambda: "",
                block_s=lambda: DELIVERY_POLL_S,
            )

    def _await_readers(self, step: int) -> None:
        """Before publishing ``step``: every out-neighbour restarted by then has done its first
        tick again, so it hears this and everything after (and after our own restart, we have
        seen every out-neighbour's liveliness)."""
        due = [g for g in self._gates if g[0] <= step]
        if not due:
            return
        self._gates = [g for g in self._gates if g[0] > step]
        start = time.monotonic()
        inner = self.inner
        for back, d, restarted in due:
            while (inner.progress(d) < back) if restarted else (inner.alive_puts(d) < 1):
                if time.monotonic() - start > self.stall_timeout_s:
                    raise StallError(
                        f"node {self.node} at tick {step}: node {d} did not come back after its restart "
                        f"(waited {time.monotonic() - start:.1f} s)"
                    )
                time.sleep(POLL_S)
                self.inner.poll()

    def publish_status(self, status: Status) -> None:
        self.inner.publish_status(status)

    def forget_before(self, step: int) -> None:
        self.inner.forget_before(step)

    def progress(self, follower: int) -> int:
        """A follower's last reported tick; one that is down (or has not yet come back from a
        restart) does not hold the leader's window."""
        real = self.inner.progress(follower)
        for _, back in self.outages.get(follower, []):
            if back is None or real < back:
                return 1 << 62
        return real

    def start_epoch(self) -> float | None:
        return self.inner.start_epoch()

    def hold_tick(self) -> int:
        return self.inner.hold_tick()

    def lost(self) -> set[int]:
        """Nodes whose liveliness is gone, but for those the plan restarts: their absence is
        planned, and the stall timeout still bounds the wait for them."""
        return self.inner.lost() - self._coming_back

    def set_ready(self) -> None:
        self.inner.set_ready()

    def drain(self, timeout_s: float) -> bool:
        return self.inner.drain(timeout_s)

    def close(self) -> None:
        self.inner.close()

    def edge_stats(self) -> dict[int, dict[str, Any]]:
        return self.faults.edge_stats()

    def counts_names(self) -> list[str]:
        return self.faults.counts_names()

    def keep_counts(self, counts: NamedCounts) -> None:
        """Count every in-edge in ``counts`` (names from ``counts_names``)."""
        self.faults.keep_counts(counts)


def acts_on(plan: FaultPlan, node: int, graph_edges: list[tuple[int, int]]) -> bool:
    """Whether ``plan`` has an entry on an edge into ``node`` or a process fault (else the bus
    needs no wrapper)."""
    if any(f.is_process for f in plan.plan):
        return True
    return any(plan.on_edge(s, d, graph_edges) for s, d in graph_edges if d == node)
