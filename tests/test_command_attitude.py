"""Command attitude extraction (Lemma 3.3 with docs/paper.md erratum 1)."""

import numpy as np
import pytest
from hypothesis import assume, given

from sim_vehicles.common.quaternion import rotation_matrix
from swarm_sitl.laws.command_attitude import SingularCommandError, command_attitude
from tests.strategies import vec3

pytestmark = pytest.mark.unit


@given(vec3)
def test_extracted_attitude_points_thrust_along_u(u):
    n = np.linalg.norm(u)
    assume(n > 1e-3 and 1 + u[2] / n > 1e-6)
    q, _, _ = command_attitude(u)
    # rounding in |q_c| grows as sigma_c^2 = (1 + u_z/|u|)/2 shrinks toward the singular set
    sigma2 = (1 + u[2] / n) / 2
    assert abs(np.linalg.norm(q) - 1.0) < 1e-13 / sigma2
    np.testing.assert_allclose(rotation_matrix(q) @ [0, 0, 1.0], u / n, atol=1e-9)
    assert q[3] == 0.0  # minimal rotation from e3: no rotation about the thrust axis


@pytest.mark.parametrize("u", [[0, 0, -9.81], [0, 0, -1e-3], [0, 0, 0], [0.0, 0.0, -0.0]])
def test_singular_set_gives_a_clear_error(u):
    with pytest.raises(SingularCommandError, match="straight down or is zero"):
        command_attitude(np.array(u, dtype=float))


def test_printed_formula_is_not_a_unit_quaternion_at_hover():
    """docs/paper.md, erratum 1: the paper's sigma_c = sqrt(1/2 + (g - u_z)/(2|u|)) fails at u = g e3."""
    g = 9.81
    u = np.array([0, 0, g])
    sigma_printed = np.sqrt(0.5 + (g - u[2]) / (2 * g))
    assert abs(sigma_printed**2 - 1.0) > 0.4  # printed: q_c = 0 and sigma = 0.707, not unit
    q, _, _ = command_attitude(u)
    np.testing.assert_allclose(q, [1.0, 0, 0, 0], atol=1e-15)


def test_command_rates_are_finite_differences_of_the_command_attitude():
    """omega_c = 2 vec(conj(Q_c) dQ_c/dt) and its derivative, along u(t) = u0 + u' t + u'' t^2 / 2."""
    from sim_vehicles.common.quaternion import qconj, qmul

    u0, ud, udd = np.array([1.2, -0.7, 9.0]), np.array([0.4, 0.9, -0.3]), np.array([-0.8, 0.5, 0.6])

    def at(t):
        return command_attitude(u0 + ud * t + 0.5 * udd * t * t, ud + udd * t, udd)

    q, w, wd = at(0.0)
    h = 1e-5
    dq = (at(h)[0] - at(-h)[0]) / (2 * h)
    np.testing.assert_allclose(w, 2 * qmul(qconj(q), dq)[1:], rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(wd, (at(h)[1] - at(-h)[1]) / (2 * h), rtol=1e-6, atol=1e-8)
    assert np.linalg.norm(w) > 0.05 and np.linalg.norm(wd) > 0.05  # not trivially zero
    _, w0, wd0 = command_attitude(u0)  # no rates given: a still command
    np.testing.assert_array_equal(np.r_[w0, wd0], np.zeros(6))
