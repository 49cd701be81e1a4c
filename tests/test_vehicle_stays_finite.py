"""No valid setpoint makes a vehicle non-finite: every built-in model, from random states (any
attitude, fast rates), held on random valid commands (any unit quaternion, the one exactly
upside down from the vehicle's and those within 1e-12 rad of it, any thrust the vehicle takes,
any body rates), stays finite with a unit attitude; and the quadrotor so with every PX4 parameter
drawn in its range, its ends included."""

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from sim_vehicles.common.command import AttitudeCommand
from sim_vehicles.common.quaternion import qmul
from sim_vehicles.common.state import QUAT, make_state
from sim_vehicles.models.build import MODELS, build_vehicle
from sim_vehicles.models.vehicle_config import VehicleConfig
from sim_vehicles.plant import px4_params
from tests.strategies import FUZZ, in_range, unit_quaternions

pytestmark = pytest.mark.unit

rates = st.tuples(*[st.floats(-30.0, 30.0)] * 3)


@st.composite
def setpoints(draw, q_now: np.ndarray):
    """Any unit quaternion, or ``q_now`` turned half a turn about a horizontal body axis (its
    thrust axis opposite), exactly or off by at most 1e-12 rad."""
    kind = draw(st.sampled_from(["any", "opposite", "near"]))
    if kind == "any":
        return draw(unit_quaternions())
    phi = draw(st.floats(0.0, 2 * math.pi))
    q = qmul(q_now, np.array([0.0, math.cos(phi), math.sin(phi), 0.0]))
    if kind == "near":
        off = draw(st.floats(-1e-12, 1e-12))
        q = qmul(q, np.array([math.cos(off / 2), 0.0, math.sin(off / 2), 0.0]))
    return q


@FUZZ
@given(st.sampled_from(sorted(MODELS)), st.data())
def test_any_valid_setpoint_from_any_state_keeps_the_vehicle_finite(model, data):
    q0 = data.draw(unit_quaternions())
    x0 = make_state(
        data.draw(st.tuples(*[st.floats(-100.0, 100.0)] * 3)),
        data.draw(st.tuples(*[st.floats(-20.0, 20.0)] * 3)),
        q0,
        data.draw(rates),
    )
    spec = VehicleConfig(model=model)
    vehicle = build_vehicle(spec, 1)
    vehicle.state = x0
    command = AttitudeCommand(
        q_c=data.draw(setpoints(q0)),
        thrust_N=data.draw(st.floats(0.0, spec.max_thrust_N)),
        omega_c_B=np.array(data.draw(st.tuples(*[st.floats(-50.0, 50.0)] * 3))),
    )
    vehicle.set_command(command)
    for _ in range(20):
        vehicle.advance(10)
        x = np.asarray(vehicle.state)
        assert np.all(np.isfinite(x)), (model, x)
        assert np.linalg.norm(x[QUAT]) == pytest.approx(1.0, abs=1e-9)


@st.composite
def px4_params_in_range(draw) -> dict[str, float]:
    """Every PX4 parameter of ``px4_quad_x`` (``plant.px4_params``) drawn in its range, its ends
    and its default as often as the rest."""
    out = {}
    for p in px4_params.PARAMS:
        if p.name in px4_params.RATE_MAX:  # the vehicle's max_rate_rps, not a param
            continue
        if p.choices:
            out[p.name] = draw(st.sampled_from(p.choices))
        else:
            out[p.name] = draw(in_range(p.low, p.high, p.default))
    return out


@FUZZ
@given(st.data())
def test_any_px4_parameter_set_in_range_with_any_valid_setpoint_keeps_the_quadrotor_finite(data):
    """The same, with every PX4 parameter drawn in its range (its ends included), as a PARAM_SET
    or a config may set them: a yaw weight of 0, a gain of 0, no motor lag."""
    q0 = data.draw(unit_quaternions())
    spec = VehicleConfig(model="px4_quad_x", params=data.draw(px4_params_in_range()))
    vehicle = build_vehicle(spec, 1)
    vehicle.state = make_state(
        [0.0, 0.0, 10.0], data.draw(st.tuples(*[st.floats(-20.0, 20.0)] * 3)), q0, data.draw(rates)
    )
    vehicle.set_command(
        AttitudeCommand(
            q_c=data.draw(setpoints(q0)),
            thrust_N=data.draw(st.floats(0.0, spec.max_thrust_N)),
            omega_c_B=np.array(data.draw(st.tuples(*[st.floats(-50.0, 50.0)] * 3))),
        )
    )
    for _ in range(20):
        vehicle.advance(10)
        x = np.asarray(vehicle.state)
        assert np.all(np.isfinite(x)), (spec.params, x)
        assert np.linalg.norm(x[QUAT]) == pytest.approx(1.0, abs=1e-9)
