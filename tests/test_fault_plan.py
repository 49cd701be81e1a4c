"""The fault plan: validated at load with one-line errors, and the fate of each message a pure,
seeded function with the statistics the plan asks for."""

import math

import numpy as np
import pytest
import yaml

from swarm_sitl.config.load import ConfigError, parse_config, with_faults
from swarm_sitl.faults.draws import uniform
from swarm_sitl.faults.plan import FaultEntry, FaultPlan, edge_channel, fate
from tests.support import CONFIGS, cli

pytestmark = pytest.mark.unit


def _paper(faults: object) -> dict:
    data = yaml.safe_load((CONFIGS / "paper.yaml").read_text())
    data["faults"] = faults
    return data


@pytest.mark.parametrize(
    "plan, message",
    [
        ([{"edge": [1, 4], "los": 0.5}], r"faults\.plan\.0\.los: unknown key"),
        ([{"edge": [1, 4]}], r"faults\.plan\.0: name exactly one of drop, .* \(how it fails\); got none"),
        ([{"edge": [1, 4], "into": 4, "drop": True}], r"name exactly one of edge, .* got \['edge', 'into'\]"),
        ([{"edge": [1, 4], "drop": True, "loss": 0.1}], r"got \['drop', 'loss'\]"),
        ([{"edge": [3, 4], "drop": True}], r"faults\.plan\.0: edge 3->4 is not in the graph"),
        ([{"edge": [1, 4], "drop": True}, {"into": 9, "drop": True}], r"faults\.plan\.1\.into: follower 9"),
        ([{"edge": [1, 4], "drop": True, "from_s": 60}], r"faults\.plan\.0\.from_s: 60 s is not within"),
        ([{"edge": [1, 4], "drop": True, "until_s": 61}], r"faults\.plan\.0\.until_s: 61 s is past the end"),
        ([{"edge": [1, 4], "drop": True, "from_s": 5, "until_s": 5}], r"until_s \(5\) must be after from_s"),
        ([{"edge": [1, 4], "stall": True}], r"a stall needs until_s"),
        ([{"edge": [1, 4], "loss": 0.1, "jitter_s": 0.1}], r"jitter_s goes with delay_s"),
        ([{"edge": [1, 4], "loss": 1.5}], r"faults\.plan\.0\.loss: .*less than or equal to 1"),
        ([{"edge": [1, 4], "loss": 0.5, "from_s": -1}], r"faults\.plan\.0\.from_s: .*greater than or equal"),
        (
            [{"controller": 5, "kill": True, "from_s": 1}],
            r"faults\.plan\.0\.controller: follower 5 is not 1\.\.4",
        ),
        ([{"mavlink": 5, "loss": 0.1}], r"faults\.plan\.0\.mavlink: follower 5 is not 1\.\.4"),
        (
            [{"controller": 2, "kill": True, "from_s": 55, "restart_after_s": 5}],
            r"faults\.plan\.0: controller_2 is back at 60 s, not within the run \(0\.\.60 s\)",
        ),
        ([{"controller": 2, "freeze_s": 10, "from_s": 51}], r"controller_2 is back at 61 s, not within"),
        (
            [
                {"controller": 2, "kill": True, "from_s": 5, "restart_after_s": 5},
                {"controller": 2, "kill": True, "from_s": 9},
            ],
            r"faults\.plan\.1: controller_2 is killed again before it is back",
        ),
    ],
)
def test_a_bad_plan_is_one_line_naming_the_entry(plan, message):
    with pytest.raises(ConfigError, match=message) as e:
        parse_config(_paper({"plan": plan}), "paper.yaml")
    assert "\n" not in str(e.value)


def test_the_plan_names_what_how_and_when():
    cfg = parse_config(
        _paper(
            {
                "seed": 9,
                "plan": [
                    {"edge": [0, 1], "drop": True, "from_s": 20, "until_s": 30},
                    {"into": 4, "delay_s": 0.05, "jitter_s": 0.02},
                    {"out_of": 2, "duplicate": 0.1},
                    {"leader_edges": True, "stall": True, "from_s": 5, "until_s": 6},
                ],
            }
        )
    )
    p, edges = cfg.faults, cfg.graph_edges()
    assert p.seed == 9
    assert [f.edges(edges) for f in p.plan] == [
        [(0, 1)],
        [(1, 4), (2, 4)],
        [(2, 4)],
        [(0, 1), (0, 2), (0, 3)],
    ]
    assert [j for j, _ in p.on_edge(2, 4, edges)] == [1, 2]
    assert p.plan[1].how == "delay 0.05 s + U(0, 0.02) s" and p.plan[3].what == "leader's edges"


def test_a_fault_file_replaces_the_plan_and_is_checked_against_the_config(tmp_path, paper_cfg):
    f = tmp_path / "plan.yaml"
    f.write_text("faults:\n  seed: 4\n  plan:\n    - {edge: [2, 4], loss: 0.25}\n")
    assert with_faults(paper_cfg, f).faults.plan[0].loss == 0.25
    f.write_text("plan:\n  - {edge: [2, 3], loss: 0.25}\n")
    with pytest.raises(ConfigError, match=r"plan\.yaml: faults\.plan\.0: edge 2->3 is not in the graph"):
        with_faults(paper_cfg, f)
    f.write_bytes(b"\x00\xff\xfe garbage")
    with pytest.raises(ConfigError, match=r"plan\.yaml"):
        with_faults(paper_cfg, f)


def test_the_cli_refuses_a_bad_fault_file_in_one_line(tmp_path):
    f = tmp_path / "plan.yaml"
    f.write_text("plan:\n  - {edge: [1, 4], loss: 0.5, until_s: 99}\n")
    r = cli("run", str(CONFIGS / "paper.yaml"), "--faults", str(f), timeout=60)
    assert r.returncode == 2
    assert r.stderr.strip().count("\n") == 0
    assert "until_s: 99 s is past the end of the run (60 s)" in r.stderr


def _rules(*entries: dict) -> list[tuple[int, FaultEntry]]:
    return list(enumerate(FaultEntry(**e) for e in entries))


def test_a_fate_depends_only_on_seed_entry_edge_and_step():
    rules = _rules({"edge": [1, 4], "loss": 0.5}, {"edge": [1, 4], "delay_s": 0.01, "jitter_s": 0.02})
    ch = edge_channel(1, 4)
    a = [fate(7, rules, ch, k, k * 0.01, 60.0, 0.01) for k in range(500)]
    assert a == [fate(7, rules, ch, k, k * 0.01, 60.0, 0.01) for k in range(500)]
    b = [fate(8, rules, ch, k, k * 0.01, 60.0, 0.01) for k in range(500)]
    assert [f.lost for f in a] != [f.lost for f in b]  # another seed, another draw
    c = [fate(7, rules, edge_channel(2, 4), k, k * 0.01, 60.0, 0.01) for k in range(500)]
    assert [f.lost for f in a] != [f.lost for f in c]  # and each edge its own


def test_two_entries_on_one_edge_draw_independently():
    """Two losses of 1/2 on one edge lose 3/4 of the messages if their draws are independent (a
    shared draw would lose 1/2); the second entry's draws are also uncorrelated with the first's."""
    rules = _rules({"edge": [1, 4], "loss": 0.5}, {"edge": [1, 4], "corrupt": 0.5})
    n = 20000
    fates = [fate(3, rules, edge_channel(1, 4), k, 0.0, 1.0, 0.01) for k in range(n)]
    lost = sum(f.lost for f in fates)
    corrupt = sum(f.corrupt for f in fates)  # the second entry acts on the messages not lost
    assert abs(lost - n / 2) < 5 * math.sqrt(n / 4), lost
    assert abs(corrupt - n / 4) < 5 * math.sqrt(n * 3 / 16), (corrupt, n / 4)  # 1/2 of 1/2
    both = _rules({"edge": [1, 4], "loss": 0.5}, {"edge": [1, 4], "loss": 0.5})
    lost2 = sum(fate(3, both, edge_channel(1, 4), k, 0.0, 1.0, 0.01).lost for k in range(n))
    assert abs(lost2 - 0.75 * n) < 5 * math.sqrt(n * 0.75 * 0.25), lost2


def test_a_window_ends_at_until_s_and_starts_at_from_s():
    """Exactly the messages sent in [from_s, until_s) meet the entry (lockstep: sent-for time)."""
    rules = _rules({"edge": [1, 4], "drop": True, "from_s": 0.2, "until_s": 0.5})
    dt = 0.01
    lost = [k for k in range(100) if fate(1, rules, edge_channel(1, 4), k, k * dt, 1.0, dt).lost]
    assert lost == list(range(20, 50)), lost


@pytest.mark.parametrize("p", [0.02, 0.2, 0.5, 0.9])
def test_loss_happens_at_its_probability(p):
    rules = _rules({"edge": [1, 4], "loss": p})
    n = 20000
    lost = sum(fate(3, rules, 5, k, 0.0, 1.0, 0.01).lost for k in range(n))
    sigma = math.sqrt(n * p * (1 - p))
    assert abs(lost - n * p) < 5 * sigma, (lost, n * p)


def test_delays_are_the_fixed_part_plus_a_uniform_jitter():
    rules = _rules({"edge": [1, 4], "delay_s": 0.05, "jitter_s": 0.02})
    d = np.array([fate(1, rules, 5, k, 0.0, 1.0, 0.01).delay_s for k in range(20000)])
    assert d.min() >= 0.05 and d.max() < 0.07
    assert abs(d.mean() - 0.06) < 5 * 0.02 / math.sqrt(12 * len(d))  # mean of U(0.05, 0.07)
    assert np.histogram(d, bins=4, range=(0.05, 0.07))[0].min() > 4500  # spread over the range


def test_a_window_bounds_the_fault_and_a_stall_releases_at_its_end():
    rules = _rules({"edge": [1, 4], "stall": True, "from_s": 1.0, "until_s": 1.5})
    assert fate(0, rules, 5, 1, 0.99, 60.0, 0.01).delay_s == 0.0
    assert fate(0, rules, 5, 2, 1.0, 60.0, 0.01).delay_s == pytest.approx(0.5)
    assert fate(0, rules, 5, 3, 1.2, 60.0, 0.01).delay_s == pytest.approx(0.3)
    assert fate(0, rules, 5, 4, 1.5, 60.0, 0.01).delay_s == 0.0
    drop_later = _rules({"edge": [1, 4], "drop": True, "from_s": 30})
    assert not fate(0, drop_later, 5, 0, 29.9, 60.0, 0.01).lost
    assert fate(0, drop_later, 5, 0, 30.0, 60.0, 0.01).lost  # until_s defaults to the end of the run


def test_entries_act_in_plan_order_and_a_loss_ends_it():
    rules = _rules({"edge": [1, 4], "delay_s": 0.1}, {"edge": [1, 4], "drop": True})
    f = fate(0, rules, 5, 0, 0.0, 1.0, 0.01)
    assert f.lost and f.faults == (0, 1)
    rules = _rules({"edge": [1, 4], "reorder": 1.0}, {"edge": [1, 4], "duplicate": 1.0})
    f = fate(0, rules, 5, 0, 0.0, 1.0, 0.01)
    assert (f.lost, f.delay_s, f.duplicate, f.faults) == (False, 0.01, True, (0, 1))


def test_the_mixer_is_splitmix64():
    """The published first outputs of splitmix64 seeded with 0 (Vigna's reference): its state
    advances by the golden gamma and each output is the finaliser of it, which is ``_mix``."""
    from swarm_sitl.faults.draws import _mix

    gamma = 0x9E3779B97F4A7C15
    assert [_mix(k * gamma % 2**64) for k in range(3)] == [
        0xE220A8397B1DCDAF,
        0x6E789E6AA1B965F4,
        0x06C45D188009454F,
    ]


def test_a_plan_within_the_run_is_taken():
    ok = [
        {"controller": 1, "kill": True, "from_s": 50, "restart_after_s": 9.99},
        {"controller": 1, "kill": True, "from_s": 59.995},
        {"controller": 2, "freeze_s": 9, "from_s": 50},
        {"mavlink": 4, "loss": 0.1},
        {"into": 1, "loss": 0.1},
    ]
    assert len(parse_config(_paper({"plan": ok}), "paper.yaml").faults.plan) == 5


def test_uniform_draws_are_in_the_unit_interval_and_flat():
    u = np.array([uniform(11, 2, k) for k in range(50000)])
    assert u.min() >= 0.0 and u.max() < 1.0
    assert abs(u.mean() - 0.5) < 5 * math.sqrt(1 / 12 / len(u))
    counts = np.histogram(u, bins=10, range=(0, 1))[0]
    chi2 = ((counts - 5000) ** 2 / 5000).sum()
    assert chi2 < 40  # 9 degrees of freedom: p < 1e-5 of exceeding by chance


def test_an_empty_plan_is_the_default(paper_cfg):
    assert paper_cfg.faults == FaultPlan()


def _plan(*entries: dict) -> FaultPlan:
    return parse_config(_paper({"plan": list(entries)}), "paper.yaml").faults


def test_outages_are_the_ticks_each_killed_node_is_down_and_when_it_is_back():
    plan = _plan(
        {"edge": [1, 4], "loss": 0.5},  # not a process fault: no outage
        {"controller": 2, "kill": True, "from_s": 1.0, "restart_after_s": 0.5},
        {"vehicle": 3, "kill": True, "from_s": 2.0, "with_controller": False},  # its controller lives on
        {"vehicle": 4, "kill": True, "from_s": 3.004},  # and takes its controller, for good
        {"leader": True, "kill": True, "from_s": 4.0, "restart_after_s": 1.0},
        {"controller": 2, "kill": True, "from_s": 10.0},
    )
    assert plan.outages(0.01) == {2: [(100, 150), (1000, None)], 4: [(301, None)], 0: [(400, 500)]}
    assert plan.outages(0.02) == {2: [(50, 75), (500, None)], 4: [(151, None)], 0: [(200, 250)]}
    from swarm_sitl.faults.plan import down_at

    down = [k for k in range(0, 1100) if down_at(plan.outages(0.01)[2], k)]
    assert down == [*range(100, 150), *range(1000, 1100)]  # from the kill's tick to the one before back


def test_the_first_tick_at_or_after_a_time():
    from swarm_sitl.faults.plan import tick_of

    assert [tick_of(t, 0.01) for t in (0.0, 0.01, 0.015, 0.03, 1.0, 2.999)] == [0, 1, 2, 3, 100, 300]
    assert tick_of(0.1 + 0.2, 0.1) == 3  # 0.30000000000000004 s is tick 3, not 4


def test_entries_are_checked_in_time_order_and_a_kill_at_the_instant_of_return_is_refused():
    later_first = [
        {"controller": 2, "kill": True, "from_s": 5.0},
        {"controller": 2, "kill": True, "from_s": 1.0, "restart_after_s": 1.0},  # back at 2 s
    ]
    assert len(_plan(*later_first).plan) == 2
    at_return = [later_first[1], {"controller": 2, "kill": True, "from_s": 2.0}]
    with pytest.raises(ConfigError, match=r"faults\.plan\.1: controller_2 is killed again before it is back"):
        _plan(*at_return)
    assert _plan({"edge": [1, 4], "drop": True, "until_s": 60.0}).plan[0].until_s == 60.0  # to the end


def test_a_link_entry_stops_no_process_and_a_process_entry_names_no_edge():
    plan = _plan({"edge": [1, 4], "drop": True}, {"controller": 2, "kill": True, "from_s": 1})
    graph = [(0, 1), (1, 4), (2, 4)]
    assert plan.plan[0].victims() == [] and plan.plan[1].edges(graph) == []
    assert plan.plan[0].edges(graph) == [(1, 4)] and plan.plan[1].victims() == ["controller_2"]


def test_delays_of_several_entries_add_up():
    dt = 0.01
    two = _rules({"edge": [1, 4], "delay_s": 0.1}, {"edge": [1, 4], "delay_s": 0.2})
    assert fate(0, two, 5, 0, 0.0, 1.0, dt).delay_s == pytest.approx(0.3)
    stall = _rules({"edge": [1, 4], "delay_s": 0.1}, {"edge": [1, 4], "stall": True, "until_s": 0.5})
    assert fate(0, stall, 5, 0, 0.2, 1.0, dt).delay_s == pytest.approx(0.1 + 0.3)
    reorder = _rules({"edge": [1, 4], "delay_s": 0.1}, {"edge": [1, 4], "reorder": 1.0})
    assert fate(0, reorder, 5, 0, 0.0, 1.0, dt).delay_s == pytest.approx(0.1 + dt)
    # an entry outside its window is passed over, not the end of the rules
    later = _rules({"edge": [1, 4], "delay_s": 0.1, "from_s": 0.5}, {"edge": [1, 4], "drop": True})
    assert fate(0, later, 5, 0, 0.0, 1.0, dt).lost


def test_jitter_draws_are_their_own_per_seed_entry_and_channel():
    """The jitter of a message is not a function of its loss draw, and differs with the seed, the
    entry and the channel as the loss draws do."""
    rules = _rules({"edge": [1, 4], "delay_s": 0.0, "jitter_s": 1.0})
    rules2 = _rules({"edge": [1, 4], "loss": 1e-12}, {"edge": [1, 4], "delay_s": 0.0, "jitter_s": 1.0})
    n = 2000

    def jitters(seed, rules, ch):
        return np.array([fate(seed, rules, ch, k, 0.0, 1.0, 0.01).delay_s for k in range(n)])

    base = jitters(1, rules, 5)
    for other in (jitters(2, rules, 5), jitters(1, rules2, 5), jitters(1, rules, 6)):
        assert abs(np.corrcoef(base, other)[0, 1]) < 5 / math.sqrt(n)
    draws = np.array([uniform(1, 0, 5, k, 1) for k in range(n)])  # the entry's loss draws
    assert abs(np.corrcoef(base, draws)[0, 1]) < 5 / math.sqrt(n)
