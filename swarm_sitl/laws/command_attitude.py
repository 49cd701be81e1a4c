"""Command attitude from the command force (Lemma 3.3, docs/paper.md erratum 1), and its rate and
acceleration.

Hamilton convention, body FLU -> world ENU: ``R(Q_c) e3 = u / |u|`` with minimal rotation from e3::

    sigma_c = sqrt(1/2 + u_z / (2 |u|)),   q_c = [-u_y, u_x, 0] / (2 |u| sigma_c)

Singular only on ``u = [0, 0, u_z]`` with ``u_z <= 0``. ``omega_c = 2 vec(conj(Q_c) (x) Qdot_c)`` and
``omegadot_c = 2 vec(conj(Q_c) (x) Qddot_c)``, where ``Qdot_c`` and ``Qddot_c`` follow from ``u_dot``
and ``u_ddot`` exactly, by propagating second-order jets (value, first, second time derivative)
through each elementary operation.
"""

import numpy as np

from sim_vehicles.common.jit import kernel
from sim_vehicles.common.quaternion import dot3, qconj, qmul


class SingularCommandError(ValueError):
    """The command force points straight down (or is zero): no attitude can produce it."""


#: how close to the singular set a command may come, as ``1 + u_z/|u|`` (and ``|u|`` in m/s^2)
SINGULAR_TOLERANCE = 1e-12


@kernel
def _jet_sqrt(a0, a1, a2):
    s0 = np.sqrt(a0)
    s1 = a1 / (2.0 * s0)
    s2 = (a2 - 2.0 * s1 * s1) / (2.0 * s0)
    return s0, s1, s2


@kernel
def _jet_div(a0, a1, a2, b0, b1, b2):
    c0 = a0 / b0
    c1 = (a1 - c0 * b1) / b0
    c2 = (a2 - 2.0 * c1 * b1 - c0 * b2) / b0
    return c0, c1, c2


@kernel
def is_singular(u):
    n = np.sqrt(u[0] * u[0] + u[1] * u[1] + u[2] * u[2])
    return n < SINGULAR_TOLERANCE or 1.0 + u[2] / n < SINGULAR_TOLERANCE


@kernel
def command_attitude_kernel(u, u_dot, u_ddot):
    """``(q_c, omega_c, omegadot_c)``; the caller checks ``is_singular(u)`` first."""
    n0, n1, n2 = _jet_sqrt(dot3(u, u), 2.0 * dot3(u, u_dot), 2.0 * (dot3(u_dot, u_dot) + dot3(u, u_ddot)))
    c0, c1, c2 = _jet_div(u[2], u_dot[2], u_ddot[2], n0, n1, n2)
    s0, s1, s2 = _jet_sqrt(0.5 * (1.0 + c0), 0.5 * c1, 0.5 * c2)
    d0, d1, d2 = 2.0 * n0 * s0, 2.0 * (n1 * s0 + n0 * s1), 2.0 * (n2 * s0 + 2.0 * n1 * s1 + n0 * s2)
    x0, x1, x2 = _jet_div(-u[1], -u_dot[1], -u_ddot[1], d0, d1, d2)
    y0, y1, y2 = _jet_div(u[0], u_dot[0], u_ddot[0], d0, d1, d2)
    Q = np.array([s0, x0, y0, 0.0])
    Qd = np.array([s1, x1, y1, 0.0])
    Qdd = np.array([s2, x2, y2, 0.0])
    Qc = qconj(Q)
    omega = 2.0 * qmul(Qc, Qd)[1:4]
    omega_dot = 2.0 * qmul(Qc, Qdd)[1:4]
    return Q, omega, omega_dot


def command_attitude(
    u: np.ndarray, u_dot: np.ndarray | None = None, u_ddot: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(q_c, omega_c [rad/s; command body], omegadot_c [rad/s^2])`` for a command force ``u``.

    Raises ``SingularCommandError`` on the singular set ``u = [0, 0, u_z], u_z <= 0``.
    """
    u = np.asarray(u, dtype=float)
    if is_singular(u):
        raise SingularCommandError(
            f"command force {u.tolist()} points straight down or is zero: no attitude gives R(Q_c) e3 = u/|u|"
        )
    z = np.zeros(3)
    ud = z if u_dot is None else np.asarray(u_dot, dtype=float)
    udd = z if u_ddot is None else np.asarray(u_ddot, dtype=float)
    q, w, wd = command_attitude_kernel(u, ud, udd)
    return q, w, wd
