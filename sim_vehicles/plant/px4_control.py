"""PX4's multicopter attitude and rate controllers as PX4 v1.15 runs them (``mc_att_control``'s
``AttitudeControl``, ``mc_rate_control``'s ``RateControl`` and its yaw-torque low-pass), as
kernels in our ENU/FLU convention; where PX4's frames (NED/FRD) decide a corner case, it is
decided as in PX4's.

**Attitude** (quaternion error to a body-rate setpoint, Brescianini, Hehn and D'Andrea 2013, as
PX4 writes it): the setpoint ``q_d`` is first reduced to the rotation that tilts the body's z axis
onto the setpoint's (roll and pitch first; ``_tilt``, PX4's ``Quaternion(src, dst)``, which takes
a half turn about a horizontal axis when the two are opposite, and then the full setpoint is
used); the yaw left over is scaled by ``MC_YAW_WEIGHT``; the error ``q_e = conj(q) (x) q_d``
(canonical as PX4's: the sign of its first entry over float's epsilon, in FRD) gives ``e = 2
q_e.xyz`` and the rate setpoint ``omega_sp = K_att * e`` with ``K_att = (MC_ROLL_P, MC_PITCH_P,
MC_YAW_P / MC_YAW_WEIGHT)``. The feed-forward is PX4's only one: a yaw rate about the *world's*
vertical (SET_ATTITUDE_TARGET's ``body_yaw_rate``, which PX4 takes as ``yaw_sp_move_rate``),
turned into the body frame (``R(q)^T e_z``); the commanded roll and pitch rates are not used, as
PX4 does not use them with an attitude. Then clipped to ``+-MC_*RATE_MAX``.

**Rate** (PID with anti-windup, PX4's parallel form scaled by ``K``): with ``err = omega_sp -
omega``, the normalised torque is ``K P err + i - K D omegadot``; the integral ``i`` grows by ``K I
f(err) err dt`` (``f = max(0, 1 - (err / 400 deg/s)^2)``, PX4's I-factor) and is held within
``+-INT_LIM``, and not in a direction the allocation could not give last step (``saturation``:
only when the unallocated torque's norm is 1e-3 or more, as PX4's ``torque_setpoint_achieved``,
then by its sign on each axis). The yaw torque then passes PX4's first-order low-pass at
``MC_YAW_TQ_CUTOFF`` (``yaw_lowpass``, PX4's ``AlphaFilter``; 0: off).

Both run at the plant's step (1 kHz by default; PX4 runs its rate loop at the gyro's rate and its
attitude loop at 250 Hz or more). ``GAINS`` names the gain vector's entries: PX4's parameters
(``px4_params``, their one declaration).
"""

import math

import numpy as np

from sim_vehicles.common.jit import kernel
from sim_vehicles.common.quaternion import qconj, qmul, rotate, rotate_inverse
from sim_vehicles.plant import px4_params

#: the gain vector's entries, in order: PX4's parameter names and their defaults
GAINS = px4_params.GAINS
#: each gain's range for a PARAM_SET or a spec (``px4_params``)
RANGES = {n: (px4_params.BY_NAME[n].low, px4_params.BY_NAME[n].high) for n in GAINS}
_ORDER = list(GAINS)
ATT_P = _ORDER.index("MC_ROLL_P")
YAW_W = _ORDER.index("MC_YAW_WEIGHT")
RATE_P = _ORDER.index("MC_ROLLRATE_P")
RATE_I = _ORDER.index("MC_ROLLRATE_I")
RATE_D = _ORDER.index("MC_ROLLRATE_D")
RATE_K = _ORDER.index("MC_ROLLRATE_K")
INT_LIM = _ORDER.index("MC_RR_INT_LIM")
YAW_TQ_CUTOFF = _ORDER.index("MC_YAW_TQ_CUTOFF")
assert _ORDER[ATT_P : ATT_P + 3] == ["MC_ROLL_P", "MC_PITCH_P", "MC_YAW_P"]
for _first, _axes in ((RATE_P, "P"), (RATE_I, "I"), (RATE_D, "D"), (RATE_K, "K")):
    assert _ORDER[_first : _first + 3] == [f"MC_{a}RATE_{_axes}" for a in ("ROLL", "PITCH", "YAW")]
assert _ORDER[INT_LIM : INT_LIM + 3] == ["MC_RR_INT_LIM", "MC_PR_INT_LIM", "MC_YR_INT_LIM"]

I_FACTOR_RATE = math.radians(400.0)  #: PX4's I-factor scale [rad/s]
FLT_EPSILON = 1.1920929e-07  #: float's epsilon, where PX4 compares with zero
TILT_EPS = 1e-5  #: PX4's Quaternion(src, dst): a cross product under this is "parallel"
#: the unallocated torque's squared norm under which PX4 calls the torque achieved
ACHIEVED_NORM_SQ = 1e-6
_UP = np.array([0.0, 0.0, 1.0])


def gain_vector(values: dict[str, float]) -> np.ndarray:
    """The kernels' gain vector from PX4 parameter values (missing ones at ``GAINS``' defaults)."""
    return np.array([float(values.get(name, default)) for name, default in GAINS.items()])


@kernel
def _tilt(ez, ez_d):
    """The shortest rotation taking the body's z axis ``ez`` onto ``ez_d`` (unit, ENU), as PX4's
    ``Quaternion(src, dst)`` makes it from the body's down axis in NED: when the two are opposite
    (cross product under 1e-5, dot product negative) a half turn about the NED axis in which the
    down axis is smallest (north, east, down, ties as PX4's), turned back into ENU."""
    d = ez[0] * ez_d[0] + ez[1] * ez_d[1] + ez[2] * ez_d[2]
    c = np.cross(ez, ez_d)
    q = np.empty(4)
    if math.sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2]) < TILT_EPS and d < 0.0:
        a_n, a_e, a_d = abs(ez[1]), abs(ez[0]), abs(ez[2])  # PX4's src.abs(): down axis in NED
        axis = np.zeros(3)  # the NED axis it picks, in ENU: N -> y, E -> x, D -> -z
        if a_n < a_e:
            if a_n < a_d:
                axis[1] = 1.0
            else:
                axis[2] = -1.0
        elif a_e < a_d:
            axis[0] = 1.0
        else:
            axis[2] = -1.0
        q[0] = 0.0
        q[1:4] = np.cross(-ez, axis)
    else:
        n2 = ez[0] * ez[0] + ez[1] * ez[1] + ez[2] * ez[2]
        n2_d = ez_d[0] * ez_d[0] + ez_d[1] * ez_d[1] + ez_d[2] * ez_d[2]
        q[0] = d + math.sqrt(n2 * n2_d)
        q[1:4] = c
    return q / math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])


@kernel
def _canonical(q):
    """``q`` or ``-q``, as PX4's ``canonical()`` picks for a body-frame rotation: the sign of its
    first entry over float's epsilon, in FRD order (``w, x, -y, -z``)."""
    for i in range(4):
        v = q[i] if i < 2 else -q[i]
        if abs(v) > FLT_EPSILON:
            return q if v > 0.0 else -q
    return q


@kernel
def rate_setpoint(q, q_d, yaw_rate_ff, gains, max_rate):
    """The body-rate setpoint [rad/s; FLU] for attitude ``q`` and setpoint ``q_d`` (body to world),
    with ``yaw_rate_ff`` [rad/s; about the world's up axis] fed forward."""
    ez = rotate(q, _UP)
    ez_d = rotate(q_d, _UP)
    tilt = _tilt(ez, ez_d)
    # the thrust axis turned over: full attitude control, as PX4 does
    flipped = abs(tilt[1]) > 1.0 - 1e-5 or abs(tilt[2]) > 1.0 - 1e-5
    q_red = q_d.copy() if flipped else qmul(tilt, q)
    dyaw = _canonical(qmul(qconj(q_red), q_d))
    w = gains[YAW_W]
    half = min(max(dyaw[0], -1.0), 1.0)
    sz = min(max(dyaw[3], -1.0), 1.0)
    scaled = np.array([math.cos(w * math.acos(half)), 0.0, 0.0, math.sin(w * math.asin(sz))])
    qd = qmul(q_red, scaled)
    qe = _canonical(qmul(qconj(q), qd))
    yaw_p = gains[ATT_P + 2] / w if w > 1e-4 else gains[ATT_P + 2]
    rate = np.empty(3)
    rate[0] = 2.0 * qe[1] * gains[ATT_P]
    rate[1] = 2.0 * qe[2] * gains[ATT_P + 1]
    rate[2] = 2.0 * qe[3] * yaw_p
    if yaw_rate_ff != 0.0:
        rate += rotate_inverse(q, _UP) * yaw_rate_ff
    for a in range(3):
        rate[a] = min(max(rate[a], -max_rate[a]), max_rate[a])
    return rate


@kernel
def saturation(unallocated):
    """Per axis, +1 (-1) where the allocation gave less (more) torque than asked, as PX4's rate
    controller reads its allocator's status: nothing while the unallocated torque's norm is under
    1e-3 (``torque_setpoint_achieved``), else the sign of each axis's beyond float's epsilon."""
    out = np.zeros(3)
    n2 = unallocated[0] ** 2 + unallocated[1] ** 2 + unallocated[2] ** 2
    if not n2 < ACHIEVED_NORM_SQ:
        for a in range(3):
            if unallocated[a] > FLT_EPSILON:
                out[a] = 1.0
            elif unallocated[a] < -FLT_EPSILON:
                out[a] = -1.0
    return out


@kernel
def rate_control(omega, omega_sp, omegadot, integral, saturated, gains, dt_s):
    """The normalised torque (``K P err + i - K D omegadot``) and the integral one step on;
    ``saturated`` (``saturation``): the integral does not grow in a saturated axis's direction."""
    torque = np.empty(3)
    out = integral.copy()
    for a in range(3):
        k = gains[RATE_K + a]
        err = omega_sp[a] - omega[a]
        torque[a] = k * gains[RATE_P + a] * err + integral[a] - k * gains[RATE_D + a] * omegadot[a]
        e = err
        if saturated[a] > 0.0:  # more was asked than given: do not ask for more
            e = min(e, 0.0)
        elif saturated[a] < 0.0:
            e = max(e, 0.0)
        f = e / I_FACTOR_RATE
        f = max(0.0, 1.0 - f * f)
        i = integral[a] + f * k * gains[RATE_I + a] * e * dt_s
        lim = gains[INT_LIM + a]
        if math.isfinite(i):
            out[a] = min(max(i, -lim), lim)
    return torque, out


@kernel
def yaw_lowpass(state, x, cutoff_hz, dt_s):
    """One step of PX4's yaw-torque low-pass (``AlphaFilter``): ``state + alpha (x - state)``,
    ``alpha = dt / (dt + 1 / (2 pi cutoff))``; a cutoff of 0 passes ``x`` through."""
    tau = 1.0 / (2.0 * math.pi * cutoff_hz) if cutoff_hz > FLT_EPSILON else 0.0
    if tau + dt_s > FLT_EPSILON:
        return state + dt_s / (tau + dt_s) * (x - state)
    return state
