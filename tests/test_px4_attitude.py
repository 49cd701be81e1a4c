"""``px4_quad_x``'s attitude controller against PX4's ``AttitudeControl::update`` (v1.15), written
here again as PX4 writes it, in PX4's own frames (NED world, FRD body) and with its own
``Quaternion(src, dst)`` and ``canonical()``, over random attitudes, setpoints and yaw rates,
exactly opposite thrust axes and setpoints within 1e-12 of them included; the yaw-rate
feed-forward at a tilted attitude against its closed form; any yaw weight in its range; every
unit quaternion giving a finite setpoint; and the half turn between opposite thrust axes, ties
included, bit for bit."""

import math

import numpy as np
import pytest
from hypothesis import assume, given
from hypothesis import strategies as st

from sim_vehicles.mavlink.enu_ned import flu_to_frd, q_enu_flu_to_ned_frd
from sim_vehicles.plant.px4_control import _tilt, gain_vector, rate_setpoint
from tests.strategies import FUZZ, unit_quaternions

pytestmark = pytest.mark.unit

FLT_EPSILON = 1.1920929e-07
GAINS = gain_vector({})
K = np.array([6.5, 6.5, 2.8])  # MC_ROLL_P, MC_PITCH_P, MC_YAW_P (PX4 v1.15)
YAW_W = 0.4
NO_LIMIT = np.full(3, 1e9)
PX4_LIMIT = np.radians([220.0, 220.0, 200.0])


# -- PX4's AttitudeControl, in PX4's frames ----------------------------------------------------------
def _mul(a, b):
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return np.array(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ]
    )


def _inv(q):
    return np.array([q[0], -q[1], -q[2], -q[3]]) / (q @ q)


def _dcm_z(q):
    w, x, y, z = q
    return np.array([2 * (w * y + x * z), 2 * (y * z - w * x), w * w - x * x - y * y + z * z])


def _canonical(q):
    for v in q:
        if abs(v) > FLT_EPSILON:
            return q * math.copysign(1.0, v)
    return q


def _from_two_vectors(src, dst, eps=1e-5):
    """matrix::Quaternion(src, dst)."""
    cr = np.cross(src, dst)
    dt = src @ dst
    if np.linalg.norm(cr) < eps and dt < 0:
        a = np.abs(src)
        if a[0] < a[1]:
            axis = np.array([1.0, 0, 0]) if a[0] < a[2] else np.array([0, 0, 1.0])
        else:
            axis = np.array([0, 1.0, 0]) if a[1] < a[2] else np.array([0, 0, 1.0])
        q = np.concatenate([[0.0], np.cross(src, axis)])
    else:
        q = np.concatenate([[dt + math.sqrt((src @ src) * (dst @ dst))], cr])
    return q / np.linalg.norm(q)


def px4_update(q, qd, yawspeed, gain, yaw_w, rate_limit):
    """AttitudeControl::update (PX4 v1.15), NED/FRD: the body-rate setpoint [rad/s; FRD]."""
    e_z, e_z_d = _dcm_z(q), _dcm_z(qd)
    qd_red = _from_two_vectors(e_z, e_z_d)
    qd_red = qd.copy() if abs(qd_red[1]) > 1 - 1e-05 or abs(qd_red[2]) > 1 - 1e-05 else _mul(qd_red, q)
    q_mix = _canonical(_mul(_inv(qd_red), qd))
    q_mix[0] = min(max(q_mix[0], -1.0), 1.0)
    q_mix[3] = min(max(q_mix[3], -1.0), 1.0)
    qd = _mul(
        qd_red, np.array([math.cos(yaw_w * math.acos(q_mix[0])), 0, 0, math.sin(yaw_w * math.asin(q_mix[3]))])
    )
    qe = _canonical(_mul(_inv(q), qd))
    gain = np.array([gain[0], gain[1], gain[2] / yaw_w if yaw_w > 1e-4 else gain[2]])
    rate = 2.0 * qe[1:] * gain
    if math.isfinite(yawspeed):
        rate = rate + _dcm_z(_inv(q)) * yawspeed
    return np.clip(rate, -rate_limit, rate_limit)


def ours_in_frd(q_enu, qd_enu, body_yaw_rate, limit):
    """Our kernel's setpoint, in FRD; ``body_yaw_rate`` as SET_ATTITUDE_TARGET carries it (FRD),
    which our wire turns into FLU (``omega_c_B[2] = -body_yaw_rate``)."""
    return flu_to_frd(rate_setpoint(q_enu, qd_enu, -body_yaw_rate, GAINS, limit))


def px4_for(q_enu, qd_enu, body_yaw_rate, limit):
    return px4_update(
        q_enu_flu_to_ned_frd(q_enu), q_enu_flu_to_ned_frd(qd_enu), body_yaw_rate, K, YAW_W, limit
    )


def _half_turn_about_a_horizontal_body_axis(q: np.ndarray, phi: float) -> np.ndarray:
    """``q`` turned half a turn about its own body axis ``(cos phi, sin phi, 0)``: the thrust axis
    exactly opposite."""
    return _mul(q, np.array([0.0, math.cos(phi), math.sin(phi), 0.0]))


# tolerance: the kernel and the reference compute the same float64 expressions in two frames, and
# the frame change (products with 1/sqrt 2) leaves each quaternion a few ulps apart (8 ulps of 1:
# 2e-15). The yaw weighting takes acos of q_mix's w, which near 1 turns an error d into sqrt(2 d)
# (6e-8 rad here), and the yaw gain MC_YAW_P / MC_YAW_WEIGHT = 7 doubles it with the error's
# factor 2: 1e-6 rad/s bounds it, while any difference in the law (a sign, an axis, a gain, the
# feed-forward's frame) is of the order of the setpoint itself
TOL = 1e-6


@FUZZ
@given(unit_quaternions(), unit_quaternions(), st.floats(-3.0, 3.0))
def test_the_rate_setpoint_is_px4s_for_any_attitude_and_setpoint(q, qd, yaw_rate):
    for limit in (NO_LIMIT, PX4_LIMIT):
        assert ours_in_frd(q, qd, yaw_rate, limit) == pytest.approx(px4_for(q, qd, yaw_rate, limit), abs=TOL)


@FUZZ
@given(
    unit_quaternions(), unit_quaternions(), st.one_of(st.sampled_from([0.0, 1e-5, 1e-4]), st.floats(0.1, 1.0))
)
def test_the_rate_setpoint_is_px4s_for_any_yaw_weight_in_its_range(q, qd, yaw_w):
    """MC_YAW_WEIGHT anywhere in its range 0..1, its end 0 and PX4's cut at 1e-4 included (at or
    under it, PX4 leaves MC_YAW_P unscaled). The tolerance above grows as the yaw gain P / w."""
    ours = flu_to_frd(rate_setpoint(q, qd, 0.0, gain_vector({"MC_YAW_WEIGHT": yaw_w}), NO_LIMIT))
    px4 = px4_update(q_enu_flu_to_ned_frd(q), q_enu_flu_to_ned_frd(qd), 0.0, K, yaw_w, NO_LIMIT)
    assert ours == pytest.approx(px4, abs=TOL * max(1.0, YAW_W / yaw_w) if yaw_w > 1e-4 else TOL)


@FUZZ
@given(unit_quaternions(), st.floats(0.0, 2 * math.pi), st.sampled_from([0.0, 1e-13, 1e-12, -1e-12]))
def test_opposite_thrust_axes_give_px4s_finite_setpoint(q, phi, off):
    """The setpoint half a turn from the attitude about a horizontal axis (its thrust axis
    exactly opposite, or within 1e-12 rad of it): PX4's half turn, finite, the same."""
    qd = _half_turn_about_a_horizontal_body_axis(q, phi)
    qd = _mul(qd, np.array([math.cos(off / 2), math.sin(off / 2), 0.0, 0.0]))
    ours = ours_in_frd(q, qd, 0.0, NO_LIMIT)
    assert np.all(np.isfinite(ours))
    # which half turn PX4 takes is the world axis along which the thrust axis is smallest: where
    # two are equal to rounding (a tie), the last bit decides, in PX4's float32 as in our frames,
    # so neither can be held to the other there; everywhere else the choice is PX4's
    a = np.sort(np.abs(_dcm_z(q_enu_flu_to_ned_frd(q))))
    assume(a[1] - a[0] > 1e-9 and a[2] - a[1] > 1e-9)
    assert ours == pytest.approx(px4_for(q, qd, 0.0, NO_LIMIT), abs=TOL)


def test_upside_down_from_level_is_px4s_13_rad_s():
    """Level at rest, commanded (0, 1, 0, 0): exactly upside down. PX4 rolls at 2 MC_ROLL_P = 13
    rad/s before its rate limit (MC_ROLLRATE_MAX, 220 deg/s, after it)."""
    level, upside_down = np.array([1.0, 0.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0, 0.0])
    sp = rate_setpoint(level, upside_down, 0.0, GAINS, NO_LIMIT)
    assert sp == pytest.approx([13.0, 0.0, 0.0], abs=1e-12)
    assert rate_setpoint(level, upside_down, 0.0, GAINS, PX4_LIMIT) == pytest.approx(
        [math.radians(220.0), 0.0, 0.0], abs=1e-12
    )


@pytest.mark.parametrize("roll_deg", [0.0, 30.0, -50.0])
def test_the_yaw_rate_is_fed_forward_about_the_world_vertical(roll_deg):
    """At the setpoint (no error), a yaw rate ``r`` about the world's up axis is ``r R^T e_z`` in
    the body: at 30 deg of roll, (0, sin 30, cos 30) r in FLU, as PX4's ``q.inversed().dcm_z()``."""
    a = math.radians(roll_deg)
    q = np.array([math.cos(a / 2), math.sin(a / 2), 0.0, 0.0])
    r = 1.0
    sp = rate_setpoint(q, q, r, GAINS, NO_LIMIT)
    assert sp == pytest.approx([0.0, math.sin(a) * r, math.cos(a) * r], abs=1e-12)
    assert flu_to_frd(sp) == pytest.approx(
        px4_update(*map(q_enu_flu_to_ned_frd, (q, q)), -r, K, YAW_W, NO_LIMIT)
    )


@FUZZ
@given(unit_quaternions(), unit_quaternions(), st.floats(-1e3, 1e3))
def test_every_unit_quaternion_gives_a_finite_setpoint(q, qd, yaw_rate):
    assert np.all(np.isfinite(rate_setpoint(q, qd, yaw_rate, GAINS, PX4_LIMIT)))


def _enu_to_ned(v: np.ndarray) -> np.ndarray:
    return np.array([v[1], v[0], -v[2]])


#: thrust axes on which PX4's choice of half turn meets a tie exactly (two or three components of
#: equal size: the world axes, and 3-4-5 vectors in a coordinate plane), then any other
EXACT_AXES = [
    s * np.roll(np.array(v), r)
    for v in ([0, 0, 1.0], [0, 0.6, 0.8], [0, 0.8, 0.6])
    for r in range(3)
    for s in (1, -1)
]


@FUZZ
@given(
    st.one_of(
        st.sampled_from(EXACT_AXES),
        unit_quaternions()
        .filter(lambda q: np.linalg.norm(q[1:]) > 0.1)
        .map(lambda q: q[1:] / np.linalg.norm(q[1:])),
    )
)
def test_the_half_turn_between_opposite_thrust_axes_is_px4s_own_ties_included(ez):
    """``_tilt`` of a thrust axis and its opposite is PX4's ``Quaternion(src, dst)`` of the same
    axes in NED (a vector's frame change is exact: a permutation and a sign), bit for bit in its
    sign and axis: the world axis PX4 turns about is the one along which the thrust axis is
    smallest, ties resolved as PX4's comparisons resolve them."""
    ez = np.asarray(ez, dtype=float)
    q = _tilt(ez, -ez)
    down = _enu_to_ned(-ez)  # PX4's e_z: the body's down axis, in NED
    ref = _from_two_vectors(down, -down)
    assert q[0] == ref[0] == 0.0
    assert np.array_equal(_enu_to_ned(q[1:]), ref[1:]) or np.allclose(
        _enu_to_ned(q[1:]), ref[1:], atol=1e-15
    ), (q, ref)
