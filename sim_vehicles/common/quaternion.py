"""Hamilton quaternion algebra, scalar first ``[w, x, y, z]``.

A quaternion ``q_WB`` rotates body-frame vectors into the world frame: ``v_W = R(q_WB) v_B`` with
``R(Q) = (w^2 - q.q) I + 2 q q^T + 2 w q^x`` and kinematics ``Qdot = 0.5 * Q (x) [0, omega_B]``.
All functions are pure and compiled; they take and return float64 numpy arrays.
"""

import numpy as np

from sim_vehicles.common.jit import kernel


@kernel
def qmul(a, b):
    """Hamilton product ``a (x) b``."""
    aw, ax, ay, az = a[0], a[1], a[2], a[3]
    bw, bx, by, bz = b[0], b[1], b[2], b[3]
    out = np.empty(4)
    out[0] = aw * bw - ax * bx - ay * by - az * bz
    out[1] = aw * bx + ax * bw + ay * bz - az * by
    out[2] = aw * by - ax * bz + ay * bw + az * bx
    out[3] = aw * bz + ax * by - ay * bx + az * bw
    return out


@kernel
def qconj(q):
    """Conjugate ``[w, -x, -y, -z]`` (the inverse of a unit quaternion)."""
    out = np.empty(4)
    out[0] = q[0]
    out[1] = -q[1]
    out[2] = -q[2]
    out[3] = -q[3]
    return out


@kernel
def skew(v):
    """``v^x``: the matrix with ``v^x a = v x a``."""
    out = np.zeros((3, 3))
    out[0, 1] = -v[2]
    out[0, 2] = v[1]
    out[1, 0] = v[2]
    out[1, 2] = -v[0]
    out[2, 0] = -v[1]
    out[2, 1] = v[0]
    return out


@kernel
def rotation_matrix(q):
    """``R(Q) = (w^2 - q.q) I + 2 q q^T + 2 w q^x`` (body -> world for ``q_WB``)."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    R = np.empty((3, 3))
    R[0, 0] = w * w + x * x - y * y - z * z
    R[0, 1] = 2.0 * (x * y - w * z)
    R[0, 2] = 2.0 * (x * z + w * y)
    R[1, 0] = 2.0 * (x * y + w * z)
    R[1, 1] = w * w - x * x + y * y - z * z
    R[1, 2] = 2.0 * (y * z - w * x)
    R[2, 0] = 2.0 * (x * z - w * y)
    R[2, 1] = 2.0 * (y * z + w * x)
    R[2, 2] = w * w - x * x - y * y + z * z
    return R


@kernel
def dot3(a, b):
    """``a . b`` for 3-vectors."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@kernel
def matvec(M, v):
    """``M v`` for a 3x3 matrix."""
    out = np.empty(3)
    for r in range(3):
        out[r] = M[r, 0] * v[0] + M[r, 1] * v[1] + M[r, 2] * v[2]
    return out


@kernel
def matTvec(M, v):
    """``M^T v`` for a 3x3 matrix."""
    out = np.empty(3)
    for c in range(3):
        out[c] = M[0, c] * v[0] + M[1, c] * v[1] + M[2, c] * v[2]
    return out


@kernel
def rotate(q, v):
    """``R(q) v``."""
    return matvec(rotation_matrix(q), v)


@kernel
def rotate_inverse(q, v):
    """``R(q)^T v``."""
    return matTvec(rotation_matrix(q), v)


@kernel
def body_z_axis(q):
    """``R(q) e3``: the body z axis (thrust direction) in the world frame."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    out = np.empty(3)
    out[0] = 2.0 * (x * z + w * y)
    out[1] = 2.0 * (y * z - w * x)
    out[2] = w * w - x * x - y * y + z * z
    return out


@kernel
def quaternion_rate(q, omega_B):
    """``Qdot = 0.5 * Q (x) [0, omega_B]`` [1/s]."""
    p = np.empty(4)
    p[0] = 0.0
    p[1] = omega_B[0]
    p[2] = omega_B[1]
    p[3] = omega_B[2]
    return 0.5 * qmul(q, p)


def from_axis_angle(axis: np.ndarray, angle_rad: float) -> np.ndarray:
    """Unit quaternion of a rotation by ``angle_rad`` about ``axis`` (need not be unit)."""
    a = np.asarray(axis, dtype=float)
    a = a / np.linalg.norm(a)
    half = 0.5 * angle_rad
    return np.concatenate(([np.cos(half)], np.sin(half) * a))


def from_rotation_matrix(R: np.ndarray) -> np.ndarray:
    """Unit quaternion (w >= 0) with ``rotation_matrix(q) == R`` (Shepperd's method)."""
    R = np.asarray(R, dtype=float)
    tr = R[0, 0] + R[1, 1] + R[2, 2]
    cands = np.array([tr, R[0, 0], R[1, 1], R[2, 2]])
    i = int(np.argmax(cands))
    if i == 0:
        w = 0.5 * np.sqrt(1.0 + tr)
        q = np.array(
            [w, (R[2, 1] - R[1, 2]) / (4 * w), (R[0, 2] - R[2, 0]) / (4 * w), (R[1, 0] - R[0, 1]) / (4 * w)]
        )
    elif i == 1:
        x = 0.5 * np.sqrt(1.0 + 2 * R[0, 0] - tr)
        q = np.array(
            [(R[2, 1] - R[1, 2]) / (4 * x), x, (R[0, 1] + R[1, 0]) / (4 * x), (R[0, 2] + R[2, 0]) / (4 * x)]
        )
    elif i == 2:
        y = 0.5 * np.sqrt(1.0 + 2 * R[1, 1] - tr)
        q = np.array(
            [(R[0, 2] - R[2, 0]) / (4 * y), (R[0, 1] + R[1, 0]) / (4 * y), y, (R[1, 2] + R[2, 1]) / (4 * y)]
        )
    else:
        z = 0.5 * np.sqrt(1.0 + 2 * R[2, 2] - tr)
        q = np.array(
            [(R[1, 0] - R[0, 1]) / (4 * z), (R[0, 2] + R[2, 0]) / (4 * z), (R[1, 2] + R[2, 1]) / (4 * z), z]
        )
    return q if q[0] >= 0 else -q
