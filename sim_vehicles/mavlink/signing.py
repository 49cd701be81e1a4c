"""MAVLink 2 message signing on a UDP link, as a wrapper of the datagrams a link sends and receives.

The MAVLink 2 signing scheme (mavlink.io, "Message signing"): a signed frame sets incompat flag
0x01 and ends with 13 bytes, ``link_id``, a 48-bit timestamp (10 us units since 2015-01-01 UTC)
and the first 6 bytes of SHA-256(secret key + the frame up to and including the link id and
timestamp). The key is 32 bytes; ``key_from_passphrase`` gives the one MAVProxy's ``signing
setup`` and QGroundControl derive from a passphrase (its SHA-256).

- ``Signer.seal(frames)``: plain MAVLink 2 frames (one, or a telemetry pass of several), each
  signed (flag set, CRC updated, signature appended). Timestamps follow the wall clock and never
  repeat.
- ``Verifier.open(datagram)``: the datagram's frames, checked and unsigned (flag cleared, CRC
  updated): plain MAVLink 2 bytes for the parsers that follow (``tick_frames``, ``frames``,
  pymavlink). ``None`` if any frame is not signed (``unsigned``, MAVLink 1 included), is signed wrongly
  or not a frame (``bad``), or repeats or goes back in time (``replayed``: each stream, a
  ``(system, component, link id)``, must move its timestamp forward; a new stream may start at most
  a minute behind this side's clock).

Signing wraps a link whole: the wrappers around it (a fault plan, a ground-station port) see
signed bytes on the wire, and the code within sees plain frames, so the per-tick fast paths are
unchanged. Signatures are checked before timestamps, so a forged frame cannot move a stream's
clock. Little-endian hosts, as the rest of ``sim_vehicles``.

A datagram is sealed or opened in one compiled call (``seal_into``, ``open_into``, with
``sha256``'s kernel): in Python, each frame cost a SHA-256 call and a dozen byte operations, 2-3
times the hash itself right after a process woke (the lockstep paper run was 17 % slower signed).
"""

import hashlib
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from fastcrc import crc16

from sim_vehicles.common.jit import kernel
from sim_vehicles.mavlink.frames import MAGIC_V2
from sim_vehicles.mavlink.sha256 import sha256_into

SIGNED = 0x01  #: incompat flag of a signed frame
MAGIC_V1 = 0xFE
SIGNATURE_LEN = 13
_HEADER_LEN = 10
_EPOCH_2015_UNIX_S = 1420070400
NEW_STREAM_SLACK = 60 * 100_000  #: a new stream may start this far behind our clock [10 us]
KEY_LEN = 32
_MAX_DATAGRAM = 65536  #: the most a UDP datagram holds [bytes]


class SigningKeyError(ValueError):
    """A signing key file cannot be used; the message is one line."""


def _key_array(key: bytes) -> np.ndarray:
    if len(key) != KEY_LEN:
        raise SigningKeyError(f"a MAVLink 2 signing key is {KEY_LEN} bytes, not {len(key)}")
    return np.frombuffer(key, np.uint8)


def key_from_passphrase(passphrase: str) -> bytes:
    """The 32-byte key MAVProxy (``signing setup``) and QGroundControl derive from a passphrase."""
    return hashlib.sha256(passphrase.encode()).digest()


def read_key(path: str | Path) -> bytes:
    """The key of a passphrase file (its first line, surrounding whitespace removed)."""
    try:
        text = Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as e:
        raise SigningKeyError(f"{path}: cannot read the signing passphrase ({e})") from None
    lines = text.strip().splitlines()
    if not lines or not lines[0].strip():
        raise SigningKeyError(f"{path}: the signing passphrase file is empty")
    return key_from_passphrase(lines[0].strip())


def now_stamp() -> int:
    """The signing timestamp of this instant [10 us since 2015-01-01 UTC]."""
    return int((time.time() - _EPOCH_2015_UNIX_S) * 100_000)


def _flag_deltas() -> np.ndarray:
    """What setting the signed flag does to a frame's CRC, by payload length. MAVLink's X.25 CRC
    (no final XOR) is linear: CRC(A ^ D) = CRC(A) ^ CRC_0(D), where CRC_0 starts from 0. The
    flag is bit 0 of the CRC's second byte (the frame's third) and the CRC extra follows the
    body, so signing or unsigning a frame XORs its CRC with the CRC_0 of that one bit: no CRC
    is computed per frame (and no message's CRC extra is needed)."""
    out = []
    for plen in range(256):
        d = bytearray(_HEADER_LEN - 1 + plen + 1)  # body (length byte on) and the CRC extra's slot
        d[1] = SIGNED
        out.append(crc16.mcrf4xx(bytes(d), 0))
    return np.array(out, dtype=np.int64)


_FLAG_DELTA = _flag_deltas()
OK, UNSIGNED, BAD = 0, 1, 2  #: what ``open_into`` found


@kernel
def _flip_flag(buf, at, body_end):
    """Toggle the signed flag of the frame at ``buf[at]`` (its CRC at ``body_end``), CRC kept right."""
    buf[at + 2] ^= SIGNED
    crc = (np.int64(buf[body_end]) | (np.int64(buf[body_end + 1]) << 8)) ^ _FLAG_DELTA[buf[at + 1]]
    buf[body_end] = crc & 0xFF
    buf[body_end + 1] = crc >> 8


@kernel
def seal_into(data, key, link_id, stamp, out):
    """Sign each frame of ``data`` (plain MAVLink 2 frames, one after another) into ``out``: flag
    set, CRC updated, link id, timestamps ``stamp``, ``stamp + 1``, ... and the signature
    appended. Returns ``(length, frames)``; ``(0, 0)`` if ``data`` is not made of whole plain
    MAVLink 2 frames (then nothing of it is signed)."""
    n = len(data)
    at, o, frames = 0, 0, 0
    digest = np.empty(32, np.uint8)
    while at < n:
        if n - at < _HEADER_LEN + 2 or data[at] != MAGIC_V2 or data[at + 2] & SIGNED:
            return 0, 0
        end = at + _HEADER_LEN + int(data[at + 1]) + 2  # (an int: uint8 arithmetic wraps without numba)
        if end > n or o + end - at + SIGNATURE_LEN > len(out):
            return 0, 0
        start = o
        for i in range(at, end):
            out[o] = data[i]
            o += 1
        _flip_flag(out, start, o - 2)
        out[o] = link_id
        t = stamp + frames
        for j in range(6):
            out[o + 1 + j] = (t >> (8 * j)) & 0xFF
        o += 7
        sha256_into(key, KEY_LEN, out[start:o], o - start, digest)
        for j in range(6):
            out[o + j] = digest[j]
        o += 6
        at = end
        frames += 1
    return o, frames


@kernel
def open_into(data, key, out, streams):
    """Check and unsign each frame of ``data`` into ``out``; ``streams[j]`` gets frame j's
    ``(system, component, link id, timestamp)``. Returns ``(OK | UNSIGNED | BAD, length, frames,
    one)``: ``one`` when every frame is of one stream with its timestamps rising (the replay check
    then needs the first and the last only). A datagram with no frame is ``BAD``."""
    n = len(data)
    at, o, frames = 0, 0, 0
    one = True
    digest = np.empty(32, np.uint8)
    while at < n:
        if data[at] == MAGIC_V1:  # MAVLink 1 cannot be signed
            return UNSIGNED, 0, frames, one
        if n - at < _HEADER_LEN + 2 or data[at] != MAGIC_V2:
            return BAD, 0, frames, one
        end = at + _HEADER_LEN + int(data[at + 1]) + 2  # (an int: uint8 arithmetic wraps without numba)
        if not data[at + 2] & SIGNED:
            return UNSIGNED, 0, frames, one
        signed_end = end + SIGNATURE_LEN
        if signed_end > n or frames >= len(streams):
            return BAD, 0, frames, one
        sha256_into(key, KEY_LEN, data[at : signed_end - 6], signed_end - 6 - at, digest)
        for j in range(6):
            if digest[j] != data[signed_end - 6 + j]:
                return BAD, 0, frames, one
        t = np.int64(0)
        for j in range(6):
            t |= np.int64(data[end + 1 + j]) << (8 * j)
        streams[frames, 0] = data[at + 5]
        streams[frames, 1] = data[at + 6]
        streams[frames, 2] = data[end]
        streams[frames, 3] = t
        if frames > 0:
            p = frames - 1
            same = (
                streams[p, 0] == data[at + 5] and streams[p, 1] == data[at + 6] and streams[p, 2] == data[end]
            )
            one = one and same and t > streams[p, 3]
        start = o
        for i in range(at, end):  # the CRC is not checked: the signature covers it
            out[o] = data[i]
            o += 1
        _flip_flag(out, start, o - 2)
        frames += 1
        at = signed_end
    if frames == 0:
        return BAD, 0, 0, one
    return OK, o, frames, one


class Signer:
    """Signs the frames of one sender, on link ``link_id``."""

    def __init__(self, key: bytes, link_id: int = 0):
        self.link_id = link_id
        self._stamp = 0
        self._key = _key_array(key)
        self._out = np.empty(_MAX_DATAGRAM + 256 * SIGNATURE_LEN, np.uint8)

    def seal(self, frames: bytes) -> bytes:
        """``frames`` (one plain MAVLink 2 frame, or several one after another) signed, each with
        its own timestamp; anything else is returned as it is. Timestamps follow the wall clock
        and never repeat."""
        if len(frames) > _MAX_DATAGRAM:
            return frames
        stamp = max(self._stamp + 1, now_stamp())
        n, count = seal_into(frames, self._key, self.link_id, stamp, self._out)
        if not count:
            return frames
        self._stamp = stamp + count - 1
        return self._out[:n].tobytes()


def _moves_forward(stamp: int, last: int | None) -> bool:
    """MAVLink 2's replay rule: a frame's timestamp must pass its stream's last one; a stream not
    seen yet may start at most ``NEW_STREAM_SLACK`` behind our clock."""
    return stamp > (now_stamp() - NEW_STREAM_SLACK if last is None else last)


@dataclass
class Verifier:
    """Checks the signed frames a receiver gets (``open``), counting what it refuses."""

    key: bytes
    unsigned: int = 0  #: frames without a signature
    bad: int = 0  #: wrong signature, or not a frame
    replayed: int = 0  #: a timestamp that does not move its stream forward
    _streams: dict[tuple[int, int, int], int] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self._key = _key_array(self.key)
        self._out = np.empty(_MAX_DATAGRAM, np.uint8)
        self._frames = np.empty((_MAX_DATAGRAM // (_HEADER_LEN + 2 + SIGNATURE_LEN) + 1, 4), np.int64)

    def open(self, datagram: bytes) -> bytes | None:
        """The datagram's frames unsigned, or ``None`` (counted) if any of them is refused."""
        if len(datagram) > _MAX_DATAGRAM:
            self.bad += 1
            return None
        status, n, count, one = open_into(datagram, self._key, self._out, self._frames)
        if status != OK:
            if status == UNSIGNED:
                self.unsigned += 1
            else:
                self.bad += 1
            return None
        if one:  # one stream, rising: its first and last frames say as much as all of them
            system, component, link, first = self._frames[0].tolist()
            stream = (system, component, link)
            if not _moves_forward(first, self._streams.get(stream)):
                self.replayed += 1
                return None
            self._streams[stream] = first if count == 1 else int(self._frames[count - 1, 3])
        elif not self._rising(self._frames[:count].tolist()):
            self.replayed += 1
            return None
        return self._out[:n].tobytes()

    def unseal(self, datagram: bytes) -> tuple[bytes | None, bool]:
        """``open``, and whether a refusal was of a bad datagram (a wrong signature, not frames)
        rather than an unsigned or replayed one: what a receiver counts apart."""
        bad = self.bad
        return self.open(datagram), self.bad > bad

    def _rising(self, frames: list[list[int]]) -> bool:
        """Whether each frame's timestamp moves its stream forward (the table updated if so)."""
        seen: dict[tuple[int, int, int], int] = {}
        for sysid, compid, link, stamp in frames:
            stream = (sysid, compid, link)
            if not _moves_forward(stamp, seen.get(stream, self._streams.get(stream))):
                return False
            seen[stream] = stamp
        self._streams.update(seen)
        return True


def warm_up() -> None:
    """Seal and open one frame: the kernels load now (a fork server's children inherit them),
    not at a link's first datagram."""
    key = bytes(KEY_LEN)
    frame = bytes([MAGIC_V2, 0, 0, 0, 0, 1, 1, 0, 0, 0, 0, 0])  # HEARTBEAT's id, no payload
    Verifier(key).open(Signer(key).seal(frame))
