"""A lockstep run held by its page (``bus.hold``, ``bus.clock.wait_while_held``): the
supervisor's side stops every node where it is, then brings the followers up to the furthest one,
steps by the ticks asked, and puts the hold again for a node that did not hear it; a node's side
(the leader's loop, over a bus of the test's) finishes the tick it is on and waits without a stall
timeout for as long as it is held. A run held, stepped and resumed equals ``sim`` bit for bit
(tests/test_view_browser.py, through the page)."""

import threading
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from swarm_sitl.bus.codec import HOLD_NONE, PayloadError, Status, decode_hold, encode_hold
from swarm_sitl.bus.hold import REPUT_EVERY_S, SETTLE_S, STOP, LockstepHold
from tests.fakes import LeaderBus, leader_config


def _status(i: int, k: int) -> Status:
    return Status(i, k, k * 0.01, k * 0.01, np.zeros(3))


def _hold(last_tick: int = 10_000) -> tuple[LockstepHold, list[int]]:
    puts: list[int] = []
    return LockstepHold(last_tick, puts.append), puts


@pytest.mark.unit
def test_a_pause_stops_every_node_then_brings_the_followers_to_the_furthest():
    hold, puts = _hold()
    hold.act({1: _status(1, 40), 2: _status(2, 35)}, set(), 0.0)
    assert puts == []  # nothing asked: nothing put
    assert hold.control("toggle", 0) == (200, "pausing the run")
    hold.act({1: _status(1, 40), 2: _status(2, 35)}, set(), 0.1)
    # statuses from before the pause are already the furthest known: held at once at 40
    assert puts == [40] and hold.paused and hold.held_at is None  # follower 2 is not there yet
    hold.act({1: _status(1, 43), 2: _status(2, 37)}, set(), 0.15)  # 1 stopped past it: all go to 43
    assert puts == [40, 43] and hold.held_at is None
    hold.act({1: _status(1, 43), 2: _status(2, 43)}, set(), 0.2)
    assert hold.held_at is None  # (a follower past it may still say so)
    hold.act({1: _status(1, 44), 2: _status(2, 43)}, set(), 0.2 + SETTLE_S / 2)  # and 1 does
    hold.act({1: _status(1, 44), 2: _status(2, 44)}, set(), 0.2 + SETTLE_S)
    assert hold.held_at is None and puts == [40, 43, 44]
    hold.act({1: _status(1, 44), 2: _status(2, 44)}, set(), 0.21 + 2 * SETTLE_S)
    assert hold.held_at == 44


@pytest.mark.unit
def test_a_pause_before_any_status_stops_every_node_where_it_is():
    hold, puts = _hold()
    hold.control("on", 0)
    hold.act({}, set(), 0.0)
    assert puts == [STOP] and hold.held_at is None
    for t in (0.05, 0.1, 0.11 + SETTLE_S):  # (the first that sees all there starts the wait)
        hold.act({1: _status(1, 7)}, set(), t)
    assert puts == [STOP, 7] and hold.held_at == 7


@pytest.mark.unit
def test_steps_raise_the_hold_by_the_ticks_asked_and_a_resume_lets_go():
    hold, puts = _hold()
    assert hold.control(None, 1) == (409, "the run is not paused: pause it first, then step")
    hold.control("toggle", 0)
    assert hold.control(None, 1)[0] == 200  # asked after the pause: stepped once it is paused
    assert hold.control(None, 3) == (200, "stepping the run 3 ticks")
    hold.act({1: _status(1, 20), 2: _status(2, 20)}, set(), 0.0)
    assert puts == [24]
    hold.act({1: _status(1, 24), 2: _status(2, 24)}, set(), 0.05)
    hold.act({1: _status(1, 24), 2: _status(2, 24)}, set(), 0.06 + SETTLE_S)
    assert hold.held_at == 24
    assert hold.control("toggle", 0) == (200, "resuming the run")
    hold.act({1: _status(1, 24), 2: _status(2, 24)}, set(), 0.1)
    assert puts == [24, HOLD_NONE] and not hold.paused and hold.held_at is None
    hold.act({1: _status(1, 80), 2: _status(2, 81)}, set(), 5.0)
    assert puts == [24, HOLD_NONE]  # a run that flies is not held again


@pytest.mark.unit
def test_a_follower_down_is_not_waited_for_and_a_hold_never_passes_the_last_tick():
    hold, puts = _hold(last_tick=100)
    hold.control("on", 0)
    for t in (0.0, 0.05, 0.06 + SETTLE_S):
        hold.act({1: _status(1, 60), 2: _status(2, 20)}, {2}, t)
    assert puts == [60] and hold.held_at == 60
    hold.control(None, 500)
    hold.act({1: _status(1, 60), 2: _status(2, 20)}, {2}, 1.0)
    assert puts == [60, 100]


@pytest.mark.unit
def test_a_hold_is_put_again_for_a_node_that_did_not_hear_it():
    hold, puts = _hold()
    hold.control("on", 0)
    hold.act({1: _status(1, 9)}, set(), 0.0)
    hold.act({1: _status(1, 9)}, set(), REPUT_EVERY_S / 2)
    assert puts == [9]
    hold.act({1: _status(1, 9)}, set(), REPUT_EVERY_S + 1e-6)
    assert puts == [9, 9]


@pytest.mark.unit
@pytest.mark.parametrize(
    ("pause", "step", "why"),
    [
        ("maybe", 0, "pause must be toggle, on or off, not 'maybe'"),
        (None, 0, "say pause=toggle|on|off or step=<ticks>"),
        (None, 10**9, "a step runs at most 100000 ticks, not 1000000000"),
    ],
)
def test_a_request_the_hold_does_not_know_is_400_and_one_line(pause, step, why):
    hold, puts = _hold()
    assert hold.control(pause, step) == (400, why)
    hold.act({1: _status(1, 9)}, set(), 0.0)
    assert puts == [] and not hold.paused


@pytest.mark.unit
def test_a_hold_payload_round_trips_and_a_bad_one_is_refused_in_one_line():
    for tick in (STOP, 0, 12345, HOLD_NONE):
        assert decode_hold(encode_hold(tick)) == tick
    with pytest.raises(PayloadError, match="hold payload has 3 bytes, expected 9"):
        decode_hold(b"abc")
    for below in (STOP - 1, -5, -(2**62)):  # every tick below the stop, the one next to it first
        with pytest.raises(PayloadError, match="below -1"):
            decode_hold(encode_hold(below))


class _HeldBus(LeaderBus):
    """The test's bus, with a hold the test moves."""

    def __init__(self) -> None:
        super().__init__(progress=1 << 30)  # followers far ahead: only the hold paces the leader
        self.hold = 99

    def hold_tick(self) -> int:
        return self.hold


@pytest.mark.integration
def test_a_held_leader_finishes_the_tick_it_is_on_and_waits_past_the_stall_timeout():
    from swarm_sitl.nodes.leader import run_leader

    cfg = leader_config()  # stall timeout 0.3 s, 800 ticks
    bus = _HeldBus()
    errors: list[BaseException] = []

    def fly() -> None:
        try:
            run_leader(cfg, bus, True, [1, 2, 3])  # type: ignore[arg-type]
        except BaseException as e:  # (the test says what it was)
            errors.append(e)

    th = threading.Thread(target=fly, daemon=True)
    th.start()
    time.sleep(3 * cfg.run.stall_timeout_s)
    assert bus.published == list(range(100)) and th.is_alive() and not errors  # ticks 0..99, held
    bus.hold = 101  # a step of two ticks
    time.sleep(3 * cfg.run.stall_timeout_s)
    assert bus.published == list(range(102)) and not errors
    bus.hold = HOLD_NONE
    th.join(10)
    assert not errors and bus.published == list(range(cfg.n_control_steps + 1))


@pytest.mark.unit
@settings(max_examples=150, deadline=None)
@given(
    ops=st.lists(
        st.one_of(
            st.tuples(st.just("page"), st.sampled_from(["toggle", "on", "on", "off"]), st.just(0)),
            st.tuples(st.just("page"), st.none(), st.integers(1, 5)),
            st.tuples(
                st.just("act"), st.lists(st.integers(0, 60), min_size=2, max_size=2), st.floats(0.01, 0.4)
            ),
            st.tuples(st.just("act"), st.just("at the hold"), st.floats(0.01, 0.4)),
            st.just(("settle",)),  # a pause and rounds with both followers at the hold: held, often
        ),
        max_size=40,
    )
)
def test_a_run_is_said_held_only_paused_at_the_tick_every_live_follower_is_at_and_each_put_is_the_hold(ops):
    """Any sequence of page requests and supervisor rounds: ``held_at`` is None but while paused,
    and then it is the hold last put, which every follower's status says and has said for
    ``SETTLE_S``; a put is made when the hold changes and again at most ``REPUT_EVERY_S`` later."""
    hold, puts = _hold(last_tick=50)
    now, put_at, level_since = 0.0, [], None
    settle = [("page", "on", 0), *[("act", "at the hold", 0.1)] * 4]
    for op in [o for drawn in ops for o in (settle if drawn == ("settle",) else [drawn])]:
        if op[0] == "page":
            hold.control(op[1], op[2])
            continue
        steps, dt = op[1], op[2]
        if steps == "at the hold":  # both followers where the hold is (once it is a tick)
            steps = [hold.tick, hold.tick] if 0 <= hold.tick <= 50 else [3, 3]
        now += dt
        before = len(puts)
        hold.act({1: _status(1, steps[0]), 2: _status(2, steps[1])}, set(), now)
        put_at += [now] * (len(puts) - before)
        level = hold.paused and steps[0] == steps[1] == hold.tick
        level_since = (now if level_since is None else level_since) if level else None
        if not hold.paused:
            assert hold.held_at is None
        elif hold.held_at is not None:
            assert hold.held_at == hold.tick == puts[-1] == steps[0] == steps[1]
            assert level_since is not None and now - level_since >= SETTLE_S
        assert len(puts) == len(put_at)
        if puts and hold.tick != HOLD_NONE:
            assert now - put_at[-1] <= REPUT_EVERY_S + 0.4  # put again once due (rounds 0.4 s apart at most)
    assert all(p == HOLD_NONE or -1 <= p <= 50 for p in puts)
