"""What ``sim`` gives a law and its vehicle under a fault plan (``running.sim_plan``), seen by the
probe law (``tests/probe_law.py``): each edge's messages as the plan's fates let them through; a
vehicle's lost setpoints and samples, its failsafe's events; a leader killed and restarted. The
fates are drawn by ``faults.plan.fate``, the reference the processes' fault wrappers use.
"""

import numpy as np
import pytest

from swarm_sitl.running import sim_plan
from swarm_sitl.running.sim import run_sim
from tests.probe_law import climb_acceleration, loaded, probe_config

pytestmark = pytest.mark.integration


#: the edges a plan loses messages on, and at which rate
LOSSY = {(0, 1): 0.3, (1, 4): 0.5}


@pytest.fixture  # (a test's own: a mutation tester maps a run to the test that made it)
def probed_under_loss(tmp_path):
    """The paper's swarm flown 1 s in ``sim`` by the probe under a plan that loses messages on two
    edges; and its config."""
    plan = {"seed": 11, "plan": [{"edge": list(e), "loss": p} for e, p in LOSSY.items()]}
    cfg = loaded(tmp_path, probe_config(tmp_path, duration_s=1.0, faults=plan))
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


#: a plan of the MAVLink and process kinds: vehicle 2's setpoints stop for 0.7 s, half of
#: vehicle 3's samples are lost, a third of vehicle 4's setpoints, and the leader's process is
#: killed at 0.3 s and back at 0.5 s
LINK_AND_PROCESS_FAULTS = {
    "seed": 5,
    "plan": [
        {"mavlink": 2, "direction": "up", "drop": True, "from_s": 0.2, "until_s": 0.9},
        {"mavlink": 3, "direction": "down", "loss": 0.5},
        # (bursts of mean length 2: its fates depend on the chain a datagram's time stamp keys)
        {"mavlink": 4, "direction": "up", "bursty": {"p": 0.2, "r": 0.5, "loss_bad": 1.0, "loss_good": 0.0}},
        {"leader": True, "kill": True, "from_s": 0.3, "restart_after_s": 0.2},
    ],
}


def test_under_link_and_process_faults_sim_flies_the_failsafe_carries_samples_and_loses_the_leader(tmp_path):
    """Vehicle 2 without setpoints from 0.2 s enters its failsafe ``setpoint_timeout_s`` (0.5 s)
        later and leaves it when they come again at 0.9 s: the run's events, in time order, each naming
    the vehicle. A tick
        whose sample was lost carries the newest one before it, recorded with that sample's true state
        and time, and its position error measured at that time; about half are lost, never the first.
        The leader's followers hear its messages up to the tick before it was killed, then, from its
        restart on, its new ones."""
    from swarm_sitl.running.sim import run_sim_spooled

    cfg = loaded(tmp_path, probe_config(tmp_path, duration_s=1.5, faults=LINK_AND_PROCESS_FAULTS))
    rec = run_sim(cfg)
    dt, trajectory = cfg.control_dt_s, cfg.trajectory()
    said = [(e["t_s"], e["kind"], e["source"], e["vehicle"]) for e in rec.events]
    assert said == [(0.7, "failsafe_enter", "vehicle_2", 2), (0.9, "failsafe_exit", "vehicle_2", 2)]
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


@pytest.mark.parametrize("in_blocks", [True, False], ids=["fates-in-blocks", "fate-by-fate"])
def test_the_datagrams_a_plan_loses_on_a_vehicles_link_are_its_fates(tmp_path, monkeypatch, in_blocks):
    """Each way of a vehicle's MAVLink link loses the datagrams whose fate says so (never the
    first sample: it answers the controller's request). A lost sample: the tick carries the newest
    one before it. A lost setpoint: the vehicle flies that period on the one it holds, so its
    vertical acceleration over each period is that of the newest setpoint that came. Links
    without a rule lose nothing. The same whether the fates are drawn a block at a time (a
    built-in model's) or one by one (a model with no block form, as a user's may be)."""
    if not in_blocks:
        monkeypatch.setattr(sim_plan, "batched", lambda rules: False)
    cfg = loaded(tmp_path, probe_config(tmp_path, duration_s=1.5, faults=LINK_AND_PROCESS_FAULTS))
    rec = run_sim(cfg)
    n, dt = cfg.n_control_steps, cfg.control_dt_s
    for i, s in rec.followers.items():
        carried = [k for k in range(n + 1) if s["sample_t_s"][k] < s["t_s"][k]]
        assert carried == [k for k in range(1, n + 1) if _mavlink_lost(cfg, i, False, k)], i
    s = rec.followers[4]
    came = [k for k in range(n) if not _mavlink_lost(cfg, 4, True, k)]
    assert 0 < len(came) < n  # (some lost, some not)
    for k in range(n):
        newest = max(j for j in came if j <= k)
        a = climb_acceleration(cfg, s["thrust_N"][newest], s["ctx"][0][5])
        assert s["v_W"][k + 1][2] == pytest.approx(s["v_W"][k][2] + a * dt, abs=1e-12), k


@pytest.mark.parametrize("restart_s, back", [(0.2, 50), (0.004, 30)], ids=["after-20-ticks", "within-a-tick"])
def test_a_controller_killed_and_restarted_records_nothing_between_and_starts_afresh_on_its_vehicle(
    tmp_path, restart_s, back
):
    """Follower 2's controller killed at 0.3 s and started again ``restart_s`` later (tick
    ``back``; within one period: the same tick): it records nothing in between (its rows NaN),
    publishes nothing (follower 4 keeps hearing its message of 0.29 s, then its new ones); its
    new incarnation is a fresh law (the same first draw of its random stream) that hears nothing
    at its first tick and its in-neighbours from the next; and its vehicle, whose setpoints
    stopped for less than its timeout, flew the gap on the last one it had: its vertical motion
    across the periods from the last tick before the kill in closed form."""
    plan = {"seed": 2, "plan": [{"controller": 2, "kill": True, "from_s": 0.3, "restart_after_s": restart_s}]}
    cfg = loaded(tmp_path, probe_config(tmp_path, duration_s=1.0, faults=plan))
    rec = run_sim(cfg)
    n, dt = cfg.n_control_steps, cfg.control_dt_s
    down = range(30, back)
    s = rec.followers[2]
    for k in range(n + 1):
        assert (
            np.isnan(s["t_s"][k]) == np.isnan(s["thrust_N"][k]) == np.isnan(s["p_W"][k]).all() == (k in down)
        )
    assert np.isnan(s["from"][back]).all() and s["from"][back + 1][0] == 0
    assert s["sent_at"][back + 1][0] == back * dt
    assert (
        s["first_draw"][back] == s["first_draw"][0] and s["seen_t"][back] == s["sample_t"][back] == back * dt
    )
    f4 = rec.followers[4]  # (hears 1 and 2: 2 in its second slot)
    for k in range(1, n + 1):
        newest = max(j for j in range(k) if j not in down)
        assert f4["from"][k][1] == 2 and f4["sent_at"][k][1] == newest * dt, k
    a, gap = climb_acceleration(cfg, s["thrust_N"][29], s["ctx"][0][5]), (back - 29) * dt
    v, z = s["v_W"][29][2], s["p_W"][29][2]
    assert s["v_W"][back][2] == pytest.approx(v + a * gap, abs=1e-9)
    assert s["p_W"][back][2] == pytest.approx(z + v * gap + a * gap**2 / 2, abs=1e-9)
