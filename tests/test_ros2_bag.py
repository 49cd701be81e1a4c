"""``swarm-sitl export RUN_DIR --ros2``: a run directory as a rosbag2 (MCAP storage), read back by an
independent CDR reader (``mcap-ros2-support``) and by ``rosbags``' own reader: every topic's
messages are the recorded arrays (poses bit for bit, each odometry's twist the body-frame velocity
by a rotation written here), each topic's type hash in the bag's metadata, ``/clock`` at every
tick; and the CLI's errors are one line."""

import json
import shutil

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from swarm_sitl.ros2 import types
from swarm_sitl.rundir.events import write_events
from swarm_sitl.rundir.outputs import write_outputs
from swarm_sitl.rundir.ros2_bag import write_bag
from swarm_sitl.running.sim import run_sim
from tests.support import cli, config

pytestmark = pytest.mark.integration


@pytest.fixture(scope="module")
def bag(tmp_path_factory):
    d = tmp_path_factory.mktemp("ros2")
    cfg = config("paper").model_copy(update={"duration_s": 3.0})
    rec = run_sim(cfg)
    (d / "run").mkdir()
    write_outputs(cfg, rec, d / "run")
    counts = write_bag(d / "run", d / "bag", "/fleet")
    return cfg, rec, d, counts


def _decoded(path, topic):
    with open(path, "rb") as f:
        r = make_reader(f, decoder_factories=[DecoderFactory()])
        return [
            (m.log_time, schema.name, msg) for schema, _, m, msg in r.iter_decoded_messages(topics=[topic])
        ]


def _rotation(q):
    """Body to world of a Hamilton quaternion [w, x, y, z] (the textbook matrix)."""
    w, x, y, z = q / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def test_each_followers_pose_and_odometry_are_its_recorded_state(bag):
    _, rec, d, counts = bag
    mcap = d / "bag" / "bag.mcap"
    for i, a in rec.followers.items():
        poses = _decoded(mcap, f"/fleet/follower_{i}/pose")
        odoms = _decoded(mcap, f"/fleet/follower_{i}/odom")
        n = len(a["t_s"])
        assert len(poses) == len(odoms) == n == counts[f"/fleet/follower_{i}/pose"]
        for k, ((t_ns, name, p), (_, _, o)) in enumerate(zip(poses, odoms, strict=True)):
            assert name == types.POSE_STAMPED and t_ns == round(a["t_s"][k] * 1e9)
            assert (
                p.header.stamp.sec * 10**9 + p.header.stamp.nanosec == t_ns and p.header.frame_id == "world"
            )
            pos, q = p.pose.position, p.pose.orientation
            assert [pos.x, pos.y, pos.z] == a["p_W"][k].tolist()  # bit for bit
            assert [q.w, q.x, q.y, q.z] == a["q_WB"][k].tolist()
            tw = o.twist.twist
            v_body = _rotation(a["q_WB"][k]).T @ a["v_W"][k]
            np.testing.assert_allclose([tw.linear.x, tw.linear.y, tw.linear.z], v_body, rtol=0, atol=1e-12)
            assert [tw.angular.x, tw.angular.y, tw.angular.z] == a["omega_B"][k].tolist()
            op = o.pose.pose.position
            assert o.child_frame_id == f"follower_{i}" and [op.x, op.y, op.z] == [pos.x, pos.y, pos.z]


def test_each_edge_carries_what_its_sender_published_and_clock_every_tick(bag):
    cfg, rec, d, _ = bag
    mcap = d / "bag" / "bag.mcap"
    for src, dst in cfg.graph_edges():
        msgs = _decoded(mcap, f"/fleet/edge/from_{src}/to_{dst}")
        assert msgs and {name for _, name, _ in msgs} == {types.ESTIMATE}
        for t_ns, _, e in msgs:
            assert (e.src, e.dst) == (src, dst) and e.stamp.sec * 10**9 + e.stamp.nanosec == t_ns
            k = e.step
            if src == 0:
                expected = np.concatenate(cfg.trajectory().derivatives(rec.leader["t_s"][k])[:4])
            else:
                a = rec.followers[src]
                expected = np.concatenate([a[n][k] for n in ("p_hat", "v_hat", "a_hat", "a_hat_dot")])
            assert np.asarray(e.values).tolist() == expected.tolist()
    clock = _decoded(mcap, "/clock")
    assert [t for t, _, _ in clock] == [round(t * 1e9) for t in rec.leader["t_s"]]
    assert all(c.clock.sec * 10**9 + c.clock.nanosec == t for t, _, c in clock)


def test_the_leaders_reference_is_its_pose_and_odometry_and_each_event_is_one_json_string(bag, tmp_path):
    _, rec, d, _ = bag
    events = [
        {"t_s": 0.25, "kind": "failsafe_enter", "vehicle": 3, "action": "land"},
        {"t_s": 2.5, "kind": "vehicle_lost", "vehicle": 1, "source": "supervisor"},
    ]
    run = tmp_path / "run"
    shutil.copytree(d / "run", run)
    write_events(run / "events.jsonl", events)
    counts = write_bag(run, tmp_path / "bag", "/fleet")
    mcap = tmp_path / "bag" / "bag.mcap"
    said = _decoded(mcap, "/fleet/events")
    assert counts["/fleet/events"] == len(events)
    assert [json.loads(s.data) for _, _, s in said] == events
    assert [t for t, _, _ in said] == [round(e["t_s"] * 1e9) for e in events]
    assert {name for _, name, _ in said} == {types.STRING}
    poses, odoms = _decoded(mcap, "/fleet/leader/pose"), _decoded(mcap, "/fleet/leader/odom")
    assert [t for t, _, _ in poses] == [t for t, _, _ in odoms] == [round(t * 1e9) for t in rec.leader["t_s"]]
    for k, ((_, _, p), (_, _, o)) in enumerate(zip(poses, odoms, strict=True)):
        for pose in (p.pose, o.pose.pose):
            pos, q = pose.position, pose.orientation
            assert [pos.x, pos.y, pos.z] == rec.leader["p_r"][k].tolist() and [q.w, q.x, q.y, q.z] == [
                1,
                0,
                0,
                0,
            ]
        tw = o.twist.twist  # the reference does not turn: its body frame is the world's
        assert [tw.linear.x, tw.linear.y, tw.linear.z] == rec.leader["v_r"][k].tolist()
        assert [tw.angular.x, tw.angular.y, tw.angular.z] == [0, 0, 0]
        assert o.child_frame_id == "leader" and o.header.frame_id == p.header.frame_id == "world"


def test_the_bags_metadata_names_each_topics_type_and_hash_and_rosbags_reads_it(bag):
    from rosbags.rosbag2 import Reader

    _, _, d, counts = bag
    meta = yaml.safe_load((d / "bag" / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    topics = {t["topic_metadata"]["name"]: t for t in meta["topics_with_message_count"]}
    assert set(topics) == set(counts)
    for name, t in topics.items():
        tm = t["topic_metadata"]
        assert (
            tm["type_description_hash"] == types.type_hash(tm["type"]) and t["message_count"] == counts[name]
        )
        assert tm["serialization_format"] == "cdr"
    with Reader(d / "bag") as r:
        assert r.message_count == sum(counts.values())
        assert {c.topic for c in r.connections} == set(counts)


def test_the_cli_writes_the_bag_and_says_its_errors_in_one_line(bag, tmp_path):
    _, _, d, _ = bag
    args = ("export", d / "run", "--ros2")
    ok = cli(*args, "--out", tmp_path / "b", timeout=120)
    assert ok.returncode == 0 and "a rosbag2 (MCAP) of" in ok.stdout, ok.stderr
    for extra, said in (
        (["--out", tmp_path / "b"], "exists (rosbag2 writes a new directory)"),
        (["--out", tmp_path / "c", "--namespace", "/9lives"], "does not start with a digit"),
    ):
        r = cli(*args, *extra, timeout=120)
        assert r.returncode == 2 and r.stderr.count("\n") == 1 and said in r.stderr, r.stderr
