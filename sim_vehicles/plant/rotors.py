"""Four rotors in X: where they are, what they push, their motors, and the control allocation.

Rotors in PX4's quad X order, at ``(x, y)`` in the FLU body frame (``l_pitch = |x|``, ``l_roll =
|y|``), each spinning as PX4's quad X does:

    1 front right  (+l_pitch, -l_roll)   counter-clockwise seen from above
    2 rear left    (-l_pitch, +l_roll)   counter-clockwise
    3 front left   (+l_pitch, +l_roll)   clockwise
    4 rear right   (-l_pitch, -l_roll)   clockwise

Rotor ``i`` at normalised speed ``s_i`` (its speed over its largest, 0..1) pushes ``T_i = t_max
s_i^2`` along body z and twists the body about z by ``SPIN_i q_max s_i^2`` (a counter-clockwise
rotor's drag turns the body clockwise: ``SPIN = (-1, -1, +1, +1)``). Its actuator ``u_i`` (0..1)
asks for the thrust ``t_max u_i``: the motor's speed setpoint is ``sqrt(u_i)``, which its speed
follows with a first-order lag ``tau`` (``motor_speeds``, exact over a step), so a held ``u``
settles at the thrust it asks for. ``u = (1, 1, 1, 1)`` is ``4 t_max``.

The control ``c = [T, tau_x, tau_y, tau_z]`` [N, N m; FLU] the rotors make is ``E u`` with the
effectiveness ``E`` (``effectiveness``); the allocation (``allocate``) inverts it with ``M = E^-1``
and, where an actuator would leave 0..1, desaturates as PX4's sequential desaturation does with
air mode off (``ControlAllocationSequentialDesaturation::mixAirmodeDisabled``): attitude has
priority over collective thrust, and roll and pitch over yaw:

1. thrust, roll and pitch are mixed; thrust is only ever *lowered* to bring an actuator back
   under 1 (never raised to lift one off 0);
2. roll, then pitch, are scaled back as far as still needed;
3. yaw is added, and scaled back as far as needed to stay within 0..1.15 (yaw may use 15 % above
   full, which the last step takes back); then thrust is lowered again if an actuator is over 1;
4. what is left outside 0..1 is clipped.

Each desaturation moves along one column ``v`` of ``M`` by the gain that brings the worst
actuators back (``k_min + k_max``), then by half of what is still needed, as PX4 does.
``unallocated`` is what the clipped actuators miss of the asked control, per torque axis: the
rate controller's integrators stop winding up that way (``px4_control``). Pure kernels, no I/O.
"""

import math

import numpy as np

from sim_vehicles.common.jit import kernel

#: sign of each rotor's yaw torque on the body (FLU z): counter-clockwise rotors (1, 2) turn it clockwise
SPIN = np.array([-1.0, -1.0, 1.0, 1.0])
#: each rotor's position's sign, x (forward) and y (left), in PX4's quad X order
X_SIGN = np.array([1.0, -1.0, 1.0, -1.0])
Y_SIGN = np.array([-1.0, 1.0, 1.0, -1.0])
YAW_MARGIN = 0.15  #: how far over full yaw may take an actuator before thrust is lowered (PX4's)


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


def full_torque_Nm(t_max_N: float, q_max_Nm: float, l_roll_m: float, l_pitch_m: float) -> np.ndarray:
    """The largest torque the rotors make about each axis (two rotors full, two stopped)
    [N m; roll, pitch, yaw]: what a normalised torque of 1 is (``px4_control``)."""
    return np.array([2 * l_roll_m * t_max_N, 2 * l_pitch_m * t_max_N, 2 * q_max_Nm])


@kernel
def _gain(v, u, u_max):
    """How far along ``v`` brings the actuators ``u`` back into ``0..u_max``: PX4's
    ``computeDesaturationGain`` (the most negative and most positive of the gains each actuator
    out of range needs, added)."""
    k_min = 0.0
    k_max = 0.0
    scale = 0.0
    for i in range(4):
        scale = max(scale, abs(v[i]))
    for i in range(4):
        if abs(v[i]) <= 1e-12 * scale:  # an actuator this axis does not move
            continue
        k = 0.0
        out = False
        if u[i] < 0.0:
            k = -u[i] / v[i]
            out = True
        elif u[i] > u_max:
            k = (u_max - u[i]) / v[i]
            out = True
        if out:
            k_min = min(k_min, k)
            k_max = max(k_max, k)
    return k_min + k_max


@kernel
def _desaturate(u, v, u_max, lower_only):
    """``u`` moved along ``v`` by the gain that desaturates it, then by half the gain still
    needed (PX4's ``desaturateActuators``); ``lower_only``: only a gain that lowers ``v``'s axis
    (thrust is never raised to unsaturate). Returns the gain applied."""
    g = _gain(v, u, u_max)
    if lower_only and g > 0.0:
        return 0.0
    u += g * v
    g2 = 0.5 * _gain(v, u, u_max)
    if lower_only and g2 > 0.0:
        return g
    u += g2 * v
    return g + g2


@kernel
def allocate(c, M, E):
    """The actuators (0..1) for the control ``c = [T, tau_x, tau_y, tau_z]`` (``M = E^-1``), and
    what they leave unallocated of the three torques (``c - E u`` on the torque rows)."""
    u = M[:, 0] * c[0] + M[:, 1] * c[1] + M[:, 2] * c[2]
    _desaturate(u, M[:, 0].copy(), 1.0, True)
    _desaturate(u, M[:, 1].copy(), 1.0, False)
    _desaturate(u, M[:, 2].copy(), 1.0, False)
    u += M[:, 3] * c[3]
    _desaturate(u, M[:, 3].copy(), 1.0 + YAW_MARGIN, False)
    _desaturate(u, M[:, 0].copy(), 1.0, True)
    for i in range(4):
        u[i] = min(max(u[i], 0.0), 1.0)
    missed = np.empty(3)
    for a in range(3):
        got = 0.0
        for i in range(4):
            got += E[a + 1, i] * u[i]
        missed[a] = c[a + 1] - got
    return u, missed


@kernel
def motor_speeds(s, u, decay):
    """The rotors' normalised speeds one step on: each follows its setpoint ``sqrt(u_i)`` as a
    first-order lag, exactly over the step (``decay = exp(-dt / tau)``; 0: no lag)."""
    out = np.empty(4)
    for i in range(4):
        target = math.sqrt(min(max(u[i], 0.0), 1.0))
        out[i] = target + (s[i] - target) * decay
    return out


@kernel
def rotor_wrench(s, t_max_N, q_max_Nm, l_roll_m, l_pitch_m):
    """The collective thrust [N] and body torque [N m; FLU] of rotors at normalised speeds ``s``."""
    thrust = 0.0
    tau = np.zeros(3)
    for i in range(4):
        f = t_max_N * s[i] * s[i]
        thrust += f
        tau[0] += Y_SIGN[i] * l_roll_m * f
        tau[1] -= X_SIGN[i] * l_pitch_m * f
        tau[2] += SPIN[i] * q_max_Nm * s[i] * s[i]
    return thrust, tau
