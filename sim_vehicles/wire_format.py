"""What MAVLink can carry: the float32 NED/FRD fields of the messages the swarm uses.

``sim`` passes commands and samples through ``*_roundtrip`` so that, in lockstep, the transport is
the only difference between an in-process run and a run across processes. The MAVLink endpoint
and the controller's link use the same ``encode_*``/``decode_*`` functions to fill and read fields.

- SET_ATTITUDE_TARGET: ``q`` [w,x,y,z; FRD -> NED], body rates [rad/s; FRD], thrust normalised to
  ``0..1`` of ``max_thrust_N``. ``omegadot_c`` has no field: the vehicle receives zeros.
- LOCAL_POSITION_NED: position [m] and velocity [m/s], NED.
- ATTITUDE_QUATERNION: ``q`` [w,x,y,z; FRD -> NED] and body rates [rad/s; FRD].

Float32 rounding is done with ``struct`` exactly as MAVLink packs its float fields.
"""

import math
import struct
from typing import NamedTuple

import numpy as np

from sim_vehicles.autopilot import AttitudeCommand
from sim_vehicles.frames import swap_frames_wxyz


class AttitudeTargetFields(NamedTuple):
    q: tuple[float, float, float, float]
    body_rates: tuple[float, float, float]
    thrust: float


_F32 = [struct.Struct(f"<{n}f") for n in range(9)]


def f32(*values: float) -> tuple[float, ...]:
    """Round each value to the nearest float32, as a MAVLink float field does."""
    fmt = _F32[len(values)] if len(values) < len(_F32) else struct.Struct(f"<{len(values)}f")
    return fmt.unpack(fmt.pack(*values))


def _floats(v: np.ndarray) -> list[float]:
    return v.tolist() if isinstance(v, np.ndarray) else [float(x) for x in v]


def encode_attitude_target(cmd: AttitudeCommand, max_thrust_N: float) -> AttitudeTargetFields:
    q = swap_frames_wxyz(*_floats(cmd.q_c))
    wx, wy, wz = _floats(cmd.omega_c_B)
    thrust = min(max(float(cmd.thrust_N) / max_thrust_N, 0.0), 1.0)
    v = f32(q[0], q[1], q[2], q[3], wx, -wy, -wz, thrust)
    return AttitudeTargetFields((v[0], v[1], v[2], v[3]), (v[4], v[5], v[6]), v[7])


def decode_attitude_target(fields: AttitudeTargetFields, max_thrust_N: float) -> AttitudeCommand:
    """The command a vehicle holds; raises ``ValueError`` for a quaternion that is not a rotation."""
    q0, q1, q2, q3 = fields.q
    n = math.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
    if not math.isfinite(n) or abs(n - 1.0) > 1e-3:
        raise ValueError(f"attitude target quaternion {fields.q} is not a unit quaternion")
    r = fields.body_rates
    if not math.isfinite(r[0] + r[1] + r[2] + fields.thrust):  # float32 values: no overflow
        raise ValueError("attitude target has a non-finite rate or thrust")
    q = np.array(swap_frames_wxyz(q0 / n, q1 / n, q2 / n, q3 / n))
    return AttitudeCommand(
        q_c=q, thrust_N=float(fields.thrust) * max_thrust_N, omega_c_B=np.array([r[0], -r[1], -r[2]])
    )


def command_roundtrip(cmd: AttitudeCommand, max_thrust_N: float) -> AttitudeCommand:
    """The command as the vehicle receives it over MAVLink."""
    return decode_attitude_target(encode_attitude_target(cmd, max_thrust_N), max_thrust_N)


def encode_local_position(p_W: np.ndarray, v_W: np.ndarray) -> tuple[float, ...]:
    """``(x, y, z, vx, vy, vz)`` NED float32."""
    px, py, pz = _floats(p_W)
    vx, vy, vz = _floats(v_W)
    return f32(py, px, -pz, vy, vx, -vz)


def decode_local_position(fields: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
    f = fields
    return np.array([f[1], f[0], -f[2]]), np.array([f[4], f[3], -f[5]])


def encode_attitude_quaternion(q_WB: np.ndarray, omega_B: np.ndarray) -> tuple[float, ...]:
    """``(q1..q4, rollspeed, pitchspeed, yawspeed)`` NED/FRD float32."""
    q = swap_frames_wxyz(*_floats(q_WB))
    wx, wy, wz = _floats(omega_B)
    return f32(q[0], q[1], q[2], q[3], wx, -wy, -wz)


def decode_attitude_quaternion(fields: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
    q0, q1, q2, q3 = fields[0:4]
    n = math.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
    q = np.array(swap_frames_wxyz(q0 / n, q1 / n, q2 / n, q3 / n))
    return q, np.array([fields[4], -fields[5], -fields[6]])
