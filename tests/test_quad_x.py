"""The rotor-level quadrotor (``px4_quad_x``): its rotors, motors and mixer, PX4's attitude and
rate loops, and the whole model, against closed forms: the motor's step response, the
allocation inverting the effectiveness within the limits and its saturation priority
(property-based), the rotors' wrench against r x F, hover, a small attitude step against the
linearised cascade, and the yaw torque's sign and size."""

import math

import numpy as np
import pytest
from hypothesis import assume, given
from hypothesis import strategies as st

from sim_vehicles.common.command import AttitudeCommand
from sim_vehicles.common.state import POS, QUAT, RATE, VEL, make_state
from sim_vehicles.plant.params import VehicleParams
from sim_vehicles.plant.quad_x import AIRFRAME, QuadX
from sim_vehicles.plant.rigid_body import derivative
from sim_vehicles.plant.rotors import (
    SPIN,
    X_SIGN,
    Y_SIGN,
    allocate,
    effectiveness,
    full_torque_Nm,
    motor_speeds,
    rotor_wrench,
)

pytestmark = pytest.mark.unit

T_MAX, Q_MAX, L_R, L_P = 5.0, 0.1, 0.2, 0.2  # PX4 SIH's quadrotor: per rotor [N], [N m], arms [m]
E = effectiveness(T_MAX, Q_MAX, L_R, L_P)
M = np.linalg.inv(E)
SIH = VehicleParams(1.0, (0.025, 0.025, 0.03), 4 * T_MAX)
DT = 0.001
unit = st.floats(0.0, 1.0)


def _roll_q(angle: float) -> np.ndarray:
    return np.array([math.cos(angle / 2), math.sin(angle / 2), 0.0, 0.0])


def _roll_of(q: np.ndarray) -> float:
    return 2 * math.atan2(q[1], q[0])


# -- the rotors ------------------------------------------------------------------------------------
@given(st.tuples(unit, unit, unit, unit))
def test_the_rotor_wrench_is_the_sum_of_r_cross_f_and_the_drag_torques(s):
    s = np.array(s)
    T, tau = rotor_wrench(s, T_MAX, Q_MAX, L_R, L_P)
    f = T_MAX * s**2
    r = np.stack([X_SIGN * L_P, Y_SIGN * L_R, np.zeros(4)], axis=1)
    F = np.stack([np.zeros(4), np.zeros(4), f], axis=1)
    expected = np.cross(r, F).sum(axis=0) + np.array([0.0, 0.0, (SPIN * Q_MAX * s**2).sum()])
    assert pytest.approx(f.sum(), abs=1e-12) == T
    assert tau == pytest.approx(expected, abs=1e-12)
    assert np.concatenate([[T], tau]) == pytest.approx(E @ s**2, abs=1e-12)  # E is the wrench of u = s^2


def test_yaw_torque_sign_and_size_clockwise_rotors_turn_the_body_counter_clockwise():
    a, b = 0.6, 0.8  # counter-clockwise rotors (1, 2) at a, clockwise ones (3, 4) at b
    T, tau = rotor_wrench(np.array([a, a, b, b]), T_MAX, Q_MAX, L_R, L_P)
    assert tau[0] == 0.0 and tau[1] == 0.0  # the pairs sit on the diagonals: no roll or pitch
    assert (
        tau[2] == pytest.approx(2 * Q_MAX * (b * b - a * a), rel=1e-12) and tau[2] > 0
    )  # +z: CCW from above
    assert pytest.approx(2 * T_MAX * (a * a + b * b), rel=1e-12) == T
    assert full_torque_Nm(T_MAX, Q_MAX, L_R, L_P) == pytest.approx(
        [2 * L_R * T_MAX, 2 * L_P * T_MAX, 2 * Q_MAX]
    )


@pytest.mark.parametrize("tau_s", [0.0, 0.02, 0.05, 0.08])
def test_a_motor_steps_to_its_setpoint_as_a_first_order_lag(tau_s):
    """Speed ``s(t) = s_c + (s_0 - s_c) exp(-t / tau)``, sampled exactly at every step, and so
    thrust ``T_max s(t)^2``: the closed form, to rounding."""
    decay = math.exp(-DT / tau_s) if tau_s > 0 else 0.0
    s = np.full(4, 0.3)
    u = np.array([0.81, 0.25, 0.49, 1.0])  # speed setpoints 0.9, 0.5, 0.7, 1.0
    for k in range(1, 201):
        s = motor_speeds(s, u, decay)
        lag = math.exp(-k * DT / tau_s) if tau_s > 0 else 0.0
        exact = np.sqrt(u) + (0.3 - np.sqrt(u)) * lag
        assert s == pytest.approx(exact, rel=1e-12, abs=1e-15)
    if tau_s > 0:  # 63 % of the step after one time constant (exactly at a whole number of steps)
        k = round(tau_s / DT)
        s = np.full(4, 0.3)
        for _ in range(k):
            s = motor_speeds(s, u, decay)
        assert (s - 0.3) / (np.sqrt(u) - 0.3) == pytest.approx(1 - math.exp(-1), rel=1e-9)


# -- the allocation --------------------------------------------------------------------------------
@given(st.tuples(*[st.floats(0.001, 0.999)] * 4))
def test_within_the_limits_the_allocation_inverts_the_effectiveness(u):
    """``M E = I``: a control the rotors can make, with its thrust, roll and pitch alone within
    the limits too (the mixer's first stage), is made exactly, nothing unallocated."""
    assert pytest.approx(np.eye(4), abs=1e-12) == M @ E
    c = E @ np.array(u)
    first = M @ np.array([c[0], c[1], c[2], 0.0])
    assume(np.all(first >= 0.0) and np.all(first <= 1.0))
    got, missed = allocate(c, M, E)
    assert got == pytest.approx(np.array(u), abs=1e-12)
    assert missed == pytest.approx(np.zeros(3), abs=1e-9)


def test_a_demand_that_fits_only_with_its_yaw_is_desaturated_roll_and_pitch_first_as_px4_does():
    """PX4 mixes thrust, roll and pitch before yaw: if those alone leave the limits, roll and
    pitch are scaled back even where the yaw asked for would have brought the rotors back in."""
    u = np.array([0.875, 0.125, 0.125, 0.25])
    c = E @ u
    first = M @ np.array([c[0], c[1], c[2], 0.0])
    assert first.min() < 0.0  # thrust, roll and pitch alone: rotor 2 below stopped
    got, missed = allocate(c, M, E)
    assert np.all(got <= 1.0) and np.any(np.abs(missed[:2]) > 1e-3)  # roll and pitch were cut


controls = st.tuples(st.floats(0.0, 30.0), st.floats(-3.0, 3.0), st.floats(-3.0, 3.0), st.floats(-0.5, 0.5))


@given(controls)
def test_any_demand_gives_actuators_within_limits_and_never_more_thrust_than_asked(c):
    c = np.array(c)
    u, missed = allocate(c, M, E)
    assert np.all(u >= 0.0) and np.all(u <= 1.0)
    made = E @ u
    assert made[0] <= max(c[0], 0.0) + 1e-9  # thrust is never raised to unsaturate (PX4, no air mode)
    assert missed == pytest.approx(c[1:] - made[1:], abs=1e-12)


@given(st.tuples(*[st.floats(0.2, 0.8)] * 4), st.floats(-1.0, 1.0))
def test_yaw_gives_way_before_roll_and_pitch(u_rp, yaw_Nm):
    """Roll and pitch with thrust are mixed first and yaw is scaled back to fit: while the mix is
    not clipped in the end, the roll and pitch torques made are those asked for, and the yaw made
    is of the asked sign and no larger."""
    c = E @ np.array(u_rp)
    c[3] = yaw_Nm
    u, _ = allocate(c, M, E)
    assume(np.all(u > 1e-9) and np.all(u < 1 - 1e-9))
    made = E @ u
    assert made[1:3] == pytest.approx(c[1:3], abs=1e-9)
    assert made[3] * yaw_Nm >= -1e-12 and abs(made[3]) <= abs(yaw_Nm) + 1e-12


@given(st.floats(14.0, 30.0), st.floats(-0.9, 0.9), st.floats(-0.9, 0.9))
def test_roll_and_pitch_are_kept_over_collective_thrust_at_the_top(T, roll, pitch):
    """A demand over the top of the rotors' range is met by lowering the collective thrust, not
    by cutting roll and pitch, whenever lowering alone can make it fit."""
    c = np.array([T, roll, pitch, 0.0])
    u0 = M @ c
    spread = u0.max() - u0.min()
    assume(u0.max() > 1.0 and spread <= 1.0 - 1e-9)  # lowering thrust alone fits it
    u, _ = allocate(c, M, E)
    made = E @ u
    assert made[1:3] == pytest.approx(c[1:3], abs=1e-9) and made[0] < T


# -- the model ---------------------------------------------------------------------------------------
def _quad(airframe: dict | None = None, px4: dict | None = None, x0: np.ndarray | None = None) -> QuadX:
    return QuadX(SIH, make_state([0.0, 0.0, 10.0]) if x0 is None else x0, DT, airframe, px4)


def test_it_hovers_in_equilibrium_with_every_rotor_at_the_weight_over_four():
    q = _quad()
    q.advance(3000)
    s = math.sqrt(SIH.mass_kg * SIH.g_mps2 / 4 / T_MAX)
    assert q.rotor_speeds == pytest.approx(np.full(4, s), abs=1e-12)
    assert q.state[POS] == pytest.approx([0.0, 0.0, 10.0], abs=1e-9)
    assert q.state[VEL] == pytest.approx(np.zeros(3), abs=1e-9)
    assert q.state[QUAT] == pytest.approx([1.0, 0.0, 0.0, 0.0], abs=1e-12)


def _roll_step(angle: float, rate_p: float, seconds: float) -> tuple[np.ndarray, np.ndarray]:
    """The roll of a quadrotor without motor lag, I or D, after a roll command of ``angle``."""
    q = _quad({"T_TAU_S": 0.0}, {"MC_ROLLRATE_P": rate_p, "MC_ROLLRATE_I": 0.0, "MC_ROLLRATE_D": 0.0})
    q.set_command(AttitudeCommand(q_c=_roll_q(angle), thrust_N=SIH.hover_thrust_N))
    t, roll = [], []
    for k in range(1, round(seconds / DT) + 1):
        q.advance(1)
        t.append(k * DT)
        roll.append(_roll_of(q.state[QUAT]))
    return np.array(t), np.array(roll)


def _cascade_response(t: np.ndarray, rate_p: float) -> np.ndarray:
    """The unit step response from rest of the linearised roll cascade with rate gain ``rate_p``
    and attitude gain 6.5: ``x'' + 2 zeta wn x' + wn^2 x = wn^2`` with ``wn^2 = U P_r P_a / J``,
    ``2 zeta wn = U P_r / J`` (``U``: the full roll torque), under- or overdamped."""
    U = full_torque_Nm(T_MAX, Q_MAX, L_R, L_P)[0]
    J = SIH.inertia_kgm2[0]
    a, b = U * rate_p / J, U * rate_p * 6.5 / J  # x'' + a x' + b x = b
    disc = a * a / 4 - b
    if disc < 0:
        wd = math.sqrt(-disc)
        return 1 - np.exp(-a / 2 * t) * (np.cos(wd * t) + a / 2 / wd * np.sin(wd * t))
    r1, r2 = -a / 2 + math.sqrt(disc), -a / 2 - math.sqrt(disc)
    return 1 - (r2 * np.exp(r1 * t) - r1 * np.exp(r2 * t)) / (r2 - r1)


@pytest.mark.parametrize("rate_p", [0.15, 0.3])
def test_a_small_roll_step_follows_the_linearised_cascade(rate_p):
    """Roll alone, no motor lag, P only: ``J theta'' = U P_r (P_a (theta_c - theta) - theta')``
    (``U``: the full roll torque a normalised 1 is), a second-order system with ``wn^2 = U P_r
    P_a / J`` and ``2 zeta wn = U P_r / J``. The tolerance: the attitude error is ``2 sin(e / 2)``
    (relative error ``e^2 / 24``, 2e-5 here) and the loop samples every millisecond (half a step's
    delay: ``wn dt / 2`` of the step, under 1 %), so 2 % of the step holds with room."""
    angle = 0.02
    t, roll = _roll_step(angle, rate_p, 1.5)
    assert np.max(np.abs(roll - angle * _cascade_response(t, rate_p))) < 0.02 * angle
    # and the two gains differ where the closed forms do: the test tells them apart
    assert np.max(np.abs(roll - angle * _cascade_response(t, 0.45 - rate_p))) > 0.05 * angle


def test_a_yaw_rate_command_speeds_up_the_clockwise_rotors_and_turns_it_counter_clockwise():
    q = _quad()
    q.set_command(
        AttitudeCommand(
            q_c=np.array([1.0, 0.0, 0.0, 0.0]),
            thrust_N=SIH.hover_thrust_N,
            omega_c_B=np.array([0.0, 0.0, 0.5]),
        )
    )
    q.advance(20)
    s = q.rotor_speeds
    assert s[2] > s[0] and s[3] > s[1] and s[2] == pytest.approx(s[3]) and s[0] == pytest.approx(s[1])
    q.advance(200)
    assert q.state[RATE][2] > 0.05


def test_the_rigid_body_under_rotor_forces_matches_finite_differences():
    """One RK4 step of the quadrotor against the rigid body's derivative under the wrench of its
    rotors, by central differences (the state's second derivative is bounded, so the error is
    O(h^2))."""
    x0 = make_state([1.0, 2.0, 3.0], [0.5, -0.2, 0.1], _roll_q(0.3), [0.2, -0.1, 0.3])
    q = _quad({"T_TAU_S": 0.0}, x0=x0)
    s = q.rotor_speeds
    T, tau = rotor_wrench(s, T_MAX, Q_MAX, L_R, L_P)
    f = derivative(x0, T, tau, SIH.mass_kg, SIH.inertia, SIH.g_mps2)
    from sim_vehicles.plant.rigid_body import rk4_step

    h = 1e-4
    fwd = rk4_step(x0, T, tau, SIH.mass_kg, SIH.inertia, SIH.g_mps2, h)
    back = rk4_step(x0, T, tau, SIH.mass_kg, SIH.inertia, SIH.g_mps2, -h)
    assert (fwd - back) / (2 * h) == pytest.approx(f, abs=1e-6)


def test_its_pararameters_are_px4s_and_a_set_outside_the_range_is_refused():
    q = _quad()
    assert q.tunables["MC_ROLLRATE_P"] == 0.15 and q.tunables["MC_YAW_WEIGHT"] == 0.4
    assert q.set_param("MC_ROLLRATE_P", 0.3) and q.tunables["MC_ROLLRATE_P"] == 0.3
    assert not q.set_param("MC_ROLLRATE_P", 0.9) and q.tunables["MC_ROLLRATE_P"] == 0.3  # PX4: 0.01..0.5
    assert not q.set_param("MC_ROLLRATE_P", float("nan")) and not q.set_param("NOPE", 1.0)
    assert AIRFRAME == {"Q_MAX_NM": 0.1, "L_ROLL_M": 0.2, "L_PITCH_M": 0.2, "T_TAU_S": 0.05}  # SIH's
