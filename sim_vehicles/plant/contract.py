"""The vehicle contract: what a vehicle model is to the MAVLink endpoint, to ``sim`` and to the
fork server's warm-up (``sim_vehicles.models.build`` makes one from a spec).

A model holds a command and advances its plant in fixed steps, time ``step_index * dt_s``:

- ``params`` (``plant.params.VehicleParams``): mass, inertia, largest collective thrust (MAVLink's
  thrust 1.0 maps to it), gravity, drag; its hover thrust ``m g / T_max`` served as the
  autopilot's MPC_THR_HOVER or MOT_THST_HOVER (``vehicle.autopilots``);
- ``state``: the rigid body's 13 values (``common.state``: ENU position and velocity, FLU -> ENU
  Hamilton attitude, FLU body rates), what telemetry, the truth log and the failsafe read; a model
  with more state (motor speeds, integrators) keeps it beside these;
- ``command`` and ``set_command(command)``: the ``AttitudeCommand`` held from now (attitude, body
  rates, their derivative, collective thrust [N]);
- ``advance(n_steps)``: ``n_steps`` steps under the held command, in ``wind`` (a
  ``plant.wind.WindModel`` or None: still air; ``wind_W`` is the wind in force [m/s; ENU]);
- ``max_rate_rps``: the body-rate limit in force [rad/s; roll, pitch, yaw], changed in place by a
  PARAM_SET of MC_ROLLRATE_MAX, MC_PITCHRATE_MAX, MC_YAWRATE_MAX;
- ``tunables``: the model's own parameters by name (PX4's, for a PX4-like model), served over
  MAVLink, and ``set_param(name, value)``: set one if the value is in its range (whether it was).

Pure: no sockets, clocks or files. The same model from the same spec flies the same bits in a
process and in ``sim``.
"""

from typing import Protocol

import numpy as np

from sim_vehicles.common.command import AttitudeCommand
from sim_vehicles.plant.params import VehicleParams
from sim_vehicles.plant.wind import WindModel


class VehicleModel(Protocol):
    params: VehicleParams
    dt_s: float
    step_index: int
    state: np.ndarray
    command: AttitudeCommand
    max_rate_rps: np.ndarray
    wind: WindModel | None
    wind_W: np.ndarray
    tunables: dict[str, float]

    @property
    def time_s(self) -> float: ...

    def set_command(self, command: AttitudeCommand, kernel_ready: bool = False) -> None: ...

    def advance(self, n_steps: int) -> None: ...

    def set_param(self, name: str, value: float) -> bool: ...
