"""The vehicle's own setpoint-loss failsafe (``sim_vehicles.plant.failsafe``): the attitude it asks for,
and the hold and the landing it flies, closed loop on the plant and the attitude loop."""

import math
import time

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from pymavlink.dialects.v20 import common as mav

from sim_vehicles.common.command import AttitudeCommand
from sim_vehicles.common.quaternion import qconj, qmul, rotation_matrix
from sim_vehicles.common.state import POS, VEL, make_state
from sim_vehicles.mavlink import px4_profile as px4
from sim_vehicles.plant.autopilot import Autopilot
from sim_vehicles.plant.failsafe import (
    ACTION_HOLD,
    ACTION_LAND,
    ACTION_LEVEL,
    FAILSAFE_PERIOD_S,
    LAND_SPEED_MPS,
    Hold,
    attitude_for,
    climb_command,
    failsafe_command,
    hold_at,
)
from sim_vehicles.plant.params import AttitudeGains, VehicleParams
from sim_vehicles.vehicle.autopilots import ARDUCOPTER, PX4
from sim_vehicles.vehicle.modes import MODE_FAILSAFE, MODE_HOLD, MODE_OFFBOARD, FlightModes
from tests.strategies import unit_quaternions

PARAMS = VehicleParams(0.85, (0.04856, 0.04856, 0.08801), 25.0)
GAINS = AttitudeGains(16.0, 16.0)


@pytest.mark.unit
@given(
    st.floats(-5, 5),
    st.floats(-5, 5),
    st.floats(0.5, 20),
    st.floats(-math.pi + 1e-3, math.pi - 1e-3),
)
def test_the_attitude_points_thrust_along_the_acceleration_and_keeps_the_heading(ax, ay, az, yaw):
    acc = np.array([ax, ay, az])
    q = attitude_for(acc, yaw)
    R = rotation_matrix(q)
    assert np.linalg.norm(q) == pytest.approx(1.0)
    assert np.allclose(R[:, 2], acc / np.linalg.norm(acc), atol=1e-9)
    # the heading kept: q is the heading's rotation about e3, then a tilt about a horizontal axis
    # (a swing with no twist: no z component in the swing-twist decomposition)
    heading = np.array([math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)])
    assert qmul(qconj(heading), q)[3] == pytest.approx(0.0, abs=1e-9)


def _fly(action: int, v0: list[float], seconds: float) -> tuple[Autopilot, np.ndarray]:
    ap = Autopilot(PARAMS, GAINS, make_state([1.0, 2.0, 10.0], v0), 0.001)
    hold = hold_at(ap.state, 0.0)
    n = round(FAILSAFE_PERIOD_S / ap.dt_s)
    for _ in range(round(seconds / FAILSAFE_PERIOD_S)):
        ap.set_command(failsafe_command(ap.state, hold, ap.time_s, action, PARAMS))
        ap.advance(n)
    return ap, hold.p_W


@pytest.mark.integration
def test_position_hold_stops_a_moving_vehicle_near_where_its_setpoints_stopped():
    ap, at = _fly(ACTION_HOLD, [1.0, 0.5, -0.3], 6.0)
    assert np.linalg.norm(ap.state[POS] - at) < 0.01
    assert np.linalg.norm(ap.state[VEL]) < 0.01
    # the old failsafe (level, hover thrust, open loop) would have drifted 6.7 m in those 6 s


@pytest.mark.integration
def test_land_descends_at_the_landing_speed_over_the_point_of_loss():
    ap, at = _fly(ACTION_LAND, [0.0, 0.0, 0.0], 6.0)
    assert ap.state[VEL][2] == pytest.approx(-LAND_SPEED_MPS, abs=0.01)
    assert np.linalg.norm(ap.state[POS][:2] - at[:2]) < 0.01
    assert ap.state[POS][2] == pytest.approx(at[2] - LAND_SPEED_MPS * 6.0, abs=0.3)


class _Events:
    """An ``EventLog`` that keeps what it is given."""

    def __init__(self) -> None:
        self.seen: list[tuple[float, str, dict]] = []

    def add(self, t_s: float, kind: str, **fields) -> None:
        self.seen.append((t_s, kind, fields))


def _modes(action: int, timeout_s: float):
    """The vehicle's modes (``FlightModes``) over an autopilot hovering at 10 m, armed and in
    offboard, its last setpoint (level, hover thrust) taken at t = 0."""
    ap = Autopilot(PARAMS, GAINS, make_state([1.0, 2.0, 10.0], [0.0, 0.0, 0.0]), 0.001)
    said: list[str] = []
    events = _Events()
    f = FlightModes(ap, 1, timeout_s, action, events, lambda _sev, text: said.append(text))  # type: ignore[arg-type]
    assert f.arm(True, forced=False)
    f.offboard_signal_s = 0.0  # a setpoint stream runs
    assert f.set_mode(px4.OFFBOARD) == mav.MAV_RESULT_ACCEPTED and f.take_setpoint()
    ap.set_command(AttitudeCommand(np.array([1.0, 0.0, 0.0, 0.0]), PARAMS.mass_kg * 9.81))
    return ap, f, said, events


def _step(ap: Autopilot, f, n_steps: int) -> None:
    """What the vehicle does with ``n_steps`` attitude steps (``VehicleEndpoint.step``)."""
    left = n_steps
    while left > 0:
        chunk = f.own_steps(left)
        assert 0 < chunk <= left, chunk  # (else this loop would never end)
        ap.advance(chunk)
        left -= chunk
        f.check_failsafe()


def _until_failsafe(ap: Autopilot, f, max_steps: int = 3000) -> None:
    """One attitude step at a time until the vehicle leaves offboard (at most ``max_steps``)."""
    for _ in range(max_steps):
        if f.mode != MODE_OFFBOARD:
            return
        _step(ap, f, 1)
    raise AssertionError(f"still in offboard after {max_steps} steps")


@pytest.mark.unit
@pytest.mark.parametrize("timeout_s", [0.05, 0.5, 1.3])
def test_the_failsafe_begins_the_first_step_after_sp_timeout_without_a_setpoint(timeout_s):
    ap, f, said, events = _modes(ACTION_HOLD, timeout_s)
    _until_failsafe(ap, f)
    assert f.mode == MODE_FAILSAFE
    assert timeout_s < ap.time_s <= timeout_s + ap.dt_s + 1e-12, (ap.time_s, timeout_s)
    ((t_s, kind, fields),) = events.seen
    assert (t_s, kind, fields["action"]) == (ap.time_s, "failsafe_enter", "hold")
    assert said == ["Failsafe: offboard setpoints lost, hold"]
    assert f.heartbeat()[1:] == (px4.HOLD, mav.MAV_STATE_CRITICAL)
    # a setpoint brings it back to offboard, and the loss is counted again from it
    assert f.take_setpoint() and f.mode == MODE_OFFBOARD and events.seen[-1][1] == "failsafe_exit"
    t_back = ap.time_s
    _until_failsafe(ap, f)
    assert timeout_s < ap.time_s - t_back <= timeout_s + ap.dt_s + 1e-12


@pytest.mark.unit
def test_a_vehicle_set_to_land_lands_and_one_set_to_hold_holds():
    for action, mode in ((ACTION_LAND, px4.LAND), (ACTION_HOLD, px4.HOLD)):
        ap, f, _said, events = _modes(action, 0.5)
        _step(ap, f, 600)  # 0.1 s into the failsafe
        at = np.array(events.seen[0][2]["p_W"])
        assert f.mode == MODE_FAILSAFE and f.reported_mode() == mode
        _step(ap, f, 5000)
        if action == ACTION_LAND:  # down at the landing speed, over the point of loss
            assert ap.state[VEL][2] == pytest.approx(-LAND_SPEED_MPS, abs=0.01)
            assert ap.state[POS][2] < at[2] - 0.6 * LAND_SPEED_MPS * 5.0
        else:
            assert np.linalg.norm(ap.state[POS] - at) < 0.01
        assert np.linalg.norm(ap.state[POS][:2] - at[:2]) < 0.01


@pytest.mark.unit
def test_offboard_needs_a_setpoint_stream_and_a_disarm_in_flight_needs_force():
    """PX4's rules as the vehicle keeps them: OFFBOARD only while setpoints come (within
    SP_TIMEOUT_S), an unknown mode denied, Hold holds where it is, a disarm in flight refused
    unless forced; the heartbeat says armed and active, or standby."""
    ap = Autopilot(PARAMS, GAINS, make_state([1.0, 2.0, 10.0], [0.0, 0.0, 0.0]), 0.001)
    events = _Events()
    f = FlightModes(ap, 7, 0.5, ACTION_HOLD, events, lambda _s, _t: None)  # type: ignore[arg-type]
    assert f.system_id == 7 and f.mode == MODE_HOLD and not f.armed
    base, custom, status = f.heartbeat()
    assert not base & mav.MAV_MODE_FLAG_SAFETY_ARMED and (custom, status) == (px4.HOLD, mav.MAV_STATE_STANDBY)
    assert not f.take_setpoint()  # in Hold a setpoint is not flown
    assert f.set_mode(px4.OFFBOARD) == mav.MAV_RESULT_TEMPORARILY_REJECTED  # no stream yet
    assert f.set_mode(12345) == mav.MAV_RESULT_DENIED and f.mode == MODE_HOLD
    assert f.arm(True, forced=False) and f.armed
    base, custom, status = f.heartbeat()
    assert base & mav.MAV_MODE_FLAG_SAFETY_ARMED and status == mav.MAV_STATE_ACTIVE
    _step(ap, f, 300)
    f.offboard_signal_s = ap.time_s - 0.5  # the last setpoint exactly SP_TIMEOUT_S ago: a stream
    assert f.set_mode(px4.OFFBOARD) == mav.MAV_RESULT_ACCEPTED and f.mode == MODE_OFFBOARD
    assert f.last_setpoint_s == ap.time_s and events.seen == []
    assert not f.arm(False, forced=False) and f.armed  # refused in flight
    assert f.set_mode(px4.HOLD) == mav.MAV_RESULT_ACCEPTED and f.mode == MODE_HOLD
    held = ap.state[POS].copy()
    ap.set_command(AttitudeCommand(np.array([1.0, 0.0, 0.0, 0.0]), 0.0))  # what Hold flies is its own
    _step(ap, f, 3000)
    assert np.linalg.norm(ap.state[POS] - held) < 0.01
    assert f.arm(False, forced=True) and not f.armed


def _level(yaw_rad: float = 0.0) -> np.ndarray:
    return np.array([math.cos(yaw_rad / 2), 0.0, 0.0, math.sin(yaw_rad / 2)])


@pytest.mark.unit
@pytest.mark.parametrize("yaw", [0.5, 2.5, -2.0])
def test_the_hold_keeps_the_heading_the_vehicle_had(yaw):
    tilted = qmul(_level(yaw), np.array([math.cos(0.1), math.sin(0.1), 0.0, 0.0]))  # rolled a little
    state = make_state([1.0, 2.0, 3.0], [0.0, 0.0, 0.0])
    state[6:10] = tilted
    hold = hold_at(state, 4.0)
    assert hold.yaw_rad == pytest.approx(yaw, abs=1e-9) and hold.p_W.tolist() == [1.0, 2.0, 3.0]


@pytest.mark.unit
def test_the_failsafe_command_in_closed_form():
    """At the hold point and at rest: hover thrust, level, heading kept. Land, 0.5 s after a loss at
    t = 5 s: the target 0.35 m lower, descending at the landing speed. Far off: the tilt limit, the
    horizontal direction kept; far above: never less than a fifth of g up."""
    g, m = PARAMS.g_mps2, PARAMS.mass_kg
    state = make_state([1.0, 2.0, 10.0], [0.0, 0.0, 0.0])
    hold = hold_at(state, 5.0)
    c = failsafe_command(state, hold, 5.5, ACTION_HOLD, PARAMS)
    assert c.thrust_N == pytest.approx(m * g) and np.allclose(c.q_c, _level())
    land = failsafe_command(state, hold, 5.5, ACTION_LAND, PARAMS)
    az = -4.0 * (10.0 - (10.0 - LAND_SPEED_MPS * 0.5)) - 4.0 * (0.0 + LAND_SPEED_MPS) + g
    assert land.thrust_N == pytest.approx(m * az) and np.allclose(land.q_c, _level())
    off = make_state([1.0 - 10.0, 2.0 - 5.0, 10.0], [0.0, 0.0, 0.0])  # 10 m west, 5 m south
    c = failsafe_command(off, hold, 5.5, ACTION_HOLD, PARAMS)
    z_body = rotation_matrix(c.q_c)[:, 2]
    assert math.degrees(math.acos(z_body[2])) == pytest.approx(30.0)  # the tilt limit
    assert math.atan2(z_body[1], z_body[0]) == pytest.approx(math.atan2(5.0, 10.0))  # towards the hold
    assert c.thrust_N == pytest.approx(min(m * g / math.cos(math.radians(30.0)), PARAMS.max_thrust_N))
    high = make_state([1.0, 2.0, 110.0], [0.0, 0.0, 0.0])
    c = failsafe_command(high, hold, 5.5, ACTION_HOLD, PARAMS)
    assert c.thrust_N == pytest.approx(0.2 * m * g) and np.allclose(c.q_c, _level())


@pytest.mark.unit
def test_hold_mode_holds_whatever_the_failsafe_action_and_arming_holds_where_it_is():
    ap, f, _said, _events = _modes(ACTION_LAND, 0.5)
    ap.state[POS] = [3.0, 3.0, 8.0]  # flown elsewhere in offboard: Hold holds there
    assert f.set_mode(px4.HOLD) == mav.MAV_RESULT_ACCEPTED
    held = ap.state[POS].copy()
    _step(ap, f, 2000)
    assert np.linalg.norm(ap.state[POS] - held) < 0.01  # Hold is not the landing
    # armed (again) in Hold: the hold point is where it is then, not where it was before
    assert f.arm(False, forced=True)
    ap.state[POS] = [5.0, 5.0, 5.0]
    ap.state[VEL] = 0.0
    assert f.arm(True, forced=False)
    _step(ap, f, 2000)
    assert np.linalg.norm(ap.state[POS] - [5.0, 5.0, 5.0]) < 0.01
    ap.state[POS] = ap.state[POS] + np.array([1.0, 0.0, 0.0])  # pushed 1 m east
    assert f.arm(True, forced=False)  # armed already: the hold point stays
    assert f.set_mode(px4.HOLD) == mav.MAV_RESULT_ACCEPTED  # Hold again: it stays too
    _step(ap, f, 3000)
    assert np.linalg.norm(ap.state[POS] - [5.0, 5.0, 5.0]) < 0.05


@pytest.mark.unit
def test_entering_and_leaving_the_failsafe_is_said_and_recorded_naming_the_vehicle():
    severities: list[tuple[int, str]] = []
    ap, f, _said, events = _modes(ACTION_LAND, 0.05)
    f.say = lambda sev, text: severities.append((sev, text))
    before = time.time()
    _until_failsafe(ap, f)
    assert f.take_setpoint()
    f.check_failsafe()
    _step(ap, f, 100)
    assert f.mode == MODE_FAILSAFE
    assert f.set_mode(px4.HOLD) == mav.MAV_RESULT_ACCEPTED  # leaving it by a mode change
    kinds = [(kind, fields.get("vehicle"), fields.get("action")) for _t, kind, fields in events.seen]
    assert kinds == [
        ("failsafe_enter", 1, "land"),
        ("failsafe_exit", 1, None),
        ("failsafe_enter", 1, "land"),
        ("failsafe_exit", 1, None),
    ]
    assert all(before <= fields["unix_s"] <= time.time() for _t, _k, fields in events.seen)
    assert severities[:2] == [
        (mav.MAV_SEVERITY_WARNING, "Failsafe: offboard setpoints lost, land"),
        (mav.MAV_SEVERITY_NOTICE, "Failsafe cleared: offboard setpoints back"),
    ]


@pytest.mark.unit
def test_the_own_position_loop_runs_once_every_failsafe_period():
    ap, f, _said, _events = _modes(ACTION_HOLD, 0.05)
    _until_failsafe(ap, f)
    calls = []
    real = ap.set_command
    ap.set_command = lambda c: (calls.append(ap.step_index), real(c))  # type: ignore[method-assign]
    _step(ap, f, 1000)  # 1 s
    assert len(calls) == round(1.0 / FAILSAFE_PERIOD_S)
    assert np.diff(calls).tolist() == [round(FAILSAFE_PERIOD_S / ap.dt_s)] * (len(calls) - 1)


_coord = st.floats(-50, 50)
_speed = st.floats(-10, 10)


@pytest.mark.unit
@given(
    st.tuples(_coord, _coord, _coord),
    st.tuples(_speed, _speed, _speed),
    unit_quaternions(),
    st.tuples(_coord, _coord, _coord),
    st.floats(-math.pi + 1e-3, math.pi - 1e-3),
)
def test_level_flies_level_at_the_held_heading_and_only_its_altitude_sets_the_thrust(p, v, q, hold_p, yaw):
    """ArduCopter's level failsafe, from any state: body z along world z at the hold's heading,
    whatever the horizontal error and velocity; its thrust the altitude PD's (at least a fifth of
    g up), the same with the horizontal state zeroed."""
    state = make_state(p, v, q)
    hold = Hold(np.array(hold_p), yaw, 0.0)
    c = failsafe_command(state, hold, 1.0, ACTION_LEVEL, PARAMS)
    assert np.allclose(c.q_c, _level(yaw), atol=1e-9) or np.allclose(c.q_c, -_level(yaw), atol=1e-9)
    flat = make_state([hold_p[0], hold_p[1], p[2]], [0.0, 0.0, v[2]], q)
    assert c.thrust_N == failsafe_command(flat, hold, 1.0, ACTION_LEVEL, PARAMS).thrust_N
    a_z = max(-4.0 * (p[2] - hold_p[2]) - 4.0 * v[2] + PARAMS.g_mps2, 0.2 * PARAMS.g_mps2)
    assert c.thrust_N == pytest.approx(min(PARAMS.mass_kg * a_z, PARAMS.max_thrust_N), rel=1e-12)


@pytest.mark.unit
@given(
    st.floats(-50, 50),
    _speed,
    unit_quaternions(),
    st.floats(-50, 50),
    st.floats(-3, 3),
    st.floats(0, 10),
)
def test_a_climb_commands_the_attitude_asked_and_the_thrust_whose_vertical_part_is_the_pd(
    z, vz, q_c, hold_z, climb, t
):
    """ArduCopter's climb under an attitude: the attitude as asked; the thrust's vertical part
    m a_z (the altitude PD towards the target climbing from the hold) over the tilt's cosine (at
    least 0.1), within 0..max: none at all when the PD asks to fall faster than gravity."""
    state = make_state([0.0, 0.0, z], [0.0, 0.0, vz])
    hold = Hold(np.array([0.0, 0.0, hold_z]), 0.0, 0.0)
    c = climb_command(state, q_c, hold, t, climb, PARAMS)
    assert np.array_equal(c.q_c, q_c)
    a_z = -4.0 * (z - (hold_z + climb * t)) - 4.0 * (vz - climb) + PARAMS.g_mps2
    cos_tilt = max(float(rotation_matrix(q_c)[2, 2]), 0.1)
    want = min(max(PARAMS.mass_kg * a_z / cos_tilt, 0.0), PARAMS.max_thrust_N)
    assert c.thrust_N == pytest.approx(want, rel=1e-9, abs=1e-12)
    if a_z <= 0.0:
        assert c.thrust_N == 0.0


@pytest.mark.unit
@pytest.mark.parametrize("profile", [PX4, ARDUCOPTER], ids=lambda p: p.name)
@given(st.tuples(_speed, _speed, _speed))
def test_in_each_mode_its_own_loop_flies_the_modes_action_from_its_first_step(profile, v):
    """From boot (moving at any velocity), and in each mode the profile enters without a
    setpoint stream: its own loop sets the command of that mode's action at once (boot: step 0),
    from the hold where the mode was entered (the boot's, for the mode it booted in), then every
    failsafe period, whatever the failsafe action the vehicle was given."""
    ap = Autopilot(PARAMS, GAINS, make_state([1.0, 2.0, 10.0], list(v)), 0.001)
    f = FlightModes(ap, 1, 0.5, ACTION_HOLD, _Events(), lambda _s, _t: None, profile=profile)  # type: ignore[arg-type]
    period = round(FAILSAFE_PERIOD_S / ap.dt_s)
    set_at: list[tuple[int, AttitudeCommand]] = []
    real = ap.set_command
    ap.set_command = lambda c: (set_at.append((ap.step_index, c)), real(c))  # type: ignore[method-assign]

    def expect(action: int, hold) -> None:
        want = failsafe_command(ap.state, hold, ap.time_s, action, PARAMS, profile.land_speed_mps)
        assert set_at[-1][0] == ap.step_index
        assert np.array_equal(set_at[-1][1].q_c, want.q_c) and set_at[-1][1].thrust_N == want.thrust_N

    hold = hold_at(ap.state, 0.0)
    assert f.own_steps(1000) == period and [k for k, _ in set_at] == [0]
    expect(profile.modes[profile.boot_mode].own, hold)
    ap.advance(period)
    for mode in profile.modes.values():
        if mode.needs_stream:
            continue
        if mode.number != f.number:  # (the same mode again holds where it was)
            hold = hold_at(ap.state, ap.time_s)
        assert f.set_mode(mode.number) == mav.MAV_RESULT_ACCEPTED
        calls = len(set_at)
        left = f.own_steps(1000)
        if len(set_at) == calls:  # (not due yet: the period began before the mode)
            ap.advance(left)
            left = f.own_steps(1000)
        assert left == period and len(set_at) == calls + 1
        expect(mode.own, hold)
        ap.advance(left)
