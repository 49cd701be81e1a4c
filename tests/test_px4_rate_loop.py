"""``px4_quad_x``'s rate loop (``sim_vehicles.plant.px4_control.rate_control``) against PX4 v1.15's
``RateControl::update``, written here again as PX4 writes it, over random rates, gains, integrals
and saturation flags: the torque, the integral's step (its I-factor, its limit, a step that is not
finite dropped), and its anti-windup as a property: over many steps against a saturated
allocation, the integral never moves toward the saturated side, and it winds toward the error
where nothing is saturated."""

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from sim_vehicles.plant.px4_control import GAINS, I_FACTOR_RATE, gain_vector, rate_control
from tests.strategies import FUZZ

pytestmark = pytest.mark.unit

AXES = ("ROLL", "PITCH", "YAW")
LIMS = ("MC_RR_INT_LIM", "MC_PR_INT_LIM", "MC_YR_INT_LIM")


def px4_rate_update(rate, rate_sp, angular_accel, rate_int, sat_pos, sat_neg, k, p, i, d, lim, dt):
    """RateControl::update as PX4 v1.15 writes it (gains already multiplied by MC_*RATE_K, as
    MulticopterRateControl sets them), one axis at a time."""
    torque, new_int = [], []
    for a in range(3):
        err = rate_sp[a] - rate[a]
        torque.append(k[a] * p[a] * err + rate_int[a] - k[a] * d[a] * angular_accel[a])
        if sat_pos[a]:
            err = min(err, 0.0)
        if sat_neg[a]:
            err = max(err, 0.0)
        i_factor = err / math.radians(400.0)
        i_factor = max(0.0, 1.0 - i_factor * i_factor)
        rate_i = rate_int[a] + i_factor * k[a] * i[a] * err * dt
        new_int.append(min(max(rate_i, -lim[a]), lim[a]) if math.isfinite(rate_i) else rate_int[a])
    return np.array(torque), np.array(new_int)


vec = st.tuples(*[st.floats(-12.0, 12.0)] * 3).map(np.array)
flags = st.tuples(*[st.sampled_from([-1.0, 0.0, 1.0])] * 3).map(np.array)


@st.composite
def gain_sets(draw):
    values = {}
    for axis in AXES:
        for term, hi in (("P", 0.6), ("I", 0.6), ("D", 0.01), ("K", 2.0)):
            values[f"MC_{axis}RATE_{term}"] = draw(st.floats(0.0, hi))
    for name in LIMS:
        values[name] = draw(st.floats(0.01, 1.0))
    return values


@FUZZ
@given(vec, vec, vec, st.tuples(*[st.floats(-1.0, 1.0)] * 3).map(np.array), flags, gain_sets(),
       st.floats(1e-4, 0.02))  # fmt: skip
def test_the_rate_loop_is_px4s_for_any_rates_gains_and_saturation(
    omega, omega_sp, omegadot, integral, sat, g, dt
):
    gains = gain_vector(g)
    lim = np.array([g[n] for n in LIMS])
    integral = np.clip(integral, -lim, lim)
    torque, out = rate_control(omega, omega_sp, omegadot, integral, sat, gains, dt)
    per = {t: [g[f"MC_{a}RATE_{t}"] for a in AXES] for t in "PIDK"}
    want_torque, want_int = px4_rate_update(
        omega, omega_sp, omegadot, integral, sat > 0, sat < 0, per["K"], per["P"], per["I"], per["D"], lim, dt
    )
    assert torque == pytest.approx(want_torque, rel=1e-12, abs=1e-12)
    assert out == pytest.approx(want_int, rel=1e-12, abs=1e-15)


@FUZZ
@given(st.integers(0, 2), st.sampled_from([-1.0, 1.0]), st.floats(0.05, 5.0), st.integers(0, 2**32 - 1))
def test_against_a_saturated_allocation_the_integral_never_winds_toward_the_saturation(
    axis, side, err_mag, seed
):
    """Many steps of a rate error pushing into the saturated side (the allocator gives less than
    asked that way): the integral stays where it was or unwinds, never grows that way; with
    nothing saturated the same error winds it toward the error, by PX4's I-factor step."""
    rng = np.random.default_rng(seed)
    gains = gain_vector({})
    k, i_gain = (
        gains[list(GAINS).index(f"MC_{AXES[axis]}RATE_K")],
        gains[list(GAINS).index(f"MC_{AXES[axis]}RATE_I")],
    )
    sat = np.zeros(3)
    sat[axis] = side
    integral = np.zeros(3)
    integral[axis] = rng.uniform(-0.05, 0.05)
    start = integral[axis]
    for _ in range(200):
        err = np.zeros(3)
        err[axis] = side * err_mag * rng.uniform(0.2, 1.0)  # always pushing into the saturation
        _, integral = rate_control(np.zeros(3), err, np.zeros(3), integral, sat, gains, 0.001)
        assert side * (integral[axis] - start) <= 0.0
    free = np.zeros(3)
    free[axis] = side * err_mag
    _, wound = rate_control(np.zeros(3), free, np.zeros(3), np.zeros(3), np.zeros(3), gains, 0.001)
    f = max(0.0, 1.0 - (err_mag / I_FACTOR_RATE) ** 2)
    assert wound[axis] == pytest.approx(side * f * k * i_gain * err_mag * 0.001, rel=1e-12)
    assert side * wound[axis] > 0.0 or f == 0.0
