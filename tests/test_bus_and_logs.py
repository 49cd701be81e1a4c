"""The bus payloads, the zenoh key layout against the graph, and the crash-safe row logs."""

import math
import os
import re
import struct
import subprocess
import time
import zlib
from pathlib import Path

import numpy as np
import pytest
import zenoh
from hypothesis import given
from hypothesis import strategies as st

from sim_vehicles.runtime.row_log import RowLog, read_rows
from swarm_sitl.bus import keys as zenoh_keys
from swarm_sitl.bus.codec import (
    Message,
    PayloadError,
    Status,
    decode_message,
    decode_start,
    decode_status,
    decode_waiting,
    encode_message,
    encode_start,
    encode_status,
)
from swarm_sitl.bus.node_bus import ZenohNodeBus
from swarm_sitl.bus.session import ROUTER_RUNTIME, RUNTIME_ENV, ZenohSection, open_session, router_runtime
from swarm_sitl.running.children import child_env
from swarm_sitl.running.hub import free_tcp_port
from tests.support import start_cli

finite = st.floats(allow_nan=False, allow_infinity=False, width=64)


@pytest.mark.unit
@given(st.integers(0, 65535), st.integers(0, 2**32 - 1), finite, st.lists(finite, min_size=1, max_size=40))
def test_message_roundtrip_is_exact(src, step, t_s, v):
    back = decode_message(encode_message(Message(src, step, t_s, np.array(v))))
    assert (back.src, back.step, back.t_s) == (src, step, t_s)
    # float64 end to end, whatever the length: lockstep runs equal sim bit for bit
    assert back.values.dtype == np.float64 and back.values.tobytes() == np.array(v).tobytes()


@pytest.mark.unit
def test_status_and_start_roundtrip():
    s = decode_status(encode_status(Status(3, 70, 0.7, 0.69, np.array([1.0, 2.0, 3.0]))))
    assert (s.follower, s.step, s.t_s, s.sample_t_s) == (3, 70, 0.7, 0.69) and list(s.p_W) == [1, 2, 3]
    assert decode_start(encode_start(1.7e9)) == 1.7e9


def _with_crc(body: bytes, flip: int | None = None) -> bytes:
    """An estimate payload with its CRC-32; ``flip``: then one byte inverted (a corruption)."""
    data = bytearray(body + zlib.crc32(body).to_bytes(4, "little"))
    if flip is not None:
        data[flip] ^= 0xFF
    return bytes(data)


@pytest.mark.unit
@pytest.mark.parametrize(
    "payload, match",
    [
        (b"", "0 bytes"),
        (b"\x01" * 10, "10 bytes"),
        (b"\x01" + encode_message(Message(1, 1, 0.0, np.zeros(12)))[1:], "version 1"),
        (
            _with_crc(struct.pack("<BHId3dH12d", 4, 1, 1, math.nan, 0.0, 0.0, 0.0, 12, *[0.0] * 12)),
            "non-finite",
        ),
        (
            _with_crc(
                struct.pack("<BHId3dH12d", 4, 1, 1, 0.0, 0.0, 0.0, 0.0, 12, 1.0, math.inf, *[0.0] * 10)
            ),
            "non-finite",
        ),
        (
            _with_crc(struct.pack("<BHId3dH12d", 4, 1, 1, 0.0, 0.0, 0.0, 0.0, 12, *[0.0] * 12), flip=60),
            "checksum",
        ),
        (
            _with_crc(struct.pack("<BHId3dH12d", 4, 1, 1, 0.0, 0.0, 0.0, 0.0, 13, *[0.0] * 12)),
            "141 bytes, its 13 values need 149",
        ),
    ],
)
def test_malformed_messages_are_refused_with_one_line(payload, match):
    with pytest.raises(PayloadError, match=match) as e:
        decode_message(payload)
    assert "\n" not in str(e.value)


@pytest.mark.unit
def test_each_node_subscribes_to_exactly_its_in_edges(paper_cfg):
    """The bus mirrors the graph: full keys, never a wildcard."""
    g = paper_cfg.build_graph()
    session = open_session(ZenohSection(mode="peer", listen=[]))
    try:
        for f in paper_cfg.followers:
            i = f.id
            bus = ZenohNodeBus(session, "t", i, [s for s, _ in g.in_neighbours(i)], list(g.out_neighbours(i)))
            subs = {str(sub.key_expr) for _, sub in bus._est_subs}
            pubs = {str(p.key_expr) for p in bus._pubs}
            bus.close()
            assert subs == {zenoh_keys.edge("t", s, i) for s, _ in g.in_neighbours(i)}
            assert pubs == {zenoh_keys.edge("t", i, d) for d in g.out_neighbours(i)}
            assert not any("*" in k for k in subs | pubs)
    finally:
        session.close()


@pytest.mark.unit
def test_bad_payload_on_an_edge_is_dropped_and_counted():
    session = open_session(ZenohSection(mode="peer", listen=[]))
    try:
        bus = ZenohNodeBus(session, "t", 2, [1], [])
        good = Message(1, 5, 0.05, np.ones(12))
        session.put(zenoh_keys.edge("t", 1, 2), b"garbage")
        session.put(zenoh_keys.edge("t", 1, 2), encode_message(good))
        for _ in range(200):
            bus.poll()
            if bus.latest(1) is not None:
                break
            time.sleep(0.01)
        assert bus.dropped == 1 and bus.estimate(1, 5) is not None and bus.latest(1).step == 5
        bus.close()
    finally:
        session.close()


@pytest.mark.unit
def test_a_message_of_another_length_than_its_sender_sends_is_dropped_and_counted():
    """Node 2 runs a law whose messages have 9 values: from follower 1 it takes 9, never 12;
    from the leader (node 0) it takes the reference's 12, never 9."""
    session = open_session(ZenohSection(mode="peer", listen=[]))
    try:
        bus = ZenohNodeBus(session, "t", 2, [0, 1], [], message_length=9)
        sent = [
            (1, Message(1, 1, 0.01, np.ones(12))),  # the paper's length: not what 1 sends here
            (0, Message(0, 1, 0.01, np.ones(9))),  # the leader's must be the reference
            (1, Message(1, 2, 0.02, np.ones(9))),
            (0, Message(0, 2, 0.02, np.ones(12))),
        ]
        for src, m in sent:
            session.put(zenoh_keys.edge("t", src, 2), encode_message(m))
        for _ in range(200):
            bus.poll()
            if bus.latest(0) is not None and bus.latest(1) is not None:
                break
            time.sleep(0.01)
        assert bus.dropped == 2
        assert bus.estimate(1, 1) is None and bus.estimate(0, 1) is None
        assert len(bus.estimate(1, 2).values) == 9 and len(bus.estimate(0, 2).values) == 12
        bus.close()
    finally:
        session.close()


@pytest.mark.unit
def test_decode_waiting_returns_the_good_payloads_in_order_and_counts_the_bad():
    class Sample:
        def __init__(self, data):
            self.payload = type("P", (), {"to_bytes": lambda _self: data})()

    class Sub:  # a zenoh channel as the bus reads it: try_recv until None
        def __init__(self, payloads):
            self.left = [Sample(p) for p in payloads]

        def try_recv(self):
            return self.left.pop(0) if self.left else None

    st = [encode_status(Status(2, k, 0.01 * k, 0.01 * k, np.zeros(3))) for k in (3, 4)]
    sub = Sub([st[0], b"junk", st[1], st[1][:-1]])
    got, bad = decode_waiting(sub, decode_status)
    assert [s.step for s in got] == [3, 4] and bad == 2 and sub.try_recv() is None


@pytest.mark.unit
def test_forget_before_drops_exactly_the_older_ticks_even_out_of_order():
    """Out of order as a fault plan's delay files them (the wire's order is refused, below)."""
    session = open_session(ZenohSection(mode="peer", listen=[]))
    try:
        bus = ZenohNodeBus(session, "t", 2, [1], [])
        for k in [0, 1, 2, 4, 3, 5, 6, 7]:  # one pair out of order
            bus.file(Message(1, k, 0.01 * k, np.ones(12)))
        kept = lambda: [k for k in range(8) if bus.estimate(1, k) is not None]  # noqa: E731
        assert kept() == list(range(8)) and bus.latest(1).step == 7
        bus.forget_before(3)
        assert kept() == [3, 4, 5, 6, 7]
        bus.forget_before(4)  # tick 3 came after tick 4: it may stay until tick 4 goes
        assert kept()[-4:] == [4, 5, 6, 7]
        bus.forget_before(6)
        assert kept() == [6, 7]
        bus.close()
    finally:
        session.close()


def _estimate(src: int, step: int, p: float = 1.0) -> bytes:
    return encode_message(Message(src, step, 0.01 * step, np.full(12, p)))


def _drain(bus, until) -> None:
    for _ in range(300):
        bus.poll()
        if until():
            return
        time.sleep(0.01)


@pytest.mark.unit
def test_estimates_that_cannot_follow_the_last_are_refused_and_counted():
    """On node 2's in-edge from 1: another sender's estimate, a tick already taken (a replay, a
    duplicate, one out of order) and ticks past the horizon (2^32-1; past the run) are refused
    and counted per sender; the sender's next real estimates are still taken and are the newest."""
    session = open_session(ZenohSection(mode="peer", listen=[]))
    try:
        bus = ZenohNodeBus(session, "t", 2, [1], [])
        bus.horizon = lambda: 100
        key = zenoh_keys.edge("t", 1, 2)
        sent = [
            (_estimate(1, 0), True),
            (_estimate(1, 1), True),
            (_estimate(3, 2, 9.0), False),  # node 3's estimate on node 1's key
            (_estimate(1, 1, 9.0), False),  # tick 1 again
            (_estimate(1, 3), True),  # a gap (lost, or the sender restarted): fine
            (_estimate(1, 2, 9.0), False),  # out of order
            (_estimate(1, 2**32 - 1, 9.0), False),  # far ahead
            (_estimate(1, 101, 9.0), False),  # just past the horizon
            (_estimate(1, 4), True),
            (_estimate(1, 100), True),  # at the horizon
        ]
        for data, _ in sent:
            session.put(key, data)
        _drain(bus, lambda: bus.latest(1) is not None and bus.latest(1).step == 100)
        taken = [k for k in range(101) if bus.estimate(1, k) is not None]
        assert taken == [0, 1, 3, 4, 100]
        assert bus.refused == {1: sum(not ok for _, ok in sent)} and bus.dropped == 0
        assert all(bus.estimate(1, k).values.tolist() == [1.0] * 12 for k in taken)
        assert bus.received == {1: 5}
        bus.close()
    finally:
        session.close()


@pytest.mark.unit
def test_a_status_from_another_sender_or_past_the_horizon_does_not_pace_the_leader():
    session = open_session(ZenohSection(mode="peer", listen=[]))
    try:
        bus = ZenohNodeBus(session, "t", 0, [], [1], watch_status=[1])
        bus.horizon = lambda: 50
        for st in (Status(2, 40, 0.4, 0.4, np.zeros(3)), Status(1, 51, 0.5, 0.5, np.zeros(3))):
            session.put(zenoh_keys.status("t", 1), encode_status(st))
        session.put(zenoh_keys.status("t", 1), encode_status(Status(1, 7, 0.07, 0.07, np.zeros(3))))
        _drain(bus, lambda: bus.progress(1) >= 0)
        assert bus.progress(1) == 7 and bus.refused == {1: 2}
        bus.close()
    finally:
        session.close()


@pytest.mark.unit
def test_row_log_survives_a_cut_mid_row(tmp_path):
    path = tmp_path / "x.rows"
    log = RowLog(path, ["a", "b", "c"], flush_rows=2)
    for k in range(5):
        log.append((float(k),), np.array([k + 0.5, -k]))
    with pytest.raises(ValueError, match="row has 2 values, expected 3"):
        log.append((1.0,), np.array([2.0]))
    log.flush()
    with open(path, "ab") as f:
        f.write(b"\x00" * 12)  # a writer killed mid-row
    cols, rows = read_rows(path)
    assert cols == ["a", "b", "c"] and rows.shape == (5, 3) and rows[4].tolist() == [4.0, 4.5, -4.0]
    log.close()


@pytest.mark.unit
def test_the_horizon_is_the_run_in_lockstep_and_half_a_second_ahead_in_real_time():
    from swarm_sitl.bus.clock import HORIZON_LEAD_S, RunClock

    assert RunClock(True, 0.01).horizon(6000) == 6000
    rt = RunClock(False, 0.01)
    assert rt.horizon(6000) == 6000  # before the start signal
    rt.epoch_mono = time.monotonic() - 2.0  # two seconds into the run
    lead = round(HORIZON_LEAD_S / 0.01)
    assert 200 + lead <= rt.horizon(6000) <= 200 + lead + 5
    assert rt.horizon(210) == 210


@pytest.mark.unit
def test_the_bus_descriptor_wakes_a_select_when_an_estimate_comes_and_is_quiet_after_poll():
    """What a lockstep controller blocks on (``NodeBus.fileno``): readable once an estimate has
    come, quiet again once ``poll`` has taken it, and closed with the bus."""
    import select
    import socket

    session = open_session(ZenohSection(mode="peer", listen=[]))
    try:
        bus = ZenohNodeBus(session, "t", 2, [1], [])
        fd = bus.fileno()
        assert select.select([fd], [], [], 0.05)[0] == []  # nothing yet
        bus.poll()
        session.put(zenoh_keys.edge("t", 1, 2), encode_message(Message(1, 3, 0.03, np.ones(12))))
        assert select.select([fd], [], [], 5.0)[0] == [fd]
        bus.poll()
        assert bus.estimate(1, 3) is not None
        assert select.select([fd], [], [], 0.05)[0] == []  # taken: no wake-up left behind
        for k in (4, 5, 6):  # a batch between two polls: one wake-up, every estimate taken
            session.put(
                zenoh_keys.edge("t", 1, 2),
                encode_message(Message(1, k, 0.01 * k, np.ones(12))),
            )
        deadline = time.monotonic() + 5.0
        while len(bus._queue) < 3 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert len(bus._wake_r.recv(16, socket.MSG_PEEK)) == 1
        bus.poll()
        assert all(bus.estimate(1, k) is not None for k in (4, 5, 6))
        assert select.select([fd], [], [], 0.05)[0] == []
        # a callback between setting its flag and writing its byte: the poll in between finds no
        # byte, and the byte that comes after it is taken by the next poll, not left readable
        bus._woken = True
        bus.poll()
        bus._wake_w.send(b"\0")
        assert select.select([fd], [], [], 0.05)[0] == [fd]
        bus.poll()
        assert select.select([fd], [], [], 0.05)[0] == []
        # with no byte out a poll does not read the descriptor (a read that finds nothing raises,
        # which cost a controller tens of microseconds on nine ticks in ten)
        reads = []
        real = bus._wake_r

        class Counting:
            def recv(self, n: int) -> bytes:
                reads.append(n)
                return real.recv(n)

        bus._wake_r = Counting()
        for _ in range(5):
            bus.poll()
        assert reads == []
        bus._wake_r = real
        bus.close()
        session.put(zenoh_keys.edge("t", 1, 2), b"late")  # a closed bus takes nothing, quietly
        time.sleep(0.05)
    finally:
        session.close()


@pytest.mark.unit
def test_router_runtime_is_taken_back_and_leaves_a_users_own(monkeypatch):
    """The supervisor's children must not inherit the router's runtime; a user's runtime wins."""
    monkeypatch.delenv(RUNTIME_ENV, raising=False)
    with router_runtime():
        assert os.environ[RUNTIME_ENV] == ROUTER_RUNTIME
    assert RUNTIME_ENV not in os.environ
    mine = "(rx: (worker_threads: 1))"
    monkeypatch.setenv(RUNTIME_ENV, mine)
    with router_runtime():
        assert os.environ[RUNTIME_ENV] == mine
    assert os.environ[RUNTIME_ENV] == mine


def _zenoh_pools(pid: int) -> set[str]:
    """The zenoh runtime pools a process has threads of (tokio names them ``<pool>-<n>``)."""
    names = [(task / "comm").read_text().strip() for task in Path(f"/proc/{pid}/task").iterdir()]
    return {m.group(1) for n in names if (m := re.fullmatch(r"(app|rx|tx|acc|net)-\d+", n))}


@pytest.mark.system
@pytest.mark.parametrize("users_runtime", [None, "(rx: (worker_threads: 1))"])
@pytest.mark.light
def test_swarm_sitl_router_routes_on_one_thread_unless_the_user_sets_the_runtime(users_runtime):
    """``swarm-sitl router`` (and ``run``'s router) run zenoh on one worker thread: two clients
    exchange samples through it while it has threads of the application pool only; with the
    user's ``ZENOH_RUNTIME`` it has zenoh's pools as that gives them."""
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    env = {k: v for k, v in child_env().items() if k != RUNTIME_ENV}
    if users_runtime is not None:
        env[RUNTIME_ENV] = users_runtime
    router = start_cli(
        "router", "--listen", endpoint, stdout=subprocess.PIPE, env=env, stderr=None, start_new_session=False
    )
    sessions = []
    try:
        assert "router listening" in (router.stdout.readline() if router.stdout else "")
        spec = ZenohSection(mode="client", connect=[endpoint])
        sessions = [open_session(spec), open_session(spec)]
        sub = sessions[1].declare_subscriber("t/routed", zenoh.handlers.FifoChannel(64))
        got = None
        for _ in range(200):  # until the subscription has reached the router
            sessions[0].put("t/routed", b"through the router")
            got = sub.try_recv()
            if got is not None:
                break
            time.sleep(0.02)
        assert got is not None and got.payload.to_bytes() == b"through the router"
        pools = _zenoh_pools(router.pid)
        if users_runtime is None:
            assert pools == {"app"}
        else:
            assert {"app", "rx", "tx"} <= pools
    finally:
        for s in sessions:
            s.close()
        router.terminate()
        router.wait(timeout=10)
