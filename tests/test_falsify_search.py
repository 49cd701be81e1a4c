"""``falsify``'s search in the test's process, small enough to run with the fast tests: what it
writes is checked against an independent reference, each plan flown again here with
``evaluate``, its cost recomputed, the Pareto front recomputed from the evaluations; a study
resumes with only the trials it lacks; a requirement that fails with no fault stops the search.

(The searches of many followers, on several cores, on Dask, interrupted, and confirmed as
processes are ``test_falsify.py``'s system tests.)"""

import csv
import json
import math
import re

import pytest
import yaml

from swarm_sitl.falsify.evaluate import evaluate
from swarm_sitl.falsify.search import falsify, load_inputs
from swarm_sitl.falsify.space import cost
from tests.support import CONFIGS

pytestmark = pytest.mark.integration

PAPER = str(CONFIGS / "paper.yaml")  # (no fault plan of its own: a row's plan is what flew)
DURATION_S = 4.0


def _inputs(tmp_path, bound: str = "1e-4", budget: int = 4):
    (tmp_path / "space.yaml").write_text(
        yaml.safe_dump({"seeds": [0, 1], "entries": [{"edges": "each", "loss": [0.5, 1.0]}]})
    )
    (tmp_path / "spec.yaml").write_text(
        f'- {{name: estimate, formula: "always[2, end] (est_pos_err_m <= {bound})"}}\n'
    )
    args = {"space": tmp_path / "space.yaml", "spec": tmp_path / "spec.yaml", "duration_s": DURATION_S}
    cfg, _sp, name = load_inputs(
        PAPER, args["space"], args["spec"], None, None, DURATION_S, budget, "severity"
    )
    return args, cfg, name


def _rows(path) -> list[dict]:
    with open(path) as f:
        return [
            {
                **r,
                "cost": float(r["cost"]),
                "robustness": float(r["robustness"]),
                "plan": json.loads(r["plan"]),
            }
            for r in csv.DictReader(f)
        ]


def _dominated(a: dict, b: dict) -> bool:
    """``b`` is at least as good as ``a`` in both objectives and better in one (both minimised)."""
    return (
        b["cost"] <= a["cost"]
        and b["robustness"] <= a["robustness"]
        and (b["cost"], b["robustness"])
        != (
            a["cost"],
            a["robustness"],
        )
    )


def test_a_search_writes_each_plans_own_robustness_and_cost_its_front_and_a_shrunk_counterexample(tmp_path):
    """Budget 4 in batches of 2: the baseline and every row's robustness are what ``evaluate``
    gives that row's plan here, bit for bit, and its cost what ``cost`` gives; the front is exactly
    the rows no row dominates; the counterexample violates, is no costlier than any violating row,
    and its file holds it; the progress lines count the batches up to the budget."""
    args, cfg, name = _inputs(tmp_path)
    said: list[str] = []
    out = tmp_path / "out"
    found = falsify(PAPER, out, budget=4, batch=2, jobs=1, seed=3, confirm=False, say=said.append, **args)
    assert found.baseline == evaluate(cfg, name, {"seed": 0, "plan": []}) >= 0
    rows = _rows(out / "evaluations.csv")
    assert len(rows) == 4 + (found.plan is not None)  # the study's trials, and the shrunk plan
    for r in rows:
        assert r["robustness"] == evaluate(cfg, name, r["plan"]), r
        assert r["cost"] == cost(r["plan"], cfg, "severity"), r
        assert int(r["violates"]) == (r["robustness"] < 0) and int(r["seed"]) == r["plan"]["seed"]
        assert int(r["entries"]) == len(r["plan"]["plan"])
    assert [(r["cost"], r["robustness"]) for r in rows] == sorted((r["cost"], r["robustness"]) for r in rows)
    on_front = {(r["cost"], r["robustness"]) for r in _rows(out / "front.csv")}
    assert on_front == {(r["cost"], r["robustness"]) for r in rows if not any(_dominated(r, o) for o in rows)}
    assert [(f["cost"], f["robustness"]) for f in found.front] == sorted(on_front)
    violating = [r for r in rows if r["robustness"] < 0]
    if not violating:  # (the space's losses up to 1 break this bound at seed 3: see the next test)
        pytest.fail(f"no plan of four broke the requirement: {rows}")
    progress = [
        re.fullmatch(r"falsify: (\d+)/4 evaluations, (\d+) of the last violating", line) for line in said
    ]
    assert all(progress) and [int(m[1]) for m in progress if m] == [2, 4], said
    assert sum(int(m[2]) for m in progress if m) == len(violating) - 1  # (the shrunk plan's row is no trial)
    assert found.plan is not None and found.robustness < 0
    assert found.robustness == evaluate(cfg, name, found.plan)
    assert found.cost == cost(found.plan, cfg, "severity") <= min(r["cost"] for r in violating)
    assert yaml.safe_load(found.counterexample.read_text()) == json.loads(json.dumps(found.plan))
    assert found.evaluations >= 1 + 4 and found.per_minute > 0 and found.confirmed is None
    assert name in (out / "report.md").read_text()
    assert (out / "robustness_cost.png").stat().st_size > 0 and (out / "edges.png").stat().st_size > 0


def test_a_study_resumes_with_only_the_trials_it_lacks(tmp_path):
    """The same ``OUT`` with a larger budget: the study's trials are taken up and only the
    difference is flown (one batch of one, after the baseline), the first run's trials all kept."""
    args, _cfg, _name = _inputs(tmp_path, budget=2)
    out = tmp_path / "out"
    first = falsify(PAPER, out, budget=2, batch=2, jobs=1, confirm=False, say=lambda s: None, **args)
    trials = _rows(out / "evaluations.csv")
    if first.plan is not None:  # (the shrunk plan's row is no trial of the study)
        trials.remove(next(r for r in trials if r["plan"] == first.plan and r["cost"] == first.cost))
    said: list[str] = []
    again = falsify(PAPER, out, budget=3, batch=2, jobs=1, confirm=False, say=said.append, **args)
    after = _rows(out / "evaluations.csv")
    assert len(said) == 1 and said[0].startswith("falsify: 3/3 evaluations"), said
    assert len(after) == 3 + (again.plan is not None)
    assert all(t in after for t in trials), (trials, after)


def test_a_requirement_that_fails_without_a_fault_stops_the_search_after_the_baseline(tmp_path):
    """Nothing to search for: said in one line, one evaluation, no plan, no counterexample."""
    args, cfg, name = _inputs(tmp_path, bound="1e-12")
    said: list[str] = []
    found = falsify(PAPER, tmp_path / "out", budget=4, jobs=1, confirm=False, say=said.append, **args)
    assert found.baseline == evaluate(cfg, name, {"seed": 0, "plan": []}) < 0
    assert said == [f"falsify: estimate fails with any fault (robustness {found.baseline:.4g})"]
    assert found.evaluations == 1 and found.plan is None and found.counterexample is None
    assert not math.isnan(found.per_minute) and _rows(tmp_path / "out" / "evaluations.csv") == []
