"""The messages of one received datagram, for both ends of a vehicle link.

Each end first tries its own per-tick datagram in one compiled call (``tick_frames``: the vehicle
a setpoint, the controller a sample); everything else comes here. ``messages`` yields one
``Received`` per frame, lazily, so a receiver handles each message before the next is read (as it
would from a stream):

1. a datagram made only of plain MAVLink 2 frames is split without pymavlink
   (``frames.read_datagram``): a message of ``layouts`` comes with its field values (CRC
   checked) and no message object; one that ``wanted(msg_id)`` asks for is decoded by pymavlink
   (``bad`` if that fails); any other has its CRC checked only (``bad`` if it fails), for a
   receiver that counts what it does not read. A message the common set does not have (another
   dialect's, such as ArduPilot's AHRS or EKF_STATUS_REPORT) has no CRC extra to check it by:
   it is not ``bad``, as pymavlink's parser passes it on a stream (an unknown message);
2. anything else (MAVLink 1, garbage, a frame cut short, a bad CRC in one of ``layouts``' frames)
   goes to pymavlink's parser, which drops what is bad as ``BAD_DATA`` (``bad``). A datagram
   ends every frame in it (``whole``, UDP): bytes left over are a frame cut short, reported once
   as ``GARBAGE`` (as is a datagram the parser raises on) and forgotten, so they cannot spoil the
   next datagram. On a stream (serial, TCP; ``whole`` false) the parser keeps them for the next
   read and step 1 is skipped: a read may end inside a frame.

Signed datagrams are checked and unsigned before they come here (``signing``).
"""

from collections.abc import Callable, Iterator
from typing import Any, NamedTuple

from sim_vehicles.mavlink import frames


class Received(NamedTuple):
    """One frame of a datagram, as far as it was read."""

    frame: bytes  #: its bytes (what a ``.tlog`` records)
    msg_id: int
    system: int
    component: int
    values: tuple | None = None  #: its fields in declared order, for a message of ``layouts``
    message: Any = None  #: pymavlink's message object, for a message that was decoded
    bad: bool = False  #: dropped: a bad CRC, a message that does not decode, or ``BAD_DATA``


#: what ``messages`` yields once for a datagram with garbage in it or a frame cut short
GARBAGE = Received(b"", -1, 0, 0, bad=True)


def _everything(msg_id: int) -> bool:
    return True


def messages(
    data: bytes,
    parser: Any,
    layouts: dict[int, frames.Layout] | None = None,
    wanted: Callable[[int], bool] = _everything,
    whole: bool = True,
) -> Iterator[Received]:
    """The frames of ``data`` (module doc); ``parser`` is the receiver's pymavlink ``MAVLink``
    object (its state carries over between reads of a stream)."""
    split = frames.read_datagram(data, layouts or {}) if whole else None
    if split is not None:
        for msg_id, system, component, values, frame in split:
            if values is not None:
                yield Received(frame, msg_id, system, component, values)
            elif not wanted(msg_id):  # (another dialect's: not checkable, not bad, as pymavlink's parser)
                bad = frames.known(msg_id) and not frames.crc_ok(frame)
                yield Received(frame, msg_id, system, component, bad=bad)
            else:
                try:
                    m = parser.decode(bytearray(frame))
                except Exception:  # pymavlink's own errors and struct errors: dropped, counted
                    yield Received(frame, msg_id, system, component, bad=True)
                    continue
                yield Received(frame, msg_id, system, component, message=m)
        return
    try:
        msgs = parser.parse_buffer(data) or []
    except Exception:  # pymavlink raises its own and struct errors on garbage: dropped, counted
        msgs = None
    if msgs is None or (whole and parser.buf_len()):
        yield GARBAGE
        if whole:
            frames.reset_parser(parser)  # a datagram ends every frame in it: nothing carries over
        if msgs is None:
            return
    for m in msgs:
        bad = m.get_type() == "BAD_DATA"
        yield Received(
            m.get_msgbuf(), m.get_msgId(), m.get_srcSystem(), m.get_srcComponent(), message=m, bad=bad
        )
