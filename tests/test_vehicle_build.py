"""The vehicle built from a config is that config (``sim_vehicles.models.build``): what the config
says of the airframe, the rotors, the air and the sensors is what the built vehicle flies with,
for any values in range, read back from the vehicle itself; and a user's model is held to its
parameters as the config's load promises, each refusal one line naming it."""

import dataclasses
import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sim_vehicles.models.build import build_vehicle, sensor_model
from sim_vehicles.models.vehicle_config import Gusts, SensorNoise, VehicleConfig, VehicleConfigError
from sim_vehicles.plant import px4_params
from sim_vehicles.plant.quad_x import AIRFRAME
from sim_vehicles.plant.wind import WIND_MODELS

pytestmark = pytest.mark.unit

positive = st.floats(0.05, 5.0)
seeds = st.integers(0, 2**32)


@settings(max_examples=30, deadline=None)
@given(
    mass=st.floats(0.5, 5.0),
    inertia=st.tuples(positive, positive, positive),
    thrust_to_weight=st.floats(1.5, 4.0),
    drag=st.floats(0.0, 1.0),
    rates=st.tuples(positive, positive, positive),
    model=st.sampled_from(["paper_vtol", "px4_quad_x"]),
)
def test_a_built_vehicles_airframe_is_its_configs(mass, inertia, thrust_to_weight, drag, rates, model):
    spec = VehicleConfig(
        model=model,
        mass_kg=mass,
        inertia_kgm2=inertia,
        max_thrust_N=mass * 9.81 * thrust_to_weight,
        drag_Ns2pm2=drag,
        max_rate_rps=rates,
    )
    p = build_vehicle(spec, 1).params
    got = (p.mass_kg, tuple(p.inertia_kgm2), p.max_thrust_N, p.g_mps2, tuple(p.max_rate_rps), p.drag_Ns2pm2)
    assert got == (mass, inertia, spec.max_thrust_N, spec.g_mps2, rates, drag)


def _in_range(name: str, u: float) -> float:
    p = px4_params.BY_NAME[name]
    if p.choices:
        return float(p.choices[int(u * len(p.choices)) % len(p.choices)])
    return p.low + (p.high - p.low) * u


@settings(max_examples=30, deadline=None)
@given(draws=st.dictionaries(st.sampled_from(sorted(AIRFRAME)), st.floats(0.05, 0.95), min_size=1))
def test_a_quadrotors_airframe_parameters_reach_its_rotors(draws):
    """``px4_quad_x``'s airframe parameters (``quad_x.AIRFRAME``: arm lengths, rotor torque, motor
    time constant and model), set in the config within their ranges, are the rotors' (the rest
    keep PX4 SIH's defaults)."""
    params = {name: _in_range(name, u) for name, u in draws.items()}
    quad = build_vehicle(VehicleConfig(model="px4_quad_x", params=params), 1)
    want = {**AIRFRAME, **params}
    got = {
        "Q_MAX_NM": quad.q_max_Nm,
        "L_ROLL_M": quad.l_roll_m,
        "L_PITCH_M": quad.l_pitch_m,
        "T_TAU_S": quad.tau_s,
        "MOTOR_MODEL": quad.motor_model,
    }
    assert set(got) == set(AIRFRAME)
    assert got == {k: (int(v) if k == "MOTOR_MODEL" else v) for k, v in want.items()}


@settings(max_examples=30, deadline=None)
@given(
    mean=st.tuples(*[st.floats(-5.0, 5.0)] * 3),
    gust=st.floats(0.01, 3.0),
    gust_time=st.floats(0.1, 5.0),
    seed=seeds,
    model=st.sampled_from(sorted(WIND_MODELS)),
    system_id=st.integers(1, 30),
)
def test_a_built_vehicles_air_is_its_configs(mean, gust, gust_time, seed, model, system_id):
    """The wind section's mean, gusts, correlation time, seed and model are the vehicle's air;
    independent gusts are each vehicle's own, frozen ones the same for every vehicle."""
    spec = VehicleConfig(wind=Gusts(mean, gust, gust_time, seed, model))
    wind = build_vehicle(spec, system_id).wind
    assert type(wind) is WIND_MODELS[model]
    assert (tuple(wind.mean_mps), wind.gust_mps, wind.gust_time_s, wind.seed) == (mean, gust, gust_time, seed)
    other = build_vehicle(spec, system_id + 1).wind
    same = [wind.at(t).tobytes() == other.at(t).tobytes() for t in (0.0, 1.0, 2.5)]
    assert all(same) if model == "frozen" else not any(same)


@settings(max_examples=30, deadline=None)
@given(
    noise=st.tuples(*[st.floats(0.0, 0.5)] * 4),
    walk=st.floats(0.001, 0.1),
    seed=seeds,
    system_id=st.integers(1, 30),
)
def test_a_built_vehicles_sensors_are_its_configs(noise, walk, seed, system_id):
    s = SensorNoise(*noise, seed=seed, position_bias_walk_m_per_sqrt_s=walk)
    model = sensor_model(VehicleConfig(sensors=s), system_id)
    assert model is not None
    got = (
        model.position_noise_m,
        model.velocity_noise_mps,
        model.attitude_noise_rad,
        model.latency_s,
        model.seed,
        model.position_bias_walk_m_per_sqrt_s,
        model.system_id,
    )
    assert got == (*noise, seed, walk, system_id)


USERS_MODELS = """
import dataclasses

import numpy as np
from pydantic import BaseModel, Field, field_validator

from sim_vehicles.models.build import paper_vtol


class Gains(BaseModel):
    lag_s: float = Field(gt=0, le=1)

    @field_validator("lag_s")
    @classmethod
    def _below_the_period(cls, v):
        if v == 0.75:
            raise ValueError("must not be three quarters")
        return v


def declared(spec, state0, dt_s):
    return paper_vtol(spec.__class__(**{**spec.__dict__, "params": {}}), state0, dt_s)


declared.Params = Gains


@dataclasses.dataclass
class Plain:
    lag_s: float = 0.1

    def __post_init__(self):
        if not 0 < self.lag_s <= 1:
            raise ValueError(f"lag_s must be within 0..1, got {self.lag_s}")


def plain(spec, state0, dt_s):
    return paper_vtol(spec.__class__(**{**spec.__dict__, "params": {}}), state0, dt_s)


plain.Params = Plain
NOT_CALLABLE = 3


class Tunable:
    def __init__(self, spec, state0, dt_s):
        self._inner = paper_vtol(spec.__class__(**{**spec.__dict__, "params": {}}), state0, dt_s)
        self.tunables = {"lag_s": 0.1}

    def __getattr__(self, name):
        return getattr(self._inner, name)


class BadState(Tunable):
    @property
    def state(self):
        return np.full(13, np.nan)
"""


@pytest.mark.parametrize(
    ("entry", "params", "named"),
    [
        ("declared", {"lag_s": 2.0}, "params: lag_s: Input should be less than or equal to 1 (model "),
        ("declared", {"lag_s": 0.75}, "params: lag_s: must not be three quarters (model "),
        (
            "declared",
            {"lag_s": 0.5, "gain": 1.0},
            "params: model 'MODELS:declared' has no parameter gain (it has lag_s)",
        ),
        ("Tunable", {"gain": 1.0}, "params: model 'MODELS:Tunable' has no parameter gain (it has lag_s)"),
        ("BadState", {}, "model 'MODELS:BadState': state must be 13 finite values, got shape (13,)"),
        (
            "plain",
            {"lag_s": 2.0},
            "params: ValueError: lag_s must be within 0..1, got 2.0 (model 'MODELS:plain')",
        ),
        ("NOT_CALLABLE", {}, "model 'MODELS:NOT_CALLABLE' is a int, not callable"),
    ],
)
def test_a_users_model_is_held_to_its_parameters_and_state_in_one_line(tmp_path, entry, params, named):
    """A model declaring ``Params`` is held to it, one serving ``tunables`` to those, and a model
    whose state is not 13 finite values is refused, each in one line naming the model."""
    (tmp_path / "models.py").write_text(USERS_MODELS)
    where = f"{tmp_path / 'models.py'}"
    spec = VehicleConfig(model=f"{where}:{entry}", params=params)
    with pytest.raises(VehicleConfigError) as e:
        build_vehicle(spec, 1)
    said = str(e.value)
    assert said.startswith("vehicle config: ") and named.replace("MODELS", where) in said and "\n" not in said
    fine = dataclasses.replace(spec, params={"lag_s": 0.5} if entry != "BadState" else {})
    if entry not in ("BadState", "NOT_CALLABLE"):
        assert math.isfinite(float(build_vehicle(fine, 1).state[0]))


def test_a_quadrotors_rate_limits_are_px4s_unless_the_config_gives_them():
    """PX4 v1.15's MC_ROLLRATE_MAX, MC_PITCHRATE_MAX, MC_YAWRATE_MAX (220, 220, 200 deg/s) for
    ``px4_quad_x``; the paper's vehicle keeps PX4's largest setting (1800 deg/s)."""
    quad = build_vehicle(VehicleConfig(model="px4_quad_x"), 1)
    assert tuple(quad.params.max_rate_rps) == tuple(math.radians(d) for d in (220.0, 220.0, 200.0))
    vtol = build_vehicle(VehicleConfig(), 1)
    assert tuple(vtol.params.max_rate_rps) == (math.radians(1800.0),) * 3


def test_a_wind_section_without_a_mean_is_still_air_with_gusts():
    """A wind written with gusts only (``mean_mps`` left out) reads as a zero mean."""
    data = json.loads(VehicleConfig().to_json())
    data["wind"] = {"gust_mps": 0.5, "gust_time_s": 1.0, "seed": 3, "model": "independent"}
    spec = VehicleConfig.from_json(json.dumps(data))
    assert spec.wind is not None and tuple(spec.wind.mean_mps) == (0.0, 0.0, 0.0)
    assert build_vehicle(spec, 1).wind.gust_mps == 0.5


@pytest.mark.parametrize(
    ("model", "params", "said"),
    [
        ("paper_vtol", {"a": 1.0, "b": 2.0}, "vehicle config: params: paper_vtol takes none, got a, b"),
        ("px4_quad_x", {"MOTOR_MODEL": 7.0}, "vehicle config: params: MOTOR_MODEL must be 0 or 1, got 7.0"),
        (
            "quad9",
            {},
            "vehicle config: model 'quad9' is not one of paper_vtol, px4_quad_x nor an entry "
            "('my_vehicle.py:MyVehicle')",
        ),
    ],
)
def test_a_built_in_model_refuses_what_it_does_not_take_in_one_line(model, params, said):
    with pytest.raises(VehicleConfigError) as e:
        build_vehicle(VehicleConfig(model=model, params=params), 1)
    assert str(e.value) == said


def test_a_quadrotors_refusals_name_the_parameter_and_what_it_takes():
    """A rate limit given as a param is pointed to ``max_rate_rps``; an unknown name is answered
    with the names the model takes (its airframe's and PX4's gains, not the rate limits); a value
    out of range with the range."""
    from sim_vehicles.plant.px4_control import GAINS

    def said(params):
        with pytest.raises(VehicleConfigError) as e:
            build_vehicle(VehicleConfig(model="px4_quad_x", params=params), 1)
        return str(e.value)

    for rate in px4_params.RATE_MAX:
        assert said({rate: 3.0}) == (
            f"vehicle config: params: {rate} is the vehicle's max_rate_rps (roll, pitch, yaw [rad/s]), "
            "not a param"
        )
    text = said({"MC_FOO": 1.0})
    head = "vehicle config: params: px4_quad_x has no parameter 'MC_FOO' (it has "
    assert text.startswith(head) and text.endswith(")")
    assert set(text[len(head) : -1].split(", ")) == set(AIRFRAME) | set(GAINS)
    p = px4_params.BY_NAME["MC_ROLL_P"]
    assert said({"MC_ROLL_P": p.high * 2}) == (
        f"vehicle config: params: MC_ROLL_P must be within {p.low:g}..{p.high:g}, got {p.high * 2!r}"
    )


@settings(max_examples=30, deadline=None)
@given(draws=st.dictionaries(st.sampled_from(sorted(px4_params.GAINS)), st.floats(0.05, 0.95), min_size=1))
def test_a_quadrotors_px4_gains_from_its_config_are_the_ones_in_force(draws):
    """PX4's attitude and rate gains set in the config (within their ranges) are the vehicle's
    parameters in force; the others keep PX4 v1.15's defaults."""
    params = {name: _in_range(name, u) for name, u in draws.items()}
    quad = build_vehicle(VehicleConfig(model="px4_quad_x", params=params), 1)
    assert quad.tunables == {**px4_params.GAINS, **params}


@settings(max_examples=30, deadline=None)
@given(
    position=st.tuples(*[st.floats(-50.0, 50.0)] * 3),
    velocity=st.tuples(*[st.floats(-5.0, 5.0)] * 3),
    axis=st.tuples(*[st.floats(-1.0, 1.0)] * 3).filter(lambda a: math.hypot(*a) > 0.1),
    angle=st.floats(-3.0, 3.0),
    model=st.sampled_from(["paper_vtol", "px4_quad_x"]),
)
def test_a_built_vehicle_starts_where_its_config_puts_it(position, velocity, axis, angle, model):
    """Position, velocity and attitude from the config; at rest in rotation."""
    n = math.hypot(*axis)
    q = (math.cos(angle / 2), *(math.sin(angle / 2) * a / n for a in axis))
    spec = VehicleConfig(model=model, position_m=position, velocity_mps=velocity, quaternion_wxyz=q)
    state = np.asarray(build_vehicle(spec, 1).state)
    assert tuple(state[0:3]) == position and tuple(state[3:6]) == velocity
    np.testing.assert_allclose(state[6:10], q, rtol=0, atol=4e-16)  # (renormalised: an ulp or two)
    assert tuple(state[10:13]) == (0.0, 0.0, 0.0)


def test_still_air_and_true_sensors_given_as_sections_are_no_model_at_all():
    """A wind section of no mean and no gusts, a sensors section of no noise, no latency and no
    bias: the vehicle builds no wind and no sensor model (nothing to draw per step)."""
    assert build_vehicle(VehicleConfig(wind=Gusts(seed=5)), 1).wind is None
    assert sensor_model(VehicleConfig(sensors=SensorNoise(seed=5)), 1) is None
    assert build_vehicle(VehicleConfig(wind=Gusts(gust_mps=0.1)), 1).wind is not None
    assert sensor_model(VehicleConfig(sensors=SensorNoise(latency_s=0.01)), 1) is not None
