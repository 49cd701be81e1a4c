"""The paper's 6-DOF VTOL rigid body (eqs. 2-5) and its fixed-step integrator.

State vector layout (13 floats), the only place it is defined:

- ``x[POS]``  position ``p_W`` [m; world ENU]
- ``x[VEL]``  velocity ``v_W`` [m/s; world ENU]
- ``x[QUAT]`` attitude ``q_WB`` [Hamilton w,x,y,z; body FLU -> world ENU]
- ``x[RATE]`` body rates ``omega_B`` [rad/s; body FLU]

Dynamics: ``pdot = v``, ``vdot = -g e3 + (T/m) R(Q) e3``, ``Qdot = 0.5 Q (x) [0, omega]``,
``J omegadot = -omega x J omega + tau``.
"""

import numpy as np

from sim_vehicles.common.jit import kernel
from sim_vehicles.common.quaternion import body_z_axis, quaternion_rate

STATE_SIZE = 13
POS = slice(0, 3)
VEL = slice(3, 6)
QUAT = slice(6, 10)
RATE = slice(10, 13)


def make_state(
    position_m, velocity_mps=(0.0, 0.0, 0.0), q_wb=(1.0, 0.0, 0.0, 0.0), omega_radps=(0.0, 0.0, 0.0)
) -> np.ndarray:
    """Assemble a state vector from named parts."""
    x = np.empty(STATE_SIZE)
    x[POS] = position_m
    x[VEL] = velocity_mps
    x[QUAT] = q_wb
    x[RATE] = omega_radps
    return x


@kernel
def derivative(x, thrust_N, torque_B, mass_kg, inertia_kgm2, g_mps2):
    """``xdot`` of the rigid body for a thrust [N, along body z] and a torque [N m; body]."""
    dx = np.empty(13)
    q = x[6:10]
    w = x[10:13]
    dx[0:3] = x[3:6]
    zb = body_z_axis(q)
    a = thrust_N / mass_kg
    dx[3] = a * zb[0]
    dx[4] = a * zb[1]
    dx[5] = a * zb[2] - g_mps2
    dx[6:10] = quaternion_rate(q, w)
    Jw0 = inertia_kgm2[0] * w[0]
    Jw1 = inertia_kgm2[1] * w[1]
    Jw2 = inertia_kgm2[2] * w[2]
    # -omega x (J omega) + tau, divided by the diagonal inertia
    dx[10] = (-(w[1] * Jw2 - w[2] * Jw1) + torque_B[0]) / inertia_kgm2[0]
    dx[11] = (-(w[2] * Jw0 - w[0] * Jw2) + torque_B[1]) / inertia_kgm2[1]
    dx[12] = (-(w[0] * Jw1 - w[1] * Jw0) + torque_B[2]) / inertia_kgm2[2]
    return dx


@kernel
def rk4_step(x, thrust_N, torque_B, mass_kg, inertia_kgm2, g_mps2, dt_s):
    """One classical RK4 step with thrust and torque held; the quaternion is renormalised."""
    k1 = derivative(x, thrust_N, torque_B, mass_kg, inertia_kgm2, g_mps2)
    k2 = derivative(x + 0.5 * dt_s * k1, thrust_N, torque_B, mass_kg, inertia_kgm2, g_mps2)
    k3 = derivative(x + 0.5 * dt_s * k2, thrust_N, torque_B, mass_kg, inertia_kgm2, g_mps2)
    k4 = derivative(x + dt_s * k3, thrust_N, torque_B, mass_kg, inertia_kgm2, g_mps2)
    xn = x + (dt_s / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    q = xn[6:10]
    n = np.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    xn[6:10] = q / n
    return xn
