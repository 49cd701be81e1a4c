"""The 6-DOF plant against physics: hover, free fall, torque-free rotation."""

import numpy as np
import pytest

from sim_vehicles.common.quaternion import from_axis_angle, rotation_matrix
from sim_vehicles.common.state import POS, QUAT, RATE, VEL, make_state
from sim_vehicles.plant.rigid_body import rk4_step

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
