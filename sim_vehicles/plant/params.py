"""Physical and attitude-loop parameters of one simulated vehicle."""

import math
from dataclasses import dataclass

import numpy as np

#: PX4's largest MC_ROLLRATE_MAX / MC_PITCHRATE_MAX / MC_YAWRATE_MAX (1800 deg/s) [rad/s]: the
#: default body-rate limit, above the paper scenario's largest command (22.8 rad/s, in pitch)
MAX_RATE_DEFAULT_RPS = math.radians(1800.0)


class VehicleParamError(ValueError):
    """A vehicle parameter is outside its physical range."""


@dataclass(frozen=True)
class VehicleParams:
    """What the vehicle is: mass, inertia, actuator limit, gravity."""

    mass_kg: float
    inertia_kgm2: tuple[float, float, float]  #: principal inertia [kg m^2; body FLU axes]
    max_thrust_N: float  #: largest collective thrust [N]; MAVLink thrust 1.0 maps to this
    g_mps2: float = 9.81
    #: commanded body rates are clipped to +- these (PX4's MC_*RATE_MAX) [rad/s; roll, pitch, yaw]
    max_rate_rps: tuple[float, float, float] = (MAX_RATE_DEFAULT_RPS,) * 3
    #: quadratic drag, rho C_d A / 2: force -drag |v - w| (v - w) in a wind w [N s^2/m^2] (``wind``)
    drag_Ns2pm2: float = 0.0

    def __post_init__(self) -> None:
        if not self.mass_kg > 0:
            raise VehicleParamError(f"mass_kg must be > 0, got {self.mass_kg}")
        if len(self.inertia_kgm2) != 3 or not all(j > 0 for j in self.inertia_kgm2):
            raise VehicleParamError(f"inertia_kgm2 must be three values > 0, got {self.inertia_kgm2}")
        if not self.max_thrust_N > self.mass_kg * self.g_mps2:
            raise VehicleParamError(
                f"max_thrust_N ({self.max_thrust_N}) must exceed the weight m g "
                f"({self.mass_kg * self.g_mps2:.3f} N) or the vehicle cannot hover"
            )

        if len(self.max_rate_rps) != 3 or not all(0 < w < math.inf for w in self.max_rate_rps):
            raise VehicleParamError(f"max_rate_rps must be three finite values > 0, got {self.max_rate_rps}")
        if not 0 <= self.drag_Ns2pm2 < math.inf:
            raise VehicleParamError(f"drag_Ns2pm2 must be >= 0 and finite, got {self.drag_Ns2pm2}")

    @property
    def inertia(self) -> np.ndarray:
        return np.asarray(self.inertia_kgm2, dtype=float)

    @property
    def hover_thrust_N(self) -> float:
        return self.mass_kg * self.g_mps2


@dataclass(frozen=True)
class AttitudeGains:
    """Gains of the paper's torque law: sliding surface ``r = l_q q_e + omega_e``, ``J rdot = -k_q r``."""

    l_q: float
    k_q: float

    def __post_init__(self) -> None:
        if not (self.l_q > 0 and self.k_q > 0):
            raise VehicleParamError(f"l_q and k_q must be > 0, got {self.l_q}, {self.k_q}")
