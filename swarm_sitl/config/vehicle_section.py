"""The ``vehicle:`` and ``wind:`` sections of a config: every follower's airframe, autopilot and
model, what it reports of its state, and the air it flies in (``schema.SwarmConfig`` holds them;
``SwarmConfig.vehicle_config`` turns them into each vehicle's config, ``sim_vehicles.models.vehicle_config``).
"""

import dataclasses
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, StrictFloat, StrictInt, model_validator

from sim_vehicles.models import vehicle_config

Vec3 = tuple[float, float, float]
Positive = Annotated[float, Field(gt=0, allow_inf_nan=False)]  #: (every vehicle number is finite)


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class SensorSection(_Strict):
    """What each vehicle reports of its state (LOCAL_POSITION_NED, ATTITUDE_QUATERNION) as an
    autopilot's estimator gives it (``sim_vehicles.plant.sensors``); the truth files keep the
    true state. Off by default; ``sim`` reports the same, so a lockstep run still equals it."""

    position_noise_m: Annotated[float, Field(ge=0)] = 0.0  #: Gaussian, per axis [m]
    velocity_noise_mps: Annotated[float, Field(ge=0)] = 0.0  #: Gaussian, per axis [m/s]
    attitude_noise_rad: Annotated[float, Field(ge=0)] = 0.0  #: Gaussian error rotation, per axis [rad]
    latency_s: Annotated[float, Field(ge=0)] = 0.0  #: the report is the state this long ago [s]
    seed: Annotated[int, Field(ge=0, lt=2**63)] = 0  #: of the noise: the same seed, the same noise
    #: the position's bias, a random walk from zero at boot: its spread after t seconds is this
    #: times sqrt(t) on each axis, as a GNSS-aided estimate drifts [m/sqrt(s)]
    position_bias_walk_m_per_sqrt_s: Annotated[float, Field(ge=0)] = 0.0

    @property
    def enabled(self) -> bool:
        noise = (self.position_noise_m, self.velocity_noise_mps, self.attitude_noise_rad, self.latency_s)
        return any(v > 0 for v in (*noise, self.position_bias_walk_m_per_sqrt_s))


class WindSection(_Strict):
    """The air every vehicle flies in (``sim_vehicles.plant.wind``): a mean wind plus gusts, a
    first-order Gauss-Markov process per axis sampled every 10 ms, seeded per vehicle; it acts
    through ``vehicle.drag_Ns2pm2``. Still by default; ``sim`` flies the same air."""

    mean_mps: Vec3 = (0.0, 0.0, 0.0)  #: mean wind [m/s; ENU]
    gust_mps: Annotated[float, Field(ge=0)] = 0.0  #: standard deviation of each axis's gust [m/s]
    gust_time_s: Annotated[float, Field(gt=0)] = 1.0  #: the gusts' correlation time [s]
    seed: Annotated[int, Field(ge=0, lt=2**63)] = 0  #: of the gusts
    #: whose gusts: ``independent``, each vehicle's own (seeded with its id: neighbours feel
    #: unrelated gusts); ``frozen``, the world's, one gust field carried by the mean wind (Taylor's
    #: frozen turbulence: vehicles level across the wind feel the same gust at once, one ``d``
    #: metres downstream ``d / |mean|`` seconds later; in still mean air, all at once)
    model: Literal["independent", "frozen"] = "independent"

    @property
    def enabled(self) -> bool:
        return any(self.mean_mps) or self.gust_mps > 0


#: the sections that become a nested spec of the vehicle's config, each the spec it becomes
NESTED_SPECS: dict[type, type] = {
    WindSection: vehicle_config.Gusts,
    SensorSection: vehicle_config.SensorNoise,
}


#: the fields of a vehicle's config the swarm config sets from its other sections, not ``vehicle:``'s:
#: each the dotted path it is read from (``FOLLOWER.`` the follower's own section)
SET_ELSEWHERE: dict[str, str] = {
    "g_mps2": "gravity_mps2",
    "attitude_hz": "rates.attitude_hz",
    "position_m": "FOLLOWER.initial_position_m",
    "velocity_mps": "FOLLOWER.initial_velocity_mps",
    "quaternion_wxyz": "FOLLOWER.initial_quaternion_wxyz",
    "wind": "wind",
}


def spec_value(value: Any) -> Any:
    """A section's value as the vehicle config's field holds it: a section for a nested spec
    (``Gusts``, ``SensorNoise``) field by field by name, or None where it is not ``enabled``; a
    list as a tuple; the rest as it is."""
    nested = NESTED_SPECS.get(type(value))
    if nested is not None:
        if not value.enabled:
            return None
        names = [f.name for f in dataclasses.fields(nested)]
        return nested(**{n: spec_value(getattr(value, n)) for n in names})
    return tuple(value) if isinstance(value, list) else value


class VehicleSection(_Strict):
    """Every follower's vehicle. Besides the keys below, ``vehicle:`` takes any other field of the
    vehicle's config (``sim_vehicles/models/vehicle_config.py``) as it is and hands it to the vehicle: a field
    added there is a config key with no change here (a key that is neither is an unknown key)."""

    model_config = ConfigDict(extra="allow", frozen=True)

    mass_kg: Positive  #: every follower's mass m [kg]
    inertia_kgm2: tuple[
        Positive, Positive, Positive
    ]  #: principal moments of inertia J (body x, y, z) [kg m^2]
    #: the thrust a throttle of 1 gives; above the law's bound (``swarm-sitl check``) [N]
    max_thrust_N: Positive
    setpoint_timeout_s: Positive = 0.5  #: failsafe after this long without a valid setpoint
    #: what the vehicle flies in failsafe (PX4's COM_OBL_RC_ACT): a position hold at the point of
    #: loss, or a landing (descending at 0.7 m/s holding its horizontal position)
    failsafe_action: Literal["hold", "land"] = "hold"
    #: commanded body rates are clipped to +- these (PX4's MC_ROLLRATE_MAX, MC_PITCHRATE_MAX,
    #: MC_YAWRATE_MAX) [rad/s]; none given: the model's, PX4 v1.15's defaults (220, 220, 200
    #: deg/s) on ``px4_quad_x``, PX4's largest setting (1800 deg/s) on the paper's vehicle
    max_rate_rps: tuple[Positive, Positive, Positive] | None = None
    sensors: SensorSection = SensorSection()  #: latency and noise of the state it reports
    #: quadratic drag rho C_d A / 2: the air pushes with -drag |v - w| (v - w) [N s^2/m^2] (``wind``)
    drag_Ns2pm2: Annotated[float, Field(ge=0)] = 0.0
    #: the vehicle model (``sim_vehicles.models.build``): ``paper_vtol``, the paper's rigid body
    #: given thrust and torque the instant they are asked for, its torque law as autopilot; or
    #: ``px4_quad_x``, four rotors in X with motor lag, PX4's mixer and attitude and rate loops
    #: (``docs/vehicles.md``)
    model: str = "paper_vtol"
    #: the autopilot every simulated vehicle speaks as over MAVLink: ``px4`` (PX4's modes,
    #: OFFBOARD, its parameters) or ``ardupilot`` (ArduCopter's GUIDED_NOGPS, arming and
    #: parameters); a follower's own ``autopilot`` takes its place (``docs/autopilots.md``)
    autopilot: Literal["px4", "ardupilot"] = "px4"
    #: the model's own parameters by name, each in its range (``px4_quad_x``: Q_MAX_NM, L_ROLL_M,
    #: L_PITCH_M, T_TAU_S and PX4's MC_* gains; PX4 SIH's quadrotor and PX4's defaults otherwise)
    params: dict[str, StrictFloat | StrictInt] = {}
    #: ``paper_vtol``'s attitude loop, the paper's torque law: attitude-error gain (under ``gains``
    #: before; an old config is read with a notice)
    l_q: Positive = 16.0
    k_q: Positive = 16.0  #: ``paper_vtol``'s torque law: body-rate-error gain

    @model_validator(mode="after")
    def _spec_fields_only(self) -> "VehicleSection":
        spec_fields = {f.name for f in dataclasses.fields(vehicle_config.VehicleConfig)}
        unknown = sorted(set(self.model_extra or {}) - (spec_fields - set(SET_ELSEWHERE)))
        if unknown:
            raise ValueError(f"{unknown[0]}: unknown key")
        return self
