"""Laws on the rotor-level quadrotor (``configs/paper_quad.yaml``): the paper's law and
``consensus_pd`` fly ``px4_quad_x`` as processes in lockstep exactly as ``sim`` flies it, bit for
bit, and a fault plan flies it through the ``swarm`` fixture."""

import numpy as np
import pytest
import yaml

from swarm_sitl.config.load import load_config, parse_config
from swarm_sitl.running.sim import run_sim
from tests.support import CONFIGS, ROOT, cli

#: its system tests run in lockstep or ``sim`` only (no wall clock): free to run beside others
pytestmark = [pytest.mark.system, pytest.mark.lockstep]


def _lockstep_equals_sim(tmp_path, path, duration_s: float) -> None:
    out = tmp_path / "run"
    r = cli("run", path, "--duration", duration_s, "--out", out, "--quiet", timeout=240)
    assert r.returncode == 0, r.stderr + r.stdout
    cfg = load_config(path)
    sim = run_sim(cfg.model_copy(update={"duration_s": duration_s}))
    for i in sim.followers:
        a = np.load(out / f"follower_{i}.npz")
        for key, v in sim.followers[i].items():
            assert np.array_equal(a[key], v, equal_nan=True), (i, key)


def test_the_paper_law_flies_the_quadrotor_as_processes_equal_to_sim(tmp_path):
    _lockstep_equals_sim(tmp_path, CONFIGS / "paper_quad.yaml", 6.0)


def test_consensus_pd_flies_the_quadrotor_as_processes_equal_to_sim(tmp_path):
    data = yaml.safe_load((CONFIGS / "consensus_pd.yaml").read_text())
    data["vehicle"] = yaml.safe_load((CONFIGS / "paper_quad.yaml").read_text())["vehicle"]
    data["law"]["entry"] = str(ROOT / "examples" / "laws" / "consensus_pd.py") + ":ConsensusPD"
    path = tmp_path / "consensus_quad.yaml"
    path.write_text(yaml.safe_dump(data))
    parse_config(data)  # (a config the schema takes)
    _lockstep_equals_sim(tmp_path, path, 4.0)


def test_a_fault_plan_on_the_quadrotor_through_the_swarm_fixture(swarm):
    """Half the estimates 1 -> 4 lost and controller 2 killed at 8 s, started again at 9 s: the
    formation holds within 5 cm from 15 s, and follower 2 is back within the rejoin bound."""
    plan = [
        {"edge": [1, 4], "loss": 0.5},
        {"controller": 2, "kill": True, "from_s": 8, "restart_after_s": 1},
    ]
    r = swarm(CONFIGS / "paper_quad.yaml", duration_s=20, faults=plan, seed=4)
    assert r.ok, r.failure
    assert r.max_formation_error_m(after_s=15) < 0.05
    (restart,) = r.summary["rejoins"]
    assert restart["followers"]["2"]["verdict"] == "rejoined"
    assert 0.3 < r.links["1->4"]["lost"] / r.links["1->4"]["received"] < 0.7
