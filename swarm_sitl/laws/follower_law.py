"""One follower's position-level law, assembled from the estimator and the position loop.

Controller state (18 floats): ``[p_hat, v_hat, gamma, gamma_dot, eta, eta_dot]``.

Neighbour messages arrive as rows ``[weight, t_s, p_hat, v_hat, a_hat, a_hat_dot]`` (``MSG_COLS``),
valid at their own time ``t_s``. ``hold`` says how they are carried to the evaluation time ``t``:
``HOLD_ZERO_ORDER`` keeps them as they are, ``HOLD_EXTRAPOLATE`` advances them by their age
``t - t_s`` with their own derivatives (second order in p and v, first in a). The vehicle's own
position and velocity are carried the same way over a control period from the last sample.
"""

from typing import NamedTuple

import numpy as np

from sim_vehicles.common.jit import kernel
from sim_vehicles.common.quaternion import body_z_axis, dot3
from swarm_sitl.laws.command_attitude import command_attitude_kernel
from swarm_sitl.laws.estimator import acceleration_estimate_ddot, estimator_rhs
from swarm_sitl.laws.position_loop import (
    auxiliary_jerk,
    auxiliary_rhs,
    command_force,
    command_force_derivatives,
)

CTRL_SIZE = 18
CTRL_ETA = slice(12, 15)
CTRL_ETA_DOT = slice(15, 18)

MSG_WEIGHT = 0
MSG_T = 1
MSG_COLS = 14

HOLD_ZERO_ORDER = 0
HOLD_EXTRAPOLATE = 1

# layout of controller_output's result
OUT_U = slice(0, 3)
OUT_U_DOT = slice(3, 6)
OUT_U_DDOT = slice(6, 9)
OUT_THRUST = 9
OUT_Q_C = slice(10, 14)
OUT_OMEGA_C = slice(14, 17)
OUT_OMEGADOT_C = slice(17, 20)
OUT_A_HAT = slice(20, 23)
OUT_A_HAT_DOT = slice(23, 26)
OUT_ACC = slice(26, 29)
OUT_SIZE = 29


class ControlGains(NamedTuple):
    """Parameters of the estimator and the position loop (the paper's symbols)."""

    k_gamma: float
    k_p: float
    k_v: float
    l_a: float
    k_a: float
    l_p: float
    l_v: float
    k_eta: float
    sign_boundary_layer: float  #: 0 = the paper's sgn; > 0 = saturation width (deviation)
    #: weight of the acceleration sum in the estimator's bracket: l_a = the sliding-surface form
    #: Theorem 1 covers, 1 = the bracket as printed (estimator.py)
    bracket_a_weight: float
    mass_kg: float
    g_mps2: float


def gains_vector(gains: ControlGains) -> np.ndarray:
    """``controller_tick``'s form of the gains: an array in ``ControlGains`` field order. A call
    into compiled code types an array argument about four times faster than a named tuple."""
    return np.array(gains, dtype=float)


@kernel
def _gains_from(v):
    return ControlGains(v[0], v[1], v[2], v[3], v[4], v[5], v[6], v[7], v[8], v[9], v[10], v[11])


assert len(ControlGains._fields) == 12, "_gains_from reads every field of ControlGains"


@kernel
def neighbours_at(msgs, t, hold):
    """Neighbour table (estimator.NB_* layout) at time ``t`` from message rows."""
    n = msgs.shape[0]
    nb = np.empty((n, 13))
    for r in range(n):
        tau = t - msgs[r, 1] if hold == HOLD_EXTRAPOLATE else 0.0
        half_tau2 = 0.5 * tau * tau
        nb[r, 0] = msgs[r, 0]
        for c in range(3):
            p = msgs[r, 2 + c]
            v = msgs[r, 5 + c]
            a = msgs[r, 8 + c]
            ad = msgs[r, 11 + c]
            nb[r, 1 + c] = p + v * tau + a * half_tau2
            nb[r, 4 + c] = v + a * tau + ad * half_tau2
            nb[r, 7 + c] = a + ad * tau
            nb[r, 10 + c] = ad
    return nb


@kernel
def _estimator(xc, nb, gains):
    """``estimator_rhs`` of the controller state's estimator part, with ``gains``'."""
    return estimator_rhs(
        xc[0:12],
        nb,
        gains.k_gamma,
        gains.k_p,
        gains.k_v,
        gains.l_a,
        gains.k_a,
        gains.sign_boundary_layer,
        gains.bracket_a_weight,
    )


@kernel
def controller_rhs(xc, t, msgs, hold, veh_t, veh_p, veh_v, veh_a, offset, gains):
    """Time derivative of the controller state at ``t``."""
    nb = neighbours_at(msgs, t, hold)
    tau = t - veh_t if hold == HOLD_EXTRAPOLATE else 0.0
    out = np.empty(18)
    dxe, _, _, _ = _estimator(xc, nb, gains)
    out[0:12] = dxe
    p_tilde = np.empty(3)
    v_tilde = np.empty(3)
    for c in range(3):
        p = veh_p[c] + veh_v[c] * tau + 0.5 * veh_a[c] * tau * tau
        v = veh_v[c] + veh_a[c] * tau
        p_tilde[c] = p - xc[c] - offset[c] - xc[12 + c]
        v_tilde[c] = v - xc[3 + c] - xc[15 + c]
        out[12 + c] = xc[15 + c]
    out[15:18] = auxiliary_rhs(xc[12:15], xc[15:18], p_tilde, v_tilde, gains.k_eta, gains.l_p, gains.l_v)
    return out


@kernel
def controller_advance(xc, t0, dt, n_sub, msgs, hold, veh_t, veh_p, veh_v, veh_a, offset, gains):
    """Integrate the controller state over ``[t0, t0 + dt]`` in ``n_sub`` RK4 substeps."""
    h = dt / n_sub
    x = xc.copy()
    for i in range(n_sub):
        t = t0 + i * h
        k1 = controller_rhs(x, t, msgs, hold, veh_t, veh_p, veh_v, veh_a, offset, gains)
        k2 = controller_rhs(
            x + 0.5 * h * k1, t + 0.5 * h, msgs, hold, veh_t, veh_p, veh_v, veh_a, offset, gains
        )
        k3 = controller_rhs(
            x + 0.5 * h * k2, t + 0.5 * h, msgs, hold, veh_t, veh_p, veh_v, veh_a, offset, gains
        )
        k4 = controller_rhs(x + h * k3, t + h, msgs, hold, veh_t, veh_p, veh_v, veh_a, offset, gains)
        x = x + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    return x


@kernel
def controller_output(xc, t, msgs, hold, p, v, q_WB, a_given, use_a_given, offset, gains):
    """Command force, thrust, command attitude and its derivatives at ``t``.

    The follower's acceleration (needed by ``eta_dddot``) is ``-g e3 + |u| R(Q) e3`` unless
    ``use_a_given``, in which case ``a_given`` is used (for tests on prescribed trajectories).
    """
    nb = neighbours_at(msgs, t, hold)
    dxe, a_hat, a_hat_dot, gdd = _estimator(xc, nb, gains)
    eta = xc[12:15]
    eta_dot = xc[15:18]
    p_tilde = p - xc[0:3] - offset - eta
    v_tilde = v - xc[3:6] - eta_dot
    eta_ddot = auxiliary_rhs(eta, eta_dot, p_tilde, v_tilde, gains.k_eta, gains.l_p, gains.l_v)
    u = command_force(a_hat, eta, eta_dot, gains.k_eta, gains.g_mps2)
    un = np.sqrt(dot3(u, u))
    if use_a_given:
        acc = a_given.copy()
    else:
        acc = un * body_z_axis(q_WB)
        acc[2] -= gains.g_mps2
    p_tilde_dot = v - dxe[0:3] - eta_dot
    v_tilde_dot = acc - dxe[3:6] - eta_ddot
    eta_dddot = auxiliary_jerk(
        eta, eta_dot, eta_ddot, p_tilde_dot, v_tilde_dot, gains.k_eta, gains.l_p, gains.l_v
    )
    a_hat_ddot = acceleration_estimate_ddot(xc[6:9], xc[9:12], gdd, gains.k_gamma)
    u_dot, u_ddot = command_force_derivatives(
        a_hat_dot, a_hat_ddot, eta, eta_dot, eta_ddot, eta_dddot, gains.k_eta
    )
    q_c, w_c, wd_c = command_attitude_kernel(u, u_dot, u_ddot)
    out = np.empty(29)
    out[0:3] = u
    out[3:6] = u_dot
    out[6:9] = u_ddot
    out[9] = gains.mass_kg * un
    out[10:14] = q_c
    out[14:17] = w_c
    out[17:20] = wd_c
    out[20:23] = a_hat
    out[23:26] = a_hat_dot
    out[26:29] = acc
    return out


TICK_STATE = slice(0, CTRL_SIZE)
TICK_OUT = slice(CTRL_SIZE, CTRL_SIZE + OUT_SIZE)
TICK_ACC = slice(CTRL_SIZE + OUT_SIZE, CTRL_SIZE + OUT_SIZE + 3)
TICK_FINITE = CTRL_SIZE + OUT_SIZE + 3  #: 1.0 if every output is finite, else 0.0
TICK_SIZE = TICK_FINITE + 1


@kernel
def controller_tick(
    xc,
    t_prev,
    t,
    n_sub,
    msgs,
    hold,
    veh_t,
    veh_p,
    veh_v,
    veh_a,
    p,
    v,
    q_WB,
    age,
    offset,
    gains_v,
    max_thrust_N,
):
    """One control tick in one call: ``controller_advance`` from ``t_prev`` to ``t`` (none if
    ``n_sub`` is 0), ``controller_output`` at ``t`` for the sample ``(p, v, q_WB)`` carried by
    ``age`` under ``veh_a`` (0: taken at ``t``), and the acceleration the command gives once the
    thrust is limited to ``max_thrust_N``. Returns ``[state | output | acceleration | finite]``
    (``TICK_*``): one call and one array per tick, where a loaded machine charges per call.
    ``gains_v`` is ``gains_vector(gains)``."""
    gains = _gains_from(gains_v)
    res = np.empty(TICK_SIZE)
    if n_sub > 0:
        dt = t - t_prev
        x = controller_advance(xc, t_prev, dt, n_sub, msgs, hold, veh_t, veh_p, veh_v, veh_a, offset, gains)
    else:
        x = xc  # copied into the result below, never written
    if age > 0.0:
        p = p + v * age + 0.5 * veh_a * age * age
        v = v + veh_a * age
    out = controller_output(x, t, msgs, hold, p, v, q_WB, veh_a, False, offset, gains)
    applied = min(out[OUT_THRUST], max_thrust_N)
    acc = (applied / gains.mass_kg) * body_z_axis(q_WB)
    acc[2] -= gains.g_mps2
    res[0:CTRL_SIZE] = x
    res[CTRL_SIZE : CTRL_SIZE + OUT_SIZE] = out
    res[CTRL_SIZE + OUT_SIZE : TICK_FINITE] = acc
    res[TICK_FINITE] = 1.0 if np.isfinite(out).all() else 0.0
    return res
