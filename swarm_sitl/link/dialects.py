"""The two autopilot families a controller flies, as each takes an offboard controller, from the
first message to the last: recognised from the autopilot's HEARTBEAT (``dialect_of``).

=============  ==========================================  ==========================================
               PX4 (``PX4``)                               ArduPilot Copter (``ARDUPILOT``)
=============  ==========================================  ==========================================
parameters     ``MPC_THR_HOVER``                           ``MOT_THST_HOVER``, ``GUID_OPTIONS``,
read                                                       ``ATC_ANGLE_BOOST``
parameters     none                                        ``GUID_OPTIONS`` bit 3 (``ThrustAsThrust``)
set                                                        if clear, read back
engaged by     arm (MAV_CMD_COMPONENT_ARM_DISARM), then    GUIDED_NOGPS (MAV_CMD_DO_SET_MODE, custom
               OFFBOARD (MAV_CMD_DO_SET_MODE, custom main  mode 20), then arm; each answered by its
               mode 6) with setpoints already streaming;   COMMAND_ACK
               each answered by its COMMAND_ACK
thrust field   ``hover * F / (m g)`` (``thrust_map``)      the same, times the commanded tilt's
                                                           cosine while ``ATC_ANGLE_BOOST`` is on
body rates     sent (PX4 feeds forward the yaw rate)       all sent (a mix makes ArduCopter hold)
=============  ==========================================  ==========================================

Streams are asked for with MAV_CMD_SET_MESSAGE_INTERVAL, which both take (ArduPilot since 4.0;
REQUEST_DATA_STREAM's groups have no ATTITUDE_QUATERNION). Every name a controller reads is
here (``READ``): each is a parameter the autopilot ships, cited by the module that declares it.
The vehicle's mass is not among them: no autopilot has it; it comes from the config.
"""

from dataclasses import dataclass
from typing import Any

from pymavlink.dialects.v20 import common as mav

from sim_vehicles.mavlink import ardupilot_profile as ap
from sim_vehicles.mavlink import px4_profile as px4


@dataclass(frozen=True)
class Dialect:
    name: str  #: ``px4`` or ``ardupilot`` (a config's ``autopilot``)
    mav_autopilot: int  #: what its HEARTBEAT says
    hover_param: str  #: the hover thrust, a fraction of full thrust (``thrust_map``)
    read: tuple[str, ...]  #: the parameters read at connect
    mode: tuple[float, float, float]  #: MAV_CMD_DO_SET_MODE's param1..3 that engage it
    mode_name: str
    arm_first: bool  #: PX4 arms, then switches; ArduPilot switches to guided, then arms
    #: PX4 takes OFFBOARD only while setpoints stream (a setpoint before each try)
    stream_before_mode: bool
    #: a mode number its HEARTBEAT's ``custom_mode`` shows when it is engaged
    engaged_mode: int


PX4 = Dialect(
    "px4",
    mav.MAV_AUTOPILOT_PX4,
    "MPC_THR_HOVER",
    ("MPC_THR_HOVER",),
    (float(px4.BASE_FLAGS), float(px4.MAIN_OFFBOARD), 0.0),
    "OFFBOARD",
    arm_first=True,
    stream_before_mode=True,
    engaged_mode=px4.OFFBOARD,
)
ARDUPILOT = Dialect(
    "ardupilot",
    mav.MAV_AUTOPILOT_ARDUPILOTMEGA,
    "MOT_THST_HOVER",
    ("MOT_THST_HOVER", "GUID_OPTIONS", "ATC_ANGLE_BOOST"),
    (float(mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED), float(ap.GUIDED_NOGPS), 0.0),
    "GUIDED_NOGPS",
    arm_first=False,
    stream_before_mode=False,
    engaged_mode=ap.GUIDED_NOGPS,
)
DIALECTS = (PX4, ARDUPILOT)

#: every parameter a controller reads or sets, and where the autopilot that ships it declares it
READ = {
    "MPC_THR_HOVER": "PX4: src/modules/mc_pos_control (Multicopter Position Control), 0.1..0.8",
    "MOT_THST_HOVER": "ArduPilot: libraries/AP_Motors/AP_MotorsMulticopter.cpp",
    "GUID_OPTIONS": "ArduPilot: ArduCopter/Parameters.cpp (g2.guided_options)",
    "ATC_ANGLE_BOOST": "ArduPilot: libraries/AC_AttitudeControl/AC_AttitudeControl.cpp",
}


def dialect_of(heartbeat: Any) -> Dialect | None:
    """The dialect of the autopilot whose HEARTBEAT this is (None: neither PX4 nor ArduPilot)."""
    for d in DIALECTS:
        if heartbeat.autopilot == d.mav_autopilot:
            return d
    return None


def autopilot_name(autopilot: int) -> str:
    """MAV_AUTOPILOT's name for a HEARTBEAT's ``autopilot``."""
    entry = mav.enums["MAV_AUTOPILOT"].get(autopilot)
    return entry.name if entry is not None else f"autopilot {autopilot}"
