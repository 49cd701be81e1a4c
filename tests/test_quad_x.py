"""The rotor-level quadrotor (``px4_quad_x``): its rotors and motors, and the whole model, against
closed forms: the motors' step responses (SIH's thrust lag and the speed lag, alone and in the
whole model with its airframe's time constant), the rotors' wrench against r x F, hover, a small
attitude step against the linearised cascade on PX4's torque scale, the yaw torque's sign and
size, PX4's yaw-torque low-pass (in the model, and over many steps); and, for every built-in
model, any valid setpoint from any state keeps the vehicle finite. The mixer and the attitude loop
against PX4's own are ``test_px4_allocation`` and ``test_px4_attitude``."""

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sim_vehicles.common.command import AttitudeCommand
from sim_vehicles.common.state import POS, QUAT, RATE, VEL, make_state
from sim_vehicles.plant.px4_control import yaw_lowpass
from sim_vehicles.plant.px4_params import BY_NAME, GAINS
from sim_vehicles.plant.quad_x import AIRFRAME, INTEGRAL, QuadX
from sim_vehicles.plant.rigid_body import derivative
from sim_vehicles.plant.rotors import (
    SPEED_LAG,
    SPIN,
    THRUST_LAG,
    X_SIGN,
    Y_SIGN,
    effectiveness,
    motor_step,
    rotor_wrench,
    thrust_fraction,
)
from sim_vehicles.plant.wind import WindModel
from tests.strategies import in_range
from tests.support import sih_quad, sih_roll_step

pytestmark = pytest.mark.unit

T_MAX, Q_MAX, L_R, L_P = 5.0, 0.1, 0.2, 0.2  # PX4 SIH's quadrotor: per rotor [N], [N m], arms [m]
E = effectiveness(T_MAX, Q_MAX, L_R, L_P)
SIH = sih_quad()
DT = 0.001
unit = st.floats(0.0, 1.0)


def _roll_q(angle: float) -> np.ndarray:
    return np.array([math.cos(angle / 2), math.sin(angle / 2), 0.0, 0.0])


def _roll_of(q: np.ndarray) -> float:
    return 2 * math.atan2(q[1], q[0])


# -- the rotors ------------------------------------------------------------------------------------
@given(st.tuples(unit, unit, unit, unit))
def test_the_rotor_wrench_is_the_sum_of_r_cross_f_and_the_drag_torques(f):
    f = np.array(f)
    T, tau = rotor_wrench(f, T_MAX, Q_MAX, L_R, L_P)
    thrusts = T_MAX * f
    r = np.stack([X_SIGN * L_P, Y_SIGN * L_R, np.zeros(4)], axis=1)
    F = np.stack([np.zeros(4), np.zeros(4), thrusts], axis=1)
    expected = np.cross(r, F).sum(axis=0) + np.array([0.0, 0.0, (SPIN * Q_MAX * f).sum()])
    assert pytest.approx(thrusts.sum(), abs=1e-12) == T
    assert tau == pytest.approx(expected, abs=1e-12)
    assert np.concatenate([[T], tau]) == pytest.approx(E @ f, abs=1e-12)  # E is the wrench of f


def test_yaw_torque_sign_and_size_clockwise_rotors_turn_the_body_counter_clockwise():
    a, b = 0.36, 0.64  # counter-clockwise rotors (1, 2) at a, clockwise ones (3, 4) at b
    T, tau = rotor_wrench(np.array([a, a, b, b]), T_MAX, Q_MAX, L_R, L_P)
    assert tau[0] == 0.0 and tau[1] == 0.0  # the pairs sit on the diagonals: no roll or pitch
    assert tau[2] == pytest.approx(2 * Q_MAX * (b - a), rel=1e-12) and tau[2] > 0  # +z: CCW from above
    assert pytest.approx(2 * T_MAX * (a + b), rel=1e-12) == T


@pytest.mark.parametrize("model", [THRUST_LAG, SPEED_LAG])
@pytest.mark.parametrize("tau_s", [0.0, 0.02, 0.05, 0.08])
def test_a_motor_steps_to_its_setpoint_as_a_first_order_lag(model, tau_s):
    """SIH's thrust lag: the thrust fraction ``f(t) = u + (f_0 - u) exp(-t / tau)``; the speed
    lag: the speed ``s(t) = sqrt(u) + (s_0 - sqrt(u)) exp(-t / tau)`` and thrust ``s^2``. Sampled
    exactly at every step: the closed forms, to rounding; both settle at the thrust asked."""
    decay = math.exp(-DT / tau_s) if tau_s > 0 else 0.0
    u = np.array([0.81, 0.25, 0.49, 1.0])
    target = np.sqrt(u) if model == SPEED_LAG else u
    m = np.full(4, 0.3)
    for k in range(1, 201):
        m = motor_step(m, u, decay, model)
        lag = math.exp(-k * DT / tau_s) if tau_s > 0 else 0.0
        assert m == pytest.approx(target + (0.3 - target) * lag, rel=1e-12, abs=1e-15)
    for _ in range(3000):
        m = motor_step(m, u, decay, model)
    assert thrust_fraction(m, model) == pytest.approx(u, abs=1e-12)


@settings(max_examples=20, deadline=None, derandomize=True)
@given(model=st.sampled_from([THRUST_LAG, SPEED_LAG]), tau_s=st.floats(0.002, 0.9), u=st.floats(0.0, 1.0))
def test_the_quadrotors_motors_follow_a_thrust_step_with_its_airframes_time_constant(model, tau_s, u):
    """The whole quadrotor, level at hover, asked for the thrust fraction ``u``: each rotor's
    thrust follows the lag's closed form with the airframe's ``T_TAU_S`` (the motors' unit test
    above takes the decay as given; this is the decay the model makes of its time constant)."""
    q = _quad({"T_TAU_S": tau_s, "MOTOR_MODEL": model})
    start = q.thrust_fractions[0]
    q.set_command(AttitudeCommand(q_c=np.array([1.0, 0.0, 0.0, 0.0]), thrust_N=u * SIH.max_thrust_N))
    target, s0 = (math.sqrt(u), math.sqrt(start)) if model == SPEED_LAG else (u, start)
    for k in (1, 7, 40):
        q.advance(k - round(q.time_s / DT))
        s = target + (s0 - target) * math.exp(-k * DT / tau_s)
        expected = s * s if model == SPEED_LAG else s
        assert q.thrust_fractions == pytest.approx(np.full(4, expected), rel=1e-9, abs=1e-12), k


def test_a_thrust_step_through_the_speed_lag_rises_slower_than_sihs_thrust_lag():
    """From stopped to full: the speed lag's thrust ``(1 - e^-t/tau)^2`` lags SIH's ``1 -
    e^-t/tau`` by up to a quarter of full thrust (at ``t = tau ln 2``)."""
    tau = 0.05
    decay = math.exp(-DT / tau)
    f, s = np.zeros(4), np.zeros(4)
    worst = 0.0
    for _ in range(300):
        f = motor_step(f, np.ones(4), decay, THRUST_LAG)
        s = motor_step(s, np.ones(4), decay, SPEED_LAG)
        worst = max(worst, float(f[0] - thrust_fraction(s, SPEED_LAG)[0]))
    assert worst == pytest.approx(0.25, abs=1e-3)


# -- the model ---------------------------------------------------------------------------------------
def _quad(airframe: dict | None = None, px4: dict | None = None, x0: np.ndarray | None = None) -> QuadX:
    return QuadX(SIH, make_state([0.0, 0.0, 10.0]) if x0 is None else x0, DT, airframe, px4)


@pytest.mark.parametrize("model", [THRUST_LAG, SPEED_LAG])
def test_it_hovers_in_equilibrium_with_every_rotor_at_the_weight_over_four(model):
    """With either motor model (the motors' state is a thrust fraction or a speed, whose square
    the thrust is): held at hover thrust, each rotor gives a quarter of the weight, and the
    vehicle stays where it is, level and still."""
    q = _quad({"MOTOR_MODEL": model})
    q.advance(3000)
    f = SIH.mass_kg * SIH.g_mps2 / 4 / T_MAX
    assert q.thrust_fractions == pytest.approx(np.full(4, f), abs=1e-12)
    assert q.state[POS] == pytest.approx([0.0, 0.0, 10.0], abs=1e-9)
    assert q.state[VEL] == pytest.approx(np.zeros(3), abs=1e-9)
    assert q.state[QUAT] == pytest.approx([1.0, 0.0, 0.0, 0.0], abs=1e-12)


def _roll_step(
    angle: float, rate_p: float, seconds: float, rate_d: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """The roll of a quadrotor without motor lag or I (D ``rate_d``) after a roll command of ``angle``."""
    q = _quad({"T_TAU_S": 0.0}, {"MC_ROLLRATE_P": rate_p, "MC_ROLLRATE_I": 0.0, "MC_ROLLRATE_D": rate_d})
    q.set_command(AttitudeCommand(q_c=_roll_q(angle), thrust_N=SIH.hover_thrust_N))
    t, roll = [], []
    for k in range(1, round(seconds / DT) + 1):
        q.advance(1)
        t.append(k * DT)
        roll.append(_roll_of(q.state[QUAT]))
    return np.array(t), np.array(roll)


@pytest.mark.parametrize("rate_p", [0.15, 0.3])
def test_a_small_roll_step_follows_the_linearised_cascade(rate_p):
    """Roll alone, no motor lag, P only: ``J theta'' = U P_r (P_a (theta_c - theta) - theta')``
    (``U``: the full roll torque a normalised 1 is), a second-order system with ``wn^2 = U P_r
    P_a / J`` and ``2 zeta wn = U P_r / J``. The tolerance: the attitude error is ``2 sin(e / 2)``
    (relative error ``e^2 / 24``, 2e-5 here) and the loop samples every millisecond (half a step's
    delay: ``wn dt / 2`` of the step, under 1 %), so 2 % of the step holds with room."""
    angle = 0.02
    t, roll = _roll_step(angle, rate_p, 1.5)
    assert np.max(np.abs(roll - angle * sih_roll_step(t, rate_p))) < 0.02 * angle
    # and the two gains differ where the closed forms do: the test tells them apart
    assert np.max(np.abs(roll - angle * sih_roll_step(t, 0.45 - rate_p))) > 0.05 * angle


@pytest.mark.parametrize("rate_p", [0.15, 0.3])
def test_the_rate_loops_d_term_acts_on_the_measured_angular_acceleration(rate_p):
    """With PX4's D term, ``- D_r theta''`` on the normalised torque, the same cascade as above
    with the inertia ``J + U D_r`` (``tests.support.roll_cascade_step``): the model's D acts on the
    body's angular acceleration as it measures it (the rates' difference over one step). The
    backward difference lags half a step, as the sampling does, and ``U D_r / J`` = 0.45 here (the
    difference recursion's factor, well inside 1), so the P-only test's 2 % of the step holds; the
    D term moves the response by more than 3 % of it (the inertia 45 % larger)."""
    angle, rate_d = 0.02, 0.004
    t, roll = _roll_step(angle, rate_p, 1.5, rate_d)
    assert np.max(np.abs(roll - angle * sih_roll_step(t, rate_p, rate_d))) < 0.02 * angle
    assert np.max(np.abs(roll - angle * sih_roll_step(t, rate_p))) > 0.03 * angle  # D tells


@settings(max_examples=6, deadline=None)
@given(
    st.floats(0.5, 8.0),  # wind speed [m/s]
    st.floats(-math.pi, math.pi),  # its heading
    st.floats(0.02, 1.5),  # drag [N s^2/m^2]: under and over 1
)
def test_a_level_hover_in_a_steady_wind_drifts_as_quadratic_drag_says(speed, heading, drag):
    """Level at hover thrust in a steady horizontal wind ``W`` with quadratic drag ``c``: the
    attitude and the height hold (the drag acts at the centre, the thrust balances the weight),
    and the velocity relative to the air, along ``W``, obeys ``m u' = -c u^2``: ``u = W / (1 + c
    W t / m)``, so ``v = W - u`` and the distance flown ``W t - (m / c) ln(1 + c W t / m)``. RK4's
    error per 1 ms step is ``(c W / m)^4 W dt^5``-small: 1e-7 of the wind is room."""
    w = speed * np.array([math.cos(heading), math.sin(heading), 0.0])
    params = dataclasses.replace(SIH, drag_Ns2pm2=drag)
    q = QuadX(params, make_state([0.0, 0.0, 10.0]), DT)
    q.wind = WindModel(1, mean_mps=tuple(w))
    seconds = 1.0
    q.advance(round(seconds / DT))
    k = drag * speed / params.mass_kg
    u = speed / (1.0 + k * seconds)
    flown = speed * seconds - math.log1p(k * seconds) * params.mass_kg / drag
    along = w / speed
    assert q.state[VEL] == pytest.approx((speed - u) * along, abs=1e-7 * speed)
    assert q.state[POS] == pytest.approx(np.array([0.0, 0.0, 10.0]) + flown * along, abs=1e-7 * speed)
    assert q.state[QUAT] == pytest.approx([1.0, 0.0, 0.0, 0.0], abs=1e-12)


def _level_with_yaw_rate(q: QuadX, rate: float) -> None:
    """Command ``q`` level at hover thrust with a yaw rate ``rate`` [rad/s] fed forward."""
    level = np.array([1.0, 0.0, 0.0, 0.0])
    q.set_command(
        AttitudeCommand(q_c=level, thrust_N=SIH.hover_thrust_N, omega_c_B=np.array([0.0, 0.0, rate]))
    )


def test_a_yaw_rate_command_speeds_up_the_clockwise_rotors_and_turns_it_counter_clockwise():
    q = _quad()
    _level_with_yaw_rate(q, 0.5)
    q.advance(20)
    f = q.thrust_fractions
    assert f[2] > f[0] and f[3] > f[1] and f[2] == pytest.approx(f[3]) and f[0] == pytest.approx(f[1])
    q.advance(200)
    assert q.state[RATE][2] > 0.05


def test_roll_and_pitch_rates_of_an_attitude_setpoint_are_not_flown_as_px4_does_not():
    """PX4 takes only the yaw rate of a SET_ATTITUDE_TARGET that carries an attitude: roll and
    pitch rates change nothing, bit for bit."""
    runs = []
    for omega in ([0.0, 0.0, 0.3], [2.0, -1.5, 0.3]):
        q = _quad()
        q.set_command(
            AttitudeCommand(q_c=_roll_q(0.1), thrust_N=SIH.hover_thrust_N, omega_c_B=np.array(omega))
        )
        q.advance(500)
        runs.append(q.ext.copy())
    assert np.array_equal(runs[0], runs[1])


def test_the_yaw_torque_passes_px4s_first_order_low_pass():
    """MC_YAW_TQ_CUTOFF (2 Hz): the yaw torque asked at once by a yaw-rate step reaches the rotors
    through ``alpha = dt / (dt + 1 / (2 pi fc))`` per step; with the cutoff at 0 it is there at once.
    Compare the rotors' yaw split one step after the step: the filtered one is alpha of the other."""
    fc = 2.0
    alpha = DT / (DT + 1 / (2 * math.pi * fc))
    split = []
    for cutoff in (fc, 0.0):
        q = _quad({"T_TAU_S": 0.0}, {"MC_YAW_TQ_CUTOFF": cutoff})
        _level_with_yaw_rate(q, 1.0)
        q.advance(1)
        f = q.thrust_fractions
        split.append(f[2] - f[0])
    assert split[0] == pytest.approx(alpha * split[1], rel=1e-9)


@settings(max_examples=50, deadline=None, derandomize=True)
@given(
    s0=st.floats(-1.0, 1.0), x=st.floats(-1.0, 1.0), cutoff=st.floats(0.05, 10.0), steps=st.integers(1, 400)
)
def test_the_yaw_torque_low_pass_settles_on_a_held_input_as_a_geometric_sequence(s0, x, cutoff, steps):
    """PX4's ``AlphaFilter`` from any state ``s0`` on a held input ``x``: ``s_k = x + (s0 - x)
    (1 - alpha)^k``, ``alpha = dt / (dt + 1 / (2 pi fc))``; with the cutoff at 0 it is ``x`` at
    once. (The model's test above is one step from zero, where any ``s + alpha (x +- s)`` agrees.)"""
    alpha = DT / (DT + 1 / (2 * math.pi * cutoff))
    s = s0
    for _ in range(steps):
        s = yaw_lowpass(s, x, cutoff, DT)
    assert s == pytest.approx(x + (s0 - x) * (1 - alpha) ** steps, rel=1e-9, abs=1e-12)
    assert yaw_lowpass(s0, x, 0.0, DT) == pytest.approx(x, rel=1e-12, abs=1e-15)


@settings(max_examples=10, deadline=None, derandomize=True)
@given(heading=st.floats(-math.pi, math.pi), tilt=st.floats(0.2, 1.0))
def test_a_quadrotor_whose_rotors_cannot_give_the_torque_asked_does_not_wind_its_rate_integral(heading, tilt):
    """At zero thrust no rotor can slow further: a tilt asked is torque the allocation cannot
    give, step after step. PX4 reads the allocator's miss and stops the rate integral growing
    toward it, so in 0.2 s the roll and pitch integrals grow at most the one step before the first
    miss is known (each step's growth is at most K I |err| dt, |err| at most the attitude P gain
    times the tilt, the body not turning); carried nowhere, they would grow every step."""
    q = _quad({"T_TAU_S": 0.0})
    axis = np.array([math.cos(heading), math.sin(heading), 0.0])
    q.set_command(
        AttitudeCommand(q_c=np.array([math.cos(tilt / 2), *(math.sin(tilt / 2) * axis)]), thrust_N=0.0)
    )
    q.advance(200)
    for a, name in ((0, "ROLL"), (1, "PITCH")):
        step = GAINS[f"MC_{name}RATE_K"] * GAINS[f"MC_{name}RATE_I"] * GAINS[f"MC_{name}_P"] * tilt * DT
        assert abs(q.ext[INTEGRAL][a]) <= step * (1 + 1e-9), name


def test_the_rigid_body_under_rotor_forces_matches_finite_differences():
    """One RK4 step of the quadrotor against the rigid body's derivative under the wrench of its
    rotors, by central differences (the state's second derivative is bounded, so the error is
    O(h^2))."""
    x0 = make_state([1.0, 2.0, 3.0], [0.5, -0.2, 0.1], _roll_q(0.3), [0.2, -0.1, 0.3])
    q = _quad({"T_TAU_S": 0.0}, x0=x0)
    T, tau = rotor_wrench(q.thrust_fractions, T_MAX, Q_MAX, L_R, L_P)
    f = derivative(x0, T, tau, SIH.mass_kg, SIH.inertia, SIH.g_mps2)
    from sim_vehicles.plant.rigid_body import rk4_step

    h = 1e-4
    fwd = rk4_step(x0, T, tau, SIH.mass_kg, SIH.inertia, SIH.g_mps2, h)
    back = rk4_step(x0, T, tau, SIH.mass_kg, SIH.inertia, SIH.g_mps2, -h)
    assert (fwd - back) / (2 * h) == pytest.approx(f, abs=1e-6)


@settings(max_examples=25, deadline=None)
@given(st.data())
def test_a_px4_parameter_set_anywhere_in_its_range_flies_as_a_quadrotor_built_with_it(data):
    """``set_param(name, v)``: taken exactly when ``v`` is within PX4's range, both ends included,
    each also as the float32 PX4 holds it (``px4_params``, the one declaration); a value taken
    flies bit for bit as a quadrotor built with it (a tilt, a yaw rate and a thrust step: every
    gain acts); a value refused (outside the range, nan) changes nothing."""
    name = data.draw(st.sampled_from(sorted(GAINS)))
    p = BY_NAME[name]
    value = data.draw(in_range(p.low, p.high))
    span = p.high - p.low
    outside = data.draw(
        st.one_of(
            st.floats(p.low - 10 * span - 1, p.low, exclude_max=True).filter(lambda v: v < np.float32(p.low)),
            st.floats(p.high, p.high + 10 * span + 1, exclude_min=True).filter(
                lambda v: v > np.float32(p.high)
            ),
            st.just(math.nan),
        )
    )
    q, built = _quad(), _quad(px4={name: value})
    assert q.set_param(name, value) and q.tunables == built.tunables
    assert np.array_equal(q.gains, built.gains)
    assert not q.set_param(name, outside) and q.tunables == built.tunables
    command = AttitudeCommand(
        q_c=_roll_q(0.3), thrust_N=0.8 * SIH.max_thrust_N, omega_c_B=np.array([0.0, 0.0, 0.5])
    )
    for vehicle in (q, built):
        vehicle.set_command(command)
        vehicle.advance(200)
    assert np.array_equal(q.ext, built.ext, equal_nan=True)


def test_its_pararameters_are_px4s_and_a_set_outside_the_range_is_refused():
    q = _quad()
    assert q.tunables["MC_ROLLRATE_P"] == 0.15 and q.tunables["MC_YAW_WEIGHT"] == 0.4
    assert q.tunables["MC_YAW_TQ_CUTOFF"] == 2.0
    assert q.set_param("MC_ROLLRATE_P", 0.3) and q.tunables["MC_ROLLRATE_P"] == 0.3
    assert not q.set_param("MC_ROLLRATE_P", 0.9) and q.tunables["MC_ROLLRATE_P"] == 0.3  # PX4: 0.01..0.5
    assert not q.set_param("MC_ROLLRATE_P", float("nan")) and not q.set_param("NOPE", 1.0)
    assert AIRFRAME == {"Q_MAX_NM": 0.1, "L_ROLL_M": 0.2, "L_PITCH_M": 0.2, "T_TAU_S": 0.05, "MOTOR_MODEL": 0}
