"""ArduCopter's reading of SET_ATTITUDE_TARGET in guided (``mavlink.ardupilot_guided``), for any
fields and any of the masks it takes: the attitude held or the one sent (NED/FRD to ENU/FLU), the
body rates all or none, and the thrust field as thrust through the motors' curve, or as a climb
rate with the thrust it holds; what ``check_setpoint`` refuses, refused with its reason."""

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from sim_vehicles.common.command import AttitudeCommand
from sim_vehicles.common.state import make_state
from sim_vehicles.mavlink.ardupilot_guided import guided_command
from sim_vehicles.mavlink.ardupilot_profile import (
    ArduCopterState,
    check_setpoint,
    climb_rate_of,
    motor_thrust,
)
from sim_vehicles.mavlink.enu_ned import flu_to_frd, q_ned_frd_to_enu_flu
from sim_vehicles.mavlink.wire_format import IGNORE_ATTITUDE, IGNORE_RATES, AttitudeTargetFields
from tests.strategies import unit_quaternions

pytestmark = pytest.mark.unit
rate = st.floats(-10, 10)


@given(
    unit_quaternions(),
    st.tuples(rate, rate, rate),
    st.floats(-1.5, 1.5),
    st.sampled_from(
        [0, IGNORE_RATES, IGNORE_ATTITUDE, IGNORE_ATTITUDE | IGNORE_RATES, 0b0000_0010, 0b0100_0000]
    ),
    st.booleans(),
    unit_quaternions(),
    st.floats(0.0, 30.0),
    st.floats(1.0, 60.0),
)
def test_guided_flies_the_attitude_rates_and_thrust_its_mask_takes(
    q_ned, rates_frd, thrust, mask, as_thrust, held_q, held_N, max_N
):
    kept = ArduCopterState(0.35)
    kept.set("GUID_OPTIONS", 8 if as_thrust else 0)
    kept.set("ATC_ANGLE_BOOST", 0)  # (the boost: tests/test_thrust_map.py)
    held = AttitudeCommand(held_q, held_N)
    fields = AttitudeTargetFields(tuple(q_ned), rates_frd, thrust)
    cmd, climb, why = guided_command(fields, mask, held, make_state([0.0, 0.0, 5.0]), max_N, kept)
    refusal = check_setpoint(mask, tuple(q_ned))
    if refusal is not None:
        assert (cmd, climb, why) == (None, None, refusal.why) and why
        return
    assert cmd is not None and why == ""
    if mask & IGNORE_ATTITUDE:
        assert np.array_equal(cmd.q_c, held_q)
    else:
        want = q_ned_frd_to_enu_flu(np.array(q_ned))
        assert np.allclose(cmd.q_c, want, atol=1e-12) or np.allclose(cmd.q_c, -want, atol=1e-12)
    want_rates = np.zeros(3) if mask & IGNORE_RATES else flu_to_frd(np.array(rates_frd))
    assert np.allclose(cmd.omega_c_B, want_rates, rtol=0, atol=1e-12)
    if as_thrust:
        assert climb is None
        throttle = min(max(thrust, -1.0), 1.0)
        assert cmd.thrust_N == pytest.approx(
            motor_thrust(throttle, kept.get("MOT_THST_EXPO")) * max_N, rel=1e-12
        )
        assert 0.0 <= cmd.thrust_N <= max_N
    else:
        assert cmd.thrust_N == held_N
        assert climb == climb_rate_of(thrust, kept.get("WPNAV_SPEED_UP"), kept.get("WPNAV_SPEED_DN"))
        assert math.isfinite(climb)
