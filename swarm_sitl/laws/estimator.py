"""The paper's distributed estimator of the leader's state (eq. estimator), with docs/paper.md errata 2 and 7.

State of follower i (12 floats): ``[p_hat(3), v_hat(3), gamma(3), gamma_dot(3)]``, with
``a_hat = k_gamma tanh(gamma)`` and ``a_hat_dot = k_gamma Gammabar gamma_dot``,
``Gammabar = diag(1 - tanh^2(gamma))``, ``Gamma = diag(tanh(gamma) * gamma_dot)`` (not
``tanh(gamma_dot)``: only this makes ``a_hat_ddot`` follow the printed error dynamics)::

    p_hat_dot   = v_hat - k_p sum_j d_ij (p_hat_i - p_hat_j)
    v_hat_dot   = a_hat - k_v sum_j d_ij (v_hat_i - v_hat_j)
    gamma_ddot  = -l_a gamma_dot + 2 Gamma gamma_dot - (k_a/k_gamma) Gammabar^-1 (S + sgn(S))
    S           = w_a sum_j d_ij (a_hat_i - a_hat_j) + sum_j d_ij (a_hat_dot_i - a_hat_dot_j)

The bracket's weight ``w_a`` (``bracket_a_weight``) is the one choice between the two forms:

- ``w_a = l_a``, the **sliding-surface** form (``estimator.bracket: sliding_surface``, the default):
  ``S`` is then row i of the proof's surface ``s = (M x I3)(l_a abar + abardot)`` and
  ``sdot = (M x I3)(-k_a s - k_a sgn(s) + 1 x N_p)`` holds exactly, so Theorem 1's ``k_a`` bound
  (``swarm-sitl check``) covers the law that runs (docs/paper.md, erratum 7);
- ``w_a = 1``, the bracket **as printed** (``estimator.bracket: printed``): equal to the other only
  when ``l_a = 1``; it converges in simulation, without the proof's guarantee.

Neighbour table (one row per in-neighbour, the leader included as node 0), columns
``NB_WEIGHT, NB_P, NB_V, NB_A, NB_ADOT``: its estimates at the evaluation time.

``sign_boundary_layer`` = 0 is the paper's ``sgn``. A value phi > 0 replaces ``sgn(S)`` by
``clip(S / phi, -1, 1)``: a documented, opt-in deviation against sampled-time chattering.
"""

import numpy as np

from sim_vehicles.common.jit import kernel

NB_WEIGHT = 0
NB_P = slice(1, 4)
NB_V = slice(4, 7)
NB_A = slice(7, 10)
NB_ADOT = slice(10, 13)
NB_COLS = 13

EST_SIZE = 12
EST_P = slice(0, 3)
EST_V = slice(3, 6)
EST_GAMMA = slice(6, 9)
EST_GAMMA_DOT = slice(9, 12)


@kernel
def acceleration_estimate(gamma, gamma_dot, k_gamma):
    """``(a_hat, a_hat_dot)`` from ``gamma`` and ``gamma_dot``."""
    th = np.tanh(gamma)
    return k_gamma * th, k_gamma * (1.0 - th * th) * gamma_dot


@kernel
def estimator_rhs(xe, nb, k_gamma, k_p, k_v, l_a, k_a, sign_boundary_layer, bracket_a_weight):
    """``(xe_dot, a_hat, a_hat_dot, gamma_ddot)`` of one follower's estimator; ``bracket_a_weight``
    is ``w_a`` above (``l_a``: sliding-surface form, 1: as printed)."""
    out = np.empty(12)
    a = np.empty(3)
    ad = np.empty(3)
    gdd = np.empty(3)
    for c in range(3):
        th = np.tanh(xe[6 + c])
        gbar = 1.0 - th * th
        gd = xe[9 + c]
        a[c] = k_gamma * th
        ad[c] = k_gamma * gbar * gd
        ep = 0.0
        ev = 0.0
        s = 0.0
        for r in range(nb.shape[0]):
            w = nb[r, 0]
            ep += w * (xe[c] - nb[r, 1 + c])
            ev += w * (xe[3 + c] - nb[r, 4 + c])
            s += bracket_a_weight * w * (a[c] - nb[r, 7 + c]) + w * (ad[c] - nb[r, 10 + c])
        sg = np.sign(s) if sign_boundary_layer <= 0.0 else min(max(s / sign_boundary_layer, -1.0), 1.0)
        gdd[c] = -l_a * gd + 2.0 * (th * gd) * gd - (k_a / k_gamma) * (s + sg) / gbar
        out[c] = xe[3 + c] - k_p * ep
        out[3 + c] = a[c] - k_v * ev
        out[6 + c] = gd
        out[9 + c] = gdd[c]
    return out, a, ad, gdd


@kernel
def acceleration_estimate_ddot(gamma, gamma_dot, gamma_ddot, k_gamma):
    """``a_hat_ddot = k_gamma Gammabar (gamma_ddot - 2 Gamma gamma_dot)``."""
    th = np.tanh(gamma)
    return k_gamma * (1.0 - th * th) * (gamma_ddot - 2.0 * th * gamma_dot * gamma_dot)
