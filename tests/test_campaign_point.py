"""One point of a campaign as ``run_point`` runs it, with ``swarm-sitl run`` stood in for by a
script that does what the test asks (``point.run_command`` is where the command is made): the
point's config and plug-in files reach the run beside each other, its run directory is the one
kept or a temporary one removed, its output never reaches the campaign's terminal, and every way
a run can end is the row or the error it must be: a finished run's metrics with its last failure
line, a refused config's line, an interrupt, a code no run gives, a point past its wall budget."""

import json
import math
import sys
import threading
import time
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import swarm_sitl.campaigns.point as point
from swarm_sitl.campaigns.point import METRICS, PointError, run_point

pytestmark = pytest.mark.integration

#: the stand-in ``swarm-sitl run CONFIG --out RUN_DIR``: it says what it found (the config, the
#: files beside it, what the run directory held), writes the summary if asked, says its lines on
#: stdout and stderr, sleeps, and exits with the code asked (argv: config, run dir, orders)
_STAND_IN = r"""
import json, os, sys, time
cfg, run_dir, orders = sys.argv[1], sys.argv[2], json.loads(sys.argv[3])
here = os.path.dirname(cfg)
files = {}
for root, _, names in os.walk(here):
    for n in names:
        p = os.path.join(root, n)
        if not os.path.abspath(p).startswith(os.path.abspath(run_dir)):
            files[os.path.relpath(p, here)] = open(p, "rb").read().hex()
held = sorted(os.listdir(run_dir)) if os.path.isdir(run_dir) else None
os.makedirs(run_dir, exist_ok=True)
seen = {"cfg": cfg, "run_dir": run_dir, "files": files, "held": held}
json.dump(seen, open(os.path.join(run_dir, "seen.json"), "w"))
if orders["summary"]:
    open(os.path.join(run_dir, "summary.json"), "w").write("{}")
print("the run's progress, which no terminal of the campaign's should show", flush=True)
for line in orders["stderr"]:
    print(line, file=sys.stderr)
time.sleep(orders["sleep_s"])
sys.exit(orders["code"])
"""


@pytest.fixture
def stand_in(monkeypatch, tmp_path):
    """Make ``run_point``'s command the stand-in with ``orders``, and its metrics what it was
    given (the run directory's seen.json, the failure line, the wall time): returns the setter."""
    monkeypatch.setattr(point.tempfile, "tempdir", str(tmp_path / "tmp"))
    (tmp_path / "tmp").mkdir()

    def metrics(run_dir: Path, failure: str, wall_s: float) -> dict:
        return {"seen": json.loads((run_dir / "seen.json").read_text()), "failure": failure, "wall_s": wall_s}

    monkeypatch.setattr(point, "metrics_of", metrics)

    def orders(code=0, summary=True, stderr=(), sleep_s=0.0):
        o = json.dumps({"code": code, "summary": summary, "stderr": list(stderr), "sleep_s": sleep_s})
        cmd = [sys.executable, "-c", _STAND_IN]
        monkeypatch.setattr(point, "run_command", lambda cfg, run_dir: [*cmd, str(cfg), str(run_dir), o])

    return orders


_rel = st.lists(st.from_regex(r"[a-z][a-z0-9_]{0,7}", fullmatch=True), min_size=1, max_size=3).map("/".join)


@pytest.mark.parametrize("code", [point.EXIT_OK, point.EXIT_BOUND])
@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    plugins=st.dictionaries(_rel.map(lambda p: f"plugins/{p}.py"), st.binary(max_size=40), max_size=3),
    keep=st.booleans(),
)
def test_a_finished_point_ran_its_config_beside_its_plugins_and_leaves_only_the_kept_directory(
    stand_in, tmp_path, capfd, code, plugins, keep
):
    """Any plug-in files, at any depth of folders, are written beside the config the run reads;
    the run directory kept starts empty (what an earlier point left is gone) and stays; a
    temporary one goes with the point's work directory; a run that finished, whether or not it
    held its bound, has no failure; and nothing the run prints reaches the campaign's output."""
    stand_in(code=code, stderr=["a warning that is not a failure"])
    keep_dir = tmp_path / "kept" / "p3" if keep else None
    if keep_dir is not None and keep_dir.exists():  # an earlier example's: a stale run
        (keep_dir / "stale.txt").write_text("from an earlier run")
    row = run_point("name: p3\n", "p3", str(keep_dir) if keep_dir else None, plugins)
    seen = row["seen"]
    cfg = Path(seen["cfg"])
    assert cfg.name == "p3.yaml" and cfg.parent.name.startswith("sweep-p3-")  # the point's, in `ps`
    assert {k: bytes.fromhex(v) for k, v in seen["files"].items()} == {"p3.yaml": b"name: p3\n", **plugins}
    assert row["failure"] == ""
    if keep_dir is not None:
        assert Path(seen["run_dir"]) == keep_dir and seen["held"] is None
        assert (keep_dir / "seen.json").is_file()
    else:
        assert Path(seen["run_dir"]).parent == cfg.parent
    assert list((tmp_path / "tmp").iterdir()) == []  # the work directory is gone
    assert capfd.readouterr().out == ""
    assert not point.RUNNING


def test_the_wall_time_of_a_row_is_the_runs(stand_in):
    stand_in(sleep_s=0.4)
    t0 = time.monotonic()
    row = run_point("name: w\n", "w", None, None)
    assert 0.4 <= row["wall_s"] <= time.monotonic() - t0


@given(
    lines=st.lists(
        st.text(st.characters(codec="utf-8", exclude_categories=["Cc", "Cs", "Zl", "Zp"]), min_size=1).filter(
            lambda s: s == s.strip() != ""
        ),
        max_size=3,
    ),
    prefixed=st.booleans(),
)
@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
def test_a_failed_run_is_a_row_failed_with_its_last_line_and_a_refused_one_an_error_naming_it(
    stand_in, lines, prefixed
):
    """Exit 1 (a run that failed but wrote its directory): a row whose failure is the last line
    of its stderr without the ``swarm-sitl:`` of the CLI's errors, or ``failed`` when it said
    nothing. Exit 2 (its config refused) or no summary written: ``PointError`` with that line,
    or its exit code."""
    said = [("swarm-sitl: " if prefixed else "") + ln for ln in lines]
    stand_in(code=point.EXIT_FAILED, stderr=said)
    row = run_point("name: f\n", "f", None, None)
    assert row["failure"] == (said[-1].removeprefix("swarm-sitl: ") if said else "failed")
    for code, summary in ((point.EXIT_USAGE, True), (point.EXIT_FAILED, False), (point.EXIT_OK, False)):
        stand_in(code=code, summary=summary, stderr=said)
        with pytest.raises(PointError) as e:
            run_point("name: f\n", "f", None, None)
        assert str(e.value) == f"point f: {said[-1] if said else f'exit {code}'}"


@pytest.mark.parametrize("code", [129, 130, 143])
def test_a_run_ended_by_a_hangup_an_interrupt_or_a_terminate_interrupts_the_campaign(stand_in, code):
    stand_in(code=code)
    with pytest.raises(KeyboardInterrupt):
        run_point("name: i\n", "i", None, None)
    assert not point.RUNNING


@pytest.mark.parametrize("code", [4, 7, 128, 131, 137])
def test_a_run_with_an_exit_code_no_run_gives_is_an_error_naming_the_code(stand_in, code):
    stand_in(code=code)
    with pytest.raises(PointError, match=rf"^point c: swarm-sitl run exited {code}$"):
        run_point("name: c\n", "c", None, None)


def test_a_point_past_its_wall_budget_is_a_row_of_nothing_measured_but_its_wall_time(monkeypatch):
    """The stand-in never ends; interrupted at the budget it ends at once: the row has no
    metric (NaN), passed 0, the failure, and its wall time to the millisecond, between the budget
    and the time the call took."""
    monkeypatch.setattr(point, "run_command", lambda cfg, run_dir: [sys.executable, "-c", "while True: pass"])
    t0 = time.monotonic()
    row = run_point("name: x\n", "late", None, None, 0.6)
    took = time.monotonic() - t0
    assert set(row) == set(METRICS)
    assert row["passed"] == 0 and row["failure"] == "timed out after 0.6 s (the point's wall budget)"
    assert all(math.isnan(row[m]) for m in METRICS if m not in ("passed", "failure", "wall_s"))
    assert 0.6 <= row["wall_s"] <= took and row["wall_s"] == round(row["wall_s"], 3)
    assert not point.RUNNING


def test_stopping_the_runs_under_way_interrupts_each_so_the_campaign_ends(monkeypatch, tmp_path):
    """``stop_running`` (a campaign's Ctrl-C) sends each run its interrupt; a run ends on it as
    ``swarm-sitl run`` does (its directory written, exit 130), and the point is an interrupt,
    not a row."""
    ready = tmp_path / "ready"
    code = (  # as swarm-sitl run: on the interrupt, its run directory written, then exit 130
        "import pathlib, signal, sys, time\n"
        "run = pathlib.Path(sys.argv[1])\n"
        "def end(*a):\n"
        "    run.mkdir(parents=True, exist_ok=True)\n"
        "    (run / 'summary.json').write_text('{}')\n"
        "    sys.exit(130)\n"
        "signal.signal(signal.SIGINT, end)\n"
        f"pathlib.Path({str(ready)!r}).touch()\n"
        "time.sleep(60)\n"
    )
    monkeypatch.setattr(point, "run_command", lambda cfg, run_dir: [sys.executable, "-c", code, str(run_dir)])
    got: list[BaseException] = []

    def go() -> None:
        try:
            run_point("name: s\n", "s", None, None)
        except BaseException as e:
            got.append(e)

    t = threading.Thread(target=go)
    t.start()
    end = time.monotonic() + 60
    while not ready.exists() and t.is_alive() and time.monotonic() < end:
        time.sleep(0.02)
    assert len(point.RUNNING) == 1
    point.stop_running()
    t.join(30)
    assert not t.is_alive() and len(got) == 1 and isinstance(got[0], KeyboardInterrupt)
    assert not point.RUNNING
