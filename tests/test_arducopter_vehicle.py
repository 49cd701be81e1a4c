"""A simulated vehicle speaking as ArduCopter (``vehicle.autopilot: ardupilot``), driven in
lockstep by a pymavlink client with only pymavlink's public API: its HEARTBEAT and modes as
pymavlink names them, its parameters under ArduPilot's names and types, and SET_ATTITUDE_TARGET
as ArduCopter reads it: a climb rate by default, thrust with GUID_OPTIONS bit 3 (boosted by the
tilt), a refusal for a non-unit quaternion or mixed rate bits, level at its altitude when
setpoints stop in GUIDED_NOGPS and a position hold in GUIDED."""

import math

import numpy as np
import pytest
from pymavlink import mavutil

from sim_vehicles.common.state import POS, QUAT, VEL, make_state
from sim_vehicles.mavlink import ardupilot_profile as ap
from sim_vehicles.mavlink import px4_profile as px4
from sim_vehicles.mavlink.thrust_map import boosted_throttle, cos_tilt, hover_fraction
from sim_vehicles.plant.autopilot import Autopilot
from sim_vehicles.plant.params import AttitudeGains, VehicleParams
from sim_vehicles.vehicle.autopilots import ARDUCOPTER, PX4
from sim_vehicles.vehicle.endpoint import VehicleEndpoint

pytestmark = pytest.mark.integration
mav = mavutil.mavlink
PARAMS = VehicleParams(0.85, (0.05, 0.05, 0.09), 25.0)
PERIOD_MS = 10


@pytest.fixture
def copter():
    a = Autopilot(PARAMS, AttitudeGains(16.0, 16.0), make_state([1.0, 2.0, 30.0]), 0.001)
    ep = VehicleEndpoint(a, 5, lockstep_period_s=0.01, setpoint_timeout_s=0.5, profile=ARDUCOPTER)
    conn = mavutil.mavlink_connection(
        f"udpout:127.0.0.1:{ep.address[1]}", source_system=5, source_component=191
    )
    yield ep, conn
    conn.close()
    ep.close()


def _serve(ep, conn, kind=None, cond=lambda m: True):
    """The vehicle serves what came; the first message of ``kind`` back (all of them: None)."""
    ep.poll()
    found = None
    while (m := conn.recv_match(blocking=True, timeout=0.3)) is not None:
        if found is None and m.get_type() == kind and cond(m):
            found = m
            break
    return found


def _command(ep, conn, command, *params):
    p = [*params, 0, 0, 0, 0, 0, 0, 0][:7]
    conn.mav.command_long_send(5, 1, command, 0, *p)
    ack = _serve(ep, conn, "COMMAND_ACK", lambda m: m.command == command)
    assert ack is not None
    return ack.result


def _param(ep, conn, name, value=None, kind=mav.MAV_PARAM_TYPE_REAL32):
    if value is None:
        conn.mav.param_request_read_send(5, 1, name.encode(), -1)
    else:
        conn.mav.param_set_send(5, 1, name.encode(), float(value), kind)
    m = _serve(ep, conn, "PARAM_VALUE", lambda m: m.param_id == name)
    assert m is not None, name
    return m


def _heartbeat(ep, conn):
    conn.mav.heartbeat_send(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0)
    ep.send_heartbeat(ep.port)
    ep.port.flush()
    return _serve(ep, conn, "HEARTBEAT", lambda m: m.get_srcSystem() == 5)


def _setpoint(ep, conn, q=(1.0, 0.0, 0.0, 0.0), thrust=0.5, mask=0, rates=(0.0, 0.0, 0.0)):
    conn.mav.set_attitude_target_send(ep.time_boot_ms, 5, 1, mask, list(q), *rates, thrust)
    ep.poll()
    while conn.recv_match(blocking=False) is not None:
        pass


def _clock_only(ep, conn):
    """A lockstep clock-only setpoint one period ahead: the vehicle flies a period on what it
    holds and counts no setpoint."""
    conn.mav.set_attitude_target_send(
        ep.time_boot_ms + PERIOD_MS, 5, 1, 0b1100_0111, [1, 0, 0, 0], 0, 0, 0, 0
    )
    ep.poll()
    while conn.recv_match(blocking=False) is not None:
        pass


def _guided_nogps(ep, conn):
    assert _command(ep, conn, mav.MAV_CMD_DO_SET_MODE, 1, ap.GUIDED_NOGPS) == mav.MAV_RESULT_ACCEPTED
    assert _command(ep, conn, mav.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mav.MAV_RESULT_ACCEPTED


def test_its_heartbeat_modes_and_base_mode_are_arducopters_as_pymavlink_names_them(copter):
    ep, conn = copter
    hb = _heartbeat(ep, conn)
    assert hb.autopilot == mav.MAV_AUTOPILOT_ARDUPILOTMEGA and hb.type == mav.MAV_TYPE_QUADROTOR
    assert mavutil.mode_string_v10(hb) == "STABILIZE" and not hb.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED
    mapping = mavutil.mode_mapping_byname(mav.MAV_TYPE_QUADROTOR)  # pymavlink's ArduCopter table
    for name in ("GUIDED", "LAND", "GUIDED_NOGPS", "STABILIZE"):
        assert _command(ep, conn, mav.MAV_CMD_DO_SET_MODE, 1, mapping[name]) == mav.MAV_RESULT_ACCEPTED
        hb = _heartbeat(ep, conn)
        assert mavutil.mode_string_v10(hb) == name and hb.custom_mode == mapping[name]
        guided = bool(hb.base_mode & mav.MAV_MODE_FLAG_GUIDED_ENABLED)
        assert guided == (name in ("GUIDED", "LAND"))
        assert hb.base_mode & ap.BASE_FLAGS == ap.BASE_FLAGS
    for name in ("AUTO", "LOITER", "RTL", "ACRO"):  # modes this vehicle does not have
        assert _command(ep, conn, mav.MAV_CMD_DO_SET_MODE, 1, mapping[name]) == mav.MAV_RESULT_FAILED
    assert _command(ep, conn, mav.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mav.MAV_RESULT_ACCEPTED
    assert _heartbeat(ep, conn).base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED


def test_its_parameters_are_ardupilots_names_types_and_values(copter):
    ep, conn = copter
    want = {n: d.kind for n, d in ap.PARAMS.items()}
    for name, kind in want.items():
        assert _param(ep, conn, name).param_type == kind, name
    assert _param(ep, conn, "SYSID_THISMAV").param_value == 5
    hover = _param(ep, conn, "MOT_THST_HOVER").param_value
    assert hover == pytest.approx(hover_fraction(0.85, 9.81, 25.0), rel=2**-23)
    assert _param(ep, conn, "GUID_OPTIONS").param_value == 0  # as it ships: thrust is a climb rate
    assert _param(ep, conn, "GUID_OPTIONS", 8, mav.MAV_PARAM_TYPE_INT32).param_value == 8
    assert ep.ardupilot.thrust_as_thrust
    assert _param(ep, conn, "GUID_OPTIONS", 2.5e9, mav.MAV_PARAM_TYPE_INT32).param_value == 8  # refused
    assert _param(ep, conn, "SYSID_THISMAV", 9, mav.MAV_PARAM_TYPE_INT16).param_value == 5  # read-only
    assert _param(ep, conn, "GUID_TIMEOUT", 2.0).param_value == 2.0 and ep.flight.setpoint_timeout_s == 2.0
    assert _param(ep, conn, "ATC_RATE_Y_MAX", 90.0).param_value == 90.0
    assert ep.autopilot.max_rate_rps[2] == pytest.approx(math.radians(90.0))
    conn.mav.param_request_read_send(5, 1, b"MPC_THR_HOVER", -1)  # PX4's name: not an ArduCopter's
    assert _serve(ep, conn, "PARAM_VALUE") is None


def _fly(ep, conn, periods, **setpoint):
    for _ in range(periods):
        _setpoint(ep, conn, **setpoint)


def test_thrust_is_a_climb_rate_as_it_ships_and_thrust_with_guid_options_bit_3(copter):
    ep, conn = copter
    _guided_nogps(ep, conn)
    z0 = ep.autopilot.state[POS][2]
    _fly(ep, conn, 200, thrust=0.5)  # 2 s at 0.5: its altitude held
    assert abs(ep.autopilot.state[POS][2] - z0) < 0.02 and abs(ep.autopilot.state[VEL][2]) < 0.02
    _fly(ep, conn, 300, thrust=1.0)  # 3 s at 1.0: climbing at WPNAV_SPEED_UP, 2.5 m/s
    assert ep.autopilot.state[VEL][2] == pytest.approx(2.5, abs=0.05)
    _param(ep, conn, "GUID_OPTIONS", 8, mav.MAV_PARAM_TYPE_INT32)
    tilt = 0.3  # [rad] about the body x axis
    q_ned = (math.cos(tilt / 2), math.sin(tilt / 2), 0.0, 0.0)
    _fly(ep, conn, 50, q=q_ned, thrust=0.35)  # (tilted by now: the boost is past 1)
    for field in (0.2, 0.45, 0.3, 0.38):
        c = cos_tilt(ep.autopilot.state[QUAT])  # the tilt it takes the setpoint at
        _setpoint(ep, conn, q=q_ned, thrust=field)
        want = boosted_throttle(float(np.float32(field)), c) * 25.0  # (float32 on the wire)
        assert ep.autopilot.command.thrust_N == pytest.approx(want, rel=1e-9)
    assert cos_tilt(ep.autopilot.state[QUAT]) < math.cos(0.2)  # (tilted: the boost was > 1)
    _param(ep, conn, "ATC_ANGLE_BOOST", 0, mav.MAV_PARAM_TYPE_INT8)
    _setpoint(ep, conn, q=q_ned, thrust=0.45)
    assert ep.autopilot.command.thrust_N == pytest.approx(float(np.float32(0.45)) * 25.0, rel=1e-9)
    _setpoint(ep, conn, q=q_ned, thrust=-0.7)  # clamped to -1..1, and motors take no negative
    assert ep.autopilot.command.thrust_N == 0.0


def test_a_climb_rate_after_thrust_setpoints_holds_the_altitude_where_it_came(copter):
    """Thrust setpoints (GUID_OPTIONS bit 3) carry it up; with the bit cleared, a climb rate of 0
    holds the altitude it had when that first climb setpoint came, not where guided began."""
    ep, conn = copter
    _param(ep, conn, "GUID_OPTIONS", 8, mav.MAV_PARAM_TYPE_INT32)
    _guided_nogps(ep, conn)
    z_guided = ep.autopilot.state[POS][2]
    _fly(ep, conn, 100, thrust=0.45)  # 1 s at 1.3x the hover thrust: climbing
    _param(ep, conn, "GUID_OPTIONS", 0, mav.MAV_PARAM_TYPE_INT32)
    z_climb = ep.autopilot.state[POS][2]
    assert z_climb - z_guided > 1.0
    _fly(ep, conn, 400, thrust=0.5)  # 4 s of climb rate 0
    # the altitude loop is a critically damped PD (2/s): from v0 < 4 m/s up, v0 t exp(-2 t) is
    # under 0.006 m and its rate under 0.01 m/s at 4 s; ten times that for the attitude loop's lag
    # and the thrust clipped at 0 as it brakes
    assert ep.autopilot.state[POS][2] == pytest.approx(z_climb, abs=0.05)
    assert abs(ep.autopilot.state[VEL][2]) < 0.05


@pytest.mark.parametrize(
    ("mask", "q", "why"),
    [
        (0, (0.9, 0.0, 0.0, 0.0), "not of unit length"),
        (0b001, (1.0, 0.0, 0.0, 0.0), "mixed rate bits"),
        (0b110, (1.0, 0.0, 0.0, 0.0), "mixed rate bits"),
        (0b0100_0000, (1.0, 0.0, 0.0, 0.0), "throttle ignored"),
    ],
)
def test_a_setpoint_arducopter_refuses_changes_nothing_and_in_guided_it_holds(copter, mask, q, why):
    ep, conn = copter
    _param(ep, conn, "GUID_OPTIONS", 8, mav.MAV_PARAM_TYPE_INT32)
    _guided_nogps(ep, conn)
    taken = ep.stats.setpoints
    _fly(ep, conn, 5, thrust=0.34, rates=(0.1, 0.0, 0.0))
    assert ep.stats.setpoints == taken + 5  # each setpoint it takes counted once
    held = ep.autopilot.command
    invalid = ep.stats.rx_invalid
    _setpoint(ep, conn, q=q, thrust=0.9, mask=mask)
    assert ep.stats.rx_invalid == invalid + 1 and ep.stats.setpoints == taken + 5, why
    assert ep.autopilot.command is held or np.array_equal(ep.autopilot.command.q_c, held.q_c)
    assert _command(ep, conn, mav.MAV_CMD_DO_SET_MODE, 1, ap.GUIDED) == mav.MAV_RESULT_ACCEPTED
    _fly(ep, conn, 3, thrust=0.34)
    p0 = ep.autopilot.state[POS].copy()
    _setpoint(ep, conn, q=q, thrust=0.9, mask=mask)  # in GUIDED: a position hold from here
    for _ in range(300):  # 3 s with no setpoint taken: it holds where the refusal found it
        _clock_only(ep, conn)
    assert np.linalg.norm(ep.autopilot.state[POS] - p0) < 0.3


def test_when_setpoints_stop_guided_nogps_levels_at_its_altitude_and_stays_in_its_mode(copter):
    """``GUID_TIMEOUT`` after the last setpoint: level (at its heading), its altitude held, no
    position hold (it drifts on), still GUIDED_NOGPS and MAV_STATE_ACTIVE; a setpoint takes it back."""
    ep, conn = copter
    _param(ep, conn, "GUID_OPTIONS", 8, mav.MAV_PARAM_TYPE_INT32)
    _guided_nogps(ep, conn)
    tilt = 0.2
    q_ned = (math.cos(tilt / 2), 0.0, math.sin(tilt / 2), 0.0)  # nose down: accelerating north
    _fly(ep, conn, 100, q=q_ned, thrust=0.34 / math.cos(tilt))
    z = ep.autopilot.state[POS][2]
    for _ in range(250):  # 2.5 s of clock-only setpoints: none taken
        _clock_only(ep, conn)
    x = ep.autopilot.state
    assert cos_tilt(x[QUAT]) > math.cos(math.radians(2.0))  # level
    assert abs(x[POS][2] - z) < 0.3 and abs(x[VEL][2]) < 0.1  # its altitude held
    assert np.linalg.norm(x[VEL][0:2]) > 0.5  # drifting on: no horizontal hold in NOGPS
    hb = _heartbeat(ep, conn)
    assert mavutil.mode_string_v10(hb) == "GUIDED_NOGPS" and hb.system_status == mav.MAV_STATE_ACTIVE
    _setpoint(ep, conn, q=q_ned, thrust=0.3)
    assert ep.offboard


def test_pymavlink_names_the_px4_profiles_modes_too():
    a = Autopilot(PARAMS, AttitudeGains(16.0, 16.0), make_state([0.0, 0.0, 10.0]), 0.001)
    ep = VehicleEndpoint(a, 6, lockstep_period_s=0.01, profile=PX4)
    conn = mavutil.mavlink_connection(
        f"udpout:127.0.0.1:{ep.address[1]}", source_system=6, source_component=191
    )
    try:
        conn.mav.heartbeat_send(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        ep.poll()
        ep.send_heartbeat(ep.port)
        ep.port.flush()
        hb = None
        while (m := conn.recv_match(blocking=True, timeout=0.5)) is not None:
            if m.get_type() == "HEARTBEAT":
                hb = m
                break
        assert hb is not None and hb.autopilot == mav.MAV_AUTOPILOT_PX4 and hb.custom_mode == px4.HOLD
        assert mavutil.mode_string_v10(hb) == "LOITER"  # pymavlink's name of PX4's AUTO.LOITER
    finally:
        conn.close()
        ep.close()
