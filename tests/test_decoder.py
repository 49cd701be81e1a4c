"""One received datagram's messages (``sim_vehicles.mavlink.decoder.messages``), against pymavlink's
own packing as the reference: whatever mix of MAVLink 2 and MAVLink 1 frames, from whichever
systems and components, a datagram yields each of its messages once, in order, with its sender,
and nothing bad; a datagram whose last frame is cut short yields the whole ones, then one
``GARBAGE``, and the next datagram reads clean."""

import pytest
from hypothesis import given
from hypothesis import strategies as st
from pymavlink.dialects.v10 import common as mav1
from pymavlink.dialects.v20 import common as mav2

from sim_vehicles.mavlink import decoder

pytestmark = pytest.mark.unit

ids = st.integers(1, 255)
floats = st.floats(-1e3, 1e3, width=32)


@st.composite
def frames(draw):
    """A message pymavlink packs as MAVLink 2 or 1, from a drawn system and component."""
    v1 = draw(st.booleans())
    dialect = mav1 if v1 else mav2
    link = dialect.MAVLink(None, srcSystem=draw(ids), srcComponent=draw(ids))
    kind = draw(st.sampled_from(["heartbeat", "lpos", "param", "command"]))
    if kind == "heartbeat":
        m = dialect.MAVLink_heartbeat_message(
            2, 12, draw(st.integers(0, 255)), draw(st.integers(0, 2**32 - 1)), 4, 3
        )
    elif kind == "lpos":
        m = dialect.MAVLink_local_position_ned_message(
            draw(st.integers(0, 2**32 - 1)), *[draw(floats) for _ in range(6)]
        )
    elif kind == "param":
        m = dialect.MAVLink_param_request_read_message(draw(ids), draw(ids), b"MPC_THR_HOVER", -1)
    else:
        m = dialect.MAVLink_command_long_message(
            draw(ids), draw(ids), 511, 0, *[draw(floats) for _ in range(7)]
        )
    frame = bytes(m.pack(link))
    return frame, m.get_msgId(), link.srcSystem, link.srcComponent


def _read(data: bytes, parser, wanted=lambda msg_id: True) -> list[decoder.Received]:  # type: ignore[no-untyped-def]
    return list(decoder.messages(data, parser, wanted=wanted))


@given(st.lists(frames(), min_size=1, max_size=6), st.booleans())
def test_a_datagram_yields_each_message_once_in_order_with_its_sender(sent, decoded):
    """... whether the receiver asks for the messages decoded or only counts them (``wanted``)."""
    parser = mav2.MAVLink(None, srcSystem=255, srcComponent=0)
    got = _read(b"".join(f for f, *_ in sent), parser, lambda msg_id: decoded)
    assert [(r.msg_id, r.system, r.component) for r in got] == [tuple(s[1:]) for s in sent]
    assert not any(r.bad for r in got)
    assert [r.frame for r in got] == [f for f, *_ in sent]
    assert all(r.message.get_msgId() == r.msg_id for r in got if decoded or r.message is not None)


@given(st.lists(frames(), min_size=1, max_size=4), st.data())
def test_a_frame_cut_short_is_garbage_once_and_the_next_datagram_reads_clean(sent, data):
    *whole, (last, *_) = sent
    cut = data.draw(st.integers(1, len(last) - 1))
    parser = mav2.MAVLink(None, srcSystem=255, srcComponent=0)
    got = _read(b"".join(f for f, *_ in whole) + last[:-cut], parser)
    good = [r for r in got if not r.bad]
    assert [(r.msg_id, r.system, r.component) for r in good] == [tuple(s[1:]) for s in whole]
    assert got.count(decoder.GARBAGE) == 1 and len(got) == len(good) + 1
    again = _read(last, parser)
    assert [(r.msg_id, r.system, r.component, r.bad) for r in again] == [(*sent[-1][1:], False)]
