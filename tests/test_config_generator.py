"""``swarm-sitl new``: generated swarms load, have the asked shape, and their gain notes are true."""

import itertools
import math

import numpy as np
import pytest
import yaml
from hypothesis import example, given, settings
from hypothesis import strategies as st

from swarm_sitl.cli import main
from swarm_sitl.config.generator import (
    FORMATIONS,
    GRAPHS,
    MAX_SUGGESTED_K,
    PAPER_GAINS,
    SPACING_M,
    TRAJECTORIES,
    GeneratorError,
    generate,
    layer_width,
    random_edges,
)
from swarm_sitl.config.load import load_config, parse_config
from swarm_sitl.laws.gain_conditions import check_gains
from swarm_sitl.running.sim import run_sim
from tests.support import USERS_LAW, USERS_VEHICLE, users_plugins


def _load(text: str):
    return parse_config(yaml.safe_load(text), "generated")


@pytest.mark.unit
@pytest.mark.parametrize("graph, n", list(itertools.product(GRAPHS, (1, 2, 7, 16, 64))))
def test_every_graph_reaches_every_follower_with_the_asked_shape(graph, n):
    cfg = _load(generate(n, graph, "grid", "helix", seed=n))
    assert cfg.n_followers == n and [f.id for f in cfg.followers] == list(range(1, n + 1))
    edges = cfg.graph_edges()
    assert len(set(edges)) == len(edges) and all(s != d for s, d in edges)
    g = cfg.build_graph()
    assert g.unreachable_followers() == []  # also checked by the schema at load
    into = {i: sorted(s for s, d in edges if d == i) for i in range(1, n + 1)}
    if graph == "ring":
        assert into[1] == ([0, n] if n > 1 else [0])
        assert all(into[i] == [i - 1] for i in range(2, n + 1))
    elif graph == "tree":
        assert all(into[i] == [(i - 1) // 2] for i in range(1, n + 1))
    elif graph == "layered":
        w = layer_width(n)
        assert all(into[i] == [0] for i in range(1, min(w, n) + 1))
        for i in range(w + 1, n + 1):
            assert into[i] == ([i - w - 1, i - w] if (i - 1) % w else [i - w])
    else:  # random: a spanning tree from earlier nodes, plus edges between followers
        assert all(any(s < i for s in into[i]) for i in range(1, n + 1))


@pytest.mark.unit
@pytest.mark.parametrize("formation, n", list(itertools.product(FORMATIONS, (1, 3, 10, 64))))
def test_formations_are_centred_and_spaced(formation, n):
    cfg = _load(generate(n, "layered", formation, "line"))
    d = np.array([f.offset_m for f in cfg.followers])
    centre = d.mean(axis=0) if formation == "circle" else (d.max(axis=0) + d.min(axis=0)) / 2
    np.testing.assert_allclose(centre, 0.0, atol=1e-4)  # centred on the leader
    assert np.all(d[:, 2] == 0.0)
    if n > 1:
        gaps = [np.linalg.norm(a - b) for a, b in itertools.combinations(d, 2)]
        assert min(gaps) == pytest.approx(SPACING_M, abs=1e-4)  # nobody closer than the spacing


@pytest.mark.unit
@pytest.mark.parametrize("trajectory", TRAJECTORIES)
def test_initial_positions_spread_around_the_places_at_the_leaders_start(trajectory):
    cfg = _load(generate(12, "random", "circle", trajectory, seed=5))
    p0 = cfg.trajectory().derivatives(0.0)[0]
    for f in cfg.followers:
        dev = np.asarray(f.initial_position_m) - p0 - np.asarray(f.offset_m)
        assert np.all(np.abs(dev) <= 2.0 + 1e-5)
    devs = np.array([np.asarray(f.initial_position_m) - p0 - f.offset_m for f in cfg.followers])
    # drawn each on its own, uniformly on +-2 m: 36 draws all of one sign, or two alike to the
    # file's six digits, would come once in billions
    assert (devs < 0).any() and (devs > 0).any() and len(np.unique(devs.round(4))) == devs.size
    assert cfg.gains.k_gamma >= np.max(
        np.linalg.norm(cfg.trajectory().derivatives(np.linspace(0, 70, 701))[:, 2], axis=1)
    )


@pytest.mark.unit
@pytest.mark.parametrize(
    "graph, n", [("layered", 4), ("tree", 16), ("ring", 4), ("ring", 16), ("random", 32)]
)
def test_the_gain_notes_say_what_check_finds(graph, n):
    """The paper's gains where every condition holds with them; else ``check``'s suggestion where
    every condition holds with it (the notes name what failed with the paper's); else the paper's,
    the notes naming what fails and why the suggestion was not taken."""
    text = generate(n, graph, "grid", "helix", seed=2)
    cfg = _load(text)
    lines = text.splitlines()
    notes = list(itertools.takewhile(lambda x: x.startswith("  # "), lines[lines.index("gains:") + 1 :]))
    notes = [line.removeprefix("  # ") for line in notes]
    args = (cfg.build_graph(), cfg.trajectory(), cfg.gravity_mps2, 200.0)
    report = check_gains(args[0], cfg.gain_dict(), *args[1:])
    paper = check_gains(args[0], {**cfg.gain_dict(), **PAPER_GAINS}, *args[1:])
    failing = [c.name for c in paper.conditions if not c.holds]
    written = {k: cfg.gain_dict()[k] for k in PAPER_GAINS}
    if not failing:
        assert written == PAPER_GAINS and len(notes) == 1 and "every condition" in notes[0]
    elif written != PAPER_GAINS:
        assert report.all_hold  # "every condition holds": it does, with the gains written
        # (written with six significant digits: a relative half unit of the sixth)
        assert written == pytest.approx({**PAPER_GAINS, **paper.suggestion}, rel=5e-6)
        assert notes[0] == "the paper's gains fail on this graph: " + "; ".join(failing)
    else:
        assert notes[0].startswith("the paper's gains; ") and "FAIL" in notes[0]
        assert [x.strip() for x in notes[1:-1]] == failing  # every failing condition is named
        suggested = {**PAPER_GAINS, **paper.suggestion}
        assert notes[-1].startswith("(") and notes[-1].endswith(")")
        if check_gains(args[0], suggested, *args[1:]).all_hold:
            assert f"k_p = k_v = {suggested['k_p']:.4g}" in notes[-1]
            assert f"past {MAX_SUGGESTED_K:g}" in notes[-1]
        else:
            assert notes[-1] == "(no gains were found that satisfy them)"


@pytest.mark.unit
@pytest.mark.parametrize("paper_holds", [True, False])
@pytest.mark.parametrize("suggestion_holds", [True, False])
@pytest.mark.parametrize("k", [MAX_SUGGESTED_K / 2, MAX_SUGGESTED_K, MAX_SUGGESTED_K * 2])
def test_the_gains_written_are_the_papers_unless_a_suggestion_within_the_bound_satisfies_every_condition(
    monkeypatch, paper_holds, suggestion_holds, k
):
    """Every branch of the choice, with ``check``'s verdicts given (its own are tested in
    ``test_gain_conditions.py``): the suggestion is written only where the paper's gains fail, it
    satisfies every condition and its k_p and k_v are at most ``MAX_SUGGESTED_K`` (the bound
    itself included); the notes say which, whole."""
    import types

    from swarm_sitl.config import generator

    suggestion = {"k_p": k, "k_v": k / 2, "k_a": 3.0}
    cfg = _load(generate(3, "ring", "grid", "helix"))
    asked = []

    def verdict(graph, gains, trajectory, g, horizon):
        """The first call judges the config's gains, the second the suggestion."""
        asked.append(gains)
        holds = paper_holds if len(asked) == 1 else suggestion_holds
        conditions = [types.SimpleNamespace(name=n, holds=holds) for n in ("(a) one", "(b) two")]
        return types.SimpleNamespace(all_hold=holds, conditions=conditions, suggestion=suggestion)

    monkeypatch.setattr(generator, "check_gains", verdict)
    gains, notes = generator._choose_gains(cfg)
    assert asked[0] == cfg.gain_dict() and asked[1:] in ([], [{**PAPER_GAINS, **suggestion}])
    failing = ["(a) one", "(b) two"]
    if paper_holds:
        assert gains == PAPER_GAINS
        assert notes == ["the paper's gains: every condition of `swarm-sitl check` holds on this graph"]
    elif suggestion_holds and k <= MAX_SUGGESTED_K:
        assert gains == {**PAPER_GAINS, **suggestion}
        assert notes == [
            "the paper's gains fail on this graph: (a) one; (b) two",
            "these are `swarm-sitl check`'s suggestion, with which every condition holds",
        ]
    else:
        assert gains == PAPER_GAINS
        why = (
            f"the gains that satisfy them need k_p = k_v = {k:.4g}, k_a = 3: past {MAX_SUGGESTED_K:g} the "
            "sampled sgn term's chattering costs more than the guarantee gives"
            if suggestion_holds
            else "no gains were found that satisfy them"
        )
        assert notes == [
            "the paper's gains; Theorem 1's sufficient conditions FAIL on this graph (it may still "
            "converge):",
            *("  " + name for name in failing),
            f"({why})",
        ]


@pytest.mark.unit
@pytest.mark.parametrize("n", [4, 16, 64])
def test_a_random_graph_is_a_spanning_tree_plus_about_n_over_2_edges_between_followers(n):
    """Follower i hears one of 0..i-1, then n // 2 draws of a follower pair (any two followers)
    add the new ones, none from the leader, none twice. From 16 followers on, at least one in
    each seed's: a draw falls on a self-loop (1/n) or a taken edge (at most n of n^2 pairs) with a
    chance under 1/8, all eight under 1/8^8 = 6e-8."""
    ends = set()
    for seed in range(20):
        edges = random_edges(n, np.random.default_rng(seed))
        tree, extra = edges[:n], edges[n:]
        assert [d for _, d in tree] == list(range(1, n + 1)) and all(s < d for s, d in tree)
        assert (n < 16 or len(extra) >= 1) and len(extra) <= n // 2 and len(set(edges)) == len(edges)
        assert all(1 <= s <= n and 1 <= d <= n and s != d for s, d in extra)
        # at 64 followers a draw is refused with a chance under 1/64 + 96/4096 < 0.04: 10 or more of
        # the 32 refused comes with a chance under C(32, 10) 0.04^10 < 1e-6
        assert n < 64 or len(extra) > n // 2 - 10
        ends |= {("from", s) for s, _ in extra} | {("to", d) for _, d in extra}
    # every follower may be an end: the first and the last, each way, in 20 seeds' draws (at 16
    # followers, 160 draws: a given end missed by all with a chance under (15/16)^150 < 1e-4)
    assert n < 16 or {("from", 1), ("to", 1), ("from", n), ("to", n)} <= ends


@pytest.mark.unit
def test_the_same_seed_writes_the_same_file_and_another_seed_another_swarm():
    a = generate(10, "random", "grid", "figure_eight", seed=1)
    assert generate(10, "random", "grid", "figure_eight", seed=1) == a
    b = generate(10, "random", "grid", "figure_eight", seed=2)
    assert _load(a).graph_edges() != _load(b).graph_edges()


@pytest.mark.unit
def test_new_writes_a_config_and_refuses_bad_requests_in_one_line(tmp_path, capsys):
    out = tmp_path / "s.yaml"
    assert main(["new", "--followers", "6", "--graph", "ring", "-o", str(out)]) == 0
    assert _load(out.read_text()).n_followers == 6
    assert main(["new", "--followers", "6", "-o", str(out)]) == 2  # exists
    assert main(["new", "--followers", "0", "-o", str(tmp_path / "t.yaml")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        f"swarm-sitl: error: {out} exists (--force to overwrite)",
        "swarm-sitl: error: --followers must be 1..254 (MAVLink system ids), got 0",
    ]
    assert main(["new", "--followers", "6", "--force", "--seed", "3", "-o", str(out)]) == 0
    assert main(["check", str(out)]) == 0


@pytest.mark.unit
def test_254_followers_the_most_mavlink_system_ids_allow_are_generated(monkeypatch):
    """The largest swarm ``new`` writes (the ground station has id 255). Its gain check is given
    as holding: the check itself is the same at any size, and takes seconds at 254."""
    import types

    from swarm_sitl.config import generator

    holds = types.SimpleNamespace(all_hold=True, conditions=[], suggestion={})
    monkeypatch.setattr(generator, "check_gains", lambda *args: holds)
    cfg = _load(generate(254, "ring", "grid", "helix"))
    assert [f.id for f in cfg.followers] == list(range(1, 255))


@pytest.mark.unit
@pytest.mark.parametrize("followers", [-1, 0, 255, 256, 10_000])
def test_a_follower_count_outside_the_mavlink_system_ids_is_refused_in_one_line(followers):
    """MAVLink system ids are 1..255, and the ground station is 255: 254 followers at most."""
    with pytest.raises(GeneratorError) as e:
        generate(followers, "ring", "grid", "helix")
    assert str(e.value) == f"--followers must be 1..254 (MAVLink system ids), got {followers}"


@pytest.mark.unit
@pytest.mark.parametrize(
    "kwargs, named",
    [
        ({"duration_s": 0.0}, "--duration must be a number of seconds > 0, got 0.0"),
        ({"duration_s": math.inf}, "--duration must be a number of seconds > 0, got inf"),
        ({"graph": "star"}, f"--graph must be one of {', '.join(GRAPHS)}, got 'star'"),
        ({"trajectory": "loop"}, f"--trajectory must be one of {', '.join(TRAJECTORIES)}, got 'loop'"),
        ({"formation": "blob"}, f"--formation must be one of {', '.join(FORMATIONS)}, got 'blob'"),
    ],
)
def test_a_bad_request_is_named_in_one_line_with_what_is_allowed(kwargs, named):
    args = {"followers": 4, "graph": "ring", "formation": "grid", "trajectory": "helix", **kwargs}
    with pytest.raises(GeneratorError) as e:
        generate(**args)
    assert str(e.value) == named


@pytest.mark.unit
def test_a_law_and_a_vehicle_model_of_the_users_are_written_as_given_and_found_beside_the_config(
    tmp_path, monkeypatch
):
    """``new --law my_law.py:... --vehicle my_vehicle.py:...`` in the config's directory, from
    another working directory: the file holds the entries as typed (relative, so the folder can
    move), and they load from the config's folder; a file that is not there is named in one line."""
    base = tmp_path / "swarm"
    base.mkdir()
    users_plugins(base)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    law, model = USERS_LAW, USERS_VEHICLE
    params = {"THRUST_TAU_S": 0.02}
    text = generate(3, "ring", "grid", "helix", law=law, law_base=base, vehicle=model, vehicle_params=params)
    data = yaml.safe_load(text)
    assert data["law"] == {"entry": law, "params": {}} and data["vehicle"]["model"] == model
    (base / "s.yaml").write_text(text)
    cfg = load_config(base / "s.yaml")
    assert cfg.law.entry == f"{base / 'my_law.py'}:ConsensusPD"
    assert cfg.vehicle.model == f"{base / 'my_vehicle.py'}:LaggyVtol"
    assert cfg.vehicle.params == {"THRUST_TAU_S": 0.02}
    for kwargs, gone in (
        ({"law": "gone.py:Law"}, "gone.py"),
        ({"vehicle": "gone_vehicle.py:V"}, "gone_vehicle.py"),
    ):
        with pytest.raises(GeneratorError) as e:
            generate(3, "ring", "grid", "helix", law_base=base, **kwargs)
        line = str(e.value)
        assert gone in line and "\n" not in line and not line.startswith("generated config")
        assert line.startswith(("law: ", "vehicle"))


@pytest.mark.integration
def test_a_generated_swarm_flies_into_formation():
    cfg = _load(generate(6, "random", "line", "figure_eight", seed=4, duration_s=15.0))
    rec = run_sim(cfg)
    for a in rec.followers.values():
        e = np.linalg.norm(a["pos_err_m"], axis=1)
        assert e[0] > 0.3  # starts out of place
        assert e[a["t_s"] >= 12.0].max() < 0.01


@pytest.mark.system
def test_bench_scale_writes_its_table_with_consistent_figures(tmp_path, capsys):
    import csv

    assert main(["bench", "--scale", "0,2"]) == 2  # one line, no run
    assert main(["bench", "--scale", "2", "--split", "3"]) == 2  # not one of the counts
    assert main(["bench", "--empty"]) == 2  # only with --scale
    args = [
        "bench",
        "--scale",
        "2",
        "--scale-duration",
        "1",
        "--scale-realtime",
        "2",
        "--split",
        "2",
        "--empty",
    ]
    assert main([*args, "--out", str(tmp_path)]) == 0
    (row,) = list(csv.DictReader((tmp_path / "scale.csv").read_text().splitlines()))
    r = {k: float(v) for k, v in row.items()}
    assert r["followers"] == 2 and r["edges"] == 2  # layered: the leader feeds both
    assert r["startup_s"] > 0 and r["run_x"] > r["e2e_x"] > 0  # end to end counts the start-up
    parts = r["cpu_vehicles"] + r["cpu_controllers"] + r["cpu_leader"] + r["cpu_supervisor"]
    assert r["cpu_per_sim_s"] == pytest.approx(parts, rel=1e-9)
    assert r["overhead"] == pytest.approx(r["cpu_per_sim_s"] / r["sim_cpu_per_sim_s"], rel=1e-9)
    assert 0 < r["empty_cpu_per_sim_s"] < r["cpu_per_sim_s"] and r["empty_x"] > 0  # no work: cheaper
    bare = r["empty_cpu_per_sim_s"] + r["sim_cpu_per_sim_s"]
    assert r["over_empty_sim"] == pytest.approx(r["cpu_per_sim_s"] / bare, rel=1e-3)
    # in the order they happen; a process's age has the kernel's 10 ms resolution, so a forked
    # controller can reach its main within one of its ticks: 0.0
    assert 0 <= r["ctrl_main_s"] <= r["ctrl_zenoh_s"] <= r["ctrl_ready_s"] and r["ctrl_ready_s"] > 0
    assert (tmp_path / "scale.png").stat().st_size > 10_000
    (rt,) = list(csv.DictReader((tmp_path / "realtime.csv").read_text().splitlines()))
    assert int(rt["followers"]) == 2 and 0.0 <= float(rt["late_share"]) <= 1.0
    assert 0 < float(rt["out_median_ms"]) <= float(rt["out_p99_ms"])
    # every node's CPU is its main thread's and its other threads' (exact, per thread)
    nodes = r["cpu_vehicles"] + r["cpu_controllers"] + r["cpu_leader"]
    assert r["cpu_main_threads"] + r["cpu_other_threads"] == pytest.approx(nodes, rel=0.15)
    assert 0 < r["cpu_other_threads"] < r["cpu_main_threads"]
    split = {row["kind"]: row for row in csv.DictReader((tmp_path / "split2.csv").read_text().splitlines())}
    for kind, row in split.items():
        assert sum(float(v) for k, v in row.items() if k != "kind") == pytest.approx(1.0, abs=1e-3), kind
    assert float(split["vehicle"]["zenoh"]) == 0.0 < float(split["vehicle"]["MAVLink"])  # no zenoh there
    assert float(split["leader"]["MAVLink"]) == 0.0 < float(split["leader"]["zenoh"])  # no vehicle link
    assert float(split["controller"]["MAVLink"]) > 0 and float(split["controller"]["zenoh"]) > 0
    # beyond the floor: the run's CPU is the empty swarm's, sim's and the gap's, all measured
    gap = {g["kind"]: g for g in csv.DictReader((tmp_path / "gap.csv").read_text().splitlines())}
    assert set(gap) == {"vehicle", "controller", "leader", "router", "total"}
    total = {k: float(v) for k, v in gap["total"].items() if k != "kind"}
    assert total["empty"] == pytest.approx(r["empty_cpu_per_sim_s"], rel=1e-6)
    assert total["sim"] == pytest.approx(r["sim_cpu_per_sim_s"], rel=1e-6)
    assert total["run"] == pytest.approx(r["cpu_per_sim_s"], rel=0.15)  # (threads against processes)
    assert total["gap"] == pytest.approx(total["run"] - total["empty"] - total["sim"], abs=1e-6)
    out = capsys.readouterr().out
    assert "scale.csv" in out and "where the CPU goes at 2 followers" in out
    assert "beyond the floor at 2 followers" in out and "the gap is: " in out


@pytest.mark.unit
@settings(max_examples=25, deadline=None)
@given(
    duration_s=st.floats(1e-3, 4e6),
    params=st.dictionaries(st.sampled_from(["T_TAU_S", "MC_ROLL_P", "MC_PITCH_P"]), st.floats(0.0, 1.0)),
)
@example(duration_s=1.0, params={"MC_ROLL_P": 1.0, "T_TAU_S": 0.0})
@example(duration_s=0.5, params={})
@example(duration_s=1e6, params={"T_TAU_S": 1e-5})  # (1e+06 and 1e-05 are strings to YAML 1.1)
def test_the_numbers_a_generated_config_holds_are_the_ones_asked_to_six_digits(duration_s, params):
    """``--duration`` and the vehicle's parameters are written with six significant digits: what
    the config holds, read back, is what was asked, rounded so (1.0 as 1.0, 0 as 0, and a number
    written with an exponent a number, not a string)."""
    cfg = _load(
        generate(
            2,
            "ring",
            "grid",
            "figure_eight",
            duration_s=duration_s,
            vehicle="px4_quad_x",
            vehicle_params=params,
        )
    )
    assert cfg.duration_s == float(f"{duration_s:.6g}")
    assert cfg.vehicle.params == {k: float(f"{v:.6g}") for k, v in params.items()}
    assert cfg.name == "ring2-grid-figure-eight"
