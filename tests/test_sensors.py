"""What a vehicle reports of its state (``plant.sensors``): seeded Gaussian noise of the stated
spread, a latency, off by default; and a swarm flying on noisy reports, in processes and in
``sim``, the same bit for bit, its recorded state the true one."""

import math

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from sim_vehicles.common.quaternion import qconj, qmul
from sim_vehicles.common.state import POS, QUAT, VEL, make_state
from sim_vehicles.plant.sensors import SensorModel
from tests.strategies import unit_quaternions
from tests.support import CONFIGS, cli

#: its system tests run in lockstep or ``sim`` only (no wall clock): free to run beside others
pytestmark = pytest.mark.lockstep


def _x(p=(1.0, 2.0, 3.0)) -> np.ndarray:
    return make_state(list(p), [0.5, -0.5, 0.1])


@pytest.mark.unit
def test_the_noise_has_its_spread_on_every_axis_and_is_the_same_for_the_same_seed_vehicle_and_instant():
    m = SensorModel(3, position_noise_m=0.03, velocity_noise_mps=0.1, attitude_noise_rad=0.01, seed=7)
    x = _x()
    n = 4000
    reps = np.array([m.reported(10 * k, x) for k in range(n)])
    dp, dv = reps[:, POS] - x[POS], reps[:, VEL] - x[VEL]
    for d, sigma in ((dp, 0.03), (dv, 0.1)):
        # the sample standard deviation of n normals: within 5 of its own standard errors
        assert np.all(np.abs(d.std(axis=0) - sigma) < 5 * sigma / math.sqrt(2 * n))
        assert np.all(np.abs(d.mean(axis=0)) < 5 * sigma / math.sqrt(n))
    angles = np.array([2 * math.acos(min(1.0, abs(qmul(qconj(x[QUAT]), q)[0]))) for q in reps[:, QUAT]])
    assert abs(np.sqrt((angles**2).mean()) - 0.01 * math.sqrt(3)) < 0.001  # |rotation vector|: chi, 3 dof
    assert np.allclose(np.linalg.norm(reps[:, QUAT], axis=1), 1.0)
    again = SensorModel(3, position_noise_m=0.03, velocity_noise_mps=0.1, attitude_noise_rad=0.01, seed=7)
    assert np.array_equal(again.reported(500, x), m.reported(500, x))
    other = SensorModel(4, position_noise_m=0.03, seed=7)
    assert not np.array_equal(other.reported(500, x)[POS], m.reported(500, x)[POS])
    assert np.array_equal(x, _x())  # the true state is never changed


@pytest.mark.unit
@pytest.mark.parametrize("walk", [0.02, 0.05])
def test_the_position_bias_wanders_as_a_random_walk_of_its_stated_intensity(walk):
    """Over many vehicles (ids 1..400, three axes each), the bias after t seconds has variance
    ``walk^2 t`` (the sample variance of n normals is within 5 of its standard errors,
    ``sqrt(2 / n)`` relative: a time scale off by 2x is 4x outside it), starts at zero, and its
    increments over disjoint intervals are uncorrelated (within 5 / sqrt(n)); asked again, or
    earlier, it is the same walk."""
    x = _x()
    ids = range(1, 401)
    models = [SensorModel(i, seed=5, position_bias_walk_m_per_sqrt_s=walk) for i in ids]
    b = {t: np.array([m.bias(round(t / 0.01)) for m in models]) for t in (0.5, 1.0)}  # (carried on)
    n = 3 * len(ids)
    for t, v in b.items():
        assert abs(v.var() / (walk**2 * t) - 1) < 5 * math.sqrt(2 / n), t
    first, second = b[0.5].ravel(), (b[1.0] - b[0.5]).ravel()
    assert abs(np.corrcoef(first, second)[0, 1]) < 5 / math.sqrt(n)
    m = SensorModel(9, seed=5, position_bias_walk_m_per_sqrt_s=walk)
    later = m.reported(4000, x)
    assert np.array_equal(
        m.reported(2000, x), SensorModel(9, seed=5, position_bias_walk_m_per_sqrt_s=walk).reported(2000, x)
    )
    assert np.array_equal(m.reported(4000, x), later)  # asked earlier in between: the same walk
    assert np.array_equal(
        SensorModel(9, seed=5, position_bias_walk_m_per_sqrt_s=walk).reported(0, x), x
    )  # zero at boot
    assert np.array_equal(later[VEL], x[VEL]) and not np.array_equal(later[POS], x[POS])  # position only


@pytest.mark.unit
@settings(max_examples=200, deadline=None)
@given(
    spread=st.tuples(st.floats(0, 1e3), st.floats(0, 1e3), st.floats(0, 10.0)),
    tiny=st.floats(0, 1e-150),  # (its square underflows: a rotation vector of length 0 once)
    seed=st.integers(0, 2**32 - 1),
    ms=st.integers(0, 2**31),
    q=unit_quaternions(),
)
def test_any_spread_however_small_reports_a_finite_state_and_a_rotation(spread, tiny, seed, ms, q):
    x = make_state([1.0, 2.0, 3.0], [0.5, -0.5, 0.1], q)
    for att in (spread[2], tiny):
        y = SensorModel(3, spread[0], spread[1], att, seed=seed).reported(ms, x)
        assert np.isfinite(y).all() and abs(np.linalg.norm(y[QUAT]) - 1) < 1e-12, (att, y)
        if att == 0 or att < 1e-150:  # no rotation, or one below a float's resolution of 1
            assert np.allclose(np.abs(qmul(qconj(x[QUAT]), y[QUAT])[0]), 1.0, rtol=0, atol=1e-15)


@pytest.mark.unit
def test_a_latency_reports_the_state_of_the_sample_that_long_ago():
    m = SensorModel(1, latency_s=0.05)
    states = [_x((k, 0.0, 0.0)) for k in range(20)]
    reported = [m.reported(10 * k, states[k])[0] for k in range(20)]
    assert reported == [0.0] * 5 + [float(k - 5) for k in range(5, 20)]  # the first until 0.05 s
    assert not SensorModel(1).active


def _noisy_config(tmp_path) -> str:
    cfg = yaml.safe_load((CONFIGS / "paper.yaml").read_text())
    cfg["duration_s"] = 6.0
    cfg["vehicle"]["sensors"] = {
        "position_noise_m": 0.03,
        "velocity_noise_mps": 0.05,
        "latency_s": 0.02,
        "seed": 4,
    }
    path = tmp_path / "noisy.yaml"
    path.write_text(yaml.safe_dump(cfg))
    return str(path)


@pytest.mark.system
def test_a_swarm_on_noisy_late_reports_flies_in_processes_as_in_sim_and_records_the_true_state(tmp_path):

    from swarm_sitl.config.load import load_config
    from swarm_sitl.running.sim import run_sim

    path = _noisy_config(tmp_path)
    r = cli("run", path, "--out", str(tmp_path / "run"), "--quiet")
    assert r.returncode == 0, r.stderr
    sim = run_sim(load_config(path))
    for i in range(1, 5):
        a = np.load(tmp_path / "run" / f"follower_{i}.npz")
        for key in ("p_W", "p_hat", "u", "q_c", "thrust_N", "pos_err_m"):
            assert np.array_equal(a[key], sim.followers[i][key], equal_nan=True), (i, key)
    # what flew: the commands differ from a noise-free run's, the recorded state is the truth
    clean = yaml.safe_load((tmp_path / "noisy.yaml").read_text())
    clean["vehicle"]["sensors"] = {}
    (tmp_path / "clean.yaml").write_text(yaml.safe_dump(clean))
    quiet = run_sim(load_config(tmp_path / "clean.yaml"))
    assert not np.array_equal(sim.followers[1]["u"], quiet.followers[1]["u"])
    truth = np.load(tmp_path / "run" / "follower_1.npz")["p_W"]
    assert np.abs(np.diff(truth[-50:], axis=0)).max() < 0.05  # a flown path, not a noisy one
