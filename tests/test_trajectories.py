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
