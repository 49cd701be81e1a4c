"""Tests of ``consensus_pd.py`` as its author ships them: its equations against their closed forms,
then the law on the bench (``sim`` and a lockstep run of processes, a cut edge through the
``swarm`` fixture)."""

import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest

from swarm_sitl.config.load import load_config
from swarm_sitl.laws.contract import LawContext, Received, VehicleSample
from swarm_sitl.running.sim import run_sim

HERE = Path(__file__).resolve().parent
CONFIG = HERE.parents[1] / "configs" / "consensus_pd.yaml"

_spec = importlib.util.spec_from_file_location("consensus_pd_under_test", HERE / "consensus_pd.py")
assert _spec is not None and _spec.loader is not None
cpd = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(cpd)


def _random_tree_graph(rng: np.random.Generator, n: int) -> list[tuple[int, int, float]]:
    """Edges ``(src, dst, weight)``: a random spanning tree rooted at 0, plus random extra edges."""
    edges = [(int(rng.integers(0, i)), i, float(rng.uniform(0.5, 2.0))) for i in range(1, n + 1)]
    for _ in range(n):
        s, d = (int(x) for x in rng.integers(0, n + 1, size=2))
        if d != 0 and s != d and (s, d) not in {(e[0], e[1]) for e in edges}:
            edges.append((s, d, float(rng.uniform(0.5, 2.0))))
    return edges


@pytest.mark.unit
@pytest.mark.parametrize("seed", range(5))
def test_every_estimate_obeys_the_same_second_order_error_equation_whatever_the_graph(seed):
    """Ren's algorithm with the neighbours' accelerations simultaneous (its fixed point, solved by
    iterating it): ``a_i - a_0 = -alpha e_i - gamma e_i'`` for every follower, with
    ``e_i = p_i - p_0``, on any graph with a spanning tree rooted at the leader."""
    rng = np.random.default_rng(seed)
    n, alpha, gamma = 6, 2.5, 3.0
    edges = _random_tree_graph(rng, n)
    p, v = rng.normal(size=(n + 1, 3)), rng.normal(size=(n + 1, 3))
    a = np.zeros((n + 1, 3))
    a[0] = rng.normal(size=3)
    for _ in range(2000):  # Jacobi on (L + B): converges for a spanning tree rooted at 0
        new = a.copy()
        for i in range(1, n + 1):
            heard = [(w, p[s], v[s], a[s]) for s, d, w in edges if d == i]
            new[i] = cpd.consensus_acceleration(p[i], v[i], heard, alpha, gamma)
        done = np.abs(new - a).max() < 1e-14
        a = new
        if done:
            break
    for i in range(1, n + 1):
        e, e_dot = p[i] - p[0], v[i] - v[0]
        np.testing.assert_allclose(a[i] - a[0], -alpha * e - gamma * e_dot, atol=1e-10)


@pytest.mark.unit
def test_nobody_heard_gives_no_acceleration():
    assert cpd.consensus_acceleration(np.zeros(3), np.zeros(3), [], 1.0, 1.0) is None


def _context(params: dict, in_edges=((0, 1.0),), offset=(0.0, 0.0, 0.0), dt=0.01) -> LawContext:
    return LawContext(
        follower_id=1,
        in_edges=tuple(in_edges),
        out_neighbours=(),
        control_dt_s=dt,
        mass_kg=0.85,
        max_thrust_N=25.0,
        gravity_mps2=9.81,
        offset_m=np.asarray(offset, dtype=float),
        rng=np.random.default_rng(0),
        params=cpd.ConsensusPDParams(**params),
    )


def _estimate_error_run(dt: float, T: float, e0: np.ndarray, alpha: float, gamma: float) -> float:
    """Largest difference between the law's estimate error and the closed-form critically damped
    solution, for a follower hearing only a leader that moves at constant velocity."""
    law = cpd.ConsensusPD(_context({"alpha": alpha, "gamma": gamma}, dt=dt))
    v0 = np.array([1.0, -0.5, 0.2])
    lam = gamma / 2  # alpha = (gamma/2)^2: e(t) = (e0 + (e0' + lam e0) t) exp(-lam t), e0' = 0
    worst = 0.0
    for k in range(round(T / dt) + 1):
        t = k * dt
        p_r = v0 * t
        leader = Received(np.concatenate((p_r, v0, np.zeros(6))), t, 0.0)
        sample = VehicleSample(t, (p_r + e0) if k == 0 else np.zeros(3), v0.copy(), np.array([1.0, 0, 0, 0]))
        out = law.step(t, sample, {0: leader})
        e = out.message[0:3] - p_r
        exact = (e0 + lam * e0 * t) * math.exp(-lam * t)
        worst = max(worst, float(np.abs(e - exact).max()))
    return worst


@pytest.mark.unit
def test_a_leader_neighbour_estimate_decays_as_the_closed_form_with_first_order_sampling_error():
    """Sampled at ``dt`` (acceleration held over each period), the estimate's error follows
    ``e'' + gamma e' + alpha e = 0``'s solution up to O(dt): halving dt halves the deviation."""
    e0 = np.array([3.0, -2.0, 1.0])
    coarse = _estimate_error_run(0.02, 6.0, e0, 4.0, 4.0)
    fine = _estimate_error_run(0.01, 6.0, e0, 4.0, 4.0)
    assert coarse < 0.1 * np.abs(e0).max()  # the estimate does follow the closed form
    assert 1.8 < coarse / fine < 2.2  # first order in dt


@pytest.mark.unit
@pytest.mark.parametrize("seed", range(20))
def test_the_command_attitude_points_thrust_along_the_force_at_the_chosen_heading(seed):
    rng = np.random.default_rng(seed)
    F = rng.normal(size=3) + np.array([0.0, 0.0, 9.0])
    yaw = float(rng.uniform(-np.pi, np.pi))
    thrust, R_c = cpd.thrust_and_attitude(F, np.eye(3), yaw)
    np.testing.assert_allclose(R_c.T @ R_c, np.eye(3), atol=1e-12)
    assert np.linalg.det(R_c) == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(R_c[:, 2], F / np.linalg.norm(F), atol=1e-12)
    assert thrust == pytest.approx(F[2])  # F . R e3 with R level
    b1d = np.array([math.cos(yaw), math.sin(yaw), 0.0])  # its heading: b1 is b1d projected normal
    assert R_c[:, 1] @ b1d == pytest.approx(0.0, abs=1e-12)  # to b3, so b2 is normal to b1d
    assert R_c[:, 0] @ b1d > 0
    thrust_there, _ = cpd.thrust_and_attitude(F, R_c, yaw)
    assert thrust_there == pytest.approx(np.linalg.norm(F))  # once the vehicle has tilted to R_c
    q = cpd.quaternion(R_c)
    np.testing.assert_allclose(cpd.rotation(q), R_c, atol=1e-12)


@pytest.mark.unit
def test_an_aged_message_is_carried_exactly_along_a_polynomial_path():
    """A leader on a cubic path: its message carried by its age equals the path at the tick."""
    c = np.array([[1.0, 2, 3], [0.5, -1, 0.2], [0.3, 0.1, -0.4], [0.05, -0.02, 0.01]])

    def path(t):  # p, v, a, jerk of sum c_k t^k / k!
        return (
            c[0] + c[1] * t + c[2] * t**2 / 2 + c[3] * t**3 / 6,
            c[1] + c[2] * t + c[3] * t**2 / 2,
            c[2] + c[3] * t,
            c[3],
        )

    t0, age = 1.3, 0.37
    p, v, a = cpd.carried(np.concatenate(path(t0)), age, leader=True)
    for got, want in zip((p, v, a), path(t0 + age)[:3], strict=True):
        np.testing.assert_allclose(got, want, atol=1e-12)


@pytest.fixture(scope="module")
def cfg():
    return load_config(CONFIG)


@pytest.mark.system
@pytest.mark.lockstep  # (no wall clock: free to run beside others)
def test_lockstep_processes_equal_sim_bit_for_bit(tmp_path, cfg, swarm):
    sim = run_sim(cfg.model_copy(update={"duration_s": 4.0}))
    r = swarm(CONFIG, duration_s=4.0)
    assert r.ok, r.failure
    for i, series in sim.followers.items():
        got = r.followers[i].arrays
        for key in ("p_W", "v_W", "q_WB", "thrust_N", "p_hat", "v_hat", "a_hat", "a_c", "heard"):
            assert got[key].tobytes() == series[key].tobytes(), (i, key)


@pytest.mark.system
@pytest.mark.lockstep
def test_a_cut_edge_from_the_leader_costs_formation_and_the_swarm_recovers(swarm):
    """The edge 0 -> 1 is cut from 20 s to 30 s: follower 1 coasts on its last estimate of the
    leader's acceleration (the helix turns away from it) and follower 4 hears it; both come back
    after the edge returns, while followers 2 and 3 never notice."""
    r = swarm(CONFIG, duration_s=45, faults=[{"edge": [0, 1], "drop": True, "from_s": 20, "until_s": 30}])
    assert r.ok, r.failure
    f = r.followers
    assert f[1].max_formation_error_m(20, 30) > 0.1
    assert f[4].max_formation_error_m(20, 30) > 0.05
    assert max(f[i].max_formation_error_m(after_s=30 + 10) for i in (1, 4)) < 0.05
    assert max(f[i].max_formation_error_m(after_s=20) for i in (2, 3)) < 0.01
    heard = f[1].arrays["heard"]
    t = f[1].t_s
    assert heard[(t > 21) & (t < 30)].max() == 0 and heard[t > 31].min() == 1  # out, then back
    lost = r.events_of("neighbour_lost")
    assert [(e["follower"], e["neighbour"]) for e in lost] == [(1, 0)]
