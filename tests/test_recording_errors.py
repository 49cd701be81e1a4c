"""A follower's rows as recorded (``rundir.recording``): each named series is the part of the row
its layout gives it, whatever the law's fields; and the error series are the recorded state less
the leader's reference at the instant the state is of, for any ticks (the leader's, staggered,
a sample older than its tick, rows not recorded).

The reference is evaluated here one instant at a time from the trajectory, independently of the
vectorised path the recording takes (and of the leader's recorded arrays it takes where the
instants are the leader's ticks); the offsets are the config's. Tolerance: the two evaluations
agree to a few ulps of the trajectory's values (tens of metres): 1e-12 relative.
"""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from sim_vehicles.common.command import AttitudeCommand
from sim_vehicles.common.state import POS, QUAT, RATE, STATE_SIZE, VEL
from swarm_sitl.rundir.recording import COMMAND_FIELDS, FollowerSeries, Recording, leader_series
from tests.strategies import FUZZ
from tests.support import config

pytestmark = pytest.mark.unit

TRAJECTORY = config("paper").trajectory()
DT_S = 0.01


def _reference(t: float) -> np.ndarray:
    """``(p_r, v_r, a_r)`` at one instant (NaN: no instant)."""
    if np.isnan(t):
        return np.full((3, 3), np.nan)
    return np.asarray(TRAJECTORY.derivatives(np.array([t])))[0, :3]


@st.composite
def recordings(draw):
    n = draw(st.integers(2, 30))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    t_lead = np.arange(n) * DT_S
    followers, offsets, clocks = {}, {}, {}
    for i in range(1, draw(st.integers(1, 3)) + 1):
        clock = draw(st.sampled_from(["lockstep", "staggered", "older samples", "no sample column"]))
        t = t_lead + (rng.uniform(0, DT_S) if clock == "staggered" else 0.0)
        lost = rng.random(n) < draw(st.sampled_from([0.0, 0.3]))  # rows not recorded
        t = np.where(lost, np.nan, t)
        a = {"t_s": t, **{k: rng.normal(0, 20, (n, 3)) for k in ("p_W", "v_W", "p_hat", "v_hat", "a_hat")}}
        if clock == "older samples":
            a["sample_t_s"] = t - rng.uniform(0, DT_S, n)
        elif clock != "no sample column":
            a["sample_t_s"] = t.copy()
        if draw(st.booleans()):  # a law that records no estimates of the leader
            for k in ("p_hat", "v_hat", "a_hat"):
                del a[k]
        followers[i], offsets[i], clocks[i] = a, rng.normal(0, 5, 3), clock
    return Recording(leader_series(TRAJECTORY, t_lead), followers, offsets), clocks


@FUZZ
@given(drawn=recordings())
def test_each_error_is_the_state_less_the_reference_at_the_instant_the_state_is_of(drawn):
    rec, _ = drawn
    before = {i: {k: v.copy() for k, v in a.items()} for i, a in rec.followers.items()}
    once = rec.with_errors(TRAJECTORY)
    for i, a in before.items():
        got = once.followers[i]
        ts = a.get("sample_t_s", a["t_s"])
        at_sample = np.array([_reference(x) for x in ts])
        at_tick = np.array([_reference(x) for x in a["t_s"]])
        close = {"rtol": 1e-12, "atol": 1e-12, "equal_nan": True}
        np.testing.assert_allclose(got["pos_err_m"], a["p_W"] - at_sample[:, 0] - rec.offsets[i], **close)
        np.testing.assert_allclose(got["vel_err_mps"], a["v_W"] - at_sample[:, 1], **close)
        if "p_hat" in a:
            np.testing.assert_allclose(got["est_pos_err_m"], a["p_hat"] - at_tick[:, 0], **close)
            np.testing.assert_allclose(got["est_vel_err_mps"], a["v_hat"] - at_tick[:, 1], **close)
            np.testing.assert_allclose(got["est_acc_err_mps2"], a["a_hat"] - at_tick[:, 2], **close)
        else:
            assert not {"est_pos_err_m", "est_vel_err_mps", "est_acc_err_mps2"} & set(got)
        assert np.array_equal(np.isnan(got["pos_err_m"]).any(axis=1), np.isnan(ts))  # missing: NaN
    again = {i: {k: v.copy() for k, v in a.items()} for i, a in once.followers.items()}
    twice = once.with_errors(TRAJECTORY)  # idempotent
    for i, a in again.items():
        for k, v in a.items():
            np.testing.assert_array_equal(twice.followers[i][k], v)


@FUZZ
@given(seed=st.integers(0, 2**32 - 1), fields=st.lists(st.integers(1, 4), min_size=1, max_size=5))
def test_each_series_is_the_part_of_the_row_its_layout_gives_it(seed, fields):
    rng = np.random.default_rng(seed)
    record_fields = {f"f{j}": w for j, w in enumerate(fields)}
    n, n_in = 6, 2
    s = FollowerSeries(n, record_fields, n_in)
    states, commands, records, samples = [], [], [], []
    for k in range(n - 1):  # the last row never recorded
        state = rng.normal(size=STATE_SIZE)
        q = rng.normal(size=4)
        cmd = AttitudeCommand(
            q_c=q / np.linalg.norm(q),
            thrust_N=float(rng.uniform(0, 30)),
            omega_c_B=rng.normal(size=3),
            omegadot_c_B=rng.normal(size=3),
        )
        record = rng.normal(size=sum(fields))
        sample = None if k % 2 else k * DT_S - 0.003
        s.record_vehicle(k, k * DT_S, state, sample)
        s.record_controller(k, cmd, record, rng.normal(size=n_in))
        states.append(state), commands.append(cmd), records.append(record), samples.append(sample)
    a = s.arrays()
    k = n - 1
    assert np.isnan(a["t_s"][k]) and np.isnan(a["sample_t_s"][k]) and np.isnan(a["p_W"][k]).all()
    for k, (x, cmd, r, sample) in enumerate(zip(states, commands, records, samples, strict=True)):
        assert a["sample_t_s"][k] == (k * DT_S if sample is None else sample)  # none given: its tick
        for name, part in (("p_W", POS), ("v_W", VEL), ("q_WB", QUAT), ("omega_B", RATE)):
            assert a[name][k].tolist() == x[part].tolist()
        assert a["thrust_N"][k] == cmd.thrust_N and a["thrust_N"].shape == (n,)
        assert a["q_c"][k].tolist() == cmd.q_c.tolist() and a["omega_c"][k].tolist() == cmd.omega_c_B.tolist()
        assert a["omegadot_c"][k].tolist() == cmd.omegadot_c_B.tolist()
        at = 0
        for name, w in record_fields.items():
            want = r[at : at + w]
            assert (
                (a[name][k] == want[0] and a[name].shape == (n,))
                if w == 1
                else a[name][k].tolist() == want.tolist()
            )
            at += w
    assert set(COMMAND_FIELDS) <= set(a)
