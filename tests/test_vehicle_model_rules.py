"""What every built-in vehicle model does with what it is given (``plant.contract``), from random
states and commands: a state of another size is one line; it holds the command it was given; a
command attitude and its negative (the same rotation) fly the same bits, and the vehicle turns the
short way; a thrust beyond its range flies as the nearest one in it; a state's quaternion not of
unit length flies as its unit one; a body-rate limit written in place (as a PARAM_SET does) is the
limit it flies; each advance asks the wind where and when its steps start. And the paper's
autopilot (``plant.autopilot``) against closed forms: the thrust it applies, the rates it clips."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sim_vehicles.common.command import AttitudeCommand
from sim_vehicles.common.quaternion import body_z_axis, from_axis_angle, qmul
from sim_vehicles.common.state import POS, QUAT, STATE_SIZE, VEL, make_state
from sim_vehicles.models.build import MODELS
from sim_vehicles.models.vehicle_config import VehicleConfig
from tests.strategies import unit_quaternions

pytestmark = pytest.mark.unit
DT = 1e-3
RULES = settings(max_examples=25, deadline=None, derandomize=True)
axes = st.tuples(*[st.floats(-1.0, 1.0)] * 3).filter(lambda a: np.linalg.norm(a) > 0.1).map(np.array)
rates = st.tuples(*[st.floats(-2.0, 2.0)] * 3).map(np.array)


def _vehicle(model: str, q0: np.ndarray, omega0=(0.0, 0.0, 0.0), **spec):
    return MODELS[model](
        VehicleConfig(model=model, **spec), make_state([0.0, 0.0, 10.0], q_wb=q0, omega_radps=omega0), DT
    )


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    """The rotation angle between two attitudes [rad] (0..pi, either sign of either)."""
    return 2.0 * math.acos(min(1.0, abs(float(np.dot(a, b)))))


def _tilt(a: np.ndarray, b: np.ndarray) -> float:
    """The angle between the body z axes of two attitudes [rad]."""
    return math.acos(max(-1.0, min(1.0, float(np.dot(body_z_axis(a), body_z_axis(b))))))


@pytest.mark.parametrize("model", sorted(MODELS))
@RULES
@given(
    q0=unit_quaternions(),
    axis=axes,
    angle=st.floats(0.5, 3.1),
    omega0=rates,
    sign=st.sampled_from([1.0, -1.0]),
)
def test_an_attitude_and_its_negative_fly_the_same_bits_and_the_vehicle_turns_the_short_way(
    model, q0, axis, angle, omega0, sign
):
    """q and -q are one rotation: a vehicle given either flies the same. From rest it turns
    toward the command the short way (an angle under pi): after 50 ms it is nearer, where the long
    way round would first take it farther (PX4's quadrotor: its thrust axis is nearer, as PX4
    tilts before it yaws)."""
    q_c = qmul(q0, from_axis_angle(axis, angle)) * sign
    flown = []
    for command in (q_c, -q_c):
        v = _vehicle(model, q0, omega0)
        v.set_command(AttitudeCommand(q_c=command, thrust_N=v.params.hover_thrust_N))
        v.advance(100)
        flown.append(v.state.copy())
    np.testing.assert_array_equal(flown[0], flown[1])
    still = _vehicle(model, q0)
    still.set_command(AttitudeCommand(q_c=q_c, thrust_N=still.params.hover_thrust_N))
    still.advance(50)
    if model == "px4_quad_x":  # PX4 turns its thrust axis first (reduced attitude), then yaws:
        # held to its tilt where there is one to close (a command of mostly yaw has none)
        assert _tilt(still.state[QUAT], q_c) < _tilt(q0, q_c) or _tilt(q0, q_c) < 0.1
    else:
        assert _angle(still.state[QUAT], q_c) < angle


@pytest.mark.parametrize("model", sorted(MODELS))
@RULES
@given(q0=unit_quaternions(), axis=axes, angle=st.floats(0.0, 1.5), over=st.floats(1e-6, 2.0))
def test_a_thrust_beyond_its_range_flies_as_the_nearest_thrust_in_it(model, q0, axis, angle, over):
    """MAVLink's thrust is 0..1 of the largest: a command above the largest flies as the largest,
    one below zero as zero, bit for bit."""
    q_c = qmul(q0, from_axis_angle(axis, angle))
    for outside, edge in ((1.0 + over, 1.0), (-over, 0.0)):
        flown = []
        for fraction in (outside, edge):
            v = _vehicle(model, q0)
            v.set_command(AttitudeCommand(q_c=q_c, thrust_N=fraction * v.params.max_thrust_N))
            v.advance(60)
            flown.append(v.state.copy())
        np.testing.assert_array_equal(flown[0], flown[1])


@pytest.mark.parametrize("model", sorted(MODELS))
@RULES
@given(q0=unit_quaternions(), scale=st.floats(0.2, 5.0), omega0=rates)
def test_a_state_quaternion_of_any_length_flies_as_its_unit_one(model, q0, scale, omega0):
    """The attitude is the rotation, not the vector's length: the vehicle starts at the unit
    quaternion and flies as one started there (to the rounding of one division)."""
    v = _vehicle(model, q0 * scale, omega0)
    assert np.linalg.norm(v.state[QUAT]) == pytest.approx(1.0, abs=4e-16)
    unit = _vehicle(model, q0, omega0)
    for vehicle in (v, unit):
        vehicle.set_command(AttitudeCommand(q_c=q0, thrust_N=vehicle.params.hover_thrust_N))
        vehicle.advance(80)
    np.testing.assert_allclose(v.state, unit.state, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("model", sorted(MODELS))
@pytest.mark.parametrize("size", [0, 12, 14, 17])
def test_a_state_of_another_size_is_one_line_naming_both_sizes(model, size):
    with pytest.raises(ValueError) as e:
        MODELS[model](VehicleConfig(model=model), np.zeros(size), DT)
    line = str(e.value)
    assert f"{STATE_SIZE} entries" in line and f"({size},)" in line and "\n" not in line, line


@pytest.mark.parametrize("model", sorted(MODELS))
def test_a_vehicle_holds_the_command_it_was_given_and_flies_a_rate_limit_written_in_place(model):
    """``command`` is the one set last. The rate limit a PARAM_SET writes into ``max_rate_rps`` is
    the one flown, even where the config gave whole numbers: the vehicle built with integer limits
    and then given fractional ones flies as the one built with the fractional ones."""
    q0 = from_axis_angle(np.array([0.3, -0.5, 0.8]), 0.4)
    limits = (2.5, 2.25, 1.5)
    given_ints = _vehicle(model, q0, max_rate_rps=(3, 3, 2))
    given_ints.max_rate_rps[:] = limits
    built = _vehicle(model, q0, max_rate_rps=limits)
    command = AttitudeCommand(
        q_c=qmul(q0, from_axis_angle(np.array([1.0, 1.0, -1.0]), 1.2)),
        thrust_N=built.params.hover_thrust_N,
        omega_c_B=np.array([6.0, -6.0, 5.0]),
    )
    for v in (given_ints, built):
        v.set_command(command)
        assert v.command is command
        v.advance(300)
    np.testing.assert_array_equal(given_ints.state, built.state)


@pytest.mark.parametrize("model", sorted(MODELS))
def test_each_advance_asks_the_wind_at_the_instant_and_the_place_its_steps_start(model):
    """The wind a model reads (``update(t_s, position_m)``, RotorPy's call) is asked once per
    ``advance``, at the time and the position its steps start from, and is the wind in force."""

    class Recorder:
        def __init__(self) -> None:
            self.asked: list[tuple[float, np.ndarray]] = []

        def update(self, t_s: float, position_m: np.ndarray) -> np.ndarray:
            self.asked.append((t_s, position_m.copy()))
            return np.array([1.0, -2.0, 0.5]) * len(self.asked)

    x0 = make_state([0.0, 0.0, 10.0], [3.0, -1.0, 0.0])
    v = MODELS[model](VehicleConfig(model=model, drag_Ns2pm2=0.3), x0, DT)
    wind = Recorder()
    v.wind = wind
    starts = []
    for n in (1, 7, 20):
        starts.append((v.time_s, v.state[POS].copy()))
        v.advance(n)
        assert np.array_equal(v.wind_W, np.array([1.0, -2.0, 0.5]) * len(starts))
    assert [t for t, _ in wind.asked] == [t for t, _ in starts] == [0.0, DT, 8 * DT]
    for (_, asked), (_, start) in zip(wind.asked, starts, strict=True):
        assert np.array_equal(asked, start)
    assert len({tuple(p) for _, p in starts}) == 3  # it moved: the places differ


@RULES
@given(yaw=st.floats(-math.pi, math.pi), thrust_rel=st.floats(-1.0, 2.0), duration_steps=st.integers(1, 200))
def test_the_paper_vehicle_level_accelerates_as_its_clipped_thrust_over_its_mass_less_g(
    yaw, thrust_rel, duration_steps
):
    """Level and holding its attitude, the paper's vehicle feels its thrust, clipped to
    0..max_thrust_N, up its body z and gravity down: v_z(t) = (clip(T) / m - g) t, which RK4
    integrates exactly; nothing else moves."""
    q0 = from_axis_angle(np.array([0.0, 0.0, 1.0]), yaw)
    v = _vehicle("paper_vtol", q0)
    p = v.params
    v.set_command(AttitudeCommand(q_c=q0, thrust_N=thrust_rel * p.max_thrust_N))
    v.advance(duration_steps)
    t = duration_steps * DT
    a = min(max(thrust_rel, 0.0), 1.0) * p.max_thrust_N / p.mass_kg - p.g_mps2
    assert v.state[VEL][2] == pytest.approx(a * t, rel=1e-12, abs=1e-12)
    assert np.all(v.state[VEL][:2] == 0.0)


@RULES
@given(
    q0=unit_quaternions(), axis=axes, angle=st.floats(0.0, 2.0), over=st.tuples(*[st.floats(-3.0, 3.0)] * 3)
)
def test_the_paper_vehicles_command_rates_beyond_the_limit_fly_as_the_limit(q0, axis, angle, over):
    """The commanded body rates are clipped to +- max_rate_rps, each axis alone: a command beyond
    the limit flies as its clipped command, bit for bit, and one inside it flies as under a limit
    far above it."""
    limits = np.array([1.5, 1.25, 0.75])
    omega_c = np.array(over) * limits
    q_c = qmul(q0, from_axis_angle(axis, angle))
    flown = []
    for rates_c, limit in (
        (omega_c, limits),
        (np.clip(omega_c, -limits, limits), limits),
        (np.clip(omega_c, -limits, limits), 10 * limits),
    ):
        v = _vehicle("paper_vtol", q0, max_rate_rps=tuple(limit))
        v.set_command(AttitudeCommand(q_c=q_c, thrust_N=v.params.hover_thrust_N, omega_c_B=rates_c))
        v.advance(60)
        flown.append(v.state.copy())
    np.testing.assert_array_equal(flown[0], flown[1])
    np.testing.assert_array_equal(flown[1], flown[2])
