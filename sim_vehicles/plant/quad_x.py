"""A rotor-level quadrotor in X under PX4's attitude and rate control: the ``px4_quad_x`` model.

Per attitude step ``dt`` (1 ms by default), on the held command (attitude ``q_c``, body rates
``omega_c`` as feed-forward, collective thrust ``T_c``):

1. the attitude controller turns ``q_c`` into a body-rate setpoint (``px4_control.rate_setpoint``);
2. the rate controller turns it into a normalised torque (``px4_control.rate_control``; its D term
   on the body's angular acceleration over the last step), scaled to N m by the largest torque of
   each axis (``rotors.full_torque_Nm``);
3. the allocation gives each rotor's actuator 0..1 for ``[T_c, torque]`` (``rotors.allocate``),
   desaturating with attitude first, as PX4 does without air mode;
4. the motors' speeds follow their setpoints with the lag ``tau`` over the step
   (``rotors.motor_speeds``), and the rigid body (``rigid_body``) is integrated with RK4 under the
   thrust and torque of those speeds (``rotors.rotor_wrench``), held over the step.

State: the 13 values of the rigid body (``common.state``) and, after them, the rotors' normalised
speeds (4), the rate controller's integrals (3) and the body rates of the step before (3), in one
array of ``EXT_SIZE``. ``QuadX`` is the model as the vehicle endpoint flies it (the same face as
``autopilot.Autopilot``); ``QuadX.tunables`` are its PX4 parameters, served over MAVLink and set
with PARAM_SET (``vehicle.services``).
"""

import math

import numpy as np

from sim_vehicles.common.command import AttitudeCommand
from sim_vehicles.common.jit import kernel, kernel_array
from sim_vehicles.common.state import POS, QUAT, RATE, STATE_SIZE
from sim_vehicles.plant.params import VehicleParams
from sim_vehicles.plant.px4_control import GAINS, RANGES, gain_vector, rate_control, rate_setpoint
from sim_vehicles.plant.rigid_body import rk4_step, rk4_step_in_air
from sim_vehicles.plant.rotors import allocate, effectiveness, full_torque_Nm, motor_speeds, rotor_wrench
from sim_vehicles.plant.wind import WindModel

SPEEDS = slice(STATE_SIZE, STATE_SIZE + 4)  #: the rotors' normalised speeds in the extended state
INTEGRAL = slice(STATE_SIZE + 4, STATE_SIZE + 7)  #: the rate controller's integrals
LAST_RATE = slice(STATE_SIZE + 7, STATE_SIZE + 10)  #: the body rates one step before [rad/s]
EXT_SIZE = STATE_SIZE + 10

#: the airframe's own parameters and their defaults: PX4's SIH quadrotor X (``SIH_T_MAX``,
#: ``SIH_Q_MAX``, ``SIH_L_ROLL``, ``SIH_L_PITCH``, ``SIH_T_TAU``); its mass, inertia and largest
#: collective thrust (4 ``T_MAX``) are the spec's
AIRFRAME = {"Q_MAX_NM": 0.1, "L_ROLL_M": 0.2, "L_PITCH_M": 0.2, "T_TAU_S": 0.05}
#: each airframe parameter's range (``spec.params`` is held to it when the model is built)
AIRFRAME_RANGES = {
    "Q_MAX_NM": (1e-6, 10.0),
    "L_ROLL_M": (0.01, 5.0),
    "L_PITCH_M": (0.01, 5.0),
    "T_TAU_S": (0.0, 1.0),
}


@kernel
def advance_quad_kernel(
    xe,
    q_c,
    omega_c,
    thrust_N,
    mass_kg,
    inertia_kgm2,
    g_mps2,
    max_rate,
    dt_s,
    drag_Ns2pm2,
    wind_W,
    gains,
    M,
    E,
    torque_unit,
    t_max_N,
    q_max_Nm,
    l_roll_m,
    l_pitch_m,
    decay,
    missed,
    n_steps,
):
    """``n_steps`` steps of the quadrotor under one held command (module docstring); ``missed``
    (3, changed in place) carries what the allocation could not give from step to step."""
    xe = xe.copy()
    c = np.empty(4)
    c[0] = min(max(thrust_N, 0.0), 4.0 * t_max_N)
    for _ in range(n_steps):
        x = xe[:STATE_SIZE].copy()
        omega = x[RATE]
        omegadot = (omega - xe[LAST_RATE]) / dt_s
        sp = rate_setpoint(x[QUAT], q_c, omega_c, gains, max_rate)
        tn, integral = rate_control(omega, sp, omegadot, xe[INTEGRAL], missed, gains, dt_s)
        c[1] = tn[0] * torque_unit[0]
        c[2] = tn[1] * torque_unit[1]
        c[3] = tn[2] * torque_unit[2]
        u, miss = allocate(c, M, E)
        s = motor_speeds(xe[SPEEDS], u, decay)
        T, tau = rotor_wrench(s, t_max_N, q_max_Nm, l_roll_m, l_pitch_m)
        if drag_Ns2pm2 > 0.0:
            xn = rk4_step_in_air(x, T, tau, mass_kg, inertia_kgm2, g_mps2, dt_s, drag_Ns2pm2, wind_W)
        else:
            xn = rk4_step(x, T, tau, mass_kg, inertia_kgm2, g_mps2, dt_s)
        xe[LAST_RATE] = omega
        xe[:STATE_SIZE] = xn
        xe[SPEEDS] = s
        xe[INTEGRAL] = integral
        for a in range(3):
            missed[a] = miss[a] / torque_unit[a]
    return xe


class QuadX:
    """One rotor-level quadrotor: the plant, its motors and PX4's attitude and rate loops. No
    I/O: the MAVLink endpoint wraps it as it wraps ``Autopilot``.

    ``airframe``: ``AIRFRAME``'s keys (its defaults for the missing ones); ``px4``: PX4 parameters
    of ``px4_control.GAINS`` (its defaults for the missing ones)."""

    def __init__(
        self,
        params: VehicleParams,
        state0: np.ndarray,
        dt_s: float,
        airframe: dict[str, float] | None = None,
        px4: dict[str, float] | None = None,
    ):
        if state0.shape != (STATE_SIZE,):
            raise ValueError(f"state must have {STATE_SIZE} entries, got {state0.shape}")
        a = {**AIRFRAME, **(airframe or {})}
        self.params = params
        self.dt_s = float(dt_s)
        self.step_index = 0
        self.t_max_N = params.max_thrust_N / 4.0
        self.q_max_Nm, self.l_roll_m, self.l_pitch_m = a["Q_MAX_NM"], a["L_ROLL_M"], a["L_PITCH_M"]
        self.tau_s = a["T_TAU_S"]
        self.E = effectiveness(self.t_max_N, self.q_max_Nm, self.l_roll_m, self.l_pitch_m)
        self.M = np.linalg.inv(self.E)
        self.torque_unit = full_torque_Nm(self.t_max_N, self.q_max_Nm, self.l_roll_m, self.l_pitch_m)
        self.decay = math.exp(-self.dt_s / self.tau_s) if self.tau_s > 0 else 0.0
        #: the PX4 parameters in force (a PARAM_SET changes them, and ``gains`` with them)
        self.tunables = {n: float((px4 or {}).get(n, d)) for n, d in GAINS.items()}
        self.gains = gain_vector(self.tunables)
        self.max_rate_rps = np.array(params.max_rate_rps, dtype=float)
        self.wind_W = np.zeros(3)
        self.wind: WindModel | None = None
        self._inertia = params.inertia
        self._missed = np.zeros(3)
        xe = np.zeros(EXT_SIZE)
        xe[:STATE_SIZE] = state0
        xe[QUAT] /= np.linalg.norm(xe[QUAT])
        hover = params.hover_thrust_N / 4.0 / self.t_max_N  # each rotor's actuator at hover
        xe[SPEEDS] = math.sqrt(min(max(hover, 0.0), 1.0))  # spinning for hover, as if just armed aloft
        xe[LAST_RATE] = xe[RATE]
        self.ext = xe
        self.set_command(AttitudeCommand(q_c=xe[QUAT].copy(), thrust_N=params.hover_thrust_N))

    # -- the face the endpoint uses -------------------------------------------------------------
    @property
    def state(self) -> np.ndarray:
        """The rigid body's 13 values (``common.state``): a view into the extended state."""
        return self.ext[:STATE_SIZE]

    @state.setter
    def state(self, x: np.ndarray) -> None:
        self.ext[:STATE_SIZE] = x

    @property
    def time_s(self) -> float:
        return self.step_index * self.dt_s

    def set_command(self, command: AttitudeCommand, kernel_ready: bool = False) -> None:
        """Hold ``command`` from now (``kernel_ready`` as ``Autopilot.set_command``'s: accepted,
        not needed: the arrays are made contiguous here either way)."""
        self.command = command
        self._args = (
            kernel_array(command.q_c),
            kernel_array(command.omega_c_B),
            float(command.thrust_N),
        )

    def set_param(self, name: str, value: float) -> bool:
        """Set PX4 parameter ``name`` (one of ``tunables``) if ``value`` is within its range
        (``px4_control.RANGES``); whether it was."""
        lo, hi = RANGES.get(name, (math.nan, math.nan))
        if not lo <= value <= hi:
            return False
        self.tunables[name] = float(value)
        self.gains[list(GAINS).index(name)] = float(value)
        return True

    def advance(self, n_steps: int) -> None:
        """Run ``n_steps`` steps holding the current command (in the wind of the instant they start)."""
        if self.wind is not None:
            self.wind_W[:] = self.wind.update(self.time_s, self.state[POS])
        p = self.params
        q_c, omega_c, thrust = self._args
        self.ext = advance_quad_kernel(
            self.ext,
            q_c,
            omega_c,
            thrust,
            p.mass_kg,
            self._inertia,
            p.g_mps2,
            self.max_rate_rps,
            self.dt_s,
            p.drag_Ns2pm2,
            self.wind_W,
            self.gains,
            self.M,
            self.E,
            self.torque_unit,
            self.t_max_N,
            self.q_max_Nm,
            self.l_roll_m,
            self.l_pitch_m,
            self.decay,
            self._missed,
            int(n_steps),
        )
        self.step_index += int(n_steps)

    @property
    def rotor_speeds(self) -> np.ndarray:
        """The rotors' normalised speeds (0..1), in PX4's quad X order."""
        return self.ext[SPEEDS].copy()
