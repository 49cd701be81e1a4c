"""Byte layouts of what crosses the zenoh bus (little-endian, fixed size, versioned).

- estimate: ``u8 version, u16 src, u32 step, f64 t_s, 12 x f64 p_hat v_hat a_hat a_hat_dot,
  u32 crc32`` (float64: nothing is rounded, so lockstep runs equal ``sim``; the CRC-32 of the
  bytes before it, so a corrupted estimate is dropped, not flown)
- status: ``u8 version, u16 follower, u32 step, f64 t_s, f64 sample_t_s, 3 x f64 p_W``
- start: ``u8 version, f64 epoch_unix_s`` (real time: tick 0 happens at this instant)

``decode_*`` raise ``PayloadError`` (one line) for anything else; receivers drop and count it.
"""

import math
import struct
import zlib
from collections.abc import Callable
from typing import Any, NamedTuple, TypeVar

import numpy as np

from swarm_sitl.laws.follower import EstimateMessage

VERSION = 2
_EST = struct.Struct("<BHId12dI")
_EST_BODY = _EST.size - 4
_STATUS = struct.Struct("<BHIdd3d")
_START = struct.Struct("<Bd")


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


def encode_estimate(m: EstimateMessage) -> bytes:
    # ``tolist``: one call per array instead of a numpy scalar per element
    values = (*m.p_hat.tolist(), *m.v_hat.tolist(), *m.a_hat.tolist(), *m.a_hat_dot.tolist())
    body = _EST.pack(VERSION, m.src, m.step, m.t_s, *values, 0)[:_EST_BODY]
    return body + zlib.crc32(body).to_bytes(4, "little")


def decode_estimate(data: bytes) -> EstimateMessage:
    f = _check(data, _EST, "estimate", 3, 13)
    if zlib.crc32(data[:_EST_BODY]) != f[-1]:
        raise PayloadError("estimate payload fails its checksum")
    v = np.array(f[4:16])
    return EstimateMessage(f[1], f[2], f[3], v[0:3], v[3:6], v[6:9], v[9:12])


def encode_status(s: Status) -> bytes:
    p = np.asarray(s.p_W, dtype=float).tolist()
    return _STATUS.pack(VERSION, s.follower, s.step, s.t_s, s.sample_t_s, *p)


def decode_status(data: bytes) -> Status:
    f = _check(data, _STATUS, "status", 3)
    return Status(f[1], f[2], f[3], f[4], np.array(f[5:8]))


def encode_start(epoch_unix_s: float) -> bytes:
    return _START.pack(VERSION, epoch_unix_s)


def decode_start(data: bytes) -> float:
    return float(_check(data, _START, "start", 1)[1])
