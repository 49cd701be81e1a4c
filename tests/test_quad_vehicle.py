"""The rotor-level quadrotor behind its MAVLink port: PX4's gains tuned on a running vehicle
over the parameter protocol, the step response changing as the closed form says, and a bad
PARAM_SET refused while it keeps flying. The vehicle is a real ``python -m sim_vehicles``
process in lockstep (its time moves one period per stamped setpoint), driven by pymavlink."""

import json
import math
import re
import time

import numpy as np
import pytest
from pymavlink import mavutil

from sim_vehicles.mavlink.enu_ned import q_enu_flu_to_ned_frd, q_ned_frd_to_enu_flu
from sim_vehicles.models.vehicle_config import VehicleConfig
from tests.support import sih_quad, sih_roll_step, start_vehicle, vehicle

pytestmark = pytest.mark.integration
SIH = sih_quad()
mav = mavutil.mavlink
PERIOD_MS = 10


@pytest.fixture
def quad(tmp_path):
    """A px4_quad_x vehicle (PX4 SIH's airframe, no motor lag, rate loops P only) at 50 m, and a
    pymavlink connection to it as its controller."""
    spec = VehicleConfig(
        model="px4_quad_x",
        mass_kg=SIH.mass_kg,
        inertia_kgm2=SIH.inertia_kgm2,
        max_thrust_N=SIH.max_thrust_N,
        position_m=(0.0, 0.0, 50.0),
        params={"T_TAU_S": 0.0, "MC_ROLLRATE_I": 0.0, "MC_ROLLRATE_D": 0.0},
    )
    path = tmp_path / "quad.json"
    path.write_text(spec.to_json())
    proc = start_vehicle("--id", "1", "--port", "0", "--config", path, "--lockstep-period-s", "0.01")
    assert proc.stdout is not None
    line = proc.stdout.readline()
    m = re.search(r"listening on udp:([0-9.]+):(\d+)", line)
    assert m, line
    conn = mavutil.mavlink_connection(
        f"udpout:{m.group(1)}:{m.group(2)}", source_system=1, source_component=191
    )
    try:
        yield proc, conn
    finally:
        conn.close()
        proc.terminate()
        proc.wait(timeout=30)


def _wait(conn, kind: str, timeout_s: float = 5.0, **fields):
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        m = conn.recv_match(type=kind, blocking=True, timeout=0.2)
        if m is not None and all(getattr(m, k) == v for k, v in fields.items()):
            return m
    raise AssertionError(f"no {kind} {fields}")


def _param_set(conn, name: str, value: float, kind: int = mav.MAV_PARAM_TYPE_REAL32) -> float:
    conn.mav.param_set_send(1, 1, name.encode(), value, kind)
    return float(_wait(conn, "PARAM_VALUE", param_id=name).param_value)


def _fly(conn, t_ms: int, roll: float, seconds: float) -> tuple[int, np.ndarray]:
    """Stream setpoints (roll ``roll`` about the body's forward axis, heading as at the start,
    hover thrust) from ``t_ms`` for ``seconds``, one per period, each answered by the vehicle one
    period on; returns the new time and the rolls read from its ATTITUDE_QUATERNION samples.
    MAVLink's attitudes are NED/FRD: the vehicle starts level facing east (ENU identity)."""
    q = q_enu_flu_to_ned_frd(np.array([math.cos(roll / 2), math.sin(roll / 2), 0.0, 0.0]))
    thrust = SIH.mass_kg * SIH.g_mps2 / SIH.max_thrust_N
    rolls = []
    for _ in range(round(seconds * 1000 / PERIOD_MS)):
        conn.mav.set_attitude_target_send(t_ms, 1, 1, 0, q.tolist(), 0, 0, 0, thrust)
        t_ms += PERIOD_MS
        a = _wait(conn, "ATTITUDE_QUATERNION", time_boot_ms=t_ms)
        w, x, _, _ = q_ned_frd_to_enu_flu(np.array([a.q1, a.q2, a.q3, a.q4]))
        rolls.append(2 * math.atan2(x, w))  # (the heading holds: roll alone)
    return t_ms, np.array(rolls)


def test_px4_gains_set_over_mavlink_change_the_step_response_as_the_closed_form_says(quad):
    proc, conn = quad
    conn.mav.heartbeat_send(
        mav.MAV_TYPE_ONBOARD_CONTROLLER, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0
    )  # our address
    _wait(conn, "HEARTBEAT")
    conn.mav.param_request_list_send(1, 1)
    names = set()
    while (m := conn.recv_match(type="PARAM_VALUE", blocking=True, timeout=1.0)) is not None:
        names.add(m.param_id)
    assert {"MC_ROLL_P", "MC_ROLLRATE_P", "MC_ROLLRATE_I", "MC_ROLLRATE_K", "MC_YAW_WEIGHT"} <= names
    assert {"MPC_THR_HOVER", "COM_OF_LOSS_T", "MC_ROLLRATE_MAX"} <= names
    conn.mav.command_long_send(1, 1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
    _wait(conn, "COMMAND_ACK", command=mav.MAV_CMD_COMPONENT_ARM_DISARM)
    conn.mav.set_attitude_target_send(0, 1, 1, 0b1100_0111, [1.0, 0, 0, 0], 0, 0, 0, 0)  # a stream first
    conn.mav.command_long_send(1, 1, mav.MAV_CMD_DO_SET_MODE, 0, 29, 6, 0, 0, 0, 0, 0)
    assert _wait(conn, "COMMAND_ACK", command=mav.MAV_CMD_DO_SET_MODE).result == mav.MAV_RESULT_ACCEPTED

    angle = 0.02
    t = np.arange(1, 151) * PERIOD_MS / 1000
    # tolerance: the unit test's, 2 % of the step (the small-angle error and the loop's sampling),
    # plus the float32 quaternion of ATTITUDE_QUATERNION (1e-7 rad)
    t_ms, rolls = _fly(conn, 0, angle, 1.5)  # PX4's default MC_ROLLRATE_P = 0.15
    assert np.max(np.abs(rolls - angle * sih_roll_step(t, 0.15))) < 0.02 * angle

    assert _param_set(conn, "MC_ROLLRATE_P", 0.3) == pytest.approx(0.3)
    t_ms, rolls = _fly(conn, t_ms, 0.0, 1.5)  # back to level, from the first step's 0.02 rad
    assert np.max(np.abs(rolls - angle * (1 - sih_roll_step(t, 0.3)))) < 0.02 * angle
    assert np.max(np.abs(rolls - angle * (1 - sih_roll_step(t, 0.15)))) > 0.05 * angle  # not the old gain

    # refused: out of PX4's range, not a float, no such parameter; the kept value is answered
    assert _param_set(conn, "MC_ROLLRATE_P", 0.9) == pytest.approx(0.3)
    assert _param_set(conn, "MC_ROLLRATE_P", 0.2, mav.MAV_PARAM_TYPE_INT32) == pytest.approx(0.3)
    conn.mav.param_set_send(1, 1, b"MC_NOPE_P", 1.0, mav.MAV_PARAM_TYPE_REAL32)
    # and it flies on, with the gain it kept
    t_ms, rolls = _fly(conn, t_ms, angle, 1.5)
    assert np.max(np.abs(rolls - angle * sih_roll_step(t, 0.3))) < 0.02 * angle
    assert proc.poll() is None


def test_a_quad_spec_with_a_gain_out_of_its_range_is_one_line_before_the_vehicle_binds(tmp_path):
    path = tmp_path / "quad.json"
    path.write_text(
        json.dumps({**json.loads(VehicleConfig(model="px4_quad_x").to_json()), "params": {"MC_ROLL_P": 40}})
    )
    r = vehicle("--port", "0", "--config", path, timeout=60)
    assert r.returncode == 2 and r.stderr.strip() == (
        "sim_vehicles: error: vehicle config: params: MC_ROLL_P must be within 0..12, got 40"
    )


def _offboard(conn) -> None:
    conn.mav.heartbeat_send(mav.MAV_TYPE_ONBOARD_CONTROLLER, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0)
    _wait(conn, "HEARTBEAT")
    conn.mav.command_long_send(1, 1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
    _wait(conn, "COMMAND_ACK", command=mav.MAV_CMD_COMPONENT_ARM_DISARM)
    conn.mav.set_attitude_target_send(0, 1, 1, 0b1100_0111, [1.0, 0, 0, 0], 0, 0, 0, 0)  # a stream first
    conn.mav.command_long_send(1, 1, mav.MAV_CMD_DO_SET_MODE, 0, 29, 6, 0, 0, 0, 0, 0)
    assert _wait(conn, "COMMAND_ACK", command=mav.MAV_CMD_DO_SET_MODE).result == mav.MAV_RESULT_ACCEPTED


def _hold(conn, t_ms: int, q_enu: np.ndarray, seconds: float) -> tuple[int, list[np.ndarray], list[float]]:
    """Stream the attitude ``q_enu`` at hover thrust for ``seconds``; the attitudes (ENU/FLU) and
    altitudes [m, up] the vehicle reports, one per period."""
    q = q_enu_flu_to_ned_frd(q_enu)
    thrust = SIH.mass_kg * SIH.g_mps2 / SIH.max_thrust_N
    attitudes, heights = [], []
    for _ in range(round(seconds * 1000 / PERIOD_MS)):
        conn.mav.set_attitude_target_send(t_ms, 1, 1, 0, q.tolist(), 0, 0, 0, thrust)
        t_ms += PERIOD_MS
        p = _wait(conn, "LOCAL_POSITION_NED", time_boot_ms=t_ms)
        a = _wait(conn, "ATTITUDE_QUATERNION", time_boot_ms=t_ms)
        attitudes.append(q_ned_frd_to_enu_flu(np.array([a.q1, a.q2, a.q3, a.q4])))
        heights.append(-p.z)
    return t_ms, attitudes, heights


def test_an_upside_down_setpoint_over_mavlink_leaves_the_vehicle_finite_and_flying(quad):
    """(0, 1, 0, 0) from level: exactly upside down, a valid setpoint that once gave NaN. The
    vehicle turns over at its rate limit, stays finite, and when asked for level again it rights
    itself and flies on: its attitude back within 0.05 rad of level, every report finite."""
    proc, conn = quad
    _offboard(conn)
    t_ms, flipped, h1 = _hold(conn, 0, np.array([0.0, 1.0, 0.0, 0.0]), 1.0)
    t_ms, righted, h2 = _hold(conn, t_ms, np.array([1.0, 0.0, 0.0, 0.0]), 3.0)
    assert np.all(np.isfinite(np.concatenate([*flipped, *righted, h1, h2])))
    assert abs(flipped[-1][0]) < 0.2  # it did turn over: w = cos(angle / 2) near 0 at 180 deg
    tilt = 2 * math.acos(min(1.0, abs(righted[-1][0])))  # angle from level (heading is level's)
    assert tilt < 0.05
    assert proc.poll() is None
