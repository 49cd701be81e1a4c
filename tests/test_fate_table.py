"""A lockstep link's fates drawn a block of ticks at a time (``faults.fate_table``) against
``plan.fate`` asked message by message: the same fate, field for field and bit for bit, for
random plans of every kind a table draws (several entries on one link, each in its window), on
an edge (keyed by step) and on a MAVLink link (keyed by ``time_boot_ms``), across block edges."""

import math

import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from swarm_sitl.faults.fate_table import BLOCK, FateTable, batched
from swarm_sitl.faults.plan import FaultEntry, edge_channel, fate, mavlink_channel

PERIOD_S = 0.01  #: the paper's control period
END_S = 12.0  #: the run's end: past two blocks of ticks
probability = st.floats(0.01, 1.0)
hows = st.one_of(
    st.just({"drop": True}),
    st.builds(lambda p: {"loss": p}, probability),
    st.builds(lambda p: {"duplicate": p}, probability),
    st.builds(lambda p: {"corrupt": p}, probability),
    st.builds(lambda p: {"reorder": p}, probability),
    st.builds(lambda d, j: {"delay_s": d, "jitter_s": j}, st.floats(0.0, 0.5), st.floats(0.0, 0.2)),
    st.builds(
        lambda p, r, lb, lg: {"bursty": {"p": p, "r": r, "loss_bad": lb, "loss_good": lg}},
        probability,
        probability,
        st.floats(0.5, 1.0),
        st.floats(0.0, 0.3),
    ),
    st.builds(lambda b: {"bandwidth": {"rate_bps": b}}, st.floats(2000.0, 1e5)),
)
#: a window in seconds (``from_s``, ``until_s``; None: to the run's end); a stall needs its end
windows = st.tuples(st.floats(0.0, 6.0), st.one_of(st.none(), st.floats(6.01, 11.0)))


def _entry(how: dict, window: tuple[float, float | None], what: dict) -> FaultEntry:
    frm, until = window
    if "bandwidth" in how:  # (a sending node's radio: every edge out of the edge's sender)
        what = {"out_of": 2}
    return FaultEntry.model_validate({**what, **how, "from_s": frm, "until_s": until})


def _same(a, b) -> bool:
    fields = ("lost", "corrupt", "duplicate", "out_of_range", "retried")
    return all(getattr(a, f) == getattr(b, f) for f in fields) and (a.lost or a.delay_s == b.delay_s)


@pytest.mark.unit
@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**63 - 1),
    plan=st.lists(st.tuples(hows, windows), min_size=1, max_size=4),
    stall=st.booleans(),
    first=st.integers(0, 3 * BLOCK),
    back=st.lists(st.integers(0, 2 * BLOCK), max_size=5),
)
def test_an_edges_table_gives_each_step_the_fate_plan_fate_gives_it(seed, plan, stall, first, back):
    """From any first tick (a node restarted mid-block), in order, and with steps back (a message
    delayed past later ones, any distance back): each tick's fate is ``plan.fate``'s."""
    what = {"edge": (2, 3)}
    rules = [(j, _entry(how, w, what)) for j, (how, w) in enumerate(plan)]
    if stall:  # (a stall's delay is its end less the message's time)
        rules.append((len(rules), _entry({"stall": True}, (1.0, 7.5), what)))
    assert batched(rules)
    channel = edge_channel(2, 3)
    table = FateTable(seed, rules, channel, END_S, PERIOD_S)
    n = math.ceil(END_S / PERIOD_S) + BLOCK  # (past the run's end: every entry off)
    ticks = list(range(min(first, n - 1), n))
    for i, b in enumerate(back):  # a step back at evenly spread points of the walk
        at = len(ticks) * (i + 1) // (len(back) + 1)
        ticks.insert(at, max(0, ticks[at] - b))
    for k in ticks:
        want = fate(seed, rules, channel, k, k * PERIOD_S, END_S, PERIOD_S)
        assert _same(table.at(k), want), (k, table.at(k), want)


@pytest.mark.unit
@settings(max_examples=25, deadline=None)
@given(
    seed=st.integers(0, 2**63 - 1),
    plan=st.lists(
        st.tuples(
            st.one_of(
                st.just({"drop": True}),
                st.builds(lambda p: {"loss": p}, probability),
                st.builds(lambda p: {"corrupt": p}, probability),
                st.builds(lambda p, r: {"bursty": {"p": p, "r": r}}, probability, probability),
                st.builds(lambda p: {"reorder": p}, probability),
                st.builds(lambda p: {"duplicate": p}, probability),
            ),
            windows,
        ),
        min_size=1,
        max_size=3,
    ),
    period_ms=st.sampled_from([4, 10, 20, 33, 500, 1000]),
)
@example(seed=1, plan=[({"bursty": {"p": 0.5, "r": 0.5}}, (0.0, None))], period_ms=1000)  # (a chain at 1 Hz)
def test_a_mavlink_links_table_gives_each_datagram_the_fate_keyed_by_its_time_boot_ms(seed, plan, period_ms):
    period_s = period_ms / 1000
    rules = [(j, _entry(how, w, {"mavlink": 2, "direction": "up"})) for j, (how, w) in enumerate(plan)]
    channel = mavlink_channel(2, True)
    table = FateTable(seed, rules, channel, END_S, period_s, stamp_ms=True)
    for k in range(math.ceil(END_S / period_s) + 2):
        ms = round(k * period_s * 1000)
        # keyed by its time_boot_ms, and the k-th datagram of its stream (a burst chain's step)
        want = fate(seed, rules, channel, ms, ms / 1000, END_S, period_s, k)
        assert _same(table.at(k), want), (k, ms)


@pytest.mark.unit
def test_a_model_that_needs_the_distance_or_draws_one_at_a_time_has_no_table():
    ranged = FaultEntry.model_validate({"edge": (1, 2), "range": {"range_m": 50}})
    lossy = FaultEntry.model_validate({"edge": (1, 2), "loss": 0.5})
    assert batched([(0, lossy)]) and not batched([(0, lossy), (1, ranged)])

    class OneAtATime:  # a user's model without ``fates``: the contract's required part only
        def fate(self, p, m):
            return None

    user = lossy.model_copy()
    user.__dict__["link_how"] = (OneAtATime(), None)  # (``link_how`` is cached in the instance)
    assert not batched([(0, user)])
