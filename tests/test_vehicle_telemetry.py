"""What a ground station reads of a vehicle in any state (``vehicle.telemetry``), parsed back with
pymavlink and checked against MAVLink's units and frames and against the physics: positions on a
flat earth about home (degE7, mm), NED velocities in cm/s, the heading of the body's nose from
north, the IMU's specific force (thrust over mass flying, the stand's reaction held) and rates in
FRD, the status and landed state as PX4 reports them. The endpoint is driven in process."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import common as mav

from sim_vehicles.common.command import AttitudeCommand
from sim_vehicles.common.quaternion import rotation_matrix
from sim_vehicles.common.state import make_state
from sim_vehicles.mavlink import px4_profile as px4
from sim_vehicles.plant.sensors import SensorModel
from sim_vehicles.vehicle.endpoint import VehicleEndpoint
from tests.fakes import ENDPOINT_PARAMS as PARAMS
from tests.fakes import recording_endpoint
from tests.strategies import unit_quaternions

pytestmark = pytest.mark.integration  # (an endpoint driven in process)
EARTH_RADIUS_M = 6371000.0  #: PX4's CONSTANTS_RADIUS_OF_EARTH (src/lib/geo/geo.h): its flat-earth offsets
span = st.floats(-500, 500)
speed = st.floats(-20, 20)


def _telemetry(ep: VehicleEndpoint, msg_id: int, ms: int):
    ep.port.sock.sent.clear()
    ep.telemetry.senders[msg_id](ep.port, ms)
    ep.port.flush()
    (m,) = [m for d in ep.port.sock.sent for m in mav.MAVLink(None).parse_buffer(d) or []]
    return m


@pytest.fixture(scope="module")  # (each example sets the state it reads)
def endpoint():
    ep = recording_endpoint(3)
    ep.port.peer = ("127.0.0.1", 40001)
    yield ep
    ep.close()


@settings(max_examples=60, deadline=None)
@given(
    st.tuples(span, span, span),
    st.tuples(speed, speed, speed),
    unit_quaternions(),
    st.tuples(speed, speed, speed),
    st.floats(-5.0, 40.0),
    st.booleans(),
    st.integers(0, 2**31),
)
def test_a_ground_station_reads_the_vehicles_state_in_mavlinks_units_and_frames(
    endpoint, p, v, q, w, thrust_N, armed, ms
):
    ep = endpoint
    ep.autopilot.state[:] = make_state(p, v, q, w)
    ep.autopilot.command = AttitudeCommand(np.array([1.0, 0.0, 0.0, 0.0]), thrust_N)
    ep.flight.armed = armed
    home = ep.home
    e, n, u = p

    g = _telemetry(ep, mav.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, ms)
    lat = home.latitude_deg + math.degrees(n / EARTH_RADIUS_M)
    lon = home.longitude_deg + math.degrees(e / (EARTH_RADIUS_M * math.cos(math.radians(home.latitude_deg))))
    assert abs(g.lat - lat * 1e7) <= 0.5 + 1e-6 and abs(g.lon - lon * 1e7) <= 0.5 + 1e-6
    assert abs(g.alt - (home.altitude_m + u) * 1000) <= 0.5 + 1e-6 and abs(g.relative_alt - u * 1000) <= 0.5
    for got, ned_mps in ((g.vx, v[1]), (g.vy, v[0]), (g.vz, -v[2])):  # NED [cm/s]
        assert abs(got - ned_mps * 100) <= 0.5 + 1e-9
    nose = rotation_matrix(np.array(q))[:, 0]  # ENU: its heading from north, clockwise
    heading = math.degrees(math.atan2(nose[0], nose[1])) % 360.0
    assert 0 <= g.hdg < 36000
    diff = abs(g.hdg - heading * 100) % 36000
    assert min(diff, 36000 - diff) <= 0.5 + 1e-6

    imu = _telemetry(ep, mav.MAVLINK_MSG_ID_HIGHRES_IMU, ms)
    if armed:  # flying: thrust over mass along the body's up axis (FRD: -z)
        f_frd = np.array([0.0, 0.0, -min(max(thrust_N, 0.0), PARAMS.max_thrust_N) / PARAMS.mass_kg])
    else:  # held on its stand: the reaction to gravity, in the body frame
        f_flu = rotation_matrix(np.array(q)).T @ np.array([0.0, 0.0, PARAMS.g_mps2])
        f_frd = f_flu * np.array([1.0, -1.0, -1.0])
    got = np.array([imu.xacc, imu.yacc, imu.zacc])
    assert np.allclose(got, f_frd, rtol=2**-23, atol=1e-6)
    assert np.allclose([imu.xgyro, imu.ygyro, imu.zgyro], np.array(w) * [1, -1, -1], rtol=2**-23, atol=1e-6)
    assert (imu.xmag, imu.ymag, imu.zmag, imu.diff_pressure, imu.pressure_alt) == (0, 0, 0, 0, 0)
    assert imu.time_usec == ms * 1000 and imu.fields_updated == 0b111111

    gps = _telemetry(ep, mav.MAVLINK_MSG_ID_GPS_RAW_INT, ms)
    assert (gps.lat, gps.lon, gps.alt) == (g.lat, g.lon, g.alt) and gps.fix_type == mav.GPS_FIX_TYPE_3D_FIX
    assert abs(gps.vel - math.hypot(v[0], v[1]) * 100) <= 0.5 + 1e-9 and gps.time_usec == ms * 1000

    landed = _telemetry(ep, mav.MAVLINK_MSG_ID_EXTENDED_SYS_STATE, ms).landed_state
    assert landed == (mav.MAV_LANDED_STATE_IN_AIR if armed else mav.MAV_LANDED_STATE_ON_GROUND)


def test_the_status_says_every_sensor_present_enabled_and_healthy_and_home_where_it_is(endpoint):
    ep = endpoint
    s = _telemetry(ep, mav.MAVLINK_MSG_ID_SYS_STATUS, 5)
    assert s.onboard_control_sensors_present == s.onboard_control_sensors_enabled == px4.SENSORS
    assert s.onboard_control_sensors_health & px4.SENSORS == px4.SENSORS
    assert s.onboard_control_sensors_health & mav.MAV_SYS_STATUS_GEOFENCE  # no fence: none breached
    assert s.drop_rate_comm == s.errors_comm == 0
    h = _telemetry(ep, mav.MAVLINK_MSG_ID_HOME_POSITION, 5)
    home = ep.home
    assert (h.latitude, h.longitude) == (round(home.latitude_deg * 1e7), round(home.longitude_deg * 1e7))
    assert h.altitude == round(home.altitude_m * 1000) and (h.x, h.y, h.z) == (0.0, 0.0, 0.0)
    # a multicopter lands straight down: its approach vector ends where home is
    assert (h.approach_x, h.approach_y, h.approach_z) == (h.x, h.y, h.z)


@settings(max_examples=30, deadline=None)
@given(
    noise=st.tuples(st.floats(0, 2), st.floats(0, 2), st.floats(0, 0.3), st.floats(0, 0.5)),
    latency_s=st.sampled_from([0.0, 0.004, 0.05]),
    seed=st.integers(0, 2**31),
    states=st.lists(
        st.tuples(st.tuples(span, span, span), st.tuples(speed, speed, speed), unit_quaternions()),
        min_size=1,
        max_size=6,
    ),
)
def test_a_vehicle_with_sensors_sends_its_sensor_models_report_of_its_truth(noise, latency_s, seed, states):
    """LOCAL_POSITION_NED and ATTITUDE_QUATERNION of a vehicle with sensor noise and latency
    (``plant.sensors``) are, byte for byte, what a vehicle without them sends when its truth is
    what an identical sensor model, fed the same truths at the same instants, reports."""

    def model():
        pos, vel, att, walk = noise
        return SensorModel(3, pos, vel, att, latency_s, seed, position_bias_walk_m_per_sqrt_s=walk)

    noisy, plain, reference = recording_endpoint(3, sensors=model()), recording_endpoint(3), model()
    noisy.port.peer = plain.port.peer = ("127.0.0.1", 40001)
    try:
        for k, (p, v, q) in enumerate(states):
            ms = 20 * k + 7  # (a sample every 20 ms: latencies of none, less than one, more than two)
            noisy.autopilot.state[:] = make_state(p, v, q)
            plain.autopilot.state[:] = reference.reported(ms, make_state(p, v, q))
            for msg_id in (mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED, mav.MAVLINK_MSG_ID_ATTITUDE_QUATERNION):
                got, want = _telemetry(noisy, msg_id, ms), _telemetry(plain, msg_id, ms)
                assert got.get_payload() == want.get_payload(), (k, got, want)
        assert any(noise) or noisy.autopilot.state.tolist() == plain.autopilot.state.tolist()
    finally:
        noisy.close()
        plain.close()
