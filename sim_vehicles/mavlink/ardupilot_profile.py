"""What a MAVLink tool expects of an ArduCopter, as the vehicle provides it (the ArduPilot profile,
beside ``px4_profile``). From ArduPilot's own sources: ``ArduCopter/mode.h`` (mode numbers),
``ArduCopter/GCS_MAVLink_Copter.cpp`` (``base_mode``, system status, SET_ATTITUDE_TARGET),
``ArduCopter/mode_guided.cpp`` (the angle controller and its timeout), ``AP_Motors`` (hover
throttle, thrust curve), ``AC_AttitudeControl`` (angle boost, rate limits).

- modes: ``custom_mode`` is the mode's number (``mode.h``); the vehicle has STABILIZE, GUIDED,
  LAND and GUIDED_NOGPS (``MODES``); any other is refused (MAV_RESULT_FAILED, as ArduCopter
  answers a mode it cannot enter);
- ``base_mode``: STABILIZE_ENABLED and MANUAL_INPUT_ENABLED always, CUSTOM_MODE_ENABLED, GUIDED_ENABLED
  while its horizontal position controller runs, SAFETY_ARMED when armed
  (``GCS_MAVLINK_Copter::base_mode``);
- SET_ATTITUDE_TARGET (``handle_message_set_attitude_target``), taken in GUIDED and GUIDED_NOGPS
  only: a throttle ignored, a quaternion not of unit length (squared length off 1 by 1e-3 or
  more) or body rates neither all used nor all ignored is refused (``Refusal``); the thrust field
  is a climb rate (0.5 holds the altitude, 1 climbs at ``WPNAV_SPEED_UP``, 0 descends at
  ``WPNAV_SPEED_DN``) unless bit 3 of ``GUID_OPTIONS`` makes it thrust, clamped to -1..1 and
  boosted by the tilt (``thrust_map.boosted_throttle``) when ``ATC_ANGLE_BOOST`` is on; the
  motors turn that thrust into a motor command through ``MOT_THST_EXPO``'s curve and the
  airframe's rotors back into thrust (``motor_thrust``);
- parameters under ArduPilot's names and types (``PARAMS``, each with its MAVLink type);
- AUTOPILOT_VERSION in ArduPilot's encoding (``FLIGHT_SW_VERSION``).
"""

import math
from typing import NamedTuple

from pymavlink.dialects.v20 import common as mav

STABILIZE, GUIDED, LAND, GUIDED_NOGPS = 0, 4, 9, 20
#: the modes this vehicle has, by number (``ArduCopter/mode.h``'s ``Mode::Number``)
MODES = {STABILIZE: "STABILIZE", GUIDED: "GUIDED", LAND: "LAND", GUIDED_NOGPS: "GUIDED_NOGPS"}
GUIDED_MODES = (GUIDED, GUIDED_NOGPS)  #: where SET_ATTITUDE_TARGET is taken (``in_guided_mode``)
THRUST_AS_THRUST = 1 << 3  #: GUID_OPTIONS' SetAttitudeTarget_ThrustAsThrust
#: base_mode flags ArduCopter always reports (besides GUIDED_ENABLED and SAFETY_ARMED)
BASE_FLAGS = (
    mav.MAV_MODE_FLAG_STABILIZE_ENABLED
    | mav.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED
    | mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
)
CAPABILITIES = (
    mav.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    | mav.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
    | mav.MAV_PROTOCOL_CAPABILITY_SET_ATTITUDE_TARGET
    | mav.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
    | mav.MAV_PROTOCOL_CAPABILITY_MISSION_INT
)
FLIGHT_SW_VERSION = (4 << 24) | (6 << 16) | (2 << 8) | 255  #: "4.6.2 official", ArduPilot's encoding
#: the airframe's own thrust curve (thrust = (1 - e) a + e a^2 of motor command a): ArduCopter's
#: default MOT_THST_EXPO, which then linearises it exactly
AIRFRAME_EXPO = 0.65


class Param(NamedTuple):
    """One ArduCopter parameter: its MAVLink type, default and range (None: the vehicle's own)."""

    kind: int  #: MAV_PARAM_TYPE_*
    default: float | None
    low: float
    high: float


#: what this ArduCopter serves, ArduPilot's names and types (defaults as ArduCopter ships them;
#: None: from the vehicle). Rate limits in deg/s, speeds in cm/s, as ArduPilot has them.
PARAMS = {
    "SYSID_THISMAV": Param(mav.MAV_PARAM_TYPE_INT16, None, 1, 255),
    "GUID_OPTIONS": Param(mav.MAV_PARAM_TYPE_INT32, 0.0, 0, 2**16 - 1),
    "GUID_TIMEOUT": Param(mav.MAV_PARAM_TYPE_REAL32, None, 0.1, 5.0),
    "MOT_THST_HOVER": Param(mav.MAV_PARAM_TYPE_REAL32, None, 0.125, 0.6875),
    "MOT_THST_EXPO": Param(mav.MAV_PARAM_TYPE_REAL32, AIRFRAME_EXPO, -1.0, 1.0),
    "ATC_ANGLE_BOOST": Param(mav.MAV_PARAM_TYPE_INT8, 1.0, 0, 1),
    "WPNAV_SPEED_UP": Param(mav.MAV_PARAM_TYPE_REAL32, 250.0, 10.0, 1000.0),
    "WPNAV_SPEED_DN": Param(mav.MAV_PARAM_TYPE_REAL32, 150.0, 10.0, 500.0),
    "LAND_SPEED": Param(mav.MAV_PARAM_TYPE_INT16, 50.0, 30.0, 200.0),
    "ATC_RATE_R_MAX": Param(mav.MAV_PARAM_TYPE_REAL32, None, 0.0, 1080.0),
    "ATC_RATE_P_MAX": Param(mav.MAV_PARAM_TYPE_REAL32, None, 0.0, 1080.0),
    "ATC_RATE_Y_MAX": Param(mav.MAV_PARAM_TYPE_REAL32, None, 0.0, 1080.0),
}
RATE_MAX = ("ATC_RATE_R_MAX", "ATC_RATE_P_MAX", "ATC_RATE_Y_MAX")  #: roll, pitch, yaw [deg/s]
#: a model's own gains under ArduPilot's names, where ArduPilot has one for the same thing
#: (``px4_quad_x``'s PX4 gains; the values stay the model's, in PX4's scale)
ATC_NAMES = {
    "MC_ROLL_P": "ATC_ANG_RLL_P",
    "MC_PITCH_P": "ATC_ANG_PIT_P",
    "MC_YAW_P": "ATC_ANG_YAW_P",
    "MC_ROLLRATE_P": "ATC_RAT_RLL_P",
    "MC_ROLLRATE_I": "ATC_RAT_RLL_I",
    "MC_ROLLRATE_D": "ATC_RAT_RLL_D",
    "MC_RR_INT_LIM": "ATC_RAT_RLL_IMAX",
    "MC_PITCHRATE_P": "ATC_RAT_PIT_P",
    "MC_PITCHRATE_I": "ATC_RAT_PIT_I",
    "MC_PITCHRATE_D": "ATC_RAT_PIT_D",
    "MC_PR_INT_LIM": "ATC_RAT_PIT_IMAX",
    "MC_YAWRATE_P": "ATC_RAT_YAW_P",
    "MC_YAWRATE_I": "ATC_RAT_YAW_I",
    "MC_YAWRATE_D": "ATC_RAT_YAW_D",
    "MC_YR_INT_LIM": "ATC_RAT_YAW_IMAX",
}


def requested_mode(param1: float, param2: float) -> int | None:
    """The mode a MAV_CMD_DO_SET_MODE asks ArduCopter for (param1 with CUSTOM_MODE_ENABLED, param2
    the mode's number), or None if it does not name one this way."""
    if not int(param1) & mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED or param2 != int(param2) or param2 < 0:
        return None
    return int(param2)


#: float's epsilon, 2^-23: ArduPilot's is_zero is ``fabsf(x) < FLT_EPSILON``
FLT_EPSILON = 2.0**-23


def motor_thrust(throttle: float, expo: float, airframe_expo: float = AIRFRAME_EXPO) -> float:
    """The thrust fraction the rotors give for ArduCopter's throttle (thrust) ``throttle``: its
    motor command through ``MOT_THST_EXPO``'s curve (``apply_thrust_curve_and_volt_scaling``, a
    full battery), then the airframe's rotors, ``(1 - e) a + e a^2``. With ``expo`` equal to the
    airframe's the two cancel: thrust is the throttle."""
    t = min(max(throttle, 0.0), 1.0)
    e = min(max(expo, -1.0), 1.0)
    # the root of e a^2 + (1 - e) a = t, ArduPilot's ((e - 1) + sqrt(...)) / (2 e) written without
    # its cancellation for a small e; no curve within float's epsilon (ArduPilot's is_zero). Under
    # the root (1 - e)^2 + 4 e t >= (1 + e)^2 >= 0, but for e near -1 and t near 1 it cancels and
    # may round below 0: taken as 0, as ArduPilot's safe_sqrt does
    root = math.sqrt(max((1.0 - e) * (1.0 - e) + 4.0 * e * t, 0.0))
    a = t if abs(e) < FLT_EPSILON else (2.0 * t / ((1.0 - e) + root) if (1.0 - e) + root > 0.0 else 0.0)
    a = min(max(a, 0.0), 1.0)
    return (1.0 - airframe_expo) * a + airframe_expo * a * a


class Refusal(NamedTuple):
    """Why ArduCopter does not take a SET_ATTITUDE_TARGET (``mode_guided.init(true)`` in its code)."""

    why: str


def check_setpoint(type_mask: int, q: tuple[float, float, float, float]) -> Refusal | None:
    """ArduCopter's checks of a SET_ATTITUDE_TARGET, in its order (None: taken)."""
    if type_mask & 0b0100_0000:
        return Refusal("throttle ignored")
    if not type_mask & 0b1000_0000:
        n2 = sum(v * v for v in q)
        if not (math.isfinite(n2) and abs(n2 - 1.0) < 1e-3):
            return Refusal("quaternion not of unit length")
    rates = type_mask & 0b0000_0111
    if rates not in (0, 0b0000_0111):
        return Refusal("body rates neither all used nor all ignored")
    return None


def climb_rate_of(thrust: float, speed_up_cms: float, speed_dn_cms: float) -> float:
    """The climb rate [m/s] a thrust field asks for when it is a climb rate (GUID_OPTIONS bit 3
    clear): 0.5 holds, 1 climbs at WPNAV_SPEED_UP, 0 descends at WPNAV_SPEED_DN."""
    t = min(max(thrust, 0.0), 1.0)
    if t == 0.5:
        return 0.0
    if t > 0.5:
        return (t - 0.5) * 2.0 * speed_up_cms / 100.0
    return (0.5 - t) * 2.0 * -speed_dn_cms / 100.0


class ArduCopterState:
    """What an ArduCopter's SET_ATTITUDE_TARGET reads of its parameters (``ardupilot_profile``),
    kept as its PARAM_SET leaves them."""

    def __init__(self, hover: float):
        self.values = {n: d.default for n, d in PARAMS.items() if d.default is not None}
        self.values["MOT_THST_HOVER"] = hover

    def get(self, name: str) -> float:
        return float(self.values[name])

    def set(self, name: str, value: float) -> None:
        self.values[name] = float(value)

    @property
    def thrust_as_thrust(self) -> bool:
        return bool(int(self.values["GUID_OPTIONS"]) & THRUST_AS_THRUST)

    @property
    def angle_boost(self) -> bool:
        return bool(round(self.values["ATC_ANGLE_BOOST"]))
