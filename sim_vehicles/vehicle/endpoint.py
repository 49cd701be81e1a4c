"""A simulated vehicle behind a MAVLink 2 endpoint on UDP, in real time.

It behaves as a MAVLink tool expects of a PX4 autopilot (the compatibility profile; PX4's
conventions are in ``px4_profile``):

- HEARTBEAT at 1 Hz: type MAV_TYPE_QUADROTOR, autopilot MAV_AUTOPILOT_PX4, system id = follower
  id, component MAV_COMP_ID_AUTOPILOT1; ``base_mode`` carries SAFETY_ARMED and CUSTOM_MODE_ENABLED;
  ``custom_mode`` is PX4's: AUTO.LOITER ("Hold", ``MODE_HOLD``: a position hold where it was when
  the mode began or it was armed, by its own loop as in its failsafe; setpoints ignored) or OFFBOARD
  (``MODE_OFFBOARD``: follows SET_ATTITUDE_TARGET). Setpoints lost for SP_TIMEOUT_S in offboard
  are its failsafe (``MODE_FAILSAFE``): it flies a position hold at the point of loss or a landing
  (``failsafe``), reported as AUTO.LOITER or AUTO.LAND with ``system_status`` MAV_STATE_CRITICAL,
  and a valid setpoint brings it back to offboard. Entering and leaving failsafe is a STATUSTEXT
  and an event (``events_path``).
- Telemetry at configurable rates: LOCAL_POSITION_NED, ATTITUDE, ATTITUDE_QUATERNION,
  ATTITUDE_TARGET, HIGHRES_IMU (specific force, body FRD), SYS_STATUS (sensor and pre-arm health
  bits), GLOBAL_POSITION_INT and GPS_RAW_INT (around ``home``), EXTENDED_SYS_STATE (landed state),
  HOME_POSITION; ``time_boot_ms`` is the vehicle's simulated time. AUTOPILOT_VERSION on request
  (PROTOCOL_VERSION is not in pymavlink's common dialect: MAV_CMD_REQUEST_PROTOCOL_VERSION is
  answered UNSUPPORTED, and tools then take MAVLink 2 from the frames themselves).
- SET_ATTITUDE_TARGET honoured as PX4 does: target system/component checked, type_mask bits
  (1..4 ignore body rates, 64 ignore throttle, 128 ignore attitude), NED/FRD converted at the wire
  (``wire_format``), thrust 0..1 of MAX_THRUST_N.
- COMMAND_LONG MAV_CMD_COMPONENT_ARM_DISARM and MAV_CMD_DO_SET_MODE (PX4's base mode, main mode,
  sub mode; OFFBOARD only while setpoints stream, as PX4 requires), each answered with COMMAND_ACK
  addressed to its sender; MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES and MAV_CMD_GET_HOME_POSITION
  answered with their message; PING answered; an empty mission list.
- Parameters MASS_KG, INERTIA_X/Y/Z, MAX_THRUST_N, SP_TIMEOUT_S, COM_OBL_ACT and MC_ROLLRATE_MAX,
  MC_PITCHRATE_MAX, MC_YAWRATE_MAX [deg/s] over the parameter protocol; PARAM_SET changes those
  that may change in flight (``SETTABLE``), answered with PARAM_VALUE.
- MAV_CMD_SET_MESSAGE_INTERVAL (param1 message id, param2 interval [us]; -1 stops, 0 restores the
  default) and MAV_CMD_REQUEST_MESSAGE (param1 message id: sent once, now) for the telemetry above.
- Every message in and out written to a ``.tlog`` (8-byte big-endian microseconds, then the frame;
  on a signed link the frame within its signature, readable without the key).
- Optionally the true state (float64, ENU/FLU) at every LOCAL_POSITION_NED instant, written to a
  ``row_log`` file: what a bench records and a real autopilot cannot give.

Two clocks:

- Real time (default, ``run_realtime``): the vehicle steps with the wall clock (``time.monotonic``).
- Lockstep (``lockstep_period_s`` set, ``run_lockstep``): simulated time stands still until a
  SET_ATTITUDE_TARGET stamped with the vehicle's current ``time_boot_ms`` arrives; the vehicle then
  applies it (if armed and in offboard) and advances exactly one period, and streams its telemetry.
  A setpoint stamped earlier (a retransmission) makes it send its current LOCAL_POSITION_NED and
  ATTITUDE_QUATERNION again and nothing else; one stamped later is refused and counted, except a
  *clock-only* setpoint (every field ignored: type_mask ``IGNORE_ALL``), which advances the vehicle
  to its stamp, period by period, under what it holds (its failsafe, once its setpoints have been
  missing for SP_TIMEOUT_S of simulated time), and counts as no setpoint: how a controller that
  was down (a planned kill and restart) takes its vehicle up again at its restart tick. The run is
  deterministic: the same setpoints give the same trajectory, bit for bit. LOCAL_POSITION_NED and
  ATTITUDE_QUATERNION default to once per period. The heartbeat runs on
  the wall clock in both modes (it says the link is alive), and a new peer gets one at once.

While disarmed the vehicle is held where it is (as if on a stand); physics runs once armed.

Hostile input (``stats`` counts each kind; nothing anyone sends stops the vehicle or moves it):

- One peer: telemetry goes to the first address that sent it a well-formed message addressed to
  it (its controller), and what
  any other address sends is refused and counted (``rx_refused``) until that peer has been silent
  for ``PEER_SILENT_S`` of wall time (its controller died: a new one may take the link). Under
  MAVLink 2 signing (``mavlink_signing``) only correctly signed datagrams are heard, from anyone
  holding the key (their commands are taken); the link moves at once to one that speaks as the
  vehicle's companion computer (a restarted controller), and telemetry stays with the peer.
- Bytes that are not MAVLink, cut short or with a bad CRC: ``rx_bad``. A message for another
  system or component: ``rx_refused``. A message the vehicle does not handle: ``rx_unhandled``.
- Values it refuses (``rx_invalid``; the vehicle keeps its last valid setpoint): a setpoint whose
  quaternion is not a rotation, with a non-finite rate or a thrust outside 0..1; a command whose
  parameters are not finite where it reads them (``COMMAND_PARAMS``; NaN in a parameter it does not
  need is MAVLink's "unused") or not what the command takes (COMMAND_ACK ``MAV_RESULT_DENIED``); a
  PARAM_SET outside the parameter's range (answered with the value it keeps).
- Commanded body rates are clipped to the vehicle's MC_ROLLRATE_MAX, MC_PITCHRATE_MAX and
  MC_YAWRATE_MAX (``VehicleParams.max_rate_rps``), so the plant's state stays finite.
- A disarm while armed is refused unless forced (param2 = 21196), as PX4 refuses one in flight.
- A handler that fails on a message it accepted is a bug: counted in ``handler_errors`` with its
  last error, never a stopped vehicle.
"""

import contextlib
import math
import select
import socket
import struct
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO, NamedTuple

import numpy as np
from pymavlink.dialects.v20 import common as mav

from sim_vehicles.common.command import AttitudeCommand
from sim_vehicles.common.quaternion import rotation_matrix
from sim_vehicles.common.state import POS, QUAT, RATE, STATE_COLUMNS, VEL
from sim_vehicles.mavlink import frames, tick_frames
from sim_vehicles.mavlink import px4_profile as px4
from sim_vehicles.mavlink.enu_ned import enu_to_ned, flu_to_frd
from sim_vehicles.mavlink.signing import SIGNATURE_LEN, Signer, Verifier
from sim_vehicles.mavlink.wire_format import (
    CMD_VALID,
    command_from_fields,
    command_of,
    encode_attitude,
    encode_attitude_quaternion,
)
from sim_vehicles.plant.autopilot import Autopilot
from sim_vehicles.plant.failsafe import ACTION_HOLD, FAILSAFE_PERIOD_S, failsafe_command, hold_at
from sim_vehicles.runtime import udp_arrival
from sim_vehicles.runtime.event_log import EventLog
from sim_vehicles.runtime.row_log import RowLog
from sim_vehicles.vehicle import lockstep_tick

#: the two messages of a lockstep sample, sent at every period
LPOS_ID, ATTQ_ID = mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED, mav.MAVLINK_MSG_ID_ATTITUDE_QUATERNION

MODE_HOLD = 0
MODE_OFFBOARD = 1
MODE_FAILSAFE = 2

IGNORE_RATES = 0b0000_0111
IGNORE_THROTTLE = 0b0100_0000
IGNORE_ATTITUDE = 0b1000_0000
IGNORE_ALL = IGNORE_RATES | IGNORE_THROTTLE | IGNORE_ATTITUDE  #: a lockstep clock-only setpoint
MAX_CLOCK_STEP_S = 3600.0  #: the furthest a clock-only setpoint may move a lockstep vehicle [s]
COMPONENT = mav.MAV_COMP_ID_AUTOPILOT1
COMPANION = mav.MAV_COMP_ID_ONBOARD_COMPUTER  #: how the vehicle's controller speaks (its system id)
RATE_MAX_PARAMS = ("MC_ROLLRATE_MAX", "MC_PITCHRATE_MAX", "MC_YAWRATE_MAX")  #: [deg/s], PX4's names
#: parameters a PARAM_SET may change, and their ranges (the others are what the vehicle is)
SETTABLE = {
    "SP_TIMEOUT_S": (0.05, 60.0),
    "COM_OBL_ACT": (0.0, 1.0),  # failsafe.ACTION_LAND, failsafe.ACTION_HOLD
    **dict.fromkeys(RATE_MAX_PARAMS, (1.0, 1800.0)),  # [deg/s], as PX4 gives them
}
#: commands that ask for a message: the message each one sends after its COMMAND_ACK
ASKS = {
    mav.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES: mav.MAVLINK_MSG_ID_AUTOPILOT_VERSION,
    mav.MAV_CMD_GET_HOME_POSITION: mav.MAVLINK_MSG_ID_HOME_POSITION,
}
#: the commands the vehicle takes: the parameters (0-based) each needs finite, and those it reads
#: that may be NaN (MAVLink's "unused", as MAVSDK sends them: taken as 0); the others are not read
COMMAND_PARAMS: dict[int, tuple[tuple[int, ...], tuple[int, ...]]] = {
    mav.MAV_CMD_COMPONENT_ARM_DISARM: ((0,), (1,)),
    mav.MAV_CMD_DO_SET_MODE: ((0, 1), (2,)),
    mav.MAV_CMD_SET_MESSAGE_INTERVAL: ((0, 1), ()),
    mav.MAV_CMD_REQUEST_MESSAGE: ((0,), ()),
    mav.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES: ((0,), ()),
    mav.MAV_CMD_GET_HOME_POSITION: ((), ()),
}
PEER_SILENT_S = 3.0  #: wall time a peer must be silent before another address may take the link [s]
FORCE_DISARM = 21196  #: MAV_CMD_COMPONENT_ARM_DISARM param2 that forces a disarm (PX4's magic number)


@dataclass(frozen=True)
class TelemetryRates:
    """Stream rates [Hz], PX4-like defaults (0 = off)."""

    local_position_hz: float = 50.0
    attitude_hz: float = 50.0
    attitude_quaternion_hz: float = 50.0
    attitude_target_hz: float = 10.0
    imu_hz: float = 50.0
    sys_status_hz: float = 1.0
    global_position_hz: float = 5.0
    gps_raw_hz: float = 1.0
    extended_sys_state_hz: float = 1.0
    home_position_hz: float = 0.5
    heartbeat_hz: float = 1.0  #: on the wall clock, in both clock modes

    def by_message(self) -> dict[int, float]:
        return {
            mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED: self.local_position_hz,
            mav.MAVLINK_MSG_ID_ATTITUDE: self.attitude_hz,
            mav.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: self.attitude_quaternion_hz,
            mav.MAVLINK_MSG_ID_ATTITUDE_TARGET: self.attitude_target_hz,
            mav.MAVLINK_MSG_ID_HIGHRES_IMU: self.imu_hz,
            mav.MAVLINK_MSG_ID_SYS_STATUS: self.sys_status_hz,
            mav.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: self.global_position_hz,
            mav.MAVLINK_MSG_ID_GPS_RAW_INT: self.gps_raw_hz,
            mav.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: self.extended_sys_state_hz,
            mav.MAVLINK_MSG_ID_HOME_POSITION: self.home_position_hz,
        }


#: a ground-station port's default rates: PX4's "normal" MAVLink mode (``mavlink_main.cpp``)
GCS_RATES = TelemetryRates(
    local_position_hz=1.0,
    attitude_hz=15.0,
    attitude_quaternion_hz=10.0,
    attitude_target_hz=2.0,
    imu_hz=0.0,
    sys_status_hz=1.0,
    global_position_hz=5.0,
    gps_raw_hz=1.0,
    extended_sys_state_hz=1.0,
    home_position_hz=0.5,
)
#: what each port of the vehicle has of its own (``_swap``): socket, packer (its sequence), what
#: is queued, its peer, its stream table and rates, its signing, its parser
_PORT_STATE = (
    "sock",
    "address",
    "mav",
    "_sink",
    "_parser",
    "peer",
    "_peer_heard_wall",
    "_accepted",
    "_accepted_from",
    "_rate_hz",
    "_defaults",
    "_next_send",
    "_next_any_s",
    "_next_other_s",
    "_signer",
    "_verifier",
    "_stamped",
    "_waiting",
)
MAX_DATAGRAM = 1200  #: bytes; below any loopback or Ethernet MTU
RX_EVERY_S = 0.01  #: real time, offboard: longest a datagram waits to be read [s]
LOCKSTEP_WAIT_S = 0.2  #: lockstep: longest wait for a datagram before the heartbeat is checked [s]
#: lockstep: how often the ground-station port is looked at between setpoints [s of wall clock]
#: (every setpoint, a system call per tick that nearly always finds nothing)
LOCKSTEP_GCS_EVERY_S = 0.005


#: a truth log's columns: the vehicle's boot time [s], then its true state (``common.state``)
TRUTH_COLUMNS = ["time_boot_s", *STATE_COLUMNS]


class _Setpoint(NamedTuple):
    """SET_ATTITUDE_TARGET as read off the wire, its fields converted (``command_from_fields``)."""

    time_boot_ms: int
    target_system: int
    target_component: int
    type_mask: int
    command: np.ndarray  #: ``wire_format.command_from_fields`` (ENU/FLU, thrust [N], valid flag)


_SETPOINT = frames.SET_ATTITUDE_TARGET
_SP_VALID = tick_frames.SP_COMMAND.start + CMD_VALID  #: ``read_setpoint``'s command is valid


def _next_due(t_s: float, rate_hz: float) -> float:
    """When a stream of ``rate_hz`` sent at ``t_s`` is next due: the next multiple of its period
    in boot time, so streams of one rate share their instants."""
    return (math.floor(t_s * rate_hz + 1e-6) + 1) / rate_hz


@dataclass
class EndpointStats:
    """What the vehicle received and what it did with it (the module doc says what each counts)."""

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


FTP_NAK = 129  #: MAVLink FTP's NAK opcode
FTP_OPEN_FILE_RO = 4
FTP_FILE_NOT_FOUND, FTP_UNKNOWN_COMMAND = 10, 7


def ftp_nak(request: bytes) -> list[int]:
    """The payload of MAVLink FTP's NAK to ``request`` (the vehicle has no files): the request's
    sequence + 1, its session, NAK, one data byte (FileNotFound to an open, else UnknownCommand)."""
    seq = (request[0] | request[1] << 8) + 1 & 0xFFFF
    error = FTP_FILE_NOT_FOUND if request[3] == FTP_OPEN_FILE_RO else FTP_UNKNOWN_COMMAND
    head = [seq & 0xFF, seq >> 8, request[2], FTP_NAK, 1, request[3], 0, 0, 0, 0, 0, 0, error]
    return head + [0] * (251 - len(head))


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
    lockstep_period_s: float | None = None  #: None: real time; else simulated time per setpoint
    truth_path: Path | None = None  #: write the true state at every LOCAL_POSITION_NED instant
    failsafe_action: int = ACTION_HOLD  #: ``failsafe.ACTION_*`` (parameter COM_OBL_ACT)
    events_path: Path | None = None  #: write failsafe events here (``event_log``)
    signing_key: bytes | None = None  #: MAVLink 2 signing on this link (``mavlink_signing``)
    home: px4.Home = field(default_factory=px4.Home)  #: where the local frame's origin is on the earth
    #: a ground station's own port (``None``: none), with its own peer and stream rates
    gcs_bind: tuple[str, int] | None = None
    gcs_rates: TelemetryRates = GCS_RATES
    #: where the ground-station port sends until someone speaks to it (PX4 sends to 14550)
    gcs_remote: tuple[str, int] | None = None

    def __post_init__(self) -> None:
        self._lockstep_steps = 0
        if self.lockstep_period_s is not None:
            n = self.lockstep_period_s / self.autopilot.dt_s
            ms = self.lockstep_period_s * 1000
            if not (round(n) >= 1 and abs(n - round(n)) < 1e-9 and abs(ms - round(ms)) < 1e-9):
                raise ValueError(
                    f"lockstep period {self.lockstep_period_s} s must be a whole number of attitude "
                    f"steps ({self.autopilot.dt_s} s) and of milliseconds"
                )
            self._lockstep_steps = round(n)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(self.bind)
        self.sock.setblocking(False)
        self.address = self.sock.getsockname()
        #: real time: datagrams carry the kernel's arrival stamp, so the loop may read them late
        self._stamped = self.lockstep_period_s is None and udp_arrival.enable(self.sock)
        self._waiting = udp_arrival.Waiting(self.sock)
        self._sink = _Sink()
        self.mav = mav.MAVLink(self._sink, srcSystem=self.system_id, srcComponent=mav.MAV_COMP_ID_AUTOPILOT1)
        self._parser = mav.MAVLink(None, srcSystem=255, srcComponent=0)
        self._parser.robust_parsing = True
        self.peer: tuple[str, int] | None = None
        self._signer = Signer(self.signing_key) if self.signing_key else None
        self._verifier = Verifier(self.signing_key) if self.signing_key else None
        self._peer_heard_wall = -math.inf  #: when the peer last sent [s; time.monotonic]
        self._accepted = 0  #: well-formed messages it knows, addressed to it, from anyone heard
        self._accepted_from = (0, 0)  #: (system, component) of the last of them
        self.armed = False
        self.mode = MODE_HOLD
        self.stats = EndpointStats()
        self._last_setpoint_s = -math.inf
        #: the last SET_ATTITUDE_TARGET for it, valid or clock-only [s; simulated]: PX4 accepts
        #: OFFBOARD only while a setpoint stream runs
        self._offboard_signal_s = -math.inf
        #: simulated time each stream is next due (0: now; inf: off), in the order they are sent
        self._next_send: dict[int, float] = {}
        self._tlog: BinaryIO | None = open(self.tlog_path, "wb") if self.tlog_path else None  # noqa: SIM115
        self._truth = RowLog(self.truth_path, TRUTH_COLUMNS) if self.truth_path else None
        self._defaults = self.rates.by_message()
        if self.lockstep_period_s is not None:  # in lockstep the sample follows every period
            for msg_id in (mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED, mav.MAVLINK_MSG_ID_ATTITUDE_QUATERNION):
                self._defaults[msg_id] = max(self._defaults[msg_id], 1.0 / self.lockstep_period_s)
        self._rate_hz = dict(self._defaults)
        self._next_send = dict.fromkeys(self._defaults, 0.0)
        self._senders: dict[int, Callable[[int], None]] = {
            mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED: self._send_local_position,
            mav.MAVLINK_MSG_ID_ATTITUDE: self._send_attitude,
            mav.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: self._send_attitude_quaternion,
            mav.MAVLINK_MSG_ID_ATTITUDE_TARGET: self._send_attitude_target,
            mav.MAVLINK_MSG_ID_HIGHRES_IMU: self._send_imu,
            mav.MAVLINK_MSG_ID_SYS_STATUS: self._send_sys_status,
            mav.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: self._send_global_position,
            mav.MAVLINK_MSG_ID_GPS_RAW_INT: self._send_gps_raw,
            mav.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: self._send_extended_sys_state,
            mav.MAVLINK_MSG_ID_HOME_POSITION: self._send_home_position,
        }
        #: sent on request only (MAV_CMD_REQUEST_MESSAGE, or their own commands)
        self._on_request: dict[int, Callable[[int], None]] = {
            **self._senders,
            mav.MAVLINK_MSG_ID_AUTOPILOT_VERSION: self._send_autopilot_version,
        }
        self._next_heartbeat_wall = -math.inf
        self._next_any_s = 0.0  #: simulated time of the next telemetry message due
        self._next_other_s = 0.0  #: ... of the next one but LOCAL_POSITION_NED and ATTITUDE_QUATERNION
        self._out = np.zeros(tick_frames.FRAME_BYTES, np.uint8)
        self._sample_out = np.zeros(lockstep_tick.SAMPLE_BYTES, np.uint8)
        p = self.autopilot.params
        self.params: dict[str, float] = {
            "MASS_KG": p.mass_kg,
            "INERTIA_X": p.inertia_kgm2[0],
            "INERTIA_Y": p.inertia_kgm2[1],
            "INERTIA_Z": p.inertia_kgm2[2],
            "MAX_THRUST_N": p.max_thrust_N,
            "SP_TIMEOUT_S": self.setpoint_timeout_s,
            "COM_OBL_ACT": float(self.failsafe_action),
            **{name: math.degrees(w) for name, w in zip(RATE_MAX_PARAMS, p.max_rate_rps, strict=True)},
        }
        self._on_gcs = False  #: the ground-station port's state is swapped in (``_gcs_port``)
        self._gcs: dict[str, Any] | None = None
        if self.gcs_bind is not None:
            self._gcs = self._new_port(self.gcs_bind, self.gcs_rates, self.gcs_remote)
        self.events = EventLog(self.events_path, f"vehicle_{self.system_id}")
        self._hold = hold_at(self.autopilot.state, 0.0)
        self._fs_steps = max(1, round(FAILSAFE_PERIOD_S / self.autopilot.dt_s))
        self._fs_next = 0  #: attitude step at which the failsafe's position loop runs next

    # -- the ground-station port ---------------------------------------------------------------
    def _new_port(
        self, bind: tuple[str, int], rates: TelemetryRates, remote: tuple[str, int] | None
    ) -> dict[str, Any]:
        """The state of a second port (``_PORT_STATE``), as ``__post_init__`` builds the first."""
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.bind(bind)
        sock.setblocking(False)
        sink = _Sink()
        parser = mav.MAVLink(None, srcSystem=255, srcComponent=0)
        parser.robust_parsing = True
        defaults = rates.by_message()
        return {
            "sock": sock,
            "address": sock.getsockname(),
            "mav": mav.MAVLink(sink, srcSystem=self.system_id, srcComponent=mav.MAV_COMP_ID_AUTOPILOT1),
            "_sink": sink,
            "_parser": parser,
            "peer": remote,
            "_peer_heard_wall": -math.inf,
            "_accepted": 0,
            "_accepted_from": (0, 0),
            "_rate_hz": dict(defaults),
            "_defaults": defaults,
            "_next_send": dict.fromkeys(defaults, 0.0),
            "_next_any_s": 0.0,
            "_next_other_s": 0.0,
            "_signer": Signer(self.signing_key) if self.signing_key else None,
            "_verifier": Verifier(self.signing_key) if self.signing_key else None,
            "_stamped": False,
            "_waiting": udp_arrival.Waiting(sock),
        }

    def _swap(self, state: dict[str, Any]) -> dict[str, Any]:
        """Put ``state`` in place of the current port's; returns the one it replaced."""
        old = {name: getattr(self, name) for name in _PORT_STATE}
        for name, value in state.items():
            setattr(self, name, value)
        return old

    @contextlib.contextmanager
    def _gcs_port(self) -> Iterator[None]:
        """Act as the ground-station port: what is sent, streamed and answered inside goes to it,
        at its rates, and a command's reply to its sender there. The controller's port is the
        one in place otherwise (no cost on its per-tick path)."""
        assert self._gcs is not None
        main = self._swap(self._gcs)
        self._on_gcs = True
        try:
            yield
        finally:
            self._on_gcs = False
            self._gcs = self._swap(main)

    @property
    def gcs_address(self) -> tuple[str, int] | None:
        return None if self._gcs is None else self._gcs["address"]

    def poll_gcs(self) -> None:
        """Handle what waits on the ground-station port (at the current state), answer it there."""
        if self._gcs is not None and self._gcs["_waiting"]():
            with self._gcs_port():
                try:
                    self._receive(None, False)
                finally:
                    self.flush()

    def _stream_gcs(self) -> None:
        """The ground-station port's streams, once it has someone to send them to (``gcs_remote``
        or a ground station that spoke): until then there is nothing to pack."""
        gcs = self._gcs
        if gcs is not None and gcs["peer"] is not None and self.autopilot.time_s + 1e-9 >= gcs["_next_any_s"]:
            with self._gcs_port():
                self._stream()
                self.flush()

    # -- I/O -------------------------------------------------------------------------------------
    def _log(self, frame: bytes) -> None:
        """One received frame into the ``.tlog``, stamped now."""
        if self._tlog is not None:
            self._tlog.write(self._tlog_stamp() + frame)

    @staticmethod
    def _tlog_stamp() -> bytes:
        return struct.pack(">Q", int(time.time() * 1e6))

    def _send(self, msg: Any) -> None:
        """Queue one message; ``flush`` sends what is queued."""
        self.mav.send(msg)

    def _send_fields(self, layout: frames.Layout, values: tuple[float, ...] | list[float]) -> None:
        """Queue one telemetry message from its field values (``mavlink_frames``: the same bytes
        as ``_send``, without building a message object)."""
        self._sink.frames.append(frames.pack_frame(self.mav, layout, values))

    def _send_sample_part(self, pack: Callable[..., int], layout: frames.Layout, ms: int) -> None:
        """Queue LOCAL_POSITION_NED or ATTITUDE_QUATERNION of the current state, converted and
        packed in one compiled call (``tick_frames``). Plain, like every frame queued: ``flush``
        signs what it sends on a signed link."""
        n = pack(
            self._out,
            self.mav.seq,
            self.system_id,
            mav.MAV_COMP_ID_AUTOPILOT1,
            layout.spec,
            ms,
            self.autopilot.state,
        )
        self._sink.frames.append(frames.take_frame(self.mav, self._out, n))

    def flush(self) -> None:
        """Send the queued frames to the peer, packed into as few datagrams as fit (as PX4 does):
        a telemetry pass is one datagram, one wake-up of the receiver."""
        frames = self._sink.frames
        if not frames:
            return
        if self._tlog is not None:  # one write, one stamp, for the pass
            stamp = self._tlog_stamp()
            self._tlog.write(b"".join([stamp + frame for frame in frames]))
        if self.peer is not None:
            self.stats.tx_messages += len(frames)
            joined = b"".join(frames)
            signatures = SIGNATURE_LEN * len(frames) if self._signer is not None else 0
            if len(joined) + signatures <= MAX_DATAGRAM:  # the usual pass: signed in one call
                self.sock.sendto(self._sealed(joined), self.peer)
            else:
                packet = b""
                for frame in map(self._sealed, frames):
                    if len(packet) + len(frame) > MAX_DATAGRAM:
                        self.sock.sendto(packet, self.peer)
                        packet = b""
                    packet += frame
                self.sock.sendto(packet, self.peer)
        self._sink.frames.clear()

    def _sealed(self, frames: bytes) -> bytes:
        """``frames`` signed on a signed link (``mavlink_signing``), else as they are."""
        return frames if self._signer is None else self._signer.seal(frames)

    def close(self) -> None:
        self.sock.close()
        if self._gcs is not None:
            self._gcs["sock"].close()
        self.events.close()
        if self._tlog is not None:
            self._tlog.close()
            self._tlog = None
        if self._truth is not None:
            self._truth.close()
            self._truth = None

    @property
    def time_boot_ms(self) -> int:
        return round(self.autopilot.time_s * 1000)

    # -- receive ---------------------------------------------------------------------------------
    def poll(self, at_arrival: Callable[[float], None] | None = None, readable: bool = False) -> None:
        """Handle every datagram waiting on the socket, then send what that produced.
        ``at_arrival(t)`` runs before each datagram with its arrival [s; ``time.monotonic``].
        ``readable``: a ``select`` has just said so (the first read needs no check)."""
        try:
            self._receive(at_arrival, readable)
        finally:
            self.flush()

    def _receive(self, at_arrival: Callable[[float], None] | None, readable: bool) -> None:
        wall_to_mono = udp_arrival.wall_to_monotonic_s() if self._stamped else 0.0
        while readable or self._waiting():
            readable = False
            try:
                if self._stamped:
                    data, addr, arrival = udp_arrival.recv(self.sock, wall_to_mono, 4096)
                else:
                    data, addr = self.sock.recvfrom(4096)
                    arrival = 0.0 if at_arrival is None else time.monotonic()  # unstamped: read now
            except OSError:  # an ICMP error, or nothing after all
                return
            if at_arrival is not None:
                at_arrival(arrival)
            self._datagram(data, addr)

    def _may_speak(self, addr: Any) -> bool:
        """Whether a datagram from ``addr`` is heard: from the peer, or from anyone while there is
        none or it has been silent for ``PEER_SILENT_S``."""
        if addr == self.peer or self._peer_silent(time.monotonic()):
            return True
        self.stats.rx_refused += 1
        return False

    def _peer_silent(self, now: float) -> bool:
        """No peer, or none heard for ``PEER_SILENT_S`` (``now``: ``time.monotonic``)."""
        return now - self._peer_heard_wall > PEER_SILENT_S

    def _heard(self, addr: Any, signed: bool) -> None:
        """``addr`` sent a well-formed message addressed to the vehicle. The peer it is, or becomes
        (with a heartbeat) if there is none or it has been silent ``PEER_SILENT_S``; on a signed
        link also if it speaks as the vehicle's companion computer (a restarted controller). Any
        other signed sender is heard, and its commands taken, but the telemetry stays with the peer."""
        now = time.monotonic()
        if addr != self.peer:
            companion = self._accepted_from == (self.system_id, COMPANION)
            if not (self._peer_silent(now) or (signed and companion)):
                return
            self.peer = addr
            self.send_heartbeat()
        self._peer_heard_wall = now

    def _datagram(self, data: bytes, addr: Any) -> None:
        """Handle one datagram from ``addr`` (what it makes the vehicle send waits for ``flush``)."""
        if self._verifier is not None:  # signed: whoever holds the key may speak
            v = self._verifier
            bad = v.bad
            opened = v.open(data)
            if opened is None:
                if v.bad > bad:
                    self.stats.rx_bad += 1
                else:  # unsigned, or a replay
                    self.stats.rx_refused += 1
                return
            data = opened
        elif not self._may_speak(addr):
            return
        if not data:  # an empty datagram is no frame
            self.stats.rx_bad += 1
            return
        accepted = self._accepted
        try:
            self._frames(data)
        finally:
            if self._accepted > accepted:
                self._heard(addr, self._verifier is not None)

    def _frames(self, data: bytes) -> None:
        """Handle a datagram of plain frames (a signed one is checked and unsigned before)."""
        r = tick_frames.read_setpoint(data, _SETPOINT.spec, self.autopilot.params.max_thrust_N)
        if r[0] and self._on_gcs:  # setpoints come on the controller's port only
            self._log(data)
            self.stats.rx_messages += 1
            self.stats.rx_refused += 1
            return
        if r[0]:  # one SET_ATTITUDE_TARGET and nothing else: what a controller sends
            self._log(data)
            self.stats.rx_messages += 1
            if self._usual_tick(r):
                return
            sp = _Setpoint(
                int(r[tick_frames.SP_TIME_MS]),
                int(r[tick_frames.SP_TARGET_SYSTEM]),
                int(r[tick_frames.SP_TARGET_COMPONENT]),
                int(r[tick_frames.SP_TYPE_MASK]),
                r[tick_frames.SP_COMMAND],
            )
            if self._for_me(sp):
                self._accepted += 1
                self._accepted_from = (int(r[tick_frames.SP_SYSID]), int(r[tick_frames.SP_COMPID]))
                self._on_setpoint(sp)
            else:
                self.stats.rx_refused += 1
            return
        fast = frames.read_datagram(data, {})
        if fast is not None:
            for _id, _sys, _comp, _values, frame in fast:
                self._log(frame)
                self.stats.rx_messages += 1
                try:
                    m = self._parser.decode(bytearray(frame))
                except Exception:  # pymavlink's own errors and struct errors: drop, count
                    self.stats.rx_bad += 1
                    continue
                self._handle_safely(m)
            return
        try:
            msgs = self._parser.parse_buffer(data) or []
        except Exception:  # pymavlink raises its own and struct errors on garbage: drop, count
            msgs = None
        if msgs is None or self._parser.buf_len():  # garbage, or a frame cut short by its datagram
            self.stats.rx_bad += 1
            frames.reset_parser(self._parser)  # a datagram ends every frame in it: nothing carries over
            if msgs is None:
                return
        for m in msgs:
            self._log(m.get_msgbuf())
            self.stats.rx_messages += 1
            if m.get_type() == "BAD_DATA":
                self.stats.rx_bad += 1
                continue
            self._handle_safely(m)

    def _usual_tick(self, r: np.ndarray) -> bool:
        """Take a setpoint (``tick_frames.read_setpoint``'s ``r``) as a lockstep tick in one
        compiled call (``lockstep_tick``) if it is the usual one: for this vehicle, stamped with its
        current time, every field taken and valid, the vehicle armed in offboard, and nothing but
        the sample due when the period ends. The books are kept as ``_on_setpoint``, ``step`` and
        ``_stream`` keep them, and the state and frames are theirs bit for bit. False: not the
        usual tick (the general path takes it)."""
        if not (self._lockstep_steps and self.armed and self.mode == MODE_OFFBOARD):
            return False
        v = r.tolist()  # Python floats: cheaper to compare than numpy's scalars
        if not (
            v[tick_frames.SP_TYPE_MASK] == 0
            and v[_SP_VALID]
            and self._addressed(v[tick_frames.SP_TARGET_SYSTEM], v[tick_frames.SP_TARGET_COMPONENT])
        ):
            return False
        ap = self.autopilot
        t0 = ap.time_s
        k1 = ap.step_index + self._lockstep_steps
        t1 = k1 * ap.dt_s
        next_send = self._next_send
        if not (
            v[tick_frames.SP_TIME_MS] == round(t0 * 1000)
            and t1 - t0 <= self.setpoint_timeout_s  # else its failsafe would begin: ``step``'s
            and t1 + 1e-9 < self._next_other_s
            and next_send[LPOS_ID] <= t1 + 1e-9
            and next_send[ATTQ_ID] <= t1 + 1e-9
        ):
            return False
        self._accepted += 1
        self._accepted_from = (int(v[tick_frames.SP_SYSID]), int(v[tick_frames.SP_COMPID]))
        self._offboard_signal_s = self._last_setpoint_s = t0
        self.stats.setpoints += 1
        ap.set_command(command_of(r[tick_frames.SP_COMMAND]), kernel_ready=True)  # views of ``r``
        link, out = self.mav, self._sample_out
        x, end_lpos, end_attq = lockstep_tick.step_and_sample(
            ap.state,
            ap.kernel_args,
            self._lockstep_steps,
            out,
            link.seq,
            self.system_id,
            COMPONENT,
            frames.LOCAL_POSITION_NED.spec,
            frames.ATTITUDE_QUATERNION.spec,
            round(t1 * 1000),
        )
        ap.state = x
        ap.step_index = k1
        sent = self._sink.frames
        sent.append(frames.take_frame(link, out, end_lpos))
        sent.append(frames.take_frame(link, out, end_attq, end_lpos))
        for msg_id in (LPOS_ID, ATTQ_ID):
            next_send[msg_id] = _next_due(t1, self._rate_hz[msg_id])
        self._next_any_s = min(next_send[LPOS_ID], next_send[ATTQ_ID], self._next_other_s)
        if self._truth is not None:
            self._truth.append((t1,), x)
        self.flush()
        self._stream_gcs()
        return True

    def _for_me(self, m: Any) -> bool:
        """Addressed to this vehicle (a message with a target system and no target component is
        for the system)."""
        return self._addressed(m.target_system, getattr(m, "target_component", 0))

    def _addressed(self, target_system: float, target_component: float) -> bool:
        """Whether a target system and component (0: any) are this vehicle's autopilot."""
        return target_system in (0, self.system_id) and target_component in (0, COMPONENT)

    def _handle_safely(self, m: Any) -> None:
        """``_handle``, counting a message addressed elsewhere, and a handler's failure (a bug the
        message found: counted and kept in ``stats``, the vehicle flies on)."""
        if hasattr(m, "target_system") and not self._for_me(m):
            self.stats.rx_refused += 1
            return
        unhandled = self.stats.rx_unhandled
        try:
            self._handle(m)
        except Exception as e:
            self.stats.handler_errors += 1
            self.stats.last_handler_error = f"{m.get_type()}: {type(e).__name__}: {e}"
        if self.stats.rx_unhandled == unhandled:  # a message it does not know claims no link
            self._accepted += 1
            self._accepted_from = (m.get_srcSystem(), m.get_srcComponent())

    def _handle(self, m: Any) -> None:
        t = m.get_type()
        if t == "SET_ATTITUDE_TARGET" and self._on_gcs:  # setpoints: the controller's port only
            self.stats.rx_refused += 1
        elif t == "SET_ATTITUDE_TARGET":
            fields = np.array(
                [*m.q, m.body_roll_rate, m.body_pitch_rate, m.body_yaw_rate, m.thrust], dtype=float
            )
            decoded = command_from_fields(fields, self.autopilot.params.max_thrust_N)
            self._on_setpoint(
                _Setpoint(m.time_boot_ms, m.target_system, m.target_component, m.type_mask, decoded)
            )
        elif t == "COMMAND_LONG":
            self._on_command(m)
        elif t == "PARAM_REQUEST_LIST":
            for i, name in enumerate(self.params):
                self._send_param(name, i)
        elif t == "PARAM_SET":
            self._on_param_set(m)
        elif t == "PARAM_REQUEST_READ":
            names = list(self.params)
            name = (
                m.param_id
                if m.param_index < 0
                else (names[m.param_index] if m.param_index < len(names) else "")
            )
            if name in self.params:
                self._send_param(name, names.index(name))
        elif t == "PING" and m.target_system == 0:  # a request: answered to its sender
            self._send(self.mav.ping_encode(m.time_usec, m.seq, m.get_srcSystem(), m.get_srcComponent()))
        elif t == "FILE_TRANSFER_PROTOCOL":  # no file system: a NAK, so a tool falls back at once
            self._send(
                self.mav.file_transfer_protocol_encode(
                    0, m.get_srcSystem(), m.get_srcComponent(), ftp_nak(bytes(m.payload))
                )
            )
        elif t == "MISSION_REQUEST_LIST":  # no mission: an empty list
            self._send(
                self.mav.mission_count_encode(m.get_srcSystem(), m.get_srcComponent(), 0, m.mission_type)
            )
        elif t != "HEARTBEAT":  # a peer's heartbeat needs no answer
            self.stats.rx_unhandled += 1

    def _on_param_set(self, m: Any) -> None:
        """Set a parameter that may change in flight (``SETTABLE``, within its range); anything else
        is refused and counted. Answered with PARAM_VALUE of what the vehicle keeps, as PX4 does."""
        name = m.param_id
        if name not in self.params:
            self.stats.rx_invalid += 1
            return
        lo, hi = SETTABLE.get(name, (math.nan, math.nan))
        value = float(m.param_value)
        if lo <= value <= hi:
            self.params[name] = value
            self._apply_param(name, value)
        else:
            self.stats.rx_invalid += 1
        self._send_param(name, list(self.params).index(name))

    def _apply_param(self, name: str, value: float) -> None:
        if name == "SP_TIMEOUT_S":
            self.setpoint_timeout_s = value
        elif name == "COM_OBL_ACT":
            self.failsafe_action = round(value)
        elif name in RATE_MAX_PARAMS:
            self.autopilot.max_rate_rps[RATE_MAX_PARAMS.index(name)] = math.radians(value)

    def _send_param(self, name: str, index: int) -> None:
        self._send(
            self.mav.param_value_encode(
                name.encode(), float(self.params[name]), mav.MAV_PARAM_TYPE_REAL32, len(self.params), index
            )
        )

    def _on_command(self, m: Any) -> None:
        cmd = m.command
        params: tuple[float, ...] = (m.param1, m.param2, m.param3, m.param4, m.param5, m.param6, m.param7)

        def ack(result: int) -> None:  # to the sender, as PX4 addresses it
            self._send(
                self.mav.command_ack_encode(cmd, result, 0, 0, m.get_srcSystem(), m.get_srcComponent())
            )

        if cmd not in COMMAND_PARAMS:
            self.stats.rx_unhandled += 1
            ack(mav.MAV_RESULT_UNSUPPORTED)
            return
        used, optional = COMMAND_PARAMS[cmd]
        if not all(math.isfinite(params[j]) for j in used) or any(math.isinf(params[j]) for j in optional):
            self.stats.rx_invalid += 1
            ack(mav.MAV_RESULT_DENIED)
            return
        params = tuple(0.0 if j in optional and math.isnan(v) else v for j, v in enumerate(params))
        p1, p2 = params[0], params[1]
        result = mav.MAV_RESULT_ACCEPTED
        if cmd == mav.MAV_CMD_COMPONENT_ARM_DISARM:
            arm = p1 >= 0.5
            if self.armed and not arm and round(p2) != FORCE_DISARM:
                self.stats.rx_invalid += 1
                result = mav.MAV_RESULT_DENIED  # PX4 refuses to disarm in flight unless forced
            else:
                if arm and not self.armed and self.mode == MODE_HOLD:
                    self._hold_here()  # armed in Hold: it holds where it is
                self.armed = arm
        elif cmd == mav.MAV_CMD_DO_SET_MODE:
            result = self._set_mode(px4.requested_mode(p1, p2, params[2]))
        elif cmd == mav.MAV_CMD_SET_MESSAGE_INTERVAL and p1 in self._rate_hz:
            msg_id, us = int(p1), p2
            self._rate_hz[msg_id] = (
                self._defaults[msg_id] if us == 0 else (0.0 if us < 0 else 1e6 / max(us, 1.0))
            )
            self._next_send[msg_id] = 0.0
            self._next_any_s = self._next_other_s = 0.0
        elif cmd == mav.MAV_CMD_REQUEST_MESSAGE and p1 in self._on_request:
            ack(result)  # the ack first, then the message, as PX4 does
            self._on_request[int(p1)](self.time_boot_ms)
            return
        elif cmd in ASKS:
            ack(result)
            self._on_request[ASKS[cmd]](self.time_boot_ms)
            return
        else:  # a message this vehicle does not have
            self.stats.rx_invalid += 1
            result = mav.MAV_RESULT_DENIED
        ack(result)

    def _set_mode(self, wanted: int | None) -> int:
        """MAV_CMD_DO_SET_MODE to PX4's ``wanted`` custom mode: Hold (AUTO.LOITER), or OFFBOARD
        while a setpoint stream runs (PX4's rule: setpoints within SP_TIMEOUT_S); the result."""
        if wanted == px4.HOLD:
            mode = MODE_HOLD
        elif wanted == px4.OFFBOARD:
            if self.autopilot.time_s - self._offboard_signal_s > self.setpoint_timeout_s:
                return mav.MAV_RESULT_TEMPORARILY_REJECTED  # no setpoint stream yet
            mode = MODE_OFFBOARD
        else:  # a mode this vehicle does not have
            self.stats.rx_invalid += 1
            return mav.MAV_RESULT_DENIED
        if self.mode == MODE_FAILSAFE:
            self._event("failsafe_exit", vehicle=self.system_id)
        if mode == MODE_HOLD and self.mode != MODE_HOLD:
            self._hold_here()
        self.mode = mode
        self._last_setpoint_s = self.autopilot.time_s if mode == MODE_OFFBOARD else -math.inf
        return mav.MAV_RESULT_ACCEPTED

    def _hold_here(self) -> None:
        """Hold (PX4's AUTO.LOITER) from now: a position hold where it is, by its own loop."""
        ap = self.autopilot
        self._hold = hold_at(ap.state, ap.time_s)
        self._fs_next = ap.step_index

    def _on_setpoint(self, m: "_Setpoint") -> None:
        ap = self.autopilot
        if self.lockstep_period_s is None or m.time_boot_ms <= self.time_boot_ms:
            self._offboard_signal_s = ap.time_s  # a stream runs (a future stamp is refused below)
        if self.lockstep_period_s is not None:
            now_ms = self.time_boot_ms
            if m.time_boot_ms < now_ms or (m.type_mask == IGNORE_ALL and m.time_boot_ms == now_ms):
                # a retransmission (the sample it waits for was lost), or a clock already there
                self.stats.lockstep_resends += 1
                self._send_local_position(now_ms)
                self._send_attitude_quaternion(now_ms)
                return
            if m.type_mask == IGNORE_ALL:  # clock only: catch up to the stamp, period by period
                if m.time_boot_ms - now_ms > MAX_CLOCK_STEP_S * 1000:
                    self.stats.rx_bad += 1
                    return
                while self.time_boot_ms < m.time_boot_ms:
                    self.step(self._lockstep_steps)
                return
            if m.time_boot_ms > now_ms:
                self.stats.rx_bad += 1
                return
        cur = ap.command
        mask = m.type_mask
        if not m.command[CMD_VALID]:  # not a rotation, or a non-finite rate or thrust
            self.stats.rx_bad += 1
            if self.lockstep_period_s is not None:
                self.step(self._lockstep_steps)  # the clock still advances; the old command is held
            return
        new = command_of(m.command)
        if mask & (IGNORE_ATTITUDE | IGNORE_THROTTLE) or mask & IGNORE_RATES == IGNORE_RATES:
            cmd = AttitudeCommand(
                q_c=cur.q_c if mask & IGNORE_ATTITUDE else new.q_c,
                thrust_N=cur.thrust_N if mask & IGNORE_THROTTLE else new.thrust_N,
                omega_c_B=np.zeros(3) if mask & IGNORE_RATES == IGNORE_RATES else new.omega_c_B,
            )
        else:  # every field taken (what a position controller sends)
            cmd = new
        self.stats.setpoints += 1
        self._last_setpoint_s = ap.time_s
        if self.mode == MODE_FAILSAFE:
            self._event("failsafe_exit", vehicle=self.system_id)
            self._statustext(mav.MAV_SEVERITY_NOTICE, "Failsafe cleared: offboard setpoints back")
        if self.mode in (MODE_OFFBOARD, MODE_FAILSAFE):
            self.mode = MODE_OFFBOARD
            ap.set_command(cmd)
        if self.lockstep_period_s is not None:
            self.step(self._lockstep_steps)

    # -- simulate --------------------------------------------------------------------------------
    def _event(self, kind: str, **fields: Any) -> None:
        """An event at the vehicle's boot time, with the UNIX time for a real-time run's clock."""
        self.events.add(self.autopilot.time_s, kind, unix_s=time.time(), **fields)

    def _statustext(self, severity: int, text: str) -> None:
        """A STATUSTEXT now, to the controller and to the ground station (sent with their next
        pass)."""
        self._send(self.mav.statustext_encode(severity, text.encode()[:50]))
        if self._gcs is not None and not self._on_gcs:
            gcs_mav = self._gcs["mav"]
            gcs_mav.send(gcs_mav.statustext_encode(severity, text.encode()[:50]))

    def _failsafe_check(self) -> None:
        ap = self.autopilot
        if self.mode == MODE_OFFBOARD and ap.time_s - self._last_setpoint_s > self.setpoint_timeout_s:
            self.mode = MODE_FAILSAFE
            self._hold = hold_at(ap.state, ap.time_s)
            self._fs_next = ap.step_index
            action = "land" if self.failsafe_action != ACTION_HOLD else "hold"
            self._event("failsafe_enter", vehicle=self.system_id, action=action, p_W=self._hold.p_W.tolist())
            self._statustext(mav.MAV_SEVERITY_WARNING, f"Failsafe: offboard setpoints lost, {action}")

    def step(self, n_steps: int = 1) -> None:
        """Advance ``n_steps`` attitude steps under the held command (held still while disarmed),
        checking the setpoint timeout; in failsafe the failsafe's position loop sets the command
        every ``FAILSAFE_PERIOD_S``. Then stream what is due."""
        ap = self.autopilot
        if not self.armed:
            ap.step_index += n_steps
            self._failsafe_check()
        left = n_steps if self.armed else 0
        while left > 0:
            chunk = left
            if self.mode in (MODE_FAILSAFE, MODE_HOLD):
                if ap.step_index >= self._fs_next:
                    action = self.failsafe_action if self.mode == MODE_FAILSAFE else ACTION_HOLD
                    ap.set_command(failsafe_command(ap.state, self._hold, ap.time_s, action, ap.params))
                    self._fs_next = ap.step_index + self._fs_steps
                chunk = min(left, self._fs_next - ap.step_index)
            ap.advance(chunk)
            left -= chunk
            self._failsafe_check()
        self._stream()
        self.flush()
        self._stream_gcs()

    def px4_mode(self) -> int:
        """The mode as PX4 reports it in ``custom_mode``: the failsafe as what it flies."""
        if self.mode == MODE_OFFBOARD:
            return px4.OFFBOARD
        if self.mode == MODE_FAILSAFE and self.failsafe_action != ACTION_HOLD:
            return px4.LAND
        return px4.HOLD

    def send_heartbeat(self) -> None:
        base = px4.BASE_FLAGS | (mav.MAV_MODE_FLAG_SAFETY_ARMED if self.armed else 0)
        status = (
            mav.MAV_STATE_CRITICAL
            if self.mode == MODE_FAILSAFE
            else (mav.MAV_STATE_ACTIVE if self.armed else mav.MAV_STATE_STANDBY)
        )
        self._send(
            self.mav.heartbeat_encode(
                mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_PX4, base, self.px4_mode(), status
            )
        )

    def heartbeat_tick(self, now_wall_s: float) -> None:
        """Send the heartbeat if it is due on the wall clock (``time.monotonic`` seconds)."""
        if self.rates.heartbeat_hz > 0 and now_wall_s >= self._next_heartbeat_wall:
            self._next_heartbeat_wall = now_wall_s + 1.0 / self.rates.heartbeat_hz
            self.send_heartbeat()
            self.flush()
            if self._gcs is not None:
                with self._gcs_port():
                    self.send_heartbeat()
                    self.flush()

    def _stream(self) -> None:
        """Send the streams due now. Each is sent on its own grid of multiples of its period in
        boot time, so streams of the same rate (LOCAL_POSITION_NED and ATTITUDE_QUATERNION)
        always share their instants."""
        t = self.autopilot.time_s
        if t + 1e-9 < self._next_any_s:
            return
        next_send = self._next_send
        for msg_id, at in next_send.items():  # values replaced in place: no key is added
            if t + 1e-9 >= at:
                rate_hz = self._rate_hz[msg_id]
                if rate_hz <= 0:
                    next_send[msg_id] = math.inf
                    continue
                next_send[msg_id] = _next_due(t, rate_hz)
                self._senders[msg_id](round(t * 1000))
        self._next_any_s = min(next_send.values())
        self._next_other_s = min(at for msg_id, at in next_send.items() if msg_id not in (LPOS_ID, ATTQ_ID))

    def _send_local_position(self, ms: int) -> None:
        self._send_sample_part(tick_frames.pack_local_position, frames.LOCAL_POSITION_NED, ms)
        if self._truth is not None and not self._on_gcs:  # the controller's samples only
            self._truth.append((self.autopilot.time_s,), self.autopilot.state)

    def _send_attitude_quaternion(self, ms: int) -> None:
        self._send_sample_part(tick_frames.pack_attitude_quaternion, frames.ATTITUDE_QUATERNION, ms)

    def _send_attitude(self, ms: int) -> None:
        x = self.autopilot.state
        self._send_fields(frames.ATTITUDE, (ms, *encode_attitude(x[QUAT], x[RATE])))

    def _send_attitude_target(self, ms: int) -> None:
        ap = self.autopilot
        c = ap.command
        f = encode_attitude_quaternion(c.q_c, c.omega_c_B)
        thrust = float(c.thrust_N) / ap.params.max_thrust_N
        self._send_fields(frames.ATTITUDE_TARGET, (ms, 0, *f[0:4], f[4], f[5], f[6], thrust))

    def _send_imu(self, ms: int) -> None:
        ap = self.autopilot
        x, p = ap.state, ap.params
        if self.armed:  # specific force [m/s^2; body FLU]: thrust when flying, the stand's reaction when held
            T = min(max(float(ap.command.thrust_N), 0.0), p.max_thrust_N)
            f_b = np.array([0.0, 0.0, T / p.mass_kg])
        else:
            f_b = rotation_matrix(x[QUAT]).T @ np.array([0.0, 0.0, p.g_mps2])
        acc, gyro = flu_to_frd(f_b), flu_to_frd(x[RATE])
        self._send_fields(
            frames.HIGHRES_IMU,
            (ms * 1000, *acc, *gyro, 0, 0, 0, 1013.25, 0, 0, 0.0, 0b111111),
        )

    def _send_sys_status(self, ms: int) -> None:
        on = px4.SENSORS
        health = on | mav.MAV_SYS_STATUS_GEOFENCE  # no fence, so none breached (MAVProxy reads it)
        self._send(self.mav.sys_status_encode(on, on, health, 0, 12000, -1, -1, 0, 0, 0, 0, 0, 0))

    def _global(self) -> tuple[int, int, int, int]:
        """(lat, lon [deg 1e7], alt AMSL, alt above home [mm]) of the current position."""
        p = self.autopilot.state[POS]
        lat, lon, alt = self.home.global_of(float(p[0]), float(p[1]), float(p[2]))
        return round(lat * 1e7), round(lon * 1e7), round(alt * 1000), round(float(p[2]) * 1000)

    def _send_global_position(self, ms: int) -> None:
        lat, lon, alt, rel = self._global()
        v = enu_to_ned(self.autopilot.state[VEL])
        heading = self._heading_cdeg()
        self._send(
            self.mav.global_position_int_encode(
                ms, lat, lon, alt, rel, round(v[0] * 100), round(v[1] * 100), round(v[2] * 100), heading
            )
        )

    def _heading_cdeg(self) -> int:
        """Yaw of the body x axis from north, clockwise [cdeg 0..35999]."""
        x_N = enu_to_ned(rotation_matrix(self.autopilot.state[QUAT])[:, 0])
        return round(math.degrees(math.atan2(x_N[1], x_N[0])) % 360.0 * 100) % 36000

    def _send_gps_raw(self, ms: int) -> None:
        lat, lon, alt, _ = self._global()
        v = self.autopilot.state[VEL]
        speed = round(math.hypot(v[0], v[1]) * 100)
        fix = mav.GPS_FIX_TYPE_3D_FIX
        self._send(self.mav.gps_raw_int_encode(ms * 1000, fix, lat, lon, alt, 80, 120, speed, 65535, 12))

    def _send_extended_sys_state(self, ms: int) -> None:
        landed = mav.MAV_LANDED_STATE_IN_AIR if self.armed else mav.MAV_LANDED_STATE_ON_GROUND
        self._send(self.mav.extended_sys_state_encode(mav.MAV_VTOL_STATE_UNDEFINED, landed))

    def _send_home_position(self, ms: int) -> None:
        h = self.home
        lat, lon = round(h.latitude_deg * 1e7), round(h.longitude_deg * 1e7)
        self._send(
            self.mav.home_position_encode(
                lat, lon, round(h.altitude_m * 1000), 0, 0, 0, [1, 0, 0, 0], 0, 0, 0, ms * 1000
            )
        )

    def _send_autopilot_version(self, ms: int) -> None:
        self._send(
            self.mav.autopilot_version_encode(
                px4.CAPABILITIES,
                px4.FLIGHT_SW_VERSION,
                0,
                0,
                0,
                [0] * 8,
                [0] * 8,
                [0] * 8,
                0,
                0,
                self.system_id,
            )
        )

    def _gcs_socks(self) -> list[socket.socket]:
        return [] if self._gcs is None else [self._gcs["sock"]]

    def run_realtime(self, duration_s: float | None = None, stop: Callable[[], bool] | None = None) -> None:
        """Step with the wall clock (``time.monotonic``) until ``duration_s`` of wall time or ``stop()``.

        The plant is caught up to each datagram's arrival before the datagram is handled, so a
        setpoint takes effect at the attitude step in which it arrived. While setpoints stream in
        (offboard) and the kernel stamps arrivals (``udp_arrival``), the loop wakes only when a
        telemetry message or the failsafe is due, or ``RX_EVERY_S`` after its last read, and
        reads what came in between: one wake-up per period instead of two. Otherwise it also
        wakes for each datagram."""
        start = time.monotonic()
        dt = self.autopilot.dt_s
        k0 = self.autopilot.step_index

        def catch_up(mono_s: float) -> None:
            due = k0 + int((mono_s - start) / dt) - self.autopilot.step_index
            if due > 0:
                self.step(due)

        while True:
            deferred = self._stamped and self.mode == MODE_OFFBOARD
            if deferred:
                self.poll(catch_up)
                self.poll_gcs()
            now = time.monotonic() - start
            if (duration_s is not None and now >= duration_s) or (stop is not None and stop()):
                return
            t_next = self._next_any_s - k0 * dt
            if self.mode == MODE_OFFBOARD:
                t_next = min(t_next, self._last_setpoint_s + self.setpoint_timeout_s - k0 * dt)
            due = k0 + int(now / dt) - self.autopilot.step_index
            if due > 0 and now >= t_next:  # only a stream or the failsafe needs the state now
                self.step(due)
                continue
            self.heartbeat_tick(start + now)
            wait = min(max(t_next - now, 0.0), 0.05)
            if deferred:
                time.sleep(min(wait, RX_EVERY_S))
            elif self.sock in select.select([self.sock, *self._gcs_socks()], [], [], wait)[0]:
                self.poll(catch_up, readable=True)
            self.poll_gcs()

    def run_lockstep(self, stop: Callable[[], bool] | None = None) -> None:
        """Serve setpoints until ``stop()``: simulated time moves only with them (see the module doc).

        One datagram per wake-up, read by a blocking ``recvfrom`` that gives up after
        ``LOCKSTEP_WAIT_S`` (``SO_RCVTIMEO``) so the heartbeat and ``stop()`` still get their turn:
        one system call where a ``select`` and a drain would take three."""
        udp_arrival.block_reads(self.sock, LOCKSTEP_WAIT_S)
        try:
            next_gcs = 0.0
            while stop is None or not stop():
                now = time.monotonic()
                self.heartbeat_tick(now)
                if now >= next_gcs:  # a ground station waits LOCKSTEP_WAIT_S at most, or 5 ms and a tick
                    next_gcs = now + LOCKSTEP_GCS_EVERY_S
                    self.poll_gcs()
                try:
                    data, addr = self.sock.recvfrom(4096)
                except OSError:  # the wait ran out (EAGAIN), or an ICMP error
                    continue
                try:
                    self._datagram(data, addr)
                finally:
                    self.flush()
        finally:
            udp_arrival.block_reads(self.sock, 0.0)
