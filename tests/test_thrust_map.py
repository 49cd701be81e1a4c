"""The one map between a thrust and SET_ATTITUDE_TARGET's thrust field (``sim_vehicles.mavlink.
thrust_map``), and ArduCopter's reading of the field (``ardupilot_profile``), against closed forms
over random airframes, thrusts and attitudes."""

import math

import numpy as np
import pytest
from hypothesis import assume, given
from hypothesis import strategies as st

from sim_vehicles.common.command import AttitudeCommand
from sim_vehicles.common.quaternion import rotation_matrix
from sim_vehicles.mavlink.ardupilot_profile import (
    AIRFRAME_EXPO,
    FLT_EPSILON,
    check_setpoint,
    climb_rate_of,
    motor_thrust,
)
from sim_vehicles.mavlink.thrust_map import (
    BOOST_MIN_COS,
    boost_compensated,
    boosted_throttle,
    cos_tilt,
    field_of_thrust,
    full_thrust_N,
    hover_fraction,
)
from sim_vehicles.mavlink.wire_format import command_roundtrip, f32

F32_EPS = 2.0**-24  #: float32's relative rounding, half an ulp

mass = st.floats(0.2, 20.0)
gravity = st.floats(9.0, 10.0)
margin = st.floats(1.2, 4.0)  #: full thrust over weight: a vehicle that can hover and climb


@st.composite
def unit_quaternions(draw: st.DrawFn) -> np.ndarray:
    v = np.array(draw(st.lists(st.floats(-1.0, 1.0), min_size=4, max_size=4)))
    n = np.linalg.norm(v)
    return v / n if n > 1e-3 else np.array([1.0, 0.0, 0.0, 0.0])


@pytest.mark.unit
@given(m=mass, g=gravity, k=margin)
def test_the_hover_field_hovers_and_the_field_scales_with_thrust(m, g, k):
    """A vehicle of ``k`` times its weight in full thrust hovers at field ``1/k``; the field of a
    thrust ``F`` is ``hover F / (m g)``, and the full thrust the controller divides by is the
    vehicle's (to float64 rounding)."""
    T = k * m * g
    hover = hover_fraction(m, g, T)
    assert hover == pytest.approx(1.0 / k, rel=1e-14)
    full = full_thrust_N(m, g, hover)
    assert full == pytest.approx(T, rel=1e-14)
    assert field_of_thrust(m * g, full) == pytest.approx(hover, rel=1e-14)
    for F in np.linspace(0.0, T, 7):
        assert field_of_thrust(F, full) == pytest.approx(hover * F / (m * g), rel=1e-13, abs=1e-15)
    assert field_of_thrust(2 * T, full) == 1.0 and field_of_thrust(-1.0, full) == 0.0


@pytest.mark.unit
@given(m=mass, g=gravity, k=margin, share=st.floats(0.0, 1.0), q=unit_quaternions())
def test_a_thrust_reaches_a_px4_vehicle_through_its_reported_hover_to_float32(m, g, k, share, q):
    """Controller side: the hover the vehicle serves, as float32; vehicle side: the field times
    its full thrust. ``F`` comes back within the two float32 roundings (hover's, field's)."""
    T = k * m * g
    (hover,) = f32(hover_fraction(m, g, T))
    F = share * T
    got = command_roundtrip(AttitudeCommand(q, F), full_thrust_N(m, g, hover), T).thrust_N
    assert got == pytest.approx(F, rel=3 * F32_EPS, abs=T * F32_EPS)


@pytest.mark.unit
@given(q=unit_quaternions())
def test_cos_tilt_is_the_vertical_entry_of_the_rotation(q):
    assert cos_tilt(q) == pytest.approx(float(rotation_matrix(q)[2, 2]), abs=1e-12)


@pytest.mark.unit
@given(F=st.floats(0.0, 0.8), q=unit_quaternions())
def test_arducopters_angle_boost_undoes_the_compensation_at_the_commanded_tilt(F, q):
    """The controller asks for ``F cos(tilt)``; ArduCopter divides by ``cos(tilt)`` (at most by
    ``1/BOOST_MIN_COS``) and cuts the throttle as it turns over (``clamp(10 cos, 0, 1)``): at the
    commanded tilt ``F`` comes back whenever the vehicle is upright within 84 degrees; past
    upside down nothing."""
    c = cos_tilt(q)
    out = boosted_throttle(boost_compensated(F, q), c)
    if c >= BOOST_MIN_COS:
        assert out == pytest.approx(min(F, 1.0), rel=1e-12, abs=1e-15)
    elif c <= 0.0:
        assert out == 0.0
    assert 0.0 <= out <= 1.0


@pytest.mark.unit
@given(t=st.floats(0.0, 1.0), q=unit_quaternions())
def test_a_tilted_arducopter_divides_its_throttle_by_the_tilts_cosine_up_to_full(t, q):
    """Any throttle in, at any tilt upright within 84 degrees: ArduCopter's angle boost gives
    ``t / cos(tilt)``, and its motors at most full (1): a throttle the boost would take past full is
    full, never more (the compensated throttles above never reach it)."""
    c = cos_tilt(q)
    assume(c >= BOOST_MIN_COS)
    assert boosted_throttle(t, c) == pytest.approx(min(t / c, 1.0), rel=1e-12, abs=1e-15)


@pytest.mark.unit
@given(t=st.floats(0.0, 1.0), e=st.floats(-1.0, 1.0))
def test_the_thrust_curve_linearises_rotors_of_the_same_curve_and_bends_others(t, e):
    """ArduCopter turns its throttle (thrust) into a motor command with MOT_THST_EXPO's curve; the
    airframe's rotors give ``(1 - e') a + e' a^2``. Equal curves cancel (thrust is the throttle),
    and with no curve at all the rotors' own curve is what comes out."""
    assert motor_thrust(t, AIRFRAME_EXPO) == pytest.approx(t, abs=1e-12)
    a = t  # MOT_THST_EXPO 0: the command is the throttle
    assert motor_thrust(t, 0.0) == pytest.approx((1 - AIRFRAME_EXPO) * a + AIRFRAME_EXPO * a * a, abs=1e-15)
    # a curve under float's epsilon is none to ArduPilot (is_zero): the airframe's own, as small,
    # is then left in, e t (1 - t) <= eps / 4 of full thrust; any other cancels to rounding
    left = abs(e) * t * (1 - t) if abs(e) < FLT_EPSILON else 0.0
    assert motor_thrust(t, e, airframe_expo=e) == pytest.approx(t, abs=left + 1e-12)


@pytest.mark.unit
@given(t=st.floats(0.0, 1.0), up=st.floats(10.0, 1000.0), down=st.floats(10.0, 500.0))
def test_a_thrust_read_as_a_climb_rate_holds_at_half_and_reaches_each_way_linearly(t, up, down):
    v = climb_rate_of(t, up, down)
    want = (t - 0.5) * 2 * up / 100 if t >= 0.5 else (t - 0.5) * 2 * down / 100
    assert v == pytest.approx(want, abs=1e-12)
    assert climb_rate_of(0.5, up, down) == 0.0


@pytest.mark.unit
@given(mask=st.integers(0, 255), q=st.lists(st.floats(-2.0, 2.0), min_size=4, max_size=4))
def test_arducopter_refuses_exactly_what_its_handler_refuses(mask, q):
    """``handle_message_set_attitude_target``: a throttle ignored, or (the attitude used) a
    quaternion whose squared length is 1e-3 or more off 1, or body rates neither all used nor all
    ignored."""
    n2 = sum(v * v for v in q)
    refused = bool(mask & 64) or (not mask & 128 and not abs(n2 - 1.0) < 1e-3) or (mask & 7 not in (0, 7))
    assert (check_setpoint(mask, tuple(q)) is not None) == refused
    assert math.isfinite(n2)


_NEAR = st.floats(-17.0, -6.0).map(lambda x: 10.0**x)  #: from a few ulp of 1 to 1e-6
#: MOT_THST_EXPO: anywhere in -1..1, its ends, and just inside -1 (where the curve's root cancels)
EXPOS = st.one_of(st.floats(-1.0, 1.0), st.sampled_from([-1.0, 1.0]), _NEAR.map(lambda d: -1.0 + d))
#: a throttle: anywhere, full, and just below full
THROTTLES = st.one_of(st.floats(0.0, 1.0), st.just(1.0), _NEAR.map(lambda d: 1.0 - d))


@pytest.mark.unit
@given(t=st.lists(THROTTLES, min_size=2, max_size=2), e=EXPOS)
def test_any_curve_maps_more_throttle_to_no_less_thrust_within_none_to_full(t, e):
    """For any MOT_THST_EXPO and throttle, the thrust is a fraction of full thrust, never less for
    more throttle. (Just inside -1, near full throttle, the root's argument ``(1 - e)^2 + 4 e t``
    cancels to about 0 and once rounded below it: the vehicle's handler raised a math domain
    error for a setpoint near full throttle.)"""
    lo, hi = sorted(t)
    a, b = motor_thrust(lo, e), motor_thrust(hi, e)
    assert 0.0 <= a <= b <= 1.0


@pytest.mark.unit
@given(
    t=st.floats(0.0, 1.0),
    e=EXPOS,
    beyond=st.floats(1.0, 10.0, exclude_min=True),
)
def test_any_curve_gives_no_thrust_at_zero_full_at_full_and_one_past_its_range_flies_as_its_bound(
    t, e, beyond
):
    """Whatever MOT_THST_EXPO is set to (ArduPilot takes any value over MAVLink and constrains the
    curve to -1..1 where it uses it): no throttle is no thrust and full throttle full thrust, the
    curve's ends included (at 1 its root is 0 at zero throttle); a curve past either end flies as
    that end. Full thrust within the rounding of the curve's root at full throttle: the root of
    ``(1 - e)^2 + 4 e``, which cancels to ``(1 + e)^2``, from a sum rounded by a few ulp of
    ``(1 - e)^2`` (``ds``); the root moves by ``ds / 2 |1 + e|`` (at most ``sqrt(ds)``) and the
    motor command by half that, the rotors' curve by at most ``1 + AIRFRAME_EXPO`` times it."""
    eps = np.finfo(float).eps
    ds = 4 * eps * (1 - e) ** 2
    droot = min(math.sqrt(ds), ds / (2 * abs(1 + e))) if e > -1 else math.sqrt(ds)
    tol = (1 + AIRFRAME_EXPO) * droot / 2 + 4 * eps
    assert motor_thrust(0.0, e) == 0.0 and motor_thrust(1.0, e) == pytest.approx(1.0, rel=0, abs=tol)
    assert motor_thrust(t, beyond) == motor_thrust(t, 1.0)
    assert motor_thrust(t, -beyond) == motor_thrust(t, -1.0)
