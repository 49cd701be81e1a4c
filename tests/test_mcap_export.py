"""``swarm-sitl export``: a run as MCAP, read back with the ``mcap`` library (not our writer)."""

import json

import numpy as np
import pytest
from mcap.reader import make_reader

from swarm_sitl.cli import main
from swarm_sitl.rundir.load import load_run
from swarm_sitl.rundir.outputs import write_outputs
from swarm_sitl.running.sim import run_sim

pytestmark = pytest.mark.integration


@pytest.fixture(scope="module")
def run_dir(paper_cfg, tmp_path_factory):
    cfg = paper_cfg.model_copy(update={"duration_s": 2.0})
    d = tmp_path_factory.mktemp("run")
    (d / "config.yaml").write_text(cfg.to_yaml())
    write_outputs(cfg, run_sim(cfg), d)
    return d


def test_the_mcap_has_a_channel_per_follower_and_edge_and_its_poses_are_the_run(run_dir, paper_cfg, capsys):
    assert main(["export", str(run_dir)]) == 0
    assert "run.mcap" in capsys.readouterr().out
    rec = load_run(run_dir)
    poses: dict[str, list] = {}
    schemas = {}
    with open(run_dir / "run.mcap", "rb") as f:
        reader = make_reader(f)
        for schema, channel, message in reader.iter_messages():
            schemas[channel.topic] = schema.name
            poses.setdefault(channel.topic, []).append((message.log_time, json.loads(message.data)))
    followers = [f"/follower_{f.id}/pose" for f in paper_cfg.followers]
    edges = [f"/edge/{s}/{d}" for s, d in paper_cfg.graph_edges()]
    assert set(followers + edges + ["/leader/pose", "/leader/reference"]) <= set(poses)
    assert all(schemas[t] == "foxglove.PoseInFrame" for t in [*followers, "/leader/pose"])
    n = len(rec.leader["t_s"])
    for f in paper_cfg.followers:
        msgs = poses[f"/follower_{f.id}/pose"]
        a = rec.followers[f.id]
        assert len(msgs) == n
        got = np.array([[m["pose"]["position"][k] for k in "xyz"] for _, m in msgs])
        q = np.array([[m["pose"]["orientation"][k] for k in "wxyz"] for _, m in msgs])
        assert np.array_equal(got, a["p_W"]) and np.array_equal(q, a["q_WB"])  # exact: JSON floats
        assert [t for t, _ in msgs] == [round(t * 1e9) for t in a["t_s"]]
    # what follower 1 published on 1 -> 4 is its estimate of the leader at each tick
    est = poses["/edge/1/4"]
    assert np.array_equal(np.array([m["p_hat"] for _, m in est]), rec.followers[1]["p_hat"])
    lead = np.array([m["p_hat"] for _, m in poses["/edge/0/1"]])
    assert np.allclose(lead, rec.leader["p_r"], rtol=0, atol=1e-12)


def test_export_of_a_folder_that_is_not_a_run_is_one_line(tmp_path, capsys):
    assert main(["export", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not a run directory" in err[0]
