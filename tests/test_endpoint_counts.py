"""What a vehicle counts of what it receives (``vehicle.endpoint``'s ``stats``), for any mix of
datagrams on its two ports: every well-formed message once in ``rx_messages``; refused once,
those addressed to another vehicle or another of its components and setpoints on the ground
station's port; unhandled once, those it has no service for (ArduCopter's REQUEST_DATA_STREAM on
PX4 among them, and a command it does not know); invalid once, a parameter it does not have and
a command whose parameter it reads is not finite; the messages after a bad frame in the same
datagram still handled, and those before a last frame cut short (bad once). A datagram of frames
is one or more messages one after another; a setpoint alone in one is what a controller sends
(the fast path)."""

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import common as mav

from sim_vehicles.vehicle.autopilots import PROFILES
from tests.fakes import recording_endpoint

pytestmark = pytest.mark.integration  # (an endpoint driven in process)
SYS = 3
PEER = ("127.0.0.1", 40003)


def _message(kind: str, seq: int):
    """``(message, counted as)``: refused, unhandled, invalid or handled."""
    if kind == "ping":  # a request (to everyone): echoed
        return mav.MAVLink_ping_message(seq, seq, 0, 0), "handled"
    if kind == "ping elsewhere":
        return mav.MAVLink_ping_message(seq, seq, SYS + 1, 1), "refused"
    if kind == "heartbeat":
        return mav.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3), "handled"
    if kind == "debug":  # nothing a vehicle answers
        return mav.MAVLink_debug_message(seq, 0, 1.5), "unhandled"
    if kind == "ping another component":  # this system, not its autopilot (1)
        return mav.MAVLink_ping_message(seq, seq, SYS, 5), "refused"
    if kind == "data stream":
        return mav.MAVLink_request_data_stream_message(SYS, 1, 0, 4, 1), "data stream"
    if kind == "unknown parameter":  # (a name no autopilot has)
        return mav.MAVLink_param_set_message(
            SYS, 1, b"NO_SUCH_PARAM", 1.0, mav.MAV_PARAM_TYPE_REAL32
        ), "invalid"
    if kind == "arm with NaN":  # a command whose parameter it reads is not finite
        return mav.MAVLink_command_long_message(
            SYS, 1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, *[math.nan] * 7
        ), "invalid"
    if kind == "unknown command":
        return mav.MAVLink_command_long_message(SYS, 1, 31999, 0, 0, 0, 0, 0, 0, 0, 0), "unhandled"
    target = {"setpoint elsewhere": (SYS + 1, 1), "setpoint to another component": (SYS, 5)}.get(
        kind, (SYS, 1)
    )
    m = mav.MAVLink_set_attitude_target_message(seq, *target, 0b111, [1, 0, 0, 0], 0, 0, 0, 0.5)
    return m, ("setpoint" if target == (SYS, 1) else "refused")


#: a frame to cut short (a PING of 9 payload bytes, 21 in all)
LAST = bytes(
    mav.MAVLink_ping_message(123456789, 7, 0, 0).pack(mav.MAVLink(None, srcSystem=255, srcComponent=190))
)

KINDS = [
    "ping", "ping elsewhere", "ping another component", "heartbeat", "debug", "data stream",
    "unknown parameter", "arm with NaN", "unknown command",
    "setpoint", "setpoint elsewhere", "setpoint to another component",
]  # fmt: skip


@settings(max_examples=40, deadline=None)
@given(
    profile=st.sampled_from(sorted(PROFILES)),
    datagrams=st.lists(
        st.tuples(
            st.sampled_from(["controller", "ground station"]),
            st.lists(
                st.sampled_from(KINDS),
                min_size=1,
                max_size=3,
            ),
            st.sampled_from([None, "crc", "not a frame"]),  # a bad frame first: its CRC broken, or bytes
            st.integers(0, len(LAST) - 1),  # a last frame cut short after this many bytes (0: none)
        ),
        max_size=12,
    ),
)
def test_every_message_is_counted_once_as_what_the_vehicle_did_with_it(profile, datagrams):
    ep = recording_endpoint(SYS, profile=PROFILES[profile], gcs_bind=("127.0.0.1", 0))
    link = mav.MAVLink(None, srcSystem=255, srcComponent=190)
    want = {"messages": 0, "refused": 0, "unhandled": 0, "bad": 0, "invalid": 0}
    try:
        for n, (where, kinds, bad_first, cut) in enumerate(datagrams):
            port = ep.port if where == "controller" else ep.gcs
            data = b""
            if bad_first == "crc":
                broken = bytearray(mav.MAVLink_ping_message(0, 0, SYS, 1).pack(link))
                broken[-1] ^= 0xFF
                data += bytes(broken)
                want["messages"] += 1  # (a frame: counted, then refused as bad)
                want["bad"] += 1
            elif bad_first == "not a frame":  # pymavlink's BAD_DATA: one bad message (``decoder``)
                data += b"\x00\x11\x22\x33"
                want["messages"] += 1
                want["bad"] += 1
            for kind in kinds:
                m, counted = _message(kind, n)
                data += bytes(m.pack(link))
                want["messages"] += 1
                if counted == "data stream":
                    counted = "handled" if profile == "ardupilot" else "unhandled"
                if counted == "setpoint":
                    counted = "refused" if port is ep.gcs else "handled"
                if counted in ("refused", "unhandled", "invalid"):
                    want[counted] += 1
            if cut:  # the datagram ends inside a frame: the datagram's garbage, once
                data += LAST[:cut]
                want["bad"] += 1
            ep.datagram(data, PEER, port)
            got = ep.stats
            counts = (got.rx_messages, got.rx_refused, got.rx_unhandled, got.rx_bad, got.rx_invalid)
            assert counts == tuple(want.values()), n
        assert ep.stats.handler_errors == 0
    finally:
        ep.close()
