"""The vehicle's own setpoint-loss failsafe (``sim_vehicles.plant.failsafe``): the attitude it asks for,
and the hold and the landing it flies, closed loop on the plant and the attitude loop."""

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from sim_vehicles.common.quaternion import qconj, qmul, rotation_matrix
from sim_vehicles.common.state import POS, VEL, make_state
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
