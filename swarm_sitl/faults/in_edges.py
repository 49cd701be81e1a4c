"""A fault plan's stage on the edges into one node: each estimate's fate, and when it may be used.

``InEdges`` takes every estimate that comes for node ``node`` (``admit``), gives it the plan's fate
(``plan.fate``: lost, corrupted, delayed, duplicated; a sender's radio queue, ``bandwidth``; a
distance, ``radio_range``) and files it in the node's ``EstimateTable`` when it is due
(``release``). It does no I/O: the zenoh bus's wrapper (``edges.FaultyBus``) feeds it what
arrives, and ``sim`` feeds it what its followers publish, so both give every message the same fate
at the same tick.

Time, for delays and for the plan's ``from_s``/``until_s``, is the run's clock's
(``bus.clock.RunClock``: ``message_due``, ``arrival_s``), which owns these rules:

- lockstep: a message of step ``s`` is on time at tick ``s + 1``; a delay of ``d`` seconds makes it
  usable from tick ``s + 1 + ceil(d / dt)``; the plan's window is read at the message's own time;
- real time: from its arrival (run seconds since the start epoch) plus the delay.

Distance and bandwidth. A range entry needs the distance between the two nodes at the message's
step: the sender's position comes with its message, the receiver's own is the one it published at
that step (``published``). In lockstep a message that comes before this node has published that
step waits, undecided, until it has (the message is needed one tick later, so it never waits for
that); in real time the receiver's newest position serves (one that comes before this node's first
tick waits for it). A bandwidth entry on the sender is its queue, which this node replays for its
in-edge (``bandwidth.RadioQueue``): a message dropped there is lost (``queue_full``), one that left
after the next tick is late.
"""

import heapq
import math
from typing import Any

from sim_vehicles.runtime.counter_file import NamedCounts
from swarm_sitl.bus.clock import RunClock
from swarm_sitl.bus.codec import Message, PayloadError, decode_message, encode_message, message_size
from swarm_sitl.bus.estimates import EstimateTable
from swarm_sitl.faults.bandwidth import RadioQueue
from swarm_sitl.faults.counts import EdgeStats, counts_names
from swarm_sitl.faults.draws import uniform
from swarm_sitl.faults.fate_table import FateTable, batched
from swarm_sitl.faults.plan import ON_TIME, FaultEntry, FaultPlan, down_at, fate
from swarm_sitl.faults.plan import edge_channel as channel_of
from swarm_sitl.faults.radio_range import distance_m

_CORRUPT_BYTE = 3  #: salt of the draw that picks the byte a corruption flips


class InEdges:
    """``plan`` on the edges into ``node``; what it lets through goes to ``table``. ``outages``:
    the lockstep outages of the nodes (``FaultPlan.outages``), which a sender's queue skips."""

    def __init__(
        self,
        table: EstimateTable,
        plan: FaultPlan,
        node: int,
        graph_edges: list[tuple[int, int]],
        clock: RunClock,
        end_s: float,
        outages: dict[int, list[tuple[int, int | None]]],
    ):
        self.table = table
        self.plan = plan
        self.node = node
        self.clock = clock
        self.end_s = end_s
        self.outages = outages
        sources = sorted({s for s, d in graph_edges if d == node})
        self.rules: dict[int, list[tuple[int, FaultEntry]]] = {
            s: plan.on_edge(s, node, graph_edges) for s in sources
        }
        self.stats = {s: EdgeStats() for s in sources}
        #: lockstep: the fates of each in-edge whose models all draw many at once, a block at a time
        self._fates = {
            s: FateTable(plan.seed, rules, channel_of(s, node), end_s, clock.period_s)
            for s, rules in self.rules.items()
            if clock.fates_by_tick and batched(rules)
        }
        self._graph_edges = graph_edges
        #: in-neighbours whose messages a link model needs the distance of (``range``'s, ...)
        self._ranged = {s for s, rules in self.rules.items() if any(f.needs_distance for _, f in rules)}
        #: in-neighbours with a bandwidth budget, and their queues (made at their first message)
        self._budgeted = {
            s: f for s, rules in self.rules.items() for _, f in rules if f.bandwidth is not None
        }
        self._queues: dict[int, RadioQueue] = {}
        #: in order (``sim``): the in-edges whose fates are all in their table (no queue, no
        #: distance), for which ``admit`` decides a message on time or only delayed by itself
        self._tabled = {
            s: t for s, t in self._fates.items() if s not in self._budgeted and s not in self._ranged
        }
        #: this node's position as it last published it, and that step's number
        self._own_newest: tuple[float, float, float] | None = None
        self._own_step = -1
        self._undecided: list[Message] = []  #: lockstep: waiting for our own position of their step
        #: real time: come before this node had the start signal, so before it had a clock to
        #: judge them by (``take_early`` judges them once it has)
        self._early: list[Message] = []
        self._uncounted = EdgeStats()  #: what steps the table does not count are counted in
        self.arrived: dict[int, int] = {}  #: per in-neighbour, the newest step that has come
        #: heap of (due, order, message, whether it is a duplicate's second copy, its stats)
        self._pending: list[tuple[float, int, Message, bool, EdgeStats]] = []
        self._order = 0
        #: every message of step s is admitted once this node has done its tick s, nothing reads
        #: the table before its tick s + 1, and the node releases at every tick (``sim``): one on
        #: time is filed at once, not held (the same table at every tick as holding it until
        #: then), and what is held waits in ``_due`` by the tick it is due at (no heap)
        self.in_order = False
        self._due: dict[float, list[tuple[Message, bool, EdgeStats]]] = {}

    def _stats_of(self, m: Message) -> EdgeStats:
        """Where ``m`` is counted: its edge's stats, or (a step the table does not count,
        ``ZenohNodeBus.counted_steps``) stats nobody reads: it meets its fate, uncounted."""
        return self.stats[m.src] if self.table.counts(m.step) else self._uncounted

    def admit(self, m: Message) -> None:
        """``m`` has come (decoded, from one of this node's in-neighbours or not)."""
        src = m.src
        st = self.stats.get(src)
        if st is None:  # not one of our in-edges (the wrapped bus subscribes to no other)
            return
        if not self.table.counts(m.step):
            st = self._uncounted
        st.received += 1
        st.held += 1  # until it is delivered, lost or dropped
        if m.step > self.arrived.get(src, -1):
            self.arrived[src] = m.step
        if self.in_order and self._plain_fate(m, st):
            return
        clock = self.clock
        if not clock.started():
            # real time, before this node has the start signal (a restarted node hears its
            # in-neighbours before it has the swarm's clock): judged once it has it
            self._early.append(m)
            return
        if self._waits_for_own(m):
            self._undecided.append(m)  # decided when this node publishes that step (or its first)
            return
        self._decide(m, st)

    def _waits_for_own(self, m: Message) -> bool:
        """Whether ``m`` needs this node's position and waits, undecided, until it publishes it."""
        return m.src in self._ranged and self.clock.decided_after(
            m.step, self._own_step, self._own_newest is not None
        )

    def _plain_fate(self, m: Message, st: EdgeStats) -> bool:
        """In order, an in-edge of ``_tabled``: ``m`` decided here if its fate is on time or a
        delay alone (what ``_decide`` does with it, in fewer steps: a delay on every message of
        a ``sim`` is 30 000 of them in the paper's minute); False: ``_decide`` it."""
        table = self._tabled.get(m.src)
        if table is None:
            return False
        dt = table.period_s
        step = m.step
        if m.t_s != step * dt:  # (a message stamped with another time than its tick's)
            return False
        f = table.at(step)
        if f is not ON_TIME and (f.lost or f.corrupt or f.duplicate or f.retried):
            return False
        st.last_lost = False  # (``count_fate`` of one that is not lost)
        due = step + 1
        if f.delay_s > 0:
            due += math.ceil(f.delay_s / dt - 1e-9)
            st.delayed += 1
            st.delays_s.append(f.delay_s)
        if due == step + 1:  # nothing reads before tick step + 1: filed now
            st.delivered += 1
            st.held -= 1
            self.table.file(m)
        else:
            self._due.setdefault(due, []).append((m, False, st))
        return True

    def take_early(self) -> None:
        """Real time: judge what came before this node had a clock, once it has one."""
        if self._early and self.clock.started():
            early, self._early = self._early, []
            for m in early:
                if self._waits_for_own(m):
                    self._undecided.append(m)
                else:
                    self._decide(m)

    def _decide(self, m: Message, st: EdgeStats | None = None) -> None:
        """``st``: where ``m`` is counted (``_stats_of``), if the caller has it."""
        src = m.src
        if st is None:
            st = self._stats_of(m)
        counted = st is not self._uncounted
        clock = self.clock
        dt = clock.period_s
        at = clock.arrival_s(m.t_s)
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
        table = self._fates.get(src)
        if table is not None and at == m.step * dt:  # (a message stamped with its tick's time)
            f = table.at(m.step)
        else:
            channel = channel_of(src, self.node)
            f = fate(self.plan.seed, self.rules[src], channel, m.step, at, self.end_s, dt, distance_m=d)
        if f.lost:
            st.count_fate(True)
            st.out_of_range += f.out_of_range
            st.held -= 1
            return
        st.last_lost = False  # (``count_fate`` of one that is not lost)
        if f.retried:
            st.retried += 1
        if f is ON_TIME and left_s == 0.0 and self.in_order:  # on time (in order: filed at once)
            st.delivered += 1
            st.held -= 1
            self.table.file(m)
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
                self.table.dropped += counted
                return
        due, late, again = clock.message_due(m.step, m.t_s, left_s, f.delay_s)
        if f.delay_s > 0 or late:
            st.delayed += 1
            st.delays_s.append(f.delay_s + (left_s if late else 0.0))
        if self.in_order and due == m.step + 1:  # on time, and nothing reads before tick step + 1
            st.delivered += 1
            st.held -= 1
            self.table.file(m)
        else:
            self._push(due, m, False, st)
        if f.duplicate:
            self._push(due + again, m, True, st)

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

    def _push(self, due: float, m: Message, copy: bool, st: EdgeStats) -> None:
        """Hold ``m`` until ``due`` (``clock.now()``'s unit); ``copy``: a duplicate's second copy;
        ``st``: where it is counted (``_stats_of``)."""
        if self.in_order:  # (released at every tick: what is due at a tick, in the order it came)
            self._due.setdefault(due, []).append((m, copy, st))
            return
        self._order += 1
        heapq.heappush(self._pending, (due, self._order, m, copy, st))

    def release(self) -> None:
        """File what is due now."""
        if self.in_order:
            due = self._due.pop(self.clock.tick, None)
            if due:
                file = self.table.file
                for m, copy, st in due:  # (``_deliver``, written out: one call a message less)
                    st.delivered += 1
                    if copy:
                        st.duplicated += 1
                    else:
                        st.held -= 1
                    file(m)
            return
        pending = self._pending
        if not pending:
            return
        now = self.clock.now()
        while pending and pending[0][0] <= now:
            _, _, m, copy, st = heapq.heappop(pending)
            self._deliver(m, copy, st)

    def held(self) -> list[tuple[float, Message, bool]]:
        """What the plan holds now: (when it is due, the message, whether a duplicate's copy)."""
        out = [(due, m, copy) for due, _, m, copy, _ in self._pending]
        return out + [(due, m, copy) for due, due_now in self._due.items() for m, copy, _ in due_now]

    def _deliver(self, m: Message, copy: bool, st: EdgeStats) -> None:
        st.delivered += 1
        if copy:
            st.duplicated += 1
        else:
            st.held -= 1
        self.table.file(m)

    def published(self, msg: Message) -> None:
        """This node published ``msg``: where it is, for the distance of what waits for it."""
        if not self._ranged:
            return
        self._own_newest, self._own_step = msg.p_W, msg.step
        if self._undecided:
            last = self.clock.decidable_through(msg.step)
            now = [m for m in self._undecided if m.step <= last]
            self._undecided = [m for m in self._undecided if m.step > last]
            for m in now:
                self._decide(m)

    def edge_stats(self) -> dict[int, dict[str, Any]]:
        return {s: st.as_dict() for s, st in self.stats.items()}

    def counts_names(self) -> list[str]:
        return [n for s in self.stats for n in counts_names(f"in {s}")]

    def keep_counts(self, counts: NamedCounts) -> None:
        """Count every in-edge in ``counts`` (names from ``counts_names``)."""
        for s, st in self.stats.items():
            st.bind(counts.view(counts_names(f"in {s}")))
