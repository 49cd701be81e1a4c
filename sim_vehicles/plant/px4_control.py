"""PX4's multicopter attitude and rate controllers, as kernels (``mc_att_control``'s
``AttitudeControl``, ``mc_rate_control``'s ``RateControl``), in our ENU/FLU convention.

**Attitude** (quaternion error to a body-rate setpoint, Brescianini, Hehn and D'Andrea 2013, as
PX4 writes it): the setpoint ``q_d`` is first reduced to the rotation that tilts the body's z axis
onto the setpoint's (roll and pitch first); the yaw left over is scaled by ``MC_YAW_WEIGHT``; the
error ``q_e = conj(q) (x) q_d`` (taken with ``w >= 0``) gives ``e = 2 q_e.xyz`` and the rate
setpoint ``omega_sp = K_att * e`` with ``K_att = (MC_ROLL_P, MC_PITCH_P, MC_YAW_P / MC_YAW_WEIGHT)``
(the yaw gain compensated for the weight, as PX4 does), plus the commanded body rates, rotated from
the setpoint's body frame into the current one, as feed-forward; clipped to ``+-MC_*RATE_MAX``.

**Rate** (PID with anti-windup, PX4's parallel form scaled by ``K``): with ``err = omega_sp -
omega``, the normalised torque is ``K P err + i - K D omegadot``; the integral ``i`` grows by ``K I
f(err) err dt`` (``f = max(0, 1 - (err / 400 deg/s)^2)``, PX4's I-factor) and is held within
``+-INT_LIM``, and not in a direction the allocation could not give last step (``unallocated``).
A normalised torque of 1 is the largest the rotors make about that axis (``rotors.full_torque_Nm``).

Both run at the plant's step (1 kHz by default; PX4 runs its rate loop at the gyro's rate and its
attitude loop at 250 Hz or more). ``GAINS`` names the gain vector's entries: PX4's parameters.
"""

import math

import numpy as np

from sim_vehicles.common.jit import kernel
from sim_vehicles.common.quaternion import qconj, qmul, rotate, rotate_inverse

#: the gain vector's entries, in order: PX4's parameter names and their defaults
GAINS = {
    "MC_ROLL_P": 6.5,
    "MC_PITCH_P": 6.5,
    "MC_YAW_P": 2.8,
    "MC_YAW_WEIGHT": 0.4,
    "MC_ROLLRATE_P": 0.15,
    "MC_PITCHRATE_P": 0.15,
    "MC_YAWRATE_P": 0.2,
    "MC_ROLLRATE_I": 0.2,
    "MC_PITCHRATE_I": 0.2,
    "MC_YAWRATE_I": 0.1,
    "MC_ROLLRATE_D": 0.003,
    "MC_PITCHRATE_D": 0.003,
    "MC_YAWRATE_D": 0.0,
    "MC_ROLLRATE_K": 1.0,
    "MC_PITCHRATE_K": 1.0,
    "MC_YAWRATE_K": 1.0,
    "MC_RR_INT_LIM": 0.3,
    "MC_PR_INT_LIM": 0.3,
    "MC_YR_INT_LIM": 0.3,
}
#: each gain's range for a PARAM_SET: PX4's own (its parameter reference) where it gives one, else
#: ours, finite so that a typo cannot make the loop blow up (the I gains, D of pitch and yaw, the
#: integrator limits: PX4 bounds them below only)
RANGES = {
    "MC_ROLL_P": (0.0, 12.0),
    "MC_PITCH_P": (0.0, 12.0),
    "MC_YAW_P": (0.0, 5.0),
    "MC_YAW_WEIGHT": (0.0, 1.0),
    "MC_ROLLRATE_P": (0.01, 0.5),
    "MC_PITCHRATE_P": (0.01, 0.6),
    "MC_YAWRATE_P": (0.0, 0.6),
    "MC_ROLLRATE_I": (0.0, 10.0),
    "MC_PITCHRATE_I": (0.0, 10.0),
    "MC_YAWRATE_I": (0.0, 10.0),
    "MC_ROLLRATE_D": (0.0, 0.01),
    "MC_PITCHRATE_D": (0.0, 0.1),
    "MC_YAWRATE_D": (0.0, 0.1),
    "MC_ROLLRATE_K": (0.01, 5.0),
    "MC_PITCHRATE_K": (0.01, 5.0),
    "MC_YAWRATE_K": (0.01, 5.0),
    "MC_RR_INT_LIM": (0.0, 1.0),
    "MC_PR_INT_LIM": (0.0, 1.0),
    "MC_YR_INT_LIM": (0.0, 1.0),
}
ATT_P, YAW_W, RATE_P, RATE_I, RATE_D, RATE_K, INT_LIM = 0, 3, 4, 7, 10, 13, 16
I_FACTOR_RATE = math.radians(400.0)  #: PX4's I-factor scale [rad/s]


def gain_vector(values: dict[str, float]) -> np.ndarray:
    """The kernels' gain vector from PX4 parameter values (missing ones at ``GAINS``' defaults)."""
    return np.array([float(values.get(name, default)) for name, default in GAINS.items()])


@kernel
def _shortest(a, b):
    """The shortest rotation taking unit vector ``a`` to unit vector ``b`` (a quaternion)."""
    c = np.cross(a, b)
    d = a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
    q = np.empty(4)
    q[0] = 1.0 + d
    q[1:4] = c
    return q / np.sqrt(q[0] * q[0] + c[0] * c[0] + c[1] * c[1] + c[2] * c[2])


@kernel
def rate_setpoint(q, q_d, omega_ff, gains, max_rate):
    """The body-rate setpoint [rad/s; FLU] for attitude ``q`` and setpoint ``q_d`` (body to world),
    with ``omega_ff`` [rad/s; the setpoint's body frame] fed forward."""
    ez = rotate(q, np.array([0.0, 0.0, 1.0]))
    ez_d = rotate(q_d, np.array([0.0, 0.0, 1.0]))
    tilt = _shortest(ez, ez_d)
    # the thrust axis turned over: full attitude control, as PX4 does
    flipped = abs(tilt[1]) > 1.0 - 1e-5 or abs(tilt[2]) > 1.0 - 1e-5
    q_red = q_d.copy() if flipped else qmul(tilt, q)
    dyaw = qmul(qconj(q_red), q_d)
    if dyaw[0] < 0.0:
        dyaw = -dyaw
    w = gains[YAW_W]
    half = min(max(dyaw[0], -1.0), 1.0)
    sz = min(max(dyaw[3], -1.0), 1.0)
    scaled = np.array([math.cos(w * math.acos(half)), 0.0, 0.0, math.sin(w * math.asin(sz))])
    qd = qmul(q_red, scaled)
    qe = qmul(qconj(q), qd)
    if qe[0] < 0.0:
        qe = -qe
    yaw_p = gains[ATT_P + 2] / w if w > 1e-4 else gains[ATT_P + 2]
    rate = np.empty(3)
    rate[0] = 2.0 * qe[1] * gains[ATT_P]
    rate[1] = 2.0 * qe[2] * gains[ATT_P + 1]
    rate[2] = 2.0 * qe[3] * yaw_p
    rate += rotate_inverse(q, rotate(q_d, omega_ff))
    for a in range(3):
        rate[a] = min(max(rate[a], -max_rate[a]), max_rate[a])
    return rate


@kernel
def rate_control(omega, omega_sp, omegadot, integral, missed, gains, dt_s):
    """The normalised torque (``K P err + i - K D omegadot``) and the integral one step on;
    ``missed``: the torque the allocation could not give last step (its sign stops the
    integral growing that way)."""
    torque = np.empty(3)
    out = integral.copy()
    for a in range(3):
        k = gains[RATE_K + a]
        err = omega_sp[a] - omega[a]
        torque[a] = k * gains[RATE_P + a] * err + integral[a] - k * gains[RATE_D + a] * omegadot[a]
        e = err
        if missed[a] > 1e-9:  # more was asked than given: do not ask for more
            e = min(e, 0.0)
        elif missed[a] < -1e-9:
            e = max(e, 0.0)
        f = e / I_FACTOR_RATE
        f = max(0.0, 1.0 - f * f)
        i = integral[a] + f * k * gains[RATE_I + a] * e * dt_s
        lim = gains[INT_LIM + a]
        if math.isfinite(i):
            out[a] = min(max(i, -lim), lim)
    return torque, out
