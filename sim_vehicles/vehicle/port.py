"""One UDP port of a vehicle and the link behind it: the transport layer of the endpoint.

A vehicle has a port for its controller and, optionally, one for a ground station. Each is its
own ``Port``: its socket, its packer (with its own sequence numbers), the frames it has queued,
its parser, its peer, its signing, its stream schedule (``Streams``); what they share is
the vehicle's ``.tlog`` (``Tlog``) and counters (``EndpointStats``).

- Streams: each stream is sent on its own grid of multiples of its period in boot time, so
  streams of one rate (LOCAL_POSITION_NED and ATTITUDE_QUATERNION) always share their instants;
  MAV_CMD_SET_MESSAGE_INTERVAL changes a rate (-1 stops it, 0 restores the default).
- Sending: messages are queued (``send``, ``send_fields``, ``take``) and ``flush`` sends what is
  queued to the peer, packed into as few datagrams as fit (as PX4 does: a telemetry pass is one
  datagram, one wake-up of the receiver), signed on a signed link, and written to the ``.tlog``
  in one write with one stamp.
- Receiving: ``datagrams`` reads what waits on the socket, each with its arrival (the kernel's
  stamp where ``stamped``, ``udp_arrival``); ``admit`` applies the link's rule to one datagram
  (below) and returns its plain frames.
- One peer (hostile input): telemetry goes to the first address that sent a well-formed message
  addressed to the vehicle (its controller), and what any other address sends is refused and
  counted (``rx_refused``) until that peer has been silent for ``PEER_SILENT_S`` of wall time.
  Under MAVLink 2 signing only correctly signed datagrams are heard, from anyone holding the key;
  the link moves at once to one that speaks as the vehicle's companion computer (a restarted
  controller), and telemetry stays with the peer (``heard``).
"""

import math
import struct
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from socket import AF_INET, SOCK_DGRAM, socket
from typing import Any, BinaryIO

import numpy as np
from pymavlink.dialects.v20 import common as mav

from sim_vehicles.mavlink import frames
from sim_vehicles.mavlink.px4_profile import AUTOPILOT, COMPANION
from sim_vehicles.mavlink.signing import SIGNATURE_LEN, Signer, Verifier
from sim_vehicles.runtime import udp_arrival

#: the two messages of a lockstep sample, sent at every period
LPOS_ID, ATTQ_ID = mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED, mav.MAVLINK_MSG_ID_ATTITUDE_QUATERNION
MAX_DATAGRAM = 1200  #: bytes; below any loopback or Ethernet MTU
PEER_SILENT_S = 3.0  #: wall time a peer must be silent before another address may take the link [s]


@dataclass
class EndpointStats:
    """What the vehicle received and what it did with it, on all its ports."""

    rx_messages: int = 0
    rx_bad: int = 0  #: bytes that are not a MAVLink frame, or fail its CRC or signature
    rx_refused: int = 0  #: from an address that is not the peer, unsigned, or for another system
    rx_invalid: int = 0  #: well-formed, with values the vehicle refuses
    rx_unhandled: int = 0  #: messages the vehicle does not handle
    handler_errors: int = 0  #: a handler failed on an accepted message (a bug)
    last_handler_error: str = ""
    tx_messages: int = 0
    setpoints: int = 0
    lockstep_resends: int = 0  #: retransmitted setpoints answered with the current sample


def next_due(t_s: float, rate_hz: float) -> float:
    """When a stream of ``rate_hz`` sent at ``t_s`` is next due: the next multiple of its period
    in boot time, so streams of one rate share their instants."""
    return (math.floor(t_s * rate_hz + 1e-6) + 1) / rate_hz


class Streams:
    """One port's schedule: each stream's rate [Hz] and when it is next due [s; simulated time]."""

    def __init__(self, defaults: dict[int, float]):
        self.defaults = defaults  #: the rates a MAV_CMD_SET_MESSAGE_INTERVAL of 0 restores
        self.rate_hz = dict(defaults)
        #: simulated time each stream is next due (0: now; inf: off), in the order they are sent
        self.next_send = dict.fromkeys(defaults, 0.0)
        self.next_any_s = 0.0  #: simulated time of the next message due
        self.next_other_s = 0.0  #: ... of the next one but LOCAL_POSITION_NED and ATTITUDE_QUATERNION

    def due(self, t_s: float) -> Iterator[int]:
        """The streams due at ``t_s``, in order, each moved to its next instant (a stream of rate 0
        to never); exhaust it to keep the schedule right."""
        if t_s + 1e-9 < self.next_any_s:
            return
        next_send = self.next_send
        for msg_id, at in next_send.items():  # values replaced in place: no key is added
            if t_s + 1e-9 >= at:
                rate_hz = self.rate_hz[msg_id]
                if rate_hz <= 0:
                    next_send[msg_id] = math.inf
                    continue
                next_send[msg_id] = next_due(t_s, rate_hz)
                yield msg_id
        self.next_any_s = min(next_send.values())
        self.next_other_s = min(at for msg_id, at in next_send.items() if msg_id not in (LPOS_ID, ATTQ_ID))

    def set_interval(self, msg_id: int, interval_us: float) -> None:
        """MAV_CMD_SET_MESSAGE_INTERVAL: every ``interval_us`` (-1: off; 0: the default), from now."""
        self.rate_hz[msg_id] = (
            self.defaults[msg_id]
            if interval_us == 0
            else (0.0 if interval_us < 0 else 1e6 / max(interval_us, 1.0))
        )
        self.next_send[msg_id] = 0.0
        self.next_any_s = self.next_other_s = 0.0

    def sample_sent(self, t_s: float) -> None:
        """The sample (LOCAL_POSITION_NED and ATTITUDE_QUATERNION) was sent at ``t_s`` and nothing
        else was due (a lockstep tick in one call): what ``due`` would have done."""
        next_send = self.next_send
        for msg_id in (LPOS_ID, ATTQ_ID):
            next_send[msg_id] = next_due(t_s, self.rate_hz[msg_id])
        self.next_any_s = min(next_send[LPOS_ID], next_send[ATTQ_ID], self.next_other_s)


class Tlog:
    """Every message a vehicle sends and receives, as a ``.tlog``: 8-byte big-endian microseconds
    of the wall clock, then the frame (on a signed link the frame within its signature, readable
    without the key). ``path=None``: nowhere."""

    def __init__(self, path: str | Path | None):
        self._f: BinaryIO | None = open(path, "wb") if path else None  # noqa: SIM115  (closed by close())

    @staticmethod
    def _stamp() -> bytes:
        return struct.pack(">Q", int(time.time() * 1e6))

    def frame(self, frame: bytes) -> None:
        """One received frame, stamped now."""
        if self._f is not None:
            self._f.write(self._stamp() + frame)

    def frames(self, queued: list[bytes]) -> None:
        """A pass of frames sent together: one write, one stamp."""
        if self._f is not None:
            stamp = self._stamp()
            self._f.write(b"".join([stamp + frame for frame in queued]))

    def close(self) -> None:
        if self._f is not None:
            self._f.close()
            self._f = None


class _Sink:
    """File-like object pymavlink writes frames into; the port sends and logs them."""

    def __init__(self) -> None:
        self.frames: list[bytes] = []

    def write(self, data: bytes) -> None:
        self.frames.append(bytes(data))


class Port:
    """One UDP socket of vehicle ``system_id`` bound to ``bind``, with ``rates`` (``Streams``)
    and, until someone speaks to it, ``remote`` as its peer. ``stamped``: ask the kernel for
    arrival stamps (a real-time controller port)."""

    def __init__(
        self,
        bind: tuple[str, int],
        system_id: int,
        rates: dict[int, float],
        stats: EndpointStats,
        tlog: Tlog,
        remote: tuple[str, int] | None = None,
        signing_key: bytes | None = None,
        stamped: bool = False,
    ):
        self.system_id = system_id
        self.stats = stats
        self.tlog = tlog
        self.sock: Any = socket(AF_INET, SOCK_DGRAM)
        self.sock.bind(bind)
        self.sock.setblocking(False)
        self.address = self.sock.getsockname()
        #: datagrams carry the kernel's arrival stamp, so a loop may read them late
        self.stamped = stamped and udp_arrival.enable(self.sock)
        self.waiting = udp_arrival.Waiting(self.sock)
        self.sink = _Sink()
        self.mav = mav.MAVLink(self.sink, srcSystem=system_id, srcComponent=AUTOPILOT)
        self.parser = mav.MAVLink(None, srcSystem=255, srcComponent=0)
        self.parser.robust_parsing = True
        self.peer: tuple[str, int] | None = remote
        self.peer_heard_wall = -math.inf  #: when the peer last sent [s; time.monotonic]
        self.accepted = 0  #: well-formed messages it knows, addressed to it, from anyone heard
        self.accepted_from = (0, 0)  #: (system, component) of the last of them
        self.signer = Signer(signing_key) if signing_key else None
        self.verifier = Verifier(signing_key) if signing_key else None
        self.streams = Streams(rates)

    # -- send ------------------------------------------------------------------------------------
    def send(self, msg: Any) -> None:
        """Queue one message; ``flush`` sends what is queued."""
        self.mav.send(msg)

    def send_fields(self, layout: frames.Layout, values: tuple[float, ...] | list[float]) -> None:
        """Queue one telemetry message from its field values (``frames.pack_frame``: the same bytes
        as ``send``, without building a message object)."""
        self.sink.frames.append(frames.pack_frame(self.mav, layout, values))

    def stream(self, t_s: float, senders: dict[int, Callable[["Port", int], None]]) -> None:
        """Queue the streams due at ``t_s`` (``Streams``), each by its sender in ``senders``."""
        for msg_id in self.streams.due(t_s):
            senders[msg_id](self, round(t_s * 1000))

    def take(self, out: np.ndarray, end: int, start: int = 0) -> None:
        """Queue the frame a kernel packed into ``out[start:end]`` with this port's sequence number."""
        self.sink.frames.append(frames.take_frame(self.mav, out, end, start))

    def flush(self) -> None:
        """Send the queued frames to the peer, packed into as few datagrams as fit, and write them
        to the ``.tlog`` (peer or not)."""
        queued = self.sink.frames
        if not queued:
            return
        self.tlog.frames(queued)
        if self.peer is not None:
            self.stats.tx_messages += len(queued)
            joined = b"".join(queued)
            signatures = SIGNATURE_LEN * len(queued) if self.signer is not None else 0
            if len(joined) + signatures <= MAX_DATAGRAM:  # the usual pass: signed in one call
                self.sock.sendto(self._sealed(joined), self.peer)
            else:
                packet = b""
                for frame in map(self._sealed, queued):
                    if len(packet) + len(frame) > MAX_DATAGRAM:
                        self.sock.sendto(packet, self.peer)
                        packet = b""
                    packet += frame
                self.sock.sendto(packet, self.peer)
        queued.clear()

    def _sealed(self, data: bytes) -> bytes:
        """``data`` (frames) signed on a signed link (``signing``), else as it is."""
        return data if self.signer is None else self.signer.seal(data)

    # -- receive ---------------------------------------------------------------------------------
    def datagrams(self, at_arrival: bool, readable: bool = False) -> Iterator[tuple[bytes, Any, float]]:
        """Every datagram waiting: ``(data, sender, arrival [s; time.monotonic])``. ``at_arrival``:
        the caller needs the arrival (an unstamped one is dated when read; else 0).
        ``readable``: a ``select`` has just said so (the first read needs no check)."""
        wall_to_mono = udp_arrival.wall_to_monotonic_s() if self.stamped else 0.0
        while readable or self.waiting():
            readable = False
            try:
                if self.stamped:
                    data, addr, arrival = udp_arrival.recv(self.sock, wall_to_mono, 4096)
                else:
                    data, addr = self.sock.recvfrom(4096)
                    arrival = time.monotonic() if at_arrival else 0.0  # unstamped: read now
            except OSError:  # an ICMP error, or nothing after all
                return
            yield data, addr, arrival

    def admit(self, data: bytes, addr: Any) -> bytes | None:
        """The plain frames of a datagram from ``addr`` that the link hears (signed: checked and
        unsigned; unsigned: from the peer, or anyone while it is silent); None, counted, for one
        it refuses."""
        if self.verifier is not None:  # signed: whoever holds the key may speak
            opened, bad = self.verifier.unseal(data)
            if opened is None:
                if bad:
                    self.stats.rx_bad += 1
                else:  # unsigned, or a replay
                    self.stats.rx_refused += 1
            return opened
        if addr == self.peer or self._peer_silent(time.monotonic()):
            return data
        self.stats.rx_refused += 1
        return None

    def _peer_silent(self, now: float) -> bool:
        """No peer, or none heard for ``PEER_SILENT_S`` (``now``: ``time.monotonic``)."""
        return now - self.peer_heard_wall > PEER_SILENT_S

    def heard(self, addr: Any, greet: Callable[["Port"], None]) -> None:
        """``addr`` sent a well-formed message addressed to the vehicle. The peer it is, or becomes
        (greeted with ``greet(port)``, a heartbeat) if there is none or it has been silent
        ``PEER_SILENT_S``; on a signed link also if it speaks as the vehicle's companion computer
        (a restarted controller). Any other signed sender is heard, and its commands taken, but
        the telemetry stays with the peer."""
        now = time.monotonic()
        if addr != self.peer:
            companion = self.accepted_from == (self.system_id, COMPANION)
            if not (self._peer_silent(now) or (self.verifier is not None and companion)):
                return
            self.peer = addr
            greet(self)
        self.peer_heard_wall = now

    def close(self) -> None:
        self.sock.close()
