"""MAVLink 2 message signing on a UDP link, as a wrapper of the datagrams a link sends and receives.

The MAVLink 2 signing scheme (mavlink.io, "Message signing"): a signed frame sets incompat flag
0x01 and ends with 13 bytes, ``link_id``, a 48-bit timestamp (10 us units since 2015-01-01 UTC)
and the first 6 bytes of SHA-256(secret key + the frame up to and including the link id and
timestamp). The key is 32 bytes; ``key_from_passphrase`` gives the one MAVProxy's ``signing
setup`` and QGroundControl derive from a passphrase (its SHA-256).

- ``Signer.seal(frame)``: a plain MAVLink 2 frame, signed (flag set, CRC updated, signature
  appended). Its timestamps follow the wall clock and never repeat.
- ``Verifier.open(datagram)``: the datagram's frames, checked and unsigned (flag cleared, CRC
  updated): plain MAVLink 2 bytes for the parsers that follow (``tick_frames``, ``mavlink_frames``,
  pymavlink). ``None`` if any frame is not signed (``unsigned``, MAVLink 1 included), is signed wrongly
  or not a frame (``bad``), or repeats or goes back in time (``replayed``: each stream, a
  ``(system, component, link id)``, must move its timestamp forward; a new stream may start at most
  a minute behind this side's clock).

Signing wraps a link whole: the wrappers around it (a fault plan, a ground-station port) see
signed bytes on the wire, and the code within sees plain frames, so the per-tick fast paths are
unchanged. Signatures are checked before timestamps, so a forged frame cannot move a stream's
clock. Little-endian hosts, as the rest of ``sim_vehicles``.
"""

import hashlib
import time
from dataclasses import dataclass, field
from pathlib import Path

from fastcrc import crc16

from sim_vehicles.mavlink_frames import MAGIC_V2

SIGNED = 0x01  #: incompat flag of a signed frame
MAGIC_V1 = 0xFE
SIGNATURE_LEN = 13
_HEADER_LEN = 10
_EPOCH_2015_UNIX_S = 1420070400
NEW_STREAM_SLACK = 60 * 100_000  #: a new stream may start this far behind our clock [10 us]


class SigningKeyError(ValueError):
    """A signing key file cannot be used; the message is one line."""


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


def _flag_deltas() -> list[int]:
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
    return out


_FLAG_DELTA = _flag_deltas()


def _flip_flag(frame: bytearray, body_end: int) -> None:
    """Toggle the signed flag of the frame in ``frame`` (its CRC at ``body_end``), CRC kept right."""
    frame[2] ^= SIGNED
    crc = (frame[body_end] | frame[body_end + 1] << 8) ^ _FLAG_DELTA[frame[1]]
    frame[body_end] = crc & 0xFF
    frame[body_end + 1] = crc >> 8


class Signer:
    """Signs the frames of one sender, on link ``link_id``."""

    def __init__(self, key: bytes, link_id: int = 0):
        self.key = key
        self.link_id = link_id
        self._stamp = 0
        self._link = bytes([link_id])

    def seal(self, frame: bytes) -> bytes:
        """``frame`` (one plain MAVLink 2 frame) signed; anything else is returned as it is."""
        n = len(frame)
        if n < _HEADER_LEN + 2 or frame[0] != MAGIC_V2 or frame[2] & SIGNED:
            return frame
        self._stamp = stamp = max(self._stamp + 1, now_stamp())
        head = bytearray(frame)
        _flip_flag(head, n - 2)
        head += self._link
        head += stamp.to_bytes(6, "little")
        return bytes(head) + hashlib.sha256(self.key + head).digest()[:6]


@dataclass
class Verifier:
    """Checks the signed frames a receiver gets (``open``), counting what it refuses."""

    key: bytes
    unsigned: int = 0  #: frames without a signature
    bad: int = 0  #: wrong signature, or not a frame
    replayed: int = 0  #: a timestamp that does not move its stream forward
    _streams: dict[tuple[int, int, int], int] = field(default_factory=dict)

    def open(self, datagram: bytes) -> bytes | None:
        """The datagram's frames unsigned, or ``None`` (counted) if any of them is refused."""
        out = []
        at, n = 0, len(datagram)
        seen: dict[tuple[int, int, int], int] = {}
        while at < n:
            if datagram[at] == MAGIC_V1:  # MAVLink 1 cannot be signed
                self.unsigned += 1
                return None
            if n - at < _HEADER_LEN + 2 or datagram[at] != MAGIC_V2:
                self.bad += 1
                return None
            flags = datagram[at + 2]
            end = at + _HEADER_LEN + datagram[at + 1] + 2
            if not flags & SIGNED:
                self.unsigned += 1
                return None
            signed_end = end + SIGNATURE_LEN
            if signed_end > n:
                self.bad += 1
                return None
            frame = datagram[at:signed_end]
            if hashlib.sha256(self.key + frame[:-6]).digest()[:6] != frame[-6:]:
                self.bad += 1
                return None
            body_end = end - at - 2  # the CRC is not checked: the signature covers it
            stream = (frame[5], frame[6], frame[end - at])
            stamp = int.from_bytes(frame[end - at + 1 : end - at + 7], "little")
            last = seen.get(stream, self._streams.get(stream))
            if stamp <= (now_stamp() - NEW_STREAM_SLACK if last is None else last):
                self.replayed += 1
                return None
            seen[stream] = stamp
            head = bytearray(frame[: body_end + 2])
            _flip_flag(head, body_end)
            out.append(bytes(head))
            at = signed_end
        if not out:
            self.bad += 1
            return None
        self._streams.update(seen)
        return b"".join(out)
