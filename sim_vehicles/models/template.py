"""A vehicle model to start from: the paper's vehicle whose collective thrust lags its command.

Copy this file, change what it flies, name it in a config (``vehicle: {model:
"my_vehicle.py:LaggyVtol", params: {THRUST_TAU_S: 0.05}}``) and ``swarm-sitl sim``, ``run``, the
fault plans and the ``swarm`` fixture fly it (``docs/vehicles.md``).

**The contract** (``plant.contract.VehicleModel``; ``models.build`` holds a model to it when it is
built, and a run builds it once at load to check it):

- it is built as ``Model(spec, state0, dt_s)``: ``spec`` the ``models.spec.VehicleConfig`` (mass,
  inertia, largest thrust, gravity, rate limits, drag, ``l_q``/``k_q``, and ``spec.params``: the
  model's own parameters, by name, from the config's ``vehicle.params``: each one the model
  declares, in its ``Params`` if it has one, else in its ``tunables``; ``models.build`` refuses
  any other name before the model sees it), ``state0`` the 13-value
  rigid-body state (``common.state``: position, velocity [ENU], attitude [Hamilton, FLU -> ENU],
  body rates [FLU]), ``dt_s`` its step. Raise ``models.spec.VehicleConfigError`` (one line naming
  the parameter) for parameters it cannot take;
- ``params``: a ``plant.params.VehicleParams`` (the vehicle serves its hover thrust from
  it; a controller's thrust 1.0 is ``max_thrust_N``);
- ``state`` (13 values, readable and writable), ``step_index`` (steps flown), ``dt_s``, ``time_s``
  (``step_index * dt_s``: simulated time is counted, never summed);
- ``command`` and ``set_command(command, kernel_ready=False)``: the ``common.command.AttitudeCommand``
  held from now (``q_c`` [Hamilton, FLU -> ENU], ``omega_c_B`` [rad/s], ``omegadot_c_B``
  [rad/s^2], ``thrust_N``);
- ``advance(n_steps)``: fly ``n_steps`` steps under the held command; it must depend on nothing but
  its state, its command and its parameters (no clock, no randomness but seeded), so the same
  spec flies the same bits in ``sim`` and as a process;
- ``max_rate_rps`` (3, changed in place by a PARAM_SET of MC_*RATE_MAX), ``wind`` (None, or a
  ``plant.wind.WindModel`` the builder sets) and ``wind_W`` (the wind in force, 3);
- ``tunables``: its own parameters that a ground station may read and set over MAVLink, by name
  (REAL32), and ``set_param(name, value) -> bool``: set one if ``value`` is within its range.

This one: the paper's rigid body (``plant.rigid_body``) under the paper's torque law
(``plant.torque_law``), stepped with RK4, its collective thrust following the command through a
first-order lag of ``THRUST_TAU_S`` (exact over a step). It ignores drag, wind and the rate limit
(a model that flies them reads ``spec.drag_Ns2pm2``, ``wind_W`` and ``max_rate_rps``). Plain
Python around two compiled kernels: a step costs some 15 us (the built-in models are one kernel).
"""

import math

import numpy as np

from sim_vehicles.common.command import AttitudeCommand
from sim_vehicles.common.state import QUAT, RATE
from sim_vehicles.models.build import vehicle_params
from sim_vehicles.models.vehicle_config import VehicleConfig, VehicleConfigError
from sim_vehicles.plant.rigid_body import rk4_step
from sim_vehicles.plant.torque_law import torque

THRUST_TAU_RANGE_S = (0.0, 1.0)  #: the range of ``THRUST_TAU_S`` [s]


class LaggyVtol:
    def __init__(self, spec: VehicleConfig, state0: np.ndarray, dt_s: float):
        self.params = vehicle_params(spec)  # the config's mass, inertia, thrust, gravity, rate limits, drag
        self.dt_s = float(dt_s)
        self.step_index = 0
        self.state = np.array(state0, dtype=float)
        self.max_rate_rps = np.array(spec.max_rate_rps, dtype=float)
        self.wind = None
        self.wind_W = np.zeros(3)
        self.tunables = {"THRUST_TAU_S": 0.05}
        if not self.set_param("THRUST_TAU_S", float(spec.params.get("THRUST_TAU_S", 0.05))):
            raise VehicleConfigError(
                f"vehicle config: params: THRUST_TAU_S must be within {THRUST_TAU_RANGE_S}, "
                f"got {spec.params['THRUST_TAU_S']!r}"
            )
        self.l_q, self.k_q = spec.l_q, spec.k_q
        self.thrust_N = self.params.hover_thrust_N  #: the thrust the rotors give now [N]
        self.set_command(AttitudeCommand(q_c=self.state[QUAT].copy(), thrust_N=self.thrust_N))

    @property
    def time_s(self) -> float:
        return self.step_index * self.dt_s

    def set_command(self, command: AttitudeCommand, kernel_ready: bool = False) -> None:
        self.command = command

    def set_param(self, name: str, value: float) -> bool:
        lo, hi = THRUST_TAU_RANGE_S
        if name != "THRUST_TAU_S" or not lo <= value <= hi:
            return False
        self.tunables[name] = float(value)
        return True

    def advance(self, n_steps: int) -> None:
        c, p = self.command, self.params
        tau = self.tunables["THRUST_TAU_S"]
        decay = math.exp(-self.dt_s / tau) if tau > 0 else 0.0
        target = min(max(float(c.thrust_N), 0.0), p.max_thrust_N)
        q_c = np.asarray(c.q_c, dtype=float)
        w_c = np.asarray(c.omega_c_B, dtype=float)
        wd_c = np.asarray(c.omegadot_c_B, dtype=float)
        inertia = p.inertia
        for _ in range(n_steps):
            x = self.state
            q = x[QUAT].copy()
            qc = q_c if float(q @ q_c) >= 0.0 else -q_c  # the same attitude, the nearer sign
            tau_B = torque(q, x[RATE].copy(), qc, w_c, wd_c, inertia, self.l_q, self.k_q)
            self.thrust_N = target + (self.thrust_N - target) * decay
            self.state = rk4_step(x, self.thrust_N, tau_B, p.mass_kg, inertia, p.g_mps2, self.dt_s)
            self.step_index += 1
