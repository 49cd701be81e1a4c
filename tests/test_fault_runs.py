"""Fault plans on the swarm as real processes, through the CLI: deterministic lockstep runs under
every kind of link fault, a bound that fails a degraded run, and riding through in real time.

(The user-style lockstep scenarios, a lossy edge and a cut edge, are in ``examples/``.)"""

import json
import subprocess
import sys
import time

import numpy as np
import pytest
import yaml

from tests.conftest import CONFIGS

pytestmark = pytest.mark.system

CLI = [sys.executable, "-m", "swarm_sitl"]

EVERY_KIND = {
    "seed": 11,
    "plan": [
        {"edge": [1, 4], "loss": 0.3},
        {"into": 4, "delay_s": 0.02, "jitter_s": 0.03},
        {"out_of": 2, "duplicate": 0.2},
        {"leader_edges": True, "corrupt": 0.05},
        {"edge": [0, 3], "stall": True, "from_s": 2, "until_s": 3},
        {"edge": [0, 2], "reorder": 0.3},
        {"edge": [0, 1], "drop": True, "from_s": 4, "until_s": 5},
    ],
}
SAME_BYTES = ["config.yaml", "summary.json", "events.jsonl", "leader.npz"] + [
    f"follower_{i}.npz" for i in range(1, 5)
]


def _run(path, out, *extra, timeout=240):
    t0 = time.monotonic()
    r = subprocess.run(
        [*CLI, "run", str(path), "--out", str(out), "--quiet", *map(str, extra)],
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    return r, time.monotonic() - t0


def test_a_lockstep_run_under_every_link_fault_is_the_same_twice_and_never_stalls(tmp_path):
    plan = tmp_path / "plan.yaml"
    plan.write_text(yaml.safe_dump(EVERY_KIND))
    outs = []
    for name in ("a", "b"):
        out = tmp_path / name
        r, wall = _run(CONFIGS / "paper.yaml", out, "--duration", 8, "--faults", plan)
        assert r.returncode == 0, r.stderr + r.stdout
        assert wall < 60  # the default stall timeout is 20 s: nothing waited on a message that never came
        outs.append(out)
    for name in SAME_BYTES:
        assert (outs[0] / name).read_bytes() == (outs[1] / name).read_bytes(), name
    s = json.loads((outs[0] / "summary.json").read_text())
    links = s["links"]
    assert links["1->4"]["lost"] > 0.2 * links["1->4"]["received"]
    # every estimate into 4 is delayed but the last one, sent at the end of the plan's window
    assert links["2->4"]["duplicated"] > 0 and links["2->4"]["delayed"] == links["2->4"]["received"] - 1
    assert all(links[f"0->{i}"]["corrupt"] > 0 for i in (1, 2, 3))
    assert links["0->1"]["lost"] == 100  # the cut: 4 s to 5 s, every message
    d = links["1->4"]["delay_s"]
    assert 0.02 <= d["median"] <= d["p99"] <= d["max"] <= 0.05
    kinds = {e["kind"] for e in (json.loads(x) for x in (outs[0] / "events.jsonl").read_text().splitlines())}
    assert {"fault_start", "fault_end"} <= kinds
    for i in range(1, 5):
        a = np.load(outs[0] / f"follower_{i}.npz")
        assert np.isfinite(a["p_W"]).all() and len(a["t_s"]) == 801


def test_a_run_past_its_bound_exits_non_zero_naming_the_follower_and_its_stale_input(tmp_path):
    """Real time, an edge cut and a bound: the run completes, says what went wrong, and fails."""
    cfg = yaml.safe_load((CONFIGS / "paper.yaml").read_text())
    cfg["run"] = {"max_formation_error_m": 0.05, "settle_s": 8.0}
    cfg["faults"] = {"plan": [{"edge": [0, 1], "drop": True, "from_s": 5}]}
    path = tmp_path / "cut.yaml"
    path.write_text(yaml.safe_dump(cfg))
    r, _ = _run(path, tmp_path / "rt", "--realtime", "--duration", 12)
    assert r.returncode == 3, r.stderr + r.stdout
    lines = r.stderr.strip().splitlines()
    named = [ln for ln in lines if ln.startswith("swarm-sitl: error: follower ")]
    assert named and named[0].startswith("swarm-sitl: error: follower 1: formation error"), r.stderr
    assert "exceeds run.max_formation_error_m = 0.05 m" in named[0]
    assert "neighbour estimates past staleness" in named[0]
    assert all("follower 2" not in ln and "follower 3" not in ln for ln in named)
    s = json.loads((tmp_path / "rt" / "summary.json").read_text())
    assert s["inputs"]["1"]["stale_estimates"] > 500


def test_real_time_rides_through_half_an_edge_lost(tmp_path):
    cfg = yaml.safe_load((CONFIGS / "paper.yaml").read_text())
    cfg["faults"] = {"seed": 2, "plan": [{"edge": [1, 4], "loss": 0.5}]}
    path = tmp_path / "loss.yaml"
    path.write_text(yaml.safe_dump(cfg))
    out = tmp_path / "rt"
    r, _ = _run(path, out, "--realtime", "--duration", 25)
    assert r.returncode == 0, r.stderr + r.stdout
    s = json.loads((out / "summary.json").read_text())
    link = s["links"]["1->4"]
    assert 0.4 < link["lost"] / link["received"] < 0.6
    for i in range(1, 5):
        a = np.load(out / f"follower_{i}.npz")
        e = np.linalg.norm(a["pos_err_m"], axis=1)
        assert np.nanmax(e[a["t_s"] >= 20]) < 0.1, i
