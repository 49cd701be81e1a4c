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
    FAILSAFE_PERIOD_S,
    LAND_SPEED_MPS,
    attitude_for,
    failsafe_command,
    hold_at,
)
from sim_vehicles.plant.params import AttitudeGains, VehicleParams
from sim_vehicles.vehicle.modes import MODE_FAILSAFE, MODE_HOLD, MODE_OFFBOARD, FlightModes

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
