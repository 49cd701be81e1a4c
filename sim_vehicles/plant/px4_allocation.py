"""PX4's control allocation for a multicopter without air mode, as PX4 v1.15 runs it
(``ControlAllocationPseudoInverse``, ``ControlAllocationSequentialDesaturation``,
``ControlAllocator``'s status), in our FLU convention with thrust up.

**The mix** (``normalized_mix``): the pseudo-inverse ``M = pinv(E)`` of the effectiveness ``E``
(rows ``[T, tau_x, tau_y, tau_z]``, ``rotors.effectiveness``), each column scaled as PX4's
``updateControlAllocationMatrixScale`` does: roll and pitch by one scale, the larger of
``sqrt(|M_col|^2 / (n / 2))`` over the two (``n``: the column's entries over 1e-3), yaw by the
largest entry of PX4's (FRD) yaw column, thrust by the mean of its entries' size; then every
entry under 1e-3 is zero. The controls it takes are PX4's normalised ones: the collective thrust
over the largest (0..1: MAVLink's thrust) and the rate controller's torques, where 1 is what the
scale makes it (``torque_per_unit_Nm``: for PX4 SIH's quadrotor, 0.707 of an actuator per rotor in
roll and pitch, 1 in yaw).

**The allocation** (``allocate``, PX4's ``mixAirmodeDisabled`` and ``mixYaw``):

1. thrust, roll and pitch are mixed; desaturated along thrust, only if that *lowers* it;
2. desaturated along roll, then pitch;
3. yaw is added and desaturated within 0..1.15 (15 % over full, ``MINIMUM_YAW_MARGIN``); then
   along thrust again, only if that lowers it;
4. clipped to 0..1.

A desaturation along a column ``v`` (``_desaturate``, PX4's ``desaturateActuators``) moves by the
gain that brings the worst actuators back (``_gain``: the most negative and the most positive
gain any actuator out of range needs, added; an actuator with ``|v_i| < 0.2`` is left out), then
by half the gain still needed *whatever its sign*: after a thrust cut that leaves a rotor under
zero, the half step raises the thrust again. ``lower_only`` refuses the first step only.

**What is left unallocated** (``ControlAllocator::publish_control_allocator_status``): the torque
asked minus the torque the clipped actuators make, in the same normalised units
(``(E u) * scale``); the rate controller stops integrating into an axis where it is not met
(``px4_control.saturation``). PX4 publishes it at most every 5 ms; here it is every step.
Pure kernels, no I/O.
"""

import numpy as np

from sim_vehicles.common.jit import kernel

FLT_EPSILON = 1.1920929e-07  #: float's epsilon, PX4's threshold where it compares with zero
WEAK_ENTRY = 0.2  #: an actuator moved less than this by an axis is not desaturated by it (PX4's)
ZERO_ENTRY = 1e-3  #: mix entries under this are zero (PX4's)
YAW_MARGIN = 0.15  #: how far over full yaw may take an actuator (PX4's MINIMUM_YAW_MARGIN)


def normalized_mix(E: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """PX4's normalised mix of the effectiveness ``E`` and its scale: ``mix`` (actuators x
    ``[thrust, roll, pitch, yaw]``, the normalised controls) and ``scale`` (per control: a
    normalised control of 1 is ``1 / scale`` of ``E``'s units, N or N m)."""
    M = np.linalg.pinv(E)
    mix = M.copy()
    scale = np.ones(4)

    def rp_scale(col: np.ndarray) -> float:
        n = int(np.sum(np.abs(col) > ZERO_ENTRY))
        return float(np.sqrt(col @ col / (n / 2.0))) if n > 0 else 1.0

    scale[1] = scale[2] = max(rp_scale(M[:, 1]), rp_scale(M[:, 2]))
    scale[3] = float(np.max(-M[:, 3]))  # PX4's yaw column is FRD's, about z down: ours negated
    sizes = np.abs(M[:, 0])  # each actuator's thrust vector's norm (only z here)
    n_thrust = int(np.sum(sizes > FLT_EPSILON))
    scale[0] = float(sizes.sum() / n_thrust) if n_thrust > 0 else 1.0
    if scale[1] > FLT_EPSILON:
        mix[:, 1] /= scale[1]
        mix[:, 2] /= scale[2]
    if scale[3] > FLT_EPSILON:
        mix[:, 3] /= scale[3]
    if scale[0] > FLT_EPSILON:
        mix[:, 0] /= scale[0]
    mix[np.abs(mix) < ZERO_ENTRY] = 0.0
    return mix, scale


def torque_per_unit_Nm(scale: np.ndarray) -> np.ndarray:
    """What a normalised torque of 1 asks of the rotors [N m; roll, pitch, yaw] (while nothing
    saturates): ``1 / scale``."""
    return 1.0 / np.asarray(scale[1:4], dtype=float)


@kernel
def _gain(v, u, u_max):
    """How far along ``v`` brings the actuators ``u`` back into ``0..u_max``: PX4's
    ``computeDesaturationGain``."""
    k_min = 0.0
    k_max = 0.0
    for i in range(u.shape[0]):
        if abs(v[i]) < WEAK_ENTRY:
            continue
        if u[i] < 0.0:
            k = -u[i] / v[i]
            k_min = min(k_min, k)
            k_max = max(k_max, k)
        if u[i] > u_max:
            k = (u_max - u[i]) / v[i]
            k_min = min(k_min, k)
            k_max = max(k_max, k)
    return k_min + k_max


@kernel
def _desaturate(u, v, u_max, lower_only):
    """``u`` moved along ``v`` by the gain that desaturates it, then by half the gain still
    needed (PX4's ``desaturateActuators``); ``lower_only``: the first step only if it lowers
    ``v``'s axis (PX4's ``increase_only`` on its thrust axis, which points down)."""
    g = _gain(v, u, u_max)
    if lower_only and g > 0.0:
        return
    u += g * v
    u += 0.5 * _gain(v, u, u_max) * v


@kernel
def allocate(thrust, torque, mix, E, scale):
    """The actuators (0..1) for the normalised thrust (0..1) and ``torque`` (3), and the
    normalised torque they leave unallocated (3)."""
    u = mix[:, 0] * thrust + mix[:, 1] * torque[0] + mix[:, 2] * torque[1]
    _desaturate(u, mix[:, 0].copy(), 1.0, True)
    _desaturate(u, mix[:, 1].copy(), 1.0, False)
    _desaturate(u, mix[:, 2].copy(), 1.0, False)
    u += mix[:, 3] * torque[2]
    _desaturate(u, mix[:, 3].copy(), 1.0 + YAW_MARGIN, False)
    _desaturate(u, mix[:, 0].copy(), 1.0, True)
    for i in range(u.shape[0]):
        u[i] = min(max(u[i], 0.0), 1.0)
    unallocated = np.empty(3)
    for a in range(3):
        made = 0.0
        for i in range(u.shape[0]):
            made += E[a + 1, i] * u[i]
        unallocated[a] = torque[a] - made * scale[a + 1]
    return u, unallocated
