"""A fault plan acting on a node's in-edges: ``FaultyBus`` wraps a ``ZenohNodeBus``.

Every estimate the wrapped bus decodes comes here first (its ``deliver``). The plan's fate for it
(``plan.fate``: lost, corrupted, delayed, duplicated) decides whether and when the loop may
use it; the wrapped bus files it then. Nothing in the loop or the laws knows about faults: a lost
estimate is one the loop does not get, and it rides through on the last one it has
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

Time, for delays and for the plan's ``from_s``/``until_s``:

- lockstep: a message of step ``s`` is on time at tick ``s + 1``; a delay of ``d`` seconds makes it
  usable from tick ``s + 1 + ceil(d / dt)``; the plan's window is read at the message's own time;
- real time: from its arrival (run seconds since the start epoch) plus the delay.

Distance and bandwidth. A range entry needs the distance between the two nodes at the message's
step: the sender's position comes with its message, the receiver's own is the one it published at
that step (``publish``). In lockstep a message that comes before this node has done its own tick
of that step waits, undecided, until it has (the message is needed one tick later, so it never
waits for that); in real time the receiver's newest position serves (one that comes before this
node's first tick waits for it). A bandwidth entry on the
sender is its queue, which this node replays for its in-edge (``bandwidth.RadioQueue``): a
message dropped there is lost (``queue_full``), one that left after the next tick is late.
"""

import contextlib
import heapq
import math
import os
import signal
import time
from typing import Any

from sim_vehicles.runtime.counter_file import NamedCounts
from swarm_sitl.bus.clock import POLL_S, RunClock, StallError, wait_until
from swarm_sitl.bus.codec import Message, PayloadError, Status, decode_message, encode_message, message_size
from swarm_sitl.bus.node_bus import ZenohNodeBus
from swarm_sitl.faults.bandwidth import RadioQueue
from swarm_sitl.faults.counts import EdgeStats, counts_names
from swarm_sitl.faults.draws import uniform
from swarm_sitl.faults.plan import FaultPlan, FaultSpec, down_at, fate
from swarm_sitl.faults.plan import edge_channel as channel_of
from swarm_sitl.faults.radio_range import distance_m

_CORRUPT_BYTE = 3  #: salt of the draw that picks the byte a corruption flips
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
        self.plan = plan
        self.node = node
        self.clock = clock
        self.end_s = end_s
        self.stall_timeout_s = stall_timeout_s
        sources = sorted({s for s, d in graph_edges if d == node})
        self.dests = dests = sorted({d for s, d in graph_edges if s == node})
        # lockstep process faults: who is down when, what this node waits for before publishing
        outages = plan.outages(clock.period_s) if clock.lockstep else {}
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
        self.rules: dict[int, list[tuple[int, FaultSpec]]] = {
            s: plan.on_edge(s, node, graph_edges) for s in sources
        }
        self.stats = {s: EdgeStats() for s in sources}
        self._graph_edges = graph_edges
        #: in-neighbours whose messages a link model needs the distance of (``range``'s, ...)
        self._ranged = {s for s, rules in self.rules.items() if any(f.needs_distance for _, f in rules)}
        #: in-neighbours with a bandwidth budget, and their queues (made at their first message)
        self._budgeted = {
            s: f for s, rules in self.rules.items() for _, f in rules if f.bandwidth is not None
        }
        self._queues: dict[int, RadioQueue] = {}
        #: this node's position as it last published it, and that step's number
        self._own_newest: tuple[float, float, float] | None = None
        self._own_step = -1
        self._undecided: list[Message] = []  #: lockstep: waiting for our own position of their step
        #: real time: come before this node had the start signal, so before it had a clock to
        #: judge them by (``poll`` judges them once it has)
        self._early: list[Message] = []
        self._uncounted = EdgeStats()  #: what steps the bus does not count are counted in
        self._arrived: dict[int, int] = {}
        #: heap of (due, order, message, whether it is a duplicate's second copy)
        self._pending: list[tuple[float, int, Message, bool]] = []
        self._order = 0
        inner.deliver = self._admit

    # -- the plan ------------------------------------------------------------------------------------
    def _stats_of(self, m: Message) -> EdgeStats:
        """Where ``m`` is counted: its edge's stats, or (a step the bus does not count,
        ``ZenohNodeBus.counted_steps``) stats nobody reads: it meets its fate, uncounted."""
        return self.stats[m.src] if self.inner.counts(m.step) else self._uncounted

    def _admit(self, m: Message) -> None:
        src = m.src
        if src not in self.stats:  # not one of our in-edges (the wrapped bus subscribes to no other)
            return
        st = self._stats_of(m)
        st.received += 1
        st.held += 1  # until it is delivered, lost or dropped
        self._arrived[src] = max(self._arrived.get(src, -1), m.step)
        if not self.clock.started():
            # real time, before this node has the start signal (a restarted node hears its
            # in-neighbours before it has the swarm's clock): judged once it has it
            self._early.append(m)
            return
        self._route(m)

    def _route(self, m: Message) -> None:
        if m.src in self._ranged and (
            m.step > self._own_step if self.clock.lockstep else self._own_newest is None
        ):
            self._undecided.append(m)  # decided when this node publishes that step (or its first)
            return
        self._decide(m)

    def _decide(self, m: Message) -> None:
        src = m.src
        counted = self.inner.counts(m.step)
        st = self._stats_of(m)
        clock = self.clock
        dt = clock.period_s
        at = m.t_s if clock.lockstep else clock.now_s()
        left_s = 0.0  # how long after its tick it left its sender's queue [s]
        if src in self._budgeted:
            left = self._queue(m).leaves(m.step)
            if left is None:
                st.queue_full += 1
                st.count_fate(True)
                st.held -= 1
                return
            left_s = left
        d = math.nan
        if src in self._ranged:  # a link model needs the distance
            # Lockstep: this node's position of the message's own step. A message of step s is
            # decided when this node publishes s, or when it comes after that, and it comes before
            # this node publishes s + 1, which waits for it (one sender's messages come in order):
            # either way this node's newest is of step s (of its first step if s is before it,
            # after a restart). Real time: the newest.
            own = self._own_newest
            assert own is not None  # (a message is decided once this node has published)
            d = distance_m(m.p_W, own)
            st.count_distance(d)
        rules = self.rules[src]
        f = fate(self.plan.seed, rules, channel_of(src, self.node), m.step, at, self.end_s, dt, distance_m=d)
        st.count_fate(f.lost)
        st.out_of_range += f.out_of_range
        st.retried += f.retried
        if f.lost:
            st.held -= 1
            return
        if f.corrupt:
            data = bytearray(encode_message(m))
            j = int(uniform(self.plan.seed, channel_of(src, self.node), m.step, _CORRUPT_BYTE) * len(data))
            data[j] ^= 0xFF
            try:
                m = decode_message(bytes(data))
            except PayloadError:
                st.corrupt += 1
                st.held -= 1
                self.inner.dropped += counted
                return
        due: float
        if clock.lockstep:
            # on time at the next tick if it left its queue by then, else at the first tick after
            queued = max(0, math.ceil(left_s / dt - 1e-9) - 1)
            due = m.step + 1 + queued + (math.ceil(f.delay_s / dt - 1e-9) if f.delay_s > 0 else 0)
            late = queued > 0
            again = 1.0
        else:
            now = clock.now_s()
            late = left_s > 0 and m.t_s + left_s > now  # (a budget's: it has left its queue)
            due = (m.t_s + left_s if late else now) + f.delay_s
            again = dt
        if f.delay_s > 0 or late:
            st.delayed += 1
            st.delays_s.append(f.delay_s + (left_s if late else 0.0))
        self._push(due, m, False)
        if f.duplicate:
            self._push(due + again, m, True)

    def _queue(self, m: Message) -> RadioQueue:
        """The sender's queue (``bandwidth``), made at its first message (which gives its size)."""
        q = self._queues.get(m.src)
        if q is None:
            f = self._budgeted[m.src]
            dests = sorted({d for s, d in self._graph_edges if s == m.src})
            down = self.outages.get(m.src, [])
            until = self.end_s if f.until_s is None else f.until_s
            assert f.bandwidth is not None
            q = self._queues[m.src] = RadioQueue(
                f.bandwidth,
                len(dests),
                dests.index(self.node),
                message_size(len(m.values)),
                self.clock.period_s,
                lambda k: down_at(down, k),
                lambda t: f.from_s <= t < until,
            )
        return q

    def _push(self, due: float, m: Message, copy: bool) -> None:
        """Hold ``m`` until ``due`` (``clock.now()``'s unit); ``copy``: a duplicate's second copy."""
        self._order += 1
        heapq.heappush(self._pending, (due, self._order, m, copy))

    def _release(self) -> None:
        pending = self._pending
        if not pending:
            return
        now = self.clock.now()
        while pending and pending[0][0] <= now:
            _, _, m, copy = heapq.heappop(pending)
            st = self._stats_of(m)
            st.delivered += 1
            if copy:
                st.duplicated += 1
            else:
                st.held -= 1
            self.inner.file(m)

    # -- NodeBus -------------------------------------------------------------------------------------
    @property
    def dropped(self) -> int:
        return self.inner.dropped

    def poll(self) -> None:
        self.inner.poll()
        if self._early and self.clock.started():
            early, self._early = self._early, []
            for m in early:
                self._route(m)
        self._release()

    def fileno(self) -> int:
        return self.inner.fileno()

    def settled(self, src: int, step: int) -> bool:
        if self._arrived.get(src, -1) >= step:
            return True
        down = self.outages.get(src)
        return down is not None and down_at(down, step)

    def estimate(self, src: int, step: int) -> Message | None:
        return self.inner.estimate(src, step)

    def latest(self, src: int) -> Message | None:
        return self.inner.latest(src)

    def publish(self, msg: Message) -> None:
        if self._ranged:
            self._own_newest, self._own_step = msg.p_W, msg.step
            if self._undecided:
                last = msg.step if self.clock.lockstep else math.inf
                now = [m for m in self._undecided if m.step <= last]
                self._undecided = [m for m in self._undecided if m.step > last]
                for m in now:
                    self._decide(m)
        if self.own_outages and down_at(self.own_outages, msg.step):
            # the plan kills this node here: as a crash would, with what it has not flushed, once
            # what it published before has reached its readers
            self._await_delivery(msg.step)
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
        return {s: st.as_dict() for s, st in self.stats.items()}

    def counts_names(self) -> list[str]:
        return [n for s in self.stats for n in counts_names(f"in {s}")]

    def keep_counts(self, counts: NamedCounts) -> None:
        """Count every in-edge in ``counts`` (names from ``counts_names``)."""
        for s, st in self.stats.items():
            st.bind(counts.view(counts_names(f"in {s}")))


def acts_on(plan: FaultPlan, node: int, graph_edges: list[tuple[int, int]]) -> bool:
    """Whether ``plan`` has an entry on an edge into ``node`` or a process fault (else the bus
    needs no wrapper)."""
    if any(f.is_process for f in plan.plan):
        return True
    return any(plan.on_edge(s, d, graph_edges) for s, d in graph_edges if d == node)
