"""The per-tick MAVLink path (``sim_vehicles.mavlink.frames``) against pymavlink itself: the same
bytes out, the same fields in, and anything it does not handle left to pymavlink whole."""

import contextlib
import os
import select
import socket
import struct
import time
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import common as mav

from sim_vehicles.mavlink import frames
from tests.fakes import FrameSink
from tests.support import raw_frame

pytestmark = pytest.mark.unit

LAYOUTS = [
    frames.LOCAL_POSITION_NED,
    frames.ATTITUDE_QUATERNION,
    frames.ATTITUDE,
    frames.ATTITUDE_TARGET,
    frames.HIGHRES_IMU,
    frames.SET_ATTITUDE_TARGET,
]
#: every other field kind the kernels handle: signed integers (SYS_STATUS, which the vehicle sends,
#: GPS_GLOBAL_ORIGIN, TIMESYNC), uint64 and float64 arrays (WHEEL_DISTANCE)
OTHER_KINDS = [
    frames.Layout(mav.MAVLink_sys_status_message),
    frames.Layout(mav.MAVLink_gps_global_origin_message),
    frames.Layout(mav.MAVLink_timesync_message),
    frames.Layout(mav.MAVLink_wheel_distance_message),
]


def _f32(x: float) -> float:
    return struct.unpack("<f", struct.pack("<f", x))[0]


def _values(layout: frames.Layout, draw: st.DrawFn) -> list:
    """Random declared-order values that fit each field's wire type."""
    fmt = layout.struct.format.lstrip("<")
    wire_types: list[str] = []
    count = ""
    for ch in fmt:
        if ch.isdigit():
            count += ch
        else:
            wire_types += [ch] * int(count or 1)
            count = ""
    out = []
    for d in range(len(layout.names)):
        t = wire_types[layout.wire_of[d]]
        if t == "f":
            out.append(_f32(draw(st.floats(-1e6, 1e6))) if draw(st.booleans()) else 0.0)
        elif t == "d":
            out.append(draw(st.floats(-1e300, 1e300)) if draw(st.booleans()) else 0.0)
        else:
            bits = min({"B": 8, "H": 16, "I": 32, "Q": 64}[t.upper()], 53)  # values travel as float64
            lo, hi = (-(2 ** (bits - 1)), 2 ** (bits - 1) - 1) if t.islower() else (0, 2**bits - 1)
            out.append(draw(st.integers(lo, hi)) if draw(st.booleans()) else 0)
    return out


def _pymavlink_message(layout: frames.Layout, values: list):
    """The pymavlink message with these declared-order values (arrays regrouped)."""
    cls = mav.mavlink_map[layout.msg_id]
    args, i = [], 0
    for name in cls.fieldnames:
        if f"{name}[0]" in layout.names:
            n = sum(1 for x in layout.names if x.startswith(f"{name}["))
            args.append(list(values[i : i + n]))
            i += n
        else:
            args.append(values[i])
            i += 1
    return cls(*args)


def _afresh_or_not(layout: frames.Layout, draw: st.DrawFn) -> frames.Layout:
    """``layout``, or the same message's built again here: the module's layouts are built when it
    is imported, so only a fresh one shows what ``Layout`` builds now (a mutation test switches a
    mutant on after the import)."""
    return frames.Layout(mav.mavlink_map[layout.msg_id]) if draw(st.booleans()) else layout


@settings(max_examples=150, deadline=None)
@given(data=st.data(), seq=st.integers(0, 255), sysid=st.integers(1, 255), compid=st.integers(0, 255))
def test_frames_are_byte_identical_to_pymavlink_and_read_back_the_same(data, seq, sysid, compid):
    layout = _afresh_or_not(data.draw(st.sampled_from(LAYOUTS)), data.draw)
    values = _values(layout, data.draw)
    ref, ours = mav.MAVLink(FrameSink(), sysid, compid), mav.MAVLink(FrameSink(), sysid, compid)
    ref.seq = ours.seq = seq
    ref.send(_pymavlink_message(layout, values))
    frame = frames.pack_frame(ours, layout, values)
    assert frame == ref.file.frames[0]
    assert ours.seq == ref.seq == (seq + 1) % 256

    (msg_id, s, c, got, raw), *rest = frames.read_datagram(frame, {layout.msg_id: layout})
    assert not rest and (msg_id, s, c, raw) == (layout.msg_id, sysid, compid, frame)
    decoded = mav.MAVLink(None, 255, 0).decode(bytearray(frame))
    flat = []
    for name in decoded.fieldnames:
        v = getattr(decoded, name)
        flat += list(v) if isinstance(v, list) else [v]
    assert list(got) == flat == values


def test_trailing_zero_fields_shorten_the_frame_and_read_back_as_zero():
    ours = mav.MAVLink(FrameSink(), 1, 1)
    frame = frames.pack_frame(ours, frames.LOCAL_POSITION_NED, (5, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0))
    assert frame[1] == 8  # time_boot_ms and x: the zeros after them are not sent
    ((_, _, _, got, _),) = frames.read_datagram(frame, {32: frames.LOCAL_POSITION_NED})
    assert got == (5, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0)


def _two_frames() -> tuple[bytes, bytes]:
    link = mav.MAVLink(FrameSink(), 3, 1)
    a = frames.pack_frame(link, frames.LOCAL_POSITION_NED, (10, 1.0, 2.0, 3.0, 0.1, 0.2, 0.3))
    link.heartbeat_send(mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_GENERIC, 0, 0, 0)
    return a, link.file.frames[0]


def test_other_messages_are_handed_back_whole_for_pymavlink():
    lpos, hb = _two_frames()
    out = frames.read_datagram(lpos + hb, {32: frames.LOCAL_POSITION_NED})
    assert [o[0] for o in out] == [32, mav.MAVLINK_MSG_ID_HEARTBEAT]
    assert out[1][3] is None and out[1][4] == hb
    assert mav.MAVLink(None, 255, 0).decode(bytearray(out[1][4])).get_type() == "HEARTBEAT"


@pytest.mark.parametrize(
    "mangle",
    [
        lambda d: d[:-1],  # truncated
        lambda d: d[:20] + bytes([d[20] ^ 0xFF]) + d[21:],  # a payload byte flipped: bad CRC
        lambda d: b"\xfe" + d[1:],  # not a MAVLink 2 start byte
        lambda d: d[:2] + b"\x01" + d[3:],  # signed (incompat flag): pymavlink's job
        lambda d: b"garbage" + d,
        lambda d: d + b"\x00",
    ],
)
def test_anything_but_plain_mavlink2_frames_goes_to_pymavlink(mangle):
    lpos, hb = _two_frames()
    assert frames.read_datagram(mangle(lpos + hb), {32: frames.LOCAL_POSITION_NED}) is None


def test_pack_frame_leaves_signing_to_pymavlink():
    link = mav.MAVLink(FrameSink(), 1, 1)
    link.signing.sign_outgoing = True
    with pytest.raises(ValueError, match="sign"):
        frames.pack_frame(link, frames.LOCAL_POSITION_NED, (1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0))


@pytest.mark.skipif(os.uname().sysname != "Linux", reason="kernel receive timestamps are Linux only")
def test_a_udp_link_knows_when_a_sample_arrived_without_reading_it_then():
    from swarm_sitl.link.vehicle_link import VehicleLink

    vehicle = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    vehicle.bind(("127.0.0.1", 0))
    vehicle.settimeout(5)
    link = VehicleLink(f"udpout:127.0.0.1:{vehicle.getsockname()[1]}", 3)
    try:
        assert link.stamps_arrivals
        link.send_heartbeat_if_due()
        _, controller_addr = vehicle.recvfrom(512)
        tx = mav.MAVLink(FrameSink(), 3, 1)
        # a first datagram, read: the kernel turns receive stamps on for the whole system lazily
        # (a deferred job), and one that comes before that is stamped when it is read
        vehicle.sendto(
            frames.pack_frame(tx, frames.LOCAL_POSITION_NED, (20, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)),
            controller_addr,
        )
        time.sleep(0.05)
        link.poll()
        sample = frames.pack_frame(tx, frames.LOCAL_POSITION_NED, (40, 1.0, 2.0, -3.0, 0.0, 0.0, 0.0))
        sample += frames.pack_frame(tx, frames.ATTITUDE_QUATERNION, (40, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0))
        wall_offset = time.time() - time.monotonic()
        sent = time.monotonic()
        vehicle.sendto(sample, controller_addr)
        # readable: it has arrived (on a loaded machine loopback delivery can lag sendto)
        assert select.select([link.fileno()], [], [], 5.0)[0]
        arrived_by = time.monotonic()
        time.sleep(0.2)  # read long after it arrived
        read_at = time.monotonic()
        link.poll()
        # the kernel stamps arrivals on the wall clock: a step of it meanwhile moves the stamp by as
        # much, which the tolerance takes
        step = abs((time.time() - time.monotonic()) - wall_offset)
        assert link.sample_ms == 40
        assert sent - 0.005 - step <= link.sample_arrival_mono <= arrived_by + 0.005 + step
        assert arrived_by + 0.005 < read_at
        _, p, _, _ = link.sample()
        assert list(p) == [2.0, 1.0, 3.0]  # NED -> ENU
    finally:
        link.close()
        vehicle.close()


def _sample_pass(tx: Any, ms: int, down_m: float = -3.0) -> bytes:
    """A vehicle's sample pass from ``tx``: LOCAL_POSITION_NED (``down_m`` in NED) and
    ATTITUDE_QUATERNION of instant ``ms``."""
    s = frames.pack_frame(tx, frames.LOCAL_POSITION_NED, (ms, 1.0, 2.0, down_m, 0.0, 0.0, 0.0))
    return s + frames.pack_frame(tx, frames.ATTITUDE_QUATERNION, (ms, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0))


@contextlib.contextmanager
def _vehicle_and_link(**link_kwargs: Any) -> Iterator[tuple[socket.socket, Any, Any]]:
    """A bare UDP socket standing in for vehicle 3, and a controller's ``VehicleLink`` to it (no
    arrival stamps) that has spoken once: yields the socket, the link and the link's address."""
    from swarm_sitl.link.vehicle_link import VehicleLink

    vehicle = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    vehicle.bind(("127.0.0.1", 0))
    vehicle.settimeout(5)
    link = VehicleLink(f"udpout:127.0.0.1:{vehicle.getsockname()[1]}", 3, stamp_arrivals=False, **link_kwargs)
    try:
        link.send_heartbeat_if_due()
        _, controller_addr = vehicle.recvfrom(512)
        yield vehicle, link, controller_addr
    finally:
        link.close()
        vehicle.close()


@pytest.mark.parametrize("signed", [False, True])
def test_a_link_speaks_mavlink_2_whatever_its_environment(monkeypatch, signed):
    """pymavlink takes a connection's wire protocol from the environment when it opens it: a
    controller forked from a server whose environment was replaced after the import spoke
    MAVLink 1, which cannot be signed, and its signed vehicle refused every message."""
    from sim_vehicles.mavlink.signing import SIGNED
    from swarm_sitl.link.vehicle_link import VehicleLink

    monkeypatch.delenv("MAVLINK20", raising=False)
    vehicle = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    vehicle.bind(("127.0.0.1", 0))
    vehicle.settimeout(5)
    key = bytes(32) if signed else None
    link = VehicleLink(
        f"udpout:127.0.0.1:{vehicle.getsockname()[1]}", 3, stamp_arrivals=False, signing_key=key
    )
    try:
        link.send_heartbeat_if_due()
        data, _ = vehicle.recvfrom(512)
    finally:
        link.close()
        vehicle.close()
    assert data[0] == frames.MAGIC_V2 and bool(data[2] & SIGNED) == signed


def test_a_link_checks_the_telemetry_it_ignores_and_counts_what_is_bad():
    """The controller's link decodes only the messages it uses; a frame it skips still has its
    CRC checked, and a bad one is counted, as pymavlink's parser would; a message the common set
    does not have (no CRC extra to check it by) is passed over, as pymavlink's parser passes it
    (``MAVLink_unknown``)."""
    with _vehicle_and_link() as (vehicle, link, controller_addr):
        assert not link.stamps_arrivals
        tx = mav.MAVLink(FrameSink(), 3, 1)
        sample = _sample_pass(tx, 40)
        attitude = frames.pack_frame(tx, frames.ATTITUDE, (40, 0.1, 0.2, 0.3, 0.0, 0.0, 0.0))
        corrupted = attitude[:-1] + bytes([attitude[-1] ^ 0xFF])
        unknown = bytearray(attitude)
        unknown[7:10] = (60000).to_bytes(3, "little")  # no such message in the common set
        for extra, bad in ((attitude, 0), (corrupted, 1), (bytes(unknown), 0)):
            before = link.rx_bad
            vehicle.sendto(sample + extra, controller_addr)
            deadline = time.monotonic() + 5
            while link.poll() == 0 and time.monotonic() < deadline:
                time.sleep(0.01)
            assert link.sample_ms == 40
            assert link.rx_bad - before == bad


def test_a_lockstep_read_stops_at_the_sample_it_waits_for_and_leaves_the_rest_queued():
    """``poll(until_ms=...)``: once the sample of that instant is in, the link stops reading (a
    lockstep tick needs nothing more); what came after it is read by the next poll."""
    tx = mav.MAVLink(FrameSink(), 3, 1)
    with _vehicle_and_link() as (vehicle, link, controller_addr):
        for datagram in (
            _sample_pass(tx, 10),
            _sample_pass(tx, 20),
            bytes(mav.MAVLink_heartbeat_message(2, 12, 0, 4, 3, 3).pack(tx)),
        ):
            vehicle.sendto(datagram, controller_addr)
        time.sleep(0.2)  # all three have arrived
        assert link.poll(until_ms=10) == 2 and link.sample_ms == 10  # the first datagram only
        assert link.poll(until_ms=20) == 2 and link.sample_ms == 20 and link.heartbeat is None
        assert link.poll() == 1 and link.heartbeat is not None  # the rest, at the next read


def test_a_signed_link_reads_its_sample_and_refuses_the_rest():
    """On a signed link a sample datagram is checked, unsigned and read as the sample; anything
    else it takes goes on to the general reader, and what it refuses is counted: unsigned or
    replayed as refused, wrongly signed as bad."""
    from sim_vehicles.mavlink.signing import Signer, key_from_passphrase

    key = key_from_passphrase("run key")
    signer = Signer(key)
    tx = mav.MAVLink(FrameSink(), 3, 1)

    def deliver(datagram: bytes) -> None:
        vehicle.sendto(datagram, controller_addr)
        deadline = time.monotonic() + 5
        while link.poll() == 0 and link.rx_bad + link.rx_refused == counts and time.monotonic() < deadline:
            time.sleep(0.01)

    with _vehicle_and_link(signing_key=key) as (vehicle, link, controller_addr):
        counts = 0
        first = signer.seal(_sample_pass(tx, 40, -3.0))
        deliver(first)
        assert link.sample_ms == 40 and link.sample()[1][2] == 3.0  # NED down -3 m: ENU up 3 m
        heartbeat = bytes(mav.MAVLink_heartbeat_message(2, 12, 0, 4, 3, 3).pack(tx))
        deliver(signer.seal(heartbeat))  # not a sample: unsigned and read the general way
        assert link.heartbeat is not None and link.heartbeat.autopilot == 12
        for datagram, refused, bad in (
            (_sample_pass(tx, 50, -4.0), 1, 0),  # unsigned
            (first, 1, 0),  # replayed
            (Signer(key_from_passphrase("other")).seal(_sample_pass(tx, 50, -4.0)), 0, 1),  # wrongly signed
        ):
            before = (link.rx_refused, link.rx_bad)
            counts = sum(before)
            deliver(datagram)
            assert (link.rx_refused - before[0], link.rx_bad - before[1]) == (refused, bad)
            assert link.sample_ms == 40
        counts = link.rx_bad + link.rx_refused
        deliver(signer.seal(_sample_pass(tx, 50, -4.0)))
        assert link.sample_ms == 50 and link.sample()[1][2] == 4.0


@settings(max_examples=150, deadline=None)
@given(data=st.data(), seq=st.integers(0, 255), sysid=st.integers(1, 255), compid=st.integers(0, 255))
def test_compiled_frames_are_byte_identical_to_pymavlink_and_read_back_the_same(data, seq, sysid, compid):
    """``pack_into``/``read_into`` (the kernels of ``tick_frames``) against pymavlink itself."""
    layout = _afresh_or_not(data.draw(st.sampled_from(LAYOUTS + OTHER_KINDS)), data.draw)
    values = _values(layout, data.draw)
    ref = mav.MAVLink(FrameSink(), sysid, compid)
    ref.seq = seq
    ref.send(_pymavlink_message(layout, values))
    expected = ref.file.frames[0]
    out = np.full(layout.struct.size + 16, 0xAA, dtype=np.uint8)  # stale bytes must not leak in
    at = data.draw(st.integers(0, 4))
    end = frames.pack_into(out, at, seq, sysid, compid, layout.spec, np.array(values, dtype=float))
    assert out[at:end].tobytes() == expected

    datagram = b"\x00" * at + expected
    assert frames.frame_at(datagram, at) == (layout.msg_id, sysid, compid, len(datagram))
    back = np.empty(len(values))
    assert frames.read_into(datagram, at, len(datagram), layout.spec, back)
    assert back.tolist() == values
    bad = bytearray(datagram)
    bad[-3] ^= 0x01  # the last payload byte (or a header byte of an empty payload): CRC must fail
    assert not frames.read_into(bytes(bad), at, len(bad), layout.spec, back)


@pytest.mark.parametrize("cut", [1, 5, 11])
def test_frame_at_refuses_what_is_not_a_whole_plain_frame(cut):
    lpos, _ = _two_frames()
    assert frames.frame_at(lpos[:-cut], 0)[3] == -1
    assert frames.frame_at(b"\xfe" + lpos[1:], 0)[3] == -1  # MAVLink 1
    assert frames.frame_at(lpos[:2] + b"\x01" + lpos[3:], 0)[3] == -1  # signed


@given(data=st.data())
def test_crc_ok_checks_any_common_message_by_its_own_crc_extra(data):
    """Any message of the common set (ids from 0 to over 2^8 and 2^16's byte), any payload: its
    frame with the CRC of its own CRC extra passes; with another CRC extra, or any covered byte
    changed, it does not; a frame with an id the set does not have never passes."""
    cls = data.draw(st.sampled_from(sorted(mav.mavlink_map.values(), key=lambda c: c.id)))
    payload = data.draw(st.binary(min_size=1, max_size=cls.unpacker.size))
    frame = raw_frame(cls, payload)
    assert frames.crc_ok(frame)
    other = data.draw(st.integers(0, 255).filter(lambda e: e != cls.crc_extra))
    assert not frames.crc_ok(raw_frame(cls, payload, other))
    # any byte the CRC covers or is, but the length and the id (which would make it another
    # frame): X.25 detects every change of one byte
    at = data.draw(st.sampled_from([j for j in range(2, len(frame)) if j not in (7, 8, 9)]))
    bad = bytearray(frame)
    bad[at] ^= data.draw(st.integers(1, 255))
    assert not frames.crc_ok(bytes(bad))
    unknown = data.draw(st.integers(0, 2**24 - 1).filter(lambda i: i not in mav.mavlink_map))
    alien = bytearray(frame)
    alien[7:10] = unknown.to_bytes(3, "little")
    assert not frames.crc_ok(bytes(alien))
