"""A campaign's bookkeeping (``campaigns.sweep``), its runs stood in for by a model whose error is
known in closed form: each row judged against the bound (at the bound: held), its record saying
what it is, a campaign run again with another bound judged again without flying, the bisection's
steps and what they keep, an interrupted campaign drawing nothing, and the campaign's inputs
refused in one line before anything runs. (The flights themselves: ``test_sweep.py``.)"""

import json
import math
import re

import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

import swarm_sitl.campaigns.sweep as sweep_mod
from swarm_sitl.campaigns.breaking import toward
from swarm_sitl.campaigns.point import METRICS
from swarm_sitl.campaigns.table import SPEC
from swarm_sitl.config.load import ConfigError
from tests.support import CONFIGS, config

pytestmark = pytest.mark.integration

PAPER = CONFIGS / "paper.yaml"
KEY = "link.loss"


def _error_m(task) -> float:
    """The stand-in's error: the swept value itself, plus a thousandth per seed."""
    return task.key[0] + task.key[-1] / 1000


class _Flights:
    """``run_local`` stood in for: every task handed noted, its row the model's error (and, for each
    requirement named, a robustness of ``0.4 - error``); ``stop_after`` rows, then Ctrl-C."""

    def __init__(self, requirements=(), stop_after: int | None = None):
        self.requirements, self.stop_after = requirements, stop_after
        self.handed: list = []

    def __call__(self, tasks, jobs):
        for t in tasks:
            if self.stop_after is not None and len(self.handed) >= self.stop_after:
                raise KeyboardInterrupt
            self.handed.append(t)
            err = _error_m(t)
            row = {m: 0.0 for m in METRICS} | {"failure": "", "max_error_m": err}
            yield t, row | {f"{SPEC}{r}": 0.4 - err for r in self.requirements}


@pytest.fixture
def flights(monkeypatch):
    f = _Flights()
    monkeypatch.setattr(sweep_mod, "run_local", f)
    drawn: list = []
    monkeypatch.setattr(sweep_mod, "draw", lambda c: drawn.append(c) or [])
    f.drawn = drawn
    return f


@settings(max_examples=200, deadline=None)
@given(
    bound=st.floats(1e-6, 10.0),
    err=st.one_of(st.floats(0.0, 20.0), st.just(math.nan), st.just("bound")),
    failure=st.sampled_from(["", "follower 2 lost"]),
    robustness=st.lists(st.one_of(st.floats(-5.0, 5.0), st.just(0.0), st.just(math.nan)), max_size=3),
)
def test_a_row_passes_if_it_completed_its_error_is_within_the_bound_and_every_requirement_holds(
    bound, err, failure, robustness
):
    """At the bound is within it, NaN is not, and a robustness of zero holds."""
    err = bound if err == "bound" else err
    row = {"failure": failure, "max_error_m": err} | {f"{SPEC}r{i}": v for i, v in enumerate(robustness)}
    sweep_mod.judge([row], bound)
    held = all(v >= 0 for v in robustness)  # (NaN >= 0 is False)
    assert row["passed"] == int(failure == "" and err <= bound and held)


def test_a_campaign_records_what_it_is_and_each_rows_verdict(tmp_path, flights):
    """``campaign.json``: the config (a file's path, or a config object's name), the keys, values,
    seeds, bound and duration; every row judged against the bound as it came."""
    for source, named in ((PAPER, str(PAPER)), (config("paper"), config("paper").name)):
        out = tmp_path / f"c{len(flights.handed)}"
        c = sweep_mod.sweep(source, {KEY: [0.0, 0.3]}, out=out, seeds=[0, 2], bound_m=0.1, duration_s=25.0)
        recorded = json.loads((out / "campaign.json").read_text())
        assert recorded["config"] == named and recorded["keys"] == [KEY]
        assert recorded["values"] == {KEY: [0.0, 0.3]} and recorded["seeds"] == [0, 2]
        assert recorded["bound_m"] == 0.1 and recorded["duration_s"] == 25.0
        assert sorted((r[KEY], r["seed"], r["passed"]) for r in c.rows) == [
            (0.0, 0, 1), (0.0, 2, 1), (0.3, 0, 0), (0.3, 2, 0)
        ]  # fmt: skip


def test_another_bound_judges_the_same_rows_again_and_flies_none(tmp_path, flights):
    out = tmp_path / "c"
    sweep_mod.sweep(PAPER, {KEY: [0.0, 0.2, 0.4]}, out=out, seeds=1, bound_m=0.1)
    flown = len(flights.handed)
    c = sweep_mod.sweep(PAPER, {KEY: [0.0, 0.2, 0.4]}, out=out, seeds=1, bound_m=0.3)
    assert len(flights.handed) == flown == 3  # (the same flights: nothing new to fly)
    assert {r[KEY]: r["passed"] for r in c.rows} == {0.0: 1, 0.2: 1, 0.4: 0}
    assert json.loads((out / "campaign.json").read_text())["bound_m"] == 0.3


@settings(max_examples=6, deadline=None)
@given(
    first=st.sets(st.sampled_from([0.0, 0.1, 0.2, 0.3]), min_size=1),
    second=st.sets(st.sampled_from([0.0, 0.1, 0.2, 0.3]), min_size=1),
    seeds=st.tuples(st.sets(st.integers(0, 2), min_size=1), st.sets(st.integers(0, 2), min_size=1)),
)
def test_a_campaign_run_again_with_other_values_records_the_union_of_both(
    tmp_path_factory, first, second, seeds
):
    """Either call's values and seeds (neither a superset of the other, drawn at random): the
    record holds the union, and the table every run either asked for."""
    out = tmp_path_factory.mktemp("union")
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(sweep_mod, "run_local", _Flights())
        mp.setattr(sweep_mod, "draw", lambda c: [])
        sweep_mod.sweep(PAPER, {KEY: sorted(first)}, out=out, seeds=sorted(seeds[0]), bound_m=0.5)
        c = sweep_mod.sweep(PAPER, {KEY: sorted(second)}, out=out, seeds=sorted(seeds[1]), bound_m=0.5)
    recorded = json.loads((out / "campaign.json").read_text())
    assert recorded["values"] == {KEY: sorted(first | second)}
    assert recorded["seeds"] == sorted(seeds[0] | seeds[1])
    asked = {(v, s) for v in first for s in seeds[0]} | {(v, s) for v in second for s in seeds[1]}
    assert sorted((r[KEY], r["seed"]) for r in c.rows) == sorted(asked)


def test_the_bisection_halves_between_the_last_hold_and_the_first_break_keeping_its_runs(tmp_path, flights):
    """Error = loss (one seed): with a bound of 0.5 between 0.0 (held) and 1.0 (broke), three steps
    fly 0.5 (held: at the bound), 0.75 and 0.625, each row marked refined and its run kept."""
    c = sweep_mod.sweep(PAPER, {KEY: [0.0, 1.0]}, out=tmp_path / "c", seeds=[0], bound_m=0.5, refine=3,
                        keep_runs=True)  # fmt: skip
    assert [t.key[0] for t in flights.handed] == [0.0, 1.0, 0.5, 0.75, 0.625]
    assert all(t.keep_dir == str(tmp_path / "c" / "runs" / t.name) for t in flights.handed)
    assert {r[KEY]: r["refined"] for r in c.rows} == {0.0: 0, 0.5: 1, 0.625: 1, 0.75: 1, 1.0: 0}
    assert c.breaking_point() == (0.5, 0.625) and len(flights.drawn) == 1


def test_a_campaign_with_nothing_to_bisect_or_not_asked_to_ends_as_any_other(tmp_path, flights):
    """Every value holds (no break to bisect towards), or no ``refine`` (the default): the grid's
    runs only, the table written sorted and the figures drawn."""
    held = sweep_mod.sweep(PAPER, {KEY: [0.2, 0.0]}, out=tmp_path / "a", seeds=[0], bound_m=0.5, refine=4)
    plain = sweep_mod.sweep(PAPER, {KEY: [0.0, 1.0]}, out=tmp_path / "b", seeds=[0], bound_m=0.5)
    for c, values in ((held, [0.0, 0.2]), (plain, [0.0, 1.0])):
        assert isinstance(c, sweep_mod.Campaign) and [r[KEY] for r in c.rows] == values
        assert all(r["refined"] == 0 for r in c.rows)
        table = c.table.read_text().splitlines()[1:]
        assert [float(line.split(",")[0]) for line in table] == values
    assert [t.key[0] for t in flights.handed] == [0.0, 0.2, 0.0, 1.0] and len(flights.drawn) == 2


def test_an_interrupted_campaign_keeps_its_rows_and_draws_nothing(tmp_path, monkeypatch, flights):
    monkeypatch.setattr(sweep_mod, "run_local", _Flights(stop_after=2))
    c = sweep_mod.sweep(PAPER, {KEY: [0.0, 0.1, 0.2, 0.3]}, out=tmp_path / "c", seeds=1, bound_m=0.5)
    assert isinstance(c.interrupted, KeyboardInterrupt) and len(c.rows) == 2
    assert flights.drawn == [] and c.figures == []
    assert len(c.table.read_text().splitlines()) == 3


def test_a_requirement_is_a_column_whether_the_config_is_a_file_or_an_object(tmp_path, monkeypatch):
    """``spec``: each requirement's robustness a column of the table, and a run passes only if
    every one holds (robustness ``0.4 - error`` in the stand-in: 0.5 breaks it, within the bound)."""
    spec = tmp_path / "spec.yaml"
    spec.write_text('- {name: apart, formula: "always (pos_err_m <= 1)"}\n'
                    '- {name: tight, formula: "always (pos_err_m <= 2)"}\n')  # fmt: skip
    monkeypatch.setattr(sweep_mod, "run_local", _Flights(requirements=("apart", "tight")))
    monkeypatch.setattr(sweep_mod, "draw", lambda c: [])
    for source in (PAPER, config("paper")):
        out = tmp_path / f"c{id(source)}"
        c = sweep_mod.sweep(source, {KEY: [0.0, 0.5]}, out=out, seeds=1, bound_m=1.0, spec=spec)
        header = c.table.read_text().splitlines()[0].split(",")
        assert header[-3:] == [f"{SPEC}apart", f"{SPEC}tight", "config"]
        assert {r[KEY]: r["passed"] for r in c.rows} == {0.0: 1, 0.5: 0}


def test_a_base_plan_is_under_every_point(tmp_path, flights):
    """``faults``: the plan's entries in every run's config, the swept ones with them."""
    cut = {"edge": [0, 1], "drop": True, "from_s": 1.0, "until_s": 2.0}
    sweep_mod.sweep(PAPER, {KEY: [0.0, 0.2]}, out=tmp_path / "c", seeds=[3], bound_m=0.5,
                    faults={"seed": 7, "plan": [cut]})  # fmt: skip
    for t in flights.handed:
        plan = yaml.safe_load(t.config_yaml)["faults"]["plan"]
        assert any(e.get("edge") == [0, 1] and e.get("drop") and e.get("from_s") == 1.0 for e in plan), plan


def test_values_as_text_in_a_mapping_are_the_command_lines_values(tmp_path, flights):
    a = sweep_mod.sweep(PAPER, {KEY: "0:0.3:0.1"}, out=tmp_path / "a", seeds=1, bound_m=0.5)
    b = sweep_mod.sweep(PAPER, [f"{KEY}=0:0.3:0.1"], out=tmp_path / "b", seeds=1, bound_m=0.5)
    assert [r[KEY] for r in a.rows] == [r[KEY] for r in b.rows] and len(a.rows) == 4


def test_the_progress_bar_names_the_swept_keys_and_counts_runs(tmp_path, flights, capsys):
    sweep_mod.sweep(PAPER, {KEY: [0.0, 0.1]}, out=tmp_path / "c", seeds=1, bound_m=0.5, progress=True)
    err = capsys.readouterr().err
    assert f"sweep {KEY}:" in err and re.search(r"2/2 \[.*(run/s|s/run)\]", err), err


@pytest.mark.parametrize(
    ("kw", "says"),
    [
        ({"seeds": []}, r"^sweep: seeds must be a positive count or non-negative integers, got \[\]$"),
        ({"seeds": 0}, r"^sweep: seeds must be a positive count or non-negative integers, got 0$"),
        ({"seeds": [2, -1]}, r"^sweep: seeds must be .* got \[2, -1\]$"),
        ({"point_timeout_s": 0.0}, r"^sweep: --point-timeout must be a number of seconds > 0, got 0.0$"),
        ({"point_timeout_s": math.inf}, r"^sweep: --point-timeout must be .* got inf$"),
    ],
)
def test_a_campaign_it_cannot_run_is_one_line_before_anything_runs(tmp_path, flights, kw, says):
    with pytest.raises(sweep_mod.SweepSpecError, match=says):
        sweep_mod.sweep(PAPER, {KEY: [0.0]}, out=tmp_path / "c", bound_m=0.5, **{"seeds": 1, **kw})
    assert flights.handed == [] and not (tmp_path / "c").exists()


def test_a_base_that_is_not_a_valid_config_is_one_line_naming_the_sweep(tmp_path, flights):
    with pytest.raises(ConfigError, match=r"^sweep: .*duration_s"):
        sweep_mod.sweep(PAPER, {KEY: [0.0]}, out=tmp_path / "c", seeds=1, bound_m=0.5, duration_s=-1.0)


def test_an_out_that_cannot_hold_the_campaign_is_one_line_saying_why(tmp_path, flights):
    sweep_mod.sweep(PAPER, {KEY: [0.0]}, out=tmp_path / "c", seeds=1, bound_m=0.5)
    with pytest.raises(
        sweep_mod.SweepSpecError,
        match=rf"^--out {tmp_path / 'c'} holds another campaign \(its config, plan or swept keys differ\); "
        "give another --out$",
    ):
        sweep_mod.sweep(PAPER, {"link.delay_s": [0.0]}, out=tmp_path / "c", seeds=1, bound_m=0.5)
    (tmp_path / "file").write_text("x")
    under = tmp_path / "file" / "c"
    with pytest.raises(
        sweep_mod.SweepSpecError, match=rf"^--out {under}: cannot write there \(Not a directory\)$"
    ):
        sweep_mod.sweep(PAPER, {KEY: [0.0]}, out=under, seeds=1, bound_m=0.5)


def test_the_summary_says_which_way_the_key_breaks(tmp_path, flights):
    c = sweep_mod.sweep(PAPER, {KEY: [0.0, 1.0]}, out=tmp_path / "c", seeds=1, bound_m=0.5)
    lines = sweep_mod.summary_lines(c)
    assert lines[0] == f"2 runs in {c.table} (1 held the bound of 0.5 m)"
    assert (
        lines[1] == f"breaking point: every seed holds the bound {toward(KEY)} {KEY} = 0; a seed breaks at 1"
    )
