"""The registry of vehicle models and the one function that builds a vehicle from its config.

``build_vehicle(spec, system_id)`` is what ``swarm-sitl sim`` flies, what ``python -m
sim_vehicles`` puts behind its MAVLink endpoint and what the fork server warms up: the same
object from the same spec, so a lockstep run of processes equals ``sim`` bit for bit.

A model is a function ``(spec, state0, dt_s) -> VehicleModel`` (``plant.contract``: what the
endpoint and ``sim`` ask of a vehicle). ``MODELS`` names every model a spec may ask for:

- ``paper_vtol`` (the default): the paper's rigid body, thrust and torque applied the instant they
  are asked for, its torque law as autopilot (``plant.autopilot``); ``spec.params`` must be empty;
- ``px4_quad_x``: four rotors in X with motor lag, PX4's mixer and attitude and rate loops
  (``plant.quad_x``); ``spec.params`` takes the airframe's ``quad_x.AIRFRAME`` keys and PX4's
  gains (``px4_control.GAINS``), each in its range (``plant.px4_params``, their one declaration).

A user's own model is an entry, ``"my_vehicle.py:MyVehicle"`` or ``"package.module:MyVehicle"``
(``common.entry``; a config's relative file path is relative to the config): a class (or any
callable) taking ``(spec, state0, dt_s)``, held to ``CONTRACT`` when it is built; its own
parameters come in ``spec.params``, and each must be one it declares: in its ``Params`` (a
pydantic model or a dataclass, checked with their ranges before it is built) if it has one, else
in the ``tunables`` it serves. A name it does not declare is refused here, whatever the model's
own code does with it. ``models/template.py`` is one, runnable, with the contract
in its docstring.
"""

from collections.abc import Callable
from typing import Any

import numpy as np

from sim_vehicles.common.contract import missing_members, protocol_members
from sim_vehicles.common.entry import EntryError, declared_params, load_entry, one_line, undeclared_line
from sim_vehicles.common.state import STATE_SIZE, make_state
from sim_vehicles.models.vehicle_config import VehicleConfig, VehicleConfigError
from sim_vehicles.plant import px4_params
from sim_vehicles.plant.autopilot import Autopilot
from sim_vehicles.plant.contract import VehicleModel
from sim_vehicles.plant.params import AttitudeGains, VehicleParams
from sim_vehicles.plant.px4_control import GAINS
from sim_vehicles.plant.quad_x import AIRFRAME, QuadX
from sim_vehicles.plant.sensors import SensorModel
from sim_vehicles.plant.wind import WIND_MODELS, WindModel


def vehicle_params(spec: VehicleConfig) -> VehicleParams:
    """What the airframe is, as the plant and the endpoint's parameters take it."""
    assert spec.max_rate_rps is not None  # (the config holds the model's default once it is made)
    return VehicleParams(
        spec.mass_kg, spec.inertia_kgm2, spec.max_thrust_N, spec.g_mps2, spec.max_rate_rps, spec.drag_Ns2pm2
    )


def paper_vtol(spec: VehicleConfig, state0: np.ndarray, dt_s: float) -> VehicleModel:
    """The paper's vehicle: its rigid body (eqs. 2-5) under the paper's torque law, thrust and
    torque applied the instant they are asked for (``plant.autopilot``)."""
    if spec.params:
        raise VehicleConfigError(
            f"vehicle config: params: paper_vtol takes none, got {', '.join(sorted(spec.params))}"
        )
    return Autopilot(vehicle_params(spec), AttitudeGains(spec.l_q, spec.k_q), state0, dt_s)


def px4_quad_x(spec: VehicleConfig, state0: np.ndarray, dt_s: float) -> VehicleModel:
    """A rotor-level quadrotor in X under PX4's attitude and rate control (``plant.quad_x``),
    its airframe and gains from ``spec.params`` (PX4 SIH's quadrotor and PX4 v1.15's defaults,
    ``plant.px4_params``)."""
    for name, value in spec.params.items():
        p = px4_params.BY_NAME.get(name)
        if name in px4_params.RATE_MAX:
            raise VehicleConfigError(
                f"vehicle config: params: {name} is the vehicle's max_rate_rps (roll, pitch, yaw "
                "[rad/s]), not a param"
            )
        if p is None:
            raise VehicleConfigError(
                f"vehicle config: params: px4_quad_x has no parameter {name!r} "
                f"(it has {', '.join(n for n in px4_params.BY_NAME if n not in px4_params.RATE_MAX)})"
            )
        if not p.accepts(value):
            allowed = (
                " or ".join(f"{c:g}" for c in p.choices) if p.choices else f"within {p.low:g}..{p.high:g}"
            )
            raise VehicleConfigError(f"vehicle config: params: {name} must be {allowed}, got {value!r}")
    airframe = {k: float(v) for k, v in spec.params.items() if k in AIRFRAME}
    px4 = {k: float(v) for k, v in spec.params.items() if k in GAINS}
    return QuadX(vehicle_params(spec), state0, dt_s, airframe, px4)


MODELS: dict[str, Callable[[VehicleConfig, np.ndarray, float], VehicleModel]] = {
    "paper_vtol": paper_vtol,
    "px4_quad_x": px4_quad_x,
}


#: what a model built from a user's entry must have: what ``plant.contract.VehicleModel`` declares
CONTRACT = protocol_members(VehicleModel)


def _user_model(spec: VehicleConfig, state0: np.ndarray, dt_s: float) -> VehicleModel:
    """A model of the user's (``model: "my_vehicle.py:MyQuad"``), built and held to the contract."""
    try:
        factory = load_entry(spec.model, "sim_vehicles_model")
    except EntryError as e:
        raise VehicleConfigError(f"vehicle config: model: {e}") from None
    if not callable(factory):
        raise VehicleConfigError(
            f"vehicle config: model {spec.model!r} is a {type(factory).__name__}, not callable"
        )
    schema = getattr(factory, "Params", None)
    if schema is not None:  # declared: held to it before the model sees them
        _check_params(spec, schema)
    try:
        vehicle = factory(spec, state0, dt_s)
    except VehicleConfigError:
        raise
    except Exception as e:
        raise VehicleConfigError(
            f"vehicle config: model {spec.model!r}: building it raised {one_line(e)}"
        ) from None
    missing = missing_members(vehicle, VehicleModel)
    if missing:
        raise VehicleConfigError(
            f"vehicle config: model {spec.model!r} does not meet the vehicle contract: "
            f"no {', '.join(missing)}"
        )
    if schema is None:  # its parameters are the ones it serves (``tunables``)
        unknown = undeclared_line(spec.params, frozenset(vehicle.tunables), f"model {spec.model!r}")
        if unknown is not None:
            raise VehicleConfigError(f"vehicle config: params: {unknown}")
    state = np.asarray(vehicle.state)
    if state.shape != (STATE_SIZE,) or not np.all(np.isfinite(state)):
        raise VehicleConfigError(
            f"vehicle config: model {spec.model!r}: state must be {STATE_SIZE} finite values, "
            f"got shape {state.shape}"
        )
    return vehicle


def _check_params(spec: VehicleConfig, schema: Any) -> None:
    """``spec.params`` held to a model's ``Params``: every name declared, every value in its range."""
    unknown = undeclared_line(spec.params, declared_params(schema), f"model {spec.model!r}")
    if unknown is not None:
        raise VehicleConfigError(f"vehicle config: params: {unknown}")
    validate = getattr(schema, "model_validate", None)  # a pydantic model's; else a class of keywords
    try:
        validate(dict(spec.params)) if validate is not None else schema(**spec.params)
    except (TypeError, ValueError) as e:
        errors = getattr(e, "errors", None)  # a pydantic ValidationError: its first error, one line
        if callable(errors):
            err = errors()[0]
            where = ".".join(str(p) for p in err["loc"])
            msg = str(err["msg"]).removeprefix("Value error, ")
            raise VehicleConfigError(
                f"vehicle config: params: {where}: {msg} (model {spec.model!r})"
            ) from None
        raise VehicleConfigError(f"vehicle config: params: {one_line(e)} (model {spec.model!r})") from None


def check(spec: VehicleConfig) -> None:
    """``VehicleConfigError`` (one line) if ``spec``'s model does not exist or does not take its
    parameters: what a config's load asks before anything starts."""
    build_vehicle(spec, 1)


def build_vehicle(spec: VehicleConfig, system_id: int) -> VehicleModel:
    """Vehicle ``system_id`` as ``spec`` says, at its initial state, in its air."""
    model = _user_model if ":" in spec.model else MODELS.get(spec.model)
    if model is None:
        raise VehicleConfigError(
            f"vehicle config: model {spec.model!r} is not one of {', '.join(sorted(MODELS))} "
            "nor an entry ('my_vehicle.py:MyVehicle')"
        )
    x0 = make_state(spec.position_m, spec.velocity_mps, np.asarray(spec.quaternion_wxyz, dtype=float))
    ap = model(spec, x0, 1.0 / spec.attitude_hz)
    w = spec.wind
    if w is not None and (any(w.mean_mps) or w.gust_mps > 0):
        air = WIND_MODELS[w.model]  # the world's field is the same for every id: seeded by 0
        ap.wind = air(
            system_id=system_id if air is WindModel else 0,
            mean_mps=w.mean_mps,
            gust_mps=w.gust_mps,
            gust_time_s=w.gust_time_s,
            seed=w.seed,
        )
    return ap


def sensor_model(spec: VehicleConfig, system_id: int) -> SensorModel | None:
    """What vehicle ``system_id`` reports of its state (None: the true state)."""
    s = spec.sensors
    if s is None:
        return None
    values = (s.position_noise_m, s.velocity_noise_mps, s.attitude_noise_rad, s.latency_s)
    if not any(v > 0 for v in (*values, s.position_bias_walk_m_per_sqrt_s)):
        return None
    return SensorModel(
        system_id, *values, seed=s.seed, position_bias_walk_m_per_sqrt_s=s.position_bias_walk_m_per_sqrt_s
    )
