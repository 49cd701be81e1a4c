"""One vehicle: rigid-body plant plus its attitude loop, advanced in fixed steps.

Sampled-data semantics (the vehicle side):

- The attitude loop and the plant share one step ``dt_s`` (1 ms by default). At the start of each
  step the torque law is evaluated on the current state and held over the step; the plant is
  integrated over the step with RK4. Time is ``k * dt_s``.
- Between two commands the vehicle holds the last command: attitude ``q_c``, body rates
  ``omega_c``, their derivative ``omegadot_c`` (zero when the sender cannot give it, as over
  MAVLink) and thrust. Thrust is clipped to ``[0, max_thrust_N]``, body rates to
  ``+-max_rate_rps`` (PX4's MC_*RATE_MAX).
- ``q_c`` and ``-q_c`` are the same attitude; the loop takes the one in the hemisphere of the current
  attitude so it never unwinds a full turn (identical to the paper's law whenever the error scalar
  part is non-negative, which is the paper's operating region).
"""

import numpy as np

from sim_vehicles.common.command import ZERO3, AttitudeCommand
from sim_vehicles.common.jit import kernel, kernel_array
from sim_vehicles.common.state import POS, QUAT, RATE, STATE_SIZE
from sim_vehicles.plant.params import AttitudeGains, VehicleParams
from sim_vehicles.plant.rigid_body import rk4_step, rk4_step_in_air
from sim_vehicles.plant.torque_law import torque
from sim_vehicles.plant.wind import WindModel

_ZERO3_ARG = np.zeros(3)  #: what the kernel gets for ``ZERO3``: writable (one signature), never written


@kernel
def advance_kernel(
    x,
    q_c,
    omega_c,
    omegadot_c,
    thrust_N,
    mass_kg,
    inertia_kgm2,
    g_mps2,
    l_q,
    k_q,
    max_thrust_N,
    max_rate,
    dt_s,
    drag_Ns2pm2,
    wind_W,
    n_steps,
):
    """Advance the state ``n_steps`` attitude-loop steps under one held command (thrust clipped to
    ``0..max_thrust_N``, body rates to ``+-max_rate``); with drag, in the wind ``wind_W``."""
    T = min(max(thrust_N, 0.0), max_thrust_N)
    qc_neg = -q_c
    if np.any(np.abs(omega_c) > max_rate):
        omega_c = np.minimum(np.maximum(omega_c, -max_rate), max_rate)
    for _ in range(n_steps):
        q = x[QUAT]
        dot = q[0] * q_c[0] + q[1] * q_c[1] + q[2] * q_c[2] + q[3] * q_c[3]
        qc = q_c if dot >= 0.0 else qc_neg
        tau = torque(q, x[RATE], qc, omega_c, omegadot_c, inertia_kgm2, l_q, k_q)
        if drag_Ns2pm2 > 0.0:
            x = rk4_step_in_air(x, T, tau, mass_kg, inertia_kgm2, g_mps2, dt_s, drag_Ns2pm2, wind_W)
        else:  # still air: the step without the drag term at all (the same bits as before it)
            x = rk4_step(x, T, tau, mass_kg, inertia_kgm2, g_mps2, dt_s)
    return x


def _kernel_arg(v: np.ndarray) -> np.ndarray:
    """A writable C-contiguous float64 array: one compiled signature of the kernel whatever the
    command's arrays are (the read-only default rates would otherwise compile a second one in
    every vehicle process)."""
    if v is ZERO3:  # the default rates of nearly every command: no new array per setpoint
        return _ZERO3_ARG
    return kernel_array(v)


class Autopilot:
    """Plant and attitude loop of one vehicle. No I/O: the MAVLink endpoint wraps it."""

    def __init__(self, params: VehicleParams, gains: AttitudeGains, state0: np.ndarray, dt_s: float):
        if state0.shape != (STATE_SIZE,):
            raise ValueError(f"state must have {STATE_SIZE} entries, got {state0.shape}")
        self.params = params
        self.gains = gains
        self.dt_s = float(dt_s)
        self.state = np.array(state0, dtype=float)
        self.state[QUAT] /= np.linalg.norm(self.state[QUAT])
        self.step_index = 0
        self._inertia = params.inertia
        #: the body-rate limit in force [rad/s], from ``params.max_rate_rps`` (a PARAM_SET may change it)
        self.max_rate_rps = np.array(params.max_rate_rps, dtype=float)
        #: the wind at the vehicle [m/s; ENU], changed in place (``wind``, at each ``advance``)
        self.wind_W = np.zeros(3)
        self.wind: WindModel | None = None  #: the air it flies in (``plant.wind``); None: still air
        self.tunables: dict[str, float] = {}  #: none: its gains are the vehicle config's (``l_q``, ``k_q``)
        self.set_command(AttitudeCommand(q_c=self.state[QUAT].copy(), thrust_N=params.hover_thrust_N))

    @property
    def time_s(self) -> float:
        return self.step_index * self.dt_s

    def set_command(self, command: AttitudeCommand, kernel_ready: bool = False) -> None:
        """Hold ``command`` from now. ``kernel_ready``: its attitude and rates are writable
        C-contiguous float64 arrays already (views into a kernel's fresh result), not checked again."""
        self.command = command
        p = self.params
        q_c, omega_c = command.q_c, command.omega_c_B
        if not kernel_ready:
            q_c, omega_c = _kernel_arg(q_c), _kernel_arg(omega_c)
        # the kernel's arguments but the state and the step count, prepared once per command
        # rather than once per advance (``max_rate_rps`` is changed in place, never replaced)
        self.kernel_args = (
            q_c,
            omega_c,
            _kernel_arg(command.omegadot_c_B),
            float(command.thrust_N),
            p.mass_kg,
            self._inertia,
            p.g_mps2,
            self.gains.l_q,
            self.gains.k_q,
            p.max_thrust_N,
            self.max_rate_rps,
            self.dt_s,
            p.drag_Ns2pm2,
            self.wind_W,
        )

    def set_param(self, name: str, value: float) -> bool:
        """No parameter of its own can be set (``contract.VehicleModel``)."""
        return False

    def advance(self, n_steps: int) -> None:
        """Run ``n_steps`` attitude-loop steps holding the current command (in the wind of the
        instant they start, if there is one)."""
        if self.wind is not None:
            self.wind_W[:] = self.wind.update(self.time_s, self.state[POS])
        self.state = advance_kernel(self.state, *self.kernel_args, int(n_steps))
        self.step_index += int(n_steps)
