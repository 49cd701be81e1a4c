"""MAVLink 2 frames of the few messages crossing a link every tick, without a message object.

pymavlink parses byte by byte into a message object per frame and builds an object to pack one;
on the per-tick path (a telemetry sample one way, a setpoint the other) that is most of what a tick
costs in Python. ``Layout`` describes one message from pymavlink's own definition (wire order,
array lengths, CRC extra; its precompiled ``struct`` reads a payload, ``spec`` drives the compiled
packer), so there is no second copy of the message set:

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

The compiled kernels (``pack_into``, ``frame_at``, ``read_into``, ``crc_x25``) do the same in
nopython code, for callers that convert and pack (or read and convert) a per-tick message in one
compiled call (``tick_frames``). They take a layout as ``Layout.spec``: one int64 array, row 0
``[msg_id, crc_extra, payload_size]``, then one row ``[kind, byte offset]`` per declared slot,
derived from pymavlink's definition like the rest. Values travel as float64: integers are exact
within +-2**53, which holds every integer field of the messages used (a uint64 ``time_usec`` would
take 285 years to leave it). Little-endian hosts only, as the wire is.
"""

import operator
import struct
import sys
from collections.abc import Sequence
from typing import Any

import numpy as np
from fastcrc import crc16
from pymavlink.dialects.v20 import common as mav

from sim_vehicles.common.jit import kernel

if sys.byteorder != "little":  # the kernels write native floats as wire bytes
    raise ImportError("sim_vehicles.mavlink.frames needs a little-endian host")

MAGIC_V2 = 0xFD
_HEADER = struct.Struct("<BBBBBBBHB")
_HEADER_LEN = 10
_CRC = struct.Struct("<H")

# field kinds of ``Layout.spec`` and their widths [bytes]
_KINDS = {"f": 0, "d": 1, "B": 2, "b": 3, "H": 4, "h": 5, "I": 6, "i": 7, "Q": 8, "q": 9}
_WIDTH = (4, 8, 1, 1, 2, 2, 4, 4, 8, 8)
_SIGNED = (False, False, False, True, False, True, False, True, False, True)


def _wire_kinds(fmt: str) -> list[str]:
    """One struct code per wire slot of a pymavlink ``unpacker`` format (``"<I4f"`` -> I f f f f)."""
    out, count = [], ""
    for ch in fmt.lstrip("<"):
        if ch.isdigit():
            count += ch
        else:
            out += [ch] * int(count or 1)
            count = ""
    return out


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
        self._identity = self.wire_of == tuple(range(len(self.wire_of)))
        self._to_declared = operator.itemgetter(*self.wire_of)
        #: the layout for the compiled kernels (module doc); ``None`` if a field is a char array
        self.spec: np.ndarray | None = None
        codes = _wire_kinds(self.struct.format)
        if all(c in _KINDS for c in codes):
            offsets = np.cumsum([0] + [_WIDTH[_KINDS[c]] for c in codes])
            spec = [[self.msg_id, cls.crc_extra, self.struct.size]]
            spec += [[_KINDS[codes[w]], int(offsets[w]), 0] for w in self.wire_of]
            self.spec = np.array(spec, dtype=np.int64)

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
    if layout.spec is None:
        raise ValueError(f"pack_frame cannot pack {layout.name}: it has a char field")
    out = np.empty(layout.struct.size + _HEADER_LEN + 2, np.uint8)
    n = pack_into(out, 0, link.seq, link.srcSystem, link.srcComponent, layout.spec, np.asarray(values, float))
    return take_frame(link, out, n)


def take_frame(link: Any, out: np.ndarray, n: int, start: int = 0) -> bytes:
    """The frame a kernel packed into ``out[start:n]`` with ``link``'s sequence number, as bytes;
    advances ``link``'s sequence number and counters past it, as pymavlink's send would."""
    frame = out[start:n].tobytes()
    link.seq = (link.seq + 1) % 256
    link.total_packets_sent += 1
    link.total_bytes_sent += n - start
    return frame


def _crc_matches(frame: bytes, crc_extra: bytes) -> bool:
    """Whether the CRC a whole frame ends with is the one its bytes and ``crc_extra`` give."""
    return bool(_CRC.unpack_from(frame, len(frame) - 2)[0] == _crc(frame[1:-2], crc_extra))


def known(msg_id: int) -> bool:
    """Whether the common set has message ``msg_id`` (and so its CRC extra: a frame of another
    dialect's message, such as ArduPilot's AHRS, cannot be checked by a receiver of this one)."""
    return msg_id in mav.mavlink_map


def crc_ok(frame: bytes) -> bool:
    """Whether a plain MAVLink 2 frame (as ``read_datagram`` returns it) of any message of the
    common set has a valid CRC: what a receiver that ignores the message still checks, to count it."""
    msg_id = frame[7] | (frame[8] << 8) | (frame[9] << 16)
    cls = mav.mavlink_map.get(msg_id)
    return cls is not None and _crc_matches(frame, bytes([cls.crc_extra]))


def reset_parser(parser: Any) -> None:
    """Forget the bytes pymavlink's stream parser keeps for the rest of a frame. On UDP a datagram
    ends every frame in it: bytes left over are a frame cut short (counted bad by the caller), and
    kept they would spoil the next datagram, or not, depending on what it is."""
    parser.buf = bytearray()
    parser.buf_index = 0
    parser.expected_length = mav.HEADER_LEN_V1 + 2
    parser.have_prefix_error = False


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


# -- compiled ------------------------------------------------------------------------------------


@kernel
def crc_x25(buf, start, end, crc_extra):
    """MAVLink's X.25 CRC of ``buf[start:end]`` followed by the byte ``crc_extra``."""
    crc = 0xFFFF
    for j in range(start, end + 1):
        b = int(buf[j]) if j < end else int(crc_extra)  # (ints: as Python, uint8 arithmetic overflows)
        tmp = (b ^ crc) & 0xFF
        tmp = (tmp ^ (tmp << 4)) & 0xFF
        crc = ((crc >> 8) ^ (tmp << 8) ^ (tmp << 3) ^ (tmp >> 4)) & 0xFFFF
    return crc


@kernel
def pack_into(out, at, seq, sysid, compid, spec, values):
    """Write at ``out[at:]`` the MAVLink 2 frame of ``values`` (declared order, float64; slots past
    ``len(values)`` are zero) for the layout ``spec``; returns the index after the frame. ``out``
    must have room for the whole frame (``payload_size + 12`` bytes)."""
    size = spec[0, 2]
    p0 = at + _HEADER_LEN
    out[p0 : p0 + size] = 0
    word = np.zeros(1, np.float64)
    raw = word.view(np.uint8)
    for d in range(values.shape[0]):
        kind = spec[d + 1, 0]
        if kind == 0:
            word.view(np.float32)[0] = values[d]
        elif kind == 1:
            word[0] = values[d]
        else:
            word.view(np.int64)[0] = np.int64(values[d])  # two's complement, low bytes first
        off = p0 + spec[d + 1, 1]
        out[off : off + _WIDTH[kind]] = raw[: _WIDTH[kind]]
    n = size
    while n > 1 and out[p0 + n - 1] == 0:  # MAVLink 2 drops the payload's trailing zeros
        n -= 1
    msg_id = spec[0, 0]
    out[at] = MAGIC_V2
    out[at + 1] = n
    out[at + 2] = 0
    out[at + 3] = 0
    out[at + 4] = seq & 0xFF
    out[at + 5] = sysid
    out[at + 6] = compid
    out[at + 7] = msg_id & 0xFF
    out[at + 8] = (msg_id >> 8) & 0xFF
    out[at + 9] = (msg_id >> 16) & 0xFF
    crc = crc_x25(out, at + 1, p0 + n, spec[0, 1])
    out[p0 + n] = crc & 0xFF
    out[p0 + n + 1] = crc >> 8
    return p0 + n + 2


@kernel
def frame_at(data, at):
    """The plain MAVLink 2 frame starting at ``data[at]``: ``(msg_id, sysid, compid, end)``, with
    ``end`` -1 if there is none (not a MAVLink 2 start, signed, or cut short). The CRC is not
    checked here (``crc_x25`` with the message's CRC extra over ``data[at + 1:end - 2]``)."""
    n = len(data)
    if n - at < _HEADER_LEN + 2 or data[at] != MAGIC_V2 or data[at + 2] != 0:
        return 0, 0, 0, -1
    end = at + _HEADER_LEN + data[at + 1] + 2
    if end > n:
        return 0, 0, 0, -1
    msg_id = data[at + 7] | (np.int64(data[at + 8]) << 8) | (np.int64(data[at + 9]) << 16)
    return msg_id, np.int64(data[at + 5]), np.int64(data[at + 6]), end


@kernel
def read_into(data, at, end, spec, values):
    """Read the frame ``data[at:end]`` of layout ``spec`` into ``values`` (declared order; as many
    slots as ``values`` holds); the payload is zero-extended as MAVLink 2 requires. Returns whether
    its CRC is good (``values`` is filled either way)."""
    p0 = at + _HEADER_LEN
    plen = end - 2 - p0
    word = np.zeros(1, np.float64)
    raw = word.view(np.uint8)
    for d in range(values.shape[0]):
        kind = spec[d + 1, 0]
        w = _WIDTH[kind]
        off = spec[d + 1, 1]
        raw[:] = 0
        for b in range(w):
            if off + b < plen:
                raw[b] = data[p0 + off + b]
        if kind == 0:
            values[d] = word.view(np.float32)[0]
        elif kind == 1:
            values[d] = word[0]
        elif _SIGNED[kind]:
            shift = 64 - 8 * w
            values[d] = (word.view(np.int64)[0] << shift) >> shift
        else:
            values[d] = word.view(np.int64)[0]
    crc = crc_x25(data, at + 1, end - 2, spec[0, 1])
    return (data[end - 2] | (np.int64(data[end - 1]) << 8)) == crc
