"""A rotor-level quadrotor in X under PX4's attitude and rate control: the ``px4_quad_x`` model.

Per attitude step ``dt`` (1 ms by default), on the held command (attitude ``q_c``, the yaw rate
about the world's vertical as feed-forward, the collective thrust), as PX4 v1.15 on its SIH
quadrotor:

1. the attitude controller turns ``q_c`` into a body-rate setpoint (``px4_control.rate_setpoint``);
2. the rate controller turns it into a normalised torque (``px4_control.rate_control``; its D term
   on the body's angular acceleration over the last step; its integral held where the allocation
   left torque unallocated the step before), the yaw torque through PX4's low-pass
   (``px4_control.yaw_lowpass``);
3. PX4's allocation gives each rotor's actuator 0..1 for the normalised thrust and torque, on the
   mix PX4 normalises from the effectiveness (``px4_allocation``), desaturating with attitude
   first, as PX4 does without air mode;
4. the motors follow their actuators with the lag ``T_TAU_S`` (``rotors.motor_step``: SIH's thrust
   lag, or a rotor-speed lag), and the rigid body (``rigid_body``) is integrated with RK4 under
   the thrust and torque they make (``rotors.rotor_wrench``), held over the step.

State: the 13 values of the rigid body (``common.state``) and, after them, the motors' state (4),
the rate controller's integrals (3), the body rates of the step before (3) and the low-passed yaw
torque (1), in one array of ``EXT_SIZE``. ``QuadX`` is the model as the vehicle endpoint flies it
(the same face as ``autopilot.Autopilot``); ``QuadX.tunables`` are its PX4 parameters, served over
MAVLink and set with PARAM_SET (``vehicle.services``). Every parameter, its default and its range
is declared once, in ``px4_params``.
"""

import math

import numpy as np

from sim_vehicles.common.command import AttitudeCommand
from sim_vehicles.common.jit import kernel, kernel_array
from sim_vehicles.common.state import POS, QUAT, RATE, STATE_SIZE
from sim_vehicles.plant import px4_params
from sim_vehicles.plant.params import VehicleParams
from sim_vehicles.plant.px4_allocation import allocate, normalized_mix
from sim_vehicles.plant.px4_control import (
    GAINS,
    RANGES,
    YAW_TQ_CUTOFF,
    gain_vector,
    rate_control,
    rate_setpoint,
    saturation,
    yaw_lowpass,
)
from sim_vehicles.plant.rigid_body import rk4_step, rk4_step_in_air
from sim_vehicles.plant.rotors import SPEED_LAG, effectiveness, motor_step, rotor_wrench, thrust_fraction
from sim_vehicles.plant.wind import WindModel

MOTORS = slice(STATE_SIZE, STATE_SIZE + 4)  #: the motors' state in the extended state (``rotors``)
INTEGRAL = slice(STATE_SIZE + 4, STATE_SIZE + 7)  #: the rate controller's integrals
LAST_RATE = slice(STATE_SIZE + 7, STATE_SIZE + 10)  #: the body rates one step before [rad/s]
YAW_TORQUE = STATE_SIZE + 10  #: the low-passed normalised yaw torque
EXT_SIZE = STATE_SIZE + 11

#: the airframe's own parameters and their defaults: PX4's SIH quadrotor X (``SIH_Q_MAX``,
#: ``SIH_L_ROLL``, ``SIH_L_PITCH``, ``SIH_T_TAU``) and the motor model (``px4_params``); its mass,
#: inertia and largest collective thrust (4 ``SIH_T_MAX``) are the spec's
AIRFRAME = px4_params.AIRFRAME


@kernel
def advance_quad_kernel(
    xe,
    q_c,
    yaw_rate_ff,
    thrust,
    mass_kg,
    inertia_kgm2,
    g_mps2,
    max_rate,
    dt_s,
    drag_Ns2pm2,
    wind_W,
    gains,
    mix,
    E,
    scale,
    t_max_N,
    q_max_Nm,
    l_roll_m,
    l_pitch_m,
    decay,
    motor_model,
    unallocated,
    n_steps,
):
    """``n_steps`` steps of the quadrotor under one held command (module docstring); ``thrust`` is
    PX4's normalised one (0..1); ``unallocated`` (3, changed in place) carries the torque the
    allocation could not give from step to step."""
    xe = xe.copy()
    cutoff = gains[YAW_TQ_CUTOFF]
    for _ in range(n_steps):
        x = xe[:STATE_SIZE].copy()
        omega = x[RATE]
        omegadot = (omega - xe[LAST_RATE]) / dt_s
        sp = rate_setpoint(x[QUAT], q_c, yaw_rate_ff, gains, max_rate)
        tn, integral = rate_control(omega, sp, omegadot, xe[INTEGRAL], saturation(unallocated), gains, dt_s)
        tn[2] = yaw_lowpass(xe[YAW_TORQUE], tn[2], cutoff, dt_s)
        u, miss = allocate(thrust, tn, mix, E, scale)
        m = motor_step(xe[MOTORS], u, decay, motor_model)
        T, tau = rotor_wrench(thrust_fraction(m, motor_model), t_max_N, q_max_Nm, l_roll_m, l_pitch_m)
        if drag_Ns2pm2 > 0.0:
            xn = rk4_step_in_air(x, T, tau, mass_kg, inertia_kgm2, g_mps2, dt_s, drag_Ns2pm2, wind_W)
        else:
            xn = rk4_step(x, T, tau, mass_kg, inertia_kgm2, g_mps2, dt_s)
        xe[LAST_RATE] = omega
        xe[:STATE_SIZE] = xn
        xe[MOTORS] = m
        xe[INTEGRAL] = integral
        xe[YAW_TORQUE] = tn[2]
        unallocated[:] = miss
    return xe


#: each gain's range (``RANGES``) widened to take its bounds as float32 too: PX4's parameters are
#: float32, and so are the bounds it compares a PARAM_SET's value with
_HELD_RANGES = {
    n: (min(lo, float(np.float32(lo))), max(hi, float(np.float32(hi)))) for n, (lo, hi) in RANGES.items()
}


class QuadX:
    """One rotor-level quadrotor: the plant, its motors and PX4's attitude and rate loops. No
    I/O: the MAVLink endpoint wraps it as it wraps ``Autopilot``.

    ``airframe``: ``AIRFRAME``'s keys (its defaults for the missing ones); ``px4``: PX4 parameters
    of ``px4_control.GAINS`` (its defaults for the missing ones). The body-rate limits are
    ``params.max_rate_rps`` (PX4's ``MC_*RATE_MAX``)."""

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
        self.motor_model = int(a["MOTOR_MODEL"])
        self.E = effectiveness(self.t_max_N, self.q_max_Nm, self.l_roll_m, self.l_pitch_m)
        #: PX4's normalised mix and its scale (``px4_allocation.normalized_mix``)
        self.mix, self.scale = normalized_mix(self.E)
        self.decay = math.exp(-self.dt_s / self.tau_s) if self.tau_s > 0 else 0.0
        #: the PX4 parameters in force (a PARAM_SET changes them, and ``gains`` with them)
        self.tunables = {n: float((px4 or {}).get(n, d)) for n, d in GAINS.items()}
        self.gains = gain_vector(self.tunables)
        self.max_rate_rps = np.array(params.max_rate_rps, dtype=float)
        self.wind_W = np.zeros(3)
        self.wind: WindModel | None = None
        self._inertia = params.inertia
        self._unallocated = np.zeros(3)
        xe = np.zeros(EXT_SIZE)
        xe[:STATE_SIZE] = state0
        xe[QUAT] /= np.linalg.norm(xe[QUAT])
        hover = min(max(params.hover_thrust_N / 4.0 / self.t_max_N, 0.0), 1.0)  # each rotor's share
        # the motors at hover, as if just armed aloft
        xe[MOTORS] = math.sqrt(hover) if self.motor_model == SPEED_LAG else hover
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
        not needed: the arrays are made contiguous here either way). As PX4 flies an attitude
        setpoint: its yaw rate (``omega_c_B[2]``, MAVLink's ``body_yaw_rate``) is fed forward
        about the world's vertical, its roll and pitch rates are not used; the thrust is taken
        over the largest (PX4's normalised thrust, 0..1)."""
        self.command = command
        thrust = min(max(float(command.thrust_N) / self.params.max_thrust_N, 0.0), 1.0)
        self._args = (kernel_array(command.q_c), float(command.omega_c_B[2]), thrust)

    def set_param(self, name: str, value: float) -> bool:
        """Set PX4 parameter ``name`` (one of ``tunables``) if ``value`` is within its range
        (``px4_control.RANGES``, each bound also as the float32 PX4 holds it: a bound sent in a
        PARAM_SET arrives as its float32, 0.01 as 0.0099999998, and PX4 takes it); whether it was."""
        lo, hi = _HELD_RANGES.get(name, (math.nan, math.nan))
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
        q_c, yaw_rate, thrust = self._args
        self.ext = advance_quad_kernel(
            self.ext,
            q_c,
            yaw_rate,
            thrust,
            p.mass_kg,
            self._inertia,
            p.g_mps2,
            self.max_rate_rps,
            self.dt_s,
            p.drag_Ns2pm2,
            self.wind_W,
            self.gains,
            self.mix,
            self.E,
            self.scale,
            self.t_max_N,
            self.q_max_Nm,
            self.l_roll_m,
            self.l_pitch_m,
            self.decay,
            self.motor_model,
            self._unallocated,
            int(n_steps),
        )
        self.step_index += int(n_steps)

    @property
    def thrust_fractions(self) -> np.ndarray:
        """Each rotor's thrust over its largest (0..1), in PX4's quad X order."""
        return thrust_fraction(self.ext[MOTORS], self.motor_model)
