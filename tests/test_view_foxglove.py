"""The live stream to Foxglove (``view.foxglove_live``, ``run --foxglove``), read by a client of
the protocol's own (a plain WebSocket, as Foxglove's app is one): the channels the MCAP export has,
with its schemas; each frame of the page's feed on them at its simulated time; nothing logged
to a channel no client wants; a client that never reads never holds the feed up; a port in use
is one line. And a lockstep run streamed as it flies: every pose a client gets is where the run
recorded its follower at that tick (to the page's millimetre)."""

import json
import re
import socket
import struct
import threading
import time

import numpy as np
import pytest

from swarm_sitl.bus.codec import Status
from swarm_sitl.view.foxglove_live import FoxgloveError, FoxgloveStream
from swarm_sitl.view.live import LiveFeed
from tests.support import CONFIGS, config, start_cli

#: its system tests run in lockstep or ``sim`` only (no wall clock): free to run beside others
pytestmark = pytest.mark.lockstep

websocket = pytest.importorskip("websocket", reason="websocket-client is in the test extra")
pytest.importorskip("foxglove", reason="foxglove-sdk is in the test extra")

SUBPROTOCOL = "foxglove.sdk.v1"  #: the SDK's name for Foxglove's WebSocket protocol
MESSAGE_DATA = struct.Struct("<BIQ")  #: opcode 1, subscription id, log time [ns]; the payload after
MM = 0.5e-3 + 1e-12  #: the page's frames have positions to the millimetre (``frames.num``)


class _Client:
    """A Foxglove client: the server's channels by topic, subscriptions, messages as they come."""

    def __init__(self, url: str):
        self.ws = websocket.create_connection(url, subprotocols=[SUBPROTOCOL], timeout=10)
        self.info: dict = {}
        self.channels: dict[str, dict] = {}
        while not self.channels:
            m = json.loads(self.ws.recv())
            if m["op"] == "serverInfo":
                self.info = m
            elif m["op"] == "advertise":
                self.channels = {c["topic"]: c for c in m["channels"]}
        self._topic_of: dict[int, str] = {}

    def subscribe(self, *topics: str) -> None:
        subs = []
        for topic in topics:
            sid = len(self._topic_of) + 1
            self._topic_of[sid] = topic
            subs.append({"id": sid, "channelId": self.channels[topic]["id"]})
        self.ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))

    def messages(self, until_s: float, first_s: float | None = None) -> list[tuple[str, int, dict]]:
        """(topic, log time [ns], message) until nothing comes for ``until_s`` or the server is gone;
        ``first_s``: how long the first message may take (a run still starting its processes on a
        loaded machine sends nothing yet: that silence is not its end)."""
        out: list[tuple[str, int, dict]] = []
        self.ws.settimeout(until_s if first_s is None else first_s)
        while True:
            try:
                data = self.ws.recv()
            except (
                websocket.WebSocketTimeoutException,
                websocket.WebSocketConnectionClosedException,
                OSError,
            ):
                return out  # (a run that ends may close its server's socket without a close frame: a reset)
            if isinstance(data, bytes) and data[0] == 1:
                _, sid, ns = MESSAGE_DATA.unpack_from(data)
                out.append((self._topic_of[sid], ns, json.loads(data[MESSAGE_DATA.size :])))
                self.ws.settimeout(until_s)

    def close(self) -> None:
        self.ws.close()


def _until(cond, what: str, timeout_s: float = 10.0) -> None:
    end = time.monotonic() + timeout_s
    while not cond():
        assert time.monotonic() < end, f"{what}: not within {timeout_s:g} s"
        time.sleep(0.02)


@pytest.fixture
def cfg():
    return config("paper")


def _statuses(cfg, k: int) -> dict[int, Status]:
    t = k * cfg.control_dt_s
    return {f.id: Status(f.id, k, t, t, np.array([f.id, -0.5 * k, 1.25 + 0.001 * k])) for f in cfg.followers}


@pytest.fixture
def streamed(cfg, tmp_path):
    """A live feed streaming to Foxglove on a free port, and a client connected to it."""
    stream = FoxgloveStream(cfg, "127.0.0.1", 0)
    feed = LiveFeed(cfg, tmp_path, lockstep=True)
    feed.sinks.append(stream)
    client = _Client(stream.url)
    yield stream, feed, client
    client.close()
    stream.close()


@pytest.mark.unit
def test_the_stream_has_the_exports_channels_and_carries_each_frame_at_its_time(cfg, streamed):
    stream, feed, client = streamed
    topics = {"/leader/pose", "/edges", "/events"}
    topics |= {f"/follower_{f.id}/{what}" for f in cfg.followers for what in ("pose", "formation")}
    assert set(client.channels) == topics
    assert client.channels["/follower_2/pose"]["schemaName"] == "foxglove.PoseInFrame"  # (the export's)
    assert all(c["encoding"] == "json" for c in client.channels.values())
    wanted = {"/follower_2/pose", "/follower_3/formation", "/edges"}
    client.subscribe(*wanted)
    _until(lambda: stream.subscribed() == wanted, "the subscriptions reach the server")
    for k in range(0, 100, 5):  # 20 frames a second of simulated time: every status makes one
        feed.update(_statuses(cfg, k), {3: 0.01 * k}, down={3} if 40 <= k < 60 else set())
    got = client.messages(1.0)
    by_topic: dict[str, list[tuple[int, dict]]] = {}
    for topic, ns, m in got:
        by_topic.setdefault(topic, []).append((ns, m))
    assert set(by_topic) == {"/follower_2/pose", "/follower_3/formation", "/edges"}
    ks = list(range(0, 100, 5))
    assert [ns for ns, _ in by_topic["/follower_2/pose"]] == [round(k * cfg.control_dt_s * 1e9) for k in ks]
    for k, (_, m) in zip(ks, by_topic["/follower_2/pose"], strict=True):
        p = m["pose"]["position"]
        assert m["frame_id"] == "world"
        assert np.allclose([p["x"], p["y"], p["z"]], _statuses(cfg, k)[2].p_W, rtol=0, atol=MM)
    for k, (_, m) in zip(ks, by_topic["/follower_3/formation"], strict=True):
        down = 40 <= k < 60
        assert m["down"] == down and (m["error_m"] is None if down else m["error_m"] == round(0.01 * k, 4))
    assert set(by_topic["/edges"][0][1]["age_s"]) == {f"{s}->{d}" for s, d in cfg.graph_edges() if s != 0}
    # nothing went to the channels no client subscribed to
    assert stream.logged == len(got) and not feed.sink_errors


@pytest.mark.integration
def test_a_client_that_never_reads_never_holds_the_feed_up(cfg, streamed):
    stream, feed, client = streamed
    client.subscribe(*client.channels)  # every channel, and then it reads nothing
    _until(lambda: stream.subscribed() == set(client.channels), "the subscriptions reach the server")
    done = threading.Event()

    def feed_frames() -> None:  # far more than the client's backlog and its socket's buffers
        for k in range(0, 40_000, 5):
            feed.update(_statuses(cfg, k), {}, set())
        done.set()

    th = threading.Thread(target=feed_frames, daemon=True)
    th.start()
    assert done.wait(120), "the feed was held up by a client that does not read"
    assert stream.logged == 8000 * 10 and not feed.sink_errors  # 10 channels a frame, whatever it dropped


@pytest.mark.unit
def test_a_port_in_use_is_one_line(cfg):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        with pytest.raises(FoxgloveError, match=rf"^cannot serve Foxglove on 127\.0\.0\.1:{port} \(") as e:
            FoxgloveStream(cfg, "127.0.0.1", port)
        assert "\n" not in str(e.value)


@pytest.mark.system
def test_a_lockstep_run_streams_where_it_recorded_each_follower(tmp_path):
    out = tmp_path / "run"
    argv = ["run", CONFIGS / "paper.yaml", "--duration", "20", "--foxglove", "0", "--out", out, "--quiet"]
    proc = start_cli(*argv, start_new_session=False)
    try:
        line = proc.stdout.readline() if proc.stdout else ""
        m = re.match(r"foxglove: (ws://127\.0\.0\.1:\d+) ", line)
        assert m, line
        client = _Client(m.group(1))  # (the run is starting up: its processes, then the start)
        client.subscribe("/follower_1/pose", "/leader/pose")
        got = client.messages(5.0, first_s=60.0)  # until the run is over and nothing comes
        client.close()
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    assert re.search(r"foxglove: \d+ messages logged\n", err) and "stopped" not in err
    a = np.load(out / "follower_1.npz")
    poses = [(ns, msg) for topic, ns, msg in got if topic == "/follower_1/pose"]
    # the feed is given the statuses 20 times a second of wall time: a lockstep run flying at
    # several times real time makes fewer frames than 20 a simulated second, in order, to its end
    times = [ns for ns, _ in poses]
    assert len(poses) >= 10 and times == sorted(set(times)) and times[-1] >= 10e9, times
    for ns, msg in poses:
        k = round(ns / 1e9 / 0.01)
        p = msg["pose"]["position"]
        assert np.allclose([p["x"], p["y"], p["z"]], a["p_W"][k], rtol=0, atol=MM), (k, p, a["p_W"][k])
    assert any(topic == "/leader/pose" for topic, _, _ in got)
