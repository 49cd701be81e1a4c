"""When each UDP datagram arrived, as the kernel saw it (Linux ``SO_TIMESTAMPNS``).

A real-time loop that reads its socket at its own instants, instead of waking up for every
datagram, still knows when each datagram came: the kernel stamps it on receipt. Both ends of the
vehicle link use this: the controller to date its vehicle's samples, the vehicle to apply each
setpoint at the instant it arrived.

``Waiting(sock)`` says whether a datagram waits, so a loop that drains its socket stops on a
``poll(2)`` that returns nothing instead of on the ``BlockingIOError`` of a read that finds
nothing. Building that exception (its message from ``strerror``, decoded) is what such a read costs,
and in a loop just woken from sleep it cost about 65 us against 24 us for the poll, on every drain.

Stamps are on ``time.monotonic``'s clock (the kernel's are CLOCK_REALTIME; ``wall_to_monotonic_s``
converts). Where the option is missing (not Linux), ``enable`` says so and a caller falls back to
reading datagrams as they come.
"""

import select
import socket
import struct
import sys
import time
from typing import Any

SO_TIMESTAMPNS = 35  #: Linux's value (the ``socket`` module does not export it)
_TIMESPEC = struct.Struct("qq")
_ANCILLARY_BYTES = 64


def block_reads(sock: socket.socket, timeout_s: float) -> None:
    """Reads of ``sock`` wait up to ``timeout_s`` for a datagram (``SO_RCVTIMEO``; then
    ``BlockingIOError``); 0: they return at once again (non-blocking). A loop that waits for one
    datagram then waits in ``recvfrom``: one system call where ``select`` and a read take two."""
    if timeout_s <= 0:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVTIMEO, struct.pack("@ll", 0, 0))
        sock.setblocking(False)
        return
    sock.setblocking(True)
    timeval = struct.pack("@ll", int(timeout_s), round((timeout_s % 1.0) * 1e6))
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVTIMEO, timeval)


def enable(sock: socket.socket) -> bool:
    """Ask the kernel to stamp each datagram ``sock`` receives; ``False`` where it cannot."""
    if not sys.platform.startswith("linux") or sock.type != socket.SOCK_DGRAM:
        return False
    try:
        sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
    except OSError:
        return False
    return True


def wall_to_monotonic_s() -> float:
    """Add to a CLOCK_REALTIME instant to get the ``time.monotonic`` instant (read it once per
    batch of datagrams: the two clocks drift apart only slowly)."""
    return time.monotonic() - time.time()


class Waiting:
    """``Waiting(sock)()``: whether a datagram (or an error, which the next read raises) waits."""

    def __init__(self, sock: socket.socket):
        self._fd = sock.fileno()
        self._poll = select.poll() if hasattr(select, "poll") else None
        if self._poll is not None:
            self._poll.register(self._fd, select.POLLIN)

    def __call__(self) -> bool:
        if self._poll is None:
            return bool(select.select([self._fd], [], [], 0)[0])
        return bool(self._poll.poll(0))


def recv(sock: socket.socket, wall_to_mono_s: float, bufsize: int = 65535) -> tuple[bytes, Any, float]:
    """One datagram, its sender and its arrival [s; ``time.monotonic``]. Raises what ``recvmsg``
    raises (``BlockingIOError`` when nothing waits on a non-blocking socket). A datagram without a
    stamp is dated now."""
    data, ancillary, _flags, addr = sock.recvmsg(bufsize, _ANCILLARY_BYTES)
    for level, kind, raw in ancillary:
        if level == socket.SOL_SOCKET and kind == SO_TIMESTAMPNS and len(raw) >= _TIMESPEC.size:
            sec, nsec = _TIMESPEC.unpack_from(raw)
            return data, addr, sec + nsec * 1e-9 + wall_to_mono_s
    return data, addr, time.monotonic()
