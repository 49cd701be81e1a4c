"""A simulated vehicle behind a MAVLink 2 endpoint on UDP, as a MAVLink tool expects a PX4 autopilot.

The endpoint is the vehicle's flight state (armed, mode, failsafe) and what it does with each
message; its layers are apart: its UDP ports (``port``: sockets, peers, signing, the ``.tlog``),
its telemetry (``telemetry``), its protocol services (``services``: parameters, commands) and its
two run loops (``loops``). PX4's conventions are in ``mavlink.px4_profile``.

- HEARTBEAT at 1 Hz: type MAV_TYPE_QUADROTOR, autopilot MAV_AUTOPILOT_PX4, system id = follower
  id, component MAV_COMP_ID_AUTOPILOT1; ``base_mode`` carries SAFETY_ARMED and CUSTOM_MODE_ENABLED,
  ``custom_mode`` PX4's mode: Hold (AUTO.LOITER), OFFBOARD, or its failsafe as what it flies
  (``modes``: arming, modes and the setpoint-loss failsafe, as PX4 has them).
- SET_ATTITUDE_TARGET honoured as PX4 does, on the controller's port only: target system and
  component checked, type_mask bits (1, 2, 4 each ignore a body rate, which is then none: 0;
  64 ignore throttle, 128 ignore attitude), NED/FRD converted at the wire (``wire_format``),
  thrust 0..1 of its largest thrust (``thrust_map``; an ArduCopter's reading:
  ``mavlink.ardupilot_guided``). What the model does with the body rates is its own: the paper's
  vehicle tracks all three, ``px4_quad_x`` feeds the yaw rate forward about the vertical as PX4
  does (``plant.px4_control``).
  Commanded body rates are clipped to MC_ROLLRATE_MAX, MC_PITCHRATE_MAX and MC_YAWRATE_MAX, so the
  plant's state stays finite.
- Optionally the true state (float64, ENU/FLU) at every LOCAL_POSITION_NED instant sent to its
  controller, written to a ``row_log`` file (``TRUTH_COLUMNS``): what a bench records and a real
  autopilot cannot give.

Two clocks (``loops``): real time, on the wall clock; or lockstep (``lockstep_period_s`` set),
where simulated time moves one period per setpoint stamped with the vehicle's current
``time_boot_ms`` (``_on_setpoint`` says what other stamps do): the same setpoints give the same
trajectory, bit for bit, and the usual tick runs in one compiled call (``lockstep_tick``).

Hostile input (``stats`` counts each kind; nothing anyone sends stops the vehicle or moves it):
what is not MAVLink, cut short or with a bad CRC is ``rx_bad``; a message for another system or
component, or from anyone but the port's peer, ``rx_refused`` (``port``); a message the vehicle
does not handle ``rx_unhandled``; values it refuses ``rx_invalid`` (a setpoint whose quaternion is
not a rotation, with a non-finite rate or a thrust outside 0..1, and the vehicle keeps its last
valid one; commands and parameters: ``services``). A handler that fails on a message it accepted
is a bug: counted in ``handler_errors`` with its last error, never a stopped vehicle.
"""

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import common as mav

from sim_vehicles.common.command import AttitudeCommand
from sim_vehicles.common.state import TRUTH_COLUMNS
from sim_vehicles.mavlink import ardupilot_profile as ap_profile
from sim_vehicles.mavlink import decoder, frames, tick_frames
from sim_vehicles.mavlink import px4_profile as px4
from sim_vehicles.mavlink.ardupilot_guided import guided_command
from sim_vehicles.mavlink.ardupilot_profile import GUIDED_MODES, ArduCopterState
from sim_vehicles.mavlink.thrust_map import hover_fraction
from sim_vehicles.mavlink.wire_format import (
    CMD_VALID,
    IGNORE_ALL,
    IGNORE_ATTITUDE,
    IGNORE_RATES,
    IGNORE_THROTTLE,
    AttitudeTargetFields,
    Setpoint,
    command_of,
    setpoint_of,
)
from sim_vehicles.plant.contract import VehicleModel
from sim_vehicles.plant.failsafe import ACTION_HOLD
from sim_vehicles.plant.sensors import SensorModel
from sim_vehicles.runtime.event_log import EventLog
from sim_vehicles.runtime.row_log import RowLog
from sim_vehicles.vehicle import lockstep_tick, loops, services
from sim_vehicles.vehicle.autopilots import ARDUCOPTER, PX4, Profile
from sim_vehicles.vehicle.modes import MODE_HOLD, MODE_OFFBOARD, FlightModes
from sim_vehicles.vehicle.port import ATTQ_ID, LPOS_ID, EndpointStats, Port, Tlog
from sim_vehicles.vehicle.telemetry import GCS_RATES, Telemetry, TelemetryRates

MAX_CLOCK_STEP_S = 3600.0  #: the furthest a clock-only setpoint may move a lockstep vehicle [s]


_SETPOINT = frames.SET_ATTITUDE_TARGET


@dataclass
class VehicleEndpoint:
    autopilot: VehicleModel
    system_id: int
    bind: tuple[str, int] = ("127.0.0.1", 0)
    setpoint_timeout_s: float = (
        0.5  #: COM_OF_LOSS_T or GUID_TIMEOUT at start (``flight`` keeps the current one)
    )
    rates: TelemetryRates = field(default_factory=TelemetryRates)
    tlog_path: Path | None = None
    lockstep_period_s: float | None = None  #: None: real time; else simulated time per setpoint
    truth_path: Path | None = None  #: write the true state at every LOCAL_POSITION_NED instant
    failsafe_action: int = ACTION_HOLD  #: ``failsafe.ACTION_*`` at start (parameter COM_OBL_RC_ACT)
    events_path: Path | None = None  #: write failsafe events here (``event_log``)
    signing_key: bytes | None = None  #: MAVLink 2 signing on this link (``mavlink.signing``)
    home: px4.Home = field(default_factory=px4.Home)  #: where the local frame's origin is on the earth
    #: a ground station's own port (``None``: none), with its own peer and stream rates
    gcs_bind: tuple[str, int] | None = None
    gcs_rates: TelemetryRates = GCS_RATES
    #: where the ground-station port sends until someone speaks to it (PX4 sends to 14550)
    gcs_remote: tuple[str, int] | None = None
    #: latency and noise of the state it reports (``plant.sensors``; None: the true state)
    sensors: SensorModel | None = None
    #: the autopilot it speaks as (``autopilots``: PX4 or ArduCopter)
    profile: Profile = PX4

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
        self.stats = EndpointStats()
        #: real time: the UNIX instant of its ``time_boot_ms`` 0 (set when its loop starts)
        self.boot_unix_s = math.nan
        self.tlog = Tlog(self.tlog_path)
        rates = self.rates.by_message()
        if self.lockstep_period_s is not None:  # in lockstep the sample follows every period
            for msg_id in (LPOS_ID, ATTQ_ID):
                rates[msg_id] = max(rates[msg_id], 1.0 / self.lockstep_period_s)
        #: the controller's port (real time: with the kernel's arrival stamps where it can)
        self.port = Port(
            self.bind,
            self.system_id,
            rates,
            self.stats,
            self.tlog,
            signing_key=self.signing_key,
            stamped=self.lockstep_period_s is None,
        )
        self.address = self.port.address
        self._truth = RowLog(self.truth_path, TRUTH_COLUMNS) if self.truth_path else None
        self.telemetry = Telemetry(self)
        self._senders = {**self.telemetry.senders, LPOS_ID: self._send_local_position}
        #: what MAV_CMD_REQUEST_MESSAGE may ask for (``services``)
        self.on_request = {**self.telemetry.on_request, LPOS_ID: self._send_local_position}
        self._next_heartbeat_wall = -math.inf
        self._sample_out = np.zeros(lockstep_tick.SAMPLE_BYTES, np.uint8)
        #: the ground station's port, if it has one
        self.gcs: Port | None = None
        if self.gcs_bind is not None:
            self.gcs = Port(
                self.gcs_bind,
                self.system_id,
                self.gcs_rates.by_message(),
                self.stats,
                self.tlog,
                remote=self.gcs_remote,
                signing_key=self.signing_key,
            )
        self.events = EventLog(self.events_path, f"vehicle_{self.system_id}")
        self.flight = FlightModes(
            self.autopilot,
            self.system_id,
            self.setpoint_timeout_s,
            self.failsafe_action,
            self.events,
            self._statustext,
            self.profile,
        )
        p = self.autopilot.params
        #: an ArduCopter's parameters its SET_ATTITUDE_TARGET reads (``mavlink.ardupilot_guided``)
        self.ardupilot = ArduCopterState(hover_fraction(p.mass_kg, p.g_mps2, p.max_thrust_N))
        self.parameters = services.Parameters(self, self.flight, self.stats)

    def unsigned_by_port(self) -> dict[str, int]:
        """Datagrams each port of a signed vehicle refused for want of a signature (or of the
        run's key: a signature from another key is ``rx_bad``), by port: ``controller`` and
        ``ground_station``; empty on an unsigned vehicle."""
        ports = {"controller": self.port, "ground_station": self.gcs}
        return {name: p.verifier.unsigned for name, p in ports.items() if p is not None and p.verifier}

    @property
    def armed(self) -> bool:
        return self.flight.armed

    @armed.setter
    def armed(self, armed: bool) -> None:
        self.flight.armed = armed

    @property
    def mode(self) -> int:
        """``modes.MODE_*``."""
        return self.flight.mode

    @mode.setter
    def mode(self, mode: int) -> None:
        self.flight.mode = mode

    @property
    def params(self) -> dict[str, float]:
        """The parameters by name, as the vehicle keeps them."""
        return self.parameters.values

    @property
    def gcs_address(self) -> tuple[str, int] | None:
        return None if self.gcs is None else self.gcs.address

    @property
    def time_boot_ms(self) -> int:
        return round(self.autopilot.time_s * 1000)

    @property
    def offboard(self) -> bool:
        """Flying its controller's setpoints."""
        return self.flight.mode == MODE_OFFBOARD

    def run_realtime(self, duration_s: float | None = None, stop: Callable[[], bool] | None = None) -> None:
        loops.run_realtime(self, duration_s, stop)

    def run_lockstep(self, stop: Callable[[], bool] | None = None) -> None:
        loops.run_lockstep(self, stop)

    def close(self) -> None:
        self.port.close()
        if self.gcs is not None:
            self.gcs.close()
        self.events.close()
        self.tlog.close()
        if self._truth is not None:
            self._truth.close()
            self._truth = None

    # -- receive ---------------------------------------------------------------------------------
    def poll(self, at_arrival: Callable[[float], None] | None = None, readable: bool = False) -> None:
        """Handle every datagram waiting on the controller's port, then send what that produced.
        ``at_arrival(t)`` runs before each datagram with its arrival [s; ``time.monotonic``].
        ``readable``: a ``select`` has just said so (the first read needs no check)."""
        try:
            for data, addr, arrival in self.port.datagrams(at_arrival is not None, readable):
                if at_arrival is not None:
                    at_arrival(arrival)
                self.datagram(data, addr)
        finally:
            self.port.flush()

    def poll_gcs(self) -> None:
        """Handle what waits on the ground-station port (at the current state), answer it there."""
        gcs = self.gcs
        if gcs is not None and gcs.waiting():
            try:
                for data, addr, _ in gcs.datagrams(False):
                    self.datagram(data, addr, gcs)
            finally:
                gcs.flush()

    def flush(self) -> None:
        """Send what the controller's port has queued."""
        self.port.flush()

    def datagram(self, data: bytes, addr: Any, port: Port | None = None) -> None:
        """Handle one datagram from ``addr`` on ``port`` (default: the controller's); what it makes
        the vehicle send waits for the port's ``flush``."""
        port = self.port if port is None else port
        plain = port.admit(data, addr)
        if plain is None:
            return
        if not plain:  # an empty datagram is no frame
            self.stats.rx_bad += 1
            return
        accepted = port.accepted
        try:
            self._frames(plain, port)
        finally:
            if port.accepted > accepted:
                port.heard(addr, self.send_heartbeat)

    def _frames(self, data: bytes, port: Port) -> None:
        """Handle a datagram of plain frames: a setpoint alone in one compiled call, the rest
        through ``decoder``."""
        r = tick_frames.read_setpoint(data, _SETPOINT.spec, self.autopilot.params.max_thrust_N)
        if r[0] and self.profile is PX4:  # one SET_ATTITUDE_TARGET and nothing else: what a controller sends
            self.tlog.frame(data)
            self.stats.rx_messages += 1
            if port is not self.port:  # setpoints come on the controller's port only
                self.stats.rx_refused += 1
                return
            if lockstep_tick.usual_tick(self, r):
                return
            sp = tick_frames.setpoint_of(r)
            if self._addressed(sp.target_system, sp.target_component):
                port.accepted += 1
                port.accepted_from = (int(r[tick_frames.SP_SYSID]), int(r[tick_frames.SP_COMPID]))
                self._on_setpoint(sp)
            else:
                self.stats.rx_refused += 1
            return
        for got in decoder.messages(data, port.parser):
            if got is decoder.GARBAGE:
                self.stats.rx_bad += 1
                continue
            self.tlog.frame(got.frame)
            self.stats.rx_messages += 1
            if got.bad:
                self.stats.rx_bad += 1
                continue
            self._handle_safely(got.message, port)

    def _addressed(self, target_system: float, target_component: float) -> bool:
        """Whether a target system and component (0: any) are this vehicle's autopilot."""
        return target_system in (0, self.system_id) and target_component in (0, px4.AUTOPILOT)

    def _handle_safely(self, m: Any, port: Port) -> None:
        """``_handle``, counting a message addressed elsewhere, and a handler's failure (a bug the
        message found: counted and kept in ``stats``, the vehicle flies on). A message it knows
        from anyone heard counts towards the port's peer rule (``Port.heard``)."""
        if hasattr(m, "target_system") and not self._addressed(
            m.target_system, getattr(m, "target_component", 0)
        ):
            self.stats.rx_refused += 1
            return
        unhandled = self.stats.rx_unhandled
        try:
            self._handle(m, port)
        except Exception as e:
            self.stats.handler_errors += 1
            self.stats.last_handler_error = f"{m.get_type()}: {type(e).__name__}: {e}"
        if self.stats.rx_unhandled == unhandled:  # a message it does not know claims no link
            port.accepted += 1
            port.accepted_from = (m.get_srcSystem(), m.get_srcComponent())

    def _handle(self, m: Any, port: Port) -> None:
        t = m.get_type()
        if t == "SET_ATTITUDE_TARGET" and port is not self.port:  # setpoints: the controller's port only
            self.stats.rx_refused += 1
        elif t == "SET_ATTITUDE_TARGET":
            raw = AttitudeTargetFields(
                tuple(m.q), (m.body_roll_rate, m.body_pitch_rate, m.body_yaw_rate), m.thrust
            )
            self._on_setpoint(setpoint_of(m, self.autopilot.params.max_thrust_N), raw)
        elif t == "REQUEST_DATA_STREAM" and self.profile is ARDUCOPTER:
            services.data_stream(port, m)
        elif t == "COMMAND_LONG":
            services.on_command(self, port, m)
        elif t == "PARAM_REQUEST_LIST":
            self.parameters.request_list(port)
        elif t == "PARAM_SET":
            self.parameters.set(port, m)
        elif t == "PARAM_REQUEST_READ":
            self.parameters.request_read(port, m)
        elif not services.answer_request(port, m) and t != "HEARTBEAT":  # a heartbeat needs no answer
            self.stats.rx_unhandled += 1

    def reported_state(self, ms: int) -> np.ndarray:
        """The state its sample at ``time_boot_ms`` ``ms`` reports (``plant.sensors``)."""
        x = self.autopilot.state
        return x if self.sensors is None else self.sensors.reported(ms, x)

    # -- setpoints -------------------------------------------------------------------------------
    def _on_setpoint(self, m: Setpoint, raw: AttitudeTargetFields | None = None) -> None:
        """A setpoint for this vehicle. In lockstep one stamped with its current time is applied
        (armed in offboard) and the vehicle advances exactly one period and streams its sample;
        one stamped earlier (a retransmission: its sample was lost) makes it send its current
        sample again and nothing else; one stamped later is refused and counted, except a
        *clock-only* setpoint (type_mask ``IGNORE_ALL``), which advances the vehicle to its stamp,
        period by period, under what it holds (its failsafe once setpoints have been missing for
        the setpoint timeout of simulated time) and counts as no setpoint: how a controller that was down
        (a planned kill and restart) takes its vehicle up again at its restart tick."""
        ap = self.autopilot
        if self.lockstep_period_s is None or m.time_boot_ms <= self.time_boot_ms:
            self.flight.offboard_signal_s = ap.time_s  # a stream runs (a future stamp is refused below)
        if self.lockstep_period_s is not None:
            now_ms = self.time_boot_ms
            if m.time_boot_ms < now_ms or (m.type_mask == IGNORE_ALL and m.time_boot_ms == now_ms):
                # a retransmission (the sample it waits for was lost), or a clock already there
                self.stats.lockstep_resends += 1
                self._send_local_position(self.port, now_ms)
                self.telemetry.attitude_quaternion(self.port, now_ms)
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
        if self.profile is ARDUCOPTER:
            self._on_guided_setpoint(m, raw)
            return
        if not m.command[CMD_VALID]:  # not a rotation, or a non-finite rate or thrust
            self.stats.rx_bad += 1
            if self.lockstep_period_s is not None:
                self.step(self._lockstep_steps)  # the clock still advances; the old command is held
            return
        new = command_of(m.command)
        if mask & (IGNORE_ATTITUDE | IGNORE_THROTTLE | IGNORE_RATES):
            omega = new.omega_c_B.copy()
            for axis in range(3):  # each body rate its bit ignores is not given: none asked
                if mask & (1 << axis):
                    omega[axis] = 0.0
            cmd = AttitudeCommand(
                q_c=cur.q_c if mask & IGNORE_ATTITUDE else new.q_c,
                thrust_N=cur.thrust_N if mask & IGNORE_THROTTLE else new.thrust_N,
                omega_c_B=omega,
            )
        else:  # every field taken (what a position controller sends)
            cmd = new
        self.stats.setpoints += 1
        if self.flight.take_setpoint():
            ap.set_command(cmd)
        if self.lockstep_period_s is not None:
            self.step(self._lockstep_steps)

    def _on_guided_setpoint(self, m: Setpoint, raw: AttitudeTargetFields | None) -> None:
        """An ArduCopter's setpoint (``mavlink.ardupilot_guided``): taken in its guided modes only;
        refused, it keeps what it flies (GUIDED: a position hold where it is, as
        ``mode_guided.init`` does)."""
        ap, f = self.autopilot, self.flight
        if raw is not None and f.number in GUIDED_MODES:
            cmd, climb, _why = guided_command(
                raw, m.type_mask, ap.command, ap.state, ap.params.max_thrust_N, self.ardupilot
            )
            if cmd is None:
                self.stats.rx_invalid += 1
                if f.number == ap_profile.GUIDED and f.mode != MODE_HOLD:
                    f.set_mode(ap_profile.GUIDED)  # (its position hold, from where it is)
            else:
                self.stats.setpoints += 1
                if f.take_setpoint(climb):
                    ap.set_command(cmd)
        if self.lockstep_period_s is not None:
            self.step(self._lockstep_steps)

    # -- flight ----------------------------------------------------------------------------------
    def _statustext(self, severity: int, text: str) -> None:
        """A STATUSTEXT now, to the controller and to the ground station (sent with their next
        pass)."""
        for port in (self.port, self.gcs):
            if port is not None:
                port.send(port.mav.statustext_encode(severity, text.encode()[:50]))

    def step(self, n_steps: int = 1) -> None:
        """Advance ``n_steps`` attitude steps under the held command (held still while disarmed),
        checking the setpoint timeout; in Hold or failsafe its own position loop sets the command
        (``modes``). Then stream what is due."""
        ap, f = self.autopilot, self.flight
        if not f.armed:
            ap.step_index += n_steps
            f.check_failsafe()
        left = n_steps if f.armed else 0
        while left > 0:
            chunk = f.own_steps(left)
            ap.advance(chunk)
            left -= chunk
            f.check_failsafe()
        self.port.stream(self.autopilot.time_s, self._senders)
        self.port.flush()
        self._stream_gcs()

    # -- send ------------------------------------------------------------------------------------
    def send_heartbeat(self, port: Port) -> None:
        base, custom, status = self.flight.heartbeat()
        port.send(
            port.mav.heartbeat_encode(
                mav.MAV_TYPE_QUADROTOR, self.profile.mav_autopilot, base, custom, status
            )
        )

    def heartbeat_tick(self, now_wall_s: float) -> None:
        """Send the heartbeat on every port if it is due on the wall clock (``time.monotonic`` s)."""
        if self.rates.heartbeat_hz > 0 and now_wall_s >= self._next_heartbeat_wall:
            self._next_heartbeat_wall = now_wall_s + 1.0 / self.rates.heartbeat_hz
            for port in (self.port, self.gcs):
                if port is not None:
                    self.send_heartbeat(port)
                    port.flush()

    def _stream_gcs(self) -> None:
        """The ground-station port's streams, once it has someone to send them to (``gcs_remote``
        or a ground station that spoke): until then there is nothing to pack."""
        gcs = self.gcs
        if (
            gcs is not None
            and gcs.peer is not None
            and self.autopilot.time_s + 1e-9 >= gcs.streams.next_any_s
        ):
            gcs.stream(self.autopilot.time_s, self._senders)
            gcs.flush()

    def _send_local_position(self, port: Port, ms: int) -> None:
        """LOCAL_POSITION_NED, and on the controller's port the true state at its instant."""
        self.telemetry.local_position(port, ms)
        if self._truth is not None and port is self.port:  # the controller's samples only
            self._truth.append((self.autopilot.time_s,), self.autopilot.state)
