"""Where a node takes up the swarm's clock (``bus.clock.join_tick``), and the verdict on the
followers after a planned restart (``rundir.rejoins``), against closed forms on made-up traces."""

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from swarm_sitl.bus.clock import join_tick
from swarm_sitl.laws.graph import Graph
from swarm_sitl.rundir.metrics import bound_failures
from swarm_sitl.rundir.rejoins import REJOIN_ERROR_M, dependants, judge_rejoins, rejoin_lines

pytestmark = pytest.mark.unit
DT = 0.01
PAPER = Graph.from_edges(4, [(0, 1), (0, 2), (0, 3), (1, 4), (2, 4)])


@given(
    st.floats(-2.0, 3600.0),
    st.floats(0.0, 0.0099),
    st.sampled_from([0.01, 0.02, 0.004]),
    st.floats(0.0, 0.5),
)
def test_a_node_joins_at_the_first_tick_at_least_its_lead_ahead(now_s, phase_s, dt, lead_s):
    epoch = 1000.0
    k = join_tick(epoch + now_s, epoch, phase_s, dt, lead_s)
    instant = lambda j: epoch + j * dt + phase_s  # noqa: E731
    assert k >= 0
    assert instant(k) >= epoch + now_s + lead_s - 1e-6  # not in the past, nor within the lead
    if k > 0:
        assert instant(k - 1) < epoch + now_s + lead_s + 1e-6  # the first such tick


def test_a_node_with_the_start_signal_before_the_epoch_starts_at_tick_0_and_a_restart_where_the_clock_is():
    assert join_tick(99.5, 100.0, 0.0025, DT, 0.1) == 0  # the start signal comes 0.5 s ahead
    # 11.003 s into the run, ticks at k * 10 ms + 2.5 ms, 0.1 s to arm first: tick 1111 (11.1125 s)
    assert join_tick(111.003, 100.0, 0.0025, DT, 0.1) == 1111


def test_what_depends_on_a_process_follows_the_graph():
    assert dependants(PAPER, "controller_2") == [2, 4]
    assert dependants(PAPER, "controller_4") == [4]
    assert dependants(PAPER, "leader") == [1, 2, 3, 4]
    assert dependants(PAPER, "vehicle_2") == []  # a vehicle is lost, not restarted
    ring = Graph.from_edges(3, [(0, 1), (1, 2), (2, 3), (3, 1)])
    assert dependants(ring, "controller_2") == [1, 2, 3]  # a cycle carries it round


def _decay(t_r: float, e0: float, tau: float, end_s: float) -> dict[str, np.ndarray]:
    """A follower whose error is 1 mm until ``t_r``, then ``e0 exp(-(t - t_r) / tau)``."""
    t = np.arange(round(end_s / DT) + 1) * DT
    e = np.where(t < t_r, 1e-3, e0 * np.exp(-(t - t_r) / tau))
    return {"t_s": t, "pos_err_m": np.stack([e, 0 * e, 0 * e], axis=1)}


def _restart(process: str, t_s: float) -> list[dict]:
    return [
        {"t_s": t_s - 1, "kind": "process_killed", "process": process},
        {"t_s": t_s, "kind": "process_restarted", "process": process},
    ]


@pytest.mark.parametrize("bound_m", [None, 0.05, 0.005])
@pytest.mark.parametrize("tau", [0.5, 2.0])
def test_back_is_the_first_instant_the_error_stays_within_the_bound_after_the_restart(bound_m, tau):
    t_r, e0, end = 11.0, 25.0, 40.0
    followers = {i: _decay(t_r, e0, tau, end) for i in (1, 2, 3, 4)}
    (r,) = judge_rejoins(followers, _restart("controller_2", t_r), PAPER, end, bound_m, 10.0, set())
    bound = REJOIN_ERROR_M if bound_m is None else bound_m
    exact = tau * math.log(e0 / bound)  # e0 exp(-x / tau) = bound
    assert r["bound_m"] == bound and r["window_s"] == end - t_r and set(r["followers"]) == {"2", "4"}
    for f in r["followers"].values():
        assert exact <= f["back_after_s"] < exact + DT + 1e-9  # the first grid instant past it
        assert f["verdict"] == ("rejoined" if exact <= 10.0 else "did not rejoin")
        assert f["error_at_end_m"] == pytest.approx(e0 * math.exp(-(end - t_r) / tau))


def test_a_follower_that_never_comes_back_is_named_and_fails_a_run_with_a_bound():
    t_r, end = 11.0, 25.0
    stuck = _decay(t_r, 25.5, math.inf, end)  # 25.5 m from the restart on
    followers = {i: _decay(t_r, 1.0, 0.3, end) for i in (1, 3, 4)} | {2: stuck}
    events = _restart("controller_2", t_r)
    summary = {"rejoins": judge_rejoins(followers, events, PAPER, end, None, 10.0, set())}
    lines, failures = rejoin_lines(summary)
    assert failures == [
        "did not rejoin: follower 2, 25.5 m at the end (controller_2 restarted at 11 s; "
        "not within 0.1 m for good within run.rejoin_within_s = 10 s)"
    ]
    # follower 4: 1 m exp(-x / 0.3 s) is 0.1 m at x = 0.3 ln 10 = 0.69 s: back at the next tick
    assert lines == ["  controller_2 restarted at 11 s: back within 0.1 m: follower 4 after 0.70 s"]
    # with a bound the same follower fails the run; nothing else does (all within it after 20 s)
    with_bound = {
        "swarm": {"settle_from_s": 20.0},
        "followers": {str(i): {"peak_pos_err_after_settle_m": 0.0} for i in (1, 3, 4)}
        | {"2": {"peak_pos_err_after_settle_m": 0.0}},
        "rejoins": judge_rejoins(followers, events, PAPER, end, 0.3, 10.0, set()),
    }
    assert [x.split(",")[0] for x in bound_failures(with_bound, 0.3)] == ["did not rejoin: follower 2"]
    assert bound_failures(summary | {"swarm": {"settle_from_s": 0}, "followers": {}}, None) == []


def test_a_window_cut_short_is_not_judged_and_a_lost_vehicle_or_a_skipped_row_is_left_out():
    t_r, end = 11.0, 25.0
    followers = {i: _decay(t_r, 1.0, 2.0, end) for i in (1, 2, 3, 4)}  # back after 2 ln 10 = 4.6 s
    followers[4]["pos_err_m"][1200:1300] = np.nan  # ticks a real-time controller skipped
    events = [*_restart("leader", t_r), {"t_s": 15.0, "kind": "process_killed", "process": "controller_1"}]
    (r,) = judge_rejoins(followers, events, PAPER, end, None, 10.0, {3})
    assert r["window_s"] == 4.0 and set(r["followers"]) == {"1", "2", "4"}  # 3's vehicle is lost
    assert {f["verdict"] for f in r["followers"].values()} == {"not judged"}
    assert rejoin_lines({"rejoins": [r]}) == (
        [
            "  leader restarted at 11 s: follower 1, 2, 4 not back within 0.1 m when the run ended or the "
            "next kill came 4.00 s later: not judged (run.rejoin_within_s = 10 s)"
        ],
        [],
    )
    (r,) = judge_rejoins(followers, events[:2], PAPER, end, None, 10.0, {3})
    assert all(f["verdict"] == "rejoined" for f in r["followers"].values())
    lines, failures = rejoin_lines({"rejoins": [r]})
    assert failures == [] and lines[0].startswith("  leader restarted at 11 s: back within 0.1 m: follower 1")


def test_restarts_are_judged_in_time_order_and_one_with_nothing_recorded_says_so():
    t_r, end = 11.0, 40.0
    followers = {i: _decay(t_r, 1.0, 0.3, end) for i in (1, 3, 4)}
    followers[2] = {"t_s": np.full(4001, np.nan), "pos_err_m": np.full((4001, 3), np.nan)}  # no row
    events = [*_restart("controller_4", 25.0), *_restart("controller_2", t_r)]  # the later one first
    rs = judge_rejoins(followers, events, PAPER, end, None, 10.0, set())
    assert [(r["process"], r["restart_s"]) for r in rs] == [("controller_2", t_r), ("controller_4", 25.0)]
    assert rs[0]["window_s"] == 24.0 - t_r  # until the next kill, a second before the next restart
    assert rs[0]["followers"]["2"] == {
        "back_after_s": None,
        "error_at_end_m": None,
        "verdict": "did not rejoin",
    }
    _, failures = rejoin_lines({"rejoins": rs})
    assert failures[0].startswith("did not rejoin: follower 2, nothing recorded at the end (controller_2 ")
