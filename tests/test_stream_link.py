"""A controller's link over a stream (``tcp:``, as to an ArduPilot SITL's SERIAL0 on port 5760):
it opens without the kernel's datagram stamps (a stream has none), reads the vehicle's bytes
however the stream cuts them into reads (a read may end inside a frame: pymavlink's parser keeps
the rest for the next), and sends its own messages on the same connection."""

import socket
import time

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import common as mav

from sim_vehicles.mavlink import frames
from swarm_sitl.link.vehicle_link import VehicleLink
from tests.fakes import FrameSink

pytestmark = pytest.mark.integration
SYS = 3


def _stream(samples: list[int]) -> bytes:
    """A vehicle's HEARTBEAT, then a sample (LOCAL_POSITION_NED and ATTITUDE_QUATERNION) at each
    instant of ``samples`` [ms], up 1 m more each time."""
    tx = mav.MAVLink(FrameSink(), SYS, 1)
    out = bytes(mav.MAVLink_heartbeat_message(2, 12, 0, 4, 3, 3).pack(tx))
    for k, ms in enumerate(samples):
        out += frames.pack_frame(tx, frames.LOCAL_POSITION_NED, (ms, 1.0, 2.0, -float(k), 0.0, 0.0, 0.0))
        out += frames.pack_frame(tx, frames.ATTITUDE_QUATERNION, (ms, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0))
    return out


@settings(max_examples=10, deadline=None)
@given(n=st.integers(1, 4), cuts=st.lists(st.integers(1, 400), max_size=6))
def test_a_link_over_tcp_reads_the_stream_however_it_is_cut_and_speaks_on_it(n, cuts):
    samples = [20 * (k + 1) for k in range(n)]
    data = _stream(samples)
    at = sorted({c % len(data) for c in cuts} - {0})
    pieces = [data[i:j] for i, j in zip([0, *at], [*at, len(data)], strict=True)]
    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen(1)
        link = VehicleLink(f"tcp:127.0.0.1:{server.getsockname()[1]}", SYS)  # (stamps asked for)
        vehicle, _ = server.accept()
        try:
            assert not link.transport.stamps_arrivals and not link.transport.whole_datagrams
            for piece in pieces:
                vehicle.sendall(piece)
                time.sleep(0.005)
                link.poll()
            deadline = time.monotonic() + 5
            while link.sample_ms != samples[-1] and time.monotonic() < deadline:
                link.conn.select(0.05)
                link.poll()
            assert link.sample_ms == samples[-1] and link.sample()[1][2] == n - 1  # NED down -> ENU up
            assert link.heartbeat is not None and link.rx_bad == 0
            link.send_heartbeat_if_due()  # and what it sends comes on the same connection
            vehicle.settimeout(5)
            got = mav.MAVLink(None).parse_buffer(vehicle.recv(4096)) or []
            assert [(m.get_type(), m.get_srcSystem(), m.get_srcComponent()) for m in got][:1] == [
                ("HEARTBEAT", SYS, mav.MAV_COMP_ID_ONBOARD_COMPUTER)
            ]
        finally:
            link.close()
            vehicle.close()
