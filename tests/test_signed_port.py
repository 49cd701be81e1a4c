"""A signed vehicle port admits a datagram exactly when it is signed with the link's key and moves
its stream forward, for any mix of datagrams: signed right, signed with another key, unsigned,
replayed, garbage. Each datagram is counted once: admitted + bad + refused = received, bad being
a wrong signature or not frames, refused an unsigned or replayed one (``vehicle.port.Port.admit``);
an admitted one is its frames as sent. Who the port's peer is (``Port.heard``): the first address
heard; another after the peer's silence, or at once as the vehicle's signed companion. A signed
vehicle's two ports alike answer only the signed, and sign what they answer."""

import math
from unittest import mock

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import common as mav

from sim_vehicles.mavlink.px4_profile import COMPANION
from sim_vehicles.mavlink.signing import Signer
from sim_vehicles.vehicle import port as port_module
from sim_vehicles.vehicle.port import PEER_SILENT_S, EndpointStats, Port, Tlog
from tests.fakes import recording_endpoint

KEY, OTHER = bytes(range(32)), bytes(range(1, 33))


def _frame(n: int) -> bytes:
    link = mav.MAVLink(None, srcSystem=255, srcComponent=190)
    return bytes(mav.MAVLink_heartbeat_message(6, 8, 0, n, 0, 3).pack(link))


@pytest.mark.unit
@settings(max_examples=60, deadline=None)
@given(kinds=st.lists(st.sampled_from(["signed", "other key", "unsigned", "replay", "garbage"]), max_size=25))
def test_each_datagram_is_admitted_or_counted_bad_or_refused_once(kinds):
    port = Port(("127.0.0.1", 0), 3, {}, EndpointStats(), Tlog(None), signing_key=KEY)
    ours, theirs = Signer(KEY), Signer(OTHER)
    sent: list[bytes] = []
    admitted = expected_bad = expected_refused = 0
    try:
        for n, kind in enumerate(kinds):
            plain = _frame(n)
            if kind == "signed":
                data = ours.seal(plain)
                sent.append(data)
            elif kind == "replay" and sent:
                data = sent[0]  # the first signed one again: its timestamp does not move forward
            elif kind == "other key":
                data = theirs.seal(plain)
            elif kind == "garbage":
                data = b"\xfd" + bytes(range(40))  # a MAVLink 2 start and no frame
            else:
                kind, data = "unsigned", plain
            got = port.admit(data, ("127.0.0.1", 40000 + n))
            if kind == "signed":
                assert got == plain
                admitted += 1
            else:
                assert got is None, kind
                expected_bad += kind in ("other key", "garbage")
                expected_refused += kind in ("unsigned", "replay")
            assert (port.stats.rx_bad, port.stats.rx_refused) == (expected_bad, expected_refused)
        assert admitted + port.stats.rx_bad + port.stats.rx_refused == len(kinds)
    finally:
        port.close()


#: who speaks (``Port.accepted_from`` of the message heard): the vehicle's own companion computer
#: (its controller), a ground station, another vehicle's companion
SPEAKERS = {"companion": (3, COMPANION), "ground station": (255, 190), "another companion": (4, COMPANION)}


@pytest.mark.unit
@settings(max_examples=80, deadline=None)
@given(
    signed=st.booleans(),
    events=st.lists(
        st.tuples(st.integers(0, 3), st.sampled_from(sorted(SPEAKERS)), st.floats(0.0, 2 * PEER_SILENT_S)),
        max_size=20,
    ),
)
def test_a_new_address_takes_the_link_after_the_peers_silence_or_at_once_as_its_signed_companion(
    signed, events
):
    """The first address heard is the peer (greeted once); another takes its place (greeted) only
    after the peer has been silent ``PEER_SILENT_S``, or at once on a signed link when it speaks
    as the vehicle's own companion computer (a restarted controller at a new port). Anyone else
    signed is heard, and the telemetry stays with the peer."""
    port = Port(("127.0.0.1", 0), 3, {}, EndpointStats(), Tlog(None), signing_key=KEY if signed else None)
    clock = [100.0]
    peer, peer_heard, greeted, want_greeted = None, -math.inf, [], []
    try:
        with mock.patch.object(port_module.time, "monotonic", lambda: clock[0]):
            for n, who, dt in events:
                clock[0] += dt
                addr = ("127.0.0.1", 40000 + n)
                port.accepted_from = SPEAKERS[who]
                port.heard(addr, lambda p, addr=addr: greeted.append(addr))
                silent = clock[0] - peer_heard > PEER_SILENT_S
                if addr != peer and (silent or (signed and who == "companion")):
                    peer = addr
                    want_greeted.append(addr)
                if addr == peer:
                    peer_heard = clock[0]
                assert (port.peer, greeted) == (peer, want_greeted), (n, who)
    finally:
        port.close()


@pytest.mark.integration
@settings(max_examples=20, deadline=None)
@given(
    order=st.lists(st.tuples(st.sampled_from(["controller", "ground station"]), st.booleans()), max_size=10)
)
def test_both_ports_of_a_signed_vehicle_answer_only_the_signed_and_sign_their_answers(order):
    """A signed vehicle's controller port and ground-station port alike: a PING request signed
    with the key is answered, signed; an unsigned one is refused, counted against its port
    (``unsigned_by_port``), and answered by nothing."""
    ep = recording_endpoint(3, signing_key=KEY, gcs_bind=("127.0.0.1", 0))
    ports = {"controller": ep.port, "ground station": ep.gcs}
    unsigned = {"controller": 0, "ground_station": 0}
    link, signer = mav.MAVLink(None, srcSystem=255, srcComponent=190), Signer(KEY)
    try:
        for n, (where, signed) in enumerate(order):
            port = ports[where]
            ping = bytes(mav.MAVLink_ping_message(n, n, 0, 0).pack(link))
            ping = signer.seal(ping) if signed else ping
            port.sock.sent.clear()
            ep.datagram(ping, ("127.0.0.1", 40000), port)
            port.flush()
            unsigned[where.replace(" ", "_")] += not signed
            assert ep.unsigned_by_port() == unsigned
            reader = mav.MAVLink(None)
            reader.signing.secret_key = KEY
            back = [m for d in port.sock.sent for m in reader.parse_buffer(d) or [] if m.get_type() == "PING"]
            assert [(m.seq, m.get_signed()) for m in back] == ([(n, True)] if signed else [])
    finally:
        ep.close()
