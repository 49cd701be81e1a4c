"""The run on ROS 2 topics (``run --ros2``): a lockstep paper run with its face on, read while it
flies by an independent ROS 2 client (``zenoh-ros2-sdk``, which computes each type's hash from its
``.msg`` text to subscribe) joining the run's router as its ROS 2 user, with the one line the run
writes. What it reads is the run's recorded state bit for bit; the graph it sees (liveliness
tokens) is the face's node and one publisher per topic; each put carries the 33-byte attachment;
the ROS 2 user reads nothing of ``swarm/**`` and what it puts there is refused; and the run equals
``sim`` bit for bit with all that going on. Also the state payload the face reads, over random
values and bad bytes."""

import json
import random
import re
import time

import numpy as np
import pytest
import zenoh

from swarm_sitl.bus.codec import PayloadError, State, decode_state, encode_state
from swarm_sitl.ros2 import types, wire
from swarm_sitl.running.sim import run_sim
from tests.support import CONFIGS, config, fresh_ros2_client, msg_dir, ros2_user_session, start_cli


@pytest.mark.unit
@pytest.mark.parametrize("seed", range(10))
def test_a_state_payload_round_trips_and_bad_bytes_are_one_line(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(0, 40))
    s = State(
        int(rng.integers(1, 255)), int(rng.integers(0, 2**32)), float(rng.normal()),
        rng.normal(size=3), rng.normal(size=3), rng.normal(size=4), rng.normal(size=3), rng.normal(size=n),
    )  # fmt: skip
    data = encode_state(s)
    back = decode_state(data)
    assert back.follower == s.follower and back.step == s.step and back.t_s == s.t_s
    for a, b in zip(back[3:], s[3:], strict=True):
        assert np.array_equal(a, b)
    with_nan_rates = s._replace(omega_B=np.full(3, np.nan))  # (not reported yet: allowed)
    assert np.isnan(decode_state(encode_state(with_nan_rates)).omega_B).all()
    cut = random.Random(seed).randrange(0, len(data))
    with pytest.raises(PayloadError, match="state payload has"):
        decode_state(data[:cut])
    for bad in (s._replace(p_W=np.array([0.0, np.inf, 0.0])), s._replace(values=np.full(max(n, 1), np.nan))):
        with pytest.raises(PayloadError, match="non-finite"):
            decode_state(encode_state(bad))


@pytest.mark.system
@pytest.mark.lockstep
def test_a_ros2_client_reads_a_lockstep_run_through_its_router_and_the_run_equals_sim(tmp_path, monkeypatch):
    out = tmp_path / "run"
    run = start_cli("run", CONFIGS / "paper.yaml", "--ros2", "--duration", 12, "--out", out, "--quiet")
    join_file = out / "ros2_join.json"
    end = time.monotonic() + 60
    while not join_file.is_file() and run.poll() is None and time.monotonic() < end:
        time.sleep(0.01)
    join = json.loads(join_file.read_text())
    password = (out / "zenoh_ros2_password.txt").read_text().strip()
    assert join["user"] == "ros2" and f"$(cat {out / 'zenoh_ros2_password.txt'})" in join["line"]
    override = re.search(r"ZENOH_CONFIG_OVERRIDE='(.*?)' ROS_DOMAIN_ID", join["line"]).group(1)
    override = override.replace("'\"$(cat " + str(out / "zenoh_ros2_password.txt") + ")\"'", password)
    # the independent client, configured by the run's own line (as rmw_zenoh reads it)
    from zenoh_ros2_sdk import ROS2Subscriber
    from zenoh_ros2_sdk.message_registry import get_registry

    fresh_ros2_client(monkeypatch)
    get_registry(str(msg_dir(tmp_path / "msgs", [types.POSE_STAMPED])))
    monkeypatch.setenv("ZENOH_CONFIG_OVERRIDE", override)
    poses: dict[int, list] = {i: [] for i in range(1, 5)}
    host, port = join["endpoint"].removeprefix("tcp/").split(":")
    subs = [
        ROS2Subscriber(
            f"/swarm/follower_{i}/pose",
            types.POSE_STAMPED,
            poses[i].append,
            router_ip=host,
            router_port=int(port),
        )
        for i in range(1, 5)
    ]
    assert {s.type_hash for s in subs} == {types.type_hash(types.POSE_STAMPED)}  # its own, from the .msg text
    # a raw session as the same user: the graph, the attachments, and swarm/** shut to it
    raw, writer = ros2_user_session(out), ros2_user_session(out)
    attachments: list[bytes] = []
    clock: list[bytes] = []

    def on_clock(s) -> None:
        attachments.append(s.attachment.to_bytes())
        clock.append(s.payload.to_bytes())

    raw.declare_subscriber("0/clock/**", on_clock)
    leaked: list[str] = []
    raw.declare_subscriber("swarm/**", lambda s: leaked.append(str(s.key_expr)))
    writer.put("swarm/paper/edge/0/1", b"\x04" + bytes(200))  # refused by the router (below)
    clock_key = wire.data_key(0, "/clock", types.CLOCK, types.type_hash(types.CLOCK))
    writer.put(clock_key, b"forged")  # and a put on a face's topic is refused too (below)
    tokens: list[str] = []
    nodes = ("/NN/%/%swarm/swarm_sitl", "/NN/%/%swarm/swarm_sitl_clock")  # the face's, the leader's
    clock_pub = "/MP/%/%swarm/swarm_sitl_clock/%clock/"  # (declared after its node)
    while not all(any(n in t for t in tokens) for n in (*nodes, clock_pub)) and run.poll() is None:
        tokens = [str(r.ok.key_expr) for r in raw.liveliness().get("@ros2_lv/0/**", timeout=1) if r.ok]
    stdout, stderr = run.communicate(timeout=300)
    raw.close()
    writer.close()
    for sub in subs:
        sub.close()
    assert run.returncode == 0, stderr + stdout

    # the graph: the face's node and one publisher per topic, as wire writes them, and the reader
    node = next(t for t in tokens if t.endswith(nodes[0]))
    zid = node.split("/")[2]
    assert node == wire.node_token(0, zid, 0, "/swarm", "swarm_sitl")
    face = [t for t in tokens if t.split("/")[2] == zid]
    assert len(face) == 1 + 1 + 2 * (1 + 4) + 5  # node, events, pose+odom x5, five edges
    listed = {
        (wire.demangle(t.split("/")[9]), t.split("/")[10]) for t in face if "/MP/" in t
    }  # (topic, type)
    topics = {("/swarm/events", types.STRING)}
    topics |= {(f"/swarm/{who}/{w}", ty) for who in ["leader", *(f"follower_{i}" for i in range(1, 5))]
               for w, ty in (("pose", types.POSE_STAMPED), ("odom", types.ODOMETRY))}  # fmt: skip
    topics |= {(f"/swarm/edge/from_{s}/to_{d}", types.ESTIMATE) for s, d in config("paper").graph_edges()}
    assert listed == {(t, wire.dds_type_name(ty)) for t, ty in topics}  # exactly the face's topics and types
    topic, h = "/swarm/follower_1/pose", types.type_hash(types.POSE_STAMPED)
    ours = (0, zid, 0)
    expected = {
        wire.publisher_token(*ours, e, "/swarm", "swarm_sitl", topic, types.POSE_STAMPED, h, wire.Qos())
        for e in range(1, len(face))
    }
    assert len(expected & set(face)) == 1
    assert any("/MS/" in t and "%swarm%follower_1%pose" in t for t in tokens if t not in face)
    # /clock: the leader's node and publisher, and every tick of the run's simulated time in
    # order, each dt after the one before (the forged put never came)
    leader = next(t for t in tokens if t.endswith(nodes[1]))
    published = [t for t in tokens if t.split("/")[2] == leader.split("/")[2] and "/MP/" in t]
    assert [(wire.demangle(t.split("/")[9]), t.split("/")[10]) for t in published] == [
        ("/clock", wire.dds_type_name(types.CLOCK))
    ]
    ns = [c.clock.sec * 10**9 + c.clock.nanosec for c in (types.decode(b, types.CLOCK) for b in clock)]
    assert ns == [round(k * 0.01 * 1e9) for k in range(1201)]
    # every put's attachment: 33 bytes, its sequence counting each put, its publisher's GID
    assert attachments and all(len(a) == 33 for a in attachments)
    seqs = [wire.Attachment.unpack(a).sequence for a in attachments]
    assert seqs == list(range(1, len(seqs) + 1))
    assert {wire.Attachment.unpack(a).gid for a in attachments} == {wire.gid(published[0])}
    assert leaked == []  # nothing of swarm/** reaches the ROS 2 user
    stats = json.loads((out / "procs" / "controller_1.stats.json").read_text())
    assert stats["report"]["dropped_payloads"] == 0  # and its put on an edge reached no node
    # what the client read is the vehicle's state at the stamp's tick as its controller sampled it:
    # the recorded truth in LOCAL_POSITION_NED's float32, bit for bit
    for i, read in poses.items():
        rec = np.load(out / f"follower_{i}.npz")
        assert read, f"the client read nothing of follower {i}"
        for m in read:
            k = round((m.header.stamp.sec + m.header.stamp.nanosec * 1e-9) / 0.01)
            pos = m.pose.position
            assert [pos.x, pos.y, pos.z] == rec["p_W"][k].astype(np.float32).astype(float).tolist()
    # and the run is sim's, bit for bit
    sim = run_sim(config("paper").model_copy(update={"duration_s": 12.0}))
    for i, s in sim.followers.items():
        a = np.load(out / f"follower_{i}.npz")
        for key in ("p_W", "v_W", "q_WB", "p_hat", "v_hat"):
            assert np.array_equal(a[key], s[key]), (i, key)


def _lone_session():
    """A zenoh session of this process alone (no scouting, no listener): its own puts reach its
    own subscribers, nothing leaves the process."""
    conf = zenoh.Config()
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("listen/endpoints", "[]")
    return zenoh.open(conf)


@pytest.mark.unit
def test_the_face_republishes_each_state_drops_bad_bytes_and_an_error_ends_it_not_the_run(tmp_path):
    from sim_vehicles.common.quaternion import rotation_matrix
    from swarm_sitl.bus import keys as zk
    from swarm_sitl.running.ros2_face import Ros2Face

    cfg = config("paper")
    session = _lone_session()
    got: dict[str, list[bytes]] = {}

    def heard(sample) -> None:
        topic = "/".join(str(sample.key_expr).split("/")[1:-2])  # (domain / topic / type / hash)
        got.setdefault(topic, []).append(sample.payload.to_bytes())

    session.declare_subscriber("0/**", heard)
    face = Ros2Face(session, cfg, tmp_path)
    rng = np.random.default_rng(3)
    sent = {}
    for i in range(1, 5):  # one state each (rates not reported yet), and a bad payload for follower 2
        q = rng.normal(size=4)
        sent[i] = State(i, 40, 0.4, rng.normal(size=3), rng.normal(size=3), q / np.linalg.norm(q),
                        np.full(3, np.nan), rng.normal(size=12))  # fmt: skip
        session.put(zk.state(cfg.name, i), encode_state(sent[i]))
    session.put(zk.state(cfg.name, 2), b"\x04garbage")
    time.sleep(0.2)
    face.act(0.0, 0.0)
    time.sleep(0.2)
    assert face.dropped == 1 and face.error is None
    topics = {
        "swarm/leader/pose",
        "swarm/leader/odom",
        "swarm/edge/from_0/to_1",
        "swarm/edge/from_2/to_4",
    }
    assert topics | {f"swarm/follower_{i}/{w}" for i in range(1, 5) for w in ("pose", "odom")} <= set(got)
    s3 = sent[3]
    odom = types.decode(got["swarm/follower_3/odom"][-1], types.ODOMETRY)
    tw = odom.twist.twist.linear
    np.testing.assert_allclose(
        [tw.x, tw.y, tw.z], np.asarray(rotation_matrix(s3.q_WB)).T @ s3.v_W, atol=1e-12
    )
    assert list(odom.twist.covariance[21::7]) == [-1.0, -1.0, -1.0]  # its rates: not known yet
    edge = types.decode(got["swarm/edge/from_2/to_4"][-1], types.ESTIMATE)
    assert np.array_equal(edge.values, sent[2].values) and (edge.src, edge.dst, edge.step) == (2, 4, 40)

    def broken() -> None:
        raise RuntimeError("a broken encoder")

    face._republish = broken  # type: ignore[method-assign]
    face.act(1.0, 1.0)
    assert face.error == "the ROS 2 face stopped: RuntimeError: a broken encoder"
    face.act(2.0, 2.0)  # said once; the face is closed, and its caller (the run) goes on
    session.close()


@pytest.mark.unit
def test_the_join_file_is_whole_or_absent_for_a_script_that_polls_for_it(tmp_path, monkeypatch):
    """A write cut short half way (a signal, a full disk) leaves no ``ros2_join.json`` at all: a
    ROS 2 user's script that waits for it never reads half of it."""
    from pathlib import Path

    from swarm_sitl.running.ros2_face import write_ros2_join

    cfg = config("paper").model_copy(
        update={"ros2": config("paper").ros2.model_copy(update={"enabled": True})}
    )
    real = Path.write_text

    def half_then_cut(self, text, *a, **kw):
        real(self, text[: len(text) // 2], *a, **kw)
        raise KeyboardInterrupt

    monkeypatch.setattr(Path, "write_text", half_then_cut)
    with pytest.raises(KeyboardInterrupt):
        write_ros2_join(cfg, "tcp/127.0.0.1:7447", tmp_path)
    monkeypatch.undo()
    assert list(tmp_path.iterdir()) == []
    line = write_ros2_join(cfg, "tcp/127.0.0.1:7447", tmp_path)
    assert json.loads((tmp_path / "ros2_join.json").read_text())["line"] == line
