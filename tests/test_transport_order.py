"""A controller's MAVLink transport (``link.transport.Transport``) under a fault plan: what the plan
held and now releases is read in the plan's order, before what arrives live, each datagram once."""

import socket

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from swarm_sitl.link.transport import Transport

pytestmark = pytest.mark.unit


class _Releases:
    """A fault plan that releases ``held`` (in that order) at its first look and passes the rest."""

    def __init__(self, held: list[bytes]):
        self.held = list(held)

    def release(self, write) -> list[bytes]:  # type: ignore[no-untyped-def]
        out, self.held = self.held, []
        return out

    def receive(self, data: bytes) -> bytes:
        return data


@settings(max_examples=30)
@given(
    st.lists(st.binary(min_size=1, max_size=40), min_size=1, max_size=8, unique=True), st.binary(min_size=1)
)
def test_held_datagrams_come_out_in_the_order_released_then_the_live_one(held, live):
    t = Transport("udpin:127.0.0.1:0", 1, stamp_arrivals=False, faults=_Releases(held))
    try:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.sendto(live, t.conn.port.getsockname())
            got = []
            for data, _ in t.datagrams(readable=True):
                got.append(data)
        assert got == [*held, live]
    finally:
        t.close()
