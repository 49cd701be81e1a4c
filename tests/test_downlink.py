"""What a controller reads from its vehicle (``link.decoding.Downlink``), whichever way a sample
comes: alone in a datagram (the compiled read), beside other messages or split across datagrams
(the split read), or on a stream through pymavlink's parser. The three ways give the same sample,
the vehicle's NED/FRD float32 fields in ENU/FLU, stamped with its ``time_boot_ms`` and the arrival
of the datagram that completed it; a vehicle that reboots or disarms is ``gone``, and each bad
frame, and a last one cut short, is counted once; another dialect's message is passed over."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega
from pymavlink.dialects.v20 import common as mav

from sim_vehicles.mavlink.enu_ned import ned_to_enu, q_ned_frd_to_enu_flu
from swarm_sitl.link.decoding import REBOOT_MS, Downlink
from tests.strategies import unit_quaternions
from tests.support import raw_frame

pytestmark = pytest.mark.unit
SYS = 4
coords = st.floats(-1e3, 1e3).map(lambda x: float(np.float32(x)))


def _link(sysid: int = SYS, compid: int = 1) -> mav.MAVLink:
    return mav.MAVLink(None, srcSystem=sysid, srcComponent=compid)


def _lpos(ms: int, p, v, sysid: int = SYS, compid: int = 1) -> bytes:
    return bytes(mav.MAVLink_local_position_ned_message(ms, *p, *v).pack(_link(sysid, compid)))


def _attq(ms: int, q, sysid: int = SYS, compid: int = 1) -> bytes:
    m = mav.MAVLink_attitude_quaternion_message(ms, *q, 0.0, 0.0, 0.0, [0.0, 0.0, 0.0, 0.0])
    return bytes(m.pack(_link(sysid, compid)))


def _heartbeat(armed: bool) -> bytes:
    flags = mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (mav.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0)
    m = mav.MAVLink_heartbeat_message(mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_PX4, flags, 0, 4, 3)
    return bytes(m.pack(_link()))


def _downlink(whole: bool = True) -> Downlink:
    parser = mav.MAVLink(None)
    parser.robust_parsing = True
    return Downlink(SYS, parser, whole)


samples = st.tuples(
    st.integers(0, 2**31),
    st.tuples(coords, coords, coords),
    st.tuples(coords, coords, coords),
    unit_quaternions().map(lambda q: tuple(float(np.float32(x)) for x in q)),
)


@given(samples, st.floats(0.0, 1e6), st.floats(0.0, 1e6))
def test_a_sample_reads_the_same_alone_beside_others_split_or_on_a_stream(sample, t1, t2):
    ms, p, v, q = sample
    lpos, attq = _lpos(ms, p, v), _attq(ms, q)
    want_p, want_v = ned_to_enu(np.array(p)), ned_to_enu(np.array(v))
    want_q = q_ned_frd_to_enu_flu(np.array(q))

    alone = _downlink()
    assert alone.read(lpos + attq, t1) == (2, ms)  # (the sample alone: its time)
    beside = _downlink()
    assert beside.read(_heartbeat(False) + lpos + attq, t1) == (3, -1)
    split = _downlink()
    assert split.read(attq, t2) == (1, -1) and split.sample_ms == -1  # (half a sample: none yet)
    assert split.read(lpos, t1) == (1, -1)
    stream = _downlink(whole=False)
    assert stream.read(lpos, t2) == (1, -1) and stream.read(attq, t1) == (1, -1)
    for d in (alone, beside, split, stream):
        t_s, p_W, v_W, q_WB = d.sample()
        assert t_s == ms / 1000.0 and d.sample_ms == ms and d.sample_arrival_mono == t1
        assert np.allclose(p_W, want_p, rtol=0, atol=1e-12) and np.allclose(v_W, want_v, rtol=0, atol=1e-12)
        assert np.allclose(q_WB, want_q, atol=1e-7) or np.allclose(q_WB, -want_q, atol=1e-7)
        assert np.array_equal(d.sample_fields, alone.sample_fields)  # the same bits every way
        assert d.gone == "" and d.rx_bad == 0


@given(samples, st.sampled_from([(SYS + 1, 1), (SYS, 191), (1, 1)]), st.booleans())
def test_a_sample_from_another_system_or_component_is_not_the_vehicles(sample, sender, whole):
    ms, p, v, q = sample
    d = _downlink(whole)
    d.read(_lpos(ms, p, v, *sender) + _attq(ms, q, *sender), 1.0)
    assert d.sample_ms == -1


@given(st.integers(REBOOT_MS + 10, 2**31), st.integers(1, REBOOT_MS + 5), st.booleans())
def test_a_clock_gone_back_over_reboot_ms_is_a_reboot_and_a_held_back_sample_is_not(ms, back, whole):
    """A sample older than the newest is one a fault held back (dropped, nothing else); older by
    more than ``REBOOT_MS``, the vehicle's clock started again: it rebooted."""
    d = _downlink(whole)
    z, q = (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0)
    d.read(_lpos(ms, z, z), 1.0)
    d.read(_attq(ms, q), 1.0)
    d.read(_lpos(ms - back, z, z), 2.0)
    d.read(_attq(ms - back, q), 2.0)
    assert d.sample_ms == ms and d.sample_arrival_mono == 1.0  # (never taken)
    if back > REBOOT_MS:
        assert d.gone == f"it rebooted (its time_boot_ms went from {ms} to {ms - back})"
    else:
        assert d.gone == ""


@given(st.lists(st.booleans(), max_size=8), st.booleans())
def test_a_vehicle_is_gone_once_it_disarms_after_it_was_armed(armed, whole):
    d = _downlink(whole)
    seen_armed, want = False, ""
    for a in armed:
        d.read(_heartbeat(a), 0.0)
        if seen_armed and not a:
            want = "it disarmed (its HEARTBEAT)"
        seen_armed = seen_armed or a
        assert d.gone == want, armed


@given(st.integers(0, 5), samples, st.integers(0, len(_heartbeat(True)) - 1))
def test_each_bad_frame_is_counted_once_and_the_good_ones_still_read(n_bad, sample, cut):
    """Frames whose CRC is broken, then a sample, then (``cut`` > 0) a last frame cut short after
    ``cut`` bytes: each bad frame and the cut one counted once, the sample read."""
    ms, p, v, q = sample
    bad = bytearray(_heartbeat(True))
    bad[-1] ^= 0xFF  # its CRC
    d = _downlink()
    d.read(bytes(bad) * n_bad + _lpos(ms, p, v) + _attq(ms, q) + _heartbeat(True)[:cut], 3.0)
    assert d.rx_bad == n_bad + (cut > 0) and d.sample_ms == ms and d.heartbeat is None


#: the messages of ArduPilot's dialect that the common set does not have (AHRS, EKF_STATUS_REPORT, ...)
ARDUPILOT_ONLY = sorted(
    (c for i, c in ardupilotmega.mavlink_map.items() if i not in mav.mavlink_map), key=lambda c: c.id
)


@given(st.data(), samples, st.booleans(), st.sampled_from([SYS, 1, 200]))
def test_another_dialects_message_is_passed_over_not_counted_bad_whichever_read_takes_it(
    data, sample, whole, sender
):
    """A message of a dialect the controller does not read (an ArduPilot SITL streams AHRS,
    EKF_STATUS_REPORT and more beside the common set), well formed, from the vehicle or anyone,
    beside the sample: the sample is read and nothing is counted bad, on a datagram read whole
    (its CRC cannot be checked without the message's CRC extra) as on a stream (where pymavlink
    passes it as an unknown message)."""
    cls = data.draw(st.sampled_from(ARDUPILOT_ONLY))
    other = raw_frame(cls, data.draw(st.binary(min_size=1, max_size=cls.unpacker.size)), sysid=sender)
    ms, p, v, q = sample
    d = _downlink(whole)
    d.read(other + _lpos(ms, p, v) + other + _attq(ms, q), 3.0)
    assert d.rx_bad == 0 and d.sample_ms == ms
