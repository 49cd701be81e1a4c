"""The paper's applied torque (eq. torque), written in the Hamilton convention of docs/paper.md (erratum 4).

Attitude error ``Q_e = conj(Q_c) (x) Q``, ``omega_e = omega - R(Q_e)^T omega_c``,
sliding surface ``r = l_q q_e + omega_e`` and

    tau = -k_q r - (l_q/2) J (w_e I + q_e^x) omega_e + omega x J omega
          - J [ omega_e^x R(Q_e)^T omega_c - R(Q_e)^T omegadot_c ]

which gives ``J rdot = -k_q r`` exactly.
"""

import numpy as np

from sim_vehicles.common.jit import kernel
from sim_vehicles.common.quaternion import matTvec, qconj, qmul, rotation_matrix


@kernel
def attitude_error(q_WB, omega_B, q_c, omega_c):
    """``(Q_e, omega_e, R(Q_e))`` for the actual and commanded attitude and rates."""
    q_e = qmul(qconj(q_c), q_WB)
    R_e = rotation_matrix(q_e)
    omega_e = omega_B - matTvec(R_e, omega_c)
    return q_e, omega_e, R_e


@kernel
def torque(q_WB, omega_B, q_c, omega_c, omegadot_c, inertia_kgm2, l_q, k_q):
    """Applied torque ``tau`` [N m; body FLU] of the paper's attitude law.

    ``q_c`` is the command attitude, ``omega_c`` [rad/s; command body frame] and ``omegadot_c``
    [rad/s^2] its rate and rate derivative (zeros where unknown).
    """
    q_e, omega_e, R_e = attitude_error(q_WB, omega_B, q_c, omega_c)
    w_e = q_e[0]
    v_e = q_e[1:4]
    r = l_q * v_e + omega_e
    # (w_e I + q_e^x) omega_e
    m = w_e * omega_e + np.cross(v_e, omega_e)
    J = inertia_kgm2
    Jw = J * omega_B
    gyro = np.cross(omega_B, Jw)
    Rt_wc = matTvec(R_e, omega_c)
    ff = np.cross(omega_e, Rt_wc) - matTvec(R_e, omegadot_c)
    return -k_q * r - 0.5 * l_q * J * m + gyro - J * ff
