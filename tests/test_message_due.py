"""When a message is due to be used (``bus.clock``'s ``message_due``), in each clock, for any step,
period, queue and delay: stated here as the rule the docstrings give, computed another way.

Lockstep (``TickTime``): a message of step ``s`` left its sender's queue ``left_s`` after its tick;
it is used at the first tick after ``s`` at whose instant it has left (``s + 1`` when it left by
then: on time), then ``ceil(delay / dt)`` ticks later; late when the queue kept it past ``s + 1``.
Real time (``WallTime``): used from now, or from when it left its queue if that is later, plus
the delay; late when it left after now. A duplicate's second copy comes one period after it.
Times on a tick's edge are drawn as often as the rest: 1e-9 of a period is the code's and this
test's tolerance for a time computed as a sum of floats.
"""

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from swarm_sitl.bus.clock import RunClock, TickTime, WallTime
from tests.strategies import FUZZ

pytestmark = pytest.mark.unit

periods = st.sampled_from([0.004, 0.01, 0.02, 0.05])


def spans(period_s: float) -> st.SearchStrategy[float]:
    """0, whole periods (a tick's edge) and anything up to five periods."""
    return st.one_of(
        st.just(0.0),
        st.integers(1, 5).map(lambda n: n * period_s),
        st.floats(0, 5 * period_s, exclude_min=True),
    )


@st.composite
def lockstep_cases(draw):
    dt = draw(periods)
    return dt, draw(st.integers(0, 10**6)), draw(spans(dt)), draw(spans(dt))


@FUZZ
@given(case=lockstep_cases())
def test_in_lockstep_a_message_is_used_at_the_first_tick_it_has_left_by_then_its_delay(case):
    dt, step, left_s, delay_s = case
    clock = RunClock(True, dt)
    assert isinstance(clock, TickTime)
    tick = step + 1
    while (tick - step) * dt < left_s - 1e-9 * dt:  # not yet left at that tick's instant
        tick += 1
    on_time = tick == step + 1
    ticks_late = 0
    while ticks_late * dt < delay_s - 1e-9 * dt:
        ticks_late += 1
    assert clock.message_due(step, step * dt, left_s, delay_s) == (tick + ticks_late, not on_time, 1.0)


class _WallAt(WallTime):
    """A wall clock read at a fixed run time (``at``)."""

    def __init__(self, period_s: float, at: float):
        super().__init__(False, period_s)
        self.at = at

    def now_s(self) -> float:
        return self.at


@FUZZ
@given(
    dt=periods,
    t_s=st.floats(0, 100),
    ahead=st.one_of(st.just(0.0), st.floats(-0.2, 0.2)),
    left_s=st.one_of(st.just(0.0), st.floats(0, 0.2)),
    delay_s=st.one_of(st.just(0.0), st.floats(0, 0.2)),
    edge=st.booleans(),
)
def test_in_real_time_a_message_is_used_from_now_or_when_it_left_if_later_plus_its_delay(
    dt, t_s, ahead, left_s, delay_s, edge
):
    now = t_s + left_s if edge else t_s + ahead  # (on the edge: it left just now)
    clock = _WallAt(dt, now)
    left_at = t_s + left_s
    late = left_s > 0 and left_at > now
    due, said_late, second_after = clock.message_due(7, t_s, left_s, delay_s)
    assert said_late == late and second_after == dt
    assert due == (left_at if late else now) + delay_s
    assert due >= now + delay_s and (left_s == 0 or due >= min(left_at, now) + delay_s)
    assert not math.isnan(due)
