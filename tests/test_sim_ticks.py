"""What ``sim`` gives a law and its vehicle at each tick (``running.sim``), seen by the probe law
(``tests/probe_law.py``) that records everything it is handed: its context, its tick's time and
sample, and each in-neighbour's message; and what the vehicle does with the commands it is given.
Under fault plans: ``tests/test_sim_under_plans.py``.

The expectations are the tick's definition (``laws.contract``): at tick ``k`` (``t = k dt``) the
law gets its vehicle's state at ``t`` through the wire (float32), the newest message of each of
its in-neighbours (tick ``k - 1``'s, ``dt`` old; none at the first tick), and its command is
held by the vehicle until ``t + dt``. The probe flies level with a thrust that changes every
tick, so the vehicle's vertical motion over each period is constant acceleration in closed form
(RK4 integrates it exactly), and its horizontal position does not move.
"""

import numpy as np
import pytest

from sim_vehicles.mavlink.thrust_map import full_thrust_N, hover_fraction
from sim_vehicles.mavlink.wire_format import f32
from swarm_sitl.running.sim import run_sim
from tests.probe_law import SLOTS, climb_acceleration, loaded, probe_config
from tests.support import config_data

pytestmark = pytest.mark.integration


# (each fixture is a test's own, not a module's: a mutation tester maps a run to the tests that
# made it, and a module's fixture would make it for its first test only; a flight here is 0.1 s)
@pytest.fixture
def probed(tmp_path):
    """The paper's swarm, its edges weighted and follower 2 an ArduCopter, flown 0.5 s in ``sim`` by
    the probe; and its config."""
    data = probe_config(tmp_path, duration_s=0.5)
    data["graph"]["edges"] = [[0, 1, 1.5], [0, 2], [0, 3, 0.75], [1, 4, 2.0], [2, 4, 0.5]]
    data["followers"][1]["autopilot"] = "ardupilot"  # (level: its GUIDED thrust is PX4's, unboosted)
    cfg = loaded(tmp_path, data)
    return cfg, run_sim(cfg)


def test_a_law_is_built_from_its_followers_place_in_the_graph_and_its_vehicles_reported_numbers(probed):
    """The context: its id, its in-edges and their weights and its out-neighbours as the config
    gives them, the control period, the mass as configured, the full thrust as the vehicle reports
    it over the float32 parameter protocol (``thrust_map``: its hover throttle as a float32), g,
    and its own random stream (``law.seed`` and its id)."""
    cfg, rec = probed
    for i, s in rec.followers.items():
        ctx = s["ctx"]
        assert (ctx == ctx[0]).all()  # the same at every tick
        edges = sorted((e[0], e[2] if len(e) == 3 else 1.0) for e in cfg.graph.edges if e[1] == i)
        assert ctx[0][:4].tolist() == [i, len(edges), sum(w for _, w in edges), cfg.control_dt_s]
        weights = [w for _, w in edges] + [np.nan] * (SLOTS - len(edges))
        np.testing.assert_array_equal(s["weights"], np.broadcast_to(weights, s["weights"].shape))
        outs = sorted(e[1] for e in cfg.graph.edges if e[0] == i)
        outs = outs + [np.nan] * (SLOTS - len(outs))
        np.testing.assert_array_equal(s["outs"], np.broadcast_to(outs, s["outs"].shape))
        assert (s["first_draw"] == np.random.default_rng([cfg.law.seed, i]).random()).all()
        v = cfg.vehicle
        assert ctx[0][4] == v.mass_kg and ctx[0][6] == cfg.gravity_mps2
        (hover,) = f32(hover_fraction(v.mass_kg, cfg.gravity_mps2, v.max_thrust_N))
        assert ctx[0][5] == full_thrust_N(v.mass_kg, cfg.gravity_mps2, hover)


def test_each_tick_gives_the_law_its_time_and_its_vehicles_state_at_that_time_through_the_wire(probed):
    """Tick ``k`` at ``k dt``; the sample is the recorded state of that row as LOCAL_POSITION_NED
    and ATTITUDE_QUATERNION carry it: each number within a float32 rounding (half a unit in the
    last of 24 bits, relative; the quaternion's frame change adds a few float64 roundings)."""
    cfg, rec = probed
    n = cfg.n_control_steps
    for i, s in rec.followers.items():
        k = np.arange(n + 1)
        assert s["seen_t"].tolist() == (k * cfg.control_dt_s).tolist() == s["t_s"].tolist()
        assert s["sample_t"].tolist() == s["t_s"].tolist()  # (its own instant's sample)
        for field, truth in (("sample_p", s["p_W"]), ("sample_v", s["v_W"]), ("sample_q", s["q_WB"])):
            assert np.all(np.abs(s[field] - truth) <= 2.0**-24 * np.abs(truth) + 1e-15), (i, field)
        assert s["p_W"][0].tolist() == list(cfg.follower(i).initial_position_m)


def test_each_tick_hears_every_in_neighbour_once_with_its_message_of_the_tick_before(probed):
    """No message at the first tick; from the second on, each in-neighbour's (and only theirs),
    sent at the tick before, ``dt`` old, saying its sender and its time: the leader's is its
    trajectory's position at that time."""
    cfg, rec = probed
    graph, dt = cfg.build_graph(), cfg.control_dt_s
    trajectory = cfg.trajectory()
    for i, s in rec.followers.items():
        assert np.isnan(s["from"][0]).all() and np.isnan(s["ref_p"][0]).all()
        sources = sorted(src for src, _ in graph.in_neighbours(i))
        pad = [np.nan] * (SLOTS - len(sources))
        for k in range(1, cfg.n_control_steps + 1):
            sent = (k - 1) * dt
            row = {name: s[name][k].tolist() for name in ("from", "sent_at", "age", "said_id", "said_t")}
            assert row["from"][: len(sources)] == sources and np.isnan(row["from"][len(sources) :]).all()
            assert row["sent_at"][: len(sources)] == [sent] * len(sources), (i, k)
            assert row["age"][: len(sources)] == [k * dt - sent] * len(sources), (i, k)
            assert row["said_id"][: len(sources)] == [float(x) for x in sources]
            said_t = [sent if x else np.nan for x in sources]
            np.testing.assert_array_equal(row["said_t"], said_t + pad)
            if 0 in sources:
                np.testing.assert_array_equal(s["ref_p"][k], trajectory.derivatives(sent)[0])


def test_each_command_is_held_by_the_vehicle_for_one_period_as_the_wire_carries_its_thrust(probed):
    """Level, with the thrust of tick ``k`` as the vehicle reads it off SET_ATTITUDE_TARGET, the
    vehicle accelerates at ``T / m - g`` straight up from ``t_k`` to ``t_k + dt``: its velocity
    and height at the next row in closed form (to a few float64 roundings of the numbers), its
    horizontal position still where it started, its attitude level."""
    cfg, rec = probed
    dt = cfg.control_dt_s
    for i, s in rec.followers.items():
        full = s["ctx"][0][5]
        assert s["thrust_N"].shape == (cfg.n_control_steps + 1,)
        for k in range(cfg.n_control_steps):
            a = climb_acceleration(cfg, s["thrust_N"][k], full)
            v, z = s["v_W"][k][2], s["p_W"][k][2]
            assert s["v_W"][k + 1][2] == pytest.approx(v + a * dt, abs=1e-12), (i, k)
            assert s["p_W"][k + 1][2] == pytest.approx(z + v * dt + a * dt**2 / 2, abs=1e-12), (i, k)
        np.testing.assert_array_equal(
            s["p_W"][:, :2], np.broadcast_to(s["p_W"][0, :2], s["p_W"][:, :2].shape)
        )
        np.testing.assert_array_equal(s["q_WB"], np.broadcast_to([1.0, 0.0, 0.0, 0.0], s["q_WB"].shape))


@pytest.mark.parametrize("planned", [False, True], ids=["plain", "planned"])
def test_a_vehicle_that_reports_late_and_noisy_gives_the_law_what_its_sensors_report(tmp_path, planned):
    """With ``vehicle.sensors`` (latency, noise, a drifting bias), the sample of tick ``k`` is what
    a fresh copy of the vehicle's sensor model (``plant.sensors``, seeded as the vehicle is) reports
    at ``k`` ms times the period, fed the recorded true states in order; through the wire's float32,
    as without sensors; plain, and on the planned path (a plan that touches no vehicle link)."""
    from sim_vehicles.common.state import POS, QUAT, RATE, STATE_SIZE, VEL
    from sim_vehicles.models.build import sensor_model

    # (past 0.5 s: a tick's ms is not t * 1001's)
    data = probe_config(tmp_path, duration_s=1.0, **({"faults": LATE_DROP} if planned else {}))
    data["vehicle"]["sensors"] = {
        "position_noise_m": 0.05,
        "velocity_noise_mps": 0.02,
        "attitude_noise_rad": 0.01,
        "latency_s": 0.03,
        "seed": 4,
        "position_bias_walk_m_per_sqrt_s": 0.1,
    }
    cfg = loaded(tmp_path, data)
    rec = run_sim(cfg)
    for i, s in rec.followers.items():
        model = sensor_model(cfg.vehicle_config(i), i)
        for k in range(cfg.n_control_steps + 1):
            x = np.empty(STATE_SIZE)
            x[POS], x[VEL], x[QUAT], x[RATE] = s["p_W"][k], s["v_W"][k], s["q_WB"][k], s["omega_B"][k]
            y = model.reported(round(k * cfg.control_dt_s * 1000), x)
            for field, part in (("sample_p", POS), ("sample_v", VEL)):
                assert np.all(np.abs(s[field][k] - y[part]) <= 2.0**-24 * np.abs(y[part]) + 1e-15), (i, k)
            # a unit quaternion's float32 parts mixed by the frame change (each part two of them
            # times 1/sqrt(2)): within sqrt(2) half-steps of 1, 2^-23, on each part; either sign
            q = y[QUAT] if y[QUAT] @ s["sample_q"][k] >= 0 else -y[QUAT]
            assert np.abs(s["sample_q"][k] - q).max() <= 2.0**-23, (i, k)
        assert np.abs(s["sample_p"] - s["p_W"]).max() > 0.01  # (the noise is there, not the truth)


#: a plan that acts late (follower 1 stops hearing the leader at 0.45 s): ``sim`` flies it on the
#: planned path
LATE_DROP = {"seed": 1, "plan": [{"edge": [0, 1], "drop": True, "from_s": 0.45}]}


@pytest.mark.parametrize("plan", [None, LATE_DROP], ids=["plain", "planned"])
def test_sim_tells_its_progress_at_every_tick_and_flies_the_ticks_asked(tmp_path, plan):
    """``progress`` is called with each tick in order, in memory and spooled, plain and under a
    plan; ``n_steps`` rows past the first are flown, whatever the config's duration."""
    from swarm_sitl.running.sim import run_sim_spooled

    cfg = loaded(tmp_path, probe_config(tmp_path, duration_s=0.5, **({"faults": plan} if plan else {})))
    told: list[int] = []
    rec = run_sim(cfg, n_steps=7, progress=told.append)
    assert told == list(range(8))
    assert all(s["t_s"].tolist() == [k * cfg.control_dt_s for k in range(8)] for s in rec.followers.values())
    told.clear()
    run_sim_spooled(cfg, tmp_path / "spool", progress=told.append)
    assert told == list(range(cfg.n_control_steps + 1))


CHATTY = """
import time
import numpy as np
from swarm_sitl.laws.contract import AttitudeCommand, LawOutput


class Chatty:
    '''Says each tick it steps; at 0.05 s follower 3's step hangs (4 s, once).'''
    message_length = 1
    record_fields = {}

    def __init__(self, ctx):
        self.id, self.weight = ctx.follower_id, ctx.mass_kg * ctx.gravity_mps2

    def step(self, t_s, sample, inbox):
        print(f"follower {self.id} at {t_s:.2f}")
        if self.id == 3 and round(t_s * 100) == 5:
            time.sleep(4)
        return LawOutput(AttitudeCommand(np.array([1.0, 0.0, 0.0, 0.0]), self.weight), np.zeros(1), {})
"""


@pytest.mark.parametrize("plan", [None, LATE_DROP], ids=["plain", "planned"])
@pytest.mark.parametrize("spooled", [False, True], ids=["in memory", "spooled"])
def test_a_users_law_in_sim_is_guarded_its_prints_given_and_a_hung_step_ends_the_run_with_what_was_recorded(
    tmp_path, plan, spooled
):
    """A law that is not the paper's runs under its guard in ``sim`` as in a controller, plain or
    under a plan, in memory or spooled: what it prints goes to ``law_output``, and a step past
    ``run.tick_timeout_s`` ends the run with one line naming the follower, its time and the
    timeout, the rows before it kept."""
    import io

    from swarm_sitl.running.sim import SimFailedError, run_sim_spooled

    (tmp_path / "chatty.py").write_text(CHATTY)
    data = config_data("paper")
    # (1 s: a step of this law on a busy machine takes far less)
    data.update(duration_s=0.5, law={"entry": "chatty.py:Chatty"}, run={"tick_timeout_s": 1.0})
    if plan:
        data["faults"] = plan
    cfg = loaded(tmp_path, data)
    said = io.StringIO()
    with pytest.raises(SimFailedError) as e:
        if spooled:
            run_sim_spooled(cfg, tmp_path / "spool", law_output=said)
        else:
            run_sim(cfg, law_output=said)
    assert str(e.value) == (
        f"law {tmp_path / 'chatty.py'}:Chatty, follower 3 at t=0.050 s: its step did not return within "
        "1 s (run.tick_timeout_s)"
    )
    lines = said.getvalue().splitlines()
    assert lines == [
        f"follower {i} at {k * 0.01:.2f}" for k in range(6) for i in (1, 2, 3, 4) if (k, i) < (5, 4)
    ]
    if not spooled:
        rows = e.value.recording.followers[2]
        assert np.isfinite(rows["thrust_N"][:5]).all() and np.isnan(rows["thrust_N"][6:]).all()


def test_the_leaders_message_is_its_trajectory_at_the_tick(probed):
    """Node 0's message of tick ``k``: the reference ``laws.contract.REFERENCE`` of its trajectory
    at ``k dt`` (p, v, a, jerk), stamped with the tick and its time, its position the message's
    ``p_W`` (what a link model's distance is measured from)."""
    from swarm_sitl.laws.contract import reference_values
    from swarm_sitl.nodes.assembly import build_leader

    cfg, _ = probed
    leader, trajectory = build_leader(cfg), cfg.trajectory()
    for k in (0, 1, 7, 4321):
        m = leader.step(k)
        d = trajectory.derivatives(k * cfg.control_dt_s)
        assert (m.src, m.step, m.t_s) == (0, k, k * cfg.control_dt_s)
        np.testing.assert_array_equal(m.values, reference_values(d))
        assert m.p_W == tuple(d[0])


def test_a_first_tick_is_the_law_at_zero_on_its_initial_state_hearing_the_leaders_reference_and_zeros(
    tmp_path,
):
    """``assembly.first_tick`` (``run`` and ``check --law`` step each law once before anything
    starts): at t = 0, on its configured initial state as it is (no wire), with the leader's
    reference at 0 if it hears node 0 and zeros from its other in-neighbours, all at 0 and 0 old;
    its context built with the mass and full thrust it is given."""
    from swarm_sitl.nodes.assembly import first_tick
    from swarm_sitl.rundir.recording import layout

    data = probe_config(tmp_path, duration_s=0.5)
    data["followers"][3]["initial_velocity_mps"] = [0.5, -0.25, 1.0]
    data["followers"][3]["initial_quaternion_wxyz"] = [0.6, 0.0, 0.8, 0.0]
    cfg = loaded(tmp_path, data)
    ref = cfg.trajectory().derivatives(0.0)[0]
    for f in cfg.followers:
        step = first_tick(cfg, f.id, 0.7, 19.5)
        at = layout(cfg.law_class().record_fields)
        rec = {name: step.record[where] for name, where in at.items()}
        sources = sorted(s for s, d in cfg.graph_edges() if d == f.id)
        n_in, g = len(sources), cfg.gravity_mps2  # (the paper's edges weigh 1 each)
        assert rec["ctx"].tolist() == [f.id, n_in, float(n_in), cfg.control_dt_s, 0.7, 19.5, g]
        assert rec["seen_t"].tolist() == rec["sample_t"].tolist() == [0.0]
        for name, given in (
            ("sample_p", f.initial_position_m),
            ("sample_v", f.initial_velocity_mps),
            ("sample_q", f.initial_quaternion_wxyz),
        ):
            assert rec[name].tolist() == list(given), (f.id, name)
        assert rec["from"][: len(sources)].tolist() == sources
        assert (
            rec["sent_at"][: len(sources)].tolist()
            == rec["age"][: len(sources)].tolist()
            == [0.0] * len(sources)
        )
        said = [0.0] * len(sources)  # (the probe's "said_id" of node 0 is 0; a follower's zeros say 0)
        assert rec["said_id"][: len(sources)].tolist() == said
        if 0 in sources:
            assert rec["ref_p"].tolist() == ref.tolist()
        assert step.message.tolist() == [f.id, 0.0, *f.initial_position_m]
