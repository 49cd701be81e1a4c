"""Fuzzing a controller's zenoh subscription: follower 4's in-edge from follower 1, as its bus reads it.

Every input is put on the edge key through a real zenoh session and read by the bus's ``poll``:
each one is either taken (exactly when an oracle written here from the documented layout says it
is a well-formed message of 12 values from node 1 that can follow the last one taken) or dropped
and counted,
and the bus's table changes only when one is taken. Each example is a sequence of 1 to 8 inputs
on a fresh bus; ``SWARM_SITL_FUZZ_EXAMPLES`` sets the number of examples (``tests/strategies.py``).
"""

import math
import struct
import time
import zlib

import pytest
from hypothesis import event, given
from hypothesis import strategies as st

from swarm_sitl.bus import keys as zenoh_keys
from swarm_sitl.bus.node_bus import ZenohNodeBus
from swarm_sitl.bus.session import ZenohSection, open_session
from tests.strategies import FUZZ, FUZZ_TIMEOUT

pytestmark = pytest.mark.unit
HEAD = struct.Struct("<BHId3dH")  # version, src, step, t_s, p_W, n; then n float64 values and a CRC-32
VERSION = 4
LENGTH = 12  #: what node 4's bus takes from node 1 (a law whose messages have 12 values)
HORIZON = 6000


def _estimate(
    src: int, step: int, values: list[float], version: int = VERSION, n: int | None = None
) -> bytes:
    """A message as the documented layout has it; ``n``: the count it claims (default: its own)."""
    body = HEAD.pack(version, src, step, step * 0.01, 1.0, -2.0, 3.0, len(values) if n is None else n)
    body += struct.pack(f"<{len(values)}d", *values)
    return body + struct.pack("<I", zlib.crc32(body))


def _takes(data: bytes, last: int) -> int | None:
    """The step the bus must take ``data`` as, or None: the oracle."""
    if len(data) < HEAD.size + 4:
        return None
    version, src, step, t_s, _, _, _, n = HEAD.unpack_from(data)
    if len(data) != HEAD.size + 8 * n + 4 or version != VERSION or n != LENGTH:
        return None
    values = struct.unpack_from(f"<{n}d", data, HEAD.size)
    if zlib.crc32(data[:-4]) != struct.unpack("<I", data[-4:])[0]:
        return None
    if not all(map(math.isfinite, (t_s, *values))):
        return None
    return step if src == 1 and last < step <= HORIZON else None


floats = st.one_of(st.floats(-1e3, 1e3), st.sampled_from([math.nan, math.inf, -math.inf, 1e308]))
finite12 = st.lists(st.floats(-1e3, 1e3), min_size=12, max_size=12)
#: values of another length than the receiver takes (another law's, or a broken sender's)
other_lengths = st.lists(st.floats(-1e3, 1e3), min_size=0, max_size=20).filter(lambda v: len(v) != LENGTH)
#: a step: this far from the last one taken (most), or anywhere in the run, or far past it
steps = st.one_of(
    st.tuples(st.just("near"), st.integers(-3, 3)),
    st.tuples(st.just("at"), st.integers(0, HORIZON + 5)),
    st.tuples(st.just("at"), st.sampled_from([2**32 - 1, 2**31])),
)
#: what to put, as a function of the last step taken (hypothesis draws it without knowing that)
inputs = st.one_of(
    st.tuples(st.just("bytes"), st.binary(max_size=200)),
    st.tuples(st.just("valid"), steps, finite12),  # from node 1, well formed
    st.tuples(
        st.just("estimate"),  # any sender, any version, any length, values finite or not
        steps,
        st.one_of(finite12, st.lists(floats, min_size=12, max_size=12), other_lengths),
        st.sampled_from([1, 0, 2, 4, 65535]),
        st.sampled_from([4, 4, 4, 0, 1, 3, 255]),
        st.sampled_from([None, None, None, 0, 11, 12, 13, 65535]),  # the count it claims
    ),
    st.tuples(
        st.just("mutated"),
        steps,
        finite12,
        st.lists(st.tuples(st.integers(0, 140), st.integers(0, 255)), min_size=1, max_size=4),
        st.integers(0, 141),  # cut short, or whole
    ),
)


def _payload(spec: tuple, last: int) -> bytes:
    kind = spec[0]
    if kind == "bytes":
        return spec[1]
    how, n = spec[1]
    step = max(0, last + n) if how == "near" else n
    if kind == "valid":
        return _estimate(1, step, spec[2])
    if kind == "estimate":
        return _estimate(spec[3], step, spec[2], spec[4], spec[5])
    b = bytearray(_estimate(1, step, spec[2]))
    for j, v in spec[3]:
        b[j % len(b)] = v
    return bytes(b[: spec[4]])


@pytest.fixture(scope="module")
def session():
    s = open_session(ZenohSection(mode="peer", listen=[]))
    yield s
    s.close()


def _counted(bus: ZenohNodeBus) -> int:
    return bus.dropped + sum(bus.refused.values()) + sum(bus.received.values())


KEY = zenoh_keys.edge("fuzz", 1, 4)


@FUZZ_TIMEOUT
@FUZZ
@given(specs=st.lists(inputs, min_size=1, max_size=8))
def test_fuzz_every_payload_on_an_in_edge_is_taken_exactly_when_valid_or_counted(session, specs):
    """A sequence of inputs on a fresh bus (a sender's whole life: the rule looks at the last one)."""
    bus = ZenohNodeBus(session, "fuzz", 4, [1], [])
    bus.horizon = lambda: HORIZON
    try:
        for spec in specs:
            _one(session, bus, spec)
    finally:
        bus.close()


def _one(session, bus: ZenohNodeBus, spec: tuple) -> None:
    before = _counted(bus)
    latest = bus.latest(1)
    data = _payload(spec, -1 if latest is None else latest.step)
    expect = _takes(data, -1 if latest is None else latest.step)
    event("taken" if expect is not None else "dropped")
    session.put(KEY, data)
    end = time.monotonic() + 5.0
    while _counted(bus) == before:
        assert time.monotonic() < end, "the payload was neither taken nor counted"
        bus.poll()
    assert _counted(bus) == before + 1
    now = bus.latest(1)
    if expect is None:
        assert now is latest, "an invalid payload changed what the bus holds"
    else:
        assert now is not None and now.step == expect and bus.estimate(1, expect) is now
        assert now.values.tobytes() == data[HEAD.size : -4]
