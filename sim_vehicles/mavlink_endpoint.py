"""A simulated vehicle behind a MAVLink 2 endpoint on UDP, in real time.

It behaves as a MAVLink tool expects of an autopilot (the PX4 SITL habits):

- HEARTBEAT at 1 Hz: type MAV_TYPE_QUADROTOR, autopilot MAV_AUTOPILOT_GENERIC, system id = follower
  id, component MAV_COMP_ID_AUTOPILOT1; ``base_mode`` carries SAFETY_ARMED and CUSTOM_MODE_ENABLED;
  ``custom_mode`` is ``MODE_HOLD`` (0, ignores setpoints), ``MODE_OFFBOARD`` (1, follows
  SET_ATTITUDE_TARGET) or ``MODE_FAILSAFE`` (2, setpoint lost: level attitude, hover thrust), and
  ``system_status`` is MAV_STATE_CRITICAL in failsafe.
- Telemetry at configurable rates: LOCAL_POSITION_NED, ATTITUDE, ATTITUDE_QUATERNION,
  ATTITUDE_TARGET, HIGHRES_IMU (specific force, body FRD), SYS_STATUS; ``time_boot_ms`` is the
  vehicle's simulated time.
- SET_ATTITUDE_TARGET honoured as PX4 does: target system/component checked, type_mask bits
  (1..4 ignore body rates, 64 ignore throttle, 128 ignore attitude), NED/FRD converted at the wire
  (``wire_format``), thrust 0..1 of MAX_THRUST_N.
- COMMAND_LONG MAV_CMD_COMPONENT_ARM_DISARM and MAV_CMD_DO_SET_MODE (param2 = custom mode), each
  answered with COMMAND_ACK.
- Parameters MASS_KG, INERTIA_X/Y/Z, MAX_THRUST_N, SP_TIMEOUT_S over the parameter protocol.
- Every message in and out written to a ``.tlog`` (8-byte big-endian microseconds, then the frame).

While disarmed the vehicle is held where it is (as if on a stand); physics runs once armed.
Bad bytes are dropped and counted (``stats``); nothing a peer sends stops the vehicle.
"""

import math
import socket
import struct
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
from pymavlink.dialects.v20 import common as mav

from sim_vehicles.autopilot import AttitudeCommand, Autopilot
from sim_vehicles.quaternion import rotation_matrix
from sim_vehicles.rigid_body import POS, QUAT, RATE, VEL
from sim_vehicles.wire_format import (
    AttitudeTargetFields,
    decode_attitude_target,
    encode_attitude_quaternion,
    encode_local_position,
)

MODE_HOLD = 0
MODE_OFFBOARD = 1
MODE_FAILSAFE = 2

IGNORE_RATES = 0b0000_0111
IGNORE_THROTTLE = 0b0100_0000
IGNORE_ATTITUDE = 0b1000_0000


@dataclass(frozen=True)
class TelemetryRates:
    """Stream rates [Hz], PX4-like defaults."""

    local_position_hz: float = 50.0
    attitude_hz: float = 50.0
    attitude_quaternion_hz: float = 50.0
    attitude_target_hz: float = 10.0
    imu_hz: float = 50.0
    sys_status_hz: float = 1.0
    heartbeat_hz: float = 1.0


@dataclass
class EndpointStats:
    rx_messages: int = 0
    rx_bad: int = 0  #: frames that failed to parse or were refused
    tx_messages: int = 0
    setpoints: int = 0


class _Sink:
    """File-like object pymavlink writes frames into; we send them and log them."""

    def __init__(self) -> None:
        self.frames: list[bytes] = []

    def write(self, data: bytes) -> None:
        self.frames.append(bytes(data))


@dataclass
class VehicleEndpoint:
    autopilot: Autopilot
    system_id: int
    bind: tuple[str, int] = ("127.0.0.1", 0)
    setpoint_timeout_s: float = 0.5
    rates: TelemetryRates = field(default_factory=TelemetryRates)
    tlog_path: Path | None = None

    def __post_init__(self) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(self.bind)
        self.sock.setblocking(False)
        self.address = self.sock.getsockname()
        self._sink = _Sink()
        self.mav = mav.MAVLink(self._sink, srcSystem=self.system_id, srcComponent=mav.MAV_COMP_ID_AUTOPILOT1)
        self._parser = mav.MAVLink(None, srcSystem=255, srcComponent=0)
        self._parser.robust_parsing = True
        self.peer: tuple[str, int] | None = None
        self.armed = False
        self.mode = MODE_HOLD
        self.stats = EndpointStats()
        self._last_setpoint_s = -math.inf
        self._next_send: dict[str, float] = {}
        self._tlog: BinaryIO | None = open(self.tlog_path, "wb") if self.tlog_path else None  # noqa: SIM115
        p = self.autopilot.params
        self.params: dict[str, float] = {
            "MASS_KG": p.mass_kg,
            "INERTIA_X": p.inertia_kgm2[0],
            "INERTIA_Y": p.inertia_kgm2[1],
            "INERTIA_Z": p.inertia_kgm2[2],
            "MAX_THRUST_N": p.max_thrust_N,
            "SP_TIMEOUT_S": self.setpoint_timeout_s,
        }

    # -- I/O -------------------------------------------------------------------------------------
    def _log(self, frame: bytes) -> None:
        if self._tlog is not None:
            self._tlog.write(struct.pack(">Q", int(time.time() * 1e6)) + frame)

    def _send(self, msg: Any) -> None:
        self.mav.send(msg)
        for frame in self._sink.frames:
            self._log(frame)
            if self.peer is not None:
                self.sock.sendto(frame, self.peer)
                self.stats.tx_messages += 1
        self._sink.frames.clear()

    def close(self) -> None:
        self.sock.close()
        if self._tlog is not None:
            self._tlog.close()
            self._tlog = None

    # -- receive ---------------------------------------------------------------------------------
    def poll(self) -> None:
        """Handle every datagram waiting on the socket."""
        while True:
            try:
                data, addr = self.sock.recvfrom(4096)
            except BlockingIOError:
                return
            except OSError:
                return
            self.peer = addr
            try:
                msgs = self._parser.parse_buffer(data) or []
            except Exception:  # pymavlink raises its own and struct errors on garbage: drop, count
                self.stats.rx_bad += 1
                continue
            for m in msgs:
                self._log(m.get_msgbuf())
                self.stats.rx_messages += 1
                if m.get_type() == "BAD_DATA":
                    self.stats.rx_bad += 1
                    continue
                self._handle(m)

    def _for_me(self, m: Any) -> bool:
        return m.target_system in (0, self.system_id) and m.target_component in (
            0,
            mav.MAV_COMP_ID_AUTOPILOT1,
        )

    def _handle(self, m: Any) -> None:
        t = m.get_type()
        if t == "SET_ATTITUDE_TARGET" and self._for_me(m):
            self._on_setpoint(m)
        elif t == "COMMAND_LONG" and self._for_me(m):
            self._on_command(m)
        elif t == "PARAM_REQUEST_LIST" and self._for_me(m):
            for i, name in enumerate(self.params):
                self._send_param(name, i)
        elif t == "PARAM_REQUEST_READ" and self._for_me(m):
            names = list(self.params)
            name = (
                m.param_id
                if m.param_index < 0
                else (names[m.param_index] if m.param_index < len(names) else "")
            )
            if name in self.params:
                self._send_param(name, names.index(name))

    def _send_param(self, name: str, index: int) -> None:
        self._send(
            self.mav.param_value_encode(
                name.encode(), float(self.params[name]), mav.MAV_PARAM_TYPE_REAL32, len(self.params), index
            )
        )

    def _on_command(self, m: Any) -> None:
        result = mav.MAV_RESULT_ACCEPTED
        if m.command == mav.MAV_CMD_COMPONENT_ARM_DISARM:
            self.armed = m.param1 >= 0.5
        elif m.command == mav.MAV_CMD_DO_SET_MODE and int(m.param2) in (MODE_HOLD, MODE_OFFBOARD):
            self.mode = int(m.param2)
            self._last_setpoint_s = self.autopilot.time_s if self.mode == MODE_OFFBOARD else -math.inf
        else:
            result = mav.MAV_RESULT_UNSUPPORTED
        self._send(self.mav.command_ack_encode(m.command, result))

    def _on_setpoint(self, m: Any) -> None:
        ap = self.autopilot
        cur = ap.command
        mask = m.type_mask
        try:
            new = decode_attitude_target(
                AttitudeTargetFields(
                    tuple(m.q), (m.body_roll_rate, m.body_pitch_rate, m.body_yaw_rate), m.thrust
                ),
                ap.params.max_thrust_N,
            )
        except ValueError:
            self.stats.rx_bad += 1
            return
        cmd = AttitudeCommand(
            q_c=cur.q_c if mask & IGNORE_ATTITUDE else new.q_c,
            thrust_N=cur.thrust_N if mask & IGNORE_THROTTLE else new.thrust_N,
            omega_c_B=np.zeros(3) if mask & IGNORE_RATES == IGNORE_RATES else new.omega_c_B,
        )
        self.stats.setpoints += 1
        self._last_setpoint_s = ap.time_s
        if self.mode in (MODE_OFFBOARD, MODE_FAILSAFE):
            self.mode = MODE_OFFBOARD
            ap.set_command(cmd)

    # -- simulate --------------------------------------------------------------------------------
    def _failsafe_check(self) -> None:
        ap = self.autopilot
        if self.mode == MODE_OFFBOARD and ap.time_s - self._last_setpoint_s > self.setpoint_timeout_s:
            self.mode = MODE_FAILSAFE
            x_w = rotation_matrix(ap.state[QUAT])[:, 0]
            yaw = math.atan2(x_w[1], x_w[0])  # keep heading, level the vehicle
            q = np.array([math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)])
            ap.set_command(AttitudeCommand(q_c=q, thrust_N=ap.params.hover_thrust_N))

    def step(self, n_steps: int = 1) -> None:
        """Advance the vehicle ``n_steps`` attitude steps (held still while disarmed), then stream."""
        ap = self.autopilot
        for _ in range(n_steps):
            if self.armed:
                ap.advance(1)
            else:
                ap.step_index += 1
            self._failsafe_check()
        self._stream()

    def _due(self, name: str, rate_hz: float) -> bool:
        t = self.autopilot.time_s
        nxt = self._next_send.get(name, 0.0)
        if rate_hz <= 0 or t + 1e-9 < nxt:
            return False
        self._next_send[name] = max(nxt + 1.0 / rate_hz, t)
        return True

    def _stream(self) -> None:
        ap, r = self.autopilot, self.rates
        ms = round(ap.time_s * 1000)
        x = ap.state
        if self._due("heartbeat", r.heartbeat_hz):
            base = mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (
                mav.MAV_MODE_FLAG_SAFETY_ARMED if self.armed else 0
            )
            status = (
                mav.MAV_STATE_CRITICAL
                if self.mode == MODE_FAILSAFE
                else (mav.MAV_STATE_ACTIVE if self.armed else mav.MAV_STATE_STANDBY)
            )
            self._send(
                self.mav.heartbeat_encode(
                    mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_GENERIC, base, self.mode, status
                )
            )
        if self._due("lpos", r.local_position_hz):
            self._send(self.mav.local_position_ned_encode(ms, *encode_local_position(x[POS], x[VEL])))
        send_attq = self._due("attq", r.attitude_quaternion_hz)
        send_att = self._due("att", r.attitude_hz)
        if send_attq or send_att:
            f = encode_attitude_quaternion(x[QUAT], x[RATE])  # once for both messages
            if send_attq:
                self._send(self.mav.attitude_quaternion_encode(ms, *f))
            if send_att:
                w, qx, qy, qz = f[0:4]
                roll = math.atan2(2 * (w * qx + qy * qz), 1 - 2 * (qx * qx + qy * qy))
                pitch = math.asin(max(-1.0, min(1.0, 2 * (w * qy - qz * qx))))
                yaw = math.atan2(2 * (w * qz + qx * qy), 1 - 2 * (qy * qy + qz * qz))
                self._send(self.mav.attitude_encode(ms, roll, pitch, yaw, f[4], f[5], f[6]))
        if self._due("target", r.attitude_target_hz):
            c = ap.command
            f = encode_attitude_quaternion(c.q_c, c.omega_c_B)
            self._send(
                self.mav.attitude_target_encode(
                    ms, 0, list(f[0:4]), f[4], f[5], f[6], float(c.thrust_N) / ap.params.max_thrust_N
                )
            )
        if self._due("imu", r.imu_hz):
            p = ap.params
            T = min(max(float(ap.command.thrust_N), 0.0), p.max_thrust_N) if self.armed else p.hover_thrust_N
            # specific force [m/s^2; body FLU]: thrust when flying, the stand's reaction when held
            f_b = (
                np.array([0.0, 0.0, T / p.mass_kg])
                if self.armed
                else rotation_matrix(x[QUAT]).T @ [0, 0, p.g_mps2]
            )
            self._send(
                self.mav.highres_imu_encode(
                    ms * 1000,
                    f_b[0],
                    -f_b[1],
                    -f_b[2],
                    x[RATE][0],
                    -x[RATE][1],
                    -x[RATE][2],
                    0,
                    0,
                    0,
                    1013.25,
                    0,
                    0,
                    0.0,
                    0b111111,
                )
            )
        if self._due("sys", r.sys_status_hz):
            self._send(self.mav.sys_status_encode(0, 0, 0, 0, 12000, -1, -1, 0, 0, 0, 0, 0, 0))

    def run_realtime(self, duration_s: float | None = None, stop: Any = None) -> None:
        """Run against the wall clock (``time.monotonic``) until ``duration_s`` or ``stop()``."""
        start = time.monotonic()
        dt = self.autopilot.dt_s
        k0 = self.autopilot.step_index
        while True:
            now = time.monotonic() - start
            if (duration_s is not None and now >= duration_s) or (stop is not None and stop()):
                return
            self.poll()
            due = k0 + int(now / dt) - self.autopilot.step_index
            if due > 0:
                self.step(min(due, 50))
            else:
                time.sleep(dt / 2)
