"""``falsify``'s search in the test's process, small enough to run with the fast tests: what it
writes is checked against an independent reference, each plan flown again here with
``evaluate``, its cost recomputed, the Pareto front recomputed from the evaluations; a study
resumes with only the trials it lacks; a requirement that fails with no fault stops the search.

(The searches of many followers, on several cores, on Dask, interrupted, and confirmed as
processes are ``test_falsify.py``'s system tests.)"""

import csv
import inspect
import json
import math
import os
import re
import signal
import threading

import pytest
import yaml

from swarm_sitl.falsify.evaluate import evaluate
from swarm_sitl.falsify.search import falsify, load_inputs
from swarm_sitl.falsify.space import cost, flown_plan
from tests.support import CONFIGS, config_data

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
    assert (
        name in (out / "report.md").read_text() and (out / "study.db").is_file()
    )  # (a later run resumes it)
    assert (out / "robustness_cost.png").stat().st_size > 0 and (out / "edges.png").stat().st_size > 0


def test_a_study_resumes_with_only_the_trials_it_lacks(tmp_path):
    """The same ``OUT`` with a larger budget: the study's trials are taken up and only the
    difference is flown (one batch of one, after the baseline), the first run's trials all kept.
    (A bound no plan breaks: nothing to shrink. Loss on all edges at once, costed by the edges a
    plan touches: an entry on every follower's in-edges, or none.)"""
    args, cfg, _name = _inputs(tmp_path, bound="1", budget=2)
    (tmp_path / "space.yaml").write_text(
        yaml.safe_dump({"seeds": [0, 1], "entries": [{"edges": "all", "loss": [0.2, 0.4]}]})
    )
    args["cost_how"] = "edges"
    out = tmp_path / "out"
    first = falsify(PAPER, out, budget=2, batch=2, jobs=1, confirm=False, say=lambda s: None, **args)
    trials = _rows(out / "evaluations.csv")
    assert first.plan is None and len(trials) == 2
    every = len(cfg.graph_edges())
    for t in trials:  # (written as flown: one entry into each follower)
        entries = t["plan"]["plan"]
        assert len(entries) in (0, len(cfg.followers)) and t["cost"] == (every if entries else 0.0)
        assert sorted(e["into"] for e in entries) == ([f.id for f in cfg.followers] if entries else [])
    said: list[str] = []
    again = falsify(PAPER, out, budget=3, batch=2, jobs=1, confirm=False, say=said.append, **args)
    after = _rows(out / "evaluations.csv")
    assert len(said) == 1 and said[0].startswith("falsify: 3/3 evaluations"), said
    assert len(after) == 3 and again.plan is None and again.evaluations == 2  # (the baseline, one trial)
    assert all(t in after for t in trials), (trials, after)


def test_a_requirement_that_fails_without_a_fault_stops_the_search_after_the_baseline(tmp_path, monkeypatch):
    """Nothing to search for: said in one line, one evaluation, no plan, no counterexample; the
    same for a bound on the formation error (``--bound``) no run can hold. The rate is the
    evaluations per minute of the search's own clock (stood in for: 30 s; none passed: no rate)."""
    import types

    import swarm_sitl.falsify.search as search_mod

    args, cfg, name = _inputs(tmp_path, bound="1e-12")
    said: list[str] = []
    monkeypatch.setattr(search_mod, "time", types.SimpleNamespace(monotonic=iter([100.0, 130.0]).__next__))
    found = falsify(PAPER, tmp_path / "out", budget=4, jobs=1, confirm=False, say=said.append, **args)
    assert found.baseline == evaluate(cfg, name, {"seed": 0, "plan": []}) < 0
    assert said == [f"falsify: estimate fails with any fault (robustness {found.baseline:.4g})"]
    assert found.evaluations == 1 and found.plan is None and found.counterexample is None
    assert found.per_minute == 1 / 30 * 60 and _rows(tmp_path / "out" / "evaluations.csv") == []
    # (judged from run.settle_s, 20 s in the paper's config: a run past it)
    monkeypatch.setattr(search_mod, "time", types.SimpleNamespace(monotonic=iter([5.0, 5.0]).__next__))
    bound = falsify(
        PAPER, tmp_path / "b", bound_m=1e-9, duration_s=21.0, budget=4, jobs=1, confirm=False, say=said.append
    )
    assert bound.requirement == "bound" and bound.evaluations == 1 and bound.baseline < 0
    assert math.isnan(bound.per_minute)
    assert said[-1] == f"falsify: bound fails with any fault (robustness {bound.baseline:.4g})"


def test_the_command_line_and_the_python_api_search_alike_by_default():
    """``swarm-sitl falsify CONFIG --out DIR`` and ``falsify(CONFIG, DIR)``: the same budget, seed,
    batch, cost, workers and confirmation unless told otherwise."""
    from swarm_sitl.cli import build_parser

    args = build_parser().parse_args(["falsify", PAPER, "--out", "x"])
    api = {k: p.default for k, p in inspect.signature(falsify).parameters.items()}
    cli = {
        "budget": args.budget,
        "seed": args.seed,
        "batch": args.batch,
        "cost_how": args.cost,
        "jobs": args.jobs,
    }
    assert cli == {k: api[k] for k in cli} and (not args.no_confirm) == api["confirm"] is True


class _InProcessCluster:
    """A Dask client's part ``workers.Dask`` uses, each task run here when it is submitted."""

    def __init__(self, address: str):
        self.address, self.tasks, self.closed = address, 0, False

    def submit(self, fn, *args, pure=True, **_):
        assert pure is False  # (a plan flown twice is flown twice: no cached result)
        self.tasks += 1
        return fn(*args)

    def gather(self, futures):
        return list(futures)

    def close(self):
        self.closed = True


def _own_plan_config(tmp_path, loss: float) -> tuple:
    """The paper's config with a plan of its own (``loss`` on edge 0 -> 1 all run long, seed 0)
    and two requirements; a space of one cut of edge 1 -> 4 within [1, 3] s, seeds 0 and 1."""
    data = config_data("paper")
    data["faults"] = {"seed": 0, "plan": [{"edge": [0, 1], "loss": loss}]}
    data["spec"] = [
        {"name": "formation", "formula": "always[3, end] (pos_err_m <= 10)"},
        {"name": "estimate", "formula": "always[2, end] (est_pos_err_m <= 1e-4)"},
    ]
    (tmp_path / "own.yaml").write_text(yaml.safe_dump(data))
    space = {"seeds": [0, 1], "entries": [{"edges": [[1, 4]], "drop": True, "window_s": [1.0, 3.0]}]}
    (tmp_path / "space.yaml").write_text(yaml.safe_dump(space))
    cfg, _sp, name = load_inputs(
        tmp_path / "own.yaml", tmp_path / "space.yaml", None, "estimate", None, 4.0, 2, "severity"
    )
    return tmp_path / "own.yaml", tmp_path / "space.yaml", cfg, name


def test_a_configs_own_plan_flies_under_every_plan_and_a_cluster_finds_what_this_machine_does(
    tmp_path, monkeypatch
):
    """The config's own lossy plan under every searched plan, with the searched seed: the baseline
    is the own plan at the space's first seed, each row is its searched entries flown after the own
    plan, every searched cut lies in its window; the requirement named is the one judged; by
    default the workers are the cores, at most the batch; and on a cluster (a stand-in client
    running each task here) the study, rows and counterexample are the same."""
    import swarm_sitl.campaigns.runner as runner
    import swarm_sitl.falsify.search as search
    import swarm_sitl.falsify.workers as workers

    monkeypatch.setattr(workers, "_SHIPPED", {})  # (a cluster's worker starts with nothing unpacked)
    monkeypatch.setattr(workers, "_UNPACKED", {})
    config, space, cfg, name = _own_plan_config(tmp_path, loss=0.3)
    own = {"seed": 0, "plan": []}
    at_seed = [evaluate(cfg, name, flown_plan({**own, "seed": s}, cfg)) for s in (0, 1)]
    assert at_seed[0] != at_seed[1]  # (the own plan's draws follow the seed: so the baseline's seed shows)
    jobs: list[int] = []
    real_local = search.Local
    monkeypatch.setattr(search, "Local", lambda j, *a: jobs.append(j) or real_local(j, *a))
    args = {"space": space, "requirement": "estimate", "duration_s": 4.0, "budget": 2, "batch": 2}
    here = falsify(config, tmp_path / "here", confirm=False, say=lambda s: None, **args)
    assert jobs == [min(2, os.cpu_count() or 1)]
    clusters: list[_InProcessCluster] = []
    monkeypatch.setattr(
        runner, "connect", lambda address: clusters.append(_InProcessCluster(address)) or clusters[-1]
    )
    there = falsify(
        config, tmp_path / "there", scheduler="tcp://stand-in:8786", confirm=False, say=lambda s: None, **args
    )
    assert [c.address for c in clusters] == ["tcp://stand-in:8786"] and clusters[0].closed
    assert clusters[0].tasks == there.evaluations and jobs == [min(2, os.cpu_count() or 1)]
    for f in (here, there):
        assert f.requirement == name == "estimate" and f.base_entries == 1
        assert f.baseline == at_seed[0]
    rows = _rows(tmp_path / "here" / "evaluations.csv")
    assert rows == _rows(tmp_path / "there" / "evaluations.csv") and len(rows) >= 2
    assert (here.plan, here.robustness) == (there.plan, there.robustness)
    for r in rows:
        searched = r["plan"]["plan"]
        assert r["robustness"] == evaluate(cfg, name, flown_plan(r["plan"], cfg)), r
        assert r["plan"]["seed"] in (0, 1) and all(e["edge"] == [1, 4] and e["drop"] for e in searched)
        assert all(1.0 <= e["from_s"] < e["until_s"] <= 3.0 for e in searched), searched
    if here.plan is not None:
        assert here.plan["plan"][0] == {"edge": [0, 1], "loss": 0.3}


def test_a_search_called_from_another_thread_says_the_configs_own_plan_alone_breaks_it(tmp_path):
    """A config whose own plan (the leader's edge to follower 1 cut for good) breaks the
    requirement: one line saying so, from a search run in a thread that is not the main one (no
    signal handlers there to take Ctrl-C: the caller's)."""
    config, space, _cfg, _name = _own_plan_config(tmp_path, loss=1.0)
    said: list[str] = []
    found: list = []
    args = {"space": space, "requirement": "estimate", "duration_s": 4.0, "budget": 2, "jobs": 1}
    t = threading.Thread(
        target=lambda: found.append(falsify(config, tmp_path / "o", confirm=False, say=said.append, **args))
    )
    t.start()
    t.join()
    assert found and found[0].baseline < 0 and found[0].evaluations == 1
    assert said == [
        f"falsify: estimate fails with the config's own plan alone (robustness {found[0].baseline:.4g})"
    ]


def test_a_search_interrupted_between_batches_keeps_the_flown_trials_and_no_asked_one(tmp_path):
    """Ctrl-C (SIGINT to this process) after the first batch of two: the search stops before it
    flies the next, marks itself interrupted by SIGINT, and writes the two trials flown; the ones
    asked for and never flown are no rows."""
    if threading.current_thread() is not threading.main_thread():
        pytest.skip("signals reach only the main thread, where pytest runs tests")  # (never so)
    args, _cfg, _name = _inputs(tmp_path)
    said: list[str] = []

    def say(line: str) -> None:
        said.append(line)
        os.kill(os.getpid(), signal.SIGINT)

    found = falsify(PAPER, tmp_path / "out", budget=6, batch=2, jobs=1, confirm=False, say=say, **args)
    assert (
        said[0].startswith("falsify: 2/6 evaluations")
        and said[-1] == "falsify: interrupted; what was found is kept"
    )
    assert found.interrupted and found.signum == signal.SIGINT and found.plan is None
    assert len(_rows(tmp_path / "out" / "evaluations.csv")) == 2


def test_a_study_on_disk_as_optuna_writes_it_is_taken_up_and_its_unfinished_trial_is_not(tmp_path):
    """``OUT/study.db`` written by Optuna itself (as an earlier version of the search wrote it,
    and as a user's own script may): its completed trial counts towards the budget and is a row;
    a trial asked and never told (a search killed mid-batch) is neither."""
    import optuna

    args, cfg, _name = _inputs(tmp_path, bound="1", budget=1)
    out = tmp_path / "out"
    out.mkdir()
    plan = {"seed": 1, "plan": [{"into": cfg.followers[0].id, "edge": [0, 1], "loss": 0.6}]}
    study = optuna.create_study(
        study_name="falsify", storage=f"sqlite:///{out / 'study.db'}", directions=["minimize", "minimize"]
    )
    study.add_trial(optuna.trial.create_trial(values=[0.25, 0.5], user_attrs={"plan": plan}))
    study.ask()  # (asked, never told: RUNNING)
    found = falsify(PAPER, out, budget=1, jobs=1, confirm=False, say=lambda s: None, **args)
    assert found.evaluations == 1  # (the baseline: the budget was spent)
    assert [(r["cost"], r["robustness"], r["plan"]) for r in _rows(out / "evaluations.csv")] == [
        (0.25, 0.5, plan)
    ]
