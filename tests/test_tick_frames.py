"""The per-tick frames in one compiled call (``sim_vehicles.mavlink.tick_frames``) against pymavlink and an
independent reference of the wire conversions (Python floats through ``struct``'s float32)."""

import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import common as mav

from sim_vehicles.mavlink import frames
from sim_vehicles.mavlink import tick_frames as tf
from sim_vehicles.mavlink.enu_ned import swap_frames_wxyz
from sim_vehicles.mavlink.wire_format import AttitudeTargetFields, decode_attitude_target
from tests.fakes import FrameSink
from tests.strategies import unit_quaternions, vec3

pytestmark = pytest.mark.unit

LPOS, ATTQ, SETPOINT = frames.LOCAL_POSITION_NED, frames.ATTITUDE_QUATERNION, frames.SET_ATTITUDE_TARGET
time_ms = st.integers(0, 2**32 - 1)
#: a reader that reads the sample and HEARTBEAT, and only counts ATTITUDE and HIGHRES_IMU
IGNORED = np.full(200, -1, dtype=np.int64)
for _cls in (mav.MAVLink_attitude_message, mav.MAVLink_highres_imu_message):
    IGNORED[_cls.id] = _cls.crc_extra


def _f32(*values: float) -> tuple[float, ...]:
    return struct.unpack(f"<{len(values)}f", struct.pack(f"<{len(values)}f", *values))


def _state(p, v, q, w) -> np.ndarray:
    return np.concatenate([p, v, q, w])


def _reference_sample_frames(x: np.ndarray, ms: int, seq: int) -> tuple[bytes, bytes]:
    """What the vehicle must send for state ``x``, built by pymavlink from fields computed here."""
    ref = mav.MAVLink(FrameSink(), 3, 1)
    ref.seq = seq
    ref.local_position_ned_send(ms, *_f32(x[1], x[0], -x[2], x[4], x[3], -x[5]))
    q = swap_frames_wxyz(*x[6:10].tolist())
    ref.attitude_quaternion_send(ms, *_f32(*q, x[10], -x[11], -x[12]))
    a, b = ref.file.frames
    return a, b


@settings(max_examples=200, deadline=None)
@given(vec3, vec3, unit_quaternions(), vec3, time_ms, st.integers(0, 255))
def test_sample_frames_are_pymavlinks_and_read_back_as_the_float32_state(p, v, q, w, ms, seq):
    x = _state(p * 100, v, q, w)
    ref_lpos, ref_attq = _reference_sample_frames(x, ms, seq)
    out = np.full(tf.FRAME_BYTES, 0xAA, np.uint8)  # what was there before must not leak in
    n = tf.pack_local_position(out, seq, 3, 1, LPOS.spec, ms, x)
    assert out[:n].tobytes() == ref_lpos
    n = tf.pack_attitude_quaternion(out, (seq + 1) % 256, 3, 1, ATTQ.spec, ms, x)
    assert out[:n].tobytes() == ref_attq

    for datagram in (ref_lpos + ref_attq, ref_attq + ref_lpos):
        got = tf.read_sample(datagram, 3, 1, LPOS.spec, ATTQ.spec, IGNORED)
        assert got[tf.RS_OK] == 1 and got[tf.RS_TIME_MS] == ms
        assert (got[tf.RS_FRAMES], got[tf.RS_BAD]) == (2, 0)
        sample = got[tf.RS_SAMPLE]
        assert sample[0:6].tolist() == [*_f32(*x[0:6])]  # NED and back: exact, at float32
        q_back = sample[6:10]
        assert abs(np.linalg.norm(q_back) - 1) < 1e-15
        assert min(np.abs(q_back - q).max(), np.abs(q_back + q).max()) < 1e-6


def test_read_sample_counts_the_telemetry_it_ignores_and_leaves_the_rest_to_the_general_path():
    x = _state(np.array([1.0, 2.0, 3.0]), np.zeros(3), np.array([1.0, 0, 0, 0]), np.zeros(3))
    lpos, attq = _reference_sample_frames(x, 40, 0)
    later, _ = _reference_sample_frames(x, 50, 2)
    other = mav.MAVLink(FrameSink(), 3, 1)
    other.heartbeat_send(mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_GENERIC, 0, 0, 0)
    other.attitude_send(40, 0.1, 0.2, 0.3, 0.0, 0.0, 0.0)
    other.sys_status_send(0, 0, 0, 0, 12000, -1, -1, 0, 0, 0, 0, 0, 0)  # not in IGNORED: unknown here
    hb, attitude, unknown = other.file.frames
    bad_attitude = attitude[:-1] + bytes([attitude[-1] ^ 0xFF])
    corrupt = bytearray(lpos)
    corrupt[12] ^= 0x10

    def read(datagram: bytes, sysid: int = 3) -> tuple[float, float, float]:
        got = tf.read_sample(datagram, sysid, 1, LPOS.spec, ATTQ.spec, IGNORED)
        return got[tf.RS_OK], got[tf.RS_FRAMES], got[tf.RS_BAD]

    assert read(lpos + attq) == (1, 2, 0)
    assert read(attitude + lpos + attq) == (1, 3, 0)  # counted, not read
    assert read(lpos + bad_attitude + attq) == (1, 3, 1)  # counted as bad
    assert read(lpos + attq, sysid=4)[0] == 0  # another vehicle's
    assert read(lpos)[0] == 0 and read(attq)[0] == 0  # half a sample
    assert read(later + attq)[0] == 0  # two instants
    assert read(lpos + attq + hb)[0] == 0  # a message the reader reads
    assert read(lpos + attq + unknown)[0] == 0  # one it does not know
    assert read(lpos + attq + lpos)[0] == 0  # a second sample message
    assert read(bytes(corrupt) + attq)[0] == 0  # bad CRC of the sample
    assert read((lpos + attq)[:-1])[0] == 0 and read(b"")[0] == 0


@settings(max_examples=200, deadline=None)
@given(unit_quaternions(), vec3, st.floats(-10.0, 40.0), time_ms, st.integers(0, 255))
def test_setpoint_frame_is_pymavlinks_and_the_vehicle_reads_the_command_sim_uses(q_c, w, thrust, ms, seq):
    out = np.zeros(tf.FRAME_BYTES, np.uint8)
    n = tf.pack_setpoint(out, seq, 7, 191, SETPOINT.spec, ms, 7, 1, q_c, w, thrust, 25.0)
    frame = out[:n].tobytes()

    fields = _f32(*swap_frames_wxyz(*q_c.tolist()), w[0], -w[1], -w[2], min(max(thrust / 25.0, 0.0), 1.0))
    ref = mav.MAVLink(FrameSink(), 7, 191)
    ref.seq = seq
    ref.set_attitude_target_send(ms, 7, 1, 0, list(fields[0:4]), *fields[4:8])
    assert frame == ref.file.frames[0]

    got = tf.read_setpoint(frame, SETPOINT.spec, 25.0)
    assert got[0] == 1
    assert got[[tf.SP_SYSID, tf.SP_COMPID, tf.SP_TIME_MS, tf.SP_TARGET_SYSTEM]].tolist() == [7, 191, ms, 7]
    assert got[[tf.SP_TARGET_COMPONENT, tf.SP_TYPE_MASK]].tolist() == [1, 0]
    cmd = decode_attitude_target(AttitudeTargetFields(fields[0:4], fields[4:7], fields[7]), 25.0)
    command = got[tf.SP_COMMAND]
    assert command[0:4].tolist() == cmd.q_c.tolist()
    assert command[4:7].tolist() == cmd.omega_c_B.tolist()
    assert command[7] == cmd.thrust_N and command[8] == 1.0


def test_read_setpoint_takes_one_whole_frame_and_flags_a_bad_quaternion():
    ref = mav.MAVLink(FrameSink(), 7, 191)
    ref.set_attitude_target_send(10, 7, 1, 0, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, 0.5)
    ref.set_attitude_target_send(10, 7, 1, 0, [0.5, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, 0.5)
    good, not_unit = ref.file.frames

    def read(datagram: bytes) -> np.ndarray:
        return tf.read_setpoint(datagram, SETPOINT.spec, 25.0)

    assert read(good)[0] == 1 and read(good)[tf.SP_COMMAND][8] == 1.0
    assert read(not_unit)[0] == 1 and read(not_unit)[tf.SP_COMMAND][8] == 0.0  # read, then refused
    assert read(good + good)[0] == 0  # more than one frame: the general path
    assert read(good[:-1])[0] == 0
    assert read(good[:-1] + bytes([good[-1] ^ 1]))[0] == 0  # bad CRC
    lpos, _ = _reference_sample_frames(np.zeros(13), 10, 0)
    assert read(lpos)[0] == 0  # another message
