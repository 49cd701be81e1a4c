"""The MAVLink protocol services of a vehicle: parameters, commands and the small requests.

Each answers on the port the request came on, addressed to its sender as PX4 addresses it:

- parameters (``Parameters``): the autopilot's own (``autopilots``: PX4's MPC_THR_HOVER,
  COM_OF_LOSS_T, COM_OBL_RC_ACT, MC_*RATE_MAX, all REAL32; ArduCopter's SYSID_THISMAV,
  GUID_OPTIONS, GUID_TIMEOUT, MOT_THST_HOVER, MOT_THST_EXPO, ATC_ANGLE_BOOST, ..., each in its own
  type) and the model's own (``tunables``: PX4's MC_* gains for ``px4_quad_x``, under ArduPilot's
  ATC_* names where it has them) over the parameter protocol; PARAM_SET of a writable one within
  its range changes it, answered with PARAM_VALUE of what the vehicle keeps;
- COMMAND_LONG (``Commands``), each answered with COMMAND_ACK: MAV_CMD_COMPONENT_ARM_DISARM (a
  disarm while armed is refused unless forced, param2 = 21196, as PX4 refuses one in flight),
  MAV_CMD_DO_SET_MODE (PX4's base mode, main mode, sub mode; ArduCopter's mode number: ``modes``),
  MAV_CMD_SET_MESSAGE_INTERVAL (param1 message id, param2 interval [us]) and
  MAV_CMD_REQUEST_MESSAGE (param1 message id: sent once, now, after the ack) for its telemetry,
  MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES and MAV_CMD_GET_HOME_POSITION answered with their
  message. MAV_CMD_REQUEST_PROTOCOL_VERSION is answered UNSUPPORTED (PROTOCOL_VERSION is not in
  pymavlink's common dialect; tools then take MAVLink 2 from the frames themselves);
- PING answered; FILE_TRANSFER_PROTOCOL answered with a NAK (no file system: a tool falls back at
  once); MISSION_REQUEST_LIST answered with an empty mission; an ArduCopter's REQUEST_DATA_STREAM
  (``data_stream``: the rate of a group of its streams, as MAVProxy asks for them).

Values the vehicle refuses are counted (``rx_invalid``) and change nothing: a command whose
parameters are not finite where it reads them (``COMMAND_PARAMS``; NaN in a parameter it does not
need is MAVLink's "unused") or not what the command takes (MAV_RESULT_DENIED); a PARAM_SET outside
the parameter's range, or of a parameter that is what the vehicle is.
"""

import math
from collections.abc import Callable
from typing import Any, Protocol

from pymavlink.dialects.v20 import common as mav

from sim_vehicles.mavlink.wire_format import f32
from sim_vehicles.vehicle.autopilots import PARAMS_OF
from sim_vehicles.vehicle.modes import FlightModes
from sim_vehicles.vehicle.port import EndpointStats, Port

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
    """The parameter protocol over a vehicle's parameters (``autopilots.PARAMS_OF``: its
    autopilot's names and types), in the order PARAM_REQUEST_LIST gives them."""

    def __init__(self, vehicle: Any, flight: FlightModes, stats: EndpointStats):
        self.profile = flight.profile
        self.stats = stats
        self.defs = {d.name: d for d in PARAMS_OF[self.profile.name](vehicle, flight)}
        self.values: dict[str, float] = {n: d.value for n, d in self.defs.items()}
        self._index = {n: j for j, n in enumerate(self.defs)}

    def send(self, port: Port, name: str) -> None:
        """PARAM_VALUE of ``name``, in its MAVLink type (its value as a float, as both autopilots
        with the PARAM_FLOAT capability send it)."""
        port.send(
            port.mav.param_value_encode(
                name.encode(),
                float(self.values[name]),
                self.defs[name].kind,
                len(self.values),
                self._index[name],
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
        """Set a parameter within its range; anything else (a name it does not have, a value out
        of range or not finite, a read-only one; for PX4 any type but REAL32, which is every one's)
        is refused and counted. Answered with PARAM_VALUE of what the vehicle keeps, as both do; an
        integer parameter keeps the value rounded. A bound is compared as a float32, as the
        autopilots compare it: a parameter's maximum sent as MAVLink's float is taken."""
        name = m.param_id
        d = self.defs.get(name)
        if d is None:
            self.stats.rx_invalid += 1
            return
        value = float(m.param_value)
        wrong_type = self.profile.name == "px4" and m.param_type != mav.MAV_PARAM_TYPE_REAL32
        if d.kind != mav.MAV_PARAM_TYPE_REAL32:
            value = float(round(value)) if math.isfinite(value) else value
        low, high = f32(d.low, d.high)  # the bounds as the float a PARAM_SET carries them (0.8 is 0.80000001)
        if wrong_type or not d.writable or not (low <= value <= high):
            self.stats.rx_invalid += 1
            self.send(port, name)
            return
        try:
            if d.apply is not None:
                d.apply(value)
        except (ValueError, KeyError):  # the model's own range, or a value it has no meaning for
            self.stats.rx_invalid += 1
        else:
            self.values[name] = value
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
        flight = vehicle.flight
        result = flight.set_mode(flight.profile.requested(p1, p2, params[2]))
        if result == flight.profile.refused_mode:  # a mode this vehicle does not have
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


#: ArduPilot's stream groups (``GCS_MAVLink``'s ``ap_message`` groups) as this vehicle's streams
DATA_STREAMS = {
    mav.MAV_DATA_STREAM_RAW_SENSORS: (mav.MAVLINK_MSG_ID_HIGHRES_IMU,),
    mav.MAV_DATA_STREAM_EXTENDED_STATUS: (mav.MAVLINK_MSG_ID_SYS_STATUS, mav.MAVLINK_MSG_ID_GPS_RAW_INT),
    mav.MAV_DATA_STREAM_POSITION: (
        mav.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,
        mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED,
    ),
    mav.MAV_DATA_STREAM_EXTRA1: (mav.MAVLINK_MSG_ID_ATTITUDE,),
    mav.MAV_DATA_STREAM_EXTRA3: (mav.MAVLINK_MSG_ID_HOME_POSITION,),
}


def data_stream(port: Port, m: Any) -> None:
    """REQUEST_DATA_STREAM: a group of streams (all of them for MAV_DATA_STREAM_ALL) at
    ``req_message_rate`` [Hz], or off (``start_stop`` 0), on the port it came on."""
    groups = (
        DATA_STREAMS.values()
        if m.req_stream_id == mav.MAV_DATA_STREAM_ALL
        else [DATA_STREAMS.get(m.req_stream_id, ())]
    )
    on = m.start_stop and m.req_message_rate > 0
    for ids in groups:
        for msg_id in ids:
            if msg_id in port.streams.rate_hz:
                port.streams.set_interval(msg_id, 1e6 / m.req_message_rate if on else -1.0)
