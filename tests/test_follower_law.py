"""The follower law's assembly (``swarm_sitl/laws/follower_law.py``) against what it is made of.

The pieces (the estimator, the auxiliary system, the command force and attitude) are tested in
their own modules against the paper; here each of the assembly's kernels is checked, over random
states, messages, vehicles and gains, against a closed form or against the pieces composed by the
test itself:

- ``neighbours_at`` carries a message along its own derivatives: exact for a neighbour of constant
  jerk in velocity, acceleration and its rate, second order in position (the jerk's ``tau^3 / 6``
  is what it leaves out), each row from its own time; the zero-order hold carries nothing;
- ``controller_rhs`` is the estimator's right-hand side on that table beside the auxiliary system
  fed the vehicle carried to ``t`` at constant acceleration;
- ``controller_advance`` is classical RK4 of ``controller_rhs`` (one substep written out here), and
  ``n`` substeps are ``n`` single steps, bit for bit;
- ``controller_output``'s force, thrust, estimate, acceleration and command attitude are the pieces'
  at its state; moving the vehicle and its formation offset together changes nothing;
- ``controller_tick`` is ``controller_advance`` then ``controller_output`` on the sample carried by
  its age, with the thrust limited to the vehicle's, and says whether the output is finite.

Tolerances: where the test composes the same floating-point operations in the same order it asks
for equality; the closed forms of the hold differ from the kernel's by rounding of terms of size at
most ``|x| (1 + tau)^3`` with ``|x|, tau`` drawn below 10 and 1: 1e-12 relative to that scale is
a thousand ulps.
"""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sim_vehicles.common.quaternion import rotate
from swarm_sitl.laws.command_attitude import command_attitude_kernel
from swarm_sitl.laws.estimator import acceleration_estimate, estimator_rhs
from swarm_sitl.laws.follower_law import (
    CTRL_SIZE,
    HOLD_EXTRAPOLATE,
    HOLD_ZERO_ORDER,
    MSG_COLS,
    OUT_A_HAT,
    OUT_A_HAT_DOT,
    OUT_ACC,
    OUT_OMEGA_C,
    OUT_OMEGADOT_C,
    OUT_Q_C,
    OUT_THRUST,
    OUT_U,
    OUT_U_DDOT,
    OUT_U_DOT,
    TICK_ACC,
    TICK_FINITE,
    TICK_OUT,
    TICK_STATE,
    ControlGains,
    controller_advance,
    controller_output,
    controller_rhs,
    controller_tick,
    gains_vector,
    neighbours_at,
)
from swarm_sitl.laws.position_loop import auxiliary_rhs, command_force

pytestmark = pytest.mark.unit

SEEDS = settings(max_examples=25, deadline=None)
E3 = np.array([0.0, 0.0, 1.0])


def _gains(rng: np.random.Generator) -> ControlGains:
    """Positive gains of a few magnitudes; the sign term as printed (0) or with a layer; the
    bracket's weight as printed (1) or ``l_a``."""
    k = rng.uniform(0.2, 10.0, size=8)
    l_a = float(k[3])
    return ControlGains(
        *map(float, k),
        sign_boundary_layer=float(rng.choice([0.0, rng.uniform(0.1, 20.0)])),
        bracket_a_weight=float(rng.choice([1.0, l_a])),
        mass_kg=float(rng.uniform(0.3, 3.0)),
        g_mps2=float(rng.uniform(9.0, 10.0)),
    )


def _msgs(rng: np.random.Generator, n: int) -> np.ndarray:
    """``n`` message rows, each with its own weight and time."""
    m = rng.uniform(-3.0, 3.0, size=(n, MSG_COLS))
    m[:, 0] = rng.uniform(0.1, 2.0, size=n)
    m[:, 1] = rng.uniform(0.0, 1.0, size=n)
    return m


def _case(seed: int):
    """A random controller state, messages, vehicle and gains at a time after every message."""
    rng = np.random.default_rng(seed)
    gains = _gains(rng)
    msgs = _msgs(rng, int(rng.integers(1, 4)))
    xc = rng.uniform(-1.0, 1.0, size=CTRL_SIZE)
    t = float(rng.uniform(1.0, 1.5))
    veh = (float(rng.uniform(0.5, 1.0)), *rng.uniform(-2.0, 2.0, size=(3, 3)))
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    offset = rng.uniform(-3.0, 3.0, size=3)
    return rng, gains, msgs, xc, t, veh, q, offset


@given(st.integers(0, 2**32 - 1), st.sampled_from([1, 2, 5]))
@SEEDS
def test_a_neighbours_message_is_carried_along_its_own_derivatives_from_its_own_time(seed, n):
    rng = np.random.default_rng(seed)
    msgs = _msgs(rng, n)
    t = float(rng.uniform(1.0, 2.0))
    tau = t - msgs[:, 1:2]
    w, p, v, a, j = msgs[:, 0], msgs[:, 2:5], msgs[:, 5:8], msgs[:, 8:11], msgs[:, 11:14]
    nb = neighbours_at(msgs, t, HOLD_EXTRAPOLATE)
    scale = np.abs(msgs).max() * (1.0 + tau.max()) ** 3
    assert nb.shape == (n, 13)
    np.testing.assert_array_equal(nb[:, 0], w)
    # a neighbour of constant jerk j: velocity, acceleration and jerk exact; position without j
    np.testing.assert_allclose(nb[:, 1:4], p + v * tau + a * tau**2 / 2, rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(nb[:, 4:7], v + a * tau + j * tau**2 / 2, rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(nb[:, 7:10], a + j * tau, rtol=0, atol=1e-12 * scale)
    np.testing.assert_array_equal(nb[:, 10:13], j)
    # held: the message as it came, whatever the time
    np.testing.assert_array_equal(neighbours_at(msgs, t, HOLD_ZERO_ORDER), msgs[:, [0, *range(2, 14)]])


def _carried(veh, t, hold):
    """The vehicle's sample ``(t_s, p, v, a)`` carried to ``t`` at constant acceleration."""
    t_s, p, v, a = veh
    tau = t - t_s if hold == HOLD_EXTRAPOLATE else 0.0
    return p + v * tau + a * tau**2 / 2, v + a * tau


@given(st.integers(0, 2**32 - 1), st.sampled_from([HOLD_ZERO_ORDER, HOLD_EXTRAPOLATE]))
@SEEDS
def test_the_controller_state_moves_as_the_estimator_beside_the_auxiliary_system(seed, hold):
    _, g, msgs, xc, t, veh, _, offset = _case(seed)
    dx = controller_rhs(xc, t, msgs, hold, *veh, offset, g)
    est = estimator_rhs(
        xc[0:12],
        neighbours_at(msgs, t, hold),
        g.k_gamma,
        g.k_p,
        g.k_v,
        g.l_a,
        g.k_a,
        g.sign_boundary_layer,
        g.bracket_a_weight,
    )[0]
    p, v = _carried(veh, t, hold)
    eta, eta_dot = xc[12:15], xc[15:18]
    eta_ddot = auxiliary_rhs(
        eta, eta_dot, p - xc[0:3] - offset - eta, v - xc[3:6] - eta_dot, g.k_eta, g.l_p, g.l_v
    )
    assert dx.shape == (CTRL_SIZE,)
    np.testing.assert_array_equal(dx[0:12], est)
    np.testing.assert_array_equal(dx[12:15], eta_dot)
    np.testing.assert_allclose(dx[15:18], eta_ddot, rtol=1e-12, atol=1e-12)


@given(st.integers(0, 2**32 - 1), st.integers(1, 4), st.sampled_from([HOLD_ZERO_ORDER, HOLD_EXTRAPOLATE]))
@SEEDS
def test_the_controller_state_advances_by_classical_rk4_in_equal_substeps(seed, n_sub, hold):
    rng, g, msgs, xc, t0, veh, _, offset = _case(seed)
    dt = float(rng.uniform(0.001, 0.05))

    def f(x, t):
        return controller_rhs(x, t, msgs, hold, *veh, offset, g)

    h = dt / n_sub
    k1 = f(xc, t0)
    k2 = f(xc + 0.5 * h * k1, t0 + 0.5 * h)
    k3 = f(xc + 0.5 * h * k2, t0 + 0.5 * h)
    k4 = f(xc + h * k3, t0 + h)
    one = xc + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    np.testing.assert_array_equal(controller_advance(xc, t0, h, 1, msgs, hold, *veh, offset, g), one)
    steps = xc
    for i in range(n_sub):
        steps = controller_advance(steps, t0 + i * h, h, 1, msgs, hold, *veh, offset, g)
    whole = controller_advance(xc, t0, dt, n_sub, msgs, hold, *veh, offset, g)
    np.testing.assert_array_equal(whole, steps)
    # the start is not written
    assert whole is not xc and not np.array_equal(whole, xc)


def _output(xc, t, msgs, hold, p, v, q, offset, g, a_given=None):
    a = np.zeros(3) if a_given is None else a_given
    return controller_output(xc, t, msgs, hold, p, v, q, a, a_given is not None, offset, g)


@given(st.integers(0, 2**32 - 1), st.sampled_from([HOLD_ZERO_ORDER, HOLD_EXTRAPOLATE]))
@SEEDS
def test_the_output_is_the_pieces_at_the_controller_state(seed, hold):
    rng, g, msgs, xc, t, _, q, offset = _case(seed)
    p, v = rng.uniform(-3.0, 3.0, size=(2, 3))
    out = _output(xc, t, msgs, hold, p, v, q, offset, g)
    a_hat, a_hat_dot = acceleration_estimate(xc[6:9], xc[9:12], g.k_gamma)
    u = command_force(a_hat, xc[12:15], xc[15:18], g.k_eta, g.g_mps2)
    np.testing.assert_array_equal(out[OUT_A_HAT], a_hat)
    np.testing.assert_array_equal(out[OUT_A_HAT_DOT], a_hat_dot)
    np.testing.assert_array_equal(out[OUT_U], u)
    assert out[OUT_THRUST] == pytest.approx(g.mass_kg * np.linalg.norm(u), rel=1e-14)
    # the vehicle's acceleration under that thrust along its body z, against gravity
    np.testing.assert_allclose(
        out[OUT_ACC], np.linalg.norm(u) * rotate(q, E3) - g.g_mps2 * E3, rtol=0, atol=1e-12
    )
    q_c, w_c, wd_c = command_attitude_kernel(u, out[OUT_U_DOT], out[OUT_U_DDOT])
    np.testing.assert_array_equal(out[OUT_Q_C], q_c)
    np.testing.assert_array_equal(out[OUT_OMEGA_C], w_c)
    np.testing.assert_array_equal(out[OUT_OMEGADOT_C], wd_c)
    # a given acceleration (a prescribed trajectory's) is the one used, and changes u's derivatives
    a_given = rng.uniform(-3.0, 3.0, size=3)
    given_out = _output(xc, t, msgs, hold, p, v, q, offset, g, a_given)
    np.testing.assert_array_equal(given_out[OUT_ACC], a_given)
    np.testing.assert_array_equal(given_out[OUT_U], u)
    assert not np.allclose(given_out[OUT_U_DDOT], out[OUT_U_DDOT], rtol=0, atol=1e-9)


@given(st.integers(0, 2**32 - 1), st.sampled_from([HOLD_ZERO_ORDER, HOLD_EXTRAPOLATE]))
@SEEDS
def test_the_output_sees_the_vehicle_only_relative_to_its_place_in_the_formation(seed, hold):
    rng, g, msgs, xc, t, _, q, offset = _case(seed)
    p, v = rng.uniform(-3.0, 3.0, size=(2, 3))
    d = rng.uniform(-3.0, 3.0, size=3)
    out = _output(xc, t, msgs, hold, p, v, q, offset, g)
    np.testing.assert_allclose(
        _output(xc, t, msgs, hold, p + d, v, q, offset + d, g), out, rtol=1e-9, atol=1e-9
    )
    # the vehicle alone moved: the auxiliary system's acceleration, and so u's rate, moves with it
    moved = _output(xc, t, msgs, hold, p + d, v, q, offset, g)
    assert not np.allclose(moved[OUT_U_DOT], out[OUT_U_DOT], rtol=0, atol=1e-9)
    faster = _output(xc, t, msgs, hold, p, v + d, q, offset, g)
    assert not np.allclose(faster[OUT_U_DOT], out[OUT_U_DOT], rtol=0, atol=1e-9)


@given(st.integers(0, 2**32 - 1), st.integers(0, 3), st.sampled_from([HOLD_ZERO_ORDER, HOLD_EXTRAPOLATE]))
@SEEDS
def test_a_tick_is_the_advance_then_the_output_on_the_sample_carried_by_its_age(seed, n_sub, hold):
    rng, g, msgs, xc, t, veh, q, offset = _case(seed)
    t_prev = t - float(rng.uniform(0.005, 0.05))
    p, v = rng.uniform(-3.0, 3.0, size=(2, 3))
    age = float(rng.choice([0.0, rng.uniform(0.001, 0.1)]))
    out = controller_output(
        xc if n_sub == 0 else controller_advance(xc, t_prev, t - t_prev, n_sub, msgs, hold, *veh, offset, g),
        t,
        msgs,
        hold,
        p + v * age + veh[3] * age**2 / 2,
        v + veh[3] * age,
        q,
        veh[3],
        False,
        offset,
        g,
    )
    # a limit below, at or above the thrust asked for
    max_thrust = float(out[OUT_THRUST] * rng.choice([0.5, 1.0, 2.0]))
    res = controller_tick(
        xc, t_prev, t, n_sub, msgs, hold, *veh, p, v, q, age, offset, gains_vector(g), max_thrust
    )
    if n_sub == 0:
        np.testing.assert_array_equal(res[TICK_STATE], xc)
    else:
        np.testing.assert_array_equal(
            res[TICK_STATE], controller_advance(xc, t_prev, t - t_prev, n_sub, msgs, hold, *veh, offset, g)
        )
    np.testing.assert_allclose(res[TICK_OUT], out, rtol=1e-12, atol=1e-12)
    applied = min(out[OUT_THRUST], max_thrust)
    np.testing.assert_allclose(
        res[TICK_ACC], applied / g.mass_kg * rotate(q, E3) - g.g_mps2 * E3, rtol=0, atol=1e-12
    )
    assert res[TICK_FINITE] == 1.0


@pytest.mark.parametrize("column", [0, 2, 5, 8, 11])
def test_a_tick_on_a_message_that_is_not_a_number_says_its_output_is_not_finite(column):
    _, g, msgs, xc, t, veh, q, offset = _case(column)
    bad = msgs.copy()
    bad[0, column] = np.nan
    p, v = np.zeros(3), np.zeros(3)
    args = (0, bad, HOLD_EXTRAPOLATE, *veh, p, v, q, 0.0, offset, gains_vector(g), 100.0)
    assert controller_tick(xc, t - 0.01, t, *args)[TICK_FINITE] == 0.0
    args = (0, msgs, HOLD_EXTRAPOLATE, *veh, p, v, q, 0.0, offset, gains_vector(g), 100.0)
    assert controller_tick(xc, t - 0.01, t, *args)[TICK_FINITE] == 1.0
