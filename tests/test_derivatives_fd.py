"""u_dot, u_ddot, omega_c and omegadot_c against central finite differences along a trajectory.

One follower hears the leader directly; both the leader's message and the follower's vehicle are
smooth prescribed inputs, and the controller state (estimator + auxiliary system) is integrated
with RK4 at 1e-4 s. The sign term is taken with a boundary layer wide enough that S stays inside it
(asserted): the paper's sgn(S) switches within milliseconds, and no finite difference is meaningful
across a switch; the derivative formulas take gamma_ddot from the estimator whatever its sign term.
The analytic derivatives from ``controller_output`` must match fourth-order
central differences of the recorded u and Q_c to a relative 1e-5. This is what catches docs/paper.md
errors 2 (Gamma with tanh(gamma_dot)) and 3 (Dbar, Sbar): with either, u_ddot is off by far more.
"""

import numpy as np
import pytest

from sim_vehicles.common.quaternion import qconj, qmul
from swarm_sitl.laws.contract import reference_values
from swarm_sitl.laws.estimator import acceleration_estimate
from swarm_sitl.laws.follower_law import (
    HOLD_EXTRAPOLATE,
    OUT_OMEGA_C,
    OUT_OMEGADOT_C,
    OUT_Q_C,
    OUT_U,
    OUT_U_DDOT,
    OUT_U_DOT,
    ControlGains,
    controller_advance,
    controller_output,
    neighbours_at,
)
from swarm_sitl.laws.position_loop import command_force
from swarm_sitl.laws.trajectories import Helix

#: one worker runs them all: their trajectory (a module fixture) calls kernels a flight calls only
#: inside its tick (``controller_output``, ``acceleration_estimate``), which a fresh machine compiles
#: once for them (7 s of CPU), not once per worker at once. The gains are floats, as a config's are:
#: integers were another signature, compiled again (7 s more)
pytestmark = [pytest.mark.unit, pytest.mark.xdist_group("derivatives_fd")]

PHI = 20.0
GAINS = ControlGains(
    k_gamma=0.5,
    k_p=8.0,
    k_v=8.0,
    l_a=12.0,
    k_a=4.0,
    l_p=4.0,
    l_v=4.0,
    k_eta=4.0,
    sign_boundary_layer=PHI,
    bracket_a_weight=12.0,
    mass_kg=0.85,
    g_mps2=9.81,
)
OFFSET = np.array([2.0, 2.0, 0.0])
H_INT = 1e-4
H_FD = 1e-3
STRIDE = round(H_FD / H_INT)


def _d1(f):  # 5-point central first derivative, samples at -2h..2h
    return (f[0] - 8 * f[1] + 8 * f[3] - f[4]) / (12 * H_FD)


def _d2(f):
    return (-f[0] + 16 * f[1] - 30 * f[2] + 16 * f[3] - f[4]) / (12 * H_FD**2)


def _rel(a, b):
    return np.linalg.norm(a - b) / np.linalg.norm(b)


@pytest.fixture(scope="module")
def trajectory():
    d = Helix(5.0, 0.2, 1.0).derivatives(0.0)
    msgs = np.array([[1.0, 0.0, *reference_values(d)]])  # the leader's message at t = 0
    veh_p, veh_v, veh_a = np.array([5.0, 3.0, -1.0]), np.array([0.5, -0.3, 0.2]), np.array([0.1, 0.2, -0.3])
    x = np.zeros(18)
    x[6:9] = [0.3, -0.2, 0.1]  # start gamma off zero so a_hat_ddot has every term
    xs = [x]
    n = round(2.0 / H_INT)
    for k in range(n):
        x = controller_advance(
            x, k * H_INT, H_INT, 1, msgs, HOLD_EXTRAPOLATE, 0.0, veh_p, veh_v, veh_a, OFFSET, GAINS
        )
        xs.append(x)
    return np.array(xs), msgs, (veh_p, veh_v, veh_a)


def _outputs(xs, msgs, veh, idx):
    p0, v0, a0 = veh
    outs = []
    for j in idx:
        t = j * H_INT
        p, v = p0 + v0 * t + 0.5 * a0 * t * t, v0 + a0 * t
        outs.append(
            controller_output(
                xs[j], t, msgs, HOLD_EXTRAPOLATE, p, v, np.array([1.0, 0, 0, 0]), a0, True, OFFSET, GAINS
            )
        )
    return np.array(outs)


def _max_abs_S(xs, msgs, j0, j1):
    """max |S| over every integration step in [j0, j1]."""
    worst = 0.0
    for j in range(j0, j1 + 1):
        nb = neighbours_at(msgs, j * H_INT, HOLD_EXTRAPOLATE)
        a, ad = acceleration_estimate(xs[j][6:9], xs[j][9:12], GAINS.k_gamma)
        worst = max(worst, np.abs((a - nb[0, 7:10]) + (ad - nb[0, 10:13])).max())
    return worst


@pytest.mark.parametrize("t_check", [0.25, 0.6, 1.1, 1.7])
def test_analytic_derivatives_match_finite_differences(trajectory, t_check):
    xs, msgs, veh = trajectory
    jc = round(t_check / H_INT)
    idx = [jc + m * STRIDE for m in (-2, -1, 0, 1, 2)]
    assert _max_abs_S(xs, msgs, idx[0], idx[-1]) < PHI, "S left the boundary layer: the input is not smooth"
    out = _outputs(xs, msgs, veh, idx)
    u = np.array(
        [
            command_force(
                acceleration_estimate(x[6:9], x[9:12], GAINS.k_gamma)[0],
                x[12:15],
                x[15:18],
                GAINS.k_eta,
                GAINS.g_mps2,
            )
            for x in xs[idx]
        ]
    )
    np.testing.assert_allclose(out[:, OUT_U], u, atol=1e-14)
    c = out[2]
    assert _rel(_d1(u), c[OUT_U_DOT]) < 1e-5
    assert _rel(_d2(u), c[OUT_U_DDOT]) < 1e-5
    q = out[:, OUT_Q_C]
    qdot = _d1(q)
    omega_fd = 2 * qmul(qconj(q[2]), qdot)[1:]
    assert _rel(omega_fd, c[OUT_OMEGA_C]) < 1e-5
    assert _rel(_d1(out[:, OUT_OMEGA_C]), c[OUT_OMEGADOT_C]) < 1e-5
    # the check is not vacuous: the derivatives are of a size finite differences can resolve
    assert np.linalg.norm(c[OUT_U_DDOT]) > 1e-2 and np.linalg.norm(c[OUT_OMEGA_C]) > 1e-3


def test_printed_gamma_would_break_the_acceleration_error_dynamics(trajectory):
    """docs/paper.md, erratum 2: a_hat_ddot = -l_a a_hat_dot - k_a (S + sat(S)) holds with tanh(gamma) only
    (S with the bracket's weight l_a on its first sum: the default sliding-surface form)."""
    xs, msgs, _ = trajectory
    j = round(0.6 / H_INT)
    idx = [j + m * STRIDE for m in (-2, -1, 0, 1, 2)]
    a_hat = np.array([acceleration_estimate(x[6:9], x[9:12], GAINS.k_gamma)[0] for x in xs[idx]])
    x = xs[j]
    nb = neighbours_at(msgs, j * H_INT, HOLD_EXTRAPOLATE)
    a, ad = acceleration_estimate(x[6:9], x[9:12], GAINS.k_gamma)
    S = GAINS.bracket_a_weight * (a - nb[0, 7:10]) + (ad - nb[0, 10:13])
    expected = -GAINS.l_a * ad - GAINS.k_a * (S + np.clip(S / PHI, -1, 1))
    assert _rel(_d2(a_hat), expected) < 1e-5
    # the printed Gamma (tanh(gamma_dot) gamma_dot) in the same gamma_ddot gives a different a_hat_ddot
    g, gd = x[6:9], x[9:12]
    th = np.tanh(g)
    gdd_printed = (
        -GAINS.l_a * gd
        + 2 * np.tanh(gd) * gd * gd
        - GAINS.k_a / GAINS.k_gamma * (S + np.clip(S / PHI, -1, 1)) / (1 - th**2)
    )
    a_ddot_printed = GAINS.k_gamma * (1 - th**2) * (gdd_printed - 2 * th * gd * gd)
    assert _rel(a_ddot_printed, expected) > 1e-3
