"""``px4_quad_x``'s mixer against PX4 v1.15's control allocation, written here again as PX4
writes it, in PX4's frames: the effectiveness from the rotors' geometry as
``ActuatorEffectivenessRotors`` builds it (FRD, thrust along -z, ``CT``, ``KM``), its normalised
pseudo-inverse (``ControlAllocationPseudoInverse``) and ``mixAirmodeDisabled``. Over random quad
X airframes and demands, saturated and not: the same actuators and the same unallocated torque.
Then the findings that were bugs, each as its class: the minimal saturated case with PX4's
numbers, the torque scale against the pseudo-inverse, and the mixer's properties (thrust never
raised above the demand, roll and pitch kept before yaw, the second half step applied)."""

import math

import numpy as np
import pytest
from hypothesis import assume, given
from hypothesis import strategies as st

from sim_vehicles.plant.px4_allocation import allocate, normalized_mix, torque_per_unit_Nm
from sim_vehicles.plant.rotors import effectiveness
from tests.strategies import FUZZ

pytestmark = pytest.mark.unit

FLT_EPSILON = 1.1920929e-07
SIH = (5.0, 0.1, 0.2, 0.2)  # PX4 SIH's quadrotor: T_MAX [N], Q_MAX [N m], L_ROLL, L_PITCH [m]


# -- PX4's allocation, in PX4's frames ---------------------------------------------------------------
def px4_effectiveness(t_max, q_max, l_roll, l_pitch, ct=6.5):
    """ActuatorEffectivenessRotors: rows roll, pitch, yaw, thrust x, y, z (FRD), per rotor in
    PX4's quad X order; ``KM = q_max / t_max``, positive for the counter-clockwise rotors 1, 2."""
    km = q_max / t_max
    positions = [
        (l_pitch, l_roll, 0.0),
        (-l_pitch, -l_roll, 0.0),
        (l_pitch, -l_roll, 0.0),
        (-l_pitch, l_roll, 0.0),
    ]
    B = np.zeros((6, 4))
    axis = np.array([0.0, 0.0, -1.0])
    for i, (pos, k) in enumerate(zip(positions, (km, km, -km, -km), strict=True)):
        B[0:3, i] = ct * np.cross(pos, axis) - ct * k * axis
        B[3:6, i] = ct * axis
    return B


def px4_mix(B):
    """ControlAllocationPseudoInverse: geninv, the scale (updateControlAllocationMatrixScale),
    the normalisation (normalizeControlAllocationMatrix)."""
    mix = np.linalg.pinv(B)
    scale = np.ones(6)
    n_r = np.sum(np.abs(mix[:, 0]) > 1e-3)
    n_p = np.sum(np.abs(mix[:, 1]) > 1e-3)
    r = math.sqrt(mix[:, 0] @ mix[:, 0] / (n_r / 2)) if n_r else 1.0
    p = math.sqrt(mix[:, 1] @ mix[:, 1] / (n_p / 2)) if n_p else 1.0
    scale[0] = scale[1] = max(r, p)
    scale[2] = mix[:, 2].max()
    norms = np.linalg.norm(mix[:, 3:6], axis=1)
    n_t = np.sum(norms > FLT_EPSILON)
    scale[3:6] = norms.sum() / n_t if n_t else 1.0
    if scale[0] > FLT_EPSILON:
        mix[:, 0:2] /= scale[0]
    if scale[2] > FLT_EPSILON:
        mix[:, 2] /= scale[2]
    if scale[3] > FLT_EPSILON:
        mix[:, 3:6] /= scale[3]
    mix[np.abs(mix) < 1e-3] = 0.0
    return mix, scale


def _gain(v, u, lo=0.0, hi=1.0):
    k_min = k_max = 0.0
    for vi, ui in zip(v, u, strict=True):
        if abs(vi) < 0.2:
            continue
        if ui < lo:
            k = (lo - ui) / vi
            k_min, k_max = min(k_min, k), max(k_max, k)
        if ui > hi:
            k = (hi - ui) / vi
            k_min, k_max = min(k_min, k), max(k_max, k)
    return k_min + k_max


def _desaturate(u, v, increase_only=False, hi=1.0):
    g = _gain(v, u, hi=hi)
    if increase_only and g < 0:
        return u
    u = u + g * v
    return u + 0.5 * _gain(v, u, hi=hi) * v


def px4_allocate(B, sp):
    """mixAirmodeDisabled + mixYaw, clipped; the unallocated control (ControlAllocator's status)."""
    mix, scale = px4_mix(B)
    u = mix[:, 0] * sp[0] + mix[:, 1] * sp[1] + mix[:, 3:6] @ sp[3:6]
    u = _desaturate(u, mix[:, 5], increase_only=True)
    u = _desaturate(u, mix[:, 0])
    u = _desaturate(u, mix[:, 1])
    u = u + mix[:, 2] * sp[2]
    u = _desaturate(u, mix[:, 2], hi=1.15)
    u = _desaturate(u, mix[:, 5], increase_only=True)
    u = np.clip(u, 0.0, 1.0)
    return u, sp - (B @ u) * scale


def px4_for(airframe, thrust, torque):
    """PX4's actuators and unallocated torque (in our FLU) for our normalised controls."""
    sp = np.array([torque[0], -torque[1], -torque[2], 0.0, 0.0, -thrust])  # FLU -> FRD, thrust up -> z
    u, un = px4_allocate(px4_effectiveness(*airframe), sp)
    return u, np.array([un[0], -un[1], -un[2]])


def ours(airframe, thrust, torque):
    E = effectiveness(*airframe)
    mix, scale = normalized_mix(E)
    return allocate(thrust, np.asarray(torque, dtype=float), mix, E, scale)


airframes = st.tuples(
    st.floats(1.0, 20.0), st.floats(0.01, 1.0), st.floats(0.05, 1.0), st.floats(0.05, 1.0)
)  # t_max, q_max, l_roll, l_pitch: arms from a twentieth to twenty times each other
#: airframes whose mix has no entry under 0.2 (arms within 0.3 of each other; PX4's cut is
#: 1 / (2 sqrt 2) = 0.28): the ones PX4's desaturation works on whole, where its properties hold
balanced = airframes.filter(lambda a: 0.3 <= a[2] / a[3] <= 1 / 0.3)
demands = st.tuples(st.floats(0.0, 1.0), st.tuples(*[st.floats(-2.0, 2.0)] * 3))


@FUZZ
@given(airframes, demands)
def test_the_allocation_is_px4s_for_any_quad_x_and_any_demand(airframe, demand):
    """Actuators and unallocated torque equal to PX4's (float64 here and there: the same
    operations in two frames, 1e-9 of an actuator holds with room), saturated or not, with arms
    unequal enough that PX4 leaves the weak axis out of its desaturation (|entry| < 0.2)."""
    thrust, torque = demand
    u, un = ours(airframe, thrust, torque)
    u_px4, un_px4 = px4_for(airframe, thrust, torque)
    assert u == pytest.approx(u_px4, abs=1e-9)
    assert un == pytest.approx(un_px4, abs=1e-9)


def test_the_minimal_saturated_case_gives_px4s_10_n_and_2_n_m():
    """SIH's airframe asked for 18 N and 2.4 N m of roll: the thrust cut leaves two rotors under
    zero, PX4's half step raises the thrust again, roll is scaled back: 10 N and 2.0 N m (without
    the half step: 8 N and 1.6 N m)."""
    E = effectiveness(*SIH)
    mix, scale = normalized_mix(E)
    roll = 2.4 / torque_per_unit_Nm(scale)[0]
    u, _ = allocate(18.0 / 20.0, np.array([roll, 0.0, 0.0]), mix, E, scale)
    made = E @ u
    assert made[0] == pytest.approx(10.0, abs=1e-9) and made[1] == pytest.approx(2.0, abs=1e-9)
    assert made[2:] == pytest.approx([0.0, 0.0], abs=1e-9)


@given(airframes)
def test_the_torque_scale_is_the_pseudo_inverses(airframe):
    """The normalised mix is the effectiveness' pseudo-inverse, columns scaled: roll and pitch by
    one scale, sqrt(sum M_i^2 / (n / 2)) of the larger, yaw so its largest entry is 1, thrust so
    its mean is 1. For a quad X these are closed forms: a normalised torque of 1 asks 2 sqrt 2 l
    T_max of roll (pitch) of the axis with the shorter arm, and 4 Q_MAX of yaw."""
    t_max, q_max, l_roll, l_pitch = airframe
    E = effectiveness(*airframe)
    mix, scale = normalized_mix(E)
    M = np.linalg.pinv(E)
    assert mix == pytest.approx(M / scale, abs=1e-12)  # (no entry of a quad X's is under 1e-3)
    per_unit = torque_per_unit_Nm(scale)
    arm = min(l_roll, l_pitch)
    assert per_unit == pytest.approx([2 * math.sqrt(2) * arm * t_max] * 2 + [4 * q_max], rel=1e-12)
    assert np.abs(mix[:, 3]).max() == pytest.approx(1.0) and mix[:, 0] == pytest.approx(np.ones(4))
    # for PX4 SIH's quadrotor: 0.707 of an actuator per rotor in roll and pitch, 1 in yaw
    mix_sih, _ = normalized_mix(effectiveness(*SIH))
    assert np.abs(mix_sih[:, 1:3]) == pytest.approx(np.full((4, 2), 1 / math.sqrt(2)))


@FUZZ
@given(balanced, demands)
def test_thrust_is_never_raised_above_the_demand_and_actuators_stay_within_limits(airframe, demand):
    thrust, torque = demand
    u, _un = ours(airframe, thrust, torque)
    assert np.all(u >= 0.0) and np.all(u <= 1.0)
    E = effectiveness(*airframe)
    assert (E @ u)[0] <= thrust * 4 * airframe[0] + 1e-9


@FUZZ
@given(balanced, st.floats(0.1, 0.9), st.tuples(*[st.floats(-0.5, 0.5)] * 2), st.floats(-3.0, 3.0))
def test_roll_and_pitch_are_kept_before_yaw(airframe, thrust, rp, yaw):
    """A roll and pitch demand the rotors can make with the thrust asked, and any yaw on top:
    while the last clip does not cut (PX4's yaw step may push a rotor past a limit its last thrust
    cut cannot bring back, and the clip then takes from every axis), roll and pitch are made in
    full, and yaw gives way (the same sign as asked, no more)."""
    E = effectiveness(*airframe)
    mix, scale = normalized_mix(E)
    first = mix[:, 0] * thrust + mix[:, 1] * rp[0] + mix[:, 2] * rp[1]
    assume(np.all(first >= 0.0) and np.all(first <= 1.0))
    u, un = allocate(thrust, np.array([rp[0], rp[1], yaw]), mix, E, scale)
    assume(np.all(u > 1e-9) and np.all(u < 1 - 1e-9))
    assert un[:2] == pytest.approx([0.0, 0.0], abs=1e-9)
    made_yaw = yaw - un[2]
    assert made_yaw * yaw >= -1e-12 and abs(made_yaw) <= abs(yaw) + 1e-12


@FUZZ
@given(st.floats(0.501, 1.0), st.floats(0.0, 1.0))
def test_the_half_step_after_a_thrust_cut_is_applied(a, f):
    """Roll that puts two rotors over full and, once the thrust is cut to bring them back, the
    other two under zero (each rotor's share of the roll ``a`` over 0.5, the thrust ``t`` from
    ``a`` to 1): the half step raises the thrust by half what those need, and roll is scaled back
    around it: thrust 0.5 of full, where the cut alone leaves ``1 - a``."""
    E = effectiveness(*SIH)
    mix, scale = normalized_mix(E)
    thrust = a + f * (1.0 - a)
    u, _ = allocate(thrust, np.array([a * math.sqrt(2), 0.0, 0.0]), mix, E, scale)
    cut_alone = 1.0 - a
    with_half_step = cut_alone + 0.5 * (2 * a - 1.0)  # = 0.5
    assert u.mean() == pytest.approx(with_half_step, abs=1e-9) and u.mean() > cut_alone


def test_an_axis_under_0_2_of_an_actuator_is_left_out_of_the_desaturation_as_px4_does():
    """Arms of 1 m and 0.25 m: pitch moves each rotor 0.707 per unit, roll 0.177, under PX4's
    0.2, so PX4 does not desaturate along roll; asked for roll alone with no thrust, the rotors
    are only clipped, and they make more thrust than asked. Ours does what PX4 does."""
    airframe = (1.0, 1.0, 1.0, 0.25)
    E = effectiveness(*airframe)
    mix, _ = normalized_mix(E)
    assert np.abs(mix[:, 1]) == pytest.approx(np.full(4, 0.25 / math.sqrt(2)))
    u, _un = ours(airframe, 0.0, (1.0, 0.0, 0.0))
    u_px4, _un_px4 = px4_for(airframe, 0.0, (1.0, 0.0, 0.0))
    assert u == pytest.approx(u_px4, abs=1e-12) and (E @ u)[0] > 0.1


def px4_saturation_flags(unallocated):
    """MulticopterRateControl's reading of the allocator's status: nothing while
    ``torque_setpoint_achieved`` (norm squared under 1e-6), else each axis by its sign beyond
    float's epsilon."""
    pos, neg = [False] * 3, [False] * 3
    if not float(np.sum(np.square(unallocated))) < 1e-6:
        for i in range(3):
            if unallocated[i] > FLT_EPSILON:
                pos[i] = True
            elif unallocated[i] < -FLT_EPSILON:
                neg[i] = True
    return np.array(pos, dtype=float) - np.array(neg, dtype=float)


small = st.floats(-2e-3, 2e-3)


@FUZZ
@given(st.tuples(small, small, small), st.sampled_from([1.0, 1e-3, 1e-6]))
def test_anti_windup_acts_only_where_px4s_rate_controller_sees_a_torque_not_achieved(un, size):
    """Unallocated torques around PX4's threshold (a norm of 1e-3) and far from it: the flags are
    PX4's, and the integral freezes in a flagged direction only (a 1e-9 miss no longer stops it)."""
    from sim_vehicles.plant.px4_control import gain_vector, rate_control, saturation

    un = np.array(un) * (size / 1e-3)
    flags = saturation(un)
    assert flags == pytest.approx(px4_saturation_flags(un))
    err = np.array([0.3, -0.3, 0.3])  # a rate error each way
    _, integral = rate_control(np.zeros(3), err, np.zeros(3), np.zeros(3), flags, gain_vector({}), 0.001)
    for a in range(3):
        grows = abs(integral[a]) > 0.0
        assert grows == (flags[a] * err[a] <= 0.0), (a, flags, integral)
