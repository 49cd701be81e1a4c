"""ENU/FLU <-> NED/FRD at the MAVLink boundary, and float32 round trips."""

import math

import numpy as np
import pytest
from hypothesis import assume, given
from hypothesis import strategies as st

from sim_vehicles.common.command import AttitudeCommand
from sim_vehicles.common.quaternion import from_axis_angle, rotation_matrix
from sim_vehicles.mavlink.enu_ned import enu_to_ned, flu_to_frd, q_enu_flu_to_ned_frd, q_ned_frd_to_enu_flu
from sim_vehicles.mavlink.wire_format import (
    command_roundtrip,
    decode_attitude_target,
    encode_attitude,
    encode_attitude_quaternion,
    encode_attitude_target,
    f32,
)
from tests.strategies import unit_quaternions, vec3

pytestmark = pytest.mark.unit


@given(unit_quaternions(), vec3)
def test_attitude_conversion_rotates_the_same_physical_vector(q, v_flu):
    """R_NED_FRD(q') (FRD v) == NED(R_ENU_FLU(q) v): one physical vector, two frames."""
    q_ned = q_enu_flu_to_ned_frd(q)
    np.testing.assert_allclose(
        rotation_matrix(q_ned) @ flu_to_frd(v_flu), enu_to_ned(rotation_matrix(q) @ v_flu), atol=1e-9
    )
    back = q_ned_frd_to_enu_flu(q_ned)
    assert min(np.linalg.norm(back - q), np.linalg.norm(back + q)) < 1e-12


def test_level_vehicle_facing_east_is_yaw_90_in_ned():
    q = q_enu_flu_to_ned_frd(np.array([1.0, 0, 0, 0]))
    np.testing.assert_allclose(q, [np.sqrt(0.5), 0, 0, np.sqrt(0.5)], atol=1e-15)


def test_command_roundtrip_is_float32_exact_and_drops_omegadot():
    cmd = AttitudeCommand(
        from_axis_angle([1, 2, 3], 0.3), 12.345678, np.array([0.1, -0.2, 0.3]), np.array([1.0, 1.0, 1.0])
    )
    fields = encode_attitude_target(cmd, 25.0)
    assert all(np.float32(x) == x for x in (*fields.q, *fields.body_rates, fields.thrust))
    back = command_roundtrip(cmd, 25.0)
    assert abs(back.thrust_N - 12.345678) < 25.0 * 2**-24
    np.testing.assert_allclose(back.omega_c_B, [0.1, -0.2, 0.3], rtol=1e-6)
    np.testing.assert_array_equal(back.omegadot_c_B, np.zeros(3))
    assert abs(np.linalg.norm(back.q_c) - 1) < 1e-15


def test_bad_attitude_target_is_refused():
    with pytest.raises(ValueError, match="not a unit quaternion"):
        decode_attitude_target(
            encode_attitude_target(AttitudeCommand(np.array([2.0, 0, 0, 0]), 1.0), 25.0)._replace(
                q=(0.0, 0.0, 0.0, 0.0)
            ),
            25.0,
        )


@given(
    unit_quaternions(),
    st.floats(0.0, 1.0),
    st.floats(1.0, 200.0),
    st.floats(1.0, 200.0),
)
def test_a_thrust_travels_as_a_fraction_of_the_senders_full_thrust_read_as_one_of_the_vehicles(
    q, share, full_N, vehicle_N
):
    """The controller sends ``F / full`` (float32); the vehicle flies that fraction of its own
    maximum thrust, which may differ (one float32 rounding apart); by default the sender's."""
    cmd = AttitudeCommand(q, share * full_N)
    got = command_roundtrip(cmd, full_N, vehicle_N).thrust_N
    assert got == pytest.approx(share * vehicle_N, rel=2**-23, abs=vehicle_N * 2**-24)
    same = command_roundtrip(cmd, full_N).thrust_N
    assert same == pytest.approx(share * full_N, rel=2**-23, abs=full_N * 2**-24)


@given(st.lists(st.floats(-3e38, 3e38), max_size=20))
def test_f32_rounds_any_number_of_values_as_float32_does(values):
    assert f32(*values) == tuple(float(np.float32(v)) for v in values)


@given(unit_quaternions(), vec3)
def test_attitudes_euler_angles_turn_as_its_quaternion_does(q_WB, omega_B):
    """ATTITUDE's roll, pitch and yaw, composed in pymavlink's own ZYX order (its ``Quaternion``
    from Euler angles, an independent reference), give the rotation of the float32 quaternion
    ATTITUDE_QUATERNION sends, and its rates are that message's. Tolerance: the float32 quaternion
    is unit within a few of its ulps, ||q|^2 - 1| < 1e-6; the angles' formulas take it as unit, so
    each argument is off by about that, and an angle by that over cos(pitch), at most 10x with the
    pitch kept within 84 degrees here; 1e-5 on the matrix's entries is over that."""
    from pymavlink.quaternion import Quaternion

    f = encode_attitude_quaternion(q_WB, omega_B)
    sent = np.array(f[0:4]) / np.linalg.norm(f[0:4])
    roll, pitch, yaw, *rates = encode_attitude(q_WB, omega_B)
    assert rates == list(f[4:7])
    assume(abs(rotation_matrix(sent)[2, 0]) < math.cos(math.radians(6.0)))  # |pitch| < 84 degrees
    np.testing.assert_allclose(
        rotation_matrix(np.array(Quaternion([roll, pitch, yaw]).q)), rotation_matrix(sent), atol=1e-5
    )


@given(st.floats(-math.pi, math.pi), st.sampled_from([-1.0, 1.0]))
def test_at_either_gimbal_lock_attitude_says_a_quarter_turn_of_pitch(yaw, up):
    """Nose straight up or down (NED: pitch +-90 degrees), any yaw: the float32 quaternion's sine
    of the pitch may pass 1 by its rounding; ATTITUDE says the quarter turn, finite, never a math
    domain error. Tolerance: a sine within 1e-6 of 1 is a pitch within sqrt(2e-6) = 1.4e-3."""
    from pymavlink.quaternion import Quaternion

    q_ned = np.array(Quaternion([0.0, up * math.pi / 2, yaw]).q)
    roll, pitch, yaw_sent, *_ = encode_attitude(q_ned_frd_to_enu_flu(q_ned), np.zeros(3))
    assert math.isfinite(roll) and math.isfinite(yaw_sent)
    assert pitch == pytest.approx(up * math.pi / 2, abs=1.5e-3)
