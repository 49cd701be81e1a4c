"""The MAVLink frames that cross a vehicle link every tick, each converted and packed (or read and
converted) in one compiled call.

A lockstep tick is a ping-pong: the vehicle sends its sample (LOCAL_POSITION_NED and
ATTITUDE_QUATERNION), the controller answers with SET_ATTITUDE_TARGET. Done in Python, field by
field, that costs more than the laws: these kernels do the conversion (``wire_format``) and the
frame (``frames``: the bytes pymavlink would write, tested against it) in one call each.

- ``pack_local_position`` / ``pack_attitude_quaternion`` (vehicle): the message of state ``x``
  (``common.state``) at ``time_boot_ms``, written to ``out``; returns its length.
- ``read_sample`` (controller): a datagram holding those two frames from ``(sysid, compid)``, of
  the same ``time_boot_ms`` and with good CRCs, as ``[1, time_boot_ms, p_W, v_W, q_WB, frames,
  bad]`` (``RS_*``). Other frames may come with them if ``ignored[msg_id]`` gives their CRC extra:
  the caller does not read those messages, so they are only counted, and ``bad`` of them had a bad
  CRC (what pymavlink would drop). Anything else (a message the caller reads, an unknown one, a
  frame that is not plain MAVLink 2) gives ``[0, ...]`` and the caller reads the datagram the
  general way.
- ``pack_setpoint`` (controller): SET_ATTITUDE_TARGET of a command, every field taken.
- ``read_setpoint`` (vehicle): a datagram made of exactly one SET_ATTITUDE_TARGET frame with a
  good CRC, as ``[1, sysid, compid, time_boot_ms, target_system, target_component, type_mask]``
  followed by ``wire_format.command_from_fields`` of its fields; else ``[0, ...]``.
  ``setpoint_of(r)`` gives it as a ``wire_format.Setpoint``.

``spec`` arguments are ``frames.Layout.spec`` of the message named.
"""

import numpy as np

from sim_vehicles.common.jit import kernel
from sim_vehicles.common.state import POS, QUAT, QUAT0, RATE, STATE_SIZE, VEL
from sim_vehicles.mavlink.frames import (
    ATTITUDE_QUATERNION,
    LOCAL_POSITION_NED,
    SET_ATTITUDE_TARGET,
    crc_x25,
    frame_at,
    pack_into,
    read_into,
)
from sim_vehicles.mavlink.wire_format import (
    Setpoint,
    attitude_quaternion_fields,
    attitude_target_fields,
    command_from_fields,
    local_position_fields,
    sample_from_fields,
)

#: room for any one frame of the messages above (largest payload 39 bytes, plus 12)
FRAME_BYTES = 64
RS_OK, RS_TIME_MS, RS_SAMPLE, RS_FRAMES, RS_BAD = 0, 1, slice(2, 12), 12, 13
SAMPLE_SIZE = 14
SETPOINT_SIZE = 7 + 9
SP_SYSID, SP_COMPID, SP_TIME_MS, SP_TARGET_SYSTEM, SP_TARGET_COMPONENT, SP_TYPE_MASK = 1, 2, 3, 4, 5, 6
SP_COMMAND = slice(7, 16)  #: ``wire_format.command_from_fields``


@kernel
def local_position_into(out, at, seq, sysid, compid, spec, time_boot_ms, x):
    """LOCAL_POSITION_NED of state ``x`` written at ``out[at:]``; returns the index after it."""
    v = np.empty(7)
    v[0] = time_boot_ms
    v[1:7] = local_position_fields(x[POS], x[VEL])
    return pack_into(out, at, seq, sysid, compid, spec, v)


@kernel
def attitude_quaternion_into(out, at, seq, sysid, compid, spec, time_boot_ms, x):
    """ATTITUDE_QUATERNION of state ``x`` written at ``out[at:]``; returns the index after it."""
    v = np.empty(8)
    v[0] = time_boot_ms
    v[1:8] = attitude_quaternion_fields(x[QUAT], x[RATE])
    return pack_into(out, at, seq, sysid, compid, spec, v)


@kernel
def pack_local_position(out, seq, sysid, compid, spec, time_boot_ms, x):
    return local_position_into(out, 0, seq, sysid, compid, spec, time_boot_ms, x)


@kernel
def pack_attitude_quaternion(out, seq, sysid, compid, spec, time_boot_ms, x):
    return attitude_quaternion_into(out, 0, seq, sysid, compid, spec, time_boot_ms, x)


@kernel
def pack_setpoint(
    out,
    seq,
    sysid,
    compid,
    spec,
    time_boot_ms,
    target_system,
    target_component,
    q_c,
    omega_c_B,
    thrust_N,
    max_thrust_N,
):
    f = attitude_target_fields(q_c, omega_c_B, thrust_N, max_thrust_N)
    v = np.empty(12)
    v[0] = time_boot_ms
    v[1] = target_system
    v[2] = target_component
    v[3] = 0.0  # type_mask: every field taken
    v[4:12] = f
    return pack_into(out, 0, seq, sysid, compid, spec, v)


@kernel
def read_sample(data, sysid, compid, lpos_spec, attq_spec, ignored):
    res = np.zeros(SAMPLE_SIZE)
    lpos = np.empty(7)
    attq = np.empty(8)
    got_lpos = False
    got_attq = False
    n_frames = 0
    n_bad = 0
    at = 0
    while at < len(data):
        msg_id, s, c, end = frame_at(data, at)
        if end < 0:
            return res
        n_frames += 1
        ours = s == sysid and c == compid
        if ours and msg_id == lpos_spec[0, 0] and not got_lpos:
            got_lpos = read_into(data, at, end, lpos_spec, lpos)
            if not got_lpos:
                return res
        elif ours and msg_id == attq_spec[0, 0] and not got_attq:
            got_attq = read_into(data, at, end, attq_spec, attq)
            if not got_attq:
                return res
        elif msg_id < len(ignored) and ignored[msg_id] >= 0:
            if crc_x25(data, at + 1, end - 2, ignored[msg_id]) != (
                data[end - 2] | (np.int64(data[end - 1]) << 8)
            ):
                n_bad += 1
        else:
            return res
        at = end
    if got_lpos and got_attq and lpos[0] == attq[0]:
        res[RS_OK] = 1.0
        res[RS_TIME_MS] = lpos[0]
        res[2:12] = sample_from_fields(lpos[1:7], attq[1:5])
        res[RS_FRAMES] = n_frames
        res[RS_BAD] = n_bad
    return res


@kernel
def read_setpoint(data, spec, max_thrust_N):
    res = np.zeros(SETPOINT_SIZE)
    msg_id, s, c, end = frame_at(data, 0)
    if end != len(data) or msg_id != spec[0, 0]:
        return res
    v = np.empty(12)  # time_boot_ms, target_system, target_component, type_mask, q[4], rates[3], thrust
    if not read_into(data, 0, end, spec, v):
        return res
    res[0] = 1.0
    res[1] = s
    res[2] = c
    res[3:7] = v[0:4]
    res[7:16] = command_from_fields(v[4:12], max_thrust_N)
    return res


def setpoint_of(r: np.ndarray) -> Setpoint:
    """``read_setpoint``'s result (a setpoint was read) as a ``Setpoint``; its command is a view."""
    return Setpoint(
        int(r[SP_TIME_MS]),
        int(r[SP_TARGET_SYSTEM]),
        int(r[SP_TARGET_COMPONENT]),
        int(r[SP_TYPE_MASK]),
        r[SP_COMMAND],
    )


def warm_up() -> None:
    """Call each kernel once with the argument types a link uses, so loading them from numba's
    cache (milliseconds each, and 16 processes at once on a small machine) happens at start-up
    and not at the first tick: without this a real-time swarm16 run lost its first 180 ms."""
    out = np.zeros(FRAME_BYTES, np.uint8)
    x = np.zeros(STATE_SIZE)
    x[QUAT0] = 1.0
    n = pack_local_position(out, 0, 1, 1, LOCAL_POSITION_NED.spec, 0, x)
    sample = out[:n].tobytes()
    n = pack_attitude_quaternion(out, 0, 1, 1, ATTITUDE_QUATERNION.spec, 0, x)
    sample += out[:n].tobytes()
    read_sample(sample, 1, 1, LOCAL_POSITION_NED.spec, ATTITUDE_QUATERNION.spec, np.full(1, -1, np.int64))
    n = pack_setpoint(
        out, 0, 1, 1, SET_ATTITUDE_TARGET.spec, 0, 1, 1, x[QUAT].copy(), x[RATE].copy(), 1.0, 2.0
    )
    read_setpoint(out[:n].tobytes(), SET_ATTITUDE_TARGET.spec, 2.0)
