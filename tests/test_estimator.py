"""The distributed estimator alone, on the directed ring, with gains that satisfy Theorem 1."""

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from swarm_sitl.laws.contract import Received, VehicleSample, reference_values
from swarm_sitl.laws.gain_conditions import check_gains
from swarm_sitl.laws.zou_meng import ZouMengLaw
from swarm_sitl.nodes.assembly import law_context
from tests.support import config

pytestmark = pytest.mark.integration


def test_estimator_converges_to_the_leader_on_the_cyclic_graph(ring_cfg):
    graph = ring_cfg.build_graph()
    report = check_gains(graph, ring_cfg.gain_dict(), ring_cfg.trajectory(), ring_cfg.gravity_mps2, 200.0)
    assert not report.all_hold  # the paper's gains do not satisfy Theorem 1 on the ring
    gains = {**ring_cfg.gain_dict(), **report.suggestion}
    assert check_gains(graph, gains, ring_cfg.trajectory(), ring_cfg.gravity_mps2, 200.0).all_hold
    cfg = ring_cfg.model_copy(update={"gains": ring_cfg.gains.model_copy(update=report.suggestion)})
    dt = cfg.control_dt_s

    def law(i: int) -> ZouMengLaw:
        ctx = law_context(cfg, i)
        return ZouMengLaw(dataclasses.replace(ctx, params=ctx.params._replace(substeps=100)))

    laws = {i: law(i) for i in range(1, 5)}
    sources = {i: [s for s, _ in graph.in_neighbours(i)] for i in laws}
    # the estimator does not use the vehicle: a fixed sample stands in for it
    sample = VehicleSample(0.0, np.zeros(3), np.zeros(3), np.array([1.0, 0, 0, 0]))
    latest: dict[int, Received] = {}
    err = []
    n = round(30.0 / dt)
    for k in range(n + 1):
        t = k * dt
        new = {0: reference_values(cfg.trajectory().derivatives(t))}
        for i, c in laws.items():
            inbox = {s: latest[s]._replace(age_s=t - latest[s].t_s) for s in sources[i] if s in latest}
            new[i] = c.step(t, sample._replace(t_s=t), inbox).message
        latest = {s: Received(v, t, 0.0) for s, v in new.items()}
        d = cfg.trajectory().derivatives(t)
        err.append(
            max(max(np.linalg.norm(new[i][0:3] - d[0]), np.linalg.norm(new[i][3:6] - d[1])) for i in laws)
        )
    err = np.array(err)
    t = np.arange(n + 1) * dt
    assert err[0] >= 5.0  # starts far (estimates at zero, leader at [5, 0, 0])
    # k_a = 31 makes sgn() chatter; with 0.1 ms estimator steps the floor is about 1 mm (0.5 ms: 7 mm)
    assert err[t >= 20.0].max() < 2e-3


def test_a_tick_after_a_long_gap_keeps_the_internal_step(tmp_path):
    """Regression from a real run (configs/swarm16.yaml in real time on an overloaded machine):
    follower 8 stalled 1.28 s between two ticks. Advancing over the gap in the 10 RK4 substeps of
    one period (h = 128 ms) turned its estimator into NaN; at the configured internal step
    (1 ms) it stays finite and its estimate moves to where its neighbours say the leader is."""
    from swarm_sitl.nodes.assembly import reported_vehicle_params

    cfg = config("swarm16")
    ctrl = ZouMengLaw(law_context(cfg, 8, *reported_vehicle_params(cfg)))
    assert [s for s, _ in ctrl.weights] == [3, 4]
    ctrl.state = np.array(
        [-4.757962741168665, -1.536824883177032, 17.270000000000056, 0.307604847480344, -0.9526119772205924,
         0.999999999999998, 0.40914127714274184, 0.0939371009027566, 0.0, -0.01631647568256747,
         0.10008970812733083, 0.0, 0.0006148942087254209, -0.008329182322908697, 3.041619089462685e-05,
         0.003454216646615267, -0.007063268194157468, 0.0005611977498840371]
    )  # fmt: skip
    prev = [17.267760242766947, 1.2443294525146484, -3.553597927093506, 17.26675033569336,
            0.31489306688308716, -0.9687008857727051, 1.0000463724136353, 0.999944442191014,
            -0.004749756421773924, 0.00941022556736777, 8.429369772832967e-08]  # fmt: skip
    ctrl._prev_sample = VehicleSample(prev[0], np.array(prev[1:4]), np.array(prev[4:7]), np.array(prev[7:11]))
    ctrl._prev_t = 17.27
    ctrl._prev_acc = np.array([0.18457523437473233, 0.09316329159330908, -0.0044710809965859966])
    rows = {
        3: [18.47, -4.256305970337456, -2.6236954941802604, 18.47, 0.5248363641483657, -0.851296198240883,
            1.0, 0.17103254992387842, 0.10468944777348439, 0.0, -0.01957261313351058, 0.033960257590095994,
            0.0],
        4: [18.13, -4.424739757704056, -2.3284334988706465, 18.13, 0.4657852623147619, -0.8849843445912079,
            1.0, 0.17783240062023417, 0.09289036738446227, 0.0, -0.017422410751370906, 0.03628958581452627,
            0.0],
    }  # fmt: skip
    t = 1855 * cfg.control_dt_s
    inbox = {s: Received(np.array(r[1:13]), r[0], t - r[0]) for s, r in rows.items()}
    q = np.array([0.9999999981104012, -1.645318455160787e-05, 2.219406222313708e-05, -5.491734213121736e-05])
    p = np.array([1.754791021347046, -4.721144199371338, 18.545101165771484])
    v = np.array([0.42843690514564514, -0.8896619081497192, 0.9973580837249756])
    sample = VehicleSample(18.54876024276695, p, v, q)
    out = ctrl.step(t, sample, inbox)
    assert np.isfinite(out.message).all() and np.isfinite(out.record).all() and np.isfinite(ctrl.state).all()
    told = np.mean([m.values[0:3] + m.values[3:6] * (18.55 - m.t_s) for m in inbox.values()], axis=0)
    assert np.linalg.norm(out.message[0:3] - told) < 0.3


def test_the_paper_laws_params_give_the_kernels_each_gain_by_its_name():
    from swarm_sitl.laws.paper_gains import PaperGains
    from swarm_sitl.laws.zou_meng import ZouMengParams

    names = list(PaperGains.model_fields)
    gains = PaperGains(**{n: float(j + 1) for j, n in enumerate(names)})
    g = ZouMengParams(gains, 0.05, 12.0).control_gains(0.85, 9.81)
    assert {n: getattr(g, n) for n in names} == {n: float(j + 1) for j, n in enumerate(names)}
    assert (g.sign_boundary_layer, g.bracket_a_weight, g.mass_kg, g.g_mps2) == (0.05, 12.0, 0.85, 9.81)


@given(
    age=st.floats(1e-4, 0.05),
    p=st.tuples(*[st.floats(-0.2, 0.2)] * 3),
    v=st.tuples(*[st.floats(-0.2, 0.2)] * 3),
)
@settings(max_examples=30, deadline=None)
def test_a_sample_older_than_its_tick_is_carried_to_it_under_the_last_commanded_acceleration(age, p, v):
    """Real time: a vehicle sample ``age`` seconds old at tick t gives the law what the sample
    carried to t gives it (``p + v age + a age^2 / 2``, ``v + a age``, under the acceleration the
    previous tick commanded), taken at t: the same command and the same message. (Near its place
    in the formation, where the auxiliary system is not saturated: the command's rates read the
    sample there.) Bit for bit: the kernel carries it by the same expression."""
    from swarm_sitl.nodes.assembly import reported_vehicle_params

    cfg = config("paper")
    dt = cfg.control_dt_s
    old, carried = (ZouMengLaw(law_context(cfg, 1, *reported_vehicle_params(cfg))) for _ in range(2))
    q = np.array([0.99, 0.1, -0.05, 0.0])
    q /= np.linalg.norm(q)  # (tilted: the commanded thrust accelerates it sideways)
    p0, v0 = np.array(p) + old.offset, np.array(v)
    for law in (old, carried):  # the same first tick
        law.step(
            0.0,
            VehicleSample(0.0, p0, v0, q),
            {0: Received(reference_values(cfg.trajectory().derivatives(0.0)), 0.0, 0.0)},
        )
    acc = old._prev_acc
    assert np.array_equal(acc, carried._prev_acc) and np.linalg.norm(acc) > 0
    inbox = {0: Received(reference_values(cfg.trajectory().derivatives(dt)), dt, 0.0)}
    a = old.step(dt, VehicleSample(dt - age, p0, v0, q), inbox)
    age = dt - (dt - age)  # (the age the law reads: t less the sample's instant, rounded)
    b = carried.step(dt, VehicleSample(dt, p0 + v0 * age + 0.5 * acc * age * age, v0 + acc * age, q), inbox)
    np.testing.assert_array_equal(a.message, b.message)
    for got, want in zip(a.command, b.command, strict=True):
        np.testing.assert_array_equal(got, want)


def test_a_tick_whose_output_is_not_finite_says_so_with_what_it_was_given():
    """Follower 4 (two in-neighbours) with a non-finite state, at its first tick and at a later
    one: one error naming the follower, the time, each message's age, and the inputs the
    controller saves to replay the tick (the previous sample empty where there was none)."""
    from swarm_sitl.laws.command_attitude import SingularCommandError
    from swarm_sitl.nodes.assembly import reported_vehicle_params

    cfg = config("paper")
    dt = cfg.control_dt_s
    law = ZouMengLaw(law_context(cfg, 4, *reported_vehicle_params(cfg)))
    assert [s for s, _ in law.weights] == [1, 2]
    sample = VehicleSample(0.0, np.zeros(3), np.zeros(3), np.array([1.0, 0.0, 0.0, 0.0]))
    msg = np.zeros(12)
    for t, prev_len in ((0.0, 0), (dt, 14)):  # (t, p, v, q and the acceleration carried)
        if t > 0:
            law.state = np.zeros_like(law.state)
            law.step(0.0, sample, {})  # a finite first tick, then a non-finite one
        law.state = np.full_like(law.state, np.nan)
        inbox = {1: Received(msg, t - 0.25, 0.25), 2: Received(msg, t - 0.5, 0.5)}
        with pytest.raises(SingularCommandError) as e:
            law.step(t, sample._replace(t_s=t), inbox)
        said = str(e.value)
        assert said.startswith(f"follower 4 at t={t:.3f}s: controller output is not finite")
        assert "message ages [0.250, 0.500] s" in said and "\n" not in said
        inputs = e.value.inputs
        assert set(inputs) == {"t", "prev_t", "state_before", "msgs", "sample", "prev_sample"}
        assert (
            inputs["t"] == t
            and np.isnan(inputs["state_before"]).all()
            and len(inputs["prev_sample"]) == prev_len
        )


def _paper_law(follower: int, **params):
    from swarm_sitl.nodes.assembly import reported_vehicle_params

    cfg = config("paper")
    ctx = law_context(cfg, follower, *reported_vehicle_params(cfg))
    if params:
        ctx = dataclasses.replace(ctx, params=ctx.params._replace(**params))
    return cfg, ZouMengLaw(ctx)


def _leader_inbox(cfg, t: float, age: float = 0.0) -> dict:
    return {0: Received(reference_values(cfg.trajectory().derivatives(t - age)), t - age, age)}


@given(
    t0=st.floats(0.0, 30.0),
    gaps=st.lists(st.integers(1, 3), min_size=1, max_size=3),
    hold=st.sampled_from([0, 1]),
)
@settings(max_examples=20, deadline=None)
def test_a_step_is_the_kernels_tick_its_command_message_and_record_the_ticks_output(t0, gaps, hold):
    """A law's first step, at any time (a restarted controller's starts late), keeps the state it
    has; each later one advances it from the last tick at the configured internal step (however
    many periods passed) carrying the previous sample; the command, the message and the record
    are the tick's output and state, field by field."""
    from swarm_sitl.laws.follower_law import (
        CTRL_SIZE,
        OUT_A_HAT,
        OUT_A_HAT_DOT,
        OUT_OMEGA_C,
        OUT_OMEGADOT_C,
        OUT_Q_C,
        OUT_THRUST,
        OUT_U,
        OUT_U_DDOT,
        OUT_U_DOT,
        TICK_ACC,
        TICK_OUT,
        TICK_STATE,
        controller_tick,
        gains_vector,
    )

    cfg, law = _paper_law(1, hold=hold)
    dt = cfg.control_dt_s
    q = np.array([0.99, 0.1, -0.05, 0.02])
    q /= np.linalg.norm(q)
    state, prev, prev_t, prev_acc = np.zeros(CTRL_SIZE), None, 0.0, np.zeros(3)
    t = t0
    for k, gap in enumerate([0, *gaps]):
        t += gap * dt
        p = cfg.trajectory().derivatives(t)[0] + law.offset + 0.1 * k
        sample = VehicleSample(t, p, np.array([0.2, -0.1, 0.05 * k]), q)
        inbox = _leader_inbox(cfg, t)
        msgs = np.array([[1.0, t, *inbox[0].values]])
        veh = sample if prev is None else prev
        n_sub = 0 if prev is None else law.substeps * gap
        want = controller_tick(
            state, prev_t, t, n_sub, msgs, hold, veh.t_s, veh.p_W, veh.v_W, prev_acc,
            sample.p_W, sample.v_W, sample.q_WB, 0.0, law.offset, gains_vector(law.gains), law.max_thrust_N,
        )  # fmt: skip
        got = law.step(t, sample, inbox)
        out = want[TICK_OUT]
        np.testing.assert_array_equal(got.command.q_c, out[OUT_Q_C])
        assert got.command.thrust_N == out[OUT_THRUST]
        np.testing.assert_array_equal(got.command.omega_c_B, out[OUT_OMEGA_C])
        np.testing.assert_array_equal(got.command.omegadot_c_B, out[OUT_OMEGADOT_C])
        x = want[TICK_STATE]
        a_hat = (out[OUT_A_HAT], out[OUT_A_HAT_DOT])
        np.testing.assert_array_equal(got.message, np.concatenate((x[0:6], *a_hat)))
        force = (out[OUT_U], out[OUT_U_DOT], out[OUT_U_DDOT])
        np.testing.assert_array_equal(got.record, np.concatenate((x, *force, *a_hat)))
        state, prev, prev_t, prev_acc = x, sample, t, want[TICK_ACC]


@pytest.mark.parametrize("hold", [0, 1])
@pytest.mark.parametrize("first", [True, False])
def test_a_sample_older_than_its_tick_is_taken_as_it_came_at_a_first_tick_or_under_a_zero_order_hold(
    hold, first
):
    """Only a later tick of a law that extrapolates carries a sample by its age (with no
    acceleration commanded yet, or messages held as they came, there is nothing to carry it by):
    elsewhere a sample ``age`` old gives what the same sample stamped at the tick gives."""
    cfg, old = _paper_law(1, hold=hold)
    _, now = _paper_law(1, hold=hold)
    dt = cfg.control_dt_s
    q = np.array([0.99, 0.1, -0.05, 0.0])
    q /= np.linalg.norm(q)
    p0 = cfg.trajectory().derivatives(0.0)[0] + old.offset + 0.3
    v0 = np.array([0.4, -0.2, 0.1])
    t = 0.0 if first else dt
    if not first:
        for law in (old, now):
            law.step(0.0, VehicleSample(0.0, p0, v0, q), _leader_inbox(cfg, 0.0))
    age = 0.004
    a = old.step(t, VehicleSample(t - age, p0, v0, q), _leader_inbox(cfg, t))
    b = now.step(t, VehicleSample(t, p0, v0, q), _leader_inbox(cfg, t))
    same = np.array_equal(a.record, b.record) and np.array_equal(a.command.q_c, b.command.q_c)
    assert same == (hold == 0 or first)  # (the carried sample itself: the test above)


def test_a_non_finite_ticks_error_says_whether_the_state_was_finite_and_how_old_its_inputs_were():
    """The line names the state's finiteness, the sample's age and, past five periods, that the
    inputs were stale; nothing after the message ages otherwise."""
    from swarm_sitl.laws.command_attitude import SingularCommandError
    from swarm_sitl.laws.zou_meng import STALE_INPUT_PERIODS

    cfg, law = _paper_law(4)
    dt = cfg.control_dt_s
    sample = VehicleSample(0.0, np.zeros(3), np.zeros(3), np.array([1.0, 0.0, 0.0, 0.0]))
    nan_msg = np.full(12, np.nan)
    for t, sample_age, msg_age, stale in (
        (1.0, 0.3 * dt, 0.5 * dt, False),
        (1.0, (STALE_INPUT_PERIODS + 1) * dt, 0.5 * dt, True),
        (1.0, 0.0, (STALE_INPUT_PERIODS + 2) * dt, True),
    ):
        law.state = np.zeros_like(law.state)
        law._prev_sample = None
        inbox = {1: Received(nan_msg, t - msg_age, msg_age), 2: Received(np.zeros(12), t, 0.0)}
        with pytest.raises(SingularCommandError) as e:
            law.step(t, sample._replace(t_s=t - sample_age), inbox)
        said = str(e.value)
        ages = f"sample age {sample_age:.3f} s, message ages [{msg_age:.3f}, 0.000] s"
        assert f"state finite: True, {ages}" in said
        oldest = max(sample_age, msg_age)
        assert said.endswith(
            f"; its inputs were up to {oldest:.2f} s old (in real time: a machine too slow for the swarm, "
            "try fewer followers or lockstep; or a fault plan held them)"
            if stale
            else "] s"
        ), said
    law.state = np.full_like(law.state, np.nan)
    with pytest.raises(SingularCommandError, match="state finite: False, "):
        law.step(2.0, sample._replace(t_s=2.0), {})
