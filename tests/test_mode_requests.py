"""MAV_CMD_DO_SET_MODE's parameters as PX4 and ArduCopter read them (``px4_profile`` and
``ardupilot_profile``'s ``requested_mode``), for any floats a sender may put there.

PX4's ``custom_mode`` is the union ``px4_custom_mode`` (``px4_custom_mode.h``): a uint16 reserved,
then the uint8 main mode, then the uint8 sub mode, read here from the returned word's bytes; its
commander takes a sub mode only for AUTO. ArduCopter's is its mode number."""

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st
from pymavlink.dialects.v20 import common as mav

from sim_vehicles.mavlink import ardupilot_profile as ap
from sim_vehicles.mavlink import px4_profile as px4

pytestmark = pytest.mark.unit
CUSTOM = mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED

#: a parameter: an integer around the uint8 range (its ends and one past them), or not an integer
params = st.one_of(
    st.integers(-2, 258).map(float),
    st.sampled_from([0.0, 255.0, 256.0, -1.0, 4.0, 6.0]),
    st.floats(-300, 300).filter(lambda x: x != int(x)),
)
base_modes = st.sampled_from([0.0, float(CUSTOM), float(CUSTOM | mav.MAV_MODE_FLAG_SAFETY_ARMED), 1.0, 129.0])


def _is_uint8(x: float) -> bool:
    return x == math.floor(x) and 0 <= x <= 255


@given(base_modes, params, params)
def test_px4_reads_a_main_and_a_sub_mode_each_a_whole_uint8_with_the_custom_flag(param1, main, sub):
    got = px4.requested_mode(param1, main, sub)
    if not int(param1) & CUSTOM or not (_is_uint8(main) and _is_uint8(sub)):
        assert got is None, (param1, main, sub)
        return
    assert got is not None
    word = got.to_bytes(4, "little")  # the union's bytes: reserved (2), main, sub
    assert word[:2] == b"\0\0" and word[2] == int(main)
    assert word[3] == (int(sub) if int(main) == px4.MAIN_AUTO else 0)


@given(base_modes, params)
def test_arducopter_reads_a_whole_non_negative_mode_number_with_the_custom_flag(param1, number):
    got = ap.requested_mode(param1, number)
    if not int(param1) & CUSTOM or number != math.floor(number) or number < 0:
        assert got is None
    else:
        assert got == int(number)
