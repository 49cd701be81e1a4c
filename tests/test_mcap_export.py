"""``swarm-sitl export``: a run as MCAP, read back with the ``mcap`` library (not our writer)."""

import json
import shutil

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader

from swarm_sitl.cli import main
from swarm_sitl.rundir.events import write_events
from swarm_sitl.rundir.load import load_run
from swarm_sitl.rundir.mcap_export import ESTIMATE_FIELDS, write_mcap
from swarm_sitl.rundir.outputs import write_outputs
from swarm_sitl.running.sim import run_sim

pytestmark = pytest.mark.integration


@pytest.fixture(scope="module")
def run_dir(paper_cfg, tmp_path_factory):
    cfg = paper_cfg.model_copy(update={"duration_s": 2.0})
    d = tmp_path_factory.mktemp("run")
    (d / "config.yaml").write_text(yaml.safe_dump(cfg.data()))
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


JSON_TYPES = {
    "number": (int, float),
    "integer": (int,),
    "string": (str,),
    "array": (list,),
    "object": (dict,),
}


def _declared(schema: dict, value: object, where: str = "") -> None:
    """``value`` is what ``schema`` declares, at every level: its JSON type, and for an object
    each field (none left undeclared but where it says its fields are open), for an array each
    item. Foxglove's panels type a field by its schema."""
    kind = schema.get("type")
    assert kind in JSON_TYPES, f"{where}: no JSON type declared ({schema})"
    assert isinstance(value, JSON_TYPES[kind]) and not isinstance(value, bool), (
        f"{where}: {value!r} is not {kind}"
    )
    if kind == "object":
        assert isinstance(value, dict)
        for k, v in value.items():
            if k in schema.get("properties", {}):
                _declared(schema["properties"][k], v, f"{where}.{k}")
            else:
                assert schema.get("additionalProperties") is True, f"{where}.{k}: not declared"
        assert set(schema.get("required", [])) <= set(value), f"{where}: a required field missing"
    elif kind == "array":
        assert isinstance(value, list)
        for j, v in enumerate(value):
            _declared(schema.get("items", {}), v, f"{where}[{j}]")


def test_every_message_is_what_its_schema_declares_at_its_own_time_and_the_events_are_the_runs(
    run_dir, paper_cfg, tmp_path
):
    d = tmp_path / "run"
    shutil.copytree(run_dir, d)
    rec = load_run(run_dir)
    events = [
        {"t_s": 0.5, "kind": "failsafe_enter", "vehicle": 2, "action": "land"},
        {"t_s": 1.25, "kind": "fault_start", "what": "edge 1->4", "unix_s": 1.8e9},
    ]
    write_events(d / "events.jsonl", events)
    a = dict(np.load(d / "follower_2.npz"))
    gap = len(a["t_s"]) // 2  # a row whose position was not recorded (a vehicle's report lost)
    a["p_W"][gap] = np.nan
    np.savez(d / "follower_2.npz", **a)
    path = tmp_path / "run.mcap"
    write_mcap(d, path)
    by_topic: dict[str, list] = {}
    with open(path, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            assert (channel.message_encoding, schema.encoding) == (
                "json",
                "jsonschema",
            )  # MCAP's well-known pair
            body = json.loads(message.data)
            _declared(json.loads(schema.data), body, channel.topic)
            assert message.log_time == message.publish_time
            by_topic.setdefault(channel.topic, []).append((message.log_time, body))
    for topic, msgs in by_topic.items():
        for ns, body in msgs:
            stamp = (
                body["timestamp"]["sec"] * 10**9 + body["timestamp"]["nsec"] if "timestamp" in body else None
            )
            assert ns == (stamp if stamp is not None else round(body["t_s"] * 1e9)), topic
    assert [b for _, b in by_topic["/events"]] == events
    lead = by_topic["/leader/pose"]
    np.testing.assert_array_equal(
        [[b["pose"]["position"][k] for k in "xyz"] for _, b in lead], rec.leader["p_r"]
    )
    assert all(b["pose"]["orientation"] == {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0} for _, b in lead)
    kept = [k for k in range(len(a["t_s"])) if k != gap]
    for part in ("pose", "state"):
        assert [ns for ns, _ in by_topic[f"/follower_2/{part}"]] == [round(a["t_s"][k] * 1e9) for k in kept]
    traj = paper_cfg.trajectory()
    for _, b in by_topic["/edge/0/1"]:
        want = traj.derivatives(b["t_s"])
        for j, name in enumerate(ESTIMATE_FIELDS):
            assert b[name] == want[j].tolist()
    assert [b["t_s"] for _, b in by_topic["/edge/1/4"]] == rec.followers[1]["t_s"].tolist()
