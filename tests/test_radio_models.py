"""The radio in the fault plan: loss and delay with distance (log-distance path loss, fading,
retries) and a bandwidth budget per node (a queue that waits and drops), against their closed
forms; a receiver's fault stage deciding a message's fate with the distance of its step; then
lockstep swarms: a generated line whose far edges lose more, measured per edge against the
formula at the recorded distances, and a leader whose radio cannot carry its messages."""

import itertools
import math
from statistics import NormalDist

import numpy as np
import pytest
import yaml

from swarm_sitl.bus.clock import RunClock
from swarm_sitl.bus.codec import Message, message_size
from swarm_sitl.config.generator import generate
from swarm_sitl.config.load import ConfigError, parse_config
from swarm_sitl.faults import bandwidth
from swarm_sitl.faults.bandwidth import KEEP_STEPS, Bandwidth, RadioQueue
from swarm_sitl.faults.counts import EdgeStats
from swarm_sitl.faults.edges import FaultyBus
from swarm_sitl.faults.plan import FaultEntry, FaultPlan, edge_channel, fate
from swarm_sitl.faults.radio_range import PathLoss, distance_m
from tests.fakes import DT, EDGES, ManualClock, MemoryBus, Publisher
from tests.support import CONFIGS

#: its system tests run in lockstep or ``sim`` only (no wall clock): free to run beside others
pytestmark = pytest.mark.lockstep

PHI = NormalDist().cdf


def _paper(plan: list[dict]) -> dict:
    data = yaml.safe_load((CONFIGS / "paper.yaml").read_text())
    data["faults"] = {"seed": 3, "plan": plan}
    return data


# -- path loss ---------------------------------------------------------------------------------
@pytest.mark.unit
@pytest.mark.parametrize("n, sigma", [(2.0, 4.0), (3.5, 8.0), (2.7, 0.5)])
def test_one_attempt_fails_as_the_log_distance_model_with_normal_fading_says(n, sigma):
    """q(d) = P(P_tx - L0 - 10 n log10 d + X < S), X ~ N(0, sigma^2): written out in dB with
    the range R at which the mean power is S, against the model's formula in margins."""
    pl = PathLoss(range_m=30.0, exponent=n, fading_db=sigma)
    p_tx, l0 = 20.0, 40.0
    sens = p_tx - l0 - 10 * n * math.log10(30.0)  # what makes R = 30 m
    for d in (0.5, 5.0, 29.0, 30.0, 31.0, 80.0, 400.0):
        mean_power = p_tx - l0 - 10 * n * math.log10(d)
        assert pl.attempt_loss(d) == pytest.approx(PHI((sens - mean_power) / sigma), abs=1e-12)
    assert pl.attempt_loss(30.0) == pytest.approx(0.5)
    ds = np.geomspace(0.1, 1000, 200)
    qs = [pl.attempt_loss(d) for d in ds]
    assert all(a <= b for a, b in itertools.pairwise(qs))  # farther never loses less
    assert pl.attempt_loss(0.0) == 0.0  # two nodes at one point hear each other


@pytest.mark.unit
def test_without_fading_the_range_is_a_hard_edge():
    pl = PathLoss(range_m=10.0)
    assert [pl.attempt_loss(d) for d in (0.0, 9.999, 10.0, 10.001, 50.0)] == [0, 0, 0, 1, 1]


@pytest.mark.unit
def test_retries_lose_q_to_the_power_of_the_attempts_and_delay_by_the_geometric_mean():
    """At one distance, over many messages: lost with probability q^(1 + r); one that gets
    through comes a * retry_s late with probability q^a (1 - q) (normalised); five binomial
    standard deviations."""
    pl = PathLoss(range_m=20.0, exponent=3.0, fading_db=6.0, retries=3, retry_s=0.004)
    d = 24.0
    q = pl.attempt_loss(d)
    rules = [(0, FaultEntry(edge=(1, 4), range=pl))]
    n = 60_000
    fates = [fate(7, rules, edge_channel(1, 4), k, 0.0, 1.0, DT, distance_m=d) for k in range(n)]
    lost = sum(f.lost for f in fates)
    assert abs(lost / n - q**4) < 5 * math.sqrt(q**4 * (1 - q**4) / n)
    assert lost == sum(f.out_of_range for f in fates)
    through = [f for f in fates if not f.lost]
    for a in range(4):
        p_a = q**a * (1 - q) / (1 - q**4)
        got = sum(f.delay_s == pytest.approx(a * 0.004) for f in through) / len(through)
        assert abs(got - p_a) < 5 * math.sqrt(p_a * (1 - p_a) / len(through)), a
    assert sum(f.retried for f in through) == sum(f.delay_s > 0 for f in through)
    mean_delay = sum(f.delay_s for f in through) / len(through)
    assert mean_delay == pytest.approx(pl.mean_delay_s(d), rel=0.05)


@pytest.mark.unit
def test_the_distance_is_euclidean_in_three_dimensions_and_the_mean_delay_is_the_geometric_one():
    assert distance_m((1.0, 2.0, 3.0), (4.0, 6.0, 15.0)) == 13.0  # 3, 4, 12
    assert distance_m((4.0, 6.0, 15.0), (1.0, 2.0, 3.0)) == 13.0
    pl = PathLoss(range_m=10.0, fading_db=3.0, retries=2, retry_s=1.0)
    assert pl.attempt_loss(10.0) == pytest.approx(0.5)  # weights 1, 1/2, 1/4 of attempts 0, 1, 2
    assert pl.mean_delay_s(10.0) == pytest.approx((0.5 + 2 * 0.25) / 1.75)
    assert pl.loss(10.0) == pytest.approx(0.125)
    hard = PathLoss(range_m=10.0, retries=2, retry_s=1.0)
    assert math.isnan(hard.mean_delay_s(11.0)) and hard.mean_delay_s(9.0) == 0.0 and hard.loss(11.0) == 1.0


@pytest.mark.unit
def test_a_range_entry_draws_the_same_fate_for_a_message_whoever_asks():
    model = {"range_m": 10.0, "fading_db": 5.0, "retries": 1, "retry_s": 0.05}
    rules = [(2, FaultEntry(all_edges=True, range=model))]
    a = [fate(9, rules, edge_channel(1, 4), k, 0.0, 1.0, DT, distance_m=11.0) for k in range(300)]
    b = [fate(9, rules, edge_channel(1, 4), k, 0.0, 1.0, DT, distance_m=11.0) for k in reversed(range(300))]
    assert a == b[::-1]
    other = [fate(9, rules, edge_channel(2, 4), k, 0.0, 1.0, DT, distance_m=11.0) for k in range(300)]
    assert [f.lost for f in a] != [f.lost for f in other]  # each edge draws its own
    seeded = [fate(10, rules, edge_channel(1, 4), k, 0.0, 1.0, DT, distance_m=11.0) for k in range(300)]
    assert [f.lost for f in a] != [f.lost for f in seeded]  # and each seed
    delayed = [(0, FaultEntry(edge=(1, 4), delay_s=0.1)), *rules]  # delays add up, entry by entry
    both = [fate(9, delayed, edge_channel(1, 4), k, 0.0, 1.0, DT, distance_m=11.0) for k in range(300)]
    assert [f.lost for f in both] == [f.lost for f in a]
    assert [f.delay_s for f in both if not f.lost] == [
        pytest.approx(0.1 + f.delay_s) for f in a if not f.lost
    ]
    later = [*rules, (3, FaultEntry(edge=(1, 4), delay_s=0.1))]  # and an entry after it still acts
    after = [fate(9, later, edge_channel(1, 4), k, 0.0, 1.0, DT, distance_m=11.0) for k in range(300)]
    assert [f.delay_s for f in after] == [f.delay_s for f in both]


# -- the bandwidth budget ------------------------------------------------------------------------
def _queue(budget: Bandwidth, n_out: int, index: int, size: int = 141, down=lambda k: False, active=None):
    return RadioQueue(budget, n_out, index, size, DT, down, active or (lambda t: True))


@pytest.mark.unit
def test_below_saturation_the_m_th_message_leaves_m_plus_one_air_times_after_its_tick():
    budget = Bandwidth(rate_bps=400_000, queue=2)
    tau = 8 * 141 / 400_000  # 2.82 ms; three of them fit in a period (two wait behind the first)
    for m in range(3):
        q = _queue(budget, 3, m)
        assert [q.leaves(k) for k in range(200)] == [pytest.approx((m + 1) * tau)] * 200


@pytest.mark.unit
@pytest.mark.parametrize("queue", [2, 4, 30])
def test_above_saturation_the_radio_sends_one_message_per_air_time_and_drops_the_rest(queue):
    """Saturated from the first tick, with a queue that holds a period's work (queue tau >= dt),
    the radio is never idle: by tick N it has accepted one message per air time, plus the
    ``queue + 1`` in it, the rest dropped, in the long run a fraction 1 - dt / (n_out tau);
    what waits leaves at most (queue + 1) air times later."""
    n_out, n = 3, 2000
    budget = Bandwidth(rate_bps=200_000, queue=queue)
    tau = budget.air_time_s(141)
    qs = [_queue(budget, n_out, m) for m in range(n_out)]
    left = [[q.leaves(k) for k in range(n)] for q in qs]
    accepted = sum(w is not None for row in left for w in row)
    assert abs(accepted - n * DT / tau) <= queue + 2
    waits = [w for row in left for w in row if w is not None]
    assert max(waits) <= (queue + 1) * tau + 1e-12 and min(waits) >= tau - 1e-12
    assert 1 - accepted / (n * n_out) == pytest.approx(1 - DT / (n_out * tau), abs=0.01)


@pytest.mark.unit
def test_a_queue_keeps_only_its_recent_steps_and_replays_an_older_one_the_same(monkeypatch):
    budget = Bandwidth(rate_bps=180_000, queue=3)  # saturated: 6.3 ms a message, 2 a tick
    with monkeypatch.context() as m:
        m.setattr(bandwidth, "KEEP_STEPS", 10**9)  # one that keeps every step
        every = _queue(budget, 2, 1)
        fresh = [every.leaves(k) for k in range(5000)]
    q = _queue(budget, 2, 1)
    assert [q.leaves(k) for k in range(5000)] == fresh
    assert len(q._left) <= 2 * KEEP_STEPS  # a long run does not keep every step
    assert [q.leaves(k) for k in (10, 4999, 3000)] == [fresh[10], fresh[4999], fresh[3000]]


@pytest.mark.unit
def test_with_no_queue_a_radio_takes_only_what_finds_it_idle():
    """Queue 0, 5.64 ms a message, a period of 10: each tick the first message finds the radio
    idle and leaves one air time later, the others are dropped (the radio idles the rest of the
    period: a queue too short for a tick's burst wastes air time)."""
    budget = Bandwidth(rate_bps=200_000, queue=0)
    qs = [_queue(budget, 3, m) for m in range(3)]
    assert [qs[0].leaves(k) for k in range(100)] == [pytest.approx(budget.air_time_s(141))] * 100
    assert [q.leaves(k) for q in qs[1:] for k in range(100)] == [None] * 200


@pytest.mark.unit
def test_a_sender_down_sends_nothing_and_comes_back_to_an_empty_queue_and_no_budget_no_wait():
    budget = Bandwidth(rate_bps=100_000, queue=50)  # 11.3 ms a message: a queue that only grows
    q = _queue(budget, 2, 0, down=lambda k: 100 <= k < 120)
    before = q.leaves(99)
    assert before is not None and before > 50 * DT  # a long way behind
    assert [q.leaves(k) for k in range(100, 120)] == [None] * 20
    assert q.leaves(120) == pytest.approx(budget.air_time_s(141))  # the queue died with it
    free = _queue(budget, 2, 0, active=lambda t: t < 0.5)
    assert free.leaves(50) == 0.0 and free.leaves(49) is not None and free.leaves(49) > DT


# -- validation ----------------------------------------------------------------------------------
@pytest.mark.unit
@pytest.mark.parametrize(
    "entries, message",
    [
        (
            [{"all_edges": True, "range": {"range_m": 0}}],
            r"faults\.plan\.0\.range\.range_m: .*greater than 0",
        ),
        (
            [{"all_edges": True, "range": {"range_m": 5, "fading_db": -1}}],
            r"range\.fading_db: .*greater than",
        ),
        ([{"all_edges": True, "range": {"range_m": 5, "exponent": 0}}], r"range\.exponent"),
        ([{"all_edges": True, "range": {"range_m": 5, "retries": 99}}], r"range\.retries"),
        ([{"mavlink": 1, "range": {"range_m": 5}}], r"range acts on bus edges"),
        ([{"mavlink": 1, "bandwidth": {"rate_bps": 1000}}], r"bandwidth acts on bus edges"),
        ([{"edge": [1, 4], "bandwidth": {"rate_bps": 1000}}], r"a sending node's radio.*not edge"),
        ([{"into": 4, "bandwidth": {"rate_bps": 1000}}], r"not into"),
        ([{"out_of": 1, "bandwidth": {"rate_bps": 0}}], r"bandwidth\.rate_bps: .*greater than 0"),
        ([{"out_of": 1, "bandwidth": {"rate_bps": 1e4, "queue": -1}}], r"bandwidth\.queue"),
        (
            [
                {"all_edges": True, "bandwidth": {"rate_bps": 1e5}},
                {"out_of": 2, "bandwidth": {"rate_bps": 1e4}},
            ],
            r"faults\.plan\.1: node 2's radio already has a bandwidth budget \(faults\.plan\.0\)",
        ),
        ([{"out_of": 3, "bandwidth": {"rate_bps": 1e4}}], r"edges out of 3 is not in the graph"),
    ],
)
def test_a_bad_radio_model_is_one_line_naming_it(entries, message):
    with pytest.raises(ConfigError, match=message) as e:
        parse_config(_paper(entries), "paper.yaml")
    assert "\n" not in str(e.value)


@pytest.mark.unit
def test_all_edges_names_every_edge_and_the_models_describe_themselves():
    cfg = parse_config(
        _paper(
            [
                {"all_edges": True, "range": {"range_m": 40, "fading_db": 4, "retries": 2, "retry_s": 0.01}},
                {"leader_edges": True, "bandwidth": {"rate_bps": 64000, "queue": 8}},
            ]
        ),
        "paper.yaml",
    )
    ranged, budget = cfg.faults.plan
    assert ranged.edges(cfg.graph_edges()) == cfg.graph_edges() and ranged.what == "every edge"
    assert ranged.how == "range 40 m (exponent 2, fading 4 dB, 2 retries 0.01 s apart)"
    assert budget.how == "bandwidth 64000 bit/s, queue 8"
    assert PathLoss(range_m=10).describe() == "range 10 m (exponent 2, fading 0 dB)"  # no retries


@pytest.mark.unit
def test_an_edges_counts_start_a_loss_run_at_a_first_lost_message_and_keep_the_distances_range():
    st = EdgeStats()
    for lost in (True, True, False, True):
        st.count_fate(lost)
    assert st.lost == 3 and st.loss_runs == 2
    for d in (0.5, 0.2, 0.1):  # fewer metres than messages: the largest is a distance's, not a count
        st.count_distance(d)
    assert st.as_dict()["distance_m"] == {"min": 0.1, "mean": pytest.approx(0.8 / 3), "max": 0.5}
    assert "distance_m" not in EdgeStats().as_dict()  # no range entry: no distances


# -- the receiver's fault stage -------------------------------------------------------------------
def _at(src: int, step: int, p: tuple[float, float, float]) -> Message:
    return Message(src, step, step * DT, np.full(12, float(step)), p)


@pytest.mark.integration
def test_a_lockstep_receiver_decides_a_range_fate_with_its_own_position_of_that_step():
    """Node 4 moves away from node 1 along x, one metre a tick: a message of step s is judged at
    distance |p_1(s) - p_4(s)|, even when it comes before node 4 has done its own tick s (it
    waits, undecided, and is still usable at tick s + 1)."""
    plan = FaultPlan(seed=1, plan=[FaultEntry(edge=(1, 4), range={"range_m": 10.0})])
    inner = Publisher({})
    clock = RunClock(True, DT)
    bus = FaultyBus(inner, plan, 4, EDGES, clock, 60.0)  # type: ignore[arg-type]
    for k in range(20):
        clock.tick = k
        inner.wire.append(_at(1, k, (0.0, 0.0, 0.0)))  # early: before node 4's own tick k
        bus.poll()
        assert bus.settled(1, k) and inner.estimate(1, k) is None  # arrived, not yet decided
        bus.publish(_at(4, k, (float(k), 0.0, 0.0)))  # now node 4 knows where it was at k
        clock.tick = k + 1
        bus.poll()
        assert (inner.estimate(1, k) is not None) == (k <= 10), k  # on time, or out of range
    st = bus.stats[1]
    assert st.lost == st.out_of_range == 9 and st.delivered == 11
    assert st.as_dict()["distance_m"] == {"min": 0.0, "mean": 9.5, "max": 19.0}
    # a sender two ticks ahead (the leader's window allows it): judged at its own step, not ours
    inner = Publisher({})
    bus = FaultyBus(inner, plan, 4, EDGES, clock, 60.0)  # type: ignore[arg-type]
    inner.wire += [_at(1, 0, (0.0, 0.0, 0.0)), _at(1, 1, (0.0, 0.0, 0.0))]
    bus.poll()
    bus.publish(_at(4, 0, (0.0, 0.0, 0.0)))  # 0 m at step 0
    bus.publish(_at(4, 1, (20.0, 0.0, 0.0)))  # 20 m at step 1
    assert bus.stats[1].out_of_range == 1 and bus.stats[1].as_dict()["distance_m"]["max"] == 20.0


@pytest.mark.integration
@pytest.mark.parametrize("seed", range(10))
def test_a_receiver_counts_what_the_range_fates_say_and_uses_a_retried_message_its_retries_later(seed):
    """Lockstep, node 4 at 11 m from node 1 (12 m range, 5 dB fading, 2 retries 15 ms apart):
    each message's fate as ``fate`` draws it; one through at its second attempt (15 ms late) is
    used ceil(1.5) = 2 ticks after the on-time tick s + 1, at its third (30 ms) 3 after it. The
    receiver ticks on past the last message (``LAST_USE`` ticks) so a late last one is seen used."""
    spec = FaultEntry(edge=(1, 4), range={"range_m": 12.0, "fading_db": 5.0, "retries": 2, "retry_s": 0.015})
    plan = FaultPlan(seed=seed, plan=[spec])
    inner = Publisher({})
    clock = RunClock(True, DT)
    bus = FaultyBus(inner, plan, 4, EDGES, clock, 60.0)  # type: ignore[arg-type]
    used_at: dict[int, int] = {}
    n, last_use = 300, 4  # (the latest use: 30 ms late, 3 ticks after s + 1)
    for k in range(n + 1 + last_use):
        clock.tick = k
        bus.poll()
        for s in range(max(0, k - 5), min(k, n + 1)):
            if inner.estimate(1, s) is not None:
                used_at.setdefault(s, k)
        if k <= n:
            bus.publish(_at(4, k, (0.0, 11.0, 0.0)))
            inner.wire.append(_at(1, k, (0.0, 0.0, 0.0)))
    fates = [
        fate(seed, [(0, spec)], edge_channel(1, 4), s, s * DT, 60.0, DT, distance_m=11.0)
        for s in range(n + 1)
    ]
    st = bus.stats[1]
    assert st.received == n + 1 and st.lost == st.out_of_range == sum(f.lost for f in fates) > 0
    assert st.retried == sum(f.retried for f in fates) > 0 and st.delayed == st.retried
    for s, f in enumerate(fates):
        late = {0.0: 1, 0.015: 3, 0.03: 4}[round(f.delay_s, 6)]
        assert used_at.get(s) == (None if f.lost else s + late), s


def _ticks_of_use(plan: FaultPlan, ticks: int, silent=range(0)) -> tuple[FaultyBus, dict[int, int]]:
    """Lockstep ticks 1..``ticks`` of node 4, node 1's message of ``k - 1`` arriving before tick k
    (but for the steps in ``silent``): the bus, and the tick each of node 1's steps was first usable."""
    inner = MemoryBus()
    clock = RunClock(True, DT)
    bus = FaultyBus(inner, plan, 4, EDGES, clock, 60.0)  # type: ignore[arg-type]
    used_at: dict[int, int] = {}
    for k in range(1, ticks + 1):
        clock.tick = k
        if k - 1 not in silent:
            inner.wire.append(_at(1, k - 1, (0.0, 0.0, 0.0)))
        bus.poll()
        used_at.update({s: k for (src, s) in inner.table if src == 1 and s not in used_at})
    return bus, used_at


@pytest.mark.integration
def test_a_budget_holds_in_its_window_and_a_sender_back_from_a_kill_has_an_empty_queue():
    """Node 1 to 4 only, 15 ms a message, a long queue: it falls 5 ms further behind each tick.
    Killed at 0.5 s and back at 0.7 s, its queue is gone: the message of tick 70 leaves 15 ms
    after its tick again (used 2 ticks later). The budget ends at 1 s: from tick 100 on time.
    A delay entry below saturation adds its own delay and no queue time."""
    plan = FaultPlan(
        plan=[
            FaultEntry(out_of=1, bandwidth={"rate_bps": 8 * 141 / 0.015, "queue": 1000}, until_s=1.0),
            FaultEntry(controller=1, kill=True, from_s=0.5, restart_after_s=0.2),
        ]
    )
    _, used_at = _ticks_of_use(plan, 130, silent=range(50, 70))
    late = {s: k - s for s, k in used_at.items()}
    assert late[0] == 2 and late[49] == math.ceil((0.015 + 0.005 * 49) / DT)  # 26 ticks behind
    assert late[70] == 2 and late[99] == math.ceil((0.015 + 0.005 * 29) / DT)
    assert all(late[s] == 1 for s in range(100, 129)) and not any(50 <= s < 70 for s in late)
    plan = FaultPlan(
        plan=[
            FaultEntry(out_of=1, bandwidth={"rate_bps": 8 * 141 / 0.004}),
            FaultEntry(edge=(1, 4), delay_s=0.02),
        ]
    )
    bus, _ = _ticks_of_use(plan, 20)
    assert bus.stats[1].delays_s == [pytest.approx(0.02)] * 20  # 4 ms on the air: on time


@pytest.mark.integration
def test_in_real_time_a_range_fate_takes_the_receivers_newest_position_and_a_late_queue_waits():
    """Real time: the distance is to where the receiver last was (it waits for no tick but its
    first); a message that leaves its sender's queue w after its tick is handed on at t_s + w."""
    clock = ManualClock()
    plan = FaultPlan(plan=[FaultEntry(edge=(1, 4), range={"range_m": 12.0})])
    inner = Publisher({})
    bus = FaultyBus(inner, plan, 4, EDGES, clock, 60.0)  # type: ignore[arg-type]
    inner.wire.append(_at(1, 2, (9.0, 0.0, 0.0)))  # its sender runs ahead of node 4
    bus.poll()
    assert bus.latest(1) is None  # before node 4's first tick: it waits for where node 4 is
    bus.publish(_at(4, 0, (0.0, 0.0, 0.0)))
    bus.poll()
    assert bus.latest(1) is not None  # 9 m
    bus.publish(_at(4, 1, (30.0, 0.0, 0.0)))
    inner.wire += [_at(1, 3, (19.0, 0.0, 0.0)), _at(1, 4, (45.0, 0.0, 0.0))]
    bus.poll()
    assert {s for (_, s) in inner.table} == {2, 3}  # 11 m: within range; 15 m: not
    assert bus.stats[1].out_of_range == 1
    assert bus.stats[1].as_dict()["distance_m"] == {"min": 9.0, "mean": 35 / 3, "max": 15.0}
    plan = FaultPlan(plan=[FaultEntry(out_of=1, bandwidth={"rate_bps": 8 * 141 / 0.025, "queue": 0})])
    inner = Publisher({})
    bus = FaultyBus(inner, plan, 4, EDGES, clock, 60.0)  # type: ignore[arg-type]
    clock.t = 0.481
    inner.wire.append(_at(1, 48, (0.0, 0.0, 0.0)))  # sent at 0.48 s, 25 ms on the air
    bus.poll()  # (queue 0: of every three ticks' messages the first finds the radio idle, 0, 3, .. 48)
    assert bus.latest(1) is None
    clock.t = 0.5049
    bus.poll()
    assert bus.latest(1) is None
    clock.t = 0.5051
    bus.poll()
    assert bus.latest(1) is not None and bus.stats[1].delays_s == [pytest.approx(0.025)]


@pytest.mark.integration
def test_a_message_that_leaves_its_senders_queue_after_the_next_tick_is_used_that_many_ticks_late():
    """Node 1 sends to 4 only (n_out 1) at 8 ms a message, queue 0: every message fits (no
    drops); at 15 ms a message the queue is too slow: half are dropped, the rest leave 15 ms
    after their tick, usable at tick s + 2."""
    for rate, lost, late in ((8 * 141 / 0.008, 0, 0), (8 * 141 / 0.015, 50, 50)):
        plan = FaultPlan(plan=[FaultEntry(out_of=1, bandwidth={"rate_bps": rate, "queue": 0})])
        bus, used_at = _ticks_of_use(plan, 100)
        st = bus.stats[1]
        assert message_size(12) == 141 and st.queue_full == st.lost == lost and st.delayed == late
        assert {k - s for s, k in used_at.items()} == ({2} if late else {1})


# -- lockstep swarms -------------------------------------------------------------------------------
@pytest.mark.system
def test_in_a_line_formation_far_edges_lose_more_as_the_path_loss_formula_says(tmp_path):
    """A generated line of 8 followers 4 m apart (28 m span), every edge under a 12 m range with
    4 dB fading: per edge, the messages lost against the sum over its steps of q(d_k) at the
    recorded distances (each step an independent draw: the variance is the sum of q (1 - q));
    farther edges lose a larger fraction; the counts' distances are those recorded; a second run
    is the same byte for byte (a fate waits for the receiver's own tick, whenever it comes)."""
    from swarm_sitl import Swarm

    data = yaml.safe_load(generate(8, "layered", "line", "line", 0, 10.0, None, tmp_path))
    model = {"range_m": 12.0, "exponent": 3.0, "fading_db": 4.0}
    data["faults"] = {"seed": 3, "plan": [{"all_edges": True, "range": model}]}
    cfg = parse_config(data, "line8.yaml")
    for run in ("run", "again"):
        with Swarm(cfg, out=tmp_path / run) as swarm:
            result = swarm.run()
        assert result.failure is None
    for name in ["summary.json", "events.jsonl", *(f"follower_{i}.npz" for i in range(1, 9))]:
        assert (tmp_path / "run" / name).read_bytes() == (tmp_path / "again" / name).read_bytes(), name
    pl = PathLoss(**model)
    leader = np.load(tmp_path / "run" / "leader.npz")
    where = {
        0: leader["p_r"],
        **{i: np.load(tmp_path / "run" / f"follower_{i}.npz")["p_W"] for i in range(1, 9)},
    }
    fraction = {}
    for src, dst in cfg.graph_edges():
        edge = result.links[f"{src}->{dst}"]
        n = edge["received"]
        d = np.linalg.norm(where[src][:n] - where[dst][:n], axis=1)
        q = np.array([pl.loss(x) for x in d])
        sigma = math.sqrt(float(np.sum(q * (1 - q))))
        assert abs(edge["lost"] - q.sum()) <= 4 * sigma + 1, (src, dst, edge["lost"], q.sum())
        assert edge["out_of_range"] == edge["lost"] and n == round(10.0 / cfg.control_dt_s)
        assert edge["distance_m"]["min"] == pytest.approx(d.min(), abs=1e-5)
        assert edge["distance_m"]["max"] == pytest.approx(d.max(), abs=1e-5)
        fraction[src, dst] = (float(d.mean()), edge["lost"] / n)
    ranked = sorted(fraction.values())
    assert ranked[0][0] < 8 < 15 < ranked[-1][0]  # the line spans near and far edges
    for (d_a, f_a), (d_b, f_b) in itertools.pairwise(ranked):
        if d_b - d_a > 1.5:
            assert f_b > f_a, ranked


@pytest.mark.system
def test_a_leader_whose_radio_cannot_carry_its_messages_sends_one_per_air_time(tmp_path):
    """The paper's leader (3 out-edges, 141-byte messages) on a 200 kbit/s radio with a queue of
    2: 5.64 ms a message, 16.9 ms of them a tick. The radio is never idle: over N ticks the
    followers take one message per air time (plus the queue's), the rest are counted dropped at
    the full queue; what is taken leaves at most 3 air times after its tick: a tick late."""
    from swarm_sitl import Swarm

    budget = {"rate_bps": 200_000, "queue": 2}
    cfg = parse_config(_paper([{"leader_edges": True, "bandwidth": budget}]), "paper.yaml")
    with Swarm(cfg, out=tmp_path / "run") as swarm:
        result = swarm.run(duration_s=10.0)
    assert result.failure is None
    tau = Bandwidth(**budget).air_time_s(141)
    edges = [result.links[f"0->{i}"] for i in (1, 2, 3)]
    n = edges[0]["received"]
    taken = sum(e["received"] - e["queue_full"] for e in edges)
    assert abs(taken - n * cfg.control_dt_s / tau) <= 2 + 2
    for e in edges:  # a message due after the last tick is never handed on
        assert e["queue_full"] == e["lost"] and e["received"] - e["lost"] - e["delivered"] in (0, 1)
    drops = [e["queue_full"] for e in edges]
    assert drops[0] < drops[1] < drops[2]  # the last in line loses most
    late = [e["delay_s"]["max"] for e in edges if "delay_s" in e]
    assert late and max(late) <= 3 * tau + 1e-9 and min(late) > cfg.control_dt_s
    untouched = result.links["1->4"]
    assert untouched["delivered"] == untouched["received"] == n  # no budget: nothing counted
