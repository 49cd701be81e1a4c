"""Command attitude extraction (Lemma 3.3 with NOTES.md fix 1)."""

import numpy as np
import pytest
from hypothesis import assume, given

from sim_vehicles.quaternion import rotation_matrix
from swarm_sitl.command_attitude import SingularCommandError, command_attitude
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
    """NOTES.md error 1: the paper's sigma_c = sqrt(1/2 + (g - u_z)/(2|u|)) fails at u = g e3."""
    g = 9.81
    u = np.array([0, 0, g])
    sigma_printed = np.sqrt(0.5 + (g - u[2]) / (2 * g))
    assert abs(sigma_printed**2 - 1.0) > 0.4  # printed: q_c = 0 and sigma = 0.707, not unit
    q, _, _ = command_attitude(u)
    np.testing.assert_allclose(q, [1.0, 0, 0, 0], atol=1e-15)
