"""A fault plan's stage on the edges into one node (``faults.in_edges.InEdges``) in lockstep, two
ways: as ``sim`` drives it (``in_order``: a message on time or only delayed is filed or held by
tick, without the heap) and as a controller process's bus does (every message through the heap).
Lockstep equals ``sim`` bit for bit only if the two file the same messages at the same ticks, so
for any plan of any hows and windows on the node's in-edges, any seed and any motion of the
senders, they must: at every tick the same table, and at the end the same counts, in which every
message received is accounted for (``received == delivered - duplicated + lost + corrupt +
held``) at every tick; and no message is filed before the tick after its own. Its real-time path
(the plan asked for each message's fate as it comes) where it differs: what comes before the
start signal, and a reorder's hold from the arrival."""

import math
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from swarm_sitl.bus.clock import RunClock
from swarm_sitl.bus.codec import Message
from swarm_sitl.bus.estimates import EstimateTable
from swarm_sitl.faults.in_edges import InEdges
from swarm_sitl.faults.plan import FaultPlan

pytestmark = pytest.mark.unit

DT = 0.02
TICKS = 40
NODE = 3
#: the leader 0 and followers 1 and 2 each send to follower 3 (and the leader to 1 and 2)
EDGES = [(0, 1), (0, 2), (0, 3), (1, 3), (2, 3)]
SOURCES = (0, 1, 2)

_p = st.floats(0.05, 0.9)
_delay = st.floats(0.0, 5 * DT)
_how = st.one_of(
    st.builds(lambda p: {"loss": p}, _p),
    st.just({"drop": True}),
    st.builds(lambda p, r: {"bursty": {"p": p, "r": r}}, _p, _p),
    st.builds(lambda d, j: {"delay_s": d, "jitter_s": j}, _delay, _delay),
    st.just({"stall": True}),
    st.builds(lambda p: {"duplicate": p}, _p),
    st.builds(lambda p: {"reorder": p}, _p),
    st.builds(lambda p: {"corrupt": p}, _p),
    st.builds(
        lambda r, f, n: {"range": {"range_m": r, "fading_db": f, "retries": n, "retry_s": DT / 2}},
        st.floats(2.0, 40.0),
        st.floats(0.0, 10.0),
        st.integers(0, 2),
    ),
)
#: a sender's radio (on the edges out of it)
_radio = st.builds(
    lambda rate, q: {"bandwidth": {"rate_bps": rate, "queue": q}}, st.floats(4e3, 4e5), st.integers(0, 4)
)
_on = st.sampled_from([{"into": NODE}, {"edge": [0, NODE]}, {"edge": [1, NODE]}, {"edge": [2, NODE]}])
_out_of = st.sampled_from([{"out_of": 1}, {"out_of": 2}, {"leader_edges": True}, {"all_edges": True}])


@st.composite
def _entry(draw) -> dict:
    radio = draw(st.integers(0, 9)) == 0
    e = {**draw(_out_of), **draw(_radio)} if radio else {**draw(_on), **draw(_how)}
    start = draw(st.sampled_from([0.0, 0.1, 0.3]))
    if start:
        e["from_s"] = start
    if e.get("stall") or draw(st.booleans()):
        e["until_s"] = start + draw(st.sampled_from([0.1, 0.25, 0.5]))
    return e


def _stage(plan: FaultPlan, in_order: bool) -> InEdges:
    stage = InEdges(EstimateTable(), plan, NODE, EDGES, RunClock(True, DT), TICKS * DT, {})
    stage.in_order = in_order
    return stage


def _tick(stage: InEdges, k: int) -> None:
    """The node's tick ``k``, as its loop runs it: what is due is filed, then it publishes (where
    it is, for what waits on the distance)."""
    stage.clock.tick = k
    stage.release()
    stage.published(Message(NODE, k, k * DT, np.zeros(5), (0.0, 0.0, 0.0)))


def _filed(table: EstimateTable) -> set[tuple[int, int, bytes]]:
    return {
        (m.src, m.step, m.values.tobytes()) for by_step in table._estimates.values() for m in by_step.values()
    }


def _accounted(stage: InEdges) -> None:
    """Every message received is delivered (a duplicate's second copy aside), lost, corrupt or
    held now, and each of these is a count of messages: none below 0."""
    for src, s in stage.edge_stats().items():
        assert s["received"] == s["delivered"] - s["duplicated"] + s["lost"] + s["corrupt"] + s["held"], (
            src,
            s,
        )
        counts = ("received", "delivered", "duplicated", "lost", "corrupt", "held")
        assert all(s[k] >= 0 for k in counts) and s["duplicated"] <= s["delivered"], (src, s)


@settings(max_examples=60, deadline=None)
@given(
    entries=st.lists(_entry(), min_size=1, max_size=3),
    seed=st.integers(0, 2**32),
    speeds=st.lists(st.floats(-20.0, 20.0), min_size=3, max_size=3),
)
def test_sim_and_a_controllers_bus_file_the_same_messages_at_the_same_ticks_and_count_every_one(
    entries, seed, speeds
):
    plan = FaultPlan(seed=seed, plan=entries)
    sim, bus = _stage(plan, True), _stage(plan, False)
    rng = np.random.default_rng(seed)
    values = {s: rng.normal(size=(TICKS, 5 if s else 12)) for s in SOURCES}
    for k in range(TICKS):
        t = k * DT
        for stage in (sim, bus):
            _tick(stage, k)
        seen = _filed(sim.table)
        assert seen == _filed(bus.table), (k, seen ^ _filed(bus.table))
        assert all(step < k for _, step, _ in seen)  # nothing before the tick after its own
        for s in SOURCES:  # then every node's message of tick k comes
            m = Message(s, k, t, values[s][k], (speeds[s] * t, 3.0 * s, 0.0))
            sim.admit(m)
            bus.admit(m)
        _accounted(sim)
        _accounted(bus)
    for stage in (sim, bus):  # (sim files a message on time as it comes, the bus at the next tick)
        stage.clock.tick = TICKS
        stage.release()
    assert _filed(sim.table) == _filed(bus.table)
    assert sim.edge_stats() == bus.edge_stats()
    assert all(s["received"] == TICKS for s in sim.edge_stats().values())
    assert sim.table.dropped == bus.table.dropped
    held = sorted((d, m.src, m.step, c) for d, m, c in sim.held())
    assert held == sorted((d, m.src, m.step, c) for d, m, c in bus.held())
    assert all(d > TICKS for d, *_ in held)  # what is still held is due after the last tick


@settings(max_examples=30, deadline=None)
@given(delay=st.floats(0.0, 5 * DT), seed=st.integers(0, 2**32))
def test_a_delay_alone_files_each_message_the_ticks_it_says_after_its_own(delay, seed):
    """A closed form: with only a fixed delay ``d`` on an edge, its message of tick ``s`` is
    filed at tick ``s + 1 + ceil(d / dt)``, by both ways; the other edges' at ``s + 1``."""
    plan = FaultPlan(seed=seed, plan=[{"edge": [1, NODE], "delay_s": delay}])
    late = math.ceil(delay / DT - 1e-9)
    for in_order in (True, False):
        stage = _stage(plan, in_order)
        for k in range(TICKS):
            _tick(stage, k)
            for s in SOURCES:
                filed = stage.table.latest(s)
                want = k - 1 - (late if s == 1 else 0)
                assert (filed.step if filed else -1) == (want if want >= 0 else -1), (in_order, k, s)
            for s in SOURCES:
                stage.admit(Message(s, k, k * DT, np.zeros(5), (0.0, 0.0, 0.0)))
        st_ = stage.edge_stats()[1]
        assert st_["delayed"] == (TICKS if delay > 0 else 0) and st_["delivered"] + st_["held"] == TICKS


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 2**32), p=st.floats(0.1, 1.0))
def test_a_corrupted_message_is_dropped_by_its_checksum_and_counted_never_filed(seed, p):
    """Whichever byte a corruption flips, the message's CRC-32 catches it: the message is
    dropped and counted (corrupt on its edge, dropped in the table), never filed; the rest of
    the edge's messages are filed as they were sent."""
    plan = FaultPlan(seed=seed, plan=[{"edge": [1, NODE], "corrupt": p}])
    for in_order in (True, False):
        stage = _stage(plan, in_order)
        sent = {}
        for k in range(TICKS + 1):
            _tick(stage, k)
            m = sent[k] = Message(1, k, k * DT, np.full(5, 0.5 + k), (1.0, 2.0, 3.0))
            stage.admit(m)
        st_ = stage.edge_stats()[1]
        filed = [stage.table.estimate(1, k) for k in range(TICKS + 1)]
        assert all(f is None or np.array_equal(f.values, sent[k].values) for k, f in enumerate(filed))
        n_filed = sum(f is not None for f in filed)
        assert st_["corrupt"] == stage.table.dropped == TICKS + 1 - st_["delivered"] - st_["held"] > 0
        assert n_filed == st_["delivered"]  # (each filed once)
        assert st_["lost"] == 0


@pytest.mark.parametrize("in_order", [True, False])
@settings(max_examples=10, deadline=None)
@given(queue=st.integers(0, 8), seed=st.integers(0, 2**32))
def test_a_sender_whose_radio_carries_a_tenth_of_its_messages_loses_most_at_its_queue(in_order, queue, seed):
    """Follower 1's radio at a tenth of the bits its message each tick needs: past its queue,
    about nine in ten are dropped there (``queue_full``, of ``lost``); ten times the bits: none."""
    from swarm_sitl.bus.codec import message_size

    need_bps = 8 * message_size(5) / DT
    for factor, most_lost in ((0.1, True), (10.0, False)):
        plan = FaultPlan(
            seed=seed, plan=[{"out_of": 1, "bandwidth": {"rate_bps": factor * need_bps, "queue": queue}}]
        )
        stage = _stage(plan, in_order)
        for k in range(TICKS):
            _tick(stage, k)
            for s in SOURCES:
                stage.admit(Message(s, k, k * DT, np.zeros(5), (0.0, 0.0, 0.0)))
        st_ = stage.edge_stats()[1]
        if most_lost:
            assert st_["queue_full"] >= 0.9 * TICKS - queue - 2 and st_["lost"] >= st_["queue_full"], st_
        else:
            assert st_["queue_full"] == 0 and st_["lost"] == 0, st_
        assert stage.edge_stats()[2]["queue_full"] == 0  # (another sender's radio is its own)


class _CountsFrom(EstimateTable):
    """A restarted node's table: the steps before ``first`` are not counted in its edges' figures
    (``ZenohNodeBus.counted_steps``)."""

    def __init__(self, first: int):
        super().__init__()
        self.first = first

    def counts(self, step: int) -> bool:
        return step >= self.first


_RANGE = {"range": {"range_m": 20.0, "fading_db": 4.0, "retries": 1, "retry_s": DT / 2}}


@settings(max_examples=20, deadline=None)
@given(first=st.integers(0, TICKS), seed=st.integers(0, 2**32), extra=st.lists(_entry(), max_size=2))
def test_steps_a_node_does_not_count_meet_their_fate_uncounted_whichever_way_they_are_decided(
    first, seed, extra
):
    """A range entry on every in-edge: each message waits for this node's position of its step
    and is decided when the node publishes it. Decided there or as it comes, a message of a step
    the table does not count is counted nowhere: each edge received the counted steps' messages,
    and every one of them is accounted for."""
    plan = FaultPlan(seed=seed, plan=[{"into": NODE, **_RANGE}, *extra])
    for in_order in (True, False):
        stage = InEdges(_CountsFrom(first), plan, NODE, EDGES, RunClock(True, DT), TICKS * DT, {})
        stage.in_order = in_order
        for k in range(TICKS):
            stage.clock.tick = k
            stage.release()
            for s in SOURCES:  # (before this node publishes k: they wait for it)
                stage.admit(Message(s, k, k * DT, np.zeros(5), (5.0 * s, 0.0, 0.0)))
            stage.published(Message(NODE, k, k * DT, np.zeros(5), (0.0, 0.0, 0.0)))
            _accounted(stage)
        assert all(s["received"] == TICKS - first for s in stage.edge_stats().values())


def _real_time(plan: FaultPlan) -> InEdges:
    return InEdges(EstimateTable(), plan, NODE, EDGES, RunClock(False, DT), TICKS * DT, {})


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**32), n=st.integers(1, 5))
def test_real_time_what_came_before_the_start_is_judged_once_the_node_has_a_clock_and_a_position(seed, n):
    """Real time: messages that come before this node has the start signal wait; once it has it
    they wait for its first position (a range entry needs it), and once it has published, each is
    decided: filed, lost or held, every one accounted for."""
    stage = _real_time(FaultPlan(seed=seed, plan=[{"into": NODE, **_RANGE}]))
    for k in range(n):
        for s in SOURCES:
            stage.admit(Message(s, k, k * DT, np.zeros(5), (5.0 * s, 0.0, 0.0)))
    stage.take_early()  # (no clock yet: nothing judged)
    assert all(s["held"] == n for s in stage.edge_stats().values())
    stage.clock.epoch_mono = time.monotonic()
    stage.take_early()
    stage.published(Message(NODE, 0, 0.0, np.zeros(5), (0.0, 0.0, 0.0)))
    _accounted(stage)
    pending = len(stage.held())
    assert sum(s["held"] for s in stage.edge_stats().values()) == pending
    stage.clock.epoch_mono -= 1.0  # a second later: everything delayed is due
    stage.release()
    assert all(s["held"] == 0 for s in stage.edge_stats().values())
    assert sum(s["received"] for s in stage.edge_stats().values()) == len(SOURCES) * n


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 2**32))
def test_real_time_a_reordered_message_is_held_one_control_period_from_its_arrival(seed):
    """Real time asks the plan for each message's fate as it comes (no table): a reorder of
    probability 1 holds each message one period from when it came."""
    stage = _real_time(FaultPlan(seed=seed, plan=[{"edge": [1, NODE], "reorder": 1.0}]))
    stage.clock.epoch_mono = time.monotonic()
    before = stage.clock.now_s()
    stage.admit(Message(1, 0, 0.0, np.zeros(5), (0.0, 0.0, 0.0)))
    after = stage.clock.now_s()
    ((due, m, copy),) = stage.held()
    assert before + DT <= due <= after + DT and (m.src, m.step, copy) == (1, 0, False)
