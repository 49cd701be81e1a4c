"""``swarm-sitl falsify``: bad input in one line before anything flies, the cost and the plans a
space writes, shrinking against a known boundary, the same front for a seed, and a minimal
counterexample on a generated ring of six followers that a lockstep run of processes replays."""

import copy
import json
import math
import signal
import tempfile
from pathlib import Path

import pytest
import yaml
from hypothesis import example, given, settings
from hypothesis import strategies as st

from swarm_sitl.campaigns.grid import point_data
from swarm_sitl.config.generator import generate
from swarm_sitl.config.load import load_config, parse_config, with_spec
from swarm_sitl.falsify.evaluate import evaluate, requirement_config
from swarm_sitl.falsify.search import assert_no_counterexample, falsify
from swarm_sitl.falsify.shrink import RESOLUTION, at, held_below, shrink
from swarm_sitl.falsify.space import cost, expand
from tests.support import CONFIGS, FixedTrial, cli, cli_in_process, start_cli

#: its system tests run in lockstep or ``sim`` only (no wall clock): free to run beside others
pytestmark = pytest.mark.lockstep

ESTIMATE_SPEC = '- {name: estimate, formula: "always[2, end] (est_pos_err_m <= 1e-4)"}\n'
PAPER = str(CONFIGS / "paper.yaml")


@pytest.mark.integration
@pytest.mark.parametrize(
    ("space", "extra", "names"),
    [
        ("entries:\n  - {edges: each, jitter: [0, 1]}\n", [], "jitter is not a key"),
        ("entries:\n  - {edges: [[0, 4]], loss: [0, 1]}\n", [], "edge [0, 4] is not an edge of the graph"),
        ("entries:\n  - {edges: each, loss: [0.5, 0.5]}\n", [], "an empty range"),
        ("entries:\n  - {links: [9], loss: [0, 1]}\n", [], "no follower 9"),
        ("entries:\n  - {controllers: each, loss: [0, 1]}\n", [], "controllers fail by kill, not loss"),
        ("entries:\n  - {links: each, delay_s: [0, 1]}\n", [], "links fail by loss or drop"),
        ("entries:\n  - {edges: each, drop: true, window_s: [10, 90]}\n", [], "after the run"),
        ("entries:\n  - {edges: each, loss: [0, 1]}\n", ["--budget", "0"], "--budget 0"),
        ("entries:\n  - {edges: each, loss: [0, 1]}\n", ["--spec", "EMPTY"], "names no requirement"),
        (
            "entries:\n  - {edges: each, loss: [0, 1]}\n",
            ["--bound", "0.005", "--requirement", "x"],
            "--requirement x",
        ),
    ],
)
def test_bad_input_is_one_line_and_nothing_flies(tmp_path, space, extra, names):
    (tmp_path / "space.yaml").write_text(space)
    (tmp_path / "empty.yaml").write_text("[]\n")
    extra = [str(tmp_path / "empty.yaml") if x == "EMPTY" else x for x in extra]
    if "--spec" not in extra and "--bound" not in extra:
        extra += ["--bound", "0.005"]
    out = tmp_path / "out"
    # (in ``swarm-sitl``'s own main, in this process: each refusal comes before anything starts)
    code, _, err = cli_in_process("falsify", PAPER, "--space", tmp_path / "space.yaml", "--out", out, *extra)
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and names in lines[0], err
    assert not out.exists()  # before anything ran


@pytest.mark.unit
def test_a_space_over_every_edge_writes_the_plan_a_sweep_writes():
    """``edges: all`` under one loss is the plan ``sweep --vary link.loss=p`` flies (the same
    entries, so the same draws): a search and a campaign judge the same runs."""
    cfg = load_config(PAPER)
    plan = expand({"seed": 2, "plan": [{"edges": "all", "loss": 0.3}]}, cfg)
    swept = point_data(cfg.data(), {"link.loss": 0.3}, 2)
    assert plan["plan"] == swept["faults"]["plan"]
    assert parse_config({**swept}, "t").faults.seed == plan["seed"]


@pytest.mark.unit
@given(
    p=st.floats(0.01, 1.0),
    start=st.floats(0.0, 30.0),
    dur=st.floats(0.5, 10.0),
    d=st.floats(0.0, 2.0),
)
def test_the_cost_of_a_plan_is_severity_times_duration_summed(p, start, dur, d):
    cfg = load_config(PAPER)  # 60 s, staleness 0.5 s
    plan = {
        "seed": 0,
        "plan": [
            {"edge": [0, 1], "loss": p, "from_s": start, "until_s": start + dur},
            {"edge": [1, 4], "drop": True, "from_s": start, "until_s": start + dur},
            {"into": 4, "delay_s": d},
        ],
    }
    run = cfg.duration_s
    want = p * dur + dur + min(1.0, d / cfg.estimator.staleness_s) * run
    assert cost(plan, cfg) == pytest.approx(want, rel=1e-12)
    assert cost(plan, cfg, "edges") == 3  # 0 -> 1, 1 -> 4, and into 4: 1 -> 4 and 2 -> 4


@pytest.mark.unit
def test_the_edges_cost_counts_the_graph_edges_a_plan_touches():
    cfg = load_config(PAPER)  # edges 0->1, 0->2, 0->3, 1->4, 2->4
    one = {"seed": 0, "plan": [{"edge": [0, 1], "loss": 0.5}, {"edge": [0, 1], "drop": True}]}
    assert cost(one, cfg, "edges") == 1
    into = {"seed": 0, "plan": [{"edge": [0, 1], "loss": 0.5}, {"into": 4, "delay_s": 0.1}]}
    assert cost(into, cfg, "edges") == 3


@pytest.mark.unit
def test_links_and_controllers_in_a_space_write_the_plan_entries_lockstep_takes():
    from swarm_sitl.falsify.space import Space, items, plan_of
    from swarm_sitl.faults.plan import FaultPlan

    cfg = load_config(PAPER)
    space = Space.model_validate(
        {
            "entries": [
                {"links": [3], "direction": "up", "loss": [0.1, 0.6], "window_s": [10, 20]},
                {"controllers": [2], "kill": True, "restart_after_s": [0.5, 3], "window_s": [22, 30]},
            ]
        }
    )
    at = {"p": 0.4, "from": 12.0, "dur": 2.0, "down": 1.5, "1.kill.controller2.from": 25.0}
    plan = plan_of(FixedTrial(at), space, items(space, cfg), cfg)
    assert plan["plan"] == [
        {"mavlink": 3, "direction": "up", "loss": 0.4, "from_s": 12.0, "until_s": 14.0},
        {"controller": 2, "kill": True, "restart_after_s": 1.5, "from_s": 25.0},
    ]
    FaultPlan.model_validate(plan).check_lockstep()  # a plan lockstep (and so sim) flies
    assert cost(plan, cfg) == pytest.approx(0.4 * 2.0 + 1.5)  # a controller down: 1 x its downtime
    assert cost(plan, cfg, "edges") == 2  # one link, one controller


ENTRIES = [[0, 1], [0, 2], [0, 3], [1, 4], [2, 4]]


MILD = 0.05  #: the searched range's mild end (not 0: a range is not its own scale)


@pytest.mark.unit
@settings(max_examples=80, deadline=None)
@given(
    losses=st.lists(st.floats(0.05, 1.0), min_size=5, max_size=5),
    a=st.sampled_from(range(5)),
    b=st.sampled_from(range(5)),
    thresholds=st.lists(st.floats(0.1, 0.9), min_size=3, max_size=3),
    seeds=st.lists(st.integers(0, 5), min_size=1, max_size=3, unique=True),
    flip=st.booleans(),
    nested=st.booleans(),
    alone=st.booleans(),
    width=st.integers(1, 3),
    held=st.one_of(st.none(), st.floats(1e-3, 0.05)),
)
@example(  # the first probe lands exactly on the threshold: robustness 0 holds
    losses=[1.0] * 5, a=0, b=1, thresholds=[0.525] * 3, seeds=[0], flip=False, nested=False,
    alone=False, width=1, held=None,
)  # fmt: skip
@example(  # bisection narrowed to 1/128 of 0.95, not of 1.05 (the range's width, not its sum)
    losses=[0.55] * 5, a=0, b=1, thresholds=[0.050005] * 3, seeds=[0], flip=False, nested=False,
    alone=False, width=1, held=None,
)  # fmt: skip
@example(  # two seeds, flipped: the mildest of their worst holds is where bisection starts
    losses=[1.0] * 5, a=0, b=1, thresholds=[0.3, 0.6, 0.6], seeds=[0, 1], flip=True, nested=True,
    alone=True, width=1, held=0.01,
)  # fmt: skip
def test_shrinking_finds_the_known_minimal_plan(
    losses, a, b, thresholds, seeds, flip, nested, alone, width, held
):
    """A requirement broken exactly when edges A and B are both faulty (A alone, with ``alone``)
    and A loses at least the plan's seed's threshold (each seed its own): shrinking keeps A and B
    only, lowers A's loss to within 1/128 of its range above the least threshold of any seed the
    space allows, with a seed that breaks there (not only the plan's own), B's to the bottom, and
    each entry left is needed. ``flip``: the searched value is 1 - loss, its range's mild end the
    high one (as a rate whose lower values hurt more); ``nested``: the value is deeper in the
    entry (``bursty.p``, as a link model's parameter). Entries are dropped under the plan's own
    seed; no plan is flown twice; ``width`` seeds at a time, all of them: the most violating is
    kept. ``held``: the search saw each seed hold just below its threshold (by ``held``): no probe
    goes milder than the mildest of those."""
    sev = (lambda v: 1.0 - v) if flip else (lambda v: v)  # (its own inverse)
    path = ("bursty", "p") if nested else ("loss",)
    if a == b:
        b = (a + 1) % 5
    threshold = dict(zip(seeds, thresholds, strict=False))
    losses[a] = max(losses[a], max(threshold.values()) + 0.05)

    def entry(e, loss, reverse=False):
        value = {"p": sev(loss)} if nested else sev(loss)
        return {path[0]: value, "edge": e} if reverse else {"edge": e, path[0]: value}

    plan = {"seed": seeds[0], "plan": [entry(e, p) for e, p in zip(ENTRIES, losses, strict=True)]}
    needed = [a] if alone else sorted({a, b})

    def robustness(p: dict) -> float:
        on = {tuple(f["edge"]): sev(at(f, path)) for f in p["plan"]}
        if all(tuple(ENTRIES[k]) in on for k in needed):
            return threshold[p["seed"]] - on[tuple(ENTRIES[a])]
        return 1.0

    flown: list[dict] = []

    def check_many(plans: list[dict]) -> list[float]:
        flown.extend(copy.deepcopy(plans))
        return [robustness(p) for p in plans]

    # the search's holds: the kept entries as found, A just below each seed's threshold (only where
    # A is lowered first: once B is, those plans differ from the one bisected elsewhere too)
    held = held if alone or a < b else None
    seen = []
    if held is not None:
        for s, t in threshold.items():
            kept = [entry(ENTRIES[k], max(t - held, 0.0) if k == a else losses[k], True) for k in needed]
            seen.append({"plan": kept, "seed": s})

    def ranges(f):  # (an entry without the value searches nothing)
        return [(path, (sev(MILD), sev(1.0)))] if at(f, path) is not None else []

    found, r, spent = shrink(plan, check_many, ranges, 0.01, seeds, seen, width=width)
    assert spent == len(flown)
    assert len({json.dumps(p, sort_keys=True) for p in flown}) == len(flown)  # none flown twice
    kept = {tuple(f["edge"]): sev(at(f, path)) for f in found["plan"]}
    assert set(kept) == {tuple(ENTRIES[k]) for k in needed}
    assert r == robustness(found) and r < 0 and found["seed"] in seeds
    least = min(threshold.values())  # where *a* seed breaks
    assert least < kept[tuple(ENTRIES[a])] <= least + (1 - MILD) / RESOLUTION + 1e-12
    if not alone:
        assert kept[tuple(ENTRIES[b])] <= MILD + (1 - MILD) / RESOLUTION + 1e-12
    for j in range(len(found["plan"])):  # minimal: without any one entry it holds
        assert robustness({**found, "plan": found["plan"][:j] + found["plan"][j + 1 :]}) >= 0
    original = {tuple(f["edge"]): at(f, path) for f in plan["plan"]}
    for p in flown:  # the entries dropped (nothing lowered yet): under the plan's own seed only
        if all(at(f, path) == original[tuple(f["edge"])] for f in p["plan"]):
            assert p["seed"] == seeds[0], p
    if width >= len(seeds):  # every seed in one batch: the most violating of them
        assert all(robustness({**found, "seed": s}) >= r for s in seeds)
    if held is not None:
        start = min(max(t - held, 0.0) for t in threshold.values())
        a_at = [sev(at(f, path)) for p in flown for f in p["plan"] if tuple(f["edge"]) == tuple(ENTRIES[a])]
        assert all(v > start for v in a_at if v != losses[a]), (start, sorted(a_at)[:3])


@pytest.mark.unit
@settings(max_examples=100, deadline=None)
@given(
    windows=st.lists(
        st.tuples(st.one_of(st.none(), st.floats(0.0, 5.0)), st.floats(0.05, 20.0), st.floats(0.0, 0.99)),
        min_size=1,
        max_size=3,
    ),  # (from_s or none: from the start, the window's length, where the need lies past a period)
    cut=st.one_of(st.none(), st.integers(0, 3)),
    period=st.sampled_from([0.01, 0.1, 0.5]),
    steps=st.one_of(st.none(), st.integers(1, 8)),
)
def test_shrinking_shortens_each_window_to_what_the_violation_needs(windows, cut, period, steps):
    """A requirement broken exactly when each window is at least its own length long: each
    window's end is bisected (``steps`` at most, down to a control period) to within
    max(period, what is left of its length over a period / 2^steps) past what it needs, a
    window with no ``from_s`` from 0; an entry with no window (a kill, anywhere in the plan)
    keeps its fields; every plan flown is counted, under the plan's own seed (the others the
    space allows are for severities). A window is probed no more once its end is known within a
    period: log2(its length over a period) probes at most (``steps`` at most, 6 by default)."""
    entries, need = [], {}
    for k, (start, length, where) in enumerate(windows):
        length = max(length, 2 * period)
        need[k + 1] = period + where * (length - period)
        f = {"edge": [0, k + 1], "drop": True, "until_s": (start or 0.0) + length}
        entries.append(f if start is None else {**f, "from_s": start})
    if cut is not None:
        entries.insert(min(cut, len(entries)), {"controller": 1, "kill": True, "from_s": 1.0})
    plan = {"seed": 0, "plan": entries}

    def robustness(p: dict) -> float:
        if len(p["plan"]) < len(entries):  # an entry dropped: it holds
            return 1.0
        windows = [f for f in p["plan"] if "until_s" in f]
        slack = min(f["until_s"] - f.get("from_s", 0.0) - need[f["edge"][1]] for f in windows)
        return 1.0 if slack < -1e-9 else -1.0 - slack  # (a length's rounding is no shortfall)

    flown: list[dict] = []

    def check_many(plans: list[dict]) -> list[float]:
        flown.extend(plans)
        return [robustness(p) for p in plans]

    more = {} if steps is None else {"steps": steps}
    found, r, spent = shrink(plan, check_many, lambda f: [], period, (0, 1, 2), **more)
    steps = 6 if steps is None else steps
    assert spent == len(flown) and r == robustness(found) < 0
    assert len(found["plan"]) == len(entries) and found["seed"] == 0
    assert all(p["seed"] == 0 for p in flown)
    for f, g in zip(found["plan"], entries, strict=True):
        if "until_s" not in g:
            assert f == g
            continue
        start = g.get("from_s", 0.0)
        length, n = g["until_s"] - start, need[g["edge"][1]]
        assert f.get("from_s") == g.get("from_s") and f["until_s"] <= g["until_s"]
        left = max(period, (length - period) / 2**steps)
        assert n - 1e-9 <= f["until_s"] - start <= n + left + 1e-9, (f, n, left)
    halvings = [
        math.ceil(math.log2((g["until_s"] - g.get("from_s", 0.0) - period) / period))
        for g in entries
        if "until_s" in g
    ]  # (one more for a width a rounding leaves a hair over a period)
    # (the plan as given, flown once more for its figure where no probe broke the requirement)
    probes = [p for p in flown if len(p["plan"]) == len(entries) and p["plan"] != entries]
    assert len(probes) <= sum(min(steps, max(0, h) + 1) for h in halvings)


@pytest.mark.unit
def test_a_plan_nothing_can_shrink_is_flown_once_more_for_its_figure():
    """One entry, nothing searched in it and no window: shrinking changes nothing and flies the
    plan once, for the robustness it returns."""
    plan = {"seed": 3, "plan": [{"controller": 2, "kill": True, "from_s": 1.0}]}
    flown: list[dict] = []

    def check_many(plans: list[dict]) -> list[float]:
        flown.extend(plans)
        return [-0.25 for _ in plans]

    assert shrink(plan, check_many, lambda f: [], 0.01, (0, 3)) == (plan, -0.25, 1)
    assert flown == [plan]


@pytest.mark.unit
def test_a_value_is_read_where_its_path_leads_and_nowhere_else():
    f = {"loss": 0.3, "bursty": {"p": 0.2, "r": {"x": 1}}, "kill": True}
    assert at(f, ("loss",)) == 0.3 and at(f, ("bursty", "p")) == 0.2 and at(f, ("bursty", "r", "x")) == 1
    assert at(f, ("delay",)) is None and at(f, ("bursty", "q")) is None
    assert at(f, ("loss", "p")) is None and at(f, ("kill", "p")) is None  # (through a number: nothing)
    assert at(f, ()) == f


@pytest.mark.unit
@settings(max_examples=100, deadline=None)
@given(
    held=st.lists(
        st.tuples(
            st.integers(0, 2),
            st.floats(0.0, 1.0),
            st.sampled_from(["", "", "longer", "elsewhere"]),
            st.sampled_from([None, None, None, True, "0.1", "short"]),
        ),
        min_size=2,
        max_size=12,
    ),  # (seed, loss, another edge faulty too or another's loss, or a value that is not one): as a
    # search leaves them
    seeds=st.lists(st.integers(0, 2), max_size=3, unique=True),
    own=st.integers(0, 2),
    ours=st.floats(0.1, 1.0),
    flip=st.booleans(),
)
@example(  # a plan that differs elsewhere, more severe than the seed's own hold: it says nothing
    held=[(0, 0.5, "", None), (0, 0.7, "elsewhere", None)], seeds=[0], own=0, ours=0.8, flip=False
)
def test_the_severity_held_below_is_the_mildest_of_every_seeds_worst_hold(held, seeds, own, ours, flip):
    """Where bisection may start: for every seed the space allows (and the plan's own), the most
    severe value below the plan's at which the same plan otherwise held; the mildest of those,
    or None while any seed has none. Plans that differ elsewhere, that have fewer entries, or
    whose value there is no number say nothing. ``flip``: values grow milder upward (the range's
    mild end is 1): the same answer from the other side."""
    sev = (lambda v: 1.0 - v) if flip else (lambda v: v)

    def plan(seed, loss, other, junk=None):
        first = {"edge": [0, 1], "loss": sev(loss) if junk is None else junk}
        before = {"edge": [2, 3], "loss": 0.7 if other == "elsewhere" else 0.5}
        if loss < 0.5:  # (keys in another order: the same entry)
            before = {"loss": before["loss"], "edge": before["edge"]}
        entries = [before, first]  # the searched entry is the second
        if other == "longer":
            entries.append({"edge": [1, 2], "loss": 0.5})
        if junk == "short":
            entries = entries[:1]
        return {"seed": seed, "plan": entries}

    plans = [plan(s, v, other, junk) for s, v, other, junk in held]
    got = held_below(plan(own, ours, ""), 1, ("loss",), plans, seeds, sev(0.0))
    tops = {}
    for s in {*seeds, own}:
        below = [v for t, v, other, junk in held if t == s and v < ours and not other and junk is None]
        tops[s] = max(below) if below else None
    assert got == (None if None in tops.values() else sev(min(tops.values())))


def _left_in(tmp: Path) -> list[str]:
    """What a search left in ``tmp``, its processes' temporary directory, after it ended."""
    return sorted(p.name for p in tmp.iterdir() if p.name.startswith("swarm-sitl"))


@pytest.mark.system
def test_the_same_seed_writes_the_same_front_on_any_cores_and_on_dask(tmp_path, monkeypatch):
    """... and each search, its workers' unpacked configs with it, leaves nothing in the
    temporary directory (a worker's directory was once left there for good, one per worker)."""
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    monkeypatch.setenv("TMPDIR", str(tmp))
    monkeypatch.setattr(tempfile, "tempdir", None)  # (this process's: read from TMPDIR again)
    (tmp_path / "space.yaml").write_text(
        yaml.safe_dump({"seeds": [0, 1], "entries": [{"edges": "each", "loss": [0.5, 1.0]}]})
    )
    (tmp_path / "spec.yaml").write_text(
        '- {name: estimate, formula: "always[2, end] (est_pos_err_m <= 1e-4)"}\n'
    )
    fronts = []
    for jobs in (1, 2):  # (with the cluster's below: three runs of one seed, in three ways, equal)
        out = tmp_path / f"j{jobs}-{len(fronts)}"
        r = cli(
            "falsify", PAPER, "--space", tmp_path / "space.yaml", "--spec", tmp_path / "spec.yaml",
            "--duration", "4", "--budget", "8", "--jobs", jobs, "--no-confirm", "--quiet", "--out", out,
        )  # fmt: skip
        assert r.returncode in (0, 3), r.stderr + r.stdout
        assert "per minute" in r.stdout
        fronts.append((out / "front.csv").read_bytes())
        assert _left_in(tmp) == []
        assert (out / "robustness_cost.png").stat().st_size > 0 and (out / "edges.png").is_file()
    assert fronts[0] == fronts[1]
    from distributed import LocalCluster

    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None) as c:
        falsify(
            PAPER, tmp_path / "dask", space=tmp_path / "space.yaml", spec=tmp_path / "spec.yaml",
            duration_s=4.0, budget=8, confirm=False, scheduler=c.scheduler_address, say=lambda s: None,
        )  # fmt: skip
    assert (tmp_path / "dask" / "front.csv").read_bytes() == fronts[0]  # on a cluster: the same
    assert _left_in(tmp) == []  # (a Dask worker's: removed as its process ended)
    rows = fronts[0].decode().splitlines()
    assert len(rows) >= 3  # a header and plans that trade cost against robustness
    assert any(",1," in r for r in rows[1:]) and any(",0," in r for r in rows[1:])  # some break it


@pytest.mark.system
def test_a_minimal_counterexample_on_a_ring_of_six_replays_as_processes(tmp_path):
    """A generated ring of six followers (a cycle 1 -> ... -> 6 -> 1, the leader into 1) held to
    5 cm from 9 s on, under the default space (loss, cuts and delays on every edge): a violating
    plan of at most two entries within 200 evaluations; removing any of its entries makes the
    requirement hold; its lockstep run as processes has the same robustness, bit for bit."""
    config = tmp_path / "ring6.yaml"
    config.write_text(generate(6, "ring", "grid", "helix", seed=0, duration_s=12.0))
    spec = tmp_path / "spec.yaml"
    spec.write_text('- {name: formation, formula: "always[9, end] (pos_err_m <= 0.05)"}\n')
    # (one worker: this file's tests run beside the real-time ones, which need their share of CPU)
    found = falsify(config, tmp_path / "out", spec=spec, budget=8, seed=0, jobs=1, say=lambda s: None)
    assert found.baseline >= 0  # it holds without a fault
    assert found.plan is not None and found.evaluations <= 200
    assert 1 <= len(found.plan["plan"]) <= 2 and found.robustness < 0
    assert found.confirmed is True  # the lockstep run: the same robustness
    cfg, name = requirement_config(with_spec(load_config(config), spec), None, None)
    assert evaluate(cfg, name, found.plan) == found.robustness  # the file replays it in sim too
    for j in range(len(found.plan["plan"])):
        rest = {**found.plan, "plan": found.plan["plan"][:j] + found.plan["plan"][j + 1 :]}
        assert evaluate(cfg, name, rest) >= 0, rest
    written = yaml.safe_load(found.counterexample.read_text())
    assert written == json.loads(json.dumps(found.plan))


@pytest.mark.system
def test_the_helper_a_users_test_calls_fails_naming_the_counterexample_only_within_its_cost(tmp_path):
    """``assert_no_counterexample``: a plan that breaks the requirement at a cost within
    ``max_cost`` fails the caller's test naming the plan's file (which replays it); the same
    search allowed a lower ``max_cost`` than the plan it finds passes and returns what it found."""
    space, spec = _estimate_space(tmp_path)
    args = {"space": space, "spec": spec, "budget": 2, "duration_s": 4.0, "jobs": 1}
    with pytest.raises(AssertionError, match=str(tmp_path / "helper" / "counterexamples")):
        assert_no_counterexample(PAPER, tmp_path / "helper", max_cost=1e9, **args)
    found = assert_no_counterexample(PAPER, tmp_path / "cheaper", max_cost=0.0, **args)
    assert found.plan is not None and found.cost > 0.0 and found.robustness < 0
    assert yaml.safe_load(found.counterexample.read_text()) == json.loads(json.dumps(found.plan))


def _estimate_space(tmp_path):
    (tmp_path / "space.yaml").write_text(
        yaml.safe_dump({"seeds": [0, 1], "entries": [{"edges": "each", "loss": [0.5, 1.0]}]})
    )
    (tmp_path / "spec.yaml").write_text(
        '- {name: estimate, formula: "always[2, end] (est_pos_err_m <= 1e-4)"}\n'
    )
    return tmp_path / "space.yaml", tmp_path / "spec.yaml"


@pytest.mark.system
def test_a_search_resumes_its_study_and_ctrl_c_keeps_what_was_found(tmp_path):
    import optuna

    space, spec = _estimate_space(tmp_path)
    out = tmp_path / "out"
    args = {
        "space": space,
        "spec": spec,
        "duration_s": 4.0,
        "confirm": False,
        "jobs": 1,
        "say": lambda s: None,
    }
    falsify(PAPER, out, budget=4, **args)
    again = falsify(PAPER, out, budget=8, **args)  # the same directory: four more, not eight
    study = optuna.load_study(study_name="falsify", storage=f"sqlite:///{out / 'study.db'}")
    assert len(study.trials) == 8
    assert again.evaluations >= 1 + 4  # the baseline and the four new (and any shrinking)
    # Ctrl-C after the first batch: exit 130, and what the study holds is written
    stop = tmp_path / "stopped"
    argv = [
        "falsify",
        PAPER,
        "--space",
        space,
        "--spec",
        spec,
        "--duration",
        4,
        "--budget",
        400,
        "--jobs",
        1,
    ]
    p = start_cli(*argv, "--no-confirm", "--out", stop, start_new_session=False)
    assert p.stdout is not None
    for line in p.stdout:
        if line.startswith("falsify: 4/400"):
            break
    p.send_signal(signal.SIGINT)
    rest, err = p.communicate(timeout=120)
    assert p.returncode == 130, err
    assert "interrupted" in rest
    kept = (stop / "evaluations.csv").read_text().splitlines()
    assert len(kept) >= 1 + 4  # the header and at least the first batch
    assert (stop / "report.md").is_file() and (stop / "front.csv").is_file()


@pytest.mark.system
def test_a_law_that_ends_its_worker_is_a_violation_and_the_pool_goes_on(tmp_path, monkeypatch):
    """A user's law held in compiled code when it hears nobody (``HeldWhenDeaf``): a cut of the
    edge 0 -> 1 longer than the staleness ends its worker process (its guard's hard stop). In a
    batch, each such plan is found (flown again one at a time), counted as a violation, and the
    pool is made again for the next plans. The ended workers' files go with the evaluator."""
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    monkeypatch.setenv("TMPDIR", str(tmp))
    monkeypatch.setattr(tempfile, "tempdir", None)
    from swarm_sitl.falsify.workers import NO_ROBUSTNESS, Local
    from tests.misbehaving_runs import LAWS_FILE

    data = yaml.safe_load((CONFIGS / "paper.yaml").read_text())
    data["duration_s"] = 1.5
    data["law"] = {"entry": f"{LAWS_FILE}:HeldWhenDeaf"}
    data["run"] = {**data.get("run", {}), "tick_timeout_s": 0.2}
    data["spec"] = [{"name": "up", "formula": "always (altitude_m >= -1000)"}]
    config = tmp_path / "held.yaml"
    config.write_text(yaml.safe_dump(data))
    cfg, name = requirement_config(load_config(config), None, None)

    def cut(until_s: float) -> dict:
        return {"seed": 0, "plan": [{"edge": [0, 1], "drop": True, "from_s": 0.3, "until_s": until_s}]}

    ev = Local(1, cfg, name)
    try:
        # 0.3 s cut: heard within the staleness; 1 s: deaf from 0.81 s on, held for good
        got = ev.map([cut(1.3), cut(0.6), cut(1.3)])
        held = evaluate(cfg, name, cut(0.6))  # the same plan in this process: bit for bit
        assert got[0] == got[2] == NO_ROBUSTNESS and got[1] == held and ev.ended == 2
        assert held == pytest.approx(997.0, abs=1e-3)  # (its altitude: 3 m below the origin)
        assert ev.map([cut(0.6), cut(0.5)]) == [held, evaluate(cfg, name, cut(0.5))]  # the pool made again
    finally:
        ev.close()
    assert _left_in(tmp) == []


#: a user's link model in a file: every message lost outside the first ``on_fraction`` of each
#: period; ``fails``: "raise" raises at 0.5 s, "die" ends the process there (after a line)
DUTY_LINK = """
import os
import sys

from pydantic import BaseModel, Field

from swarm_sitl.faults.link_model import Effect


class DutyCycleOutage:
    class Params(BaseModel):
        period_s: float = Field(gt=0)
        on_fraction: float = Field(ge=0, le=1)
        fails: str = "no"

    def fate(self, p, m):
        if p.fails != "no" and m.t_s >= 0.5:
            if p.fails == "die":
                print("duty link: the outage table is gone", file=sys.stderr, flush=True)
                os._exit(7)
            raise RuntimeError("the outage table is gone")
        return None if (m.t_s % p.period_s) < p.on_fraction * p.period_s else Effect(lost=True)
"""


def _duty_config(tmp_path, fails: str = "no", on_fraction: float = 0.0) -> tuple:
    """The paper's swarm for 3 s, its leader's edges under the user's duty-cycle model (a file
    beside the config, named relative to it), judged by a requirement it can meet or not."""
    (tmp_path / "duty_link.py").write_text(DUTY_LINK)
    data = yaml.safe_load((CONFIGS / "paper.yaml").read_text())
    data["duration_s"] = 3.0
    params = {"period_s": 1.0, "on_fraction": on_fraction, "fails": fails}
    data["faults"] = {
        "plan": [{"leader_edges": True, "model": {"entry": "duty_link.py:DutyCycleOutage", "params": params}}]
    }
    data["spec"] = [{"name": "near", "formula": "always[2, end] (pos_err_m <= 2.0)"}]
    path = tmp_path / "duty.yaml"
    path.write_text(yaml.safe_dump(data))
    (tmp_path / "space.yaml").write_text("entries:\n  - {edges: each, loss: [0.0, 1.0]}\n")
    return path, tmp_path / "space.yaml"


@pytest.mark.system
def test_a_configs_own_file_link_model_is_shipped_to_workers_and_flown_under_every_plan(tmp_path):
    """A config whose own ``faults:`` names a link model in a file (issue 46: its worker died
    importing it and the search said "fails without any fault"): the file is shipped with the
    config, the config's own plan flies under the searched plans, so the baseline is exactly the
    robustness ``sim`` gives the config as written (not the fault-free one), and the
    counterexample file holds the config's entries before the searched ones."""
    from swarm_sitl.falsify.evaluate import robustness_of
    from swarm_sitl.running.sim import run_sim

    for on_fraction in (0.0, 1.0):  # every leader message lost; none
        config, space = _duty_config(tmp_path, on_fraction=on_fraction)
        cfg, name = requirement_config(load_config(config), None, None)
        as_written = robustness_of(cfg, run_sim(cfg), name)
        free = cfg.model_copy(update={"faults": type(cfg.faults)()})
        out = tmp_path / f"out{on_fraction:g}"
        found = falsify(
            config, out, space=space, budget=4, jobs=1, batch=2, confirm=False, say=lambda s: None
        )
        assert found.baseline == pytest.approx(as_written, rel=0, abs=0), (found.baseline, as_written)
        if on_fraction == 0.0:  # the own plan breaks the requirement: nothing to search for
            assert as_written < 0 <= robustness_of(free, run_sim(free), name)
            assert "own plan alone" in (out / "report.md").read_text()
        else:
            assert found.evaluations >= 4 and found.baseline >= 0
            if found.plan is not None:
                assert found.plan["plan"][0]["model"]["entry"].endswith("duty_link.py:DutyCycleOutage")


@pytest.mark.system
@pytest.mark.parametrize(
    ("fails", "said"),
    [("raise", "RuntimeError: the outage table is gone"), ("die", "duty link: the outage table is gone")],
)
def test_a_worker_that_fails_is_an_error_naming_the_plan_the_worker_and_its_last_line(tmp_path, fails, said):
    """A plan a worker cannot fly (its flight raised; its process died with a line on stderr) ends
    ``falsify`` with exit 1 and one line naming the plan, the worker and what it last said;
    ``report.md`` gives no verdict on the swarm."""
    config, space = _duty_config(tmp_path, fails=fails)
    out = tmp_path / "out"
    r = cli("falsify", config, "--space", space, "--out", out, "--jobs", "1", "--budget", "2", "--no-confirm")
    assert r.returncode == 1, (r.stdout, r.stderr)
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and said in lines[0] and "worker" in lines[0] and '"plan"' in lines[0], lines
    if fails == "die":
        assert "exit code 7" in lines[0]
    report = (out / "report.md").read_text()
    assert "Nothing is said of the swarm" in report and "robustness" not in report
