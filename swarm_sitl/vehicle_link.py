"""A controller's MAVLink link to its vehicle, through any pymavlink connection string.

What it does is what an offboard companion computer does with PX4: it speaks as component
MAV_COMP_ID_ONBOARD_COMPUTER of the vehicle's own system, sends its heartbeat, waits for the
autopilot's, reads the vehicle's parameters (the controller uses the mass and maximum thrust the
vehicle reports, never a copy of its own), asks for LOCAL_POSITION_NED and ATTITUDE_QUATERNION at
the control rate and the streams it does not use at a lower rate (MAV_CMD_SET_MESSAGE_INTERVAL:
parsing MAVLink in Python is the largest cost of a lockstep tick), arms, switches to offboard and streams
SET_ATTITUDE_TARGET. Fields are read and written with ``sim_vehicles.wire_format``: NED/FRD exists
only inside this module.

Incoming messages are read with ``poll()`` (non-blocking; ``fileno()`` is there for ``select``).
The latest vehicle sample is the last LOCAL_POSITION_NED and ATTITUDE_QUATERNION of the same
``time_boot_ms``; ``sample_arrival_mono`` is when it arrived (``time.monotonic`` seconds). On a
plain UDP client link (``udpout:``, Linux) that instant is the kernel's receive timestamp, so a
real-time loop need not wake up for each datagram to know it (``stamps_arrivals``); on any other
link it is when ``poll()`` read it.

The per-tick messages (the two sample messages in, SET_ATTITUDE_TARGET out) are read and packed
in one compiled call each (``sim_vehicles.tick_frames``); a datagram that is not just the sample
is split with ``sim_vehicles.mavlink_frames``, and everything else goes through pymavlink.
"""

import math
import os
import time
from collections.abc import Callable
from typing import Any

os.environ.setdefault("MAVLINK20", "1")  # before pymavlink picks its wire protocol

import numpy as np
from pymavlink import mavutil

from sim_vehicles.common.command import AttitudeCommand
from sim_vehicles.mavlink import frames, tick_frames
from sim_vehicles.mavlink import px4_profile as px4
from sim_vehicles.mavlink.signing import Signer, Verifier
from sim_vehicles.mavlink.wire_format import IGNORE_ALL, SAMPLE_P, SAMPLE_Q, SAMPLE_V, sample_from_fields
from sim_vehicles.runtime import udp_arrival

mav = mavutil.mavlink
COMP_ONBOARD = 191  # MAV_COMP_ID_ONBOARD_COMPUTER
COMP_AUTOPILOT = 1
IGNORE_NOTHING = 0
REQUIRED_PARAMS = ("MASS_KG", "MAX_THRUST_N")
_LPOS = frames.LOCAL_POSITION_NED
_ATTQ = frames.ATTITUDE_QUATERNION
_FAST_IN = {_LPOS.msg_id: _LPOS, _ATTQ.msg_id: _ATTQ}
_SETPOINT_SPEC = frames.SET_ATTITUDE_TARGET.spec
#: what ``_handle`` reads besides the sample; other messages (the telemetry a ground station
#: shows) are only checked and counted, not decoded
_HANDLED = {mav.MAVLINK_MSG_ID_HEARTBEAT, mav.MAVLINK_MSG_ID_PARAM_VALUE, mav.MAVLINK_MSG_ID_COMMAND_ACK}
#: ``tick_frames.read_sample``'s table of the messages only checked and counted: CRC extra by id,
#: -1 for those read (the sample, ``_HANDLED``) and for ids the common set does not have
_IGNORED = np.full(max(mav.mavlink_map) + 1, -1, dtype=np.int64)
for _id, _cls in mav.mavlink_map.items():
    if _id not in _HANDLED and _id not in _FAST_IN:
        _IGNORED[_id] = _cls.crc_extra


class _Sealing:
    """Where pymavlink writes a link's messages: signed, then onto the connection."""

    def __init__(self, conn: Any, signer: Signer):
        self.conn = conn
        self.signer = signer

    def write(self, buf: bytes) -> None:
        self.conn.write(self.signer.seal(bytes(buf)))


class LinkError(RuntimeError):
    """The vehicle did not answer as an autopilot should; the message is one line."""


class VehicleLink:
    def __init__(
        self,
        url: str,
        system_id: int,
        stamp_arrivals: bool = True,
        faults: Any = None,
        signing_key: bytes | None = None,
    ):
        """``stamp_arrivals``: ask the kernel for arrival stamps where it can (a real-time loop
        needs them; a lockstep one does not, and reads its datagrams more cheaply without).
        ``faults``: a fault plan on this link (``link_faults.MavlinkFaults``), wrapping the
        datagrams it sends and receives. ``signing_key``: MAVLink 2 signing
        (``sim_vehicles.mavlink_signing``), between the link and its fault plan: what it sends is
        signed before the plan acts on it, what it receives is checked after."""
        # pymavlink picks the wire protocol of a connection from the environment when it opens it:
        # a process whose environment was replaced after this module was imported (a fork
        # server's child) would otherwise speak MAVLink 1, which cannot be signed
        os.environ.setdefault("MAVLINK20", "1")
        try:
            self.conn: Any = mavutil.mavlink_connection(
                url, source_system=system_id, source_component=COMP_ONBOARD, dialect="common"
            )
        except Exception as e:  # pymavlink raises many kinds for a bad connection string
            raise LinkError(f"cannot open MAVLink connection {url!r}: {e}") from None
        self.conn.mav.robust_parsing = True  # garbage becomes BAD_DATA, counted, not an exception
        self.url = url
        self.system_id = system_id
        self.faults = faults
        self._queued: list[tuple[bytes, float]] = []  #: datagrams a fault held, now due
        self.params: dict[str, float] = {}
        self._lpos: tuple = ()  #: LOCAL_POSITION_NED fields, declared order
        self._attq: tuple = ()  #: ATTITUDE_QUATERNION fields, declared order
        self._sample = np.zeros(10)  #: the latest complete sample (``wire_format.SAMPLE_*``)
        self.sample_ms = -1  #: time_boot_ms of the latest complete sample
        self._out = np.zeros(tick_frames.FRAME_BYTES, np.uint8)
        self.sample_arrival_mono = math.nan  #: when it arrived [s; time.monotonic]
        self.heartbeat: Any = None
        self.acks: dict[int, int] = {}
        self.rx_bad = 0
        self.rx_refused = 0  #: unsigned or replayed frames on a signed link
        self._signer = Signer(signing_key) if signing_key else None
        self._verifier = Verifier(signing_key) if signing_key else None
        if self._signer is not None:  # what pymavlink sends for us is signed on its way out
            self.conn.mav.file = _Sealing(self.conn, self._signer)
        self._next_hb = 0.0
        #: ``udpout:``: the socket's ``sendto`` and the resolved address, once pymavlink has them
        self._sendto: tuple[Callable[[bytes, Any], int], Any] | None = None
        self.stamps_arrivals = stamp_arrivals and self._enable_timestamps()
        # whole frames per read: UDP only (a serial or TCP read can end inside a frame, and
        # pymavlink's parser keeps the rest for the next read)
        self._datagrams = isinstance(self.conn, mavutil.mavudp)
        #: UDP: whether a datagram waits, asked without a read that raises when none does
        self._waiting = udp_arrival.Waiting(self.conn.port) if self._datagrams else None

    def _enable_timestamps(self) -> bool:
        c = self.conn
        if not isinstance(c, mavutil.mavudp) or c.udp_server or c.broadcast:
            return False
        return udp_arrival.enable(c.port)

    def fileno(self) -> int:
        return int(self.conn.fd)

    def block_reads(self, timeout_s: float) -> None:
        """UDP: a read told its socket is readable (``poll(readable=True)``) waits in ``recvfrom``
        up to ``timeout_s`` for a datagram (``SO_RCVTIMEO``): one system call where a ``select``
        and a read take two. Other reads still ask first whether a datagram waits."""
        if self._datagrams:
            udp_arrival.block_reads(self.conn.port, timeout_s)

    def close(self) -> None:
        self.conn.close()

    # -- receive ---------------------------------------------------------------------------------
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

    def poll(self, readable: bool = False, until_ms: int = -1) -> int:
        """Read everything waiting; returns the number of messages handled. ``readable``: a
        ``select`` on ``fileno()`` has just said so (the first read needs no check). ``until_ms``:
        stop once the sample of that instant has come (lockstep: what else waits is read at the
        next tick, whose wait finds the socket readable), saving a look at an empty socket. Bytes go
        straight to the parsers (``tick_frames``, ``mavlink_frames``, else ``mav.parse_buffer``):
        mavutil's per-message bookkeeping, which this link does not use, costs as much as the parsing."""
        n = 0
        conn = self.conn
        wall_to_mono = udp_arrival.wall_to_monotonic_s() if self.stamps_arrivals else 0.0
        while True:
            try:
                data, arrival = self._recv(wall_to_mono, readable)
            except OSError:
                return n
            readable = False
            if not data:
                return n
            if self._verifier is not None:
                opened = self._open(data)
                if opened is None:
                    continue
                data = opened
            plain = self._datagrams  # whole plain frames (a signed datagram is unsigned above)
            if plain:
                s = tick_frames.read_sample(
                    data, self.system_id, COMP_AUTOPILOT, _LPOS.spec, _ATTQ.spec, _IGNORED
                )
                v = s.tolist()  # Python floats: one call, where each numpy scalar costs one
                if v[tick_frames.RS_OK]:  # the sample, and telemetry that is only counted
                    n += int(v[tick_frames.RS_FRAMES])
                    self.rx_bad += int(v[tick_frames.RS_BAD])
                    ms = int(v[tick_frames.RS_TIME_MS])
                    self._lpos = self._attq = (ms,)  # this instant is complete: no half to wait for
                    self._set_sample(ms, s[tick_frames.RS_SAMPLE], arrival)
                    if ms == until_ms:
                        return n
                    continue
            fast = frames.read_datagram(data, _FAST_IN) if plain else None
            if fast is not None:
                for msg_id, sysid, compid, values, frame in fast:
                    n += 1
                    if values is None:
                        if msg_id not in _HANDLED:  # checked and counted, not decoded
                            if not frames.crc_ok(frame):
                                self.rx_bad += 1
                            continue
                        try:
                            self._handle(conn.mav.decode(bytearray(frame)), arrival)
                        except Exception:  # pymavlink's own errors and struct errors: drop, count
                            self.rx_bad += 1
                    elif sysid == self.system_id and compid == COMP_AUTOPILOT:
                        self._sample_part(msg_id == _LPOS.msg_id, values, arrival)
                continue
            try:
                msgs = conn.mav.parse_buffer(data) or []
            except Exception:  # pymavlink raises its own and struct errors on garbage: drop, count
                msgs = None
            if msgs is None or (self._datagrams and conn.mav.buf_len()):  # garbage, or cut short
                self.rx_bad += 1
                if self._datagrams:
                    frames.reset_parser(conn.mav)  # nothing carries over to the next datagram
            if msgs is None:
                continue
            for m in msgs:
                n += 1
                self._handle(m, arrival)

    def _open(self, data: bytes) -> bytes | None:
        """A signed datagram checked and unsigned; None (counted) if refused."""
        v = self._verifier
        assert v is not None
        bad = v.bad
        opened = v.open(data)
        if opened is None:
            if v.bad > bad:
                self.rx_bad += 1
            else:
                self.rx_refused += 1
        return opened

    def _handle(self, m: Any, arrival: float) -> None:
        t = m.get_type()
        if t == "BAD_DATA":
            self.rx_bad += 1
            return
        if m.get_srcSystem() != self.system_id or m.get_srcComponent() != COMP_AUTOPILOT:
            return
        if t == "LOCAL_POSITION_NED":
            self._sample_part(True, (m.time_boot_ms, m.x, m.y, m.z, m.vx, m.vy, m.vz), arrival)
        elif t == "ATTITUDE_QUATERNION":
            fields = (m.time_boot_ms, m.q1, m.q2, m.q3, m.q4, m.rollspeed, m.pitchspeed, m.yawspeed)
            self._sample_part(False, fields, arrival)
        elif t == "HEARTBEAT":
            self.heartbeat = m
        elif t == "PARAM_VALUE":
            self.params[m.param_id] = float(m.param_value)
        elif t == "COMMAND_ACK":
            self.acks[m.command] = m.result

    def _sample_part(self, is_position: bool, fields: tuple, arrival: float) -> None:
        if is_position:
            self._lpos = fields
        else:
            self._attq = fields
        lpos, attq = self._lpos, self._attq
        if len(lpos) > 1 and len(attq) > 1 and lpos[0] == attq[0]:
            decoded = sample_from_fields(np.array(lpos[1:7], dtype=float), np.array(attq[1:5], dtype=float))
            self._set_sample(int(lpos[0]), decoded, arrival)

    def _set_sample(self, time_boot_ms: int, decoded: np.ndarray, arrival: float) -> None:
        if time_boot_ms < self.sample_ms:  # a sample a fault held back, older than the one we have
            return
        self._sample = decoded
        self.sample_ms = time_boot_ms
        self.sample_arrival_mono = arrival

    def sample_settled(self, time_boot_ms: int) -> bool:
        """Lockstep: whether the sample of ``time_boot_ms`` has come, or a fault plan lost it."""
        if self.sample_ms == time_boot_ms:
            return True
        return self.faults is not None and self.faults.lost_ms == time_boot_ms

    def sample(self) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
        """``(time_boot_s, p_W, v_W, q_WB)`` of the latest complete sample, in ENU/FLU."""
        s = self._sample
        return self.sample_ms / 1000.0, s[SAMPLE_P], s[SAMPLE_V], s[SAMPLE_Q]

    # -- send ------------------------------------------------------------------------------------
    def send_heartbeat_if_due(self) -> None:
        now = time.monotonic()
        if now >= self._next_hb:
            self._next_hb = now + 1.0
            self.conn.mav.heartbeat_send(mav.MAV_TYPE_ONBOARD_CONTROLLER, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0)

    def command(self, command: int, *params: float) -> None:
        p = [*params, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0][:7]
        self.conn.mav.command_long_send(self.system_id, COMP_AUTOPILOT, command, 0, *p)

    def send_setpoint(self, cmd: AttitudeCommand, time_boot_ms: int) -> None:
        mav_ = self.conn.mav
        max_thrust = self.params["MAX_THRUST_N"]
        q_c, omega = cmd.q_c, cmd.omega_c_B
        if not (type(q_c) is np.ndarray and type(omega) is np.ndarray):
            q_c, omega = np.asarray(q_c, dtype=float), np.asarray(omega, dtype=float)
        n = tick_frames.pack_setpoint(
            self._out,
            mav_.seq,
            mav_.srcSystem,
            mav_.srcComponent,
            _SETPOINT_SPEC,
            time_boot_ms,
            self.system_id,
            COMP_AUTOPILOT,
            q_c,
            omega,
            float(cmd.thrust_N),
            max_thrust,
        )
        frame = frames.take_frame(mav_, self._out, n)
        if self._signer is not None:
            frame = self._signer.seal(frame)
        if self.faults is None:
            self._write(frame)
        else:
            self.faults.send(frame, time_boot_ms, self.conn.write, self.send_clock_only)

    def _write(self, frame: bytes) -> None:
        """``conn.write``; on a ``udpout:`` link whose address pymavlink has resolved, its socket's
        ``sendto`` straight away (what pymavlink's ``write`` ends in, without its per-call checks)."""
        to = self._sendto
        if to is None:
            c = self.conn
            c.write(frame)
            if self._datagrams and not c.udp_server and not c.broadcast and c.resolved_destination_addr:
                self._sendto = (c.port.sendto, c.destination_addr)
            return
        try:  # noqa: SIM105  (a try costs less than a suppress() object every tick)
            to[0](frame, to[1])
        except OSError:
            pass  # as pymavlink's write: a send that fails is lost

    def send_clock_only(self, time_boot_ms: int) -> None:
        """Lockstep: a clock-only SET_ATTITUDE_TARGET (every field ignored): the vehicle moves its
        clock to ``time_boot_ms`` on what it holds, and sends its sample there."""
        self.conn.mav.set_attitude_target_send(
            time_boot_ms, self.system_id, COMP_AUTOPILOT, IGNORE_ALL, [1.0, 0.0, 0.0, 0.0], 0, 0, 0, 0
        )

    # -- the start-up handshake ------------------------------------------------------------------
    def _wait(self, done: Any, what: str, timeout_s: float, resend: Any = None, every_s: float = 0.5) -> None:
        end = time.monotonic() + timeout_s
        next_send = 0.0
        while not done():
            now = time.monotonic()
            if now > end:
                raise LinkError(f"{self.url}: no {what} within {timeout_s:g} s")
            if resend is not None and now >= next_send:
                resend()
                next_send = now + every_s
            self.send_heartbeat_if_due()
            self.conn.select(0.02)
            self.poll()

    def connect(self, timeout_s: float) -> None:
        """Heartbeat, parameters and telemetry rates; raises ``LinkError`` naming what is missing."""
        self._wait(lambda: self.heartbeat is not None, f"HEARTBEAT from system {self.system_id}", timeout_s)
        self._wait(
            lambda: all(k in self.params for k in REQUIRED_PARAMS),
            f"parameters {', '.join(REQUIRED_PARAMS)}",
            timeout_s,
            lambda: self.conn.mav.param_request_list_send(self.system_id, COMP_AUTOPILOT),
            1.0,
        )

    def request_rates(self, period_s: float, other_hz: float, timeout_s: float) -> None:
        """LOCAL_POSITION_NED and ATTITUDE_QUATERNION once per ``period_s``; ATTITUDE and
        HIGHRES_IMU, which the controller does not use, at ``other_hz`` (0: off)."""
        for msg_id in (mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED, mav.MAVLINK_MSG_ID_ATTITUDE_QUATERNION):
            self._command_acked(mav.MAV_CMD_SET_MESSAGE_INTERVAL, timeout_s, float(msg_id), period_s * 1e6)
        other_us = 1e6 / other_hz if other_hz > 0 else -1.0
        for msg_id in (mav.MAVLINK_MSG_ID_ATTITUDE, mav.MAVLINK_MSG_ID_HIGHRES_IMU):
            self._command_acked(mav.MAV_CMD_SET_MESSAGE_INTERVAL, timeout_s, float(msg_id), other_us)

    def arm_offboard(self, timeout_s: float) -> None:
        """Arm, then OFFBOARD the way PX4 takes it: with a setpoint stream already running (a
        clock-only setpoint stamped with the vehicle's time, before each request: it holds what it
        holds and, in lockstep, moves no clock)."""
        self._command_acked(mav.MAV_CMD_COMPONENT_ARM_DISARM, timeout_s, 1.0)
        offboard = (float(px4.BASE_FLAGS), float(px4.MAIN_OFFBOARD), 0.0)
        self._command_acked(
            mav.MAV_CMD_DO_SET_MODE,
            timeout_s,
            *offboard,
            before=lambda: self.send_clock_only(max(self.sample_ms, 0)),
        )

    def advance_to(self, time_boot_ms: int, timeout_s: float) -> None:
        """Lockstep: move the vehicle's clock to ``time_boot_ms`` without a new setpoint (a
        clock-only SET_ATTITUDE_TARGET, every field ignored: it flies what it holds, its failsafe
        once its setpoints are overdue) and wait for its sample there."""

        self._wait(
            lambda: self.sample_ms >= time_boot_ms,
            f"the vehicle's clock at {time_boot_ms} ms",
            timeout_s,
            lambda: self.send_clock_only(time_boot_ms),
        )

    def request_sample(self, timeout_s: float) -> None:
        """Ask for LOCAL_POSITION_NED and ATTITUDE_QUATERNION now (MAV_CMD_REQUEST_MESSAGE)."""

        def ask() -> None:
            for msg_id in (mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED, mav.MAVLINK_MSG_ID_ATTITUDE_QUATERNION):
                self.command(mav.MAV_CMD_REQUEST_MESSAGE, float(msg_id))

        self._wait(lambda: self.sample_ms >= 0, "LOCAL_POSITION_NED and ATTITUDE_QUATERNION", timeout_s, ask)

    def _command_acked(
        self, command: int, timeout_s: float, *params: float, before: Callable[[], None] | None = None
    ) -> None:
        """Send ``command`` until it is answered (``before()`` ahead of each try); ``LinkError``
        if it is refused or never answered. A temporary refusal is tried again, as MAVSDK does,
        until ``timeout_s``: on a lossy link the datagram ``before()`` sent (the setpoint that
        OFFBOARD needs) can be lost while the command gets through."""
        name = mav.enums["MAV_CMD"][command].name
        self.acks.pop(command, None)  # an answer to an earlier command of the same kind is not ours

        def send() -> None:
            if before is not None:
                before()
            self.command(command, *params)

        def answered() -> bool:
            if self.acks.get(command) == mav.MAV_RESULT_TEMPORARILY_REJECTED and time.monotonic() < end:
                del self.acks[command]  # try again at the next resend
            return command in self.acks

        end = time.monotonic() + timeout_s
        self._wait(answered, f"COMMAND_ACK for {name}", timeout_s, send)
        if self.acks[command] != mav.MAV_RESULT_ACCEPTED:
            raise LinkError(f"{self.url}: {name} refused (MAV_RESULT {self.acks[command]})")
