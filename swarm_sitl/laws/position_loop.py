"""Command force with the saturated auxiliary system (section 3.3), thrust, and the derivatives of u.

    u         = g e3 + a_hat - k_eta (tanh(eta + eta_dot) + tanh(eta_dot))
    eta_ddot  = -k_eta (tanh(eta + eta_dot) + tanh(eta_dot)) + l_p p_tilde + l_v v_tilde
    T         = m |u|

with ``p_tilde = p - p_hat - delta - eta`` and ``v_tilde = v - v_hat - eta_dot``. The derivatives
(section 3.4, with docs/paper.md erratum 3 for Dbar and Sbar)::

    u_dot  = a_hat_dot - k_eta [D eta_dot + (D + S) eta_ddot]
    u_ddot = a_hat_ddot - k_eta [Dbar eta_dot + (Dbar + D + Sbar) eta_ddot + (D + S) eta_dddot]
    D = diag(1 - tanh^2(eta + eta_dot)),  S = diag(1 - tanh^2(eta_dot))
    Dbar = dD/dt = -2 tanh(eta+eta_dot)(1 - tanh^2(eta+eta_dot))(eta_dot + eta_ddot)
    Sbar = dS/dt = -2 tanh(eta_dot)(1 - tanh^2(eta_dot)) eta_ddot
    eta_dddot = -k_eta [D eta_dot + (D + S) eta_ddot] + l_p p_tilde_dot + l_v v_tilde_dot
"""

import numpy as np

from sim_vehicles.common.jit import kernel


@kernel
def command_force(a_hat, eta, eta_dot, k_eta, g_mps2):
    """``u`` [m/s^2; world ENU]."""
    u = a_hat - k_eta * (np.tanh(eta + eta_dot) + np.tanh(eta_dot))
    u[2] += g_mps2
    return u


@kernel
def auxiliary_rhs(eta, eta_dot, p_tilde, v_tilde, k_eta, l_p, l_v):
    """``eta_ddot`` of the auxiliary system."""
    out = np.empty(3)
    for c in range(3):
        out[c] = (
            -k_eta * (np.tanh(eta[c] + eta_dot[c]) + np.tanh(eta_dot[c]))
            + l_p * p_tilde[c]
            + l_v * v_tilde[c]
        )
    return out


@kernel
def saturation_rates(eta, eta_dot, eta_ddot):
    """``(D, S, Dbar, Sbar)`` as vectors (the diagonals)."""
    t1 = np.tanh(eta + eta_dot)
    t2 = np.tanh(eta_dot)
    D = 1.0 - t1 * t1
    S = 1.0 - t2 * t2
    Dbar = -2.0 * t1 * D * (eta_dot + eta_ddot)
    Sbar = -2.0 * t2 * S * eta_ddot
    return D, S, Dbar, Sbar


@kernel
def auxiliary_jerk(eta, eta_dot, eta_ddot, p_tilde_dot, v_tilde_dot, k_eta, l_p, l_v):
    """``eta_dddot``."""
    D, S, _, _ = saturation_rates(eta, eta_dot, eta_ddot)
    return -k_eta * (D * eta_dot + (D + S) * eta_ddot) + l_p * p_tilde_dot + l_v * v_tilde_dot


@kernel
def command_force_derivatives(a_hat_dot, a_hat_ddot, eta, eta_dot, eta_ddot, eta_dddot, k_eta):
    """``(u_dot, u_ddot)``."""
    D, S, Dbar, Sbar = saturation_rates(eta, eta_dot, eta_ddot)
    u_dot = a_hat_dot - k_eta * (D * eta_dot + (D + S) * eta_ddot)
    u_ddot = a_hat_ddot - k_eta * (Dbar * eta_dot + (Dbar + D + Sbar) * eta_ddot + (D + S) * eta_dddot)
    return u_dot, u_ddot
