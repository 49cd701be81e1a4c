"""The autopilots a vehicle speaks as (``vehicle.autopilot``): PX4 (``PX4``, the default) and
ArduCopter (``ARDUCOPTER``). Each is a ``Profile``: its modes and how it reports them, the mode it
boots in, what it flies on its own when setpoints stop, and its parameters (``params``: the names
and types a tool reads, each tied to what it sets in the vehicle). The wire conventions are in
``mavlink.px4_profile`` and ``mavlink.ardupilot_profile``; the flight state machine that follows
a profile is ``modes.FlightModes``.

What the vehicle flies in each mode (``Mode``): whether it takes SET_ATTITUDE_TARGET (``follows``),
whether it may be entered only while a setpoint stream runs (PX4's OFFBOARD: ``needs_stream``),
and what its own loop flies while it has no setpoint to follow (``own``: ``failsafe.ACTION_*``).

- PX4: Hold (AUTO.LOITER: a position hold), OFFBOARD (setpoints; when they stop for COM_OF_LOSS_T
  its failsafe, COM_OBL_RC_ACT's hold or land, reported as AUTO.LOITER or AUTO.LAND with
  MAV_STATE_CRITICAL); any other mode DENIED.
- ArduCopter: STABILIZE (no RC here: level, its altitude held), GUIDED (setpoints; a position
  hold before the first and when they stop for GUID_TIMEOUT), LAND (descending at LAND_SPEED over
  where it began), GUIDED_NOGPS (setpoints; level at its altitude before the first and when they
  stop); any other mode FAILED. A guided timeout is not a failsafe to ArduCopter: the mode it
  reports stays, with MAV_STATE_ACTIVE.
"""

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from pymavlink.dialects.v20 import common as mav

from sim_vehicles.mavlink import ardupilot_profile as ap
from sim_vehicles.mavlink import px4_profile as px4
from sim_vehicles.mavlink.thrust_map import hover_fraction
from sim_vehicles.plant.failsafe import ACTION_HOLD, ACTION_LAND, ACTION_LEVEL, LAND_SPEED_MPS
from sim_vehicles.plant.px4_params import BY_NAME as PX4_DECLARED
from sim_vehicles.plant.px4_params import RATE_MAX as PX4_RATE_NAMES


@dataclass(frozen=True)
class Mode:
    number: int  #: ``custom_mode`` as HEARTBEAT carries it
    name: str
    follows: bool = False  #: takes SET_ATTITUDE_TARGET
    own: int = ACTION_HOLD  #: what its own loop flies while it has no setpoint to follow
    needs_stream: bool = False  #: entered only while a setpoint stream runs (PX4's OFFBOARD)


@dataclass(frozen=True)
class ParamDef:
    """One parameter a vehicle serves: its MAVLink type, its value now, and what a PARAM_SET
    within ``low..high`` does (``apply``; None: the vehicle keeps it as a value and nothing else)."""

    name: str
    kind: int  #: MAV_PARAM_TYPE_*
    value: float
    low: float = -math.inf
    high: float = math.inf
    apply: Callable[[float], None] | None = None
    writable: bool = True


@dataclass(frozen=True)
class Profile:
    name: str  #: ``vehicle.autopilot``
    mav_autopilot: int  #: HEARTBEAT's autopilot
    modes: dict[int, Mode]
    boot_mode: int  #: the mode it starts in
    refused_mode: int  #: MAV_RESULT for a mode it does not have
    capabilities: int
    flight_sw_version: int
    #: the setpoint timeout's and the landing speed's parameter names
    timeout_param: str
    land_speed_mps: float = LAND_SPEED_MPS

    def requested(self, p1: float, p2: float, p3: float) -> int | None:
        """The mode number MAV_CMD_DO_SET_MODE's parameters ask for (None: none this way)."""
        if self is PX4:
            return px4.requested_mode(p1, p2, p3)
        return ap.requested_mode(p1, p2)

    def reported(self, number: int, state: int, action: int) -> int:
        """The ``custom_mode`` a HEARTBEAT reports, in the flight state ``state``
        (``modes.MODE_*``: 0 its own loop, 1 following setpoints, 2 failsafe): PX4 reports
        OFFBOARD while it follows them and its failsafe as what it flies; ArduCopter keeps the
        mode it is in."""
        if self is not PX4:
            return number
        if state == 2:
            return px4.LAND if action == ACTION_LAND else px4.HOLD
        return px4.OFFBOARD if state == 1 else number

    def base_mode(self, number: int, armed: bool) -> int:
        armed_flag = mav.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0
        if self is PX4:
            return px4.BASE_FLAGS | armed_flag
        guided = mav.MAV_MODE_FLAG_GUIDED_ENABLED if number in (ap.GUIDED, ap.LAND) else 0
        return ap.BASE_FLAGS | guided | armed_flag

    def status(self, armed: bool, failsafe: bool) -> int:
        if self is PX4 and failsafe:
            return mav.MAV_STATE_CRITICAL
        return mav.MAV_STATE_ACTIVE if armed else mav.MAV_STATE_STANDBY


PX4 = Profile(
    "px4",
    mav.MAV_AUTOPILOT_PX4,
    {
        px4.HOLD: Mode(px4.HOLD, "AUTO.LOITER"),
        px4.OFFBOARD: Mode(px4.OFFBOARD, "OFFBOARD", follows=True, needs_stream=True),
    },
    px4.HOLD,
    mav.MAV_RESULT_DENIED,
    px4.CAPABILITIES,
    px4.FLIGHT_SW_VERSION,
    "COM_OF_LOSS_T",
)
ARDUCOPTER = Profile(
    "ardupilot",
    mav.MAV_AUTOPILOT_ARDUPILOTMEGA,
    {
        ap.STABILIZE: Mode(ap.STABILIZE, "STABILIZE", own=ACTION_LEVEL),
        ap.GUIDED: Mode(ap.GUIDED, "GUIDED", follows=True, own=ACTION_HOLD),
        ap.LAND: Mode(ap.LAND, "LAND", own=ACTION_LAND),
        ap.GUIDED_NOGPS: Mode(ap.GUIDED_NOGPS, "GUIDED_NOGPS", follows=True, own=ACTION_LEVEL),
    },
    ap.STABILIZE,
    mav.MAV_RESULT_FAILED,
    ap.CAPABILITIES,
    ap.FLIGHT_SW_VERSION,
    "GUID_TIMEOUT",
    land_speed_mps=0.5,  # LAND_SPEED's default, 50 cm/s
)
PROFILES = {p.name: p for p in (PX4, ARDUCOPTER)}

#: PX4's COM_OBL_RC_ACT values this vehicle flies (``failsafe.ACTION_*``): 0 Position mode (no RC
#: here: a hold), 4 Land, 5 Hold
PX4_OBL_ACT = {0: ACTION_HOLD, 4: ACTION_LAND, 5: ACTION_HOLD}
PX4_RATE_MAX = PX4_RATE_NAMES  #: [deg/s]


def px4_params(vehicle: Any, flight: Any) -> list[ParamDef]:
    """PX4's parameters of this vehicle (all REAL32, as its PARAM_FLOAT capability says)."""
    a = vehicle.autopilot
    p = a.params
    real = mav.MAV_PARAM_TYPE_REAL32
    action = 4.0 if flight.failsafe_action == ACTION_LAND else 5.0

    def set_action(v: float) -> None:
        flight.failsafe_action = PX4_OBL_ACT[round(v)]

    def set_timeout(v: float) -> None:
        flight.setpoint_timeout_s = v

    out = [
        ParamDef("MPC_THR_HOVER", real, hover_fraction(p.mass_kg, p.g_mps2, p.max_thrust_N), 0.1, 0.8),
        ParamDef("COM_OF_LOSS_T", real, flight.setpoint_timeout_s, 0.05, 60.0, set_timeout),
        ParamDef("COM_OBL_RC_ACT", real, action, 0.0, 5.0, set_action),
    ]
    out += _rate_limits(a, PX4_RATE_MAX, real)
    out += _tunables(a, real, {})
    return out


def ardupilot_params(vehicle: Any, flight: Any) -> list[ParamDef]:
    """ArduCopter's parameters of this vehicle, in ArduPilot's names and types."""
    a = vehicle.autopilot
    p = a.params
    kept = vehicle.ardupilot  # the values its SET_ATTITUDE_TARGET reads (``ArduCopterState``)

    def keep(name: str) -> Callable[[float], None]:
        return lambda v: kept.set(name, v)

    def set_timeout(v: float) -> None:
        flight.setpoint_timeout_s = v

    out = []
    for name, d in ap.PARAMS.items():
        if name in ap.RATE_MAX:
            continue
        if name == "SYSID_THISMAV":
            out.append(ParamDef(name, d.kind, float(vehicle.system_id), d.low, d.high, writable=False))
        elif name == "GUID_TIMEOUT":
            out.append(ParamDef(name, d.kind, flight.setpoint_timeout_s, d.low, d.high, set_timeout))
        elif name == "MOT_THST_HOVER":
            value = hover_fraction(p.mass_kg, p.g_mps2, p.max_thrust_N)
            out.append(ParamDef(name, d.kind, value, d.low, d.high, keep(name)))
        else:
            out.append(ParamDef(name, d.kind, kept.get(name), d.low, d.high, keep(name)))
    out += _rate_limits(a, ap.RATE_MAX, mav.MAV_PARAM_TYPE_REAL32)
    out += _tunables(a, mav.MAV_PARAM_TYPE_REAL32, ap.ATC_NAMES)
    return out


#: PX4's MC_*RATE_MAX (their declaration: ``plant.px4_params``); ArduPilot's ATC_RATE_*_MAX reach
#: 1080 deg/s, and 0 is "disabled"
PX4_RATE_RANGE = (PX4_DECLARED["MC_ROLLRATE_MAX"].low, PX4_DECLARED["MC_ROLLRATE_MAX"].high)
ARDUPILOT_RATE_RANGE = (0.0, 1080.0)
NO_LIMIT_DEG_S = 1800.0  #: what ArduPilot's 0 (no limit) is here: the vehicle's largest limit


def _rate_limits(a: Any, names: tuple[str, ...], kind: int) -> list[ParamDef]:
    """The body-rate limits [deg/s], changed in place in the model (``max_rate_rps``). Under
    ArduPilot's names a limit past its range is served as 0, ArduPilot's "disabled"."""
    low, high = ARDUPILOT_RATE_RANGE if names is ap.RATE_MAX else PX4_RATE_RANGE

    def setter(axis: int) -> Callable[[float], None]:
        def put(v: float) -> None:
            a.max_rate_rps[axis] = math.radians(v if v > 0 else NO_LIMIT_DEG_S)

        return put

    def shown(w: float) -> float:
        d = math.degrees(w)
        return d if d <= high else 0.0

    return [
        ParamDef(n, kind, shown(w), low, high, setter(j))
        for j, (n, w) in enumerate(zip(names, a.max_rate_rps, strict=True))
    ]


def _tunables(a: Any, kind: int, renamed: dict[str, str]) -> list[ParamDef]:
    """The model's own parameters (``tunables``), under ``renamed``'s names where it has them,
    each set through the model's ``set_param`` (its own range)."""

    def setter(own: str) -> Callable[[float], None]:
        def put(v: float) -> None:
            if not a.set_param(own, v):
                raise ValueError(own)

        return put

    return [ParamDef(renamed.get(n, n), kind, float(v), apply=setter(n)) for n, v in a.tunables.items()]


PARAMS_OF: dict[str, Callable[[Any, Any], list[ParamDef]]] = {
    "px4": px4_params,
    "ardupilot": ardupilot_params,
}
