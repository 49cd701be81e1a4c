"""The datagrams between a controller and its vehicle: the transport layer of ``VehicleLink``.

A pymavlink connection of any connection string (``udpout:``, serial, TCP), as component
MAV_COMP_ID_ONBOARD_COMPUTER of the vehicle's own system. Around the bytes, in this order:

- MAVLink 2 signing (``sim_vehicles.mavlink.signing``): what is sent is signed, what is received
  is checked and unsigned (a refused datagram is counted: ``rx_bad`` a wrong signature,
  ``rx_refused`` an unsigned or replayed one);
- a fault plan (``faults.mavlink.MavlinkFaults``), wrapping the signed datagrams each way: what it
  holds comes out when due, what it loses never comes.

On a plain UDP client link (``udpout:``, Linux) each datagram carries the kernel's receive stamp,
so a real-time loop need not wake up for each datagram to know when it came (``stamps_arrivals``);
on any other link a datagram is dated when it is read.
"""

import math
import os
import time
from collections.abc import Callable, Iterator
from typing import Any

os.environ.setdefault("MAVLINK20", "1")  # before pymavlink picks its wire protocol

from pymavlink import mavutil

from sim_vehicles.mavlink.px4_profile import COMPANION
from sim_vehicles.mavlink.signing import Signer, Verifier
from sim_vehicles.runtime import udp_arrival


class LinkError(RuntimeError):
    """The vehicle cannot be reached or did not answer as an autopilot should; one line."""


class _Sealing:
    """Where pymavlink writes a link's messages: signed, then onto the connection."""

    def __init__(self, conn: Any, signer: Signer):
        self.conn = conn
        self.signer = signer

    def write(self, buf: bytes) -> None:
        self.conn.write(self.signer.seal(bytes(buf)))


class Transport:
    """Vehicle ``system_id``'s link at ``url``. ``stamp_arrivals``: ask the kernel for arrival
    stamps where it can (a real-time loop needs them; a lockstep one does not, and reads its
    datagrams more cheaply without). ``faults``: a fault plan on this link. ``signing_key``:
    MAVLink 2 signing, between the link and its fault plan."""

    def __init__(
        self,
        url: str,
        system_id: int,
        stamp_arrivals: bool = True,
        faults: Any = None,
        signing_key: bytes | None = None,
    ):
        # pymavlink picks the wire protocol of a connection from the environment when it opens it:
        # a process whose environment was replaced after this module was imported (a fork
        # server's child) would otherwise speak MAVLink 1, which cannot be signed
        os.environ.setdefault("MAVLINK20", "1")
        try:
            self.conn: Any = mavutil.mavlink_connection(
                url, source_system=system_id, source_component=COMPANION, dialect="common"
            )
        except Exception as e:  # pymavlink raises many kinds for a bad connection string
            raise LinkError(f"cannot open MAVLink connection {url!r}: {e}") from None
        self.conn.mav.robust_parsing = True  # garbage becomes BAD_DATA, counted, not an exception
        self.faults = faults
        self.rx_bad = 0  #: datagrams with a wrong signature
        self.rx_refused = 0  #: unsigned or replayed datagrams on a signed link
        self._queued: list[tuple[bytes, float]] = []  #: datagrams a fault held, now due
        self.signer = Signer(signing_key) if signing_key else None
        self._verifier = Verifier(signing_key) if signing_key else None
        if self.signer is not None:  # what pymavlink sends for us is signed on its way out
            self.conn.mav.file = _Sealing(self.conn, self.signer)
        #: ``udpout:``: the socket's ``sendto`` and the resolved address, once pymavlink has them
        self._sendto: tuple[Callable[[bytes, Any], int], Any] | None = None
        self.stamps_arrivals = stamp_arrivals and self._enable_timestamps()
        # whole frames per read: UDP only (a serial or TCP read can end inside a frame, and
        # pymavlink's parser keeps the rest for the next read)
        self.whole_datagrams = isinstance(self.conn, mavutil.mavudp)
        #: UDP: whether a datagram waits, asked without a read that raises when none does
        self._waiting = udp_arrival.Waiting(self.conn.port) if self.whole_datagrams else None

    def _enable_timestamps(self) -> bool:
        c = self.conn
        if not isinstance(c, mavutil.mavudp) or c.udp_server or c.broadcast:
            return False
        return udp_arrival.enable(c.port)

    def fileno(self) -> int:
        return int(self.conn.fd)

    def block_reads(self, timeout_s: float) -> None:
        """UDP: a read told its socket is readable (``datagrams(readable=True)``) waits in
        ``recvfrom`` up to ``timeout_s`` for a datagram (``SO_RCVTIMEO``): one system call where a
        ``select`` and a read take two. Other reads still ask first whether a datagram waits."""
        if self.whole_datagrams:
            udp_arrival.block_reads(self.conn.port, timeout_s)

    def close(self) -> None:
        self.conn.close()

    # -- receive ---------------------------------------------------------------------------------
    def datagrams(self, readable: bool = False) -> Iterator[tuple[bytes, float]]:
        """Every datagram waiting, plain (checked and unsigned on a signed link), as the fault
        plan lets it through, with its arrival [s; ``time.monotonic``]. ``readable``: a
        ``select`` on ``fileno()`` has just said one waits (the first read needs no check)."""
        wall_to_mono = udp_arrival.wall_to_monotonic_s() if self.stamps_arrivals else 0.0
        while True:
            try:
                data, arrival = self._recv(wall_to_mono, readable)
            except OSError:
                return
            readable = False
            if not data:
                return
            if self._verifier is not None:
                opened, bad = self._verifier.unseal(data)
                if opened is None:
                    if bad:
                        self.rx_bad += 1
                    else:
                        self.rx_refused += 1
                    continue
                data = opened
            yield data, arrival

    def _recv(self, wall_to_mono: float, readable: bool = False) -> tuple[bytes, float]:
        """One datagram (``b""`` if none) and its arrival time; ``readable``: one waits. Under a
        fault plan, what the plan lets through (``faults``)."""
        if self.faults is None:
            return self._recv_raw(wall_to_mono, readable)
        if not self._queued:
            self._queued = [(d, time.monotonic()) for d in self.faults.release(self.conn.write)]
        while not self._queued:
            data, arrival = self._recv_raw(wall_to_mono, readable)
            readable = False
            if not data:
                return data, arrival
            passed = self.faults.receive(data)
            if passed is not None:
                return passed, arrival
        return self._queued.pop(0)

    def _recv_raw(self, wall_to_mono: float, readable: bool = False) -> tuple[bytes, float]:
        if not readable and self._waiting is not None and not self._waiting():
            return b"", math.nan
        if not self.stamps_arrivals:
            return self.conn.recv(), time.monotonic()
        try:
            data, _addr, arrival = udp_arrival.recv(self.conn.port, wall_to_mono)
        except OSError:  # nothing waiting, or the vehicle's port is closed (ICMP unreachable)
            return b"", math.nan
        return data, arrival

    # -- send ------------------------------------------------------------------------------------
    def send(self, frame: bytes, time_boot_ms: int, clock_only: Callable[[int], None]) -> None:
        """Send one plain frame (a setpoint stamped ``time_boot_ms``): signed on a signed link,
        through the fault plan if there is one (``clock_only(ms)`` sends a lockstep clock-only
        setpoint in place of one it loses)."""
        if self.signer is not None:
            frame = self.signer.seal(frame)
        if self.faults is None:
            self._write(frame)
        else:
            self.faults.send(frame, time_boot_ms, self.conn.write, clock_only)

    def _write(self, frame: bytes) -> None:
        """``conn.write``; on a ``udpout:`` link whose address pymavlink has resolved, its socket's
        ``sendto`` straight away (what pymavlink's ``write`` ends in, without its per-call checks)."""
        to = self._sendto
        if to is None:
            c = self.conn
            c.write(frame)
            if self.whole_datagrams and not c.udp_server and not c.broadcast and c.resolved_destination_addr:
                self._sendto = (c.port.sendto, c.destination_addr)
            return
        try:  # noqa: SIM105  (a try costs less than a suppress() object every tick)
            to[0](frame, to[1])
        except OSError:
            pass  # as pymavlink's write: a send that fails is lost
