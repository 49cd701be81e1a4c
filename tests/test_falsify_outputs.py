"""What ``falsify`` writes of what it found (``falsify/outputs.py``), over random evaluations:

- the front is the Pareto front of (cost, robustness), both lower better: every evaluation is
  matched or beaten by a point of it, and no evaluation beats one of its points;
- ``front.csv``'s rows read back as the evaluations, each plan as the fault plan it flew;
- each edge's share of the violating plans is the share whose entries act on it (an entry over
  every edge acts on each, a MAVLink link's on none), ``None`` for every edge when none violated;
- the report says which of its three outcomes the search had, names every entry of the
  counterexample, and a failed search's report says why and gives no verdict.

Confirmation in lockstep flies a run of processes: ``tests/test_falsify.py``'s system tests.
"""

import csv
import itertools
import json

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from swarm_sitl.falsify.outputs import Found, edge_shares, failed_report, front, order, report, write_csv
from swarm_sitl.falsify.space import expand
from swarm_sitl.falsify.workers import NO_ROBUSTNESS
from tests.support import config

pytestmark = pytest.mark.unit

CFG = config("paper")  # followers 1-4, edges 0->1, 0->2, 0->3, 1->4, 2->4
EDGES = [tuple(int(x) for x in e) for e in CFG.graph_edges()]

#: few distinct values, so that ties in cost, in robustness and in both are common
_grid = st.sampled_from([0.0, 0.5, 1.0, 2.0, 3.5])
#: robustness as the workers give it: finite, between their two caps (``workers.robustness``)
_robustness = st.one_of(
    st.sampled_from([NO_ROBUSTNESS, -1.0, -0.25, 0.0, 0.25, 1.0, -NO_ROBUSTNESS]), st.floats(-5, 5)
)


@st.composite
def _entry(draw) -> dict:
    """A plan item as ``plan_of`` makes them: over every edge, on one edge, or on a MAVLink link."""
    kind = draw(st.sampled_from(["all", "edge", "mavlink"]))
    how = {"loss": draw(st.floats(0.01, 1.0))}
    if kind == "all":
        return {"edges": "all", **how}
    if kind == "edge":
        return {"edge": list(draw(st.sampled_from(EDGES))), **how}
    return {"mavlink": draw(st.integers(1, 4)), "direction": "up", **how}


_plan = st.builds(
    lambda s, p: {"seed": s, "plan": p}, st.integers(0, 9), st.lists(_entry(), min_size=1, max_size=3)
)
_rows = st.lists(
    st.builds(lambda c, r, p: {"cost": c, "robustness": r, "plan": p}, _grid, _robustness, _plan), max_size=12
)


def _beats(a: dict, b: dict) -> bool:
    """``a`` at most ``b`` in both, below it in one."""
    return (a["cost"] <= b["cost"] and a["robustness"] <= b["robustness"]) and (
        a["cost"] < b["cost"] or a["robustness"] < b["robustness"]
    )


@settings(max_examples=200, deadline=None)
@given(_rows)
def test_the_front_is_the_evaluations_no_other_beats_and_it_covers_every_evaluation(rows):
    fr = front(rows)
    assert all(any(f is r for r in rows) for f in fr)  # the evaluations themselves
    for r in rows:
        assert not any(_beats(r, f) for f in fr)
        assert any(f["cost"] <= r["cost"] and f["robustness"] <= r["robustness"] for f in fr)
    # cheapest first, each point below the last in robustness
    assert [f["cost"] for f in fr] == sorted(f["cost"] for f in fr)
    assert all(a["robustness"] > b["robustness"] for a, b in itertools.pairwise(fr))
    assert (fr == []) == (rows == [])
    # the order evaluations are told and written in: cheapest first, then least robust
    told = sorted(rows, key=order)
    assert all(
        a["cost"] < b["cost"] or (a["cost"] == b["cost"] and a["robustness"] <= b["robustness"])
        for a, b in itertools.pairwise(told)
    )


@settings(max_examples=50, deadline=None)
@given(rows=_rows)
def test_front_csv_reads_back_as_the_evaluations_each_plan_as_flown(rows, tmp_path_factory):
    path = tmp_path_factory.mktemp("csv") / "front.csv"
    write_csv(path, rows, CFG)
    with open(path, newline="") as f:
        back = list(csv.DictReader(f))
    assert len(back) == len(rows)
    for r, b in zip(rows, back, strict=True):
        flown = expand(r["plan"], CFG)
        assert float(b["cost"]) == r["cost"] and float(b["robustness"]) == r["robustness"]
        assert int(b["violates"]) == (r["robustness"] < 0)
        assert json.loads(b["plan"]) == flown
        assert int(b["seed"]) == r["plan"]["seed"] and int(b["entries"]) == len(flown["plan"])
        assert int(b["entries"]) >= len(r["plan"]["plan"])


def _touched(plan: dict) -> set:
    """The edges a plan of items acts on, read from the items themselves."""
    out: set = set()
    for f in plan["plan"]:
        if f.get("edges") == "all":
            out |= set(EDGES)
        elif "edge" in f:
            out.add(tuple(f["edge"]))
    return out


@settings(max_examples=100, deadline=None)
@given(_rows)
def test_an_edges_share_is_the_share_of_violating_plans_acting_on_it(rows):
    shares = edge_shares(rows, CFG)
    assert sorted(shares) == sorted(EDGES)
    bad = [r["plan"] for r in rows if r["robustness"] < 0]
    for e in EDGES:
        if not bad:
            assert shares[e] is None
        else:
            assert shares[e] == pytest.approx(sum(e in _touched(p) for p in bad) / len(bad), abs=1e-12)


def _found(**kw) -> Found:
    return Found(requirement="formation", evaluations=23, per_minute=41.5, **kw)


def test_the_report_says_which_of_its_three_outcomes_the_search_had(tmp_path):
    """Each outcome's report whole, as its reader reads it (a robustness of exactly 0 holds: a
    plan violates below it, as ``front.csv`` counts)."""
    path = tmp_path / "report.md"
    plan = {"seed": 3, "plan": [{"loss": 0.9, "edges": "all"}, {"edge": [1, 4], "delay_s": 0.5}]}
    head = f"# falsify {CFG.name}: requirement formation\n\n23 evaluations in 30 s (41.5 per minute).\n"
    outcomes = {
        "fails alone": (
            _found(baseline=-0.5),
            "With a fault the requirement's robustness is -0.5.\n"
            "It fails with a fault: there is nothing to search for.\n",
        ),
        "none broke it": (
            _found(baseline=0.0),
            "With a fault the requirement's robustness is 0.\nNo plan in the space broke the requirement.\n",
        ),
        "broken": (
            _found(
                baseline=0.75,
                plan=plan,
                counterexample=tmp_path / "c.yaml",
                cost=12.25,
                robustness=-0.125,
                confirmed=True,
            ),
            "With a fault the requirement's robustness is 0.75.\n"
            f"Minimal counterexample: {tmp_path / 'c.yaml'} (cost 12.25, robustness -0.125), 2 entries:\n"
            '- `{"edges": "all", "loss": 0.9}`\n'
            '- `{"delay_s": 0.5, "edge": [1, 4]}`\n'
            "Confirmed as a lockstep run of processes: True.\n",
        ),
    }
    for found, rest in outcomes.values():
        report(path, CFG, "formation", found, 30.0)
        assert path.read_text() == head + rest


def test_the_report_of_a_config_with_its_own_faults_says_they_are_flown_under_every_plan(tmp_path):
    data = CFG.data()
    data["faults"] = {"seed": 1, "plan": [{"edge": [0, 1], "loss": 0.1}, {"edge": [0, 2], "loss": 0.1}]}
    cfg = type(CFG).model_validate(data)
    path = tmp_path / "report.md"
    report(path, cfg, "formation", _found(baseline=-0.5), 30.0)
    text = path.read_text()
    assert text.splitlines()[3:6] == [
        "The config's own plan (2 entries) is flown under every searched plan, and is in the counterexample.",
        "With the config's own plan alone the requirement's robustness is -0.5.",
        "It fails with the config's own plan alone: there is nothing to search for.",
    ]


def test_a_failed_searchs_report_says_why_and_gives_no_verdict(tmp_path):
    path = tmp_path / "report.md"
    failed_report(path, CFG, "formation", "worker 2 ended: MemoryError")
    assert path.read_text() == (
        f"# falsify {CFG.name}: requirement formation\n\n"
        "The search stopped: a worker could not fly a plan. Nothing is said of the swarm.\n\n"
        "    worker 2 ended: MemoryError\n"
    )
