"""Four rotors in X: where they are, what they push, and their motors.

Rotors in PX4's quad X order, at ``(x, y)`` in the FLU body frame (``l_pitch = |x|``, ``l_roll =
|y|``), each spinning as PX4's quad X does:

    1 front right  (+l_pitch, -l_roll)   counter-clockwise seen from above
    2 rear left    (-l_pitch, +l_roll)   counter-clockwise
    3 front left   (+l_pitch, +l_roll)   clockwise
    4 rear right   (-l_pitch, -l_roll)   clockwise

Rotor ``i`` at thrust fraction ``f_i`` (0..1) pushes ``T_i = t_max f_i`` along body z and twists
the body about z by ``SPIN_i q_max f_i`` (a counter-clockwise rotor's drag turns the body
clockwise: ``SPIN = (-1, -1, +1, +1)``), as PX4 SIH's quadrotor does. The control ``c = [T,
tau_x, tau_y, tau_z]`` [N, N m; FLU] of fractions ``f`` is ``E f`` (``effectiveness``); PX4's
allocation (``px4_allocation``) inverts it.

**The motors** (``motor_step``; the state each rotor keeps, ``thrust_fraction`` of it). Each
follows its actuator ``u_i`` (0..1) with a first-order lag ``tau``, exact over the step
(``decay = exp(-dt / tau)``; 0: no lag), in one of two models:

- ``THRUST_LAG`` (the default, PX4 SIH's): the thrust fraction itself lags ``u_i``. SIH
  integrates the same lag with forward Euler at its own step (``u += dt / tau (u_sp - u)``);
  the two differ by ``(dt / tau)^2 / 2`` of the step per step (2e-4 at 1 ms and 50 ms);
- ``SPEED_LAG``: the rotor's normalised speed ``s_i`` lags its setpoint ``sqrt(u_i)`` and the
  thrust fraction is ``s_i^2``, as a rotor whose thrust goes with its speed squared does: it
  spins up more slowly than it spins down, which a thrust lag cannot show.

A held ``u`` settles at the thrust it asks for in both. Pure kernels, no I/O.
"""

import math

import numpy as np

from sim_vehicles.common.jit import kernel

#: sign of each rotor's yaw torque on the body (FLU z): counter-clockwise rotors (1, 2) turn it clockwise
SPIN = np.array([-1.0, -1.0, 1.0, 1.0])
#: each rotor's position's sign, x (forward) and y (left), in PX4's quad X order
X_SIGN = np.array([1.0, -1.0, 1.0, -1.0])
Y_SIGN = np.array([-1.0, 1.0, 1.0, -1.0])
THRUST_LAG, SPEED_LAG = 0, 1  #: the motor models (``MOTOR_MODEL``)


def effectiveness(t_max_N: float, q_max_Nm: float, l_roll_m: float, l_pitch_m: float) -> np.ndarray:
    """``E``: the control ``[T, tau_x, tau_y, tau_z]`` of actuators ``u`` is ``E @ u``. Rows: the
    collective thrust, roll torque ``sum y_i T_i``, pitch torque ``-sum x_i T_i``, yaw torque
    ``sum SPIN_i q_max u_i``."""
    E = np.empty((4, 4))
    E[0] = t_max_N
    E[1] = Y_SIGN * l_roll_m * t_max_N
    E[2] = -X_SIGN * l_pitch_m * t_max_N
    E[3] = SPIN * q_max_Nm
    return E


@kernel
def motor_step(m, u, decay, model):
    """The motors' state one step on (``model``: ``THRUST_LAG`` or ``SPEED_LAG``): each follows
    its actuator ``u_i`` (as a thrust fraction, or as the speed ``sqrt(u_i)``), a first-order lag
    exact over the step (``decay = exp(-dt / tau)``; 0: no lag)."""
    out = np.empty(4)
    for i in range(4):
        target = min(max(u[i], 0.0), 1.0)
        if model == SPEED_LAG:
            target = math.sqrt(target)
        out[i] = target + (m[i] - target) * decay
    return out


@kernel
def thrust_fraction(m, model):
    """Each rotor's thrust over its largest (0..1) of the motors' state ``m``."""
    if model == SPEED_LAG:
        return m * m
    return m.copy()


@kernel
def rotor_wrench(f, t_max_N, q_max_Nm, l_roll_m, l_pitch_m):
    """The collective thrust [N] and body torque [N m; FLU] of rotors at thrust fractions ``f``."""
    thrust = 0.0
    tau = np.zeros(3)
    for i in range(4):
        t = t_max_N * f[i]
        thrust += t
        tau[0] += Y_SIGN[i] * l_roll_m * t
        tau[1] -= X_SIGN[i] * l_pitch_m * t
        tau[2] += SPIN[i] * q_max_Nm * f[i]
    return thrust, tau
