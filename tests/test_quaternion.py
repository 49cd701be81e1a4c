"""Quaternion algebra and R(Q) (Hamilton, body -> world)."""

import numpy as np
import pytest
from hypothesis import given, settings

from sim_vehicles.common.quaternion import (
    body_z_axis,
    from_axis_angle,
    from_rotation_matrix,
    qconj,
    qmul,
    quaternion_rate,
    rotate,
    rotate_inverse,
    rotation_matrix,
    skew,
)
from tests.strategies import unit_quaternions, vec3

pytestmark = pytest.mark.unit


@given(unit_quaternions(), unit_quaternions(), unit_quaternions())
def test_product_is_associative_and_norm_preserving(a, b, c):
    np.testing.assert_allclose(qmul(qmul(a, b), c), qmul(a, qmul(b, c)), atol=1e-12)
    assert abs(np.linalg.norm(qmul(a, b)) - 1.0) < 1e-12


@given(unit_quaternions())
def test_rotation_matrix_is_in_so3(q):
    R = rotation_matrix(q)
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
    assert abs(np.linalg.det(R) - 1.0) < 1e-12


@given(unit_quaternions(), vec3)
def test_rotation_matrix_matches_sandwich_product(q, v):
    """R(Q) v == vec(Q (x) [0, v] (x) conj(Q)), the Hamilton definition."""
    sandwich = qmul(qmul(q, np.concatenate(([0.0], v))), qconj(q))
    np.testing.assert_allclose(rotation_matrix(q) @ v, sandwich[1:], atol=1e-10)
    np.testing.assert_allclose(rotate(q, v), sandwich[1:], atol=1e-10)
    np.testing.assert_allclose(rotate_inverse(q, rotate(q, v)), v, atol=1e-10)


@given(unit_quaternions())
def test_rotation_matrix_printed_formula(q):
    """R(Q) = (w^2 - q.q) I + 2 q q^T + 2 w q^x (docs/paper.md, conventions)."""
    w, v = q[0], q[1:]
    R = (w * w - v @ v) * np.eye(3) + 2 * np.outer(v, v) + 2 * w * skew(v)
    np.testing.assert_allclose(rotation_matrix(q), R, atol=1e-12)
    np.testing.assert_allclose(body_z_axis(q), R[:, 2], atol=1e-12)


@given(unit_quaternions(), unit_quaternions())
def test_composition_homomorphism(a, b):
    np.testing.assert_allclose(
        rotation_matrix(qmul(a, b)), rotation_matrix(a) @ rotation_matrix(b), atol=1e-12
    )


@given(unit_quaternions())
def test_from_rotation_matrix_roundtrip(q):
    q2 = from_rotation_matrix(rotation_matrix(q))
    assert min(np.linalg.norm(q2 - q), np.linalg.norm(q2 + q)) < 1e-9


def test_axis_angle_rotates_x_to_y_about_z():
    q = from_axis_angle(np.array([0, 0, 1.0]), np.pi / 2)
    np.testing.assert_allclose(rotation_matrix(q) @ [1.0, 0, 0], [0, 1.0, 0], atol=1e-15)


@given(unit_quaternions(), vec3)
@settings(max_examples=50)
def test_quaternion_rate_is_body_rate_kinematics(q, w):
    """Qdot = 0.5 Q (x) [0, w_B]: exp-map integration over h matches to first order (central FD)."""
    h = 1e-6

    def dq(s):
        return (
            from_axis_angle(w, s * np.linalg.norm(w)) if np.linalg.norm(w) > 0 else np.array([1.0, 0, 0, 0])
        )

    fd = (qmul(q, dq(h)) - qmul(q, dq(-h))) / (2 * h)
    np.testing.assert_allclose(quaternion_rate(q, w), fd, atol=1e-7)


def test_the_kernels_return_quaternions_of_four():
    q, w = np.array([0.5, 0.5, -0.5, 0.5]), np.array([0.1, -0.2, 0.3])
    assert qconj(q).shape == (4,) and quaternion_rate(q, w).shape == (4,)
    np.testing.assert_array_equal(qconj(q), [0.5, -0.5, 0.5, -0.5])


@pytest.mark.parametrize(
    "q",
    [
        [0.5, -0.7, 0.0, np.sqrt(0.26)],  # R[1, 2] is R's largest entry, and q_y = 0
        [0.0, 1.0, 0.0, 0.0],  # half turns: w = 0, the x, y or z branch
        [0.0, 0.0, 1.0, 0.0],
        [0.0, 0.0, 0.0, 1.0],
        [-0.3, 0.1, np.sqrt(0.9), 0.0],  # w < 0: the same rotation comes back with w > 0
    ],
)
def test_from_rotation_matrix_takes_the_stable_branch_and_w_at_least_zero(q):
    q = np.asarray(q)
    back = from_rotation_matrix(rotation_matrix(q))
    expected = q if q[0] > 0 or (q[0] == 0 and q[np.nonzero(q)[0][0]] > 0) else -q
    np.testing.assert_allclose(back, expected, atol=1e-15)
