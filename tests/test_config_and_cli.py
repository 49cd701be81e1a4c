"""Config validation (one clear line per mistake) and the CLI."""

import json
import math
import subprocess
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from swarm_sitl.cli import main
from swarm_sitl.config.load import ConfigError, parse_config
from tests.support import CONFIGS, cli_ok, config, config_data

pytestmark = pytest.mark.integration


def _paper() -> dict:
    return yaml.safe_load((CONFIGS / "paper.yaml").read_text())


def _mutated(tmp_path: Path, fn) -> Path:
    data = _paper()
    fn(data)
    p = tmp_path / "bad.yaml"
    p.write_text(yaml.safe_dump(data))
    return p


CASES = {
    "missing key": (lambda d: d["vehicle"].pop("mass_kg"), "vehicle.mass_kg: missing key"),
    "unknown key": (lambda d: d["gains"].update(k_zeta=1.0), "gains.k_zeta: unknown key"),
    "no spanning tree": (
        lambda d: d["graph"].update(edges=[[0, 1], [0, 2], [3, 4], [4, 3]]),
        "graph: no spanning tree rooted at the leader: node 0 cannot reach follower(s) 3, 4",
    ),
    "negative mass": (
        lambda d: d["vehicle"].update(mass_kg=-0.85),
        "vehicle.mass_kg: Input should be greater than 0 (got -0.85)",
    ),
    "infinite mass": (
        lambda d: d["vehicle"].update(mass_kg=float("inf")),
        "vehicle.mass_kg: Input should be a finite number (got inf)",
    ),
    "non-unit quaternion": (
        lambda d: d["followers"][1].update(initial_quaternion_wxyz=[1, 0.1, 0, 0]),
        "followers.1.initial_quaternion_wxyz: must be a unit quaternion, its norm is 1.00499",
    ),
    "rates": (
        lambda d: d["rates"].update(attitude_hz=1050),
        "rates: attitude_hz (1050.0) must be a whole multiple of control_hz (100.0)",
    ),
    "lockstep window": (
        lambda d: d.update(run={"lockstep_window": 5, "status_every": 10}),
        "run: lockstep_window (5) must exceed status_every (10), or the leader waits for a status that "
        "never comes",
    ),
    "duration past time_boot_ms": (
        lambda d: d.update(duration_s=1e300),
        "duration_s (1e+300) cannot be flown: MAVLink's time_boot_ms (uint32 ms) wraps after 4294967.295 s "
        "(49.7 days)",
    ),
    "control rate past 1 ms ticks": (
        lambda d: d["rates"].update(control_hz=2000, attitude_hz=4000),
        "rates.control_hz: Input should be less than or equal to 1000 (got 2000)",
    ),
    "zenoh mode": (
        lambda d: d.update(zenoh={"mode": "mesh"}),
        "zenoh.mode: Input should be 'router', 'peer' or 'client' (got 'mesh')",
    ),
    "a plan entry that is no mapping": (
        lambda d: d.update(faults={"plan": [1]}),
        "faults.plan.0: Input should be a valid dictionary or instance of FaultEntry (got 1)",
    ),
    # a validator's own refusal names what it was given itself: no "(got ...)" after it
    "ros2 namespace": (
        lambda d: d.update(ros2={"namespace": "bad name"}),
        "ros2.namespace: topic 'bad name': a fully qualified name starts with '/'",
    ),
}


@pytest.mark.parametrize("case", CASES)
def test_bad_config_gives_one_line_naming_the_problem(tmp_path, capsys, case):
    mutate, expected = CASES[case]
    path = _mutated(tmp_path, mutate)
    commands = (
        ["check", str(path)],
        ["sim", str(path), "--quiet", "--out", str(tmp_path / "r")],
        ["run", str(path), "--quiet", "--out", str(tmp_path / "p")],  # before any process starts
    )
    for command in commands:
        assert main(command) == 2
        assert capsys.readouterr().err == f"swarm-sitl: error: {path}: {expected}\n"


def test_a_file_that_is_no_config_is_one_whole_line_naming_it(tmp_path, capsys):
    """Not a mapping, or not YAML at all (a NUL byte: libyaml's reader, which marks no line), or
    not text: each said whole, after the file's name."""
    cases = [
        (b"- 1\n", "expected a mapping of keys at the top level"),
        (b"a: \x00\n", "not valid YAML"),
        (b"a: [1\n", "not valid YAML at line 2"),
        (b"\xff\xfe\x00", "not a text file"),
    ]
    for raw, said in cases:
        path = tmp_path / "c.yaml"
        path.write_bytes(raw)
        assert main(["check", str(path)]) == 2
        assert capsys.readouterr().err == f"swarm-sitl: error: {path}: {said}\n", raw


def test_unreadable_and_malformed_files(tmp_path, capsys):
    assert main(["check", str(tmp_path / "nope.yaml")]) == 2
    assert "cannot read" in capsys.readouterr().err
    bad = tmp_path / "x.yaml"
    bad.write_text("name: [unclosed\n")
    assert main(["check", str(bad)]) == 2
    assert "not valid YAML" in capsys.readouterr().err
    assert main(["plot", str(tmp_path)]) == 2
    assert "not a run directory" in capsys.readouterr().err
    paper = str(CONFIGS / "paper.yaml")
    assert main(["controllers", paper, "--mavlink", "udpout:127.0.0.1:9"]) == 2
    assert "one connection string per follower (4, in id order), got 1" in capsys.readouterr().err
    assert main(["vehicles", paper, "--base-port", "70000"]) == 2
    assert "--base-port" in capsys.readouterr().err
    assert main(["bench", "--against", str(tmp_path)]) == 2
    assert "not a swarm-sitl source tree" in capsys.readouterr().err


def test_check_passes_paper_and_names_failures_on_ring(capsys):
    assert main(["check", str(CONFIGS / "paper.yaml")]) == 0
    out = capsys.readouterr().out
    assert "all conditions hold." in out and "FAILS" not in out
    assert main(["check", str(CONFIGS / "ring.yaml")]) == 0
    out = capsys.readouterr().out
    failing = [line for line in out.splitlines() if line.rstrip().endswith("FAILS")]
    assert (
        len(failing) == 2
        and failing[0].strip().startswith("l_a >")
        and failing[1].strip().startswith("k_a >")
    )
    assert "suggested gains" in out


def test_check_warns_when_the_estimator_flies_the_printed_bracket(capsys, tmp_path):
    """The conditions cover the sliding-surface bracket (docs/paper.md, erratum 7); `check` says so, and
    warns when the config flies the bracket as printed."""
    assert main(["check", str(CONFIGS / "paper.yaml")]) == 0
    out = capsys.readouterr().out
    assert "this config flies bracket sliding_surface" in out and "WARNING" not in out
    text = (CONFIGS / "paper.yaml").read_text().replace("bracket: sliding_surface", "bracket: printed")
    (tmp_path / "printed.yaml").write_text(text)
    assert main(["check", str(tmp_path / "printed.yaml")]) == 0
    out = capsys.readouterr().out
    assert "all conditions hold." in out  # the same verdicts ...
    warnings = [line for line in out.splitlines() if line.startswith("WARNING")]
    assert len(warnings) == 1 and "does not cover it" in warnings[0]  # ... not a guarantee


def test_sim_writes_a_run_directory_and_plot_draws_it(tmp_path):
    run = tmp_path / "run"
    r = cli_ok("sim", str(CONFIGS / "paper.yaml"), "--duration", "3", "--out", str(run), "--quiet")
    assert "3 s simulated" in r.stdout
    assert "no peak after 20 s (the run is shorter)" in r.stdout  # not a peak of 0 m
    swarm = json.loads((run / "summary.json").read_text())["swarm"]
    assert swarm["peak_pos_err_after_settle_m"] is None and swarm["final_pos_err_m"] > 0
    for name in ("config.yaml", "leader.npz", "summary.json", *(f"follower_{i}.npz" for i in range(1, 5))):
        assert (run / name).is_file(), name
    f1 = np.load(run / "follower_1.npz")
    assert f1["t_s"].shape == (301,) and f1["p_W"].shape == (301, 3) and f1["q_c"].shape == (301, 4)
    assert yaml.safe_load((run / "config.yaml").read_text())["duration_s"] == 3.0
    r = cli_ok("plot", str(run))
    pngs = sorted(p.name for p in (run / "plots").glob("*.png"))
    assert pngs == [
        "estimator_error.png",
        "formation_3d.png",
        "position_error.png",
        "thrust.png",
        "velocity_error.png",
    ]
    assert all((run / "plots" / p).stat().st_size > 10_000 for p in pngs)


def test_children_import_what_the_supervisor_imports_not_the_working_directory(tmp_path):
    """A run started from a directory that holds other copies of the packages (a checkout beside
    an installed package) must not run its children from those copies; and a run from a checkout
    that is not installed (no PYTHONPATH either) must still find its own packages in the children."""
    import sim_vehicles
    from swarm_sitl.running.children import child_env, module_argv

    for pkg in ("sim_vehicles", "swarm_sitl"):
        (tmp_path / pkg).mkdir()
        (tmp_path / pkg / "__init__.py").write_text("raise SystemExit(7)\n")
        (tmp_path / pkg / "__main__.py").write_text("raise SystemExit(7)\n")
    here = str(Path(sim_vehicles.__file__).resolve().parents[1])
    for env in ({"PATH": "/usr/bin:/bin", "PYTHONPATH": here}, child_env({"PATH": "/usr/bin:/bin"})):
        for module in ("sim_vehicles", "swarm_sitl"):
            r = subprocess.run(
                [*module_argv(module), "--help"], cwd=tmp_path, env=env, capture_output=True, text=True
            )
            assert r.returncode == 0 and "usage" in r.stdout.lower(), (module, env, r.stderr[-300:])


_PAPER_TEXT = (CONFIGS / "paper.yaml").read_text()


@settings(
    max_examples=200,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)
@given(
    data=st.one_of(
        st.binary(max_size=400),
        st.text(max_size=200).map(str.encode),
        st.integers(0, len(_PAPER_TEXT)).map(lambda n: _PAPER_TEXT[:n].encode()),  # cut short
    )
)
def test_any_config_file_gives_one_line_never_a_traceback(tmp_path, capsys, data):
    """Binary garbage, broken YAML, YAML of the wrong shape, a config cut short: exit 2 and one
    line on stderr (a cut that leaves a whole valid config passes: exit 0)."""
    path = tmp_path / "c.yaml"
    path.write_bytes(data)
    code = main(["check", str(path)])
    err = capsys.readouterr().err
    if code == 0:
        assert err == ""
        return
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert err.startswith("swarm-sitl: error: ")


@given(
    st.sampled_from([("gains", "k_p"), ("vehicle", "mass_kg"), ("rates", "control_hz")]),
    st.one_of(
        st.text("abcdefghijklmnopqrstuvwxyz", min_size=1, max_size=8).filter(
            lambda s: s not in {"inf", "nan", "infinity"}
        ),
        st.lists(st.integers(), max_size=3),
        st.dictionaries(st.sampled_from("xyz"), st.integers(), max_size=2),
    ),
    st.text("abcdefghijklmnopqrstuvwxyz", min_size=1, max_size=8),
)
@settings(max_examples=30)  # (each example validates the paper's config twice: about 10 ms)
def test_a_refused_value_is_shown_once_and_a_refused_structure_is_not_dumped(field, value, model):
    """A number given a word: the line shows the word, once. Given a list or a mapping: it says
    what was expected without printing what was given. A value our own check refuses (a vehicle
    model that is none): that check names it, and it is not shown a second time."""
    data = config_data("paper")
    data[field[0]][field[1]] = value
    with pytest.raises(ConfigError) as e:
        parse_config(data)
    line = str(e.value)
    assert line.startswith(f"config: {field[0]}.{field[1]}: ") and "\n" not in line
    if isinstance(value, str):
        assert line.endswith(f" (got {value!r})") and line.count(repr(value)) == 1
    else:
        assert "(got" not in line
    data = config_data("paper")
    data["vehicle"]["model"] = f"no_such_{model}"
    with pytest.raises(ConfigError) as e:
        parse_config(data)
    assert str(e.value).count(repr(f"no_such_{model}")) == 1 and "(got" not in str(e.value)


@settings(suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.integers(0, _PAPER_TEXT.count("\n")))
def test_a_yaml_mistake_is_named_by_its_line_wherever_it_is(tmp_path, capsys, at):
    """A line that is not YAML (``a: b: c``), put before any line of the paper's config (or after
    the last): the one line says the line it is on, counted from 1."""
    lines = _PAPER_TEXT.splitlines()
    path = tmp_path / "c.yaml"
    path.write_text("\n".join([*lines[:at], "broken: a: b", *lines[at:]]) + "\n")
    assert main(["check", str(path)]) == 2
    assert capsys.readouterr().err.strip().endswith(f"not valid YAML at line {at + 1}")


@pytest.mark.parametrize("command", ["run", "sim"])
@pytest.mark.parametrize(
    "duration", ["inf", "-inf", "nan", "0", "-3", "1e400", "1e300", "4294968", "abc", ""]
)
def test_any_duration_gives_one_error_line(tmp_path, capsys, duration, command):
    """Refused before anything starts: our one line, or argparse's usage and its one line."""
    try:
        code = main(
            [command, str(CONFIGS / "paper.yaml"), f"--duration={duration}", "--out", str(tmp_path / "r")]
        )
    except SystemExit as e:  # argparse's own refusal of a non-number
        code = e.code
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err
    errors = [line for line in err.splitlines() if "error:" in line]
    assert len(errors) == 1 and "--duration" in errors[0], err
    assert not (tmp_path / "r").exists()


def test_the_longest_duration_is_the_last_ms_time_boot_ms_can_stamp(paper_cfg):
    """``duration_s`` up to ``(2**32 - 1)`` ms, MAVLink's uint32 ``time_boot_ms``, and not a float past."""
    from swarm_sitl.config.load import ConfigError, with_duration

    longest = (2**32 - 1) / 1000
    assert with_duration(paper_cfg, longest).n_control_steps == round(longest * paper_cfg.rates.control_hz)
    with pytest.raises(ConfigError, match="cannot be flown"):
        with_duration(paper_cfg, float(np.nextafter(longest, np.inf)))


def test_router_refuses_a_bad_endpoint_or_users_file_in_one_line(capsys, tmp_path):
    assert main(["router", "--listen", "tcp/999.1.1.1:7447"]) == 2
    assert main(["router", "--listen", "tcp/127.0.0.1:0", "--users-file", str(tmp_path / "nope")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and err[0].startswith(
        "swarm-sitl: error: cannot open a zenoh router on tcp/999.1.1.1"
    )
    assert "/.cargo/" not in err[0]  # zenoh's source location is not the user's business
    assert err[1] == f"swarm-sitl: error: --users-file {tmp_path / 'nope'}: no such file"


def test_a_config_loaded_again_unchanged_is_the_same_object_and_a_changed_one_is_parsed(tmp_path):
    """The fork server loads the run's config once and its children get that object (see
    ``config.load._LAST``); a file that changed in between is read anew."""
    from swarm_sitl.config.load import load_config

    path = tmp_path / "c.yaml"
    text = (CONFIGS / "paper.yaml").read_text()
    path.write_text(text)
    first = load_config(path)
    assert load_config(path) is first
    path.write_text(text.replace("duration_s: 60.0", "duration_s: 7.0"))
    changed = load_config(path)
    assert changed is not first and changed.duration_s == 7.0 and first.duration_s == 60.0


#: a trajectory of each kind, and the key of it the test gives a bad value
_TRAJECTORIES = [
    ({"type": "helix", "radius_m": 5.0, "angular_rate_radps": 0.2, "climb_rate_mps": 1.0}, "radius_m"),
    (
        {"type": "figure_eight", "amplitude_x_m": 4.0, "amplitude_y_m": 2.0, "angular_rate_radps": 0.3},
        "amplitude_y_m",
    ),
    ({"type": "line", "start_m": [0, 0, 1], "velocity_mps": [1, 0, 0]}, "start_m"),
]


def _section_values(section: type) -> st.SearchStrategy:
    """Values of every field of trajectory section ``section`` but its ``type``, none its default:
    each number drawn in [0.1, 10] (positive, as a radius must be), each vector of three such."""
    number = st.floats(0.1, 10.0)
    return st.fixed_dictionaries(
        {
            name: st.tuples(number, number, number) if "tuple" in str(field.annotation) else number
            for name, field in section.model_fields.items()
            if name != "type"
        }
    )


@settings(max_examples=10, deadline=None)
@given(data=st.data())
def test_every_key_of_a_trajectory_section_reaches_the_trajectory_it_builds(data):
    """For each kind of the leader's trajectory, every key given a value of its own is that field
    of the trajectory built (a key ``build`` dropped would keep the trajectory's default): the
    section and the trajectory have the same fields, and the built one equals the one made from
    the section's keys by name."""
    import dataclasses
    import typing

    from swarm_sitl.config.schema import LeaderSection

    union = typing.get_args(LeaderSection.model_fields["trajectory"].annotation)
    for section in union:
        values = data.draw(_section_values(section))
        kind = section.model_fields["type"].annotation.__args__[0]
        built = section.model_validate({"type": kind, **values}).build()
        assert {f.name for f in dataclasses.fields(built)} == set(values), section
        assert built == type(built)(**values), (section, values)


@pytest.mark.parametrize(("trajectory", "bad"), _TRAJECTORIES)
def test_a_trajectorys_bad_value_is_named_by_its_key_not_its_kinds_name(trajectory, bad):
    """The line names ``leader.trajectory.KEY``, as the file is written, whichever kind of
    trajectory it is (pydantic's path has the kind's name in it too), and the value given."""
    from swarm_sitl.config.load import ConfigError, parse_config

    data = config_data("paper")
    data["leader"]["trajectory"] = {**trajectory, bad: "north"}
    with pytest.raises(ConfigError) as e:
        parse_config(data, "my.yaml")
    line = str(e.value)
    assert line.startswith(f"my.yaml: leader.trajectory.{bad}: ") and "'north'" in line, line


def test_a_seed_and_a_duration_are_taken_over_their_whole_ranges_and_refused_just_past_them(paper_cfg):
    """``--seed`` from 0 to 2**63 - 1 and ``--duration`` any time above 0 up to the longest
    (under a second too): taken; just past either end: one line naming the flag."""
    from swarm_sitl.config.load import ConfigError, with_duration, with_seed

    for seed in (0, 1, 2**63 - 1):
        assert with_seed(paper_cfg, seed).seed == seed
    for seed in (-1, 2**63):
        with pytest.raises(
            ConfigError, match=rf"^--seed must be an integer from 0 to 2\*\*63 - 1, got {seed}$"
        ):
            with_seed(paper_cfg, seed)
    for d in (0.05, 0.5, 1.0, 7.25):
        assert with_duration(paper_cfg, d).duration_s == d
    for d in (0.0, -1.0, math.inf, math.nan):
        with pytest.raises(ConfigError, match="--duration"):
            with_duration(paper_cfg, d)


def _number_paths(d, path=()):
    """The path of every number in a config's data."""
    if isinstance(d, dict):
        for k, v in d.items():
            yield from _number_paths(v, (*path, k))
    elif isinstance(d, list):
        for i, v in enumerate(d):
            yield from _number_paths(v, (*path, i))
    elif isinstance(d, int | float) and not isinstance(d, bool):
        yield path


@pytest.mark.parametrize("value", [float("inf"), float("nan")])
def test_an_infinite_or_nan_number_anywhere_in_a_config_is_one_line_or_a_config(tmp_path, value):
    """Every number of the paper's config (with a wind section), one at a time made infinite or
    not a number, as YAML's .inf and .nan write them: the config loads, or its refusal is one line
    naming the file; never another error (attitude_hz: .inf was an OverflowError)."""
    import yaml

    from swarm_sitl.config.load import ConfigError, load_config

    base = config_data("paper")
    base["wind"] = {"mean_mps": [1.0, 0.0, 0.0], "gust_mps": 0.5, "gust_time_s": 1.0}
    paths = list(_number_paths(base))
    assert len(paths) > 30
    for where in paths:
        data = config_data("paper") | {"wind": dict(base["wind"])}
        data["wind"]["mean_mps"] = list(base["wind"]["mean_mps"])
        node = data
        for k in where[:-1]:
            node = node[k]
        node[where[-1]] = value
        path = tmp_path / "c.yaml"
        path.write_text(yaml.safe_dump(data))
        try:
            load_config(path)
        except ConfigError as e:
            assert str(e).startswith(f"{path}: ") and "\n" not in str(e), (where, str(e))


@settings(max_examples=20, deadline=None)
@given(substeps=st.integers(1, 1000), hold=st.sampled_from(["extrapolate", "zero_order"]))
def test_the_estimators_substeps_and_hold_in_a_config_are_the_laws(substeps, hold):
    """``rates.estimator_substeps`` and ``estimator.neighbour_hold`` reach the paper's law as it is
    built for a follower, whatever their values (not only the defaults)."""
    from swarm_sitl.config.schema import SwarmConfig
    from swarm_sitl.laws.follower_law import HOLD_EXTRAPOLATE, HOLD_ZERO_ORDER
    from swarm_sitl.laws.zou_meng import ZouMengLaw
    from swarm_sitl.nodes.assembly import law_context, reported_vehicle_params

    data = config_data("paper")
    data["rates"]["estimator_substeps"] = substeps
    data.setdefault("estimator", {})["neighbour_hold"] = hold
    cfg = SwarmConfig.model_validate(data)
    law = ZouMengLaw(law_context(cfg, 1, *reported_vehicle_params(cfg)))
    assert law.substeps == substeps
    assert law.hold == {"extrapolate": HOLD_EXTRAPOLATE, "zero_order": HOLD_ZERO_ORDER}[hold]


def test_each_override_of_a_config_is_refused_in_one_line_naming_its_flag_or_its_file(tmp_path):
    """``--duration``, ``--spec`` and ``--faults`` given what cannot be flown: each refusal whole,
    naming the flag or the file it came from."""
    from swarm_sitl.config.load import ConfigError, with_duration, with_faults, with_spec

    cfg = config("paper")
    (tmp_path / "not_a_list.yaml").write_text("a: 1\n")
    (tmp_path / "no_signal.yaml").write_text("- name: x\n  formula: 'always (nope <= 1)'\n")
    (tmp_path / "not_a_plan.yaml").write_text("- 1\n")
    (tmp_path / "off_graph.yaml").write_text("seed: 1\nplan: [{edge: [9, 9], loss: 0.5}]\n")
    signals = "pos_err_m, vel_err_mps, est_pos_err_m, altitude_m, speed_mps, thrust_frac, failsafe"
    cases = [
        (lambda: with_duration(cfg, 0.0), "--duration must be a number of seconds > 0, got 0.0"),
        (lambda: with_duration(cfg, math.inf), "--duration must be a number of seconds > 0, got inf"),
        (
            lambda: with_duration(cfg, 1e300),
            "--duration: duration_s (1e+300) cannot be flown: MAVLink's time_boot_ms (uint32 ms) wraps "
            "after 4294967.295 s (49.7 days)",
        ),
        (
            lambda: with_spec(cfg, tmp_path / "not_a_list.yaml"),
            f"{tmp_path / 'not_a_list.yaml'}: expected a list of requirements (name, over, formula)",
        ),
        (
            lambda: with_spec(cfg, tmp_path / "no_signal.yaml"),
            f"{tmp_path / 'no_signal.yaml'}: spec x: no signal nope for followers (there: {signals})",
        ),
        (
            lambda: with_faults(cfg, tmp_path / "not_a_plan.yaml"),
            f"{tmp_path / 'not_a_plan.yaml'}: expected a fault plan (seed, plan) at the top level",
        ),
        (
            lambda: with_faults(cfg, tmp_path / "off_graph.yaml"),
            f"{tmp_path / 'off_graph.yaml'}: faults.plan.0: edge 9->9 is not in the graph",
        ),
    ]
    for override, said in cases:
        with pytest.raises(ConfigError) as e:
            override()
        assert str(e.value) == said
