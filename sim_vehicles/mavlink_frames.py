"""MAVLink 2 frames of the few messages crossing a link every tick, without a message object.

pymavlink parses byte by byte into a message object per frame and builds an object to pack one;
on the per-tick path (a telemetry sample one way, a setpoint the other) that is most of what a tick
costs in Python. ``Layout`` packs and reads the payload of one message with one precompiled
``struct`` taken from pymavlink's own definition (wire order, array lengths, CRC extra), so there is
no second copy of the message set:

- ``pack_frame(mav, layout, values)`` builds the frame pymavlink would build, byte for byte
  (MAVLink 2, trailing zeros of the payload dropped, X.25 CRC with the CRC extra), with the
  sequence number and ids of ``mav`` (a ``pymavlink`` ``MAVLink`` object, whose sequence it
  advances). ``values`` are the fields in the order the message declares them (arrays flattened;
  extension fields left out are zero), as pymavlink's ``*_encode`` takes them.
- ``read_datagram(data, layouts)`` splits a UDP datagram into frames and returns, for each,
  ``(msg_id, system_id, component_id, values, frame)``: ``values`` in declared order for a message
  in ``layouts`` (CRC checked), ``None`` for any other message (the caller hands ``frame`` to
  pymavlink's ``decode``). It returns ``None`` for the whole datagram if anything in it is not a
  plain MAVLink 2 frame (MAVLink 1, signed, truncated, garbage, a bad CRC): the caller then gives
  the datagram to pymavlink's parser, which drops and counts what is bad.

Signing: ``pack_frame`` refuses (``ValueError``) a ``mav`` that signs outgoing frames, and
callers must not use ``read_datagram`` on a link that checks signatures; both are pymavlink's job.
"""

import operator
import struct
from collections.abc import Sequence
from typing import Any

from fastcrc import crc16
from pymavlink.dialects.v20 import common as mav

MAGIC_V2 = 0xFD
_HEADER = struct.Struct("<BBBBBBBHB")
_HEADER_LEN = 10
_CRC = struct.Struct("<H")


class Layout:
    """One message's payload: pymavlink's ``struct`` in wire order and the permutation between
    wire order and declared order (arrays flattened)."""

    def __init__(self, cls: Any):
        self.msg_id: int = cls.id
        self.name: str = cls.msgname
        self.crc_extra = bytes([cls.crc_extra])
        self.struct: struct.Struct = cls.unpacker
        # flat slots of each field, declared order and wire order
        # (pymavlink lists array lengths in wire order)
        width = {n: max(1, a) for n, a in zip(cls.ordered_fieldnames, cls.array_lengths, strict=True)}
        arrays = {n for n, a in zip(cls.ordered_fieldnames, cls.array_lengths, strict=True) if a > 0}
        wire_start, at = {}, 0
        for n in cls.ordered_fieldnames:
            wire_start[n] = at
            at += width[n]
        self.names: tuple[str, ...] = tuple(
            n if width[n] == 1 and n not in arrays else f"{n}[{j}]"
            for n in cls.fieldnames
            for j in range(width[n])
        )
        #: declared slot d -> wire slot
        self.wire_of: tuple[int, ...] = tuple(
            wire_start[n] + j for n in cls.fieldnames for j in range(width[n])
        )
        #: wire slot w -> declared slot
        self.declared_of: tuple[int, ...] = tuple(
            sorted(range(len(self.wire_of)), key=lambda d: self.wire_of[d])
        )
        self._identity = self.wire_of == tuple(range(len(self.wire_of)))
        self._to_wire = operator.itemgetter(*self.declared_of)
        self._to_declared = operator.itemgetter(*self.wire_of)

    def pack_payload(self, values: Sequence[float]) -> bytes:
        v = tuple(values)
        if len(v) < len(self.names):
            v += (0,) * (len(self.names) - len(v))
        if not self._identity:
            v = self._to_wire(v)
        return self.struct.pack(*v)

    def unpack_payload(self, payload: bytes) -> tuple:
        size = self.struct.size
        if len(payload) < size:  # MAVLink 2 dropped its trailing zeros
            payload = payload + bytes(size - len(payload))
        w = self.struct.unpack_from(payload)
        if self._identity:
            return w
        return self._to_declared(w)


LOCAL_POSITION_NED = Layout(mav.MAVLink_local_position_ned_message)
ATTITUDE_QUATERNION = Layout(mav.MAVLink_attitude_quaternion_message)
ATTITUDE = Layout(mav.MAVLink_attitude_message)
ATTITUDE_TARGET = Layout(mav.MAVLink_attitude_target_message)
HIGHRES_IMU = Layout(mav.MAVLink_highres_imu_message)
SET_ATTITUDE_TARGET = Layout(mav.MAVLink_set_attitude_target_message)


def _crc(body: bytes, crc_extra: bytes) -> int:
    """MAVLink's X.25 CRC (CRC-16/MCRF4XX) of ``body`` and the message's CRC extra: the C routine
    pymavlink itself uses, called without its per-call wrapper object."""
    return int(crc16.mcrf4xx(crc_extra, crc16.mcrf4xx(body, 0xFFFF)))


def pack_frame(link: Any, layout: Layout, values: Sequence[float]) -> bytes:
    """The MAVLink 2 frame pymavlink's ``link.send`` would write for these field values."""
    if link.signing.sign_outgoing:
        raise ValueError("pack_frame does not sign: send signed frames through pymavlink")
    payload = layout.pack_payload(values)
    body = payload.rstrip(b"\0") or payload[:1]
    msg_id = layout.msg_id
    header = _HEADER.pack(
        MAGIC_V2, len(body), 0, 0, link.seq, link.srcSystem, link.srcComponent, msg_id & 0xFFFF, msg_id >> 16
    )
    frame = header + body
    frame += _CRC.pack(_crc(frame[1:], layout.crc_extra))
    link.seq = (link.seq + 1) % 256
    link.total_packets_sent += 1
    link.total_bytes_sent += len(frame)
    return frame


def _crc_matches(frame: bytes, crc_extra: bytes) -> bool:
    """Whether the CRC a whole frame ends with is the one its bytes and ``crc_extra`` give."""
    return bool(_CRC.unpack_from(frame, len(frame) - 2)[0] == _crc(frame[1:-2], crc_extra))


def crc_ok(frame: bytes) -> bool:
    """Whether a plain MAVLink 2 frame (as ``read_datagram`` returns it) of any message of the
    common set has a valid CRC: what a receiver that ignores the message still checks, to count it."""
    msg_id = frame[7] | (frame[8] << 8) | (frame[9] << 16)
    cls = mav.mavlink_map.get(msg_id)
    return cls is not None and _crc_matches(frame, bytes([cls.crc_extra]))


Frame = tuple[int, int, int, tuple | None, bytes]


def read_datagram(data: bytes, layouts: dict[int, Layout]) -> list[Frame] | None:
    """The frames of one datagram, or ``None`` if it is not made only of plain MAVLink 2 frames."""
    out: list[Frame] = []
    i, n = 0, len(data)
    while i < n:
        if n - i < _HEADER_LEN + 2:
            return None
        magic, plen, incompat, _compat, _seq, sysid, compid, id_low, id_high = _HEADER.unpack_from(data, i)
        if magic != MAGIC_V2 or incompat != 0:
            return None
        end = i + _HEADER_LEN + plen + 2
        if end > n:
            return None
        msg_id = id_low | (id_high << 16)
        frame = data[i:end]
        layout = layouts.get(msg_id)
        if layout is None:
            out.append((msg_id, sysid, compid, None, frame))
        else:
            if not _crc_matches(frame, layout.crc_extra):
                return None
            out.append((msg_id, sysid, compid, layout.unpack_payload(frame[_HEADER_LEN:-2]), frame))
        i = end
    return out
