"""A vehicle's telemetry schedule (``vehicle.port.Streams``), its heartbeat and its flush, against what
MAVLink's MAV_CMD_SET_MESSAGE_INTERVAL says and against the schedule's own state: after any
sequence of interval changes, passes and lockstep samples, a pass sends exactly the streams due
by then, each next due at the next multiple of its period, and a sample sent alone leaves the
schedule as a pass would; the heartbeat goes out at its rate on the wall clock, whatever the steps
between looks; a flush sends every frame queued once, in order, in datagrams that fit."""

import copy
import dataclasses
import math

import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import common as mav

from sim_vehicles.common.state import make_state
from sim_vehicles.mavlink.signing import SIGNATURE_LEN, Verifier
from sim_vehicles.plant.autopilot import Autopilot
from sim_vehicles.plant.params import AttitudeGains, VehicleParams
from sim_vehicles.vehicle.endpoint import VehicleEndpoint
from sim_vehicles.vehicle.port import ATTQ_ID, LPOS_ID, MAX_DATAGRAM, EndpointStats, Port, Streams, Tlog
from sim_vehicles.vehicle.telemetry import TelemetryRates
from tests.fakes import RecordingSocket
from tests.strategies import in_range

DEFAULTS = TelemetryRates().by_message()
IDS = list(DEFAULTS)
OTHERS = [i for i in IDS if i not in (LPOS_ID, ATTQ_ID)]

#: an interval [us]: off (< 0), the default (0), under one microsecond (read as one), any other
intervals = st.one_of(in_range(-1e6, 1e7, -1.0, 0.0, 0.5, 1.0, 1.5, 2.0), st.sampled_from([-1.0, 0.0]))


@pytest.mark.unit
@given(st.sampled_from(IDS), intervals)
def test_an_interval_sets_its_streams_rate_as_mavlink_says(msg_id, interval_us):
    """-1 (any negative) turns a stream off, 0 restores its default, a positive interval is a
    rate of one per interval, and an interval under 1 us is one of 1 us; due at once either way."""
    s = Streams(DEFAULTS)
    for other in IDS:
        s.next_send[other] = 5.0  # (all sent at some earlier pass)
    s.next_any_s = s.next_other_s = 5.0
    s.set_interval(msg_id, interval_us)
    if interval_us < 0:
        want = 0.0
    elif interval_us == 0:
        want = DEFAULTS[msg_id]
    else:
        want = 1e6 / interval_us if interval_us >= 1.0 else 1e6
    assert s.rate_hz[msg_id] == pytest.approx(want, rel=1e-12)
    assert list(s.due(0.0)) == ([msg_id] if want > 0 else [])  # due now (off: never), nothing else
    assert s.next_send[msg_id] == (1.0 / want if want > 0 else math.inf)


@st.composite
def schedules(draw):
    """Operations on a schedule at non-decreasing times: an interval set, a pass, a sample."""
    t, ops = 0.0, []
    for _ in range(draw(st.integers(1, 60))):
        t += draw(st.sampled_from([0.0, 0.001, 0.01, 0.02, 0.1, 0.35, 1.0, 2.5]))
        kind = draw(st.sampled_from(["interval", "pass", "pass", "sample", "sample"]))
        arg = (draw(st.sampled_from(IDS)), draw(intervals)) if kind == "interval" else None
        ops.append((kind, round(t, 6), arg))
    return ops


@pytest.mark.unit
@settings(max_examples=300)
@given(schedules())
def test_a_pass_sends_exactly_what_is_due_whatever_came_before(ops):
    """Whatever the order of interval changes, passes and lockstep samples (the sample sent alone
    when nothing else is due): a pass sends every stream whose next instant has come, in the
    schedule's order, and none other; a stream sent at t is next due at the next multiple of its
    period after t (off: never). The schedule's shortcuts, the earliest instant of any stream and
    of any but the sample's, never pass a stream's own (a pass that looked at them first would
    skip a stream that is due)."""
    s = Streams(DEFAULTS)
    for kind, t, arg in ops:
        assert s.next_any_s <= min(s.next_send.values())
        assert s.next_other_s <= min(s.next_send[i] for i in OTHERS)
        if kind == "interval":
            s.set_interval(*arg)
            continue
        due_now = [i for i in IDS if s.next_send[i] <= t + 1e-9]
        if kind == "sample":
            # (a lockstep tick sends its sample alone, as ``lockstep_tick.usual_tick`` asks: the
            # sample due and, by the schedule, nothing else; else it makes a pass)
            alone = t + 1e-9 < s.next_other_s and LPOS_ID in due_now and ATTQ_ID in due_now
            if not alone:
                kind = "pass"
            else:
                assert not any(i in due_now for i in OTHERS)
                s.sample_sent(t)
                for i in (LPOS_ID, ATTQ_ID):
                    rate = s.rate_hz[i]
                    assert s.next_send[i] == pytest.approx((math.floor(t * rate + 1e-6) + 1) / rate)
                continue
        sent = list(s.due(t))
        assert sent == [i for i in due_now if s.rate_hz[i] > 0], (t, sent, due_now)
        for i in due_now:
            rate = s.rate_hz[i]
            if rate <= 0:
                assert s.next_send[i] == math.inf
            else:
                assert t < s.next_send[i] <= t + 1.0 / rate + 1e-9
                assert s.next_send[i] * rate == pytest.approx(round(s.next_send[i] * rate), abs=1e-6)


@pytest.mark.unit
@given(
    st.floats(0.0, 1e4),
    st.dictionaries(st.sampled_from(IDS), intervals),
    st.lists(st.floats(1e-6, 5.0), min_size=len(OTHERS), max_size=len(OTHERS)),
)
def test_a_sample_sent_alone_leaves_the_schedule_as_a_pass_would(t, intervals_us, ahead):
    """A lockstep tick that sends its sample alone (``sample_sent``) leaves the schedule exactly as
    a pass at that instant would (``due``, which then sends the sample's two and nothing else):
    whatever the rates (the sample's slower than the others' or not) and whenever the others are
    next due after it."""
    s = Streams(DEFAULTS)
    for msg_id, interval_us in intervals_us.items():
        s.set_interval(msg_id, interval_us)
    s.set_interval(ATTQ_ID, 1e6 / s.rate_hz[LPOS_ID] if s.rate_hz[LPOS_ID] > 0 else -1.0)
    assume(s.rate_hz[LPOS_ID] > 0)
    s.next_send[LPOS_ID] = s.next_send[ATTQ_ID] = t  # the sample is due, and nothing else
    for msg_id, dt in zip(OTHERS, ahead, strict=True):
        s.next_send[msg_id] = t + dt if s.rate_hz[msg_id] > 0 else math.inf
    s.next_any_s = t
    s.next_other_s = min(s.next_send[i] for i in OTHERS)
    a, b = copy.deepcopy(s), copy.deepcopy(s)
    a.sample_sent(t)
    assert list(b.due(t)) == [i for i in IDS if i in (LPOS_ID, ATTQ_ID)]
    assert (a.next_send, a.next_any_s, a.next_other_s) == (b.next_send, b.next_any_s, b.next_other_s)


@pytest.mark.integration  # (an endpoint driven in process)
@given(
    st.floats(0.2, 50.0),
    st.lists(st.floats(0.0, 0.3), min_size=1, max_size=200),
)
def test_the_heartbeat_goes_out_at_its_rate_on_the_wall_clock(rate_hz, steps):
    """Looked at every so often (any steps of wall time): a heartbeat at the first look, then at
    the first look at least a period after the last one sent; none with a rate of 0."""
    ap = Autopilot(
        VehicleParams(0.85, (0.05, 0.05, 0.09), 25.0),
        AttitudeGains(16.0, 16.0),
        make_state([0.0, 0.0, 10.0]),
        0.001,
    )
    for hz in (rate_hz, 0.0):
        ep = VehicleEndpoint(ap, 3, rates=dataclasses.replace(TelemetryRates(), heartbeat_hz=hz))
        try:
            ep.port.sock.close()
            ep.port.sock = rec = RecordingSocket()  # type: ignore[assignment]
            ep.port.peer = ("127.0.0.1", 40001)
            times, now = [], 100.0
            for dt in steps:
                now += dt
                times.append(now)
            beats, last = [], -math.inf
            for now in times:
                before = len(rec.sent)
                ep.heartbeat_tick(now)
                if len(rec.sent) > before:
                    beats.append(now)
                    parsed = mav.MAVLink(None).parse_buffer(rec.sent[-1])
                    assert parsed and parsed[0].get_type() == "HEARTBEAT"
            if hz == 0.0:
                assert beats == []
                continue
            want = []
            for t in times:
                if t >= last:
                    want.append(t)
                    last = t + 1.0 / hz
            assert beats == want
        finally:
            ep.close()


@pytest.mark.unit
@settings(max_examples=40, deadline=None)
@given(st.integers(1, 120), st.sampled_from([None, b"k" * 32]), st.integers(0, 2**31))
def test_a_flush_sends_every_queued_frame_once_in_order_in_datagrams_that_fit(n_frames, key, ms):
    """However many frames a pass queues: each sent once, in the order queued, in datagrams of at
    most ``MAX_DATAGRAM`` bytes (one when they fit), each frame whole and, on a signed link,
    signed; counted as sent."""
    stats = EndpointStats()
    port = Port(
        ("127.0.0.1", 0), 3, DEFAULTS, stats, Tlog(None), remote=("127.0.0.1", 40001), signing_key=key
    )
    try:
        port.sock.close()
        port.sock = rec = RecordingSocket()  # type: ignore[assignment]
        sent = [ms + j for j in range(n_frames)]
        for t in sent:
            port.send(port.mav.system_time_encode(t, t % 1000))
        queued = sum(len(f) + (SIGNATURE_LEN if key else 0) for f in port.sink.frames)
        port.flush()
        assert port.sink.frames == [] and stats.tx_messages == n_frames
        assert all(len(d) <= MAX_DATAGRAM for d in rec.sent)
        if queued <= MAX_DATAGRAM:
            assert len(rec.sent) == 1
        verifier = Verifier(key) if key else None
        got = []
        for d in rec.sent:
            if verifier is not None:
                d = verifier.open(d)
                assert d is not None  # every frame signed, each datagram opens whole
            msgs = mav.MAVLink(None).parse_buffer(d) or []
            got += [m.time_unix_usec for m in msgs]
        assert got == sent
    finally:
        port.close()
