"""A controller's start-up as the autopilot hears it (``link.handshake`` through ``VehicleLink``,
against ``tests.fake_autopilot``, which keeps every message it received): what it reads and sets,
the stream rates it asks, the mode and the arming in each autopilot's order, every request
addressed to the vehicle's autopilot component, a temporary refusal tried again, and a vehicle
that never answers ended in one line at the timeout."""

import math
import socket
import time

import pytest
from pymavlink.dialects.v20 import common as mav

from sim_vehicles.mavlink import ardupilot_profile as ap
from sim_vehicles.mavlink import px4_profile as px4
from sim_vehicles.mavlink.thrust_map import full_thrust_N
from sim_vehicles.mavlink.wire_format import f32
from swarm_sitl.link.dialects import ARDUPILOT, PX4
from swarm_sitl.link.transport import LinkError
from swarm_sitl.link.vehicle_link import VehicleLink
from tests.fake_autopilot import FakeAutopilot

pytestmark = pytest.mark.integration
TIMEOUT_S = 1.5
LPOS, ATTQ = mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED, mav.MAVLINK_MSG_ID_ATTITUDE_QUATERNION
OTHERS = (mav.MAVLINK_MSG_ID_ATTITUDE, mav.MAVLINK_MSG_ID_HIGHRES_IMU)
ADDRESSED = {"PARAM_REQUEST_READ", "PARAM_SET", "COMMAND_LONG", "SET_ATTITUDE_TARGET"}


@pytest.mark.parametrize("lockstep", [False, True])
@pytest.mark.parametrize(
    ("kind", "period_s", "other_hz", "guid_options"),
    [
        ("px4", 0.01, 0.0, None),
        ("px4", 0.02, 4.0, None),
        ("ardupilot", 0.01, 2.0, 0),
        ("ardupilot", 0.004, 0.0, 8),
    ],
)
def test_the_autopilot_hears_what_its_dialect_reads_the_rates_asked_and_its_mode_and_arming_in_order(
    kind, period_s, other_hz, guid_options, lockstep
):
    sysid, mass_kg, g = 5, 1.3, 9.81
    params = (
        None
        if guid_options is None
        else {"MOT_THST_HOVER": 0.35, "GUID_OPTIONS": guid_options, "ATC_ANGLE_BOOST": 1.0}
    )
    with FakeAutopilot(kind, sysid, params=params) as fake:
        link = VehicleLink(f"udpout:127.0.0.1:{fake.port}", sysid, stamp_arrivals=False)
        try:
            dialect = link.connect(TIMEOUT_S, mass_kg, g)
            link.request_rates(period_s, other_hz, TIMEOUT_S)
            link.engage(TIMEOUT_S, lockstep=lockstep)
            sample_ms = link.sample_ms
            full = link.full_thrust_N
        finally:
            link.close()
        heard = list(fake.heard)
        hover = fake.params[dialect.hover_param]
    assert dialect is (PX4 if kind == "px4" else ARDUPILOT)
    # the thrust map: the hover fraction it serves (float32 on the wire) is m g
    assert full == full_thrust_N(mass_kg, g, f32(hover)[0])
    # every request to the vehicle's autopilot (system sysid, component 1)
    for m in heard:
        if m.get_type() in ADDRESSED:
            assert (m.target_system, m.target_component) == (sysid, 1), m
    reads = {m.param_id for m in heard if m.get_type() == "PARAM_REQUEST_READ"}
    assert reads == set(dialect.read)
    assert all(m.param_index == -1 for m in heard if m.get_type() == "PARAM_REQUEST_READ")
    sets = [(m.param_id, m.param_value, m.param_type) for m in heard if m.get_type() == "PARAM_SET"]
    if kind == "ardupilot" and not guid_options & ap.THRUST_AS_THRUST:  # thrust as thrust: bit 3 set
        assert set(sets) == {("GUID_OPTIONS", guid_options | ap.THRUST_AS_THRUST, mav.MAV_PARAM_TYPE_INT32)}
    else:
        assert sets == []
    commands = [m for m in heard if m.get_type() == "COMMAND_LONG"]
    for c in commands:  # the parameters a command does not use are 0
        used = {
            mav.MAV_CMD_SET_MESSAGE_INTERVAL: 2,
            mav.MAV_CMD_DO_SET_MODE: 3,
            mav.MAV_CMD_COMPONENT_ARM_DISARM: 1,
        }
        rest = [c.param1, c.param2, c.param3, c.param4, c.param5, c.param6, c.param7][used[c.command] :]
        assert rest == [0.0] * len(rest), c
    intervals = {int(c.param1): c.param2 for c in commands if c.command == mav.MAV_CMD_SET_MESSAGE_INTERVAL}
    other_us = 1e6 / other_hz if other_hz > 0 else -1.0
    assert intervals == {LPOS: f32(period_s * 1e6)[0], ATTQ: f32(period_s * 1e6)[0]} | dict.fromkeys(
        OTHERS, f32(other_us)[0]
    )
    modes = [c for c in commands if c.command == mav.MAV_CMD_DO_SET_MODE]
    arms = [c for c in commands if c.command == mav.MAV_CMD_COMPONENT_ARM_DISARM]
    assert modes and arms and all(a.param1 == 1.0 for a in arms)
    for c in modes:
        assert int(c.param1) & mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        if kind == "px4":
            assert (c.param2, c.param3) == (px4.MAIN_OFFBOARD, 0.0)
        else:
            assert c.param2 == ap.GUIDED_NOGPS
    first_mode, first_arm = heard.index(modes[0]), heard.index(arms[0])
    setpoints = [j for j, m in enumerate(heard) if m.get_type() == "SET_ATTITUDE_TARGET"]
    if kind == "px4":  # armed, then OFFBOARD with a setpoint stream already running
        assert first_arm < first_mode and any(first_arm < j < first_mode for j in setpoints)
        before = [heard[j] for j in setpoints if j < first_mode]
        if lockstep:  # a clock-only setpoint at the vehicle's time: every field ignored
            assert all(m.type_mask == 0b1100_0111 and 0 <= m.time_boot_ms <= sample_ms for m in before)
        else:  # its attitude now at hover thrust
            assert all(m.type_mask == 0 and m.thrust == pytest.approx(hover, rel=1e-6) for m in before)
    else:  # GUIDED_NOGPS first, then armed; no setpoint before the mode
        assert first_mode < first_arm and not [j for j in setpoints if j < first_mode]


def test_a_mode_refused_for_now_is_asked_again_until_taken():
    """PX4 answers OFFBOARD TEMPORARILY_REJECTED until it has seen the stream: asked again (with
    the stream before each try) until accepted, within the timeout."""
    with FakeAutopilot("px4", 4, busy_mode=3) as fake:
        link = VehicleLink(f"udpout:127.0.0.1:{fake.port}", 4, stamp_arrivals=False)
        try:
            link.connect(TIMEOUT_S * 4, 1.0, 9.81)
            link.engage(TIMEOUT_S * 4, lockstep=False)
        finally:
            link.close()
        modes = [
            m for m in fake.heard if m.get_type() == "COMMAND_LONG" and m.command == mav.MAV_CMD_DO_SET_MODE
        ]
    assert len(modes) == 4 and fake.busy_mode == 0


def test_a_vehicle_that_never_answers_ends_the_handshake_at_its_timeout_in_one_line():
    """Nothing but silence at the address: no HEARTBEAT within the timeout, said in one line
    naming the follower and the system (no STATUSTEXT: none came), after the timeout and not
    much later."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as silent:
        silent.bind(("127.0.0.1", 0))
        url = f"udpout:127.0.0.1:{silent.getsockname()[1]}"
        link = VehicleLink(url, 6, stamp_arrivals=False)
        t0 = time.monotonic()
        try:
            with pytest.raises(LinkError) as e:
                link.connect(0.5, 1.0, 9.81)
        finally:
            link.close()
        waited = time.monotonic() - t0
    assert str(e.value) == f"follower 6: {url}: no HEARTBEAT from system 6 within 0.5 s"
    assert 0.5 <= waited < 0.5 + 1.0 and math.isfinite(waited)
