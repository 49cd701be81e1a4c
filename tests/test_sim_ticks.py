"""What ``sim`` gives a law and its vehicle at each tick (``running.sim``), seen by a probe law
that records everything it is handed: its context, its tick's time and sample, and each
in-neighbour's message; and what the vehicle does with the commands it is given.

The expectations are the tick's definition (``laws.contract``): at tick ``k`` (``t = k dt``) the
law gets its vehicle's state at ``t`` through the wire (float32), the newest message of each of
its in-neighbours (tick ``k - 1``'s, ``dt`` old; none at the first tick), and its command is
held by the vehicle until ``t + dt``. The probe flies level with a thrust that changes every
tick, so the vehicle's vertical motion over each period is constant acceleration in closed form
(RK4 integrates it exactly), and its horizontal position does not move.
"""

import numpy as np
import pytest
import yaml

from sim_vehicles.common.command import AttitudeCommand
from sim_vehicles.mavlink.thrust_map import full_thrust_N, hover_fraction
from sim_vehicles.mavlink.wire_format import command_roundtrip, f32
from swarm_sitl.config.load import load_config
from swarm_sitl.running.sim import run_sim
from tests.support import config_data

pytestmark = pytest.mark.integration

SLOTS = 3  #: in-neighbours a probe records (the paper's graph: at most 2)

PROBE = f"""
import numpy as np
from swarm_sitl.laws.contract import AttitudeCommand, LawOutput

SLOTS = {SLOTS}


def thrust_fraction(k, i):
    '''The probe's thrust at tick k, as a fraction of its weight: a different one every tick.'''
    return 1.0 + 0.2 * np.sin(0.7 * k + i)


class Probe:
    message_length = 5  # its id, its tick's time, its sample's position
    record_fields = {{
        "ctx": 7, "weights": SLOTS, "outs": SLOTS, "first_draw": 1,
        "seen_t": 1, "sample_t": 1, "sample_p": 3, "sample_v": 3, "sample_q": 4,
        "from": SLOTS, "sent_at": SLOTS, "age": SLOTS, "said_id": SLOTS, "said_t": SLOTS, "ref_p": 3,
    }}

    def __init__(self, ctx):
        self.ctx = ctx
        weights = sum(w for _, w in ctx.in_edges)
        self.row = [ctx.follower_id, len(ctx.in_edges), weights, ctx.control_dt_s, ctx.mass_kg,
                    ctx.max_thrust_N, ctx.gravity_mps2]
        by_source = [w for _, w in sorted(ctx.in_edges)]
        self.weights = [*by_source, *[np.nan] * (SLOTS - len(by_source))]
        outs = sorted(ctx.out_neighbours)
        self.outs = [*outs, *[np.nan] * (SLOTS - len(outs))]
        self.first_draw = ctx.rng.random()

    def step(self, t_s, sample, inbox):
        ctx = self.ctx
        k = round(t_s / ctx.control_dt_s)
        thrust = ctx.mass_kg * ctx.gravity_mps2 * thrust_fraction(k, ctx.follower_id)
        command = AttitudeCommand(np.array([1.0, 0.0, 0.0, 0.0]), thrust)
        sources = sorted(inbox)
        pad = lambda xs: [*xs, *[np.nan] * (SLOTS - len(xs))]
        follower = lambda s, j: inbox[s].values[j] if s != 0 else np.nan
        record = {{
            "ctx": self.row,
            "weights": self.weights,
            "outs": self.outs,
            "first_draw": self.first_draw,
            "seen_t": t_s,
            "sample_t": sample.t_s,
            "sample_p": sample.p_W, "sample_v": sample.v_W, "sample_q": sample.q_WB,
            "from": pad(sources),
            "sent_at": pad([inbox[s].t_s for s in sources]),
            "age": pad([inbox[s].age_s for s in sources]),
            "said_id": pad([follower(s, 0) if s else 0.0 for s in sources]),
            "said_t": pad([follower(s, 1) for s in sources]),
            "ref_p": inbox[0].values[:3] if 0 in inbox else [np.nan] * 3,
        }}
        message = np.array([ctx.follower_id, t_s, *sample.p_W])
        return LawOutput(command, message, record)
"""


def _probe_config(folder, **changes):
    """The paper's config flown by the probe (its file written in ``folder``), with ``changes``
    (top-level keys) made."""
    (folder / "probe.py").write_text(PROBE)
    data = config_data("paper")
    data.update(law={"entry": "probe.py:Probe"}, **changes)
    return data


def _loaded(folder, data):
    (folder / "cfg.yaml").write_text(yaml.safe_dump(data))
    return load_config(folder / "cfg.yaml")


# (each fixture is a test's own, not a module's: a mutation tester maps a run to the tests that
# made it, and a module's fixture would make it for its first test only; a flight here is 0.1 s)
@pytest.fixture
def probed(tmp_path):
    """The paper's swarm, its edges weighted and follower 2 an ArduCopter, flown 0.5 s in ``sim`` by
    the probe; and its config."""
    data = _probe_config(tmp_path, duration_s=0.5)
    data["graph"]["edges"] = [[0, 1, 1.5], [0, 2], [0, 3, 0.75], [1, 4, 2.0], [2, 4, 0.5]]
    data["followers"][1]["autopilot"] = "ardupilot"  # (level: its GUIDED thrust is PX4's, unboosted)
    cfg = _loaded(tmp_path, data)
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
    dt, m, g = cfg.control_dt_s, cfg.vehicle.mass_kg, cfg.gravity_mps2
    level = AttitudeCommand(np.array([1.0, 0.0, 0.0, 0.0]), 0.0)
    for i, s in rec.followers.items():
        full = s["ctx"][0][5]
        assert s["thrust_N"].shape == (cfg.n_control_steps + 1,)
        for k in range(cfg.n_control_steps):
            held = command_roundtrip(
                level._replace(thrust_N=s["thrust_N"][k]), full, cfg.vehicle.max_thrust_N
            )
            a = held.thrust_N / m - g
            v, z = s["v_W"][k][2], s["p_W"][k][2]
            assert s["v_W"][k + 1][2] == pytest.approx(v + a * dt, abs=1e-12), (i, k)
            assert s["p_W"][k + 1][2] == pytest.approx(z + v * dt + a * dt**2 / 2, abs=1e-12), (i, k)
        np.testing.assert_array_equal(
            s["p_W"][:, :2], np.broadcast_to(s["p_W"][0, :2], s["p_W"][:, :2].shape)
        )
        np.testing.assert_array_equal(s["q_WB"], np.broadcast_to([1.0, 0.0, 0.0, 0.0], s["q_WB"].shape))


#: the edges a plan loses messages on, and at which rate
LOSSY = {(0, 1): 0.3, (1, 4): 0.5}


@pytest.fixture
def probed_under_loss(tmp_path):
    """The paper's swarm flown 1 s in ``sim`` by the probe under a plan that loses messages on two
    edges; and its config."""
    plan = {"seed": 11, "plan": [{"edge": list(e), "loss": p} for e, p in LOSSY.items()]}
    cfg = _loaded(tmp_path, _probe_config(tmp_path, duration_s=1.0, faults=plan))
    return cfg, run_sim(cfg)


def test_under_a_plan_each_tick_hears_the_newest_message_the_plan_let_through(probed_under_loss):
    """The fate of each message (``faults.plan.fate``, keyed by its edge and tick) decides: at tick
    ``k`` an in-neighbour is heard with its newest message of a tick before ``k`` that was not
    lost, as old as that makes it (every loss run here is far shorter than the 0.5 s an estimate
    stays usable); one never yet let through is not heard. Edges without a rule lose nothing."""
    from swarm_sitl.faults.plan import edge_channel, fate

    cfg, rec = probed_under_loss
    dt, plan, edges = cfg.control_dt_s, cfg.faults, cfg.graph_edges()
    for i, s in rec.followers.items():
        for src in sorted(src for src, d in edges if d == i):
            rules = plan.on_edge(src, i, edges)
            lost = [
                bool(rules)
                and fate(plan.seed, rules, edge_channel(src, i), j, j * dt, cfg.duration_s, dt).lost
                for j in range(cfg.n_control_steps)
            ]
            p = LOSSY.get((src, i), 0.0)  # (100 draws: within five standard deviations of the rate)
            assert abs(sum(lost) / len(lost) - p) <= 5 * (p * (1 - p) / len(lost)) ** 0.5, (src, i)
            for k in range(cfg.n_control_steps + 1):
                heard = [int(x) for x in s["from"][k] if not np.isnan(x)]
                through = [j for j in range(k) if not lost[j]]
                assert (src in heard) == bool(through), (i, src, k)
                if through:
                    slot = heard.index(src)
                    assert s["sent_at"][k][slot] == through[-1] * dt, (i, src, k)
                    assert s["age"][k][slot] == k * dt - through[-1] * dt, (i, src, k)


@pytest.mark.parametrize("planned", [False, True], ids=["plain", "planned"])
def test_a_vehicle_that_reports_late_and_noisy_gives_the_law_what_its_sensors_report(tmp_path, planned):
    """With ``vehicle.sensors`` (latency, noise, a drifting bias), the sample of tick ``k`` is what
    a fresh copy of the vehicle's sensor model (``plant.sensors``, seeded as the vehicle is) reports
    at ``k`` ms times the period, fed the recorded true states in order; through the wire's float32,
    as without sensors; plain, and on the planned path (a plan that touches no vehicle link)."""
    from sim_vehicles.common.state import POS, QUAT, RATE, STATE_SIZE, VEL
    from sim_vehicles.models.build import sensor_model

    # (past 0.5 s: a tick's ms is not t * 1001's)
    data = _probe_config(tmp_path, duration_s=1.0, **({"faults": LATE_DROP} if planned else {}))
    data["vehicle"]["sensors"] = {
        "position_noise_m": 0.05,
        "velocity_noise_mps": 0.02,
        "attitude_noise_rad": 0.01,
        "latency_s": 0.03,
        "seed": 4,
        "position_bias_walk_m_per_sqrt_s": 0.1,
    }
    cfg = _loaded(tmp_path, data)
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

    cfg = _loaded(tmp_path, _probe_config(tmp_path, duration_s=0.5, **({"faults": plan} if plan else {})))
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
    cfg = _loaded(tmp_path, data)
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

    data = _probe_config(tmp_path, duration_s=0.5)
    data["followers"][3]["initial_velocity_mps"] = [0.5, -0.25, 1.0]
    data["followers"][3]["initial_quaternion_wxyz"] = [0.6, 0.0, 0.8, 0.0]
    cfg = _loaded(tmp_path, data)
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


#: a plan of the MAVLink and process kinds: vehicle 2's setpoints stop for 0.7 s, half of
#: vehicle 3's samples are lost, a third of vehicle 4's setpoints, and the leader's process is
#: killed at 0.3 s and back at 0.5 s
LINK_AND_PROCESS_FAULTS = {
    "seed": 5,
    "plan": [
        {"mavlink": 2, "direction": "up", "drop": True, "from_s": 0.2, "until_s": 0.9},
        {"mavlink": 3, "direction": "down", "loss": 0.5},
        {"mavlink": 4, "direction": "up", "loss": 0.3},
        {"leader": True, "kill": True, "from_s": 0.3, "restart_after_s": 0.2},
    ],
}


def test_under_link_and_process_faults_sim_flies_the_failsafe_carries_samples_and_loses_the_leader(tmp_path):
    """Vehicle 2 without setpoints from 0.2 s enters its failsafe ``setpoint_timeout_s`` (0.5 s)
    later and leaves it when they come again at 0.9 s: the run's events, in time order. A tick
    whose sample was lost carries the newest one before it, recorded with that sample's true state
    and time, and its position error measured at that time; about half are lost, never the first.
    The leader's followers hear its messages up to the tick before it was killed, then, from its
    restart on, its new ones."""
    from swarm_sitl.running.sim import run_sim_spooled

    cfg = _loaded(tmp_path, _probe_config(tmp_path, duration_s=1.5, faults=LINK_AND_PROCESS_FAULTS))
    rec = run_sim(cfg)
    dt, trajectory = cfg.control_dt_s, cfg.trajectory()
    said = [(e["t_s"], e["kind"], e["source"]) for e in rec.events]
    assert said == [(0.7, "failsafe_enter", "vehicle_2"), (0.9, "failsafe_exit", "vehicle_2")]
    assert run_sim_spooled(cfg, tmp_path / "spool").events == rec.events  # (spooled, the same)
    s = rec.followers[3]
    carried = np.nonzero(s["sample_t_s"] < s["t_s"])[0]
    assert 0 not in carried and abs(len(carried) / len(s["t_s"]) - 0.5) < 5 * (0.25 / len(s["t_s"])) ** 0.5
    for k in carried:
        j = round(s["sample_t_s"][k] / dt)  # the row of the sample carried: its own, the newest before k
        assert s["sample_t_s"][j] == s["t_s"][j] and (s["sample_t_s"][j + 1 : k] < s["t_s"][j + 1 : k]).all()
        assert (s["p_W"][k] == s["p_W"][j]).all() and (s["sample_p"][k] == s["sample_p"][j]).all()
        assert s["sample_t"][k] == s["sample_t_s"][k]  # (the law is told the carried sample's time)
        offset = np.asarray(cfg.follower(3).offset_m)
        expected = np.linalg.norm(s["p_W"][j] - trajectory.derivatives(s["sample_t_s"][k])[0] - offset)
        assert np.linalg.norm(s["pos_err_m"][k]) == pytest.approx(expected, rel=1e-12, abs=1e-12)
    up = [k for k in range(cfg.n_control_steps + 1) if k < 30 or k >= 50]  # (the leader's ticks)
    for i in (1, 2, 3):
        f = rec.followers[i]
        for k in range(1, cfg.n_control_steps + 1):
            newest = max(j for j in up if j < k)
            assert f["from"][k][0] == 0 and f["sent_at"][k][0] == newest * dt, (i, k)


def _mavlink_lost(cfg, vehicle: int, uplink: bool, k: int) -> bool:
    """Whether the plan loses (or corrupts) tick ``k``'s datagram on one way of ``vehicle``'s link:
    ``faults.plan.fate`` keyed by its ``time_boot_ms``, as the MAVLink wrapper draws it."""
    from swarm_sitl.faults.plan import fate, mavlink_channel

    plan, ms = cfg.faults, round(k * cfg.control_dt_s * 1000)
    rules = plan.on_mavlink(vehicle, uplink)
    period_ms = round(cfg.control_dt_s * 1000)
    f = fate(
        plan.seed,
        rules,
        mavlink_channel(vehicle, uplink),
        ms,
        ms / 1000,
        cfg.duration_s,
        cfg.control_dt_s,
        ms // period_ms,
    )
    return bool(rules) and (f.lost or f.corrupt)


def test_the_datagrams_a_plan_loses_on_a_vehicles_link_are_its_fates(tmp_path):
    """Each way of a vehicle's MAVLink link loses the datagrams whose fate says so (never the
    first sample: it answers the controller's request). A lost sample: the tick carries the newest
    one before it. A lost setpoint: the vehicle flies that period on the one it holds, so its
    vertical acceleration over each period is that of the newest setpoint that came. Links
    without a rule lose nothing."""
    cfg = _loaded(tmp_path, _probe_config(tmp_path, duration_s=1.5, faults=LINK_AND_PROCESS_FAULTS))
    rec = run_sim(cfg)
    n, dt, m, g = cfg.n_control_steps, cfg.control_dt_s, cfg.vehicle.mass_kg, cfg.gravity_mps2
    for i, s in rec.followers.items():
        carried = [k for k in range(n + 1) if s["sample_t_s"][k] < s["t_s"][k]]
        assert carried == [k for k in range(1, n + 1) if _mavlink_lost(cfg, i, False, k)], i
    s = rec.followers[4]
    came = [k for k in range(n) if not _mavlink_lost(cfg, 4, True, k)]
    assert 0 < len(came) < n  # (some lost, some not)
    level = AttitudeCommand(np.array([1.0, 0.0, 0.0, 0.0]), 0.0)
    for k in range(n):
        newest = max(j for j in came if j <= k)
        held = command_roundtrip(
            level._replace(thrust_N=s["thrust_N"][newest]), s["ctx"][0][5], cfg.vehicle.max_thrust_N
        )
        a = held.thrust_N / m - g
        assert s["v_W"][k + 1][2] == pytest.approx(s["v_W"][k][2] + a * dt, abs=1e-12), k
