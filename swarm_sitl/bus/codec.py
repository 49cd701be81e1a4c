"""Byte layouts of what crosses the zenoh bus (little-endian, fixed layouts, versioned).

- message (the estimate a node sends each out-neighbour at each tick; the leader's is the
  reference): ``u8 version, u16 src, u32 step, f64 t_s, 3 x f64 p_W, u16 n, n x f64 values,
  u32 crc32``. ``p_W``: where the sender is (its vehicle as sampled; the leader: its reference), which
  a fault plan's range model reads, as a radio would measure distance. ``n``
  is what the sender's kind sends (``laws.contract``: 12 from the leader, the law's
  ``message_length`` from a follower); float64, so nothing is rounded and lockstep runs equal
  ``sim``; the CRC-32 of the bytes before it, so a corrupted message is dropped, not flown
- status: ``u8 version, u16 follower, u32 step, f64 t_s, f64 sample_t_s, 3 x f64 p_W``
- state (a run with ``ros2:`` on): ``u8 version, u16 follower, u32 step, f64 t_s, 3 x f64 p_W,
  3 x f64 v_W, 4 x f64 q_WB, 3 x f64 omega_B, u16 n, n x f64 values``: the vehicle as the
  controller sampled it at that tick, and the message it sent its out-neighbours then
- start: ``u8 version, f64 epoch_unix_s`` (real time: tick 0 happens at this instant)
- hold: ``u8 version, i64 tick`` (lockstep: a node that has finished a tick at or past it waits
  for a later one; ``HOLD_NONE``: no hold, -1: every node stops after the tick it is on)

``docs/bus.md`` has them byte by byte, with the keys. ``decode_*`` raise ``PayloadError`` (one
line) for anything else; receivers drop and count it.
"""

import functools
import math
import struct
import zlib
from collections.abc import Callable
from typing import Any, NamedTuple, TypeVar

import numpy as np

VERSION = 4
_HEAD = struct.Struct("<BHId3dH")  #: a message's version, src, step, t_s, p_W and value count
_CRC = 4
_STATUS = struct.Struct("<BHIdd3d")
_STATE = struct.Struct("<BHId3d3d4d3dH")  #: and then ``n`` float64
_START = struct.Struct("<Bd")
_HOLD = struct.Struct("<Bq")
HOLD_NONE = 2**62  #: the hold that holds nothing (every tick of any run is below it)


class PayloadError(ValueError):
    """A payload on the bus is malformed."""


T = TypeVar("T")


def decode_waiting(sub: Any, decode: Callable[[bytes], T]) -> tuple[list[T], int]:
    """What waits on a zenoh subscriber's channel (``try_recv``), decoded, and how many payloads
    were malformed (dropped; the caller counts them)."""
    out: list[T] = []
    bad = 0
    while (sample := sub.try_recv()) is not None:
        try:
            out.append(decode(sample.payload.to_bytes()))
        except PayloadError:
            bad += 1
    return out, bad


class Status(NamedTuple):
    follower: int
    step: int
    t_s: float  #: tick time [s]
    sample_t_s: float  #: time of the vehicle sample used [s]
    p_W: np.ndarray  #: vehicle position as sampled [m; ENU]


def _check(data: bytes, layout: struct.Struct, what: str, first_float: int, n_floats: int = 99) -> tuple:
    """The fields of ``data``; the ``n_floats`` fields from ``first_float`` on (default: all) are
    floats and must be finite."""
    if len(data) != layout.size:
        raise PayloadError(f"{what} payload has {len(data)} bytes, expected {layout.size}")
    fields = layout.unpack(data)
    if fields[0] != VERSION:
        raise PayloadError(f"{what} payload version {fields[0]}, expected {VERSION}")
    if not all(map(math.isfinite, fields[first_float : first_float + n_floats])):
        raise PayloadError(f"{what} payload has a non-finite value")
    return fields


class Message(NamedTuple):
    """What node ``src`` sends its out-neighbours at tick ``step`` (the leader: its reference)."""

    src: int
    step: int
    t_s: float  #: the instant its values hold at [s]
    values: np.ndarray  #: float64
    p_W: tuple[float, float, float] = (0.0, 0.0, 0.0)  #: where the sender is [m; ENU]


@functools.lru_cache(maxsize=16)  # a swarm uses two lengths; a forged one cannot grow it
def _message_layout(n: int) -> struct.Struct:
    return struct.Struct(f"<BHId3dH{n}d")


def message_size(n: int) -> int:
    """The bytes of a message of ``n`` values on the bus."""
    return _HEAD.size + 8 * n + _CRC


def encode_message(m: Message) -> bytes:
    values = m.values.tolist()  # one call per array instead of a numpy scalar per element
    n = len(values)
    body = _message_layout(n).pack(VERSION, m.src, m.step, m.t_s, *m.p_W, n, *values)
    return body + zlib.crc32(body).to_bytes(_CRC, "little")


def decode_message(data: bytes) -> Message:
    if len(data) < _HEAD.size + _CRC:
        raise PayloadError(f"message payload has {len(data)} bytes, fewer than a header")
    version, src, step, t_s, x, y, z, n = _HEAD.unpack_from(data)
    if version != VERSION:
        raise PayloadError(f"message payload version {version}, expected {VERSION}")
    size = _HEAD.size + 8 * n + _CRC
    if len(data) != size:
        raise PayloadError(f"message payload has {len(data)} bytes, its {n} values need {size}")
    if zlib.crc32(data[:-_CRC]) != int.from_bytes(data[-_CRC:], "little"):
        raise PayloadError("message payload fails its checksum")
    values = _message_layout(n).unpack_from(data)[8:]  # a tuple: checked faster than an array
    if not (math.isfinite(t_s + x + y + z) and all(map(math.isfinite, values))):
        raise PayloadError("message payload has a non-finite value")
    return Message(src, step, t_s, np.array(values), (x, y, z))


def encode_status(s: Status) -> bytes:
    p = np.asarray(s.p_W, dtype=float).tolist()
    return _STATUS.pack(VERSION, s.follower, s.step, s.t_s, s.sample_t_s, *p)


def decode_status(data: bytes) -> Status:
    f = _check(data, _STATUS, "status", 3)
    return Status(f[1], f[2], f[3], f[4], np.array(f[5:8]))


class State(NamedTuple):
    """Follower ``follower``'s vehicle as its controller sampled it at tick ``step``."""

    follower: int
    step: int
    t_s: float  #: the tick's time [s]
    p_W: np.ndarray  #: position [m; ENU]
    v_W: np.ndarray  #: velocity [m/s; ENU]
    q_WB: np.ndarray  #: attitude, body to world, [w, x, y, z]
    omega_B: np.ndarray  #: body rates [rad/s; FLU] (NaN: not reported yet)
    values: np.ndarray  #: the message it sent its out-neighbours at that tick (float64)


def encode_state(s: State) -> bytes:
    vectors = (np.asarray(v, dtype=float).tolist() for v in (s.p_W, s.v_W, s.q_WB, s.omega_B))
    values = np.asarray(s.values, dtype="<f8")
    head = _STATE.pack(VERSION, s.follower, s.step, s.t_s, *(x for v in vectors for x in v), len(values))
    return head + values.tobytes()


def decode_state(data: bytes) -> State:
    """``PayloadError`` for a payload that is not a state; its rates may be NaN (not yet known),
    everything else is finite."""
    n = int.from_bytes(data[_STATE.size - 2 : _STATE.size], "little") if len(data) >= _STATE.size else 0
    if len(data) != _STATE.size + 8 * n:
        raise PayloadError(f"state payload has {len(data)} bytes, expected {_STATE.size + 8 * n}")
    values = np.frombuffer(data, dtype="<f8", offset=_STATE.size).copy()
    if not np.all(np.isfinite(values)):
        raise PayloadError("state payload has a non-finite value")
    f = _check(data[: _STATE.size], _STATE, "state", 3, 11)
    return State(
        f[1], f[2], f[3], np.array(f[4:7]), np.array(f[7:10]), np.array(f[10:14]), np.array(f[14:17]), values
    )


def encode_start(epoch_unix_s: float) -> bytes:
    return _START.pack(VERSION, epoch_unix_s)


def decode_start(data: bytes) -> float:
    return float(_check(data, _START, "start", 1)[1])


def encode_hold(tick: int) -> bytes:
    return _HOLD.pack(VERSION, tick)


def decode_hold(data: bytes) -> int:
    tick = int(_check(data, _HOLD, "hold", 2)[1])
    if tick < -1:
        raise PayloadError(f"hold payload has tick {tick}, below -1")
    return tick
