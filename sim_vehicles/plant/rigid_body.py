"""The paper's 6-DOF VTOL rigid body (eqs. 2-5) and its fixed-step integrator.

State ``x``: position, velocity, attitude and body rates (layout in ``common.state``).

Dynamics: ``pdot = v``, ``vdot = -g e3 + (T/m) R(Q) e3``, ``Qdot = 0.5 Q (x) [0, omega]``,
``J omegadot = -omega x J omega + tau``.
"""

import numpy as np

from sim_vehicles.common.jit import kernel
from sim_vehicles.common.quaternion import body_z_axis, quaternion_rate
from sim_vehicles.common.state import POS, QUAT, RATE, RATE0, STATE_SIZE, VEL, VEL0


@kernel
def derivative(x, thrust_N, torque_B, mass_kg, inertia_kgm2, g_mps2):
    """``xdot`` of the rigid body for a thrust [N, along body z] and a torque [N m; body]."""
    dx = np.empty(STATE_SIZE)
    q = x[QUAT]
    w = x[RATE]
    dx[POS] = x[VEL]
    zb = body_z_axis(q)
    a = thrust_N / mass_kg
    dx[VEL0] = a * zb[0]
    dx[VEL0 + 1] = a * zb[1]
    dx[VEL0 + 2] = a * zb[2] - g_mps2
    dx[QUAT] = quaternion_rate(q, w)
    Jw0 = inertia_kgm2[0] * w[0]
    Jw1 = inertia_kgm2[1] * w[1]
    Jw2 = inertia_kgm2[2] * w[2]
    # -omega x (J omega) + tau, divided by the diagonal inertia
    dx[RATE0] = (-(w[1] * Jw2 - w[2] * Jw1) + torque_B[0]) / inertia_kgm2[0]
    dx[RATE0 + 1] = (-(w[2] * Jw0 - w[0] * Jw2) + torque_B[1]) / inertia_kgm2[1]
    dx[RATE0 + 2] = (-(w[0] * Jw1 - w[1] * Jw0) + torque_B[2]) / inertia_kgm2[2]
    return dx


@kernel
def rk4_step(x, thrust_N, torque_B, mass_kg, inertia_kgm2, g_mps2, dt_s):
    """One classical RK4 step with thrust and torque held; the quaternion is renormalised."""
    k1 = derivative(x, thrust_N, torque_B, mass_kg, inertia_kgm2, g_mps2)
    k2 = derivative(x + 0.5 * dt_s * k1, thrust_N, torque_B, mass_kg, inertia_kgm2, g_mps2)
    k3 = derivative(x + 0.5 * dt_s * k2, thrust_N, torque_B, mass_kg, inertia_kgm2, g_mps2)
    k4 = derivative(x + dt_s * k3, thrust_N, torque_B, mass_kg, inertia_kgm2, g_mps2)
    xn = x + (dt_s / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    q = xn[QUAT]
    n = np.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    xn[QUAT] = q / n
    return xn


@kernel
def derivative_in_air(x, thrust_N, torque_B, mass_kg, inertia_kgm2, g_mps2, drag_Ns2pm2, wind_W):
    """``derivative`` plus quadratic drag in a wind: ``-drag |v - w| (v - w) / m`` on the
    acceleration (``plant.wind``)."""
    dx = derivative(x, thrust_N, torque_B, mass_kg, inertia_kgm2, g_mps2)
    r0 = x[VEL0] - wind_W[0]
    r1 = x[VEL0 + 1] - wind_W[1]
    r2 = x[VEL0 + 2] - wind_W[2]
    c = drag_Ns2pm2 * np.sqrt(r0 * r0 + r1 * r1 + r2 * r2) / mass_kg
    dx[VEL0] -= c * r0
    dx[VEL0 + 1] -= c * r1
    dx[VEL0 + 2] -= c * r2
    return dx


@kernel
def rk4_step_in_air(x, thrust_N, torque_B, mass_kg, inertia_kgm2, g_mps2, dt_s, drag_Ns2pm2, wind_W):
    """``rk4_step`` with the drag of ``derivative_in_air`` (the wind held over the step)."""
    a = (thrust_N, torque_B, mass_kg, inertia_kgm2, g_mps2, drag_Ns2pm2, wind_W)
    k1 = derivative_in_air(x, *a)
    k2 = derivative_in_air(x + 0.5 * dt_s * k1, *a)
    k3 = derivative_in_air(x + 0.5 * dt_s * k2, *a)
    k4 = derivative_in_air(x + dt_s * k3, *a)
    xn = x + (dt_s / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    q = xn[QUAT]
    n = np.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    xn[QUAT] = q / n
    return xn
