"""What a controller reads of its vehicle: only parameters PX4 or ArduPilot ship (a grep of the
controller's code against ``link.dialects.READ``, each name there cited by the autopilot module
that declares it), and no name of the bench's own; the names our vehicles serve are the
autopilots' own too."""

import re

import pytest

from sim_vehicles.common.state import make_state
from sim_vehicles.mavlink import ardupilot_profile as ap
from sim_vehicles.plant.autopilot import Autopilot
from sim_vehicles.plant.params import AttitudeGains, VehicleParams
from sim_vehicles.vehicle.autopilots import ARDUCOPTER, PX4
from sim_vehicles.vehicle.endpoint import VehicleEndpoint
from swarm_sitl.link.dialects import DIALECTS, READ
from tests.support import ROOT

#: every parameter name each autopilot ships that the bench uses, with where it is declared
#: (PX4-Autopilot and ArduPilot sources, read for this): a name outside these is the bench's own
PX4_SHIPS = {
    "MPC_THR_HOVER": "src/modules/mc_pos_control (Multicopter Position Control)",
    "COM_OF_LOSS_T": "src/modules/commander (offboard loss timeout)",
    "COM_OBL_RC_ACT": "src/modules/commander (offboard loss action)",
    "MC_ROLLRATE_MAX": "src/modules/mc_att_control",
    "MC_PITCHRATE_MAX": "src/modules/mc_att_control",
    "MC_YAWRATE_MAX": "src/modules/mc_att_control",
}
ARDUPILOT_SHIPS = {
    "MOT_THST_HOVER": "libraries/AP_Motors/AP_MotorsMulticopter.cpp",
    "MOT_THST_EXPO": "libraries/AP_Motors/AP_MotorsMulticopter.cpp",
    "GUID_OPTIONS": "ArduCopter/Parameters.cpp",
    "GUID_TIMEOUT": "ArduCopter/Parameters.cpp",
    "SYSID_THISMAV": "libraries/GCS_MAVLink (MAV_SYSID in 4.7)",
    "ATC_ANGLE_BOOST": "libraries/AC_AttitudeControl/AC_AttitudeControl.cpp",
    "ATC_RATE_R_MAX": "libraries/AC_AttitudeControl/AC_AttitudeControl.cpp",
    "ATC_RATE_P_MAX": "libraries/AC_AttitudeControl/AC_AttitudeControl.cpp",
    "ATC_RATE_Y_MAX": "libraries/AC_AttitudeControl/AC_AttitudeControl.cpp",
    "WPNAV_SPEED_UP": "libraries/AC_WPNav/AC_WPNav.cpp",
    "WPNAV_SPEED_DN": "libraries/AC_WPNav/AC_WPNav.cpp",
    "LAND_SPEED": "ArduCopter/Parameters.cpp",
}
#: how the controller's code names a parameter it reads or sets
USES = [
    r'params\[\s*"([A-Z0-9_]+)"\s*\]',
    r'(?:read_param|set_param)\(\s*link,\s*"([A-Z0-9_]+)"',
    r'param_(?:request_read|set)_send\([^)]*b"([A-Z0-9_]+)"',
]


def _controller_sources() -> str:
    return "\n".join(p.read_text() for d in ("link", "nodes") for p in (ROOT / "swarm_sitl" / d).glob("*.py"))


@pytest.mark.unit
def test_the_controller_reads_only_parameters_px4_or_ardupilot_ship():
    code = _controller_sources()
    used = {m for pattern in USES for m in re.findall(pattern, code)}
    declared = {n for d in DIALECTS for n in d.read}
    assert used <= set(READ), f"read but not declared in dialects.READ: {used - set(READ)}"
    assert declared == set(READ)  # each dialect reads exactly what READ says, and READ no more
    ships = set(PX4_SHIPS) | set(ARDUPILOT_SHIPS)
    assert set(READ) <= ships, f"not a parameter either autopilot ships: {set(READ) - ships}"
    for old in ("MASS_KG", "MAX_THRUST_N", "SP_TIMEOUT_S", "COM_OBL_ACT"):  # the bench's own, once
        assert old not in code, old


@pytest.mark.unit
@pytest.mark.parametrize("profile", [PX4, ARDUCOPTER], ids=["px4", "ardupilot"])
def test_our_vehicles_serve_the_autopilots_own_names_and_a_models_gains(profile):
    """Every parameter a vehicle serves is its autopilot's (or, for a model's own gains, PX4's
    ``MC_*`` names under PX4 and ArduPilot's ``ATC_*`` under ArduCopter where it has one)."""
    a = Autopilot(
        VehicleParams(0.85, (0.05, 0.05, 0.09), 25.0), AttitudeGains(16, 16), make_state([0, 0, 1]), 0.001
    )
    ep = VehicleEndpoint(a, 1, profile=profile)
    try:
        names = set(ep.params)
    finally:
        ep.close()
    ships = PX4_SHIPS if profile is PX4 else ARDUPILOT_SHIPS
    assert names <= set(ships), names - set(ships)
    if profile is ARDUCOPTER:
        assert names == set(ap.PARAMS)
    assert {"MPC_THR_HOVER", "MOT_THST_HOVER"} & names
