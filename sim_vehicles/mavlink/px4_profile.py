"""What a MAVLink tool expects of a PX4 autopilot, as the vehicle provides it (the compatibility profile).

MAVSDK, MAVProxy and QGroundControl read a vehicle that says ``MAV_AUTOPILOT_PX4`` with PX4's
conventions; this module holds them, pure, so the endpoint only sends and receives:

- component ids: the autopilot is MAV_COMP_ID_AUTOPILOT1, its offboard controller the companion
  computer of the same system (``AUTOPILOT``, ``COMPANION``);
- modes: PX4 packs its main mode in bits 16-23 of ``custom_mode`` and its sub mode in bits 24-31
  (``px4_custom_mode.h``). The vehicle's modes are AUTO.LOITER (PX4's "Hold": ``MODE_HOLD``) and
  OFFBOARD (main mode 6). Its failsafe is reported as what it flies, AUTO.LOITER or AUTO.LAND,
  with ``system_status`` MAV_STATE_CRITICAL;
- ``SYS_STATUS`` sensor bits: present, enabled and healthy for what the simulation has (gyro,
  accelerometer, magnetometer, barometer, GPS, rate and attitude control, motors) and the pre-arm
  check, so a ground station finds the vehicle armable and no fence or sensor failing;
- a home (latitude, longitude, altitude) the local ENU position is placed around, on a flat earth
  (``global_of``): GLOBAL_POSITION_INT, GPS_RAW_INT and HOME_POSITION;
- ``AUTOPILOT_VERSION`` capabilities and a version number in PX4's encoding.
"""

import math
from dataclasses import dataclass

from pymavlink.dialects.v20 import common as mav

AUTOPILOT = mav.MAV_COMP_ID_AUTOPILOT1  #: the vehicle's component id (its system id: the follower's)
#: its controller's: the companion computer of the same system (MAV_COMP_ID_ONBOARD_COMPUTER)
COMPANION = mav.MAV_COMP_ID_ONBOARD_COMPUTER

MAIN_AUTO = 4
MAIN_OFFBOARD = 6
SUB_AUTO_LOITER = 3
SUB_AUTO_LAND = 6


def custom_mode(main: int, sub: int = 0) -> int:
    return (main << 16) | (sub << 24)


HOLD = custom_mode(MAIN_AUTO, SUB_AUTO_LOITER)
LAND = custom_mode(MAIN_AUTO, SUB_AUTO_LAND)
OFFBOARD = custom_mode(MAIN_OFFBOARD)

#: base_mode flags PX4 reports with its custom modes (besides SAFETY_ARMED)
BASE_FLAGS = (
    mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    | mav.MAV_MODE_FLAG_AUTO_ENABLED
    | mav.MAV_MODE_FLAG_GUIDED_ENABLED
    | mav.MAV_MODE_FLAG_STABILIZE_ENABLED
)


def requested_mode(param1: float, param2: float, param3: float) -> int | None:
    """The PX4 ``custom_mode`` a MAV_CMD_DO_SET_MODE asks for (param1 base mode with
    CUSTOM_MODE_ENABLED, param2 main mode, param3 sub mode), or None if it is not a custom mode."""
    if not int(param1) & mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
        return None
    main, sub = int(param2), int(param3)
    if not (0 <= main <= 255 and 0 <= sub <= 255) or main != param2 or sub != param3:
        return None
    return custom_mode(main, sub if main == MAIN_AUTO else 0)


SENSORS = (
    mav.MAV_SYS_STATUS_SENSOR_3D_GYRO
    | mav.MAV_SYS_STATUS_SENSOR_3D_ACCEL
    | mav.MAV_SYS_STATUS_SENSOR_3D_MAG
    | mav.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
    | mav.MAV_SYS_STATUS_SENSOR_GPS
    | mav.MAV_SYS_STATUS_SENSOR_ANGULAR_RATE_CONTROL
    | mav.MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION
    | mav.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS
    | mav.MAV_SYS_STATUS_PREARM_CHECK
)

CAPABILITIES = (
    mav.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    | mav.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
    | mav.MAV_PROTOCOL_CAPABILITY_SET_ATTITUDE_TARGET
    | mav.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
)
FLIGHT_SW_VERSION = (1 << 24) | (15 << 16) | (0 << 8) | 255  #: "1.15.0 release", PX4's encoding
#: the earth's radius PX4 projects local positions with (``CONSTANTS_RADIUS_OF_EARTH``,
#: ``src/lib/geo/geo.h``), so a ground station reads our vehicles' positions as PX4's [m]
EARTH_RADIUS_M = 6_371_000.0


@dataclass(frozen=True)
class Home:
    """Where the local frame's origin is on the earth (WGS-84 degrees, metres above mean sea level)."""

    latitude_deg: float = 47.397742  # PX4 SITL's default home (Zurich)
    longitude_deg: float = 8.545594
    altitude_m: float = 488.0

    def global_of(self, east_m: float, north_m: float, up_m: float) -> tuple[float, float, float]:
        """(latitude [deg], longitude [deg], altitude [m]) of a local ENU point, on a flat earth
        tangent at home (metres of error at kilometres from it)."""
        lat = self.latitude_deg + math.degrees(north_m / EARTH_RADIUS_M)
        lon = self.longitude_deg + math.degrees(
            east_m / (EARTH_RADIUS_M * math.cos(math.radians(self.latitude_deg)))
        )
        return lat, lon, self.altitude_m + up_m
