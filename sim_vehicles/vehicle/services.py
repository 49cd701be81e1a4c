"""The MAVLink protocol services of a vehicle: parameters, commands and the small requests.

Each answers on the port the request came on, addressed to its sender as PX4 addresses it:

- parameters (``Parameters``): MASS_KG, INERTIA_X/Y/Z, MAX_THRUST_N, SP_TIMEOUT_S, COM_OBL_ACT,
  MC_ROLLRATE_MAX, MC_PITCHRATE_MAX, MC_YAWRATE_MAX [deg/s] and the model's own (``tunables``:
  PX4's MC_* gains for ``px4_quad_x``) over the parameter protocol, all REAL32; PARAM_SET changes
  those that may change in flight (``SETTABLE`` and the model's, within their ranges, as REAL32),
  answered with PARAM_VALUE of what the vehicle keeps;
- COMMAND_LONG (``Commands``), each answered with COMMAND_ACK: MAV_CMD_COMPONENT_ARM_DISARM (a
  disarm while armed is refused unless forced, param2 = 21196, as PX4 refuses one in flight),
  MAV_CMD_DO_SET_MODE (PX4's base mode, main mode, sub mode: ``modes``),
  MAV_CMD_SET_MESSAGE_INTERVAL (param1 message id, param2 interval [us]) and
  MAV_CMD_REQUEST_MESSAGE (param1 message id: sent once, now, after the ack) for its telemetry,
  MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES and MAV_CMD_GET_HOME_POSITION answered with their
  message. MAV_CMD_REQUEST_PROTOCOL_VERSION is answered UNSUPPORTED (PROTOCOL_VERSION is not in
  pymavlink's common dialect; tools then take MAVLink 2 from the frames themselves);
- PING answered; FILE_TRANSFER_PROTOCOL answered with a NAK (no file system: a tool falls back at
  once); MISSION_REQUEST_LIST answered with an empty mission.

Values the vehicle refuses are counted (``rx_invalid``) and change nothing: a command whose
parameters are not finite where it reads them (``COMMAND_PARAMS``; NaN in a parameter it does not
need is MAVLink's "unused") or not what the command takes (MAV_RESULT_DENIED); a PARAM_SET outside
the parameter's range, or of a parameter that is what the vehicle is.
"""

import math
from collections.abc import Callable
from typing import Any, Protocol

from pymavlink.dialects.v20 import common as mav

from sim_vehicles.mavlink import px4_profile as px4
from sim_vehicles.plant.contract import VehicleModel
from sim_vehicles.vehicle.modes import FlightModes
from sim_vehicles.vehicle.port import EndpointStats, Port

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
FORCE_DISARM = 21196  #: MAV_CMD_COMPONENT_ARM_DISARM param2 that forces a disarm (PX4's magic number)

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


class Parameters:
    """The parameter protocol over a vehicle's parameters, in the order PARAM_REQUEST_LIST gives
    them: what the vehicle is (``autopilot.params``) and what its ``flight`` may change."""

    def __init__(self, autopilot: VehicleModel, flight: FlightModes, stats: EndpointStats):
        self.autopilot = autopilot
        self.flight = flight
        self.stats = stats
        p = autopilot.params
        self.values: dict[str, float] = {
            "MASS_KG": p.mass_kg,
            "INERTIA_X": p.inertia_kgm2[0],
            "INERTIA_Y": p.inertia_kgm2[1],
            "INERTIA_Z": p.inertia_kgm2[2],
            "MAX_THRUST_N": p.max_thrust_N,
            "SP_TIMEOUT_S": flight.setpoint_timeout_s,
            "COM_OBL_ACT": float(flight.failsafe_action),
            **{n: math.degrees(w) for n, w in zip(RATE_MAX_PARAMS, p.max_rate_rps, strict=True)},
            **autopilot.tunables,  # the model's own (PX4's gains, for px4_quad_x)
        }

    def _apply(self, name: str, value: float) -> None:
        """A PARAM_SET into effect."""
        if name == "SP_TIMEOUT_S":
            self.flight.setpoint_timeout_s = value
        elif name == "COM_OBL_ACT":
            self.flight.failsafe_action = round(value)
        elif name in RATE_MAX_PARAMS:
            self.autopilot.max_rate_rps[RATE_MAX_PARAMS.index(name)] = math.radians(value)

    def send(self, port: Port, name: str) -> None:
        """PARAM_VALUE of ``name``."""
        index = list(self.values).index(name)
        port.send(
            port.mav.param_value_encode(
                name.encode(), float(self.values[name]), mav.MAV_PARAM_TYPE_REAL32, len(self.values), index
            )
        )

    def request_list(self, port: Port) -> None:
        for name in self.values:
            self.send(port, name)

    def request_read(self, port: Port, m: Any) -> None:
        names = list(self.values)
        name = (
            m.param_id if m.param_index < 0 else (names[m.param_index] if m.param_index < len(names) else "")
        )
        if name in self.values:
            self.send(port, name)

    def set(self, port: Port, m: Any) -> None:
        """Set a parameter that may change in flight (``SETTABLE``, or the model's own
        ``tunables``, within its range, as a REAL32); anything else is refused and counted.
        Answered with PARAM_VALUE of what the vehicle keeps, as PX4 does."""
        name = m.param_id
        if name not in self.values:
            self.stats.rx_invalid += 1
            return
        value = float(m.param_value)
        if m.param_type != mav.MAV_PARAM_TYPE_REAL32:  # every one is a float, as PARAM_VALUE says
            self.stats.rx_invalid += 1
            self.send(port, name)
            return
        if name in self.autopilot.tunables:  # the model's own: its range is the model's
            if self.autopilot.set_param(name, value):
                self.values[name] = self.autopilot.tunables[name]
            else:
                self.stats.rx_invalid += 1
            self.send(port, name)
            return
        lo, hi = SETTABLE.get(name, (math.nan, math.nan))
        if lo <= value <= hi:
            self.values[name] = value
            self._apply(name, value)
        else:
            self.stats.rx_invalid += 1
        self.send(port, name)


class Vehicle(Protocol):
    """What the commands act on (``endpoint.VehicleEndpoint``)."""

    stats: EndpointStats
    flight: FlightModes  #: arming and modes
    #: what MAV_CMD_REQUEST_MESSAGE may ask for: ``(port, time_boot_ms) -> None`` by message id
    on_request: dict[int, Callable[[Port, int], None]]

    @property
    def time_boot_ms(self) -> int: ...


def on_command(vehicle: Vehicle, port: Port, m: Any) -> None:
    """COMMAND_LONG ``m``, from ``port``: carried out, and acknowledged to its sender."""
    cmd = m.command
    params: tuple[float, ...] = (m.param1, m.param2, m.param3, m.param4, m.param5, m.param6, m.param7)
    stats = vehicle.stats

    def ack(result: int) -> None:  # to the sender, as PX4 addresses it
        port.send(port.mav.command_ack_encode(cmd, result, 0, 0, m.get_srcSystem(), m.get_srcComponent()))

    if cmd not in COMMAND_PARAMS:
        stats.rx_unhandled += 1
        ack(mav.MAV_RESULT_UNSUPPORTED)
        return
    used, optional = COMMAND_PARAMS[cmd]
    if not all(math.isfinite(params[j]) for j in used) or any(math.isinf(params[j]) for j in optional):
        stats.rx_invalid += 1
        ack(mav.MAV_RESULT_DENIED)
        return
    params = tuple(0.0 if j in optional and math.isnan(v) else v for j, v in enumerate(params))
    p1, p2 = params[0], params[1]
    result = mav.MAV_RESULT_ACCEPTED
    on_request = vehicle.on_request
    if cmd == mav.MAV_CMD_COMPONENT_ARM_DISARM:
        if not vehicle.flight.arm(p1 >= 0.5, round(p2) == FORCE_DISARM):
            stats.rx_invalid += 1
            result = mav.MAV_RESULT_DENIED  # PX4 refuses to disarm in flight unless forced
    elif cmd == mav.MAV_CMD_DO_SET_MODE:
        result = vehicle.flight.set_mode(px4.requested_mode(p1, p2, params[2]))
        if result == mav.MAV_RESULT_DENIED:  # a mode this vehicle does not have
            stats.rx_invalid += 1
    elif cmd == mav.MAV_CMD_SET_MESSAGE_INTERVAL and p1 in port.streams.rate_hz:
        port.streams.set_interval(int(p1), p2)
    elif cmd == mav.MAV_CMD_REQUEST_MESSAGE and p1 in on_request:
        ack(result)  # the ack first, then the message, as PX4 does
        on_request[int(p1)](port, vehicle.time_boot_ms)
        return
    elif cmd in ASKS:
        ack(result)
        on_request[ASKS[cmd]](port, vehicle.time_boot_ms)
        return
    else:  # a message this vehicle does not have
        stats.rx_invalid += 1
        result = mav.MAV_RESULT_DENIED
    ack(result)


def answer_request(port: Port, m: Any) -> bool:
    """PING, FILE_TRANSFER_PROTOCOL or MISSION_REQUEST_LIST answered on ``port``; False for any
    other message."""
    t = m.get_type()
    if t == "PING" and m.target_system == 0:  # a request: answered to its sender
        port.send(port.mav.ping_encode(m.time_usec, m.seq, m.get_srcSystem(), m.get_srcComponent()))
    elif t == "FILE_TRANSFER_PROTOCOL":  # no file system: a NAK, so a tool falls back at once
        port.send(
            port.mav.file_transfer_protocol_encode(
                0, m.get_srcSystem(), m.get_srcComponent(), ftp_nak(bytes(m.payload))
            )
        )
    elif t == "MISSION_REQUEST_LIST":  # no mission: an empty list
        port.send(port.mav.mission_count_encode(m.get_srcSystem(), m.get_srcComponent(), 0, m.mission_type))
    else:
        return False
    return True
