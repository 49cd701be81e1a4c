"""The command line's campaign and search commands in this process (``cli.main``), their engines
stood in for: every flag reaches its parameter of the Python API (``sweep``, ``falsify``), drawn
at random; each outcome is its exit code and its lines; a mistake is one line and exit 2, a
stopped engine 1, Ctrl-C and the ending signals 128 + the signal. (The engines themselves, and the
commands as new processes: ``test_sweep.py``, ``test_falsify.py``.)"""

import signal
import types
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import swarm_sitl.campaigns.sweep as sweep_mod
import swarm_sitl.falsify.search as search_mod
from swarm_sitl.campaigns.runner import SchedulerError
from swarm_sitl.campaigns.sweep import Campaign, SweepSpecError
from swarm_sitl.commands.common import Terminated
from swarm_sitl.config.load import ConfigError
from swarm_sitl.falsify.search import FalsifyError
from swarm_sitl.falsify.workers import WorkerError
from tests.support import cli_in_process

pytestmark = pytest.mark.unit

_seconds = st.floats(0.5, 500.0).map(lambda x: round(x, 3))


class _Called:
    """A stand-in engine: its arguments noted, ``result`` returned or raised."""

    def __init__(self, result):
        self.result, self.calls = result, []

    def __call__(self, *args, **kw):
        self.calls.append((args, kw))
        if isinstance(self.result, BaseException):
            raise self.result
        return self.result


def _campaign(out: str, rows=(), interrupted=None) -> Campaign:
    return Campaign(Path(out), ["link.loss"], 0.5, list(rows), interrupted=interrupted)


def _options(values: dict, files: set[str]) -> list[str]:
    """Each flag with a value (``None``: not given), then each file flag with ``NAME.yaml``."""
    given = [a for flag, v in values.items() if v is not None for a in (flag, str(v))]
    return given + [a for f in sorted(files) for a in (f, f"{f[2:]}.yaml")]


def _seeds_text(seeds) -> str:
    """A count as it is; a list comma-separated, one seed with a trailing comma (``7,``: seed 7,
    where ``7`` is seven seeds)."""
    return seeds if isinstance(seeds, str) else ",".join(map(str, seeds)) + ("," if len(seeds) == 1 else "")


# -- sweep ------------------------------------------------------------------------------------------
@settings(max_examples=40, deadline=None)
@given(
    seeds=st.one_of(st.integers(1, 9).map(str), st.lists(st.integers(0, 99), min_size=1, max_size=4)),
    duration=st.none() | _seconds,
    bound=st.none() | st.floats(0.001, 5.0).map(lambda x: round(x, 4)),
    jobs=st.none() | st.integers(1, 8),
    scheduler=st.none() | st.just("tcp://10.0.0.9:8786"),
    scheduler_timeout=st.none() | _seconds,
    refine=st.none() | st.integers(0, 6),
    point_timeout=st.none() | _seconds,
    flags=st.sets(st.sampled_from(["--keep-runs", "--quiet"])),
    files=st.sets(st.sampled_from(["--faults", "--spec"])),
    vary=st.lists(
        st.sampled_from(["link.loss=0:0.5:0.1", "link.delay_s=0,0.1", "gains.k_p=1,2"]),
        min_size=1,
        max_size=3,
        unique=True,
    ),
)
def test_every_sweep_flag_reaches_the_campaign(
    seeds, duration, bound, jobs, scheduler, scheduler_timeout, refine, point_timeout, flags, files, vary
):
    engine = _Called(_campaign("camp"))
    argv = [
        "sweep",
        "c.yaml",
        "--out",
        "camp",
        "--seeds",
        _seeds_text(seeds),
    ]
    argv += [a for v in vary for a in ("--vary", v)] + sorted(flags)
    argv += _options(
        {"--duration": duration, "--bound": bound, "--jobs": jobs, "--scheduler": scheduler,
         "--scheduler-timeout": scheduler_timeout, "--refine": refine, "--point-timeout": point_timeout},
        files,
    )  # fmt: skip
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(sweep_mod, "sweep", engine)
        code, out, err = cli_in_process(*argv)
    assert code == 0, err
    ((args, kw),) = engine.calls
    assert args == ("c.yaml", vary)
    assert kw == {
        "out": "camp",
        "seeds": int(seeds) if isinstance(seeds, str) else seeds,
        "faults": "faults.yaml" if "--faults" in files else None,
        "duration_s": duration,
        "bound_m": bound,
        "jobs": jobs,
        "scheduler": scheduler,
        "scheduler_timeout_s": 10.0 if scheduler_timeout is None else scheduler_timeout,
        "refine": refine or 0,
        "progress": "--quiet" not in flags,
        "keep_runs": "--keep-runs" in flags,
        "point_timeout_s": point_timeout,
        "spec": "spec.yaml" if "--spec" in files else None,
    }
    assert out.splitlines() == sweep_mod.summary_lines(engine.result) and err == ""


@pytest.mark.parametrize("seeds", ["x", "1,a", "2.5", "1;2"])
def test_seeds_that_are_neither_a_count_nor_a_list_are_one_line(monkeypatch, seeds):
    monkeypatch.setattr(sweep_mod, "sweep", _Called(AssertionError("ran")))
    code, out, err = cli_in_process(
        "sweep", "c.yaml", "--vary", "link.loss=0,1", "--out", "o", "--seeds", seeds
    )
    assert (code, out) == (2, "")
    assert err == f"swarm-sitl: error: --seeds {seeds}: a count or a comma list of integers\n"


@pytest.mark.parametrize(
    "error",
    [SweepSpecError("sweep: no values"), SchedulerError("cannot reach it"), ConfigError("c.yaml: bad")],
)
def test_a_campaign_refused_is_its_one_line_and_exit_2(monkeypatch, error):
    monkeypatch.setattr(sweep_mod, "sweep", _Called(error))
    code, out, err = cli_in_process("sweep", "c.yaml", "--vary", "link.loss=0,1", "--out", "o")
    assert (code, out, err) == (2, "", f"swarm-sitl: error: {error}\n")


@pytest.mark.parametrize(
    ("stop", "code", "name"),
    [
        (KeyboardInterrupt(), 130, "SIGINT"),
        (Terminated(signal.SIGTERM), 143, "SIGTERM"),
        (Terminated(signal.SIGHUP), 129, "SIGHUP"),
    ],
)
def test_an_interrupted_campaign_says_where_its_rows_are_and_exits_with_the_signal(
    monkeypatch, stop, code, name
):
    rows = [{"link.loss": 0.0, "seed": 0, "passed": 1, "max_error_m": 0.01}] * 3
    monkeypatch.setattr(sweep_mod, "sweep", _Called(_campaign("o", rows, interrupted=stop)))
    got, out, err = cli_in_process("sweep", "c.yaml", "--vary", "link.loss=0,1", "--out", "o")
    assert (
        got == code
        and out.splitlines()[0] == f"3 runs in {Path('o') / 'table.csv'} (3 held the bound of 0.5 m)"
    )
    assert err == (
        f"swarm-sitl: interrupted ({name}): the 3 finished runs are in {Path('o') / 'table.csv'}; "
        "the same command runs the rest\n"
    )


# -- falsify ----------------------------------------------------------------------------------------
def _found(**kw):
    f = {
        "per_minute": 12.34,
        "requirement": "formation",
        "evaluations": 9,
        "interrupted": False,
        "signum": 0,
        "baseline": 0.2,
        "base_entries": [],
        "plan": None,
        "counterexample": None,
        "cost": 0.0,
        "robustness": 0.1,
        "confirmed": None,
    }
    return types.SimpleNamespace(**(f | kw))


@settings(max_examples=40, deadline=None)
@given(
    budget=st.none() | st.integers(1, 500),
    seed=st.none() | st.integers(0, 2**31),
    jobs=st.none() | st.integers(1, 8),
    batch=st.none() | st.integers(1, 8),
    duration=st.none() | _seconds,
    bound=st.none() | st.floats(0.001, 5.0).map(lambda x: round(x, 4)),
    cost=st.none() | st.sampled_from(["severity", "edges"]),
    requirement=st.none() | st.just("apart"),
    scheduler=st.none() | st.just("tcp://10.0.0.9:8786"),
    files=st.sets(st.sampled_from(["--space", "--spec"])),
    flags=st.sets(st.sampled_from(["--no-confirm", "--quiet"])),
)
def test_every_falsify_flag_reaches_the_check_and_the_search(
    budget, seed, jobs, batch, duration, bound, cost, requirement, scheduler, files, flags
):
    checked, engine = _Called(None), _Called(_found())
    argv = ["falsify", "c.yaml", "--out", "o", *sorted(flags)]
    argv += _options(
        {"--budget": budget, "--seed": seed, "--jobs": jobs, "--batch": batch, "--duration": duration,
         "--bound": bound, "--cost": cost, "--requirement": requirement, "--scheduler": scheduler},
        files,
    )  # fmt: skip
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(search_mod, "load_inputs", checked)
        mp.setattr(search_mod, "falsify", engine)
        code, out, _ = cli_in_process(*argv)
    space = "space.yaml" if "--space" in files else None
    spec = "spec.yaml" if "--spec" in files else None
    budget, cost = 60 if budget is None else budget, cost or "severity"
    assert checked.calls == [(("c.yaml", space, spec, requirement, bound, duration, budget, cost), {})]
    ((args, kw),) = engine.calls
    kw.pop("say")  # (what it prints: test_the_searchs_progress_lines_are_printed_unless_quiet)
    assert args == ("c.yaml", "o")
    assert kw == {
        "space": space,
        "spec": spec,
        "requirement": requirement,
        "bound_m": bound,
        "duration_s": duration,
        "budget": budget,
        "cost_how": cost,
        "seed": seed or 0,
        "jobs": jobs,
        "batch": 4 if batch is None else batch,
        "confirm": "--no-confirm" not in flags,
        "scheduler": scheduler,
    }
    assert code == 0
    assert out.splitlines() == [
        "falsify formation: 9 evaluations, 12.3 per minute -> o",
        f"  no plan in the space breaks formation within {budget} evaluations",
    ]


@pytest.mark.parametrize("quiet", [False, True])
def test_the_searchs_progress_lines_are_printed_unless_quiet(monkeypatch, capsys, quiet):
    def engine(*a, say, **kw):
        say("trial 1: robustness 0.1")
        return _found()

    monkeypatch.setattr(search_mod, "load_inputs", _Called(None))
    monkeypatch.setattr(search_mod, "falsify", engine)
    code, out, _ = cli_in_process("falsify", "c.yaml", "--out", "o", *(["--quiet"] if quiet else []))
    assert code == 0 and ("trial 1: robustness 0.1" in out.splitlines()) is not quiet


PLAN = {"seed": 3, "plan": [{"edge": [0, 1], "drop": True}, {"edge": [1, 2], "loss": 0.5}]}


@pytest.mark.parametrize(
    ("found", "code", "lines"),
    [
        (
            _found(baseline=-0.25),
            3,
            ["  formation fails without any fault (robustness -0.25): nothing to search for"],
        ),
        (
            _found(baseline=-0.25, base_entries=[{"edge": [0, 1]}]),
            3,
            ["  formation fails with the config's own plan alone (robustness -0.25): nothing to search for"],
        ),
        (
            _found(plan=PLAN, counterexample="o/counterexamples/a.yaml", cost=1.5, robustness=-0.02),
            3,
            [
                "  minimal counterexample o/counterexamples/a.yaml: 2 entries, cost 1.5, robustness -0.02",
                "    {'edge': [0, 1], 'drop': True}",
                "    {'edge': [1, 2], 'loss': 0.5}",
            ],
        ),
        (
            _found(plan=PLAN, counterexample="c.yaml", cost=2.0, robustness=-0.5, confirmed=True),
            3,
            [
                "  minimal counterexample c.yaml: 2 entries, cost 2, robustness -0.5; lockstep run the same",
                "    {'edge': [0, 1], 'drop': True}",
                "    {'edge': [1, 2], 'loss': 0.5}",
            ],
        ),
        (
            _found(
                plan={"plan": [{"edge": [0, 1]}]},
                counterexample="c.yaml",
                cost=2.0,
                robustness=-0.5,
                confirmed=False,
            ),
            3,
            [
                "  minimal counterexample c.yaml: 1 entries, cost 2, robustness -0.5; lockstep run DIFFERS",
                "    {'edge': [0, 1]}",
            ],
        ),
        (
            _found(baseline=0.0),
            0,
            ["  no plan in the space breaks formation within 60 evaluations"],
        ),  # (0 holds)
        (_found(interrupted=True, signum=15), 143, ["  interrupted: what was found is written"]),
        (
            _found(
                interrupted=True,
                signum=2,
                plan={"plan": [{"edge": [0, 1]}]},
                counterexample="c.yaml",
                cost=1.0,
                robustness=-1.0,
            ),
            130,
            [
                "  interrupted: what was found is written",
                "  minimal counterexample c.yaml: 1 entries, cost 1, robustness -1",
                "    {'edge': [0, 1]}",
            ],
        ),
    ],
)
def test_each_outcome_of_a_search_is_its_exit_code_and_its_lines(monkeypatch, found, code, lines):
    """3: the requirement fails (a counterexample, or without any searched fault); 0: no plan
    breaks it within the budget; interrupted: 128 + the signal, what was found said."""
    monkeypatch.setattr(search_mod, "load_inputs", _Called(None))
    monkeypatch.setattr(search_mod, "falsify", _Called(found))
    got, out, err = cli_in_process("falsify", "c.yaml", "--out", "o", "--quiet")
    assert (got, out.splitlines()) == (
        code,
        ["falsify formation: 9 evaluations, 12.3 per minute -> o", *lines],
    )
    assert err == ""


@pytest.mark.parametrize(
    ("where", "error", "code", "says"),
    [
        (
            "load_inputs",
            FalsifyError("spec.yaml: no requirement"),
            2,
            "swarm-sitl: error: spec.yaml: no requirement",
        ),
        ("falsify", SchedulerError("cannot reach it"), 2, "swarm-sitl: error: cannot reach it"),
        ("falsify", WorkerError("a worker died"), 1, "swarm-sitl: error: falsify stopped: a worker died"),
        ("falsify", ConfigError("c.yaml: bad"), 2, "swarm-sitl: error: c.yaml: bad"),
        ("falsify", KeyboardInterrupt(), 130, ""),
        ("falsify", Terminated(signal.SIGTERM), 143, ""),
    ],
)
def test_a_search_refused_or_stopped_is_one_line_and_its_code(monkeypatch, where, error, code, says):
    monkeypatch.setattr(search_mod, "load_inputs", _Called(error if where == "load_inputs" else None))
    monkeypatch.setattr(search_mod, "falsify", _Called(error if where == "falsify" else _found()))
    got, out, err = cli_in_process("falsify", "c.yaml", "--out", "o", "--quiet")
    assert (got, out) == (code, "") and err == (says + "\n" if says else "")


@pytest.mark.parametrize("flag", ["--jobs", "--batch"])
@pytest.mark.parametrize("n", [0, -3])
def test_fewer_than_one_worker_or_plan_at_once_is_one_line_before_anything_is_checked(monkeypatch, flag, n):
    monkeypatch.setattr(search_mod, "load_inputs", _Called(AssertionError("checked")))
    code, out, err = cli_in_process("falsify", "c.yaml", "--out", "o", flag, str(n))
    assert (code, out, err) == (2, "", f"swarm-sitl: error: {flag} {n}: at least 1\n")


# -- the parser -------------------------------------------------------------------------------------
def test_every_documented_command_has_its_parser_and_every_parser_is_documented():
    """``docs/commands.md``'s table names each command (its first column): the parser takes each,
    and no other; each answers ``-h`` with its own usage line, exit 0."""
    import argparse
    import re

    from swarm_sitl.cli import build_parser
    from tests.support import ROOT

    table = [
        row.split("|")[1]
        for row in (ROOT / "docs" / "commands.md").read_text().splitlines()
        if row.startswith("| `")
    ]
    documented = {m for cell in table for m in re.findall(r"`swarm-sitl ([a-z]+)", cell)}
    (sub,) = [a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction)]
    assert set(sub.choices) == documented
    for command in sorted(documented):
        code, out, err = cli_in_process(command, "-h")
        assert (code, err) == (0, "") and out.startswith(f"usage: swarm-sitl {command} "), (command, out[:80])


@pytest.mark.parametrize(
    ("error", "code", "says"),
    [
        (ConfigError("c.yaml: bad"), 2, "swarm-sitl: error: c.yaml: bad"),
        (KeyboardInterrupt(), 130, "swarm-sitl: interrupted (SIGINT)"),
        (Terminated(signal.SIGHUP), 129, "swarm-sitl: interrupted (SIGHUP)"),
    ],
)
def test_what_a_command_raises_is_one_line_and_its_exit_code(monkeypatch, error, code, says):
    """Any command: a user's mistake 2, an interruption 128 + its signal, each one line."""
    monkeypatch.setattr(sweep_mod, "sweep", _Called(error))
    got, out, err = cli_in_process("sweep", "c.yaml", "--vary", "link.loss=0,1", "--out", "o")
    assert (got, out, err) == (code, "", says + "\n")


def test_no_command_is_the_usage_and_one_line_naming_what_is_missing():
    code, out, err = cli_in_process()
    assert (code, out) == (2, "")
    assert err.splitlines() == [
        "usage: swarm-sitl [-h] COMMAND ...",
        "swarm-sitl: error: the following arguments are required: COMMAND",
    ]


@pytest.mark.parametrize(("role", "argv"), [("controller", ["--id", "3", "--mavlink", "udpout:127.0.0.1:9"]),
                                            ("leader", [])])  # fmt: skip
def test_a_node_command_runs_its_role_with_its_arguments(monkeypatch, role, argv):
    import swarm_sitl.nodes.entry as entry

    ran = _Called(0)
    monkeypatch.setattr(entry, "run_role", ran)
    assert cli_in_process(role, "c.yaml", "--lockstep", *argv) == (0, "", "")
    ((args, kw),) = ran.calls
    assert args[0] == role and args[1].config == "c.yaml" and args[1].lockstep and kw == {}
    assert getattr(args[1], "id", 3) == 3


def test_every_option_of_every_command_says_what_it_is():
    """Each command and each of its options has help text (``-h`` shows what a flag does)."""
    import argparse

    from swarm_sitl.cli import build_parser

    parser = build_parser()
    assert parser.description
    (sub,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    helped = {a.dest for a in sub._choices_actions if a.help}
    assert helped == set(sub.choices), set(sub.choices) - helped
    for name, command in sub.choices.items():
        for action in command._actions:
            if action.option_strings and action.dest != "help":
                assert action.help, (name, action.option_strings)


@pytest.mark.parametrize(
    ("argv", "missing"),
    [
        (["sweep", "c.yaml", "--out", "o"], "--vary"),
        (["sweep", "c.yaml", "--vary", "link.loss=0,1"], "--out"),
        (["falsify", "c.yaml"], "--out"),
    ],
)
def test_a_command_without_what_it_needs_is_one_line_naming_it(monkeypatch, argv, missing):
    monkeypatch.setattr(sweep_mod, "sweep", _Called(AssertionError("ran")))
    monkeypatch.setattr(search_mod, "falsify", _Called(AssertionError("ran")))
    code, out, err = cli_in_process(*argv)
    assert (code, out) == (2, "")
    assert (
        err.splitlines()[-1]
        == f"swarm-sitl {argv[0]}: error: the following arguments are required: {missing}"
    )


def test_a_searchs_progress_reaches_a_pipe_as_it_is_said(monkeypatch):
    """Through a pipe (``falsify ... | tee``) standard output is buffered: each progress line is
    flushed as it is said, so a reader sees it while the search goes on, not at its end."""
    import contextlib
    import io
    import os

    read_end, write_end = os.pipe()
    os.set_blocking(read_end, False)
    seen: list[bytes] = []

    def engine(*a, say, **kw):
        say("falsify: 4/8 evaluations, 1 of the last violating")
        with contextlib.suppress(BlockingIOError):
            seen.append(os.read(read_end, 1 << 16))
        return _found()

    monkeypatch.setattr(search_mod, "load_inputs", _Called(None))
    monkeypatch.setattr(search_mod, "falsify", engine)
    piped = io.TextIOWrapper(io.BufferedWriter(io.FileIO(write_end, "w"), 1 << 16))
    try:
        assert cli_in_process("falsify", "c.yaml", "--out", "o", stdout=piped) == (0, "", "")
    finally:
        piped.close()
        os.close(read_end)
    assert seen == [b"falsify: 4/8 evaluations, 1 of the last violating\n"]
