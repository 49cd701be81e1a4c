"""MAVLink 2 signing: our signer against pymavlink's, and a signed vehicle against a spoofer.

The system test drives a vehicle process with two pymavlink clients that use only pymavlink's
public API: the owner, signing with the run's passphrase as MAVProxy would, and a stranger who
does not hold it.
"""

import hashlib
import json
import re
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mav
from pymavlink.generator.mavcrc import x25crc

import sim_vehicles.mavlink.signing as signing
from sim_vehicles.mavlink.sha256 import sha256_into
from sim_vehicles.mavlink.signing import Signer, Verifier, key_from_passphrase
from swarm_sitl.running.children import child_env
from tests.support import CONFIGS, start_cli, start_vehicle

KEY = key_from_passphrase("correct horse battery staple")


def _plain(sysid: int = 3) -> bytes:
    msg = mav.MAVLink_set_attitude_target_message(100, 3, 1, 0, [1, 0, 0, 0], 0.1, 0.2, 0.3, 0.4)
    return bytes(msg.pack(mav.MAVLink(None, srcSystem=sysid, srcComponent=191)))


@pytest.mark.unit
@settings(max_examples=200, deadline=None, derandomize=True)
@given(st.data())
def test_the_signed_flags_crc_delta_is_pymavlinks_crc_difference_for_every_payload_length(data):
    """The table ``_flip_flag`` reads, built afresh (it is built once at import): for a frame of
    any payload length, any bytes and any CRC extra, pymavlink's X.25 CRC of the frame with the
    signed flag set differs from its CRC without it by the table's entry for that length."""
    table = signing._flag_deltas()
    assert len(table) == 256
    plen = data.draw(st.integers(0, 255))
    body = bytearray(data.draw(st.binary(min_size=9 + plen, max_size=9 + plen)))  # header after STX
    body[0] = plen
    extra = data.draw(st.integers(0, 255))
    body[1] &= ~signing.SIGNED
    plain = x25crc(bytes(body) + bytes([extra])).crc
    body[1] |= signing.SIGNED
    assert x25crc(bytes(body) + bytes([extra])).crc ^ plain == table[plen]


@pytest.mark.unit
def test_the_key_is_the_sha256_of_the_passphrase_as_mavproxy_derives_it():
    assert hashlib.sha256(b"correct horse battery staple").digest() == KEY and len(KEY) == 32


@pytest.mark.unit
def test_a_sealed_frame_is_byte_for_byte_what_pymavlink_signs(monkeypatch):
    link = mav.MAVLink(None, srcSystem=3, srcComponent=191)
    link.signing.secret_key, link.signing.sign_outgoing, link.signing.link_id = KEY, True, 0
    link.signing.timestamp = 123_456_789  # pymavlink signs with it, then adds one
    msg = mav.MAVLink_set_attitude_target_message(100, 3, 1, 0, [1, 0, 0, 0], 0.1, 0.2, 0.3, 0.4)
    theirs = bytes(msg.pack(link))
    monkeypatch.setattr(signing, "now_stamp", lambda: 123_456_789)
    assert Signer(KEY).seal(_plain()) == theirs
    receiver = mav.MAVLink(None)
    receiver.signing.secret_key = KEY
    assert [m.get_type() for m in receiver.parse_buffer(theirs)] == ["SET_ATTITUDE_TARGET"]


@pytest.mark.unit
def test_the_verifier_opens_what_is_signed_and_refuses_the_rest():
    s, v = Signer(KEY), Verifier(KEY)
    plain = _plain()
    sealed = s.seal(plain)
    assert v.open(sealed) == plain  # unsigned again, for the parsers that follow
    assert v.open(sealed) is None and v.replayed == 1  # the same timestamp again
    assert v.open(plain) is None and v.unsigned == 1
    assert v.open(Signer(key_from_passphrase("wrong")).seal(plain)) is None and v.bad == 1
    for at in range(len(sealed)):  # any byte flipped
        flipped = bytearray(s.seal(plain))
        flipped[at] ^= 0x01
        assert v.open(bytes(flipped)) is None
    assert v.open(s.seal(plain)) == plain  # and the link still works
    # a new stream may not start more than a minute in the past
    old = Signer(KEY)
    old._stamp = signing.now_stamp() - 2 * signing.NEW_STREAM_SLACK
    stale = bytearray(old.seal(_plain(sysid=9)))
    assert Verifier(KEY).open(bytes(stale)) is not None  # a seal is never behind the clock
    fresh = Verifier(KEY)
    assert (
        fresh.open(_forged_stamp(_plain(sysid=9), signing.now_stamp() - 2 * signing.NEW_STREAM_SLACK)) is None
    )
    assert fresh.replayed == 1


@pytest.mark.unit
def test_the_compiled_sha256_is_hashlibs_for_any_length_and_split():
    out = np.zeros(32, np.uint8)
    rng = np.random.default_rng(5)
    for n in [*range(0, 140), 1000]:  # every padding case: 0-2 extra blocks
        data = rng.integers(0, 256, n, dtype=np.uint8).tobytes()
        for cut in {0, n // 3, n}:
            sha256_into(np.frombuffer(data[:cut], np.uint8), cut, data[cut:], n - cut, out)
            assert out.tobytes() == hashlib.sha256(data).digest(), (n, cut)


@pytest.mark.unit
def test_a_pass_of_several_frames_is_sealed_and_opened_whole_as_pymavlink_reads_it():
    s, v = Signer(KEY), Verifier(KEY)
    frames = _plain() + _plain(sysid=4) + _plain()
    sealed = s.seal(frames)
    assert len(sealed) == len(frames) + 3 * signing.SIGNATURE_LEN
    receiver = mav.MAVLink(None)
    receiver.signing.secret_key = KEY
    got = receiver.parse_buffer(sealed)
    assert [m.get_srcSystem() for m in got] == [3, 4, 3] and receiver.signing.badsig_count == 0
    assert v.open(sealed) == frames  # two streams in one datagram
    assert v.open(s.seal(frames)) == frames
    # a frame cut short or a stray byte: nothing of it is signed
    assert s.seal(frames[:-1]) == frames[:-1] and s.seal(frames + b"\0") == frames + b"\0"


@pytest.mark.unit
def test_a_repeat_inside_one_datagram_is_a_replay():
    s, v = Signer(KEY), Verifier(KEY)
    one = s.seal(_plain())
    assert v.open(one + one) is None and v.replayed == 1
    assert v.open(one) == _plain()  # the refused datagram moved no stream's clock
    two = s.seal(_plain(sysid=4))
    three = s.seal(_plain())
    assert v.open(three + two) == _plain() + _plain(sysid=4)  # streams interleaved, each rising
    assert v.open(three) is None and v.replayed == 2
    # a pass of one stream moves its clock to its last frame's stamp: a frame stamped between its
    # first and its last, or at its last, comes too late
    t = signing.now_stamp() + 1000
    w = Verifier(KEY)
    assert w.open(_forged_stamp(_plain(), t) + _forged_stamp(_plain(), t + 5)) == _plain() + _plain()
    assert w.open(_forged_stamp(_plain(), t + 3)) is None and w.open(_forged_stamp(_plain(), t + 5)) is None
    assert w.replayed == 2 and w.open(_forged_stamp(_plain(), t + 6)) == _plain()


@pytest.mark.unit
def test_a_key_of_the_wrong_length_is_refused_in_one_line():
    with pytest.raises(signing.SigningKeyError, match="32 bytes, not 16"):
        Signer(KEY[:16])
    with pytest.raises(signing.SigningKeyError, match="32 bytes, not 33"):
        Verifier(KEY + b"x")


def _raw(payload_len: int, sysid: int = 3, compid: int = 191, seq: int = 0) -> bytes:
    """A plain MAVLink 2 frame of any payload length (the kernels read the header's lengths and
    flags, never the message's CRC, so any id and payload do)."""
    body = bytes([signing.MAGIC_V2, payload_len, 0, 0, seq, sysid, compid, 0, 0, 0]) + bytes(
        range(payload_len)
    )
    return body + b"\x5a\xa5"


def _stamped(frames: bytes, stamp: int) -> bytes:
    """``frames`` signed from the timestamp given on (one in the future: the signer's clock is behind)."""
    s = Signer(KEY)
    s._stamp = stamp - 1
    return s.seal(frames)


def _seal_one(data: bytes, out_len: int, stamp: int = 1000) -> tuple[int, int]:
    return signing.seal_into(
        np.frombuffer(data, np.uint8), np.frombuffer(KEY, np.uint8), 0, stamp, np.zeros(out_len, np.uint8)
    )


def _open(data: bytes, rows: int = 8) -> tuple[int, int, int, bool, np.ndarray]:
    streams = np.zeros((rows, 4), np.int64)
    out = np.zeros(max(len(data), 1), np.uint8)
    status, n, count, one = signing.open_into(
        np.frombuffer(data, np.uint8), np.frombuffer(KEY, np.uint8), out, streams
    )
    return status, n, count, bool(one), streams


@pytest.mark.unit
def test_the_signing_clock_is_mavlinks_ten_microseconds_since_2015():
    expected = (time.time() - 1420070400) * 100_000  # as pymavlink's MAVLinkSigning counts
    assert abs(signing.now_stamp() - expected) < 100_000  # within a second


@pytest.mark.unit
def test_seal_signs_whole_plain_frames_only_and_never_writes_past_its_buffer():
    short = _raw(0)  # the shortest frame there is: a header and a CRC
    assert Verifier(KEY).open(Signer(KEY).seal(short)) == short
    whole = _raw(20)
    for cut in range(len(whole)):  # cut short, alone or after a whole frame: nothing is signed
        assert _seal_one(whole[:cut], 4096) == (0, 0), cut
        assert _seal_one(whole + whole[:cut], 4096) == ((len(whole) + 13, 1) if cut == 0 else (0, 0))
    v1 = bytes([signing.MAGIC_V1]) + whole[1:]  # MAVLink 1's magic: not ours to sign
    assert _seal_one(v1, 4096) == (0, 0) and Signer(KEY).seal(v1) == v1
    signed = Signer(KEY).seal(whole)  # signed already (its sequence byte is even)
    assert _seal_one(signed, 4096) == (0, 0) and Signer(KEY).seal(signed) == signed
    flagged = bytearray(whole)
    flagged[2] |= signing.SIGNED  # the signed flag without a signature: not plain either
    assert _seal_one(bytes(flagged), 4096) == (0, 0)
    # the buffer: an exact fit is signed, one byte less refuses (for one frame and for a pass)
    for frames in (whole, whole + _raw(3)):
        fit = len(frames) + 13 * (2 if len(frames) > len(whole) else 1)
        assert _seal_one(frames, fit)[0] == fit and _seal_one(frames, fit - 1) == (0, 0)


@pytest.mark.unit
def test_a_pass_gets_one_timestamp_per_frame_and_the_next_pass_the_next_one(monkeypatch):
    monkeypatch.setattr(signing, "now_stamp", lambda: 5_000)  # a clock that stands still
    s = Signer(KEY)
    three = _raw(4) + _raw(5, compid=1) + _raw(6, sysid=9)
    sealed = s.seal(three)
    status, n, count, _one, streams = _open(sealed)
    assert (status, n, count) == (signing.OK, len(three), 3)
    assert streams[:3].tolist() == [[3, 191, 0, 5_000], [3, 1, 0, 5_001], [9, 191, 0, 5_002]]
    for expected in (5_003, 5_004):  # never a stamp twice, and none skipped
        assert _open(s.seal(_raw(4)))[4][0, 3] == expected


@pytest.mark.unit
def test_open_names_one_rising_stream_and_tells_streams_apart_by_system_component_and_link():
    s = Signer(KEY)
    assert _open(s.seal(_raw(2)))[3] is True  # one frame: one stream
    assert _open(s.seal(_raw(2) + _raw(3) + _raw(4)))[3] is True
    for other in (_raw(3, sysid=4), _raw(3, compid=190)):
        assert _open(s.seal(_raw(2) + other))[3] is False
    linked = Signer(KEY, link_id=1).seal(_raw(3))
    assert _open(s.seal(_raw(2)) + linked)[3] is False
    t = signing.now_stamp() + 100_000  # one stream whose stamps do not rise
    assert _open(_stamped(_raw(2), t + 1) + _stamped(_raw(2), t))[3] is False


@pytest.mark.unit
def test_open_refuses_every_truncation_and_counts_what_it_refuses():
    s = Signer(KEY)
    good = s.seal(_raw(20))
    for cut in range(1, len(good)):  # cut short, alone or after a whole frame: bad, nothing out
        for data in (good[:cut], good + good[:cut]):
            status, n, count, _one, _streams = _open(data)
            assert (status, n) == (signing.BAD, 0), cut
            assert count == (1 if len(data) > len(good) else 0)
    status, n, count, _one, _streams = _open(b"")
    assert (status, n, count) == (signing.BAD, 0, 0)  # no frame at all
    assert _open(_raw(0))[:3] == (signing.UNSIGNED, 0, 0)  # a whole 12-byte plain frame
    assert _open(_raw(20)[:11])[:2] == (signing.BAD, 0)  # not a frame
    assert _open(good + _raw(0))[:3] == (signing.UNSIGNED, 0, 1)
    assert _open(bytes([signing.MAGIC_V1]) + _raw(20)[1:])[:3] == (signing.UNSIGNED, 0, 0)  # MAVLink 1
    assert _open(Signer(key_from_passphrase("wrong")).seal(_raw(20)))[:3] == (signing.BAD, 0, 0)
    # more frames than rows to name their streams: refused, not written past
    assert _open(good + s.seal(_raw(20)), rows=1)[:2] == (signing.BAD, 0)
    v = Verifier(KEY)
    for _ in range(2):
        assert v.open(_raw(0)) is None and v.open(good[:-1]) is None and v.open(good) in (None, _raw(20))
        assert v.open(bytes(signing._MAX_DATAGRAM + 1)) is None
    assert v.open(good) is None  # a replay again
    assert (v.unsigned, v.bad, v.replayed) == (2, 4, 2)


@pytest.mark.unit
def test_the_largest_datagrams_are_signed_and_opened():
    big = _raw(255) * 245  # 65415 bytes
    exact = big + _raw(signing._MAX_DATAGRAM - len(big) - 12)
    assert len(exact) == signing._MAX_DATAGRAM
    s, v = Signer(KEY), Verifier(KEY)
    sealed = s.seal(exact)  # signed, though over what a UDP datagram holds once signed
    assert len(sealed) == len(exact) + 246 * 13 and _open(sealed, rows=246)[:3] == (
        signing.OK,
        len(exact),
        246,
    )
    assert s.seal(exact + _raw(0)) == exact + _raw(0)  # over the most a datagram holds: as it is
    # the most frames a signed datagram holds, and a signed datagram of exactly the most bytes
    most = s.seal(_raw(0) * (signing._MAX_DATAGRAM // 25))
    assert v.open(most) == _raw(0) * (signing._MAX_DATAGRAM // 25)
    plain = _raw(255) * 233 + _raw(123) * 2  # signed: 233 x 280 + 2 x 148 bytes
    sealed = s.seal(plain)
    assert len(sealed) == signing._MAX_DATAGRAM and v.open(sealed) == plain


@pytest.mark.unit
def test_a_datagram_of_several_streams_cannot_replay_a_stamp_one_of_them_had():
    v = Verifier(KEY)
    t = signing.now_stamp() + 100_000
    assert v.open(_stamped(_raw(2), t)) == _raw(2)
    again = _stamped(_raw(3, sysid=4), t + 10) + _stamped(_raw(2), t)  # two streams
    assert v.open(again) is None and v.replayed == 1


def _forged_stamp(plain: bytes, stamp: int) -> bytes:
    """``plain`` signed with ``KEY`` at the timestamp given (what a recording replayed would carry)."""
    link = mav.MAVLink(None, srcSystem=plain[5], srcComponent=plain[6])
    link.signing.secret_key, link.signing.sign_outgoing = KEY, True
    link.signing.timestamp = stamp
    return bytes(mav.MAVLink(None).decode(bytearray(plain)).pack(link))


# -- a signed vehicle process ----------------------------------------------------------------------


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


VEHICLE = [
    "--id",
    "3",
    "--position",
    "0",
    "0",
    "20",
    "--duration",
    "60",
]


@pytest.fixture
def signed_vehicle(tmp_path):
    key_file = tmp_path / "key"
    key_file.write_text("correct horse battery staple\n")
    port = _free_udp_port()
    stats = tmp_path / "stats.json"
    proc = start_vehicle(*VEHICLE, "--port", port, "--signing-key-file", key_file, "--stats", stats)
    assert "listening" in proc.stdout.readline()
    yield port, proc, stats
    if proc.poll() is None:
        proc.terminate()
        proc.wait(timeout=10)


def _client(port: int, key: bytes | None) -> mavutil.mavfile:
    conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=3, source_component=191)
    if key is not None:
        conn.setup_signing(key, sign_outgoing=True)
    return conn


def _ack(conn, command: int, timeout: float = 3.0):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        m = conn.recv_match(type="COMMAND_ACK", blocking=True, timeout=0.2)
        if m is not None and m.command == command:
            return m.result
    return None


@pytest.mark.system
@pytest.mark.light
def test_a_stranger_without_the_key_cannot_command_a_signed_vehicle_or_take_its_telemetry(signed_vehicle):
    port, proc, stats_path = signed_vehicle
    owner = _client(port, KEY)
    owner.mav.heartbeat_send(mav.MAV_TYPE_ONBOARD_CONTROLLER, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0)
    hb = owner.recv_match(type="HEARTBEAT", blocking=True, timeout=5)
    assert hb is not None and hb.get_signed()  # the vehicle signs what it sends
    owner.mav.command_long_send(3, 1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
    assert _ack(owner, mav.MAV_CMD_COMPONENT_ARM_DISARM) == mav.MAV_RESULT_ACCEPTED

    stranger = _client(port, None)
    for _ in range(3):
        stranger.mav.heartbeat_send(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        stranger.mav.command_long_send(3, 1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, 0, 21196, 0, 0, 0, 0, 0)
        stranger.mav.command_long_send(3, 1, mav.MAV_CMD_DO_SET_MODE, 0, 29, 4, 3, 0, 0, 0, 0)  # Hold
        stranger.mav.set_attitude_target_send(0, 3, 1, 0, [1, 0, 0, 0], 0, 0, 0, 1.0)
        stranger.mav.param_set_send(3, 1, b"SP_TIMEOUT_S", 30.0, mav.MAV_PARAM_TYPE_REAL32)
        time.sleep(0.1)
    # a replay: the owner's own forced disarm, captured and sent again by the stranger once the
    # owner has armed again
    disarm = mav.MAVLink_command_long_message(
        3, 1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, 0, 21196, 0, 0, 0, 0, 0
    )
    captured = bytes(disarm.pack(owner.mav))
    owner.write(captured)
    assert _ack(owner, mav.MAV_CMD_COMPONENT_ARM_DISARM) == mav.MAV_RESULT_ACCEPTED
    owner.mav.command_long_send(3, 1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
    assert _ack(owner, mav.MAV_CMD_COMPONENT_ARM_DISARM) == mav.MAV_RESULT_ACCEPTED
    stranger.write(captured)
    owner.write(captured)  # even from the owner's own address
    assert stranger.recv_match(blocking=True, timeout=1.5) is None  # not one byte came back

    owner.mav.command_long_send(3, 1, mav.MAV_CMD_REQUEST_MESSAGE, 0, 32, 0, 0, 0, 0, 0, 0)
    assert owner.recv_match(type="LOCAL_POSITION_NED", blocking=True, timeout=5) is not None
    hb = owner.recv_match(type="HEARTBEAT", blocking=True, timeout=3)
    assert hb is not None and hb.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED
    assert hb.custom_mode == (4 << 16) | (3 << 24)  # PX4's AUTO.LOITER (Hold), as it started
    proc.terminate()
    proc.wait(timeout=10)
    stats = json.loads(stats_path.read_text())
    assert stats["rx_refused"] >= 3 * 5 and stats["handler_errors"] == 0, stats


def _docs_script() -> str:
    """The pymavlink script of ``docs/tools.md`` (*A pymavlink script on a signed run*), as written there."""
    text = (Path(__file__).resolve().parents[1] / "docs" / "tools.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, re.S)
    script = [b for b in blocks if "setup_signing" in b]
    assert len(script) == 1, "docs/tools.md shows one pymavlink script that signs"
    return script[0]


@pytest.mark.system
@pytest.mark.light
def test_the_docs_pymavlink_script_sets_a_parameter_of_a_signed_run_and_each_unsigned_message_is_counted(
    tmp_path,
):
    """A real-time signed run of the paper's swarm: the script of docs/tools.md, run as written,
    sets a parameter of vehicle 1 through its ground-station port and reads the vehicle's answer;
    an unsigned client sends vehicle 2's ground-station port a number of requests and gets no
    answer, and the run's last lines and ``summary.json`` count exactly those, by port."""
    script = tmp_path / "signed_param.py"
    script.write_text(_docs_script())
    cfg = yaml.safe_load((CONFIGS / "paper.yaml").read_text())
    cfg["duration_s"] = 4.0  # (the script needs about a second of it)
    path = tmp_path / "paper.yaml"
    path.write_text(yaml.safe_dump(cfg))
    out = tmp_path / "run"
    run = start_cli("run", path, "--realtime", "--out", out, start_new_session=False)
    try:
        assert run.stdout is not None
        gcs: dict[int, int] = {}
        while len(gcs) < 2:
            line = run.stdout.readline()
            assert line, "run printed no ports"
            m = re.search(r"vehicle (\d+): .*ground station udpout:127\.0\.0\.1:(\d+)", line)
            if m:
                gcs[int(m.group(1))] = int(m.group(2))
        value = 150.0 + int(np.random.default_rng().integers(0, 50)) + 0.5  # [deg/s] (not one it had)
        env = {k: v for k, v in child_env().items() if k != "MAVLINK20"}  # the script sets it itself
        done = subprocess.run(
            [sys.executable, str(script), str(out), str(gcs[1]), "MC_YAWRATE_MAX", f"{value:g}"],
            capture_output=True,
            text=True,
            timeout=30,
            env=env,
        )
        assert done.returncode == 0 and f"vehicle 1: MC_YAWRATE_MAX = {value:g}" in done.stdout, done
        stranger = mavutil.mavlink_connection(f"udpout:127.0.0.1:{gcs[2]}", source_system=250)
        sent = int(np.random.default_rng().integers(3, 12))
        for _ in range(sent):
            stranger.mav.param_request_read_send(2, 1, b"MC_YAWRATE_MAX", -1)
            time.sleep(0.01)
        assert stranger.recv_match(blocking=True, timeout=1.0) is None  # not one byte back
        stdout, stderr = run.communicate(timeout=60)
    finally:
        if run.poll() is None:
            run.kill()
            run.wait()
    assert run.returncode == 0, stderr
    assert f"vehicle 2: {sent} unsigned messages refused on its ground-station port" in stdout, stdout
    refused = json.loads((out / "summary.json").read_text())["vehicles"]
    assert refused["2"]["rx_unsigned"] == {"controller": 0, "ground_station": sent}
    assert "rx_unsigned" not in refused["1"]  # the script signed every message
