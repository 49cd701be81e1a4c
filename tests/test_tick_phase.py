"""Staggered real-time ticks (``run.realtime_ticks``): where each follower ticks in the period, and
that a tick phase only shifts the follower's time, in its law and in the recorded errors."""

import numpy as np
import pytest

from swarm_sitl.bus.codec import Message
from swarm_sitl.laws.contract import VehicleSample, reference_values
from swarm_sitl.nodes.assembly import build_law
from swarm_sitl.rundir.recording import Recording, leader_series

pytestmark = pytest.mark.unit


def test_staggered_followers_share_the_period_evenly_and_lockstep_is_aligned(paper_cfg):
    cfg = paper_cfg
    dt, n = cfg.control_dt_s, cfg.n_followers
    phases = [cfg.tick_phase_s(f.id, lockstep=False) for f in cfg.followers]
    assert cfg.run.realtime_ticks == "staggered"
    assert phases[0] == 0.0 and all(0.0 <= p < dt for p in phases)
    assert np.allclose(np.diff(phases), dt / n)
    assert all(cfg.tick_phase_s(f.id, lockstep=True) == 0.0 for f in cfg.followers)
    aligned = cfg.model_copy(update={"run": cfg.run.model_copy(update={"realtime_ticks": "aligned"})})
    assert all(aligned.tick_phase_s(f.id, lockstep=False) == 0.0 for f in cfg.followers)


def test_a_tick_phase_shifts_the_controllers_time_and_nothing_else(paper_cfg):
    """Controller A ticks at k dt + phi; controller B at k dt is given the same messages and samples
    with every time stamp moved back by phi. The law is time-invariant but for those stamps, so the
    two must compute the same commands and estimates; A ignoring its phase would see every message
    and sample phi younger than it is, and differ."""
    cfg = paper_cfg
    dt, phi = cfg.control_dt_s, 0.0075
    traj = cfg.trajectory()
    a = build_law(cfg, 3)
    b = build_law(cfg, 3)
    offset = np.asarray(cfg.follower(3).offset_m)
    q = np.array([1.0, 0.0, 0.0, 0.0])
    for k in range(40):
        t_msg = (k - 1) * dt  # the leader's message of the tick before: sent at its own (aligned) tick
        d = traj.derivatives(t_msg)
        t_sample = k * dt + phi - 0.004  # the latest telemetry, 4 ms old
        ds = traj.derivatives(t_sample)
        p = ds[0] + offset + 0.3 * np.array([1.0, -0.5, 0.2])
        steps = []
        for law, shift in ((a, 0.0), (b, phi)):
            inbox = {} if k == 0 else {0: Message(0, k - 1, t_msg - shift, reference_values(d))}
            step = law.step(k * dt + phi - shift, VehicleSample(t_sample - shift, p, ds[1], q), inbox)
            steps.append((step.message.copy(), step.record.copy(), np.array([step.command.thrust_N])))
        for x, y in zip(*steps, strict=True):
            np.testing.assert_allclose(x, y, rtol=1e-9, atol=1e-9)


def test_estimator_errors_are_taken_at_each_followers_own_ticks(paper_cfg):
    """A follower whose estimate is exactly the leader's state at its (staggered) ticks has no
    estimation error; judged at the leader's ticks it would show |v| * phase."""
    cfg = paper_cfg
    traj, dt, phi = cfg.trajectory(), cfg.control_dt_s, 0.006
    t_leader = np.arange(101) * dt
    t_f = t_leader + phi
    d = traj.derivatives(t_f)
    n = len(t_f)
    nan3 = np.full((n, 3), np.nan)
    follower = {
        "t_s": t_f,
        "sample_t_s": t_f - 0.003,
        "p_W": traj.derivatives(t_f - 0.003)[:, 0],
        "v_W": traj.derivatives(t_f - 0.003)[:, 1],
        "p_hat": d[:, 0],
        "v_hat": d[:, 1],
        "a_hat": d[:, 2],
        "q_WB": nan3,
    }
    rec = Recording(leader_series(traj, t_leader), {1: follower}, {1: np.zeros(3)}).with_errors(traj)
    a = rec.followers[1]
    for key in ("est_pos_err_m", "est_vel_err_mps", "est_acc_err_mps2", "pos_err_m", "vel_err_mps"):
        assert np.abs(a[key]).max() < 1e-12, key
    lagged = np.linalg.norm(d[:, 0] - rec.leader["p_r"], axis=1)
    assert lagged.min() > 0.5 * phi * np.linalg.norm(d[:, 1], axis=1).min()  # what it would have shown
