"""Leader trajectories: analytic derivatives up to the fourth against central differences."""

import numpy as np
import pytest

from swarm_sitl.trajectories import FigureEight, Helix, Line

pytestmark = pytest.mark.unit
TRAJS = [
    Helix(5.0, 0.2, 1.0),
    Helix(2.0, -0.7, 0.0, (1, 2, 3), 0.4),
    FigureEight(4.0, 2.0, 0.3, (0, 0, 5)),
    Line((1.0, 2.0, 3.0), (0.5, -1.0, 0.2)),
]


@pytest.mark.parametrize("traj", TRAJS, ids=lambda t: type(t).__name__)
def test_each_derivative_is_the_derivative_of_the_previous(traj):
    h = 1e-4
    for t in (0.0, 1.3, 17.2):
        d, dp, dm = traj.derivatives(t), traj.derivatives(t + h), traj.derivatives(t - h)
        for n in range(4):
            np.testing.assert_allclose(
                (dp[n] - dm[n]) / (2 * h), d[n + 1], atol=1e-6 * (1 + np.abs(d[n + 1]).max())
            )


@pytest.mark.parametrize("traj", TRAJS, ids=lambda t: type(t).__name__)
def test_scalar_and_vector_evaluation_agree(traj):
    ts = np.array([0.0, 0.5, 3.0])
    vec = traj.derivatives(ts)
    for i, t in enumerate(ts):
        np.testing.assert_allclose(traj.derivatives(float(t)), vec[i], rtol=1e-14, atol=1e-14)


def test_paper_helix():
    d = Helix(5.0, 0.2, 1.0).derivatives(0.0)
    np.testing.assert_allclose(d[0], [5, 0, 0], atol=1e-15)
    np.testing.assert_allclose(d[1], [0, 1, 1], atol=1e-15)


def test_n_p_is_minus_l_a_jerk_minus_snap_by_finite_differences_of_the_acceleration():
    """N_p as derived (NOTES.md item 8: -l_a p_r^(3) - p_r^(4), the paper prints +l_a), against
    central differences of the trajectory's own acceleration, not its derivative formulas."""
    from swarm_sitl.trajectories import N_p

    l_a, h = 12.0, 1e-3
    for traj in (Helix(5.0, 0.2, 1.0), FigureEight(6.0, 3.0, 0.4), Helix(2.0, -1.3, 0.0, phase_rad=0.7)):
        for t in (0.3, 1.7, 4.2):
            before, at, after = (traj.derivatives(s)[2] for s in (t - h, t, t + h))
            jerk = (after - before) / (2 * h)
            snap = (after - 2 * at + before) / h**2
            np.testing.assert_allclose(
                N_p(traj, l_a, t), -l_a * jerk - snap, atol=1e-4 * (1 + np.abs(jerk).max())
            )


def test_sup_n_p_of_the_helix_is_its_closed_form_for_all_time():
    """Helix: p''' = R w^3 [sin, -cos, 0] and p'''' = R w^4 [cos, sin, 0] are orthogonal, so
    |N_p| = R |w|^3 sqrt(l_a^2 + w^2) at every instant."""
    from swarm_sitl.trajectories import sup_Np

    for R, w, l_a in ((5.0, 0.2, 12.0), (3.0, -0.9, 4.0), (0.5, 2.0, 30.0)):
        expected = R * abs(w) ** 3 * np.sqrt(l_a**2 + w**2)
        assert sup_Np(Helix(R, w, 1.0), l_a, horizon_s=0.1) == pytest.approx(expected, rel=1e-12)


def test_sup_n_p_of_the_figure_eight_matches_its_closed_form_components():
    """Figure eight x = A sin(w t), y = B sin(2 w t): N_p = [A w^3 (l_a cos wt - w sin wt),
    8 B w^3 (l_a cos 2wt - 2 w sin 2wt), 0], written out here; its sup over a period taken on a grid
    of 2 million points, and the sup does not depend on the horizon asked for (a full period is)."""
    from swarm_sitl.trajectories import sup_Np

    A, B, w, l_a = 6.0, 3.0, 0.4, 12.0
    t = np.linspace(0.0, 2 * np.pi / w, 2_000_001)
    nx = A * w**3 * (l_a * np.cos(w * t) - w * np.sin(w * t))
    ny = 8 * B * w**3 * (l_a * np.cos(2 * w * t) - 2 * w * np.sin(2 * w * t))
    expected = float(np.max(np.hypot(nx, ny)))
    for horizon in (1.0, 60.0, 1000.0):
        assert sup_Np(FigureEight(A, B, w), l_a, horizon_s=horizon) == pytest.approx(expected, rel=1e-9)
    # with the printed sign the sup is the same on this curve (NOTES.md item 8): the fix changes
    # no shipped verdict, only a user's trajectory's
    printed = np.hypot(
        -A * w**3 * (l_a * np.cos(w * t) + w * np.sin(w * t)),
        -8 * B * w**3 * (l_a * np.cos(2 * w * t) + 2 * w * np.sin(2 * w * t)),
    )
    assert float(np.max(printed)) == pytest.approx(expected, rel=1e-6)
