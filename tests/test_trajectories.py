"""Leader trajectories: analytic derivatives up to the fourth against central differences."""

import numpy as np
import pytest

from swarm_sitl.laws.trajectories import FigureEight, Helix, Line

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
    """N_p as derived (docs/paper.md, erratum 8: -l_a p_r^(3) - p_r^(4), the paper prints +l_a), against
    central differences of the trajectory's own acceleration, not its derivative formulas."""
    from swarm_sitl.laws.trajectories import N_p

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
    from swarm_sitl.laws.trajectories import sup_Np

    for R, w, l_a in ((5.0, 0.2, 12.0), (3.0, -0.9, 4.0), (0.5, 2.0, 30.0)):
        expected = R * abs(w) ** 3 * np.sqrt(l_a**2 + w**2)
        assert sup_Np(Helix(R, w, 1.0), l_a, horizon_s=0.1) == pytest.approx(expected, rel=1e-12)


def test_sup_n_p_of_the_figure_eight_matches_its_closed_form_components():
    """Figure eight x = A sin(w t), y = B sin(2 w t): N_p = [A w^3 (l_a cos wt - w sin wt),
    8 B w^3 (l_a cos 2wt - 2 w sin 2wt), 0], written out here; its sup over a period taken on a grid
    of 2 million points, and the sup does not depend on the horizon asked for (a full period is)."""
    from swarm_sitl.laws.trajectories import sup_Np

    A, B, w, l_a = 6.0, 3.0, 0.4, 12.0
    t = np.linspace(0.0, 2 * np.pi / w, 2_000_001)
    nx = A * w**3 * (l_a * np.cos(w * t) - w * np.sin(w * t))
    ny = 8 * B * w**3 * (l_a * np.cos(2 * w * t) - 2 * w * np.sin(2 * w * t))
    expected = float(np.max(np.hypot(nx, ny)))
    for horizon in (1.0, 60.0, 1000.0):
        assert sup_Np(FigureEight(A, B, w), l_a, horizon_s=horizon) == pytest.approx(expected, rel=1e-9)
    # with the printed sign the sup is the same on this curve (docs/paper.md, erratum 8): the fix changes
    # no shipped verdict, only a user's trajectory's
    printed = np.hypot(
        -A * w**3 * (l_a * np.cos(w * t) + w * np.sin(w * t)),
        -8 * B * w**3 * (l_a * np.cos(2 * w * t) + 2 * w * np.sin(2 * w * t)),
    )
    assert float(np.max(printed)) == pytest.approx(expected, rel=1e-6)


def test_positions_are_the_closed_forms_about_their_centres():
    """The derivatives' tests cannot see where a path is: its position, centre and phase included."""
    c = np.array([1.5, -2.0, 3.0])
    for t in (0.0, 0.7, 4.1):
        helix = Helix(2.0, -0.7, 0.3, tuple(c), 0.4).derivatives(t)
        th = -0.7 * t + 0.4
        np.testing.assert_allclose(
            helix[0], c + np.array([2.0 * np.cos(th), 2.0 * np.sin(th), 0.3 * t]), atol=1e-14
        )
        np.testing.assert_allclose(helix[1], [1.4 * np.sin(th), -1.4 * np.cos(th), 0.3], atol=1e-14)
        eight = FigureEight(4.0, 2.0, 0.3, tuple(c)).derivatives(t)
        np.testing.assert_allclose(
            eight[0], c + np.array([4.0 * np.sin(0.3 * t), 2.0 * np.sin(0.6 * t), 0.0]), atol=1e-14
        )
        np.testing.assert_allclose(eight[1], [1.2 * np.cos(0.3 * t), 1.2 * np.cos(0.6 * t), 0.0], atol=1e-14)
        line = Line(tuple(c), (0.5, -1.0, 0.2)).derivatives(t)
        np.testing.assert_allclose(
            line, [c + np.array([0.5, -1.0, 0.2]) * t, [0.5, -1.0, 0.2], *[[0, 0, 0]] * 3]
        )


def test_periods_and_suprema_of_the_shipped_kinds():
    from swarm_sitl.laws.trajectories import period_s, sup_norm, sup_Np

    assert period_s(Helix(1.0, 1.0, 0.0)) == pytest.approx(2 * np.pi, rel=1e-15)
    assert period_s(FigureEight(1.0, 1.0, -0.25)) == pytest.approx(8 * np.pi, rel=1e-15)
    assert period_s(Helix(1.0, 0.0, 1.0)) is None and period_s(Line((0, 0, 0), (1, 0, 0))) is None
    line = Line((1.0, 2.0, 3.0), (3.0, 0.0, 4.0))  # not periodic: taken over the horizon, exactly
    assert (
        sup_norm(line, 1, 50.0) == 5.0 and sup_norm(line, 2, 50.0) == 0.0 and sup_Np(line, 12.0, 50.0) == 0.0
    )
    assert sup_norm(line, 0, 10.0) == pytest.approx(np.linalg.norm([31.0, 2.0, 43.0]), rel=1e-15)


@pytest.mark.parametrize("peak_at", [0.0, 0.003, 0.013, 0.5, 0.987, 0.997, 1.0])
def test_the_supremum_is_found_wherever_the_peak_lies_in_the_period(peak_at):
    """``_sup`` over one period of a FigureEight (2 pi / w = 10 s) of a smooth bump whose peak
    sits at ``peak_at`` of the period (wrapped, as a periodic function's would): the grid's best
    point refined to the float's precision, the value at the peak."""
    from swarm_sitl.laws.trajectories import _sup

    traj = FigureEight(1.0, 1.0, 2 * np.pi / 10.0)
    t0 = 10.0 * peak_at

    def bump(t):
        d = (np.asarray(t) - t0 + 5.0) % 10.0 - 5.0  # periodic distance to the peak
        return np.stack([3.0 + np.cos(0.5 * d) * np.exp(-d * d), 0 * d, 0 * d], axis=-1)

    assert _sup(traj, bump, 99.0, 101) == pytest.approx(4.0, abs=1e-12)


def test_suprema_are_over_all_time_for_periodic_derivatives_and_over_the_horizon_for_position():
    from swarm_sitl.laws.trajectories import sup_norm

    eight = FigureEight(4.0, 2.0, 0.3)  # period 20.9 s; |a| is 0 at t = 0 and peaks later
    period = np.linspace(0.0, 2 * np.pi / 0.3, 2_000_001)
    a_max = np.linalg.norm(eight.derivatives(period)[:, 2], axis=1).max()
    assert sup_norm(eight, 2, 0.5) == pytest.approx(a_max, rel=1e-9)  # over all time, not 0.5 s
    t = np.linspace(0.0, 3.0, 300001)
    p = np.linalg.norm(eight.derivatives(t)[:, 0], axis=1)  # position: over [0, 3 s] only
    assert sup_norm(eight, 0, 3.0) == pytest.approx(p.max(), rel=1e-9)
    assert sup_norm(eight, 0, 3.0) < 4.0  # the whole period would reach further
