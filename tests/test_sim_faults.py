"""``sim`` flies a fault plan as a lockstep run of processes flies it: the same run, bit for bit.

The plan below has every kind a lockstep run takes: each link how (``plan.LINK_HOW``) on an edge,
a partition, each of lockstep's MAVLink hows both ways, and every process fault (a controller
killed and restarted, the leader killed and restarted, a lost aircraft, a freeze). Its windows
overlap little, so each kind acts on the swarm; the test checks that they all do something.
"""

import json
import textwrap

import numpy as np
import pytest
import yaml
from pymavlink.dialects.v20 import common as mav

from swarm_sitl.config.load import load_config, parse_config
from swarm_sitl.faults.mavlink import sample_ms
from swarm_sitl.faults.plan import LINK_HOW, FaultPlan
from swarm_sitl.rundir.requirements import judge
from swarm_sitl.running.sim import run_sim
from swarm_sitl.specs.requirement import Requirement
from tests.support import CONFIGS, cli, config

#: its system tests run in lockstep or ``sim`` only (no wall clock): free to run beside others
pytestmark = pytest.mark.lockstep

SPEC = [
    {"name": "no_failsafe", "formula": "always (failsafe <= 0)"},
    {"name": "fresh", "over": "edges", "formula": "always[0.01, end] (age_s <= 0.2)"},
    {"name": "delivered", "over": "edges into 4", "formula": "always[1, end] (delivered_frac >= 0.5)"},
    {"name": "apart", "over": "pairs", "formula": "always (distance_m >= 0.5)"},
]
ARGS = ["--duration", "12", "--quiet", "--out"]

LINK_MODEL = textwrap.dedent(
    """
    from pydantic import BaseModel, Field

    from swarm_sitl.faults.link_model import Effect, MessageOnLink


    class DistanceDelay:
        needs_distance = True

        class Params(BaseModel):
            speed_mps: float = Field(gt=0)
            base_s: float = Field(default=0.0, ge=0)

        def fate(self, p: Params, m: MessageOnLink) -> Effect:
            return Effect(delay_s=p.base_s + m.distance_m / p.speed_mps)
    """
)


def every_kind(model_file: str, seed: int) -> dict:
    return {
        "seed": seed,
        "plan": [
            {"edge": [0, 1], "loss": 0.3, "from_s": 1, "until_s": 3},
            {"edge": [0, 2], "delay_s": 0.02, "jitter_s": 0.03, "from_s": 1, "until_s": 4},
            {"edge": [1, 4], "stall": True, "from_s": 2, "until_s": 2.5},
            {"edge": [2, 4], "duplicate": 0.3, "from_s": 1, "until_s": 5},
            {"edge": [0, 3], "reorder": 0.3, "from_s": 1, "until_s": 5},
            {"edge": [0, 3], "corrupt": 0.2, "from_s": 5, "until_s": 7},
            {"edge": [0, 1], "drop": True, "from_s": 4, "until_s": 4.5},
            {"into": 4, "bursty": {"p": 0.1, "r": 0.3}, "from_s": 6, "until_s": 8},
            {
                "all_edges": True,
                "range": {"range_m": 6, "fading_db": 4, "retries": 2, "retry_s": 0.004},
                "from_s": 8,
                "until_s": 9,
            },
            {"out_of": 2, "bandwidth": {"rate_bps": 20000, "queue": 2}, "from_s": 9, "until_s": 10},
            {"partition": [[0, 1], [2, 3, 4]], "from_s": 10, "until_s": 10.5},
            {
                "all_edges": True,
                "model": {
                    "entry": f"{model_file}:DistanceDelay",
                    "params": {"speed_mps": 200, "base_s": 0.005},
                },
                "from_s": 10.5,
                "until_s": 11,
            },
            {"mavlink": 1, "direction": "up", "loss": 0.3, "from_s": 1, "until_s": 3},
            {"mavlink": 2, "direction": "down", "corrupt": 0.3, "from_s": 1, "until_s": 3},
            {"mavlink": 3, "drop": True, "from_s": 3, "until_s": 4},  # both ways: its failsafe at 3.5 s
            {"mavlink": 4, "bursty": {"p": 0.2, "r": 0.5}, "from_s": 5, "until_s": 6},
            {"controller": 2, "kill": True, "from_s": 3, "restart_after_s": 1.5},
            {"leader": True, "kill": True, "from_s": 6, "restart_after_s": 1},
            {"controller": 3, "freeze_s": 0.5, "from_s": 7},
            {"vehicle": 3, "kill": True, "from_s": 11},
        ],
    }


@pytest.mark.system
def test_a_lockstep_run_under_every_fault_kind_equals_sim_bit_for_bit(tmp_path):
    model = tmp_path / "my_link.py"
    model.write_text(LINK_MODEL)
    seed = 5
    plan = every_kind(str(model), seed)
    hows = {k for e in plan["plan"] for k in e if k in LINK_HOW}
    assert hows == set(LINK_HOW)  # every link how is in the plan (a new one must be added here)
    (tmp_path / "plan.yaml").write_text(yaml.safe_dump(plan))
    (tmp_path / "spec.yaml").write_text(yaml.safe_dump(SPEC))
    out = tmp_path / "ls"
    r = cli(
        "run",
        str(CONFIGS / "paper.yaml"),
        "--faults",
        str(tmp_path / "plan.yaml"),
        "--spec",
        str(tmp_path / "spec.yaml"),
        *ARGS,
        str(out),
        timeout=300,
    )
    assert r.returncode == 3, r.stderr + r.stdout  # (the failsafe requirement fails: vehicle 3's)
    cfg = config("paper").model_copy(
        update={
            "duration_s": 12.0,
            "faults": FaultPlan.model_validate(plan),
            "spec": [Requirement.model_validate(q) for q in SPEC],
        }
    )
    sim = run_sim(cfg)
    clean = run_sim(cfg.model_copy(update={"faults": FaultPlan()}))
    for i in range(1, 5):
        a = dict(np.load(out / f"follower_{i}.npz"))
        assert set(a) - {"offset_m"} == set(sim.followers[i])  # (the file has the follower's offset)
        for key, x in a.items():
            if key == "offset_m":
                continue
            assert np.array_equal(x, sim.followers[i][key], equal_nan=True), (i, key)
        # the plan acted on each follower: its run is not the clean one
        assert not np.array_equal(a["p_W"], clean.followers[i]["p_W"], equal_nan=True), i
    # the requirements judge the same run the same, the failsafe (the vehicles' events) and the
    # edges' ages included
    lockstep_spec = json.loads((out / "summary.json").read_text())["spec"]
    assert lockstep_spec == json.loads(json.dumps(judge(cfg, sim, sim.events)))
    assert lockstep_spec["no_failsafe"]["members"]["3"] == -1.0  # vehicle 3's, 3.5 s to 4 s
    assert [e["kind"] for e in sim.events if e["vehicle"] == 3][:2] == ["failsafe_enter", "failsafe_exit"]
    dt = cfg.control_dt_s
    f2, f3 = sim.followers[2], sim.followers[3]
    assert np.isnan(f2["t_s"][300:450]).all() and np.isfinite(f2["t_s"][:300]).all()  # killed at 3 s
    assert np.isfinite(f2["t_s"][450:]).all()  # and back at 4.5 s
    assert np.isnan(f3["t_s"][1100:]).all() and np.isfinite(f3["t_s"][:1100]).all()  # lost at 11 s
    # vehicle 3's samples lost from 3 s to 4 s: its ticks carry the one of 2.99 s
    assert (f3["sample_t_s"][300:400] == 2.99).all()
    assert np.allclose(f3["t_s"][:300], np.arange(300) * dt, rtol=0, atol=1e-12)


#: air and sensors that differ by vehicle (each vehicle's own gusts and noise, drawn by its id)
WINDY = {
    "wind": {
        "mean_mps": [5.0, 0.0, 0.0],
        "gust_mps": 1.0,
        "gust_time_s": 2.0,
        "seed": 3,
        "model": "independent",
    },
    "vehicle": {"drag_Ns2pm2": 0.02, "sensors": {"position_noise_m": 0.03, "seed": 1}},
}


@pytest.mark.unit
@pytest.mark.parametrize("swarm", ["still", "gusts-and-noise", "two-arducopters"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_plan_that_does_nothing_to_the_swarm_flies_the_plain_sim(seed, swarm):
    """The planned path (stages, inboxes, the vehicle's modes) and the plain one are one run: in
    still air, in gusts with noisy reports (each vehicle's its own), and with two of the four
    vehicles ArduCopters (GUIDED_NOGPS, their thrust read as a climb rate)."""
    data = yaml.safe_load((CONFIGS / "paper.yaml").read_text())
    data["duration_s"] = 3.0
    if swarm == "gusts-and-noise":
        data["vehicle"].update(WINDY["vehicle"])
        data["wind"] = WINDY["wind"]
    if swarm == "two-arducopters":
        for f in data["followers"][2:]:
            f["autopilot"] = "ardupilot"
    cfg = parse_config(data)
    quiet = FaultPlan.model_validate(
        {
            "seed": seed,
            "plan": [{"controller": 1 + seed, "freeze_s": 1, "from_s": 1}, {"edge": [0, 1], "loss": 1e-12}],
        }
    )
    a = run_sim(cfg)
    b = run_sim(cfg.model_copy(update={"faults": quiet}))
    for i, s in a.followers.items():
        for key, x in s.items():
            assert np.array_equal(x, b.followers[i][key], equal_nan=True), (i, key)


@pytest.mark.unit
def test_a_sample_is_found_behind_a_statustext_in_its_datagram():
    """A vehicle says STATUSTEXT (its failsafe) in the pass that sends a sample: the plan's fate
    for that sample must still find it (it once let it through as start-up traffic)."""
    m = mav.MAVLink(None, srcSystem=3, srcComponent=1)
    text = m.statustext_encode(4, b"Failsafe: offboard setpoints lost, hold").pack(m)
    lpos = m.local_position_ned_encode(3500, 1.5, -2.0, 0.5, 0.1, 0.2, 0.3).pack(m)
    assert sample_ms(lpos) == 3500
    assert sample_ms(text + lpos) == 3500
    assert sample_ms(text) is None and sample_ms(text + text) is None
    # MAVLink 2 trims a payload's trailing zeros: a vehicle at rest at the origin sends a short one
    short = m.local_position_ned_encode(3500, 0, 0, 0, 0, 0, 0).pack(m)
    assert short[1] < 4 and sample_ms(text + short) == 3500


@pytest.mark.unit
def test_sim_refuses_what_lockstep_cannot_fly_in_one_line(tmp_path):
    plan = tmp_path / "plan.yaml"
    plan.write_text(yaml.safe_dump({"plan": [{"mavlink": 1, "delay_s": 0.1}]}))
    r = cli(
        "sim", str(CONFIGS / "paper.yaml"), "--faults", str(plan), "--out", str(tmp_path / "o"), timeout=120
    )
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "faults.plan.0" in lines[0] and "lockstep" in lines[0], r.stderr


@pytest.mark.system
def test_noisy_late_reports_under_sample_loss_and_a_restart_equal_sim(tmp_path):
    """With sensors that report late (a history of states) and noisy, a lost sample is still sent
    and kept by the vehicle's sensors, and a restarted controller's vehicle reports through its
    gap: sim keeps the same history, so the runs are equal, bit for bit."""
    data = yaml.safe_load((CONFIGS / "paper.yaml").read_text())
    data["duration_s"] = 6.0
    data["vehicle"]["sensors"] = {"position_noise_m": 0.03, "latency_s": 0.02, "seed": 4}
    data["faults"] = {
        "seed": 2,
        "plan": [
            {"mavlink": 2, "direction": "down", "loss": 0.4, "from_s": 1, "until_s": 4},
            {"controller": 3, "kill": True, "from_s": 2, "restart_after_s": 1.0},
            {"edge": [1, 4], "loss": 0.3},
        ],
    }
    config = tmp_path / "noisy.yaml"
    config.write_text(yaml.safe_dump(data))
    out = tmp_path / "ls"
    r = cli("run", str(config), "--out", str(out), "--quiet", timeout=300)
    assert r.returncode == 0, r.stderr + r.stdout
    sim = run_sim(load_config(config))
    for i in range(1, 5):
        a = dict(np.load(out / f"follower_{i}.npz"))
        for key, x in a.items():
            if key != "offset_m":
                assert np.array_equal(x, sim.followers[i][key], equal_nan=True), (i, key)
    carried = sim.followers[2]["sample_t_s"] < sim.followers[2]["t_s"] - 1e-9
    assert carried.sum() > 50  # the plan lost samples: ticks carried older ones
