"""A run held to its requirements (``rundir.requirements``), from recordings drawn at random: each
follower signal is its definition, the failsafe signal is a replay of its events, an edge's age
is its receiver's column for that sender and its delivered fraction a count of fresh estimates,
and each member's robustness, the run's (the least, NaN failing) and the failing lines are what
the formulas give in closed form."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from swarm_sitl.rundir.recording import Recording
from swarm_sitl.rundir.requirements import edge_signals, failsafe_signal, follower_signals, judge, spec_lines
from swarm_sitl.specs.requirement import Edge, Requirement
from tests.support import config

pytestmark = pytest.mark.unit

_FLOATS = st.floats(-50, 50, allow_nan=False)


def _norm(v: np.ndarray) -> np.ndarray:
    """Each row's length, written out (the module's is numpy's)."""
    return np.sqrt((v**2).sum(axis=1))


def _follower(n: int, draw, est: bool = True, flat: bool = False) -> dict[str, np.ndarray]:
    def arr(*shape):
        return draw(hnp.arrays(float, shape, elements=_FLOATS))

    a = {
        "t_s": np.arange(n) * 0.01,
        "pos_err_m": arr(n) if flat else arr(n, 3),
        "vel_err_mps": arr(n, 3),
        "p_W": arr(n, 3),
        "v_W": arr(n, 3),
        "thrust_N": arr(n),
        "in_age_s": np.abs(arr(n, 2)),
    }
    if est:
        a["est_pos_err_m"] = arr(n, 3)
    return a


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 30), st.booleans(), st.booleans(), st.integers(0, 30), st.data())
def test_each_follower_signal_is_its_definition(n, est, flat, enter, data):
    cfg = config("paper")
    a = _follower(n, data.draw, est, flat)
    events = [  # follower 2's vehicle in its failsafe from tick ``enter``; vehicle 3's from the start
        {"t_s": enter * 0.01, "kind": "failsafe_enter", "vehicle": 2},
        {"t_s": 0.0, "kind": "failsafe_enter", "vehicle": 3},
    ]
    got = follower_signals(Recording({}, {2: a}, {}), cfg, 2, events)
    assert np.array_equal(got["pos_err_m"], np.abs(a["pos_err_m"]) if flat else _norm(a["pos_err_m"]))
    assert np.array_equal(got["vel_err_mps"], _norm(a["vel_err_mps"]))
    assert np.array_equal(got["altitude_m"], a["p_W"][:, 2])  # ENU: z is up
    assert np.array_equal(got["speed_mps"], _norm(a["v_W"]))
    assert np.array_equal(got["thrust_frac"], a["thrust_N"] / cfg.vehicle.max_thrust_N)
    assert np.array_equal(got["failsafe"], (np.arange(n) >= enter).astype(float))
    assert ("est_pos_err_m" in got) == est
    if est:
        assert np.array_equal(got["est_pos_err_m"], _norm(a["est_pos_err_m"]))


_EVENTS = st.lists(
    st.one_of(
        st.fixed_dictionaries(
            {
                "t_s": st.integers(0, 40).map(lambda k: k * 0.05),
                "kind": st.sampled_from(["failsafe_enter", "failsafe_exit", "lost"]),
                "vehicle": st.sampled_from([1, 2]),
            }
        ),
        st.just({"kind": "router_lost"}),  # (an event of the run's, of no vehicle and no instant)
    ),
    max_size=10,
)


@settings(max_examples=150, deadline=None)
@given(_EVENTS, st.sampled_from([0.01, 0.05, 0.1]))
def test_the_failsafe_signal_is_a_replay_of_the_vehicles_events(events, dt):
    """At each tick: enter the failsafe, or leave it, as the vehicle's events up to that tick say,
    in their order (an entry while in it, or an exit while out of it, changes nothing; another
    vehicle's events and other kinds say nothing)."""
    t = np.arange(int(2.2 / dt)) * dt
    got = failsafe_signal(t, events, 1)
    ordered = sorted(events, key=lambda e: e.get("t_s", -1.0))  # (stable: one instant's in order)
    for k, tk in enumerate(t):
        inside = False
        for e in ordered:
            if e.get("t_s", -1.0) > tk + 1e-9:
                break
            if e.get("vehicle") == 1 and e["kind"] == "failsafe_enter":
                inside = True
            elif e.get("vehicle") == 1 and e["kind"] == "failsafe_exit":
                inside = False
        assert got[k] == float(inside), (k, tk, ordered)


@settings(max_examples=100, deadline=None)
@given(
    st.integers(2, 40),
    st.integers(1, 5),
    st.integers(0, 6),
    st.lists(st.integers(0, 39), max_size=4),
    st.sampled_from([0, 1]),
)
def test_an_edges_signals_are_its_senders_column_and_the_share_of_ticks_with_a_fresh_estimate(
    n, every, none_before, unticked, which
):
    """Follower 4 hears 1 and 2 (the paper's graph): ``age_s`` is the column of the sender asked
    for; a sender whose estimate comes every ``every`` ticks (none before tick ``none_before``)
    is delivered at each tick that brings a newer one, counted over the receiver's ticks after
    its first; a tick it did not record is NaN, and not counted."""
    dt = 0.01
    k = np.arange(n)
    made = np.where(k >= none_before, (k - k % every) * dt, np.nan)  # when the newest was made
    t = k * dt
    for j in unticked:
        if j < n:
            t[j] = np.nan
    age = np.full((n, 2), 0.5)
    age[:, which] = t - made
    a = {"t_s": t, "in_age_s": age}
    got = edge_signals(Recording({}, {4: a}, {}), config("paper"), Edge([1, 2][which], 4))
    assert np.array_equal(got["age_s"], age[:, which], equal_nan=True)
    seen, fresh, last = 0, 0, -math.inf
    for j in range(n):
        m = t[j] - age[j, which]
        if np.isfinite(t[j]):
            fresh += j > 0 and m > last + 1e-9 and seen > 0
            want = fresh / seen if seen > 0 else 1.0
            assert got["delivered_frac"][j] == pytest.approx(want, abs=1e-12), j
            seen += 1
        else:
            assert math.isnan(got["delivered_frac"][j])
        last = -math.inf if math.isnan(m) else m
    assert every >= 1


def _judged(spec, followers):
    cfg = config("paper").model_copy(update={"spec": [Requirement(**r) for r in spec]})
    return judge(cfg, Recording({}, followers, {}), [])


@settings(max_examples=60, deadline=None)
@given(st.integers(2, 20), st.floats(0.0, 60.0), st.integers(0, 4), st.data())
def test_a_requirements_members_and_the_run_have_the_robustness_of_the_closed_forms(n, c, lost, data):
    """``always (pos_err_m < c)`` over followers: each member c - max|e|; ``always (distance_m >
    c)`` over pairs: the least distance - c; ``always (age_s <= c)`` over edges: c - the greatest
    age; the run's the least member's, holding at 0 and above. A follower with a sample it did not
    record (``lost``, 0: none) has no robustness there (null), and the requirement fails."""
    fs = {i: _follower(n, data.draw) for i in range(1, 5)}
    if lost:
        fs[lost]["pos_err_m"][n // 2] = np.nan
    spec = [
        {"name": "err", "formula": f"always (pos_err_m < {c!r})"},
        {"name": "apart", "over": "pairs", "formula": f"always (distance_m > {c!r})"},
        {"name": "fresh", "over": "edges", "formula": f"always (age_s <= {c!r})"},
    ]
    got = _judged(spec, fs)
    err = {str(i): c - _norm(a["pos_err_m"]).max() for i, a in fs.items()}
    if lost:
        err[str(lost)] = None
    pairs = {
        f"{i}-{j}": _norm(fs[i]["p_W"] - fs[j]["p_W"]).min() - c for i in range(1, 5) for j in range(i + 1, 5)
    }
    g = config("paper").build_graph()
    edges = {}
    for d in range(1, 5):
        for col, (s, _) in enumerate(g.in_neighbours(d)):
            edges[f"{int(s)}->{d}"] = c - fs[d]["in_age_s"][:, col].max()
    for name, want in (("err", err), ("apart", pairs), ("fresh", edges)):
        r = got[name]
        assert set(r["members"]) == set(want), name
        for m, v in want.items():
            assert (r["members"][m] is None) if v is None else r["members"][m] == pytest.approx(v, abs=1e-9)
        values = [v for v in want.values() if v is not None]
        if None in want.values():
            assert r["robustness"] is None and r["holds"] is False
        else:
            assert r["robustness"] == pytest.approx(min(values), abs=1e-9)
            assert r["holds"] == (r["robustness"] >= 0)
        assert r["formula"] == next(s["formula"] for s in spec if s["name"] == name)
        assert r["over"] == next(s.get("over", "followers") for s in spec if s["name"] == name)


def test_a_requirement_over_a_follower_with_no_recording_fails_unrecorded():
    """Follower 3 lost before it recorded anything: a requirement over it alone has no member
    judged, no robustness, and does not hold; over every follower, the others are judged."""
    fs = {i: {**_FIXED, "t_s": _FIXED["t_s"].copy()} for i in (1, 2, 4)}
    got = _judged(
        [
            {"name": "three", "over": "follower 3", "formula": "always (pos_err_m < 10)"},
            {"name": "all", "formula": "always (pos_err_m < 10)"},
        ],
        fs,
    )
    assert got["three"]["members"] == {} and got["three"]["robustness"] is None
    assert got["three"]["holds"] is False
    assert set(got["all"]["members"]) == {"1", "2", "4"} and got["all"]["holds"] is True


_FIXED = {
    "t_s": np.arange(3) * 0.01,
    "pos_err_m": np.ones((3, 3)),
    "vel_err_mps": np.zeros((3, 3)),
    "p_W": np.zeros((3, 3)),
    "v_W": np.zeros((3, 3)),
    "thrust_N": np.full(3, 10.0),
    "in_age_s": np.zeros((3, 2)),
}


def test_a_failing_requirement_is_one_line_naming_its_three_worst_members():
    summary = {
        "spec": {
            "ok": {
                "formula": "f",
                "over": "followers",
                "robustness": 0.5,
                "holds": True,
                "members": {"1": 0.5},
            },
            "bad": {
                "formula": "always (pos_err_m < 1)",
                "over": "followers",
                "robustness": None,
                "holds": False,
                "members": {"1": 0.25, "2": -0.123456, "3": None, "4": -2.0},
            },
            "low": {
                "formula": "g",
                "over": "pairs",
                "robustness": -1.5,
                "holds": False,
                "members": {"1-2": -1.5},
            },
        }
    }
    assert spec_lines(summary) == [
        "requirement bad (always (pos_err_m < 1), over followers) fails: robustness not recorded "
        "(3 not recorded, 4 -2, 2 -0.1235)",
        "requirement low (g, over pairs) fails: robustness -1.5 (1-2 -1.5)",
    ]
    assert spec_lines({}) == [] and spec_lines({"spec": {}}) == []
