"""The air a vehicle flies in (``plant.wind``): quadratic drag against its closed form, the gusts'
spread and correlation time, one-line errors; and the paper's swarm in 5 m/s of wind with gusts
and noisy reports, in processes as in ``sim``, bit for bit."""

import math

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from sim_vehicles.common.command import AttitudeCommand
from sim_vehicles.common.state import POS, VEL, make_state
from sim_vehicles.plant.autopilot import Autopilot
from sim_vehicles.plant.params import AttitudeGains, VehicleParams
from sim_vehicles.plant.wind import WIND_DT_S, FrozenGusts, WindModel
from swarm_sitl.config.load import ConfigError, parse_config
from tests.support import CONFIGS, cli, config

#: its system tests run in lockstep or ``sim`` only (no wall clock): free to run beside others
pytestmark = pytest.mark.lockstep


@pytest.mark.unit
def test_a_hovering_vehicle_is_carried_by_a_steady_wind_as_quadratic_drag_says():
    """Level, at hover thrust, in a steady 5 m/s east wind: its velocity relative to the air
    u = v - w obeys du/dt = -(c/m)|u|u, so u(t) = u0 / (1 + c |u0| t / m); nothing else moves."""
    c, m = 0.05, 0.85
    params = VehicleParams(m, (0.04856, 0.04856, 0.08801), 25.0, drag_Ns2pm2=c)
    ap = Autopilot(params, AttitudeGains(16.0, 16.0), make_state([0.0, 0.0, 10.0], [0.0, 0.0, 0.0]), 0.001)
    ap.wind = WindModel(1, (5.0, 0.0, 0.0))
    ap.set_command(AttitudeCommand(np.array([1.0, 0.0, 0.0, 0.0]), m * 9.81))
    for t_end in (0.5, 1.0, 2.0):
        ap.advance(round((t_end - ap.time_s) / ap.dt_s))
        u = ap.state[VEL][0] - 5.0
        assert u == pytest.approx(-5.0 / (1 + c * 5.0 * t_end / m), rel=1e-9), t_end
    assert (
        abs(ap.state[VEL][1]) < 1e-12
        and abs(ap.state[VEL][2]) < 1e-9
        and ap.state[POS][2] == pytest.approx(10.0)
    )
    still = Autopilot(params, AttitudeGains(16.0, 16.0), make_state([0.0, 0.0, 10.0], [0.0, 0.0, 0.0]), 0.001)
    still.set_command(AttitudeCommand(np.array([1.0, 0.0, 0.0, 0.0]), m * 9.81))
    still.advance(2000)
    assert np.all(still.state[VEL] == 0.0)  # no wind, no drag force


@pytest.mark.unit
@pytest.mark.parametrize("tau", [0.25, 0.5])
def test_the_gusts_have_their_spread_and_correlation_time(tau):
    """Pooled over seeds and axes: each axis's standard deviation is gust_mps and its
    autocorrelation at one correlation time exp(-1), within five standard errors of an AR(1)
    series with coefficient a: the variance estimate counts n (1 - a^2) / (1 + a^2) independent
    samples, and the autocorrelation r_h at lag h has Bartlett's variance
    ((1 + a^2)(1 - a^2h) / (1 - a^2) - 2 h a^2h) / n per series. The other correlation times
    tau / 2 and 2 tau give exp(-2) and exp(-1/2) there, many standard errors away."""
    sigma, n, seeds = 1.5, 5000, 8
    models = [WindModel(2, gust_mps=sigma, gust_time_s=tau, seed=s) for s in range(seeds)]
    g = np.array([[m.gust(k) for k in range(n)] for m in models])  # (seed, sample, axis)
    a = math.exp(-WIND_DT_S / tau)
    n_eff = seeds * 3 * n * (1 - a * a) / (1 + a * a)
    assert abs(g.std() / sigma - 1) < 5 / math.sqrt(2 * n_eff), g.std()
    lag = round(tau / WIND_DT_S)
    corr = np.mean([np.corrcoef(g[s, :-lag, i], g[s, lag:, i])[0, 1] for s in range(seeds) for i in range(3)])
    a2h = a ** (2 * lag)
    var_one = ((1 + a * a) * (1 - a2h) / (1 - a * a) - 2 * lag * a2h) / (n - lag)
    tol = 5 * math.sqrt(var_one / (seeds * 3))
    assert abs(corr - math.exp(-1)) < tol, (corr, tol)
    assert min(abs(math.exp(-2) - math.exp(-1)), abs(math.exp(-0.5) - math.exp(-1))) > 2 * tol
    steady = WindModel(1, (3.0, -4.0, 0.0))
    assert steady.at(0.0).tolist() == [3.0, -4.0, 0.0] == steady.at(123.4).tolist()
    w = WindModel(1, (3.0, 0.0, 0.0), gust_mps=1.0, seed=5)
    assert np.array_equal(
        w.at(2.005), WindModel(1, (3.0, 0.0, 0.0), gust_mps=1.0, seed=5).at(2.0)
    )  # held 10 ms
    again = models[0]  # asked for an earlier sample after a later one: the same chain, drawn again
    assert np.array_equal(again.gust(n // 2), g[0, n // 2]) and np.array_equal(again.gust(n - 1), g[0, -1])


def _paper(**over) -> dict:
    data = yaml.safe_load((CONFIGS / "paper.yaml").read_text())
    for k, v in over.items():
        data[k] = v
    return data


@pytest.mark.unit
def test_the_gusts_start_from_their_stationary_law_and_each_vehicle_has_its_own():
    """The first sample over 400 seeds has standard deviation gust_mps (a chain started at 0 would
    give 0 there), within five standard errors of a variance estimate of 1200 normal draws; two
    vehicles' series in one air are uncorrelated (|r| below five standard errors of a correlation
    of independent AR(1) series: variance (1 + a^2) / ((1 - a^2) n))."""
    sigma, tau = 2.0, 0.3
    first = np.array([WindModel(1, gust_mps=sigma, gust_time_s=tau, seed=s).gust(0) for s in range(400)])
    assert abs(first.std() / sigma - 1) < 5 / math.sqrt(2 * first.size), first.std()
    n = 4000
    one, two = (WindModel(i, gust_mps=sigma, gust_time_s=tau, seed=3) for i in (1, 2))
    g1 = np.array([one.gust(k) for k in range(n)])
    g2 = np.array([two.gust(k) for k in range(n)])
    a = math.exp(-WIND_DT_S / tau)
    tol = 5 * math.sqrt((1 + a * a) / ((1 - a * a) * n))
    for i in range(3):
        assert abs(np.corrcoef(g1[:, i], g2[:, i])[0, 1]) < tol, i
    assert tol < 0.5  # a shared series would give r = 1


@pytest.mark.unit
def test_wind_without_drag_or_a_negative_drag_is_one_line():
    with pytest.raises(
        ConfigError, match=r"wind: the air pushes a vehicle through its drag: set vehicle\.drag_Ns2pm2"
    ):
        parse_config(_paper(wind={"mean_mps": [5, 0, 0]}), "paper.yaml")
    data = _paper()
    data["vehicle"]["drag_Ns2pm2"] = -1
    with pytest.raises(ConfigError, match=r"vehicle\.drag_Ns2pm2: .*greater than or equal to 0"):
        parse_config(data, "paper.yaml")
    with pytest.raises(ConfigError, match=r"wind\.gust_time_s: .*greater than 0"):
        parse_config(_paper(wind={"gust_mps": 1, "gust_time_s": 0}), "paper.yaml")


@pytest.mark.unit
def test_the_worlds_gusts_are_felt_alike_across_the_wind_and_later_downstream():
    """``FrozenGusts``: one field, carried by the mean wind W = (5, 0, 0) m/s. Vehicles of
    different ids level across the wind feel the same gust at every instant; one 2.5 m
    downstream feels at t + 0.5 s what the first felt at t (50 gust samples); each vehicle's own
    gusts (``WindModel``, by id) differ. In still mean air the world's gust is the same anywhere."""
    kw = {"mean_mps": (5.0, 0.0, 0.0), "gust_mps": 1.0, "gust_time_s": 0.5, "seed": 4}
    a, b, down = FrozenGusts(**kw), FrozenGusts(**kw), FrozenGusts(**kw)
    here, across, there = np.array([1.0, 2.0, 3.0]), np.array([1.0, -7.0, 9.0]), np.array([3.5, 2.0, 3.0])
    times = np.arange(0, 300) * WIND_DT_S + 1.0
    first = np.array([a.update(t, here) for t in times])
    assert np.array_equal(first, np.array([b.update(t, across) for t in times]))
    later = np.array([down.update(t + 0.5, there) for t in times])
    assert np.allclose(later, first, rtol=0, atol=1e-12)
    assert first[:, 0].std() > 0.3  # (the gusts are there to be felt)
    own = [WindModel(i, **kw) for i in (1, 2)]
    assert not np.allclose([own[0].update(t, here) for t in times], [own[1].update(t, across) for t in times])
    still = {**kw, "mean_mps": (0.0, 0.0, 0.0)}
    assert np.array_equal(FrozenGusts(**still).update(2.0, here), FrozenGusts(**still).update(2.0, there))


@pytest.mark.system
@pytest.mark.parametrize("air", ["independent", "frozen"])
def test_the_paper_swarm_in_wind_gusts_and_noisy_reports_flies_in_processes_as_in_sim(tmp_path, air):

    from swarm_sitl.config.load import load_config
    from swarm_sitl.running.sim import run_sim

    wind = {"mean_mps": [5.0, 0.0, 0.0], "gust_mps": 1.0, "gust_time_s": 2.0, "seed": 3, "model": air}
    data = _paper(duration_s=25.0, wind=wind)
    data["vehicle"]["drag_Ns2pm2"] = 0.02
    data["vehicle"]["sensors"] = {"position_noise_m": 0.03, "seed": 1}
    if air == "frozen":  # and a wandering bias on each vehicle's reported position
        data["vehicle"]["sensors"]["position_bias_walk_m_per_sqrt_s"] = 0.002
    path = tmp_path / "windy.yaml"
    path.write_text(yaml.safe_dump(data))
    r = cli("run", str(path), "--out", str(tmp_path / "run"))
    assert r.returncode == 0, r.stderr
    assert "formation error" in r.stdout  # it reports its error
    sim = run_sim(load_config(path))
    calm = run_sim(config("paper").model_copy(update={"duration_s": 25.0}))
    for i in range(1, 5):
        a = np.load(tmp_path / "run" / f"follower_{i}.npz")
        for key in ("p_W", "v_W", "u", "thrust_N", "pos_err_m"):
            assert np.array_equal(a[key], sim.followers[i][key], equal_nan=True), (i, key)
        windy = np.linalg.norm(a["pos_err_m"][a["t_s"] >= 20], axis=1)
        still = np.linalg.norm(calm.followers[i]["pos_err_m"][calm.followers[i]["t_s"] >= 20], axis=1)
        assert windy.max() > 5 * still.max()  # the air is felt
        assert windy.max() < 1.0, windy.max()  # and the formation flies on


@pytest.mark.unit
@settings(max_examples=40, deadline=None)
@given(
    heading=st.floats(0, 2 * math.pi),
    speed=st.one_of(st.floats(0.2, 1.0), st.floats(1.0, 20.0)),  # (a breeze under 1 m/s too)
    climb=st.floats(-0.5, 0.5),
    where=st.lists(st.tuples(st.floats(0, 6), st.tuples(*[st.floats(-30, 30)] * 3)), min_size=1, max_size=4),
)
def test_the_worlds_gust_is_the_mean_wind_plus_the_gust_of_the_instant_it_left_upstream(
    heading, speed, climb, where
):
    """``FrozenGusts.update(t, p)`` is ``W + g(floor(tau / 10 ms))`` with ``tau = t - p.W / |W|^2``
    (the first sample before the field reaches p), for any mean wind however light, and ``W + g(t)``
    in still mean air."""
    mean = (speed * math.cos(heading), speed * math.sin(heading), climb * speed)
    world = FrozenGusts(mean_mps=mean, gust_mps=1.5, gust_time_s=0.4, seed=7)
    series = WindModel(0, gust_mps=1.5, gust_time_s=0.4, seed=7)
    for t, p in where:
        tau = t - (np.dot(p, mean)) / np.dot(mean, mean)
        k = max(0, math.floor(tau / WIND_DT_S + 1e-9))
        assert np.array_equal(world.update(t, np.array(p)), np.array(mean) + series.gust(k)), (t, p)
    still = FrozenGusts(gust_mps=1.5, gust_time_s=0.4, seed=7)
    assert np.array_equal(still.update(1.23, np.array([5.0, 5.0, 5.0])), series.gust(123))
