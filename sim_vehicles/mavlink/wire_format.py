"""What MAVLink can carry: the float32 NED/FRD fields of the messages the swarm uses.

``sim`` passes commands and samples through these same conversions (``command_roundtrip``,
``sample_fields`` then ``sample_from_fields``) so that, in lockstep, the transport is the only
difference between an in-process run and a run across processes. The MAVLink endpoint and the
controller's link use them to fill and read fields, through ``tick_frames`` on the per-tick path.

- SET_ATTITUDE_TARGET: ``q`` [w,x,y,z; FRD -> NED], body rates [rad/s; FRD], thrust normalised to
  ``0..1`` of ``max_thrust_N``. ``omegadot_c`` has no field: the vehicle receives zeros.
- LOCAL_POSITION_NED: position [m] and velocity [m/s], NED.
- ATTITUDE_QUATERNION: ``q`` [w,x,y,z; FRD -> NED] and body rates [rad/s; FRD].

The conversions are compiled kernels on float64 arrays, so the per-tick frames can convert and
pack in one compiled call; the Python functions below wrap them for everything else. Float32
rounding is the C cast MAVLink's packing does (round to nearest even); ENU/FLU <-> NED/FRD is
``enu_ned``'s.
"""

import math
import struct
from typing import Any, NamedTuple

import numpy as np

from sim_vehicles.common.command import AttitudeCommand
from sim_vehicles.common.jit import kernel, kernel_array
from sim_vehicles.common.state import POS, QUAT, RATE, VEL
from sim_vehicles.mavlink.enu_ned import attitude_into, body_into, world_into

#: ``command_from_fields``: q_c [w,x,y,z; FLU -> ENU], omega_c [rad/s; FLU], thrust [N], valid flag
CMD_Q, CMD_OMEGA, CMD_THRUST, CMD_VALID = slice(0, 4), slice(4, 7), 7, 8
#: ``sample_from_fields``: p [m; ENU], v [m/s; ENU], q [w,x,y,z; FLU -> ENU]
SAMPLE_P, SAMPLE_V, SAMPLE_Q = slice(0, 3), slice(3, 6), slice(6, 10)
#: SET_ATTITUDE_TARGET's ``type_mask`` bits (MAVLink's ATTITUDE_TARGET_TYPEMASK): what is ignored
IGNORE_RATES = 0b0000_0111
IGNORE_THROTTLE = 0b0100_0000
IGNORE_ATTITUDE = 0b1000_0000
IGNORE_ALL = IGNORE_RATES | IGNORE_THROTTLE | IGNORE_ATTITUDE  #: a lockstep clock-only setpoint


class Setpoint(NamedTuple):
    """SET_ATTITUDE_TARGET as a vehicle reads it, its fields converted (``command_from_fields``)."""

    time_boot_ms: int
    target_system: int
    target_component: int
    type_mask: int
    command: np.ndarray  #: ``command_from_fields`` (ENU/FLU, thrust [N], valid flag)


class AttitudeTargetFields(NamedTuple):
    q: tuple[float, float, float, float]
    body_rates: tuple[float, float, float]
    thrust: float


_F32 = [struct.Struct(f"<{n}f") for n in range(9)]


def f32(*values: float) -> tuple[float, ...]:
    """Round each value to the nearest float32, as a MAVLink float field does."""
    fmt = _F32[len(values)] if len(values) < len(_F32) else struct.Struct(f"<{len(values)}f")
    return fmt.unpack(fmt.pack(*values))


# -- compiled -------------------------------------------------------------------------------------


@kernel
def _round_f32(f):
    for j in range(f.shape[0]):
        f[j] = np.float32(f[j])
    return f


@kernel
def local_position_fields(p_W, v_W):
    """LOCAL_POSITION_NED ``(x, y, z, vx, vy, vz)``, float32 values."""
    f = np.empty(6)
    world_into(f, 0, p_W)
    world_into(f, 3, v_W)
    return _round_f32(f)


@kernel
def attitude_quaternion_fields(q_WB, omega_B):
    """ATTITUDE_QUATERNION ``(q1..q4, rollspeed, pitchspeed, yawspeed)``, float32 values."""
    f = np.empty(7)
    attitude_into(f, 0, q_WB[0], q_WB[1], q_WB[2], q_WB[3])
    body_into(f, 4, omega_B)
    return _round_f32(f)


@kernel
def sample_fields(x):
    """Both sample messages' fields of the vehicle state ``x`` (``common.state``): LOCAL_POSITION_NED's
    ``(x..vz)`` then ATTITUDE_QUATERNION's ``(q1..q4, rollspeed, pitchspeed, yawspeed)``."""
    f = np.empty(13)
    f[0:6] = local_position_fields(x[POS], x[VEL])
    f[6:13] = attitude_quaternion_fields(x[QUAT], x[RATE])
    return f


@kernel
def sample_from_fields(lpos, attq):
    """``[p_W, v_W, q_WB]`` (``SAMPLE_*``) from LOCAL_POSITION_NED ``(x..vz)`` and the quaternion
    of ATTITUDE_QUATERNION ``(q1..q4, ...)``, renormalised (float32 leaves it a little off)."""
    out = np.empty(10)
    world_into(out, 0, lpos[0:3])
    world_into(out, 3, lpos[3:6])
    q0, q1, q2, q3 = attq[0], attq[1], attq[2], attq[3]
    n = math.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
    attitude_into(out, 6, q0 / n, q1 / n, q2 / n, q3 / n)
    return out


@kernel
def attitude_target_fields(q_c, omega_c_B, thrust_N, max_thrust_N):
    """SET_ATTITUDE_TARGET ``(q[4], body rates[3], thrust)``, float32 values; thrust clipped to
    ``0..1`` (NaN passes through, to be refused by the receiver)."""
    f = np.empty(8)
    attitude_into(f, 0, q_c[0], q_c[1], q_c[2], q_c[3])
    body_into(f, 4, omega_c_B)
    u = thrust_N / max_thrust_N
    if u < 0.0:
        u = 0.0
    elif u > 1.0:
        u = 1.0
    f[7] = u
    return _round_f32(f)


@kernel
def command_from_fields(f, max_thrust_N):
    """The command a vehicle holds for SET_ATTITUDE_TARGET fields ``(q[4], rates[3], thrust)``
    (``CMD_*``); ``CMD_VALID`` is 0 for a quaternion that is not a rotation, a non-finite value or a
    thrust outside ``0..1`` (what no sender means: refused, never clipped into free fall or full thrust)."""
    out = np.empty(9)
    q0, q1, q2, q3 = f[0], f[1], f[2], f[3]
    n = math.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
    rotation = math.isfinite(n) and abs(n - 1.0) <= 1e-3
    ok = rotation and math.isfinite(f[4] + f[5] + f[6]) and 0.0 <= f[7] <= 1.0
    attitude_into(out, 0, q0 / n, q1 / n, q2 / n, q3 / n)
    body_into(out, 4, f[4:7])
    out[7] = f[7] * max_thrust_N
    out[8] = 1.0 if ok else 0.0
    return out


# -- Python ---------------------------------------------------------------------------------------


def command_of(decoded: np.ndarray) -> AttitudeCommand:
    """The ``AttitudeCommand`` of a valid ``command_from_fields`` result (views into it)."""
    return AttitudeCommand(
        q_c=decoded[CMD_Q], thrust_N=float(decoded[CMD_THRUST]), omega_c_B=decoded[CMD_OMEGA]
    )


def encode_attitude_target(cmd: AttitudeCommand, max_thrust_N: float) -> AttitudeTargetFields:
    v = attitude_target_fields(
        kernel_array(cmd.q_c), kernel_array(cmd.omega_c_B), float(cmd.thrust_N), float(max_thrust_N)
    )
    f = v.tolist()
    return AttitudeTargetFields((f[0], f[1], f[2], f[3]), (f[4], f[5], f[6]), f[7])


def decode_attitude_target(fields: AttitudeTargetFields, max_thrust_N: float) -> AttitudeCommand:
    """The command a vehicle holds; raises ``ValueError`` for fields it refuses (``command_from_fields``)."""
    f = np.array([*fields.q, *fields.body_rates, fields.thrust], dtype=np.float64)
    decoded = command_from_fields(f, float(max_thrust_N))
    if not decoded[CMD_VALID]:
        raise ValueError(
            f"attitude target {fields.q} is not a unit quaternion, a rate is not finite, or thrust "
            f"{fields.thrust} is outside 0..1"
        )
    return command_of(decoded)


def setpoint_of(m: Any, max_thrust_N: float) -> Setpoint:
    """The ``Setpoint`` of pymavlink's SET_ATTITUDE_TARGET message ``m``."""
    f = np.array([*m.q, m.body_roll_rate, m.body_pitch_rate, m.body_yaw_rate, m.thrust], dtype=float)
    return Setpoint(
        m.time_boot_ms, m.target_system, m.target_component, m.type_mask, command_from_fields(f, max_thrust_N)
    )


def command_roundtrip(
    cmd: AttitudeCommand, full_thrust_N: float, max_thrust_N: float | None = None
) -> AttitudeCommand:
    """The command as the vehicle receives it over MAVLink: its thrust sent as a fraction of
    ``full_thrust_N`` (the controller's, ``thrust_map``), read back as one of the vehicle's
    ``max_thrust_N`` (default: the same)."""
    max_thrust = full_thrust_N if max_thrust_N is None else max_thrust_N
    return decode_attitude_target(encode_attitude_target(cmd, full_thrust_N), max_thrust)


def encode_attitude_quaternion(q_WB: np.ndarray, omega_B: np.ndarray) -> tuple[float, ...]:
    """``(q1..q4, rollspeed, pitchspeed, yawspeed)`` NED/FRD float32."""
    return tuple(attitude_quaternion_fields(kernel_array(q_WB), kernel_array(omega_B)).tolist())


def encode_attitude(q_WB: np.ndarray, omega_B: np.ndarray) -> tuple[float, ...]:
    """ATTITUDE's ``(roll, pitch, yaw, rollspeed, pitchspeed, yawspeed)``: the Euler angles (ZYX,
    FRD -> NED) of ATTITUDE_QUATERNION's float32 quaternion, and its rates."""
    f = encode_attitude_quaternion(q_WB, omega_B)
    w, qx, qy, qz = f[0:4]
    roll = math.atan2(2 * (w * qx + qy * qz), 1 - 2 * (qx * qx + qy * qy))
    pitch = math.asin(max(-1.0, min(1.0, 2 * (w * qy - qz * qx))))
    yaw = math.atan2(2 * (w * qz + qx * qy), 1 - 2 * (qy * qy + qz * qz))
    return roll, pitch, yaw, f[4], f[5], f[6]
