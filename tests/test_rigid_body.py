"""The 6-DOF plant against physics: hover, free fall, torque-free rotation."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sim_vehicles.common.quaternion import from_axis_angle, rotation_matrix
from sim_vehicles.common.state import POS, QUAT, RATE, VEL, make_state
from sim_vehicles.plant.rigid_body import derivative, derivative_in_air, rk4_step, rk4_step_in_air

pytestmark = pytest.mark.unit
M, G = 0.85, 9.81
J = np.array([4.856e-2, 4.856e-2, 8.801e-2])
ZERO = np.zeros(3)


def _fly(x, thrust, torque, dt, n, inertia=J):
    for _ in range(n):
        x = rk4_step(x, thrust, torque, M, inertia, G, dt)
    return x


def test_hover_is_an_equilibrium():
    x0 = make_state([1.0, 2.0, 3.0])
    x = _fly(x0, M * G, ZERO, 1e-3, 5000)
    np.testing.assert_allclose(x, x0, atol=1e-12)


def test_free_fall_follows_the_parabola():
    v0 = np.array([1.0, -2.0, 3.0])
    x = _fly(make_state([0.0, 0, 100.0], v0, from_axis_angle([1, 1, 0], 0.7)), 0.0, ZERO, 1e-3, 3000)
    t = 3.0
    np.testing.assert_allclose(
        x[POS], [0, 0, 100.0] + v0 * t - 0.5 * G * t * t * np.array([0, 0, 1.0]), atol=1e-9
    )
    np.testing.assert_allclose(x[VEL], v0 - G * t * np.array([0, 0, 1.0]), atol=1e-9)


def test_tilted_thrust_accelerates_along_body_z():
    q = from_axis_angle([0, 1.0, 0], 0.3)  # pitch about y: body z tips toward +x (east)
    x = _fly(make_state(ZERO, ZERO, q), 2 * M * G, ZERO, 1e-3, 1)
    acc = x[VEL] / 1e-3
    np.testing.assert_allclose(acc, 2 * G * rotation_matrix(q)[:, 2] - [0, 0, G], rtol=1e-6)


def test_torque_free_rotation_conserves_energy_and_world_angular_momentum():
    Ja = np.array([0.03, 0.05, 0.08])  # asymmetric: the rates tumble, invariants must not drift
    x = make_state(ZERO, ZERO, from_axis_angle([0.2, 1, 0.3], 1.0), [2.0, 0.3, -1.5])

    def invariants(x):
        w = x[RATE]
        return 0.5 * w @ (Ja * w), rotation_matrix(x[QUAT]) @ (Ja * w)

    e0, h0 = invariants(x)
    for _ in range(20):
        x = _fly(x, 0.0, ZERO, 1e-3, 500, Ja)
        e, h = invariants(x)
        assert abs(e - e0) / e0 < 1e-8
        np.testing.assert_allclose(h, h0, rtol=0, atol=1e-8 * np.linalg.norm(h0))
        assert abs(np.linalg.norm(x[QUAT]) - 1.0) < 1e-14
    # the body rates did change (the test is not vacuous)
    assert np.linalg.norm(x[RATE] - [2.0, 0.3, -1.5]) > 0.1


_VEC = st.lists(st.floats(-20, 20), min_size=3, max_size=3).map(np.array)


@settings(max_examples=100, deadline=None)
@given(_VEC, _VEC, _VEC, st.floats(0, 2), st.floats(0, 30), _VEC, st.floats(-1, 1))
def test_in_air_the_acceleration_gains_quadratic_drag_against_the_air_and_nothing_else(
    p, v, w, drag, thrust, tau, a
):
    """``derivative_in_air`` is ``derivative`` plus -drag |v - w| (v - w) / m on the acceleration,
    and nothing else; without drag ``rk4_step_in_air`` is ``rk4_step`` bit for bit; with drag, a
    step is RK4 of that derivative (its classic weights)."""
    x = make_state(p, v, from_axis_angle([0.3, 1.0, -0.2], a), [0.5, -0.2, 0.1])
    plain = derivative(x, thrust, tau, M, J, G)
    air = derivative_in_air(x, thrust, tau, M, J, G, drag, w)
    rel = v - w
    want = plain.copy()
    want[VEL] -= drag * np.linalg.norm(rel) * rel / M
    np.testing.assert_allclose(air, want, rtol=1e-12, atol=1e-12)
    dt = 0.01
    assert np.array_equal(
        rk4_step_in_air(x, thrust, tau, M, J, G, dt, 0.0, w), rk4_step(x, thrust, tau, M, J, G, dt)
    )
    d = lambda y: derivative_in_air(y, thrust, tau, M, J, G, drag, w)  # noqa: E731
    k1 = d(x)
    k2 = d(x + 0.5 * dt * k1)
    k3 = d(x + 0.5 * dt * k2)
    k4 = d(x + dt * k3)
    stepped = x + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
    got = rk4_step_in_air(x, thrust, tau, M, J, G, dt, drag, w)
    np.testing.assert_allclose(got[POS], stepped[POS], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(got[VEL], stepped[VEL], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(got[RATE], stepped[RATE], rtol=1e-12, atol=1e-12)
