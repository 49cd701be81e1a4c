"""The wall clock's ticks (``nodes.pacing.WallClock.wait_instant``): a tick a whole period late is
skipped to the swarm's current tick and counted, and never past the run's last tick, which every
node flies however late (a node late at the end still reports the end: its last row is tick n)."""

import time

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from swarm_sitl.bus.clock import RunClock
from swarm_sitl.nodes.pacing import Lockstep, WallClock, pacer

pytestmark = pytest.mark.unit

DT_S = 0.2  #: long, so a tick on time is not made late by this test's own pauses


def _behind(k: int, periods: float, phase_s: float) -> WallClock:
    """A wall clock whose tick ``k`` was due ``periods`` periods ago."""
    clock = WallClock(DT_S)
    clock.epoch_mono = time.monotonic() - (k + periods) * DT_S - phase_s
    return clock


def _wait(clock: WallClock, k: int, phase_s: float, last: int | None) -> tuple[int, float]:
    return clock.wait_instant(k, phase_s, [], lambda: None, lambda: None, last=last)


@settings(max_examples=200, deadline=None)
@given(
    k=st.integers(0, 5000),
    periods=st.floats(1.05, 400.0),
    to_last=st.integers(0, 500),
    phase_s=st.floats(0.0, DT_S * 0.99),
)
def test_a_late_tick_skips_to_the_current_tick_but_never_past_the_last(k, periods, to_last, phase_s):
    last = k + to_last
    clock = _behind(k, periods, phase_s)
    at, lateness = _wait(clock, k, phase_s, last)
    now_tick = int((time.monotonic() - clock.epoch_mono - phase_s) / DT_S)  # read after: >= the clock's
    assert lateness > DT_S
    assert min(k + int(periods), last) <= at <= min(now_tick, last)  # where the clock was, or the last
    assert clock.late == max(at - k, 1)  # the skipped ticks, or the last one flown late


@settings(max_examples=50, deadline=None)
@given(k=st.integers(0, 5000), periods=st.floats(1.05, 400.0))
def test_at_the_last_tick_a_late_node_flies_it_and_counts_it_late(k, periods):
    clock = _behind(k, periods, 0.0)
    assert _wait(clock, k, 0.0, k) == (k, pytest.approx(periods * DT_S, abs=0.1))
    assert clock.late == 1


@settings(max_examples=50, deadline=None)
@given(k=st.integers(0, 5000), periods=st.floats(0.0, 0.5))
def test_a_tick_on_time_is_flown_and_not_counted(k, periods):
    """Due less than a period ago (or not yet: ``periods`` 0 sleeps until its instant)."""
    clock = _behind(k, periods, 0.0)
    at, lateness = _wait(clock, k, 0.0, k + 10)
    assert at == k and lateness >= 0.0 and clock.late == 0


@settings(max_examples=30, deadline=None)
@given(k=st.integers(0, 5000), first=st.floats(1.05, 50.0), second=st.floats(1.05, 50.0))
def test_late_ticks_add_up_over_a_run(k, first, second):
    """Each late tick adds what it skipped (or one at the last tick) to the count the run reports."""
    clock = _behind(k, first, 0.0)
    at, _ = _wait(clock, k, 0.0, k + 10_000)
    after_first = clock.late
    assert after_first == max(at - k, 1)
    clock.epoch_mono = time.monotonic() - (at + 1 + second) * DT_S  # its next tick, late again
    at2, _ = _wait(clock, at + 1, 0.0, at + 1 + 10_000)
    assert clock.late == after_first + max(at2 - (at + 1), 1)


@pytest.mark.parametrize("lockstep", [True, False])
def test_a_pacer_is_its_clocks_run_clock_of_its_period_and_lockstep_is_never_late(lockstep):
    dt = 0.02
    clock = pacer(lockstep, dt)
    assert isinstance(clock, Lockstep if lockstep else WallClock) and isinstance(clock, RunClock)
    assert (clock.lockstep, clock.period_s) == (lockstep, dt)
    if lockstep:  # its inputs pace it: the tick asked, at once, never late
        assert clock.wait_instant(17, 0.004, [], lambda: None, lambda: None) == (17, 0.0) and clock.tick == 17
        assert clock.message_due(3, 0.06, 2.5 * dt, 0.0) == (6, True, 1.0)
