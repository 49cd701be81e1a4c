"""``VehicleConfig``: everything one simulated vehicle is, in one frozen object.

A run describes each vehicle in its config; ``swarm_sitl`` turns that into a ``VehicleConfig`` per
follower, writes it to ``RUN_DIR/procs/vehicle_<i>.config.json`` and starts ``python -m
sim_vehicles --spec FILE``; ``sim`` builds the same vehicle from the same spec in its own process
(``build.build_vehicle``). A new parameter of a model is one field here and its use in the model:
no argv flag, no parser, no second builder.

Units and frames as everywhere: SI, ENU world, FLU body, Hamilton ``[w, x, y, z]`` body to world.
``VehicleConfig.from_json`` refuses what is not one, in one line naming the field
(``VehicleConfigError``).
"""

import json
import math
from dataclasses import asdict, dataclass, field, fields
from typing import Any

from sim_vehicles.plant import px4_params
from sim_vehicles.plant.failsafe import ACTIONS
from sim_vehicles.plant.params import MAX_RATE_DEFAULT_RPS, VehicleParamError

#: the model of a spec that names none: the paper's rigid body with its torque law as autopilot
DEFAULT_MODEL = "paper_vtol"
#: the autopilots a vehicle speaks as (``vehicle.autopilots.PROFILES``' names)
AUTOPILOTS = ("px4", "ardupilot")


class VehicleConfigError(ValueError):
    """A vehicle config that is not one; the message names the field."""


@dataclass(frozen=True)
class Gusts:
    """The air (``plant.wind``): a mean wind plus first-order Gauss-Markov gusts per axis."""

    mean_mps: tuple[float, float, float] = (0.0, 0.0, 0.0)  #: [m/s; ENU]
    gust_mps: float = 0.0  #: standard deviation of each axis's gust [m/s]
    gust_time_s: float = 1.0  #: the gusts' correlation time [s]
    seed: int = 0  #: of the gusts
    #: ``independent``: each vehicle's own gusts (``plant.wind.WindModel``); ``frozen``: the world's,
    #: one field carried by the mean wind (``plant.wind.FrozenGusts``)
    model: str = "independent"


@dataclass(frozen=True)
class SensorNoise:
    """What the vehicle reports of its state (``plant.sensors``): latency and Gaussian noise."""

    position_noise_m: float = 0.0  #: per axis [m]
    velocity_noise_mps: float = 0.0  #: per axis [m/s]
    attitude_noise_rad: float = 0.0  #: error rotation, per axis [rad]
    latency_s: float = 0.0  #: the report is the state this long ago [s]
    seed: int = 0  #: of the noise
    position_bias_walk_m_per_sqrt_s: float = 0.0  #: the position's bias, a random walk [m/sqrt(s)]


#: ``VehicleConfig.from_dict``: what a JSON value of each field must be, where the field's default
#: does not say it (a section, or a field that may be left out as null), and how a refusal says it
_JSON_SECTIONS = {
    "wind": "a mapping of the wind's fields",
    "sensors": "a mapping of the sensors' fields",
    "params": "a mapping of parameter names to numbers",
    "max_rate_rps": "a list of 3 numbers",
}


def _finite_number(v: Any) -> bool:
    """A float or int (not a bool), finite."""
    return isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)


def _shown(name: Any) -> str:
    """A name from a file as a refusal shows it: as written if it reads as a name, else quoted
    (a line break or a blank in a key stays in one line, and visible)."""
    return name if isinstance(name, str) and name.isidentifier() else repr(name)


def _seed(v: Any) -> bool:
    """A seed as the swarm config takes one: a whole number in ``0 .. 2**63 - 1``."""
    return isinstance(v, int) and not isinstance(v, bool) and 0 <= v < 2**63


def _json_kind(f: Any) -> tuple[tuple[type, ...], str, bool]:
    """``(types, what it must be, whether null is allowed)`` of field ``f``'s JSON value, read
    from its default (a bool is not a number here: ``true`` for a mass is a mistake)."""
    if f.name in _JSON_SECTIONS:
        kind = (list, tuple) if f.name == "max_rate_rps" else (dict,)
        return kind, _JSON_SECTIONS[f.name], f.name != "params"
    if isinstance(f.default, str):
        return (str,), "a string", False
    if isinstance(f.default, tuple):
        return (list, tuple), f"a list of {len(f.default)} numbers", False
    return (int, float), "a number", False


def _refuse_other_kinds(cls: Any, data: dict, where: str) -> None:
    """``VehicleConfigError`` naming the first field of dataclass ``cls`` whose value in ``data``
    (JSON's) is of another kind than the field (``_json_kind``); ``where``: the section's prefix."""
    for f in fields(cls):
        if f.name not in data:
            continue
        value = data[f.name]
        types, what, nullable = _json_kind(f)
        if not (value is None and nullable) and (isinstance(value, bool) or not isinstance(value, types)):
            raise VehicleConfigError(f"vehicle config: {where}{f.name}: must be {what}, got {value!r}")


def default_max_rate_rps(model: str) -> tuple[float, float, float]:
    """The body-rate limits of a spec that gives none [rad/s]: ``px4_quad_x``'s are PX4 v1.15's
    MC_*RATE_MAX (220, 220, 200 deg/s, ``plant.px4_params``); every other model's PX4's largest
    setting, 1800 deg/s (the paper's vehicle: above its scenario's largest command)."""
    if model == "px4_quad_x":
        r, p, y = px4_params.DEFAULT_MAX_RATE_RPS
        return (r, p, y)
    return (MAX_RATE_DEFAULT_RPS,) * 3


@dataclass(frozen=True)
class VehicleConfig:
    """One vehicle: its model and every parameter the model, its autopilot and its endpoint's
    flight modes take. The defaults are the paper's section 4 airframe."""

    model: str = DEFAULT_MODEL  #: a registered model's name (``build.MODELS``)
    mass_kg: float = 0.85
    inertia_kgm2: tuple[float, float, float] = (4.856e-2, 4.856e-2, 8.801e-2)  #: principal [kg m^2; FLU]
    max_thrust_N: float = 25.0  #: largest collective thrust; MAVLink thrust 1.0 maps to it [N]
    g_mps2: float = 9.81
    #: commanded body rates are clipped to +- these (PX4's MC_*RATE_MAX) [rad/s; roll, pitch, yaw];
    #: None: the model's default (``default_max_rate_rps``), which the config holds once it is made
    max_rate_rps: tuple[float, float, float] | None = None
    drag_Ns2pm2: float = 0.0  #: quadratic drag rho C_d A / 2 [N s^2/m^2] (``plant.wind``)
    l_q: float = 16.0  #: the paper's torque law: attitude-error gain
    k_q: float = 16.0  #: the paper's torque law: body-rate-error gain
    attitude_hz: float = 1000.0  #: the attitude loop's and the plant's step rate [Hz]
    setpoint_timeout_s: float = 0.5  #: failsafe after this long without a valid setpoint [s]
    failsafe_action: str = "hold"  #: PX4's COM_OBL_RC_ACT: ``hold`` position or ``land``
    position_m: tuple[float, float, float] = (0.0, 0.0, 0.0)  #: initial [m; ENU]
    velocity_mps: tuple[float, float, float] = (0.0, 0.0, 0.0)  #: initial [m/s; ENU]
    quaternion_wxyz: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)  #: initial, body to world
    wind: Gusts | None = None  #: None: still air
    sensors: SensorNoise | None = None  #: None: the true state is reported
    params: dict[str, float] = field(default_factory=dict)  #: a model's own parameters, by name
    #: the autopilot it speaks as over MAVLink (``vehicle.autopilots``): ``px4`` or ``ardupilot``
    autopilot: str = "px4"

    def __post_init__(self) -> None:
        def bad(name: str, why: str) -> VehicleConfigError:
            return VehicleConfigError(f"vehicle config: {name}: {why}")

        if self.max_rate_rps is None:
            object.__setattr__(self, "max_rate_rps", default_max_rate_rps(self.model))
        elif isinstance(self.max_rate_rps, list):  # (JSON's list: the tuple the field is)
            object.__setattr__(self, "max_rate_rps", tuple(self.max_rate_rps))

        for name in ("mass_kg", "max_thrust_N", "g_mps2", "attitude_hz", "setpoint_timeout_s", "l_q", "k_q"):
            v = getattr(self, name)
            if not (_finite_number(v) and v > 0):
                raise bad(name, f"must be a finite number > 0, got {v!r}")
        for name, n in (("inertia_kgm2", 3), ("max_rate_rps", 3)):
            v = getattr(self, name)
            if len(v) != n or not all(_finite_number(x) and x > 0 for x in v):
                raise bad(name, f"must be {n} finite numbers > 0, got {v!r}")
        for name, n in (("position_m", 3), ("velocity_mps", 3), ("quaternion_wxyz", 4)):
            v = getattr(self, name)
            if len(v) != n or not all(map(_finite_number, v)):
                raise bad(name, f"must be {n} finite numbers, got {v!r}")
        for name, v in self.params.items():  # (a bool is not a number here: {X: true} is a mistake)
            if not _finite_number(v):
                raise bad(f"params: {_shown(name)}", f"must be a finite number, got {v!r}")
        if abs(math.sqrt(sum(x * x for x in self.quaternion_wxyz)) - 1.0) > 1e-6:
            raise bad("quaternion_wxyz", f"must be a unit quaternion, got {self.quaternion_wxyz!r}")
        if self.autopilot not in AUTOPILOTS:
            raise bad("autopilot", f"must be one of {', '.join(AUTOPILOTS)}, got {self.autopilot!r}")
        if self.failsafe_action not in ACTIONS:
            raise bad(
                "failsafe_action",
                f"must be one of {', '.join(sorted(ACTIONS))}, got {self.failsafe_action!r}",
            )
        if not 0 <= self.drag_Ns2pm2 < math.inf:
            raise bad("drag_Ns2pm2", f"must be >= 0 and finite, got {self.drag_Ns2pm2!r}")
        if not self.max_thrust_N > self.mass_kg * self.g_mps2:
            raise bad(
                "max_thrust_N",
                f"{self.max_thrust_N} must exceed the weight m g ({self.mass_kg * self.g_mps2:.3f} N) "
                "or the vehicle cannot hover",
            )
        if self.wind is not None:
            w = self.wind
            mean = w.mean_mps
            if not isinstance(mean, tuple | list) or len(mean) != 3 or not all(map(_finite_number, mean)):
                raise bad("wind", f"mean_mps must be 3 finite numbers, got {w.mean_mps!r}")
            gusts = (w.gust_mps, w.gust_time_s)
            if not (all(_finite_number(v) for v in gusts) and w.gust_mps >= 0 and w.gust_time_s > 0):
                raise bad(
                    "wind",
                    f"gust_mps must be zero or positive and gust_time_s positive, both finite, got {gusts!r}",
                )
            if w.model not in ("independent", "frozen"):
                raise bad("wind", f"model must be independent or frozen, got {w.model!r}")
            if not _seed(w.seed):
                raise bad("wind", f"seed must be a whole number in 0..2**63 - 1, got {w.seed!r}")
        if self.sensors is not None:
            s = self.sensors
            values = (
                s.position_noise_m,
                s.velocity_noise_mps,
                s.attitude_noise_rad,
                s.latency_s,
                s.position_bias_walk_m_per_sqrt_s,
            )
            if not all(_finite_number(v) and v >= 0 for v in values):
                raise bad("sensors", f"noise and latency are zero or positive, and finite, got {values!r}")
            if not _seed(s.seed):
                raise bad("sensors", f"seed must be a whole number in 0..2**63 - 1, got {s.seed!r}")

    # -- crossing a process boundary -------------------------------------------------------------
    def to_json(self) -> str:
        """The spec as one JSON document (``from_json`` reads it back to an equal spec: floats are
        written as ``repr`` writes them, so they come back bit for bit)."""
        return json.dumps(asdict(self), indent=1, sort_keys=True) + "\n"

    @classmethod
    def from_json(cls, text: str) -> "VehicleConfig":
        """The spec ``to_json`` wrote; ``VehicleConfigError`` naming what is wrong otherwise."""
        try:
            data = json.loads(text)
        except ValueError as e:
            raise VehicleConfigError(f"vehicle config: not JSON ({e})") from None
        return cls.from_dict(data)

    @classmethod
    def from_dict(cls, data: Any) -> "VehicleConfig":
        if not isinstance(data, dict):
            raise VehicleConfigError("vehicle config: must be a mapping of field names to values")
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise VehicleConfigError(f"vehicle config: unknown field(s) {', '.join(map(_shown, unknown))}")
        d = dict(data)
        _refuse_other_kinds(cls, d, "")  # what JSON can hold that no field is: one line, not a traceback
        for name, section in (("wind", Gusts), ("sensors", SensorNoise)):
            unknown = sorted(set(d.get(name) or {}) - {f.name for f in fields(section)})
            if unknown:
                shown = ", ".join(map(_shown, unknown))
                raise VehicleConfigError(f"vehicle config: {name}: unknown field(s) {shown}")
            _refuse_other_kinds(section, d.get(name) or {}, f"{name}.")
        try:
            for f in fields(cls):  # JSON's lists back to the tuples the fields are
                if isinstance(f.default, tuple) and isinstance(d.get(f.name), list):
                    d[f.name] = tuple(d[f.name])
            if d.get("wind") is not None:
                w = dict(d["wind"])
                w["mean_mps"] = tuple(w.get("mean_mps", (0.0, 0.0, 0.0)))
                d["wind"] = Gusts(**w)
            if d.get("sensors") is not None:
                d["sensors"] = SensorNoise(**d["sensors"])
            return cls(**d)
        except VehicleConfigError:
            raise
        except (TypeError, ValueError, VehicleParamError) as e:
            raise VehicleConfigError(f"vehicle config: {e}") from None
