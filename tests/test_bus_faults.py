"""The fault stage on a node's in-edges (``FaultyBus``) over an in-memory bus, and riding through
silent neighbours (``NeighbourInbox``): what the loop may use, and when, under each fault."""

import math
import os
import time

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from sim_vehicles.runtime.event_log import EventLog
from swarm_sitl.bus.clock import RunClock, StallError, WallTime
from swarm_sitl.bus.codec import Message, PayloadError, decode_message, encode_message
from swarm_sitl.faults.counts import EdgeStats
from swarm_sitl.faults.edges import FaultyBus
from swarm_sitl.faults.plan import FaultPlan
from swarm_sitl.nodes.neighbour_inbox import NeighbourInbox
from tests.fakes import DT, EDGES, ManualClock, MemoryBus, Publisher

pytestmark = pytest.mark.integration


def _bus(*entries: dict, seed: int = 0, lockstep: bool = True) -> tuple[FaultyBus, MemoryBus, RunClock]:
    inner = MemoryBus()
    clock = RunClock(lockstep, DT)
    plan = FaultPlan(seed=seed, plan=list(entries))
    return FaultyBus(inner, plan, 4, EDGES, clock, 60.0), inner, clock  # type: ignore[arg-type]


def _lockstep_ticks(bus: FaultyBus, inner: MemoryBus, clock: RunClock, n: int) -> dict[int, set[int]]:
    """Run ticks 1..n: before tick k both in-neighbours' estimates of k - 1 arrive; returns, per
    tick, the steps of source 1 usable then (the loop asks ``estimate(src, k - 1)``, ``latest``)."""
    seen: dict[int, set[int]] = {}
    for k in range(1, n + 1):
        clock.tick = k
        inner.arrive(1, k - 1)
        inner.arrive(2, k - 1)
        bus.poll()
        assert bus.settled(1, k - 1) and bus.settled(2, k - 1)  # a tick never waits on the plan
        seen[k] = {s for (src, s) in inner.table if src == 1}
    return seen


def test_lost_estimates_are_settled_but_never_used():
    bus, inner, clock = _bus({"edge": [1, 4], "loss": 0.5}, seed=5)
    seen = _lockstep_ticks(bus, inner, clock, 400)
    used = seen[400]
    st_ = bus.stats[1]
    assert st_.received == 400 and st_.lost + st_.delivered == 400 and 140 < st_.lost < 260
    assert len(used) == st_.delivered
    assert bus.stats[2].lost == 0 and bus.stats[2].delivered == 400  # the other edge is untouched
    for k in range(1, 401):  # what is delivered is delivered on time
        assert ((k - 1) in seen[k]) == ((k - 1) in used)
    again, inner2, clock2 = _bus({"edge": [1, 4], "loss": 0.5}, seed=5)
    assert _lockstep_ticks(again, inner2, clock2, 400)[400] == used  # the same plan, the same run


def test_only_the_steps_a_node_waits_for_are_counted_and_the_rest_still_meet_their_fate():
    """A lockstep node restarted at tick 100 of a 300-tick run waits for steps 100..299: what else
    arrives (an old step after its subscription, the last step before it exits) depends on timing."""
    bus, inner, clock = _bus({"edge": [1, 4], "loss": 0.5}, seed=5)
    inner.counted_steps = range(100, 300)
    _lockstep_ticks(bus, inner, clock, 301)  # steps 0..300 arrive
    st_ = bus.stats[1]
    assert st_.received == 200 and st_.lost + st_.delivered == 200
    delivered = {s for (src, s) in inner.table if src == 1}
    assert any(s < 100 for s in delivered) and len(delivered) > st_.delivered  # passed, uncounted
    bus, inner, clock = _bus({"edge": [1, 4], "corrupt": 1.0})
    inner.counted_steps = range(100, 300)
    _lockstep_ticks(bus, inner, clock, 301)
    assert bus.stats[1].corrupt == inner.dropped == 200  # a payload dropped is counted with its step


def test_a_delay_holds_an_estimate_whole_ticks_in_lockstep():
    bus, inner, clock = _bus({"edge": [1, 4], "delay_s": 0.025})  # 2.5 periods: used 3 ticks late
    seen = _lockstep_ticks(bus, inner, clock, 50)
    for k in range(1, 51):
        assert max(seen[k], default=-1) == max(k - 1 - 3, -1)
    assert bus.stats[1].delayed == 50 and bus.stats[1].delays_s[0] == pytest.approx(0.025)


def test_a_stall_releases_what_it_held_in_one_burst():
    bus, inner, clock = _bus({"edge": [1, 4], "stall": True, "from_s": 0.2, "until_s": 0.5})
    seen = _lockstep_ticks(bus, inner, clock, 80)
    assert max(seen[20]) == 19 and max(seen[50]) == 19  # held from t = 0.2 s
    assert set(range(20, 50)) <= seen[51] and max(seen[51]) == 50  # all at once, then on time


def test_duplicates_reorders_and_corruptions():
    bus, inner, clock = _bus({"edge": [1, 4], "duplicate": 1.0})
    _lockstep_ticks(bus, inner, clock, 20)
    # the last copy is due at 21: still held, so neither delivered nor counted as a duplicate
    assert bus.stats[1].duplicated == 19 and bus.stats[1].delivered == 39 and bus.stats[1].held == 0
    bus, inner, clock = _bus({"edge": [1, 4], "reorder": 1.0})
    seen = _lockstep_ticks(bus, inner, clock, 20)
    assert all(max(seen[k], default=-1) == k - 2 for k in range(1, 21))  # one period late
    bus, inner, clock = _bus({"edge": [1, 4], "corrupt": 1.0})
    _lockstep_ticks(bus, inner, clock, 20)
    assert bus.stats[1].corrupt == 20 and inner.dropped == 20 and not any(s == 1 for s, _ in inner.table)


def test_in_real_time_a_delay_counts_from_arrival():
    clock = ManualClock()
    inner = MemoryBus()
    bus = FaultyBus(inner, FaultPlan(plan=[{"edge": [1, 4], "delay_s": 0.1}]), 4, EDGES, clock, 60.0)  # type: ignore[arg-type]
    clock.t = 5.0
    inner.arrive(1, 3)  # its own time (0.03 s) does not matter in real time: its arrival does
    bus.poll()
    assert bus.latest(1) is None
    clock.t = 5.099
    bus.poll()
    assert bus.latest(1) is None
    clock.t = 5.1
    bus.poll()
    assert bus.latest(1) is not None and bus.latest(1).step == 3


def _accounted(e: EdgeStats) -> int:
    """What the counts say was received: every message delivered once, or lost, dropped, held."""
    return e.delivered - e.duplicated + e.lost + e.corrupt + e.held


@given(
    st.floats(0, 0.9),
    st.floats(0, 0.05),
    st.floats(0, 1),
    st.floats(0, 1),
    st.floats(0, 0.3),
    st.integers(0, 2**31),
    st.integers(5, 120),
)
def test_every_message_received_is_delivered_or_counted_under_a_named_reason(
    loss, delay_s, duplicate, reorder, corrupt, seed, n
):
    """Lockstep, any mix of faults on an edge: ``received == delivered - duplicated + lost +
    corrupt + held``, and ``held`` is exactly the messages the plan still holds after tick ``n``
    (due after it: ``1 + ceil(delay / dt)`` ticks after their step, one more when reordered)."""
    hows = {"loss": loss, "delay_s": delay_s, "duplicate": duplicate, "reorder": reorder, "corrupt": corrupt}
    entries = [{"edge": [1, 4], how: v} for how, v in hows.items() if v > 0]
    bus, inner, clock = _bus(*entries, seed=seed)
    _lockstep_ticks(bus, inner, clock, n)
    e = bus.stats[1]
    assert e.received == n == _accounted(e)
    held = sorted(m.step for _, m, copy in bus.faults.held() if not copy)
    assert e.held == len(held)
    assert all(m.step >= n - 2 - math.ceil(delay_s / DT - 1e-9) for _, m, _ in bus.faults.held())


def test_in_real_time_estimates_heard_before_the_start_signal_are_judged_once_it_has_come():
    """A controller restarted mid-run hears its in-neighbours before it has the swarm's clock (its
    start epoch): what it heard then is held, and delivered once the epoch has come, never lost
    to a clock that is not yet set (it was held for good: the restarted follower flew blind)."""
    clock = RunClock(False, DT)
    inner = MemoryBus()
    plan = FaultPlan(plan=[{"controller": 4, "kill": True, "from_s": 10, "restart_after_s": 1}])
    bus = FaultyBus(inner, plan, 4, EDGES, clock, 60.0)  # type: ignore[arg-type]
    for step in (1100, 1101):
        inner.arrive(1, step)
    bus.poll()
    assert bus.latest(1) is None and bus.stats[1].held == 2  # no clock yet: held, counted
    clock.epoch_mono = time.monotonic() - 11.02  # the start signal: 11.02 s into the run
    inner.arrive(1, 1102)
    bus.poll()
    assert bus.latest(1) is not None and bus.latest(1).step == 1102
    e = bus.stats[1]
    assert e.received == e.delivered == 3 and e.held == 0 and _accounted(e) == 3


@given(st.integers(0, 110), st.integers(1, 255))
def test_any_corrupted_byte_of_an_estimate_is_caught_by_its_checksum(pos, flip):
    v = np.tile([1.5, -2.0, 3.25], 4)
    data = bytearray(encode_message(Message(2, 77, 0.77, v)))
    data[pos % len(data)] ^= flip
    with pytest.raises(PayloadError):
        decode_message(bytes(data))


# -- riding through ------------------------------------------------------------------------------
def _msg(src: int, step: int) -> Message:
    return Message(src, step, step * DT, np.zeros(12))


class Events(EventLog):
    def __init__(self) -> None:
        super().__init__(None, "test")
        self.seen: list[tuple[float, str, dict]] = []

    def add(self, t_s: float, kind: str, **fields: object) -> None:
        self.seen.append((t_s, kind, fields))


def test_on_time_estimates_are_exactly_those_of_the_tick_before():
    inbox = NeighbourInbox(4, [1, 2], 0.5, Events())
    for k in range(1, 100):
        got = inbox.gather(k * DT, lambda s, k=k: _msg(s, k - 1))
        assert {s: round(m.t_s / DT) for s, m in got.items()} == {1: k - 1, 2: k - 1}
        assert all(m.age_s == k * DT - m.t_s for m in got.values())
    assert inbox.stale_ticks == {1: 0, 2: 0} and inbox.max_age_s[1] == pytest.approx(DT)


def test_a_silent_neighbour_is_carried_until_stale_then_left_out_and_regained():
    ev = Events()
    inbox = NeighbourInbox(4, [1, 2], 0.1, ev)
    last = {1: 9, 2: 19}  # 1 falls silent after step 9, 2 after step 19; both come back at 60

    def newest(s: int, k: int) -> Message | None:
        return _msg(s, k - 1) if k - 1 <= last[s] or k - 1 >= 60 else None

    used = {}
    for k in range(1, 70):
        got = inbox.gather(k * DT, lambda s, k=k: newest(s, k))
        used[k] = {s: round(m.t_s / DT) for s, m in got.items()}
    assert used[15] == {1: 9, 2: 14}  # carried: 0.06 s old
    assert used[19] == {1: 9, 2: 18} and used[20] == {2: 19}  # 9 is 0.11 s old at tick 20: out
    assert used[31] == {} and used[61] == {1: 60, 2: 60}
    kinds = [(round(t / DT), kind, f.get("neighbour")) for t, kind, f in ev.seen]
    assert kinds == [
        (20, "neighbour_lost", 1),
        (30, "neighbour_lost", 2),
        (30, "no_live_in_edge", None),
        (61, "neighbour_regained", 1),
        (61, "neighbour_regained", 2),
    ]
    assert ev.seen[0][2]["age_s"] == pytest.approx(0.11)
    assert all(f["follower"] == 4 for _, _, f in ev.seen)  # each event names whose inbox it is
    ages = {(kind, f.get("neighbour")): f.get("age_s") for _, kind, f in ev.seen}
    assert ages[("neighbour_lost", 2)] == pytest.approx(0.11)  # its newest, of step 19, at tick 30
    assert ages[("neighbour_regained", 1)] == ages[("neighbour_regained", 2)] == pytest.approx(DT)
    assert inbox.stale_ticks == {1: 41, 2: 31}


def test_an_older_estimate_never_replaces_a_newer_one():
    inbox = NeighbourInbox(4, [1], 1.0, Events())
    inbox.gather(0.1, lambda s: _msg(1, 9))
    assert round(inbox.gather(0.11, lambda s: _msg(1, 5))[1].t_s / DT) == 9  # a reordered straggler


def test_a_neighbour_never_heard_from_is_left_out_without_an_event():
    ev = Events()
    inbox = NeighbourInbox(4, [1], 0.1, ev)
    assert all(inbox.gather(k * DT, lambda s: None) == {} for k in range(50))
    assert ev.seen == [] and not math.isnan(inbox.max_age_s[1])


# -- a vehicle's MAVLink link --------------------------------------------------------------------
def _lpos_datagram(ms: int) -> bytes:
    from pymavlink.dialects.v20 import common as mav

    m = mav.MAVLink(None, srcSystem=2, srcComponent=1)
    return m.local_position_ned_encode(ms, 1.0, 2.0, 3.0, 0.0, 0.0, 0.0).pack(m)


def test_a_lockstep_mavlink_loss_sends_a_clock_only_setpoint_and_settles_a_lost_sample():
    from swarm_sitl.faults.mavlink import MavlinkFaults, sample_ms

    assert sample_ms(_lpos_datagram(1230)) == 1230 and sample_ms(b"\xfd\x00" * 10) is None
    plan = FaultPlan(seed=1, plan=[{"mavlink": 2, "loss": 0.3}])
    lf = MavlinkFaults(plan, 2, RunClock(True, DT), 60.0)
    sent: list[bytes] = []
    clock_only: list[int] = []
    for k in range(1000):
        lf.send(b"setpoint", k * 10, sent.append, clock_only.append)
    up = lf.stats["up"]
    assert 200 < up.lost < 400 and len(sent) == up.delivered == 1000 - up.lost
    assert len(clock_only) == up.lost and all(ms % 10 == 0 for ms in clock_only)  # one period on
    lost = [k for k in range(1, 1001) if lf.receive(_lpos_datagram(k * 10)) is None]
    assert 200 < len(lost) < 400 and lf.lost_ms == lost[-1] * 10
    again = MavlinkFaults(plan, 2, RunClock(True, DT), 60.0)
    assert [k for k in range(1, 1001) if again.receive(_lpos_datagram(k * 10)) is None] == lost
    assert lf.receive(b"\xfd\x09heartbeat...") is not None  # start-up traffic is never lost in lockstep
    # a resent setpoint and the vehicle's repeated answer meet their first fate, and are not
    # counted again: the counts must not depend on the machine's load
    counts = (up.as_dict(), lf.stats["down"].as_dict())
    kept = next(k for k in range(1, 1001) if k not in lost)
    assert lf.receive(_lpos_datagram(lost[0] * 10)) is None
    assert lf.receive(_lpos_datagram(kept * 10)) is not None
    n = len(sent)
    lf.send(b"setpoint", 9990, sent.append, clock_only.append)
    assert (up.as_dict(), lf.stats["down"].as_dict()) == counts
    assert len(sent) + len(clock_only) == n + 1 + up.lost


def test_the_two_directions_of_a_mavlink_link_draw_independently():
    """``loss: 0.5`` both ways: the setpoint and the sample of one tick are both lost a quarter of
    the time (a shared draw would lose them together half the time)."""
    from swarm_sitl.faults.mavlink import MavlinkFaults

    plan = FaultPlan(seed=4, plan=[{"mavlink": 3, "loss": 0.5}])
    lf = MavlinkFaults(plan, 3, RunClock(True, DT), 600.0)
    n = 4000
    up_lost: list[int] = []
    for k in range(1, n + 1):
        before = lf.stats["up"].lost
        lf.send(b"setpoint", k * 10, lambda _d: None, lambda _ms: None)
        if lf.stats["up"].lost > before:
            up_lost.append(k)
    down_lost = {k for k in range(1, n + 1) if lf.receive(_lpos_datagram(k * 10)) is None}
    for way in (len(up_lost), len(down_lost)):
        assert abs(way - n / 2) < 5 * math.sqrt(n / 4), way
    together = len(set(up_lost) & down_lost)
    assert abs(together - n / 4) < 5 * math.sqrt(n * 3 / 16), together


def test_a_corrupted_sample_repeated_in_lockstep_reaches_the_receiver_once():
    from swarm_sitl.faults.mavlink import MavlinkFaults

    lf = MavlinkFaults(
        FaultPlan(plan=[{"mavlink": 2, "direction": "down", "corrupt": 1.0}]), 2, RunClock(True, DT), 60.0
    )
    first = lf.receive(_lpos_datagram(100))
    assert first is not None and first != _lpos_datagram(100) and lf.lost_ms == 100
    assert lf.receive(_lpos_datagram(100)) is None and lf.lost_ms == 100  # the vehicle's repeat
    assert lf.stats["down"].corrupt == lf.stats["down"].received == 1


def test_a_real_time_mavlink_delay_holds_datagrams_until_due():
    from swarm_sitl.faults.mavlink import MavlinkFaults

    now = [10.0]

    class Clock(WallTime):
        def now_s(self) -> float:
            return now[0]

    lf = MavlinkFaults(
        FaultPlan(plan=[{"mavlink": 2, "direction": "down", "delay_s": 0.05}]), 2, Clock(False, DT), 60.0
    )
    assert lf.receive(b"telemetry") is None
    sent: list[bytes] = []
    lf.send(b"setpoint", 0, sent.append, lambda ms: None)
    assert sent == [b"setpoint"]  # the uplink is untouched
    now[0] = 10.049
    assert lf.release(sent.append) == []
    now[0] = 10.05
    assert lf.release(sent.append) == [b"telemetry"]


def test_a_restarted_node_waits_for_the_liveliness_of_a_neighbour_that_came_back_before_it():
    """Lockstep: controller 1 comes back at tick 400, the leader (its in-neighbour) at tick 650.
    The leader's new session cannot hear the status 1 sent at tick 400; 1 is blocked waiting for
    the leader's tick 650, so its liveliness token is what the leader waits for, not that status
    (waiting for it was a deadlock)."""
    plan = FaultPlan(
        plan=[
            {"controller": 1, "kill": True, "from_s": 3.0, "restart_after_s": 1.0},
            {"leader": True, "kill": True, "from_s": 6.0, "restart_after_s": 0.5},
        ]
    )
    resume = 650
    for alive in ({1: 1, 2: 1}, {2: 1}):
        inner = Publisher(alive)
        bus = FaultyBus(inner, plan, 0, EDGES, RunClock(True, DT), 60.0, 0.2, resume)  # type: ignore[arg-type]
        if 1 in alive:
            bus.publish(Message(0, resume, resume * DT, np.zeros(12)))
            assert inner.sent == [resume]
        else:  # no token: it waits, and names who did not come back
            with pytest.raises(StallError, match="node 0 at tick 650: node 1 did not come back"):
                bus.publish(Message(0, resume, resume * DT, np.zeros(12)))
    # the leader's first incarnation still waits for 1's first tick after its restart (it was up
    # when 1 came back, so it hears that status)
    first = FaultyBus(Publisher({1: 1, 2: 1}), plan, 0, EDGES, RunClock(True, DT), 60.0, 0.2)  # type: ignore[arg-type]
    with pytest.raises(StallError, match="node 1 did not come back"):
        first.publish(Message(0, 400, 4.0, np.zeros(12)))


@pytest.mark.parametrize("lockstep", [True, False], ids=["lockstep", "real time"])
def test_every_mavlink_datagram_meets_the_fate_the_plan_draws_for_it_and_is_counted_once(lockstep):
    """The link's wrapper against a model: each datagram's fate is drawn here from ``fate`` (the
    plan's seed, entry, channel, key, time), and what the wrapper writes, returns, holds and counts
    must be what that fate says. Lockstep keys a datagram by its stamp, real time by its order."""
    from swarm_sitl.faults.mavlink import MavlinkFaults, _flipped
    from swarm_sitl.faults.plan import fate, mavlink_channel

    entries = [
        {"mavlink": 1, "loss": 0.2},
        {"mavlink": 1, "corrupt": 0.2},
        {"mavlink": 1, "drop": True, "from_s": 2.0, "until_s": 3.0},  # read at the stamp, or at arrival
    ]
    if not lockstep:
        entries += [
            {"mavlink": 1, "direction": "up", "delay_s": 0.03},
            {"mavlink": 1, "direction": "down", "delay_s": 0.05},
            {"mavlink": 1, "duplicate": 0.2},
            {"mavlink": 1, "reorder": 0.1},
        ]
    plan = FaultPlan(seed=5, plan=entries)  # (a seed whose other entries spare the window's edges)
    clock: RunClock = RunClock(True, DT) if lockstep else ManualClock()
    lf = MavlinkFaults(plan, 1, clock, 60.0)
    n = 400
    want = {"up": dict.fromkeys(EdgeStats.FIELDS, 0), "down": dict.fromkeys(EdgeStats.FIELDS, 0)}
    held: list[tuple[float, str, bytes]] = []  # real time: what the model holds, (due, way, data)
    last_lost = {"up": False, "down": False}  # a run of lost datagrams goes on
    order = 0
    for k in range(n + 1):
        ms = k * 10
        now = 1.0 + k * DT  # real time: the run's clock is a second ahead of the stamps
        if not lockstep:
            clock.t = now  # type: ignore[attr-defined]
        for way in ("up", "down"):
            rules = plan.on_mavlink(1, way == "up")
            key = ms if lockstep else order
            f = fate(
                plan.seed,
                rules,
                mavlink_channel(1, way == "up"),
                key,
                ms / 1000 if lockstep else now,
                60.0,
                DT,
            )
            if not lockstep:
                order += 1
            w = want[way]
            w["received"] += 1
            w["loss_runs"] += int(f.lost and not last_lost[way])
            last_lost[way] = f.lost
            frame = _lpos_datagram(ms)
            if way == "up":
                written, clock_only = [], []
                lf.send(frame, ms, written.append, clock_only.append)
                if f.lost:
                    w["lost"] += 1
                    assert written == [] and clock_only == ([ms + 10] if lockstep else []), k
                elif f.corrupt:
                    w["corrupt"] += 1
                    assert written == [_flipped(frame, plan.seed, mavlink_channel(1, True), key)], k
                    assert clock_only == ([ms + 10] if lockstep else []), k
                elif f.delay_s > 0:
                    w["delayed"] += 1
                    assert written == [] and lf.next_due_s() is not None
                else:
                    w["delivered"] += 1
                    assert written == [frame], k
            else:
                got = lf.receive(frame)
                if f.lost:
                    w["lost"] += 1
                    assert got is None and (not lockstep or lf.lost_ms == ms), k
                elif f.corrupt:
                    w["corrupt"] += 1
                    assert got == _flipped(frame, plan.seed, mavlink_channel(1, False), key), k
                elif f.delay_s > 0:
                    w["delayed"] += 1
                    assert got is None, k
                else:
                    w["delivered"] += 1
                    assert got == frame, k
            if f.duplicate and not (f.lost or f.corrupt):
                w["duplicated"] += 1
                w["delivered"] += 1  # once more, a period later
                order += 0 if lockstep else 1  # (a held datagram takes a number of the order)
                held.append((now + (f.delay_s + DT), way, frame))
            if f.delay_s > 0 and not (f.lost or f.corrupt):
                w["delivered"] += 1  # when due
                order += 0 if lockstep else 1
                held.append((now + f.delay_s, way, frame))
        if not lockstep:  # what is due goes out (uplink) or is read (downlink), and only that
            assert lf.next_due_s() == (pytest.approx(min(h[0] for h in held)) if held else None)
            released_up: list[bytes] = []
            released_down = lf.release(released_up.append)
            due = [h for h in held if h[0] <= now]
            held = [h for h in held if h[0] > now]
            assert sorted(released_up) == sorted(d for _, w_, d in due if w_ == "up"), k
            assert sorted(released_down) == sorted(d for _, w_, d in due if w_ == "down"), k
    if not lockstep:
        clock.t = 1e6  # type: ignore[attr-defined]
        lf.release(lambda _d: None)
        assert lf.next_due_s() is None
    for way in ("up", "down"):
        got = lf.stats[way].as_dict()
        got.pop("delay_s", None)
        assert got == want[way], (way, got, want[way])
        assert want[way]["lost"] > 0 and want[way]["corrupt"] > 0
        if not lockstep:
            assert want[way]["duplicated"] > 0 and want[way]["delayed"] > 0
            delays = lf.stats[way].delays_s
            assert len(delays) == lf.stats[way].delayed and set(delays) >= {0.03 if way == "up" else 0.05}


def test_a_corruption_flips_one_byte_which_the_seed_and_the_datagram_pick():
    from swarm_sitl.faults.mavlink import _flipped

    data = b"\xff" * 40  # a byte set to 0xff would change nothing here
    where = []
    for key in range(400):
        b = _flipped(data, 9, 7, key)
        changed = [i for i in range(len(data)) if b[i] != data[i]]
        assert len(changed) == 1 and b[changed[0]] == 0x00
        where.append(changed[0])
    assert len(set(where)) == len(data)  # every byte can be the one
    assert where != [next(i for i in range(40) if _flipped(data, 10, 7, k)[i] != 0xFF) for k in range(400)]


def test_a_sample_is_a_datagram_that_starts_with_a_whole_local_position_ned():
    from swarm_sitl.faults.mavlink import sample_ms

    lpos = _lpos_datagram(123_456)
    assert sample_ms(lpos) == 123_456 and sample_ms(lpos[:14]) == 123_456 and sample_ms(lpos[:13]) is None
    assert sample_ms(lpos[:14] + b"\xff" * 4) == 123_456  # what follows is not the stamp
    assert sample_ms(b"\xfe" + lpos[1:]) is None  # MAVLink 1's magic


def _frame(msg, signed: bool) -> bytes:
    from pymavlink.dialects.v20 import common as mav

    m = mav.MAVLink(None, srcSystem=2, srcComponent=1)
    if signed:
        m.signing.secret_key, m.signing.sign_outgoing, m.signing.timestamp = b"k" * 32, True, 1
    return msg.pack(m)


@given(
    st.lists(st.tuples(st.text("abc XYZ!", min_size=0, max_size=50), st.booleans()), max_size=3),
    st.integers(0, 2**32 - 1),
    st.booleans(),
    st.booleans(),
)
def test_a_samples_stamp_is_found_after_any_statustexts_signed_or_not(texts, ms, signed, after):
    """The vehicle's per-tick datagram: any STATUSTEXTs it said (any length, MAVLink 2 trims
    their trailing zeros; each signed or not), then LOCAL_POSITION_NED: its ``time_boot_ms``,
    whatever follows. Any other message first: not a sample."""
    from pymavlink.dialects.v20 import common as mav

    from swarm_sitl.faults.mavlink import sample_ms

    said = b"".join(_frame(mav.MAVLink_statustext_message(6, t.encode(), 0, 0), sg) for t, sg in texts)
    lpos = _frame(mav.MAVLink_local_position_ned_message(ms, 1.0, 2.0, 3.0, 0.0, 0.0, 0.0), signed)
    tail = _frame(mav.MAVLink_attitude_message(ms, 0.1, 0.2, 0.3, 0.0, 0.0, 0.0), signed) if after else b""
    assert sample_ms(said + lpos + tail) == ms
    ack = _frame(mav.MAVLink_command_ack_message(400, 0), signed)
    assert sample_ms(said + ack + lpos) is None


def test_the_delay_summary_is_the_median_p99_and_max_of_the_delays():
    st = EdgeStats()
    assert "delay_s" not in st.as_dict() and set(st.as_dict()) == set(EdgeStats.FIELDS)
    st.delays_s = [float(x) for x in range(200, 0, -1)]  # 1..200, in any order
    st.delayed = 200
    d = st.as_dict()
    assert d["delay_s"] == {"median": 101.0, "p99": 198.0, "max": 200.0}  # the 101st, the 198th, the last
    assert d["delayed"] == 200 and all(isinstance(d[k], int) for k in EdgeStats.FIELDS)
    st.delays_s = [0.5]
    assert st.as_dict()["delay_s"] == {"median": 0.5, "p99": 0.5, "max": 0.5}
    st.delays_s = [0.3, 0.1, 0.2, 0.5, 0.4]  # under 100 delays, the 99th percentile is the largest
    assert st.as_dict()["delay_s"] == {"median": 0.3, "p99": 0.5, "max": 0.5}
    view = np.zeros(len(EdgeStats.FIELDS), dtype=np.int64)
    st.bind(view)  # the counts so far move with it
    st.lost += 3
    assert view.tolist() == [0, 0, 3, 0, 200, 0, 0, 0, 0, 0, 0]


def test_an_in_neighbour_is_settled_for_the_steps_that_arrived_and_those_the_plan_has_it_down():
    bus, inner, _clock = _bus({"controller": 1, "kill": True, "from_s": 1.0, "restart_after_s": 0.5})
    assert not bus.settled(1, 0) and not bus.settled(2, 0)  # nothing arrived yet
    inner.arrive(1, 5)
    inner.arrive(1, 3)  # an older step after a newer one: what arrived is still up to 5
    bus.poll()
    assert bus.settled(1, 5) and not bus.settled(1, 6) and not bus.settled(2, 0)
    assert [k for k in range(90, 160) if bus.settled(1, k)] == list(range(100, 150))  # down 100..149
    inner.arrive(2, 0)
    bus.poll()
    assert bus.settled(2, 0) and not bus.settled(2, 1)  # step 0 is not step 1


class _Gated(Publisher):
    """A publisher whose out-neighbours' progress the test sets (and moves after some polls)."""

    def __init__(self, alive: dict[int, int], progress: dict[int, int], later: dict[int, int] | None = None):
        super().__init__(alive)
        self.at = dict(progress)
        self.later, self.polls = later or {}, 0

    def progress(self, follower: int) -> int:
        return self.at.get(follower, -1)

    def poll(self) -> None:
        self.polls += 1
        if self.polls == 20:
            self.at.update(self.later)


def _leader_bus(plan: FaultPlan, inner: Publisher, resume: int = 0, timeout_s: float = 0.2) -> FaultyBus:
    return FaultyBus(inner, plan, 0, EDGES, RunClock(True, DT), 60.0, timeout_s, resume)  # type: ignore[arg-type]


def _publish(bus: FaultyBus, step: int) -> None:
    bus.publish(Message(0, step, step * DT, np.zeros(12)))


def test_a_publisher_waits_for_each_restarted_reader_at_its_tick_and_not_before():
    plan = FaultPlan(
        plan=[
            {"controller": 1, "kill": True, "from_s": 3.0, "restart_after_s": 1.0},  # back at 400
            {"controller": 2, "kill": True, "from_s": 4.5, "restart_after_s": 0.5},  # back at 500
        ]
    )
    inner = _Gated({1: 1, 2: 1}, {1: 400})
    bus = _leader_bus(plan, inner)
    _publish(bus, 399)  # no reader is due back yet: no wait (2 reports no progress at all)
    _publish(bus, 400)  # 1 has done its tick 400 again: exactly what is waited for
    with pytest.raises(StallError, match=r"node 0 at tick 500: node 2 did not come back .*waited 0\.\d s"):
        _publish(bus, 500)  # the second gate is still there after the first
    slow = _leader_bus(plan, _Gated({1: 1, 2: 1}, {}, later={1: 400}), timeout_s=2.0)
    _publish(slow, 400)  # back after some polls, well within the stall timeout
    assert slow.inner.sent == [400]


def test_a_restarted_node_waits_for_its_readers_liveliness_and_one_back_with_it_counts_as_before_it():
    """Restarted at 650, the leader waits for each out-neighbour's liveliness token; an
    out-neighbour restarted at the same tick may have sent its first status before this session
    could hear it, so it is judged by its token too (waiting for that status could hang)."""
    own = FaultPlan(plan=[{"leader": True, "kill": True, "from_s": 6.0, "restart_after_s": 0.5}])
    with pytest.raises(StallError, match="node 0 at tick 650: node 1 did not come back"):
        _publish(_leader_bus(own, _Gated({}, {}), resume=650), 650)
    both = FaultPlan(
        plan=[
            {"leader": True, "kill": True, "from_s": 6.0, "restart_after_s": 0.5},
            {"controller": 1, "kill": True, "from_s": 6.2, "restart_after_s": 0.3},  # also back at 650
        ]
    )
    bus = _leader_bus(both, _Gated({1: 1, 2: 1}, {}), resume=650)
    _publish(bus, 650)
    assert bus.inner.sent == [650]


def test_a_node_the_plan_kills_kills_itself_at_its_tick_in_lockstep_only(monkeypatch):
    killed: list[tuple[int, int]] = []
    monkeypatch.setattr("swarm_sitl.faults.edges.os.kill", lambda pid, sig: killed.append((pid, sig)))
    plan = FaultPlan(plan=[{"leader": True, "kill": True, "from_s": 1.0}])

    class Inner(_Gated):
        def lost(self) -> set[int]:
            return set()

        def fileno(self) -> int:
            return -1

    inner = Inner({1: 1, 2: 1}, {1: 100, 2: 100})
    bus = _leader_bus(plan, inner)
    _publish(bus, 99)
    assert killed == []
    _publish(bus, 100)  # its readers have done tick 100: the kill loses nothing before it
    import signal

    assert killed == [(os.getpid(), signal.SIGKILL)]
    real = FaultyBus(Inner({}, {}), plan, 0, EDGES, ManualClock(), 60.0)  # type: ignore[arg-type]
    _publish(real, 100)  # in real time the supervisor kills, at the plan's wall-clock time
    assert killed == [(os.getpid(), signal.SIGKILL)] and real.outages == {} and real.own_outages == []


def test_lost_leaves_out_the_neighbours_the_plan_brings_back():
    plan = FaultPlan(
        plan=[
            {"controller": 1, "kill": True, "from_s": 1.0, "restart_after_s": 0.5},
            {"controller": 2, "kill": True, "from_s": 1.0},
        ]
    )

    class Inner(_Gated):
        def lost(self) -> set[int]:
            return {1, 2}

    assert _leader_bus(plan, Inner({}, {})).lost() == {2}


def test_in_real_time_the_window_is_read_at_arrival_and_a_duplicate_follows_one_period_later():
    clock = ManualClock()
    inner = MemoryBus()
    plan = FaultPlan(plan=[{"edge": [1, 4], "duplicate": 1.0, "from_s": 5.0, "until_s": 15.0}])
    bus = FaultyBus(inner, plan, 4, EDGES, clock, 60.0)  # type: ignore[arg-type]
    clock.t = 10.0
    inner.arrive(1, 50)  # sent for t = 0.5 s, arrives at 10 s: inside the window
    bus.poll()
    assert bus.stats[1].duplicated == 0 and bus.stats[1].delayed == 0 and bus.stats[1].delays_s == []
    assert inner.estimate(1, 50) is not None  # handed on at its arrival
    # its copy a period later
    assert [(due, copy) for due, _, copy in bus.faults.held()] == [(pytest.approx(10.0 + DT), True)]
    clock.t = 10.0 + DT
    bus.poll()
    assert not bus.faults.held() and bus.stats[1].delivered == 2 and bus.stats[1].duplicated == 1


def test_a_corruption_of_a_byte_that_is_0xff_still_changes_it():
    """Estimates whose bytes are mostly 0xff: the flipped byte is always changed (a byte set to
    0xff instead would leave most of these intact)."""
    bus, inner, _clock = _bus({"edge": [1, 4], "corrupt": 1.0})
    ones = np.frombuffer(b"\xff\xff\xff\xff\xff\xff\xef\x3f" * 12, np.float64)  # 0.9999999999999999
    for k in range(40):
        inner.wire.append(Message(1, k, k * DT, ones.copy()))
    bus.poll()
    assert bus.stats[1].corrupt == 40 and not any(src == 1 for src, _ in inner.table)


def test_a_planned_kill_waits_for_its_readers_to_take_the_last_estimate_but_not_for_the_gone(monkeypatch):
    """Before killing itself at tick 100 the leader waits until each out-neighbour has done tick
    100, is down by the plan then, or is gone; a stuck reader holds it for the stall timeout,
    then it dies anyway."""
    killed: list[float] = []
    monkeypatch.setattr("swarm_sitl.faults.edges.os.kill", lambda pid, sig: killed.append(time.monotonic()))
    read_end, write_end = os.pipe()

    class Inner(_Gated):
        def __init__(self, progress: dict[int, int], gone: set[int]):
            super().__init__({1: 1, 2: 1}, progress)
            self.gone = gone

        def lost(self) -> set[int]:
            return self.gone

        def fileno(self) -> int:
            return read_end

    leader_killed = {"leader": True, "kill": True, "from_s": 1.0}
    cases = [
        (FaultPlan(plan=[leader_killed]), {1: 100}, {2}),  # 2 is gone
        (FaultPlan(plan=[leader_killed, {"controller": 2, "kill": True, "from_s": 0.5}]), {1: 100}, set()),
    ]
    for plan, progress, gone in cases:
        bus = _leader_bus(plan, Inner(progress, gone), timeout_s=5.0)
        t0 = time.monotonic()
        _publish(bus, 100)
        assert killed and killed[-1] - t0 < 1.0  # at once
    stuck = _leader_bus(FaultPlan(plan=[leader_killed]), Inner({1: 100, 2: 99}, set()), timeout_s=0.3)
    t0 = time.monotonic()
    _publish(stuck, 100)  # 2 never does tick 100: the kill comes after the stall timeout
    assert 0.3 <= killed[-1] - t0 < 2.0 and len(killed) == 3
    os.close(read_end)
    os.close(write_end)
