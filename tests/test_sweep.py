"""Robustness campaigns (``swarm-sitl sweep``, ``swarm_sitl.sweep``): the grid and its specs, the
breaking point and its bisection, the table; and campaigns of real lockstep runs, judged again at
another bound, interrupted and resumed, and each row run again from its config (on a local Dask
cluster, the same rows: ``test_sweep_plugins.py``)."""

import csv
import math
import signal
import time
from pathlib import Path

import pytest
import yaml
from hypothesis import given
from hypothesis import strategies as st

from swarm_sitl.campaigns.breaking import breaking_point
from swarm_sitl.campaigns.grid import SweepSpecError, grid, parse_values, parse_vary, point_data
from swarm_sitl.campaigns.table import TableWriter, read_rows, row_key
from swarm_sitl.config.load import ConfigError, parse_config
from tests.support import CONFIGS, cli, cli_in_process, config, start_cli

#: its system tests run in lockstep or ``sim`` only (no wall clock): free to run beside others
pytestmark = pytest.mark.lockstep


@pytest.mark.unit
def test_values_are_a_range_with_its_end_or_a_list_and_a_bad_one_is_one_line():
    assert parse_values("k", "0:0.95:0.05") == [round(0.05 * i, 12) for i in range(20)]
    assert parse_values("k", "0:1:0.3") == [0.0, 0.3, 0.6, 0.9]  # steps that miss the end stop short
    assert parse_values("k", "0.5,0,0.5,0.1") == [0.0, 0.1, 0.5]
    assert parse_vary("link.loss=0:0.2:0.1") == ("link.loss", [0.0, 0.1, 0.2])
    for spec, message in [
        ("link.loss=0.5:0.1:0.1", r"sweep link\.loss: the range '0.5:0.1:0.1' is empty"),
        ("link.loss=0:1:0", r"the step of '0:1:0' must be positive"),
        ("link.loss=", r"sweep link\.loss: no values in ''"),
        ("link.loss=a,b", r"'a,b' is not START:STOP:STEP or a list of numbers"),
        ("link.loss=0:1", r"a range is START:STOP:STEP, got '0:1'"),
        ("link.loss=nan", r"has a value that is not finite"),
        ("0.5", r"'0.5' is not KEY=VALUES"),
    ]:
        with pytest.raises(SweepSpecError, match=message):
            parse_vary(spec)


@pytest.mark.unit
def test_a_point_puts_one_entry_per_follower_and_sets_config_paths(paper_cfg):
    base = paper_cfg.data()
    data = point_data(
        base, {"link.loss": 0.3, "link.delay_s": 0.1, "link.jitter_s": 0.02, "gains.k_p": 9.0}, 7
    )
    ids = [f["id"] for f in base["followers"]]
    assert data["seed"] == 7 and "seed" not in data["faults"] and data["gains"]["k_p"] == 9.0
    assert data["faults"]["plan"] == [{"into": i, "loss": 0.3} for i in ids] + [
        {"into": i, "delay_s": 0.1, "jitter_s": 0.02} for i in ids
    ]
    assert point_data(base, {"link.loss": 0.0}, 1)["faults"]["plan"] == []  # zero: no entry
    mav = point_data(base, {"mavlink.loss": 0.2, "followers.1.offset_m.0": 2.0}, 1)
    assert (
        mav["faults"]["plan"] == [{"mavlink": i, "loss": 0.2} for i in ids]
        and mav["followers"][1]["offset_m"][0] == 2.0
    )
    assert base["faults"]["plan"] == []  # the base is not changed
    for point, message in [
        ({"gains.kp": 1.0}, r"sweep gains\.kp: no setting 'gains\.kp' in the config \(there: .*k_p"),
        ({"gains": 1.0}, r"sweep gains: gains is a section, not a value"),
        ({"duration_s.x.y": 1.0}, r"^sweep duration_s\.x\.y: duration_s is a value, not a section$"),
        ({"followers.9.mass_kg": 1.0}, r"followers\.9: no item 9 \(the list has 4\)"),
        ({"link.lost": 0.1}, r"link\.\* is one of link\.loss, "),
        ({"faults.seed": 1.0}, r"the seed is --seeds"),
    ]:
        with pytest.raises(SweepSpecError, match=message):
            point_data(base, point, 0)
    assert len(grid([("a", [1.0, 2.0]), ("b", [3.0, 4.0, 5.0])])) == 6


@pytest.mark.unit
def test_a_link_models_parameters_make_one_entry_on_every_edge_and_a_missing_one_is_named(paper_cfg):
    base = paper_cfg.data()
    data = point_data(
        base,
        {
            "link.bursty.p": 0.05,
            "link.bursty.r": 0.25,
            "link.range.range_m": 30.0,
            "link.range.fading_db": 0.0,
        },
        2,
    )
    assert data["faults"]["plan"] == [
        {"all_edges": True, "bursty": {"p": 0.05, "r": 0.25}},
        {"all_edges": True, "range": {"range_m": 30.0, "fading_db": 0.0}},  # 0 for an optional one: kept
    ]
    cfg = parse_config(data, "point")  # the entries are plan entries
    assert (
        cfg.faults.plan[1].range is not None
        and cfg.faults.plan[1].edges(cfg.graph_edges()) == cfg.graph_edges()
    )
    assert point_data(base, {"link.bursty.p": 0.0, "link.bursty.r": 0.25}, 1)["faults"]["plan"] == []
    zero = point_data(base, {"link.range.range_m": 0.0}, 1)  # not "no limit": refused as in a plan
    with pytest.raises(ConfigError, match=r"faults\.plan\.0\.range\.range_m: .*greater than 0"):
        parse_config(zero, "point")
    budget = point_data(base, {"link.bandwidth.rate_bps": 64000.0, "link.bandwidth.queue": 4.0}, 1)
    assert parse_config(budget, "point").faults.plan[0].bandwidth.queue == 4
    for point, message in [
        ({"link.bursty.p": 0.1}, r"sweep link\.bursty\.p: a bursty link needs link\.bursty\.r too"),
        ({"link.radio.range_m": 3.0}, r"link\.MODEL\.PARAM is a model of bursty, range, bandwidth"),
        ({"link.range.sigma": 3.0}, r"range has no parameter 'sigma' \(link\.range\.range_m, "),
    ]:
        with pytest.raises(SweepSpecError, match=message):
            point_data(base, point, 0)


@pytest.mark.unit
def test_the_breaking_point_is_the_last_value_before_any_seed_fails():
    def rows(*cells):  # (value, passed) per run
        return [{"x": v, "passed": p} for v, p in cells]

    assert breaking_point(rows((0, 1), (0, 1), (0.5, 1), (0.5, 0), (0.9, 1)), "x") == (0, 0.5)
    assert breaking_point(rows((0, 1), (0.5, 1)), "x") == (0.5, None)
    assert breaking_point(rows((0, 0), (0.5, 1)), "x") == (None, 0)
    # a value that holds after one that broke does not move the point (the first break counts)
    assert breaking_point(rows((0.1, 1), (0.2, 0), (0.3, 1)), "x") == (0.1, 0.2)
    # a radio's range is harsher as it shrinks: read from the largest down
    key = "link.range.range_m"
    ranged = [{key: v, "passed": ok} for v, ok in ((5, 0), (10, 1), (10, 0), (20, 1), (40, 1))]
    assert breaking_point(ranged, key) == (20, 10) and breaking_point(ranged[3:], key) == (20, None)


@pytest.mark.unit
def test_the_table_keeps_each_row_as_it_comes_and_reads_back_what_it_wrote(tmp_path):
    path = tmp_path / "table.csv"
    w = TableWriter(path, ["link.loss"])
    row = {
        "link.loss": 0.1,
        "seed": 2,
        "refined": 0,
        "passed": 1,
        "max_error_m": 0.01,
        "recovered_s": math.nan,
    }
    w.add({**row, "failure": "", "config": "points/a.yaml"})
    back = read_rows(path, ["link.loss"])  # before close: on disk already
    assert len(back) == 1 and back[0]["max_error_m"] == 0.01 and math.isnan(back[0]["recovered_s"])
    assert row_key(["link.loss"], back[0]) == (0.1, 2)
    w.close()
    TableWriter(path, ["link.loss"]).close()  # opened again: no second header
    assert len(list(csv.reader(path.open()))) == 2


def _config(tmp_path, duration_s=4.0):
    cfg = yaml.safe_load((CONFIGS / "paper.yaml").read_text())
    cfg["duration_s"] = duration_s
    cfg["run"] = {**cfg.get("run", {}), "settle_s": 2.0, "max_formation_error_m": 1.0}
    path = tmp_path / "small.yaml"
    path.write_text(yaml.safe_dump(cfg))
    return path


def _sweep(*args, timeout=300):
    return cli("sweep", *map(str, args), "--quiet", timeout=timeout)


@pytest.mark.system
def test_a_campaign_writes_one_row_per_run_is_judged_again_and_each_row_runs_again_from_its_config(tmp_path):
    out = tmp_path / "c"
    cfg = _config(tmp_path)
    r = _sweep(cfg, "--vary", "link.loss=0,0.6", "--seeds", "2", "--out", out, "--jobs", "2")
    assert r.returncode == 0, r.stderr
    rows = read_rows(out / "table.csv", ["link.loss"])
    assert [(x["link.loss"], x["seed"]) for x in rows] == [(0.0, 0), (0.0, 1), (0.6, 0), (0.6, 1)]
    for x in rows:
        assert x["failure"] == "" and x["passed"] == int(x["max_error_m"] <= 1.0)
        lost = 1.0 - x["delivered_mean"]  # every edge loses 0.6 of its messages, within 5 sigma
        assert abs(lost - x["link.loss"]) < 5 * math.sqrt(0.25 / 400) + 0.01
    clean = [x for x in rows if x["link.loss"] == 0.0]
    assert clean[0]["max_error_m"] == clean[1]["max_error_m"]  # no loss: the seed changes nothing
    assert "breaking point" in r.stdout and (out / "error_vs_link.loss.png").stat().st_size > 10_000
    # another bound judges the same runs again: none is flown
    r = _sweep(cfg, "--vary", "link.loss=0,0.6", "--seeds", "2", "--out", out, "--bound", "1e-9")
    assert r.returncode == 0, r.stderr
    judged = read_rows(out / "table.csv", ["link.loss"])
    assert [x["passed"] for x in judged] == [0] * 4
    assert "breaking point: link.loss breaks at its first value" in r.stdout
    assert [{**x, "passed": 0} for x in rows] == judged  # the same runs, to the wall time
    # a row is its config: run it again and get the same error, to the bit
    one = rows[3]
    run = tmp_path / "again"
    rr = cli("run", str(out / one["config"]), "--out", str(run), "--quiet")
    assert rr.returncode in (0, 3), rr.stderr
    from swarm_sitl.campaigns.point import metrics_of

    assert metrics_of(run, "", 0.0)["max_error_m"] == one["max_error_m"]


@pytest.mark.system
def test_an_interrupted_campaign_keeps_every_finished_row_and_the_same_command_finishes_it(tmp_path):
    out = tmp_path / "c"
    args = ["sweep", _config(tmp_path), "--vary", "link.loss=0:0.2:0.1", "--seeds", "1"]
    args += ["--out", out, "--jobs", "1", "--quiet"]
    proc = start_cli(*args, start_new_session=False)
    table = out / "table.csv"
    end = time.monotonic() + 120
    while time.monotonic() < end and len(read_rows(table, ["link.loss"])) < 1:
        time.sleep(0.2)
    proc.send_signal(signal.SIGTERM)
    _out, err = proc.communicate(timeout=60)
    assert proc.returncode == 143, err
    assert "interrupted (SIGTERM)" in err and "the same command runs the rest" in err
    kept = read_rows(table, ["link.loss"])
    assert 1 <= len(kept) < 3 and all(r["failure"] == "" for r in kept)
    r = cli(*args, timeout=300)
    assert r.returncode == 0, r.stderr
    done = read_rows(table, ["link.loss"])
    assert len(done) == 3 and all(r in done for r in kept)


@pytest.mark.unit
@given(
    end=st.floats(1.0, 60.0),
    settles=st.lists(st.floats(0.0, 90.0), min_size=1, max_size=4, unique=True),
    base_settle=st.floats(0.0, 90.0),
)
def test_the_settle_check_reads_each_points_own_settle_s_and_duration(end, settles, base_settle):
    """A campaign that varies ``run.settle_s`` (or ``duration_s``) is judged point by point: it is
    refused exactly when some point settles at or after its run's end, whatever the base says."""
    from swarm_sitl.campaigns.sweep import _check_points

    data = config("paper").data()
    data["duration_s"], data["run"]["settle_s"] = end, base_settle
    points = [{"run.settle_s": s} for s in settles]
    late = [s for s in settles if s >= end]
    if late:
        with pytest.raises(SweepSpecError, match=f"run.settle_s={late[0]:g}: the run ends at {end:g} s"):
            _check_points(data, points, 0)
    else:
        _check_points(data, points, 0)


@pytest.mark.integration
def test_bad_campaigns_are_one_line_before_anything_runs(tmp_path):
    """Each refused in ``swarm-sitl sweep``'s own ``main``, in this process (nothing of it starts
    a process before it refuses; ``test_config_and_cli`` holds the command line's exit codes)."""
    cfg = _config(tmp_path)
    for args, message in [
        (["--vary", "gains.kp=1,2"], r"no setting 'gains\.kp'"),
        (["--vary", "link.loss=0.5:0.1:0.1"], r"the range '0.5:0.1:0.1' is empty"),
        (["--vary", "link.loss=0,1.5"], r"sweep link\.loss=1\.5: .*less than or equal to 1"),
        (["--vary", "link.loss=0,0.5", "--duration", "1"], r"the run ends at 1 s, before run\.settle_s"),
        (
            ["--vary", "run.settle_s=0.5,1.5", "--duration", "1"],
            r"sweep run\.settle_s=1\.5: the run ends at 1 s, before run\.settle_s \(1\.5 s\)",
        ),
        (
            ["--vary", "link.loss=0,0.5", "--scheduler", "tcp://127.0.0.1:9", "--scheduler-timeout", "1"],
            r"cannot reach the Dask scheduler at tcp://127\.0\.0\.1:9",
        ),
        (["--vary", "link.loss=0", "--seeds", "x"], r"--seeds x: a count or a comma list"),
    ]:
        code, _, err = cli_in_process("sweep", cfg, *args, "--out", tmp_path / "bad", "--quiet")
        lines = err.strip().splitlines()
        assert code == 2 and len(lines) == 1 and lines[0].startswith("swarm-sitl: error: "), err
        assert __import__("re").search(message, lines[0]), lines[0]
        assert not (tmp_path / "bad").exists()  # nothing written either


@pytest.mark.integration
def test_refine_bisects_between_the_last_value_that_holds_and_the_first_that_breaks_once(
    tmp_path, monkeypatch
):
    """With runs whose largest error is their loss value (a stand-in for the runner), a bound of
    0.7 on the grid 0, 0.5, 1 holds up to 0.5 and breaks at 1; two bisection steps fly 0.75
    (breaks) then 0.625 (holds). The same command again flies nothing."""
    import swarm_sitl.campaigns.sweep as sweep_mod

    flown: list[float] = []

    def fake_runs(tasks, jobs):
        for t in tasks:
            loss = sum(e.get("loss", 0.0) for e in yaml.safe_load(t.config_yaml)["faults"]["plan"]) / 4
            flown.append(round(loss, 12))
            metrics = {"passed": 1, "max_error_m": loss, "final_error_m": loss, "recovered_s": math.nan}
            yield (
                t,
                {
                    **metrics,
                    "delivered_min": 1.0,
                    "delivered_mean": 1.0,
                    "failsafe_s": 0.0,
                    "failure": "",
                    "wall_s": 0.0,
                },
            )

    monkeypatch.setattr(sweep_mod, "run_local", fake_runs)
    monkeypatch.setattr(sweep_mod.charts, "error_chart", lambda *a, **k: tmp_path / "chart.png")
    kw = {"out": tmp_path / "c", "seeds": [0], "bound_m": 0.7, "duration_s": 30.0, "refine": 2}
    c = sweep_mod.sweep(CONFIGS / "paper.yaml", {"link.loss": [0.0, 0.5, 1.0]}, **kw)
    assert flown == [0.0, 0.5, 1.0, 0.75, 0.625] and c.breaking_point() == (0.625, 0.75)
    assert [r["refined"] for r in c.rows] == [0, 0, 1, 1, 0] and [r["passed"] for r in c.rows] == [
        1,
        1,
        1,
        0,
        0,
    ]
    again = sweep_mod.sweep(CONFIGS / "paper.yaml", {"link.loss": [0.0, 0.5, 1.0]}, **kw)
    assert len(flown) == 5 and again.rows == c.rows
    # a second key held at one value: the bisection runs on the varied one, the other kept
    flown.clear()
    held = {"link.delay_s": [0.0], "link.loss": [0.0, 0.5, 1.0]}
    c = sweep_mod.sweep(CONFIGS / "paper.yaml", held, **{**kw, "out": tmp_path / "held"})
    assert flown == [0.0, 0.5, 1.0, 0.75, 0.625] and c.varied == ["link.loss"]
    assert c.breaking_point() == (0.625, 0.75) and {r["link.delay_s"] for r in c.rows} == {0.0}
    with pytest.raises(
        SweepSpecError, match=r"--refine bisects one varied key .*varies link\.delay_s, link\.loss"
    ):
        sweep_mod.sweep(CONFIGS / "paper.yaml", {**held, "link.delay_s": [0.0, 0.1]}, **kw)


@pytest.mark.unit
@given(
    rows=st.lists(st.tuples(st.sampled_from([0.0, 0.1, 0.2, 0.3]), st.booleans()), max_size=8),
    key=st.sampled_from(["link.loss", "estimator.staleness_s"]),
)
def test_the_summary_reads_any_table_an_interrupted_campaign_leaves_empty_included(rows, key):
    """Whatever rows a campaign ended with (none, when a signal came before the first finished:
    it once raised on formatting None), its last lines are one per fact, naming the key and the
    breaking point the table gives."""
    from swarm_sitl.campaigns.breaking import breaking_point
    from swarm_sitl.campaigns.sweep import Campaign, summary_lines

    table = [{key: v, "passed": int(ok)} for v, ok in rows]
    c = Campaign(Path("/tmp/c"), [key], 0.005, rows=table)
    lines = summary_lines(c)
    assert lines[0].startswith(f"{len(table)} runs in ") and all("\n" not in line for line in lines)
    held, broke = breaking_point(table, key)
    point = lines[1]
    assert point.startswith("breaking point: ") and key in point
    for v in (held, broke):
        assert v is None or f"{v:g}" in point


@pytest.mark.integration
@pytest.mark.parametrize("after", [1, 2, 3])
def test_an_interrupt_just_after_a_row_reaches_the_disk_keeps_every_row_written(tmp_path, monkeypatch, after):
    """Ctrl-C or SIGTERM can land between a run's row reaching the table and anything after it; the
    campaign then writes its table again, sorted, from what it holds. Every row that reached the
    disk is still there (CI once lost the only one), whichever row the interrupt follows. The
    runs are stood in for: each point's metrics come at once."""
    from swarm_sitl.campaigns import sweep as sweep_module
    from swarm_sitl.campaigns.point import METRICS

    def quick(tasks, jobs):
        for t in tasks:
            yield t, {m: ("" if m == "failure" else 0.0) for m in METRICS} | {"passed": 1}

    written: list[dict] = []
    add = TableWriter.add

    def add_then_interrupted(self, row):
        add(self, row)
        written.append(row)
        if len(written) == after:
            raise KeyboardInterrupt  # (the signal's handler raises it here, after the write)

    monkeypatch.setattr(sweep_module, "run_local", quick)
    monkeypatch.setattr(TableWriter, "add", add_then_interrupted)
    out = tmp_path / "c"
    c = sweep_module.sweep(_config(tmp_path), ["link.loss=0:0.3:0.1"], out=out, seeds=1, jobs=1)
    assert c.interrupted is not None
    kept = read_rows(out / "table.csv", ["link.loss"])
    assert len(kept) == len(written) == after
    assert sorted(r["link.loss"] for r in kept) == sorted(r["link.loss"] for r in written)
