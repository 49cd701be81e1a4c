"""Link models of the fault plan beyond independent loss: bursty loss (Gilbert-Elliott, netem's
parameters) against the model's closed forms, and partitions; then a lockstep swarm under bursty
loss on every edge, its counts against the model and the same run twice."""

import math

import numpy as np
import pytest
import yaml
from hypothesis import assume, given
from hypothesis import strategies as st

from swarm_sitl.config.load import ConfigError, parse_config
from swarm_sitl.faults import bursts
from swarm_sitl.faults.bursts import GilbertElliott
from swarm_sitl.faults.plan import FaultEntry, edge_channel, fate
from tests.support import CONFIGS

#: its system tests run in lockstep or ``sim`` only (no wall clock): free to run beside others
pytestmark = pytest.mark.lockstep


def _paper(plan: list[dict]) -> dict:
    data = yaml.safe_load((CONFIGS / "paper.yaml").read_text())
    data["faults"] = {"seed": 3, "plan": plan}
    return data


def _losses(model: dict, n: int, seed: int = 1) -> np.ndarray:
    rules = [(0, FaultEntry(edge=(1, 4), bursty=model))]
    return np.array([fate(seed, rules, edge_channel(1, 4), k, 0.0, 1.0, 0.01).lost for k in range(n)])


def _runs(lost: np.ndarray) -> np.ndarray:
    """The lengths of the runs of True in ``lost``."""
    edges = np.diff(np.concatenate([[0], lost.astype(int), [0]]))
    return np.nonzero(edges == -1)[0] - np.nonzero(edges == 1)[0]


@pytest.mark.unit
@pytest.mark.parametrize(
    "model",
    [{"p": 0.05, "r": 0.25}, {"p": 0.02, "r": 0.1, "loss_bad": 0.8, "loss_good": 0.01}],
    ids=["clean bursts", "lossy good state"],
)
def test_bursty_loss_has_the_models_mean_loss(model):
    """The mean of a two-state chain's losses: variance of the mean pi (1 - pi) / n times
    (1 + lambda) / (1 - lambda), lambda = 1 - p - r its second eigenvalue (an upper bound when
    the states lose only in part); five standard deviations."""
    ge = GilbertElliott(**model)
    n = 100_000
    lost = _losses(model, n)
    lam = 1 - ge.p - ge.r
    sigma = math.sqrt(ge.mean_loss * (1 - ge.mean_loss) / n * (1 + lam) / (1 - lam))
    assert abs(lost.mean() - ge.mean_loss) < 5 * sigma, (lost.mean(), ge.mean_loss)
    assert ge.mean_loss == pytest.approx((ge.r * ge.loss_good + ge.p * ge.loss_bad) / (ge.p + ge.r))


@pytest.mark.unit
def test_clean_bursts_are_geometric_with_mean_one_over_r():
    """With loss_bad 1 and loss_good 0 a burst is a stay in the bad state: geometric, mean 1 / r,
    standard deviation sqrt(1 - r) / r; its mean over the bursts seen within five of theirs."""
    ge = GilbertElliott(p=0.05, r=0.25)
    runs = _runs(_losses({"p": 0.05, "r": 0.25}, 100_000))
    sigma = math.sqrt(1 - ge.r) / ge.r / math.sqrt(len(runs))
    assert abs(runs.mean() - ge.mean_burst) < 5 * sigma, (runs.mean(), len(runs))
    # the shape: P(length 1) = r
    assert abs((runs == 1).mean() - ge.r) < 5 * math.sqrt(ge.r * (1 - ge.r) / len(runs))


@pytest.mark.unit
def test_a_chain_is_the_same_whatever_order_it_is_asked_in_and_each_entry_and_edge_its_own():
    model = {"p": 0.1, "r": 0.3}
    first = _losses(model, 2000)
    bursts._CHAINS.clear()
    rules = [(0, FaultEntry(edge=(1, 4), bursty=model))]
    order = [1500, 3, 1999, 700, 0, 1200]
    again = [fate(1, rules, edge_channel(1, 4), k, 0.0, 1.0, 0.01).lost for k in order]
    assert again == [bool(first[k]) for k in order]
    other_edge = [fate(1, rules, edge_channel(2, 4), k, 0.0, 1.0, 0.01).lost for k in range(2000)]
    other_seed = _losses(model, 2000, seed=2)
    assert other_edge != first.tolist() and other_seed.tolist() != first.tolist()
    ge = GilbertElliott(**model)  # the states themselves, not only the losses drawn from them
    chains = [[bursts.state_at(ge, 1, 0, edge_channel(s, 4), k) for k in range(2000)] for s in (1, 2)]
    assert chains[0] != chains[1]


@pytest.mark.unit
@pytest.mark.parametrize("lockstep", [True, False], ids=["lockstep", "real time"])
def test_a_bursty_mavlink_link_moves_its_chain_one_step_per_datagram(lockstep):
    """A MAVLink link's bursty chain moves once per datagram: in lockstep, where a datagram's key
    is its sample time in ms, once per 10 ms tick, so bursts last 1/r datagrams (moved once per
    key they would last 1/(1 - (1 - r)^10), about 1.06); in real time, where the key counts the
    datagrams, once per key. Five standard deviations of the mean of geometric bursts."""
    from swarm_sitl.bus.clock import RunClock
    from swarm_sitl.faults.mavlink import MavlinkFaults
    from swarm_sitl.faults.plan import FaultPlan

    ge = GilbertElliott(p=0.05, r=0.25)
    plan = FaultPlan(seed=2, plan=[FaultEntry(mavlink=1, bursty={"p": ge.p, "r": ge.r})])
    faults = MavlinkFaults(plan, 1, RunClock(lockstep, 0.01), 1e9)
    per = 10 if lockstep else 1
    runs = _runs(np.array([faults._fate("up", per * k, k * 0.01).lost for k in range(100_000)]))
    sigma = math.sqrt(1 - ge.r) / ge.r / math.sqrt(len(runs))
    assert abs(runs.mean() - ge.mean_burst) < 5 * sigma, runs.mean()


@pytest.mark.unit
@pytest.mark.parametrize(
    "entry, message",
    [
        ({"edge": [1, 4], "bursty": {"p": 0, "r": 0.5}}, r"faults\.plan\.0\.bursty\.p: .*greater than 0"),
        ({"edge": [1, 4], "bursty": {"p": 0.1}}, r"faults\.plan\.0\.bursty\.r: missing key"),
        ({"edge": [1, 4], "bursty": {"p": 0.1, "r": 0.2, "loss_bad": 0}}, r"loses nothing"),
        ({"edge": [1, 4], "bursty": {"p": 0.1, "r": 0.2, "h": 0.5}}, r"bursty\.h: unknown key"),
        ({"partition": [[0, 1, 2, 3, 4]]}, r"two or more groups"),
        ({"partition": [[0, 1], [1, 2]]}, r"a node is in two groups"),
        ({"partition": [[0, 1], [2, 9]]}, r"faults\.plan\.0\.partition: node 9 is not 0\.\.4"),
    ],
)
def test_a_bad_link_model_is_one_line_naming_it(entry, message):
    with pytest.raises(ConfigError, match=message):
        parse_config(_paper([entry]), "paper.yaml")


@pytest.mark.unit
def test_a_partition_cuts_every_edge_between_its_groups_for_its_window():
    cfg = parse_config(_paper([{"partition": [[0, 1, 2], [3, 4]], "from_s": 5, "until_s": 6}]), "paper.yaml")
    edges = cfg.graph_edges()
    spec = cfg.faults.plan[0]
    crossing = [e for e in edges if (e[0] in (0, 1, 2)) != (e[1] in (0, 1, 2))]
    assert crossing and spec.edges(edges) == crossing and spec.drop and spec.how == "drop"
    rules = [(0, spec)]
    src, dst = crossing[0]
    cut = [k for k in range(1000) if fate(0, rules, edge_channel(src, dst), k, k * 0.01, 10.0, 0.01).lost]
    assert cut == list(range(500, 600))
    some = parse_config(_paper([{"partition": [[0], [3]], "loss": 0.5}]), "paper.yaml").faults.plan[0]
    assert some.edges(edges) == [(0, 3)] and some.loss == 0.5 and not some.drop  # node 4 in no group


@pytest.mark.unit
@given(
    st.lists(st.tuples(st.integers(0, 8), st.integers(0, 8)).filter(lambda e: e[0] != e[1]), max_size=30),
    st.lists(st.sampled_from([None, 0, 1, 2]), min_size=9, max_size=9),
)
def test_a_partition_names_the_edges_between_two_of_its_groups_whatever_nodes_it_leaves_out(edges, where):
    """Any graph, any partition of any of its nodes (the rest in no group): the edges named are
    those from one group into another, in the graph's order; an edge with an end in no group is
    not, whichever end."""
    groups = [[n for n in range(9) if where[n] == g] for g in range(3)]
    groups = [g for g in groups if g]
    assume(len(groups) >= 2)
    entry = FaultEntry(partition=groups)
    crossing = [(a, b) for a, b in edges if None not in (where[a], where[b]) and where[a] != where[b]]
    assert entry.edges(edges) == crossing


@pytest.mark.system
def test_a_lockstep_swarm_under_bursty_loss_counts_the_models_loss_and_bursts_and_repeats_itself(tmp_path):
    from swarm_sitl import Swarm

    model = {"p": 0.05, "r": 0.25}
    ge = GilbertElliott(**model)
    cfg = parse_config(_paper([]), "paper.yaml")
    plan = [{"into": f.id, "bursty": model} for f in cfg.followers]
    results = []
    for run in ("a", "b"):
        with Swarm(cfg, faults=plan, seed=11, out=tmp_path / run) as swarm:
            results.append(swarm.run(duration_s=20.0))
    edges = {k: v for k, v in results[0].links.items() if "->" in k}
    received = sum(v["received"] for v in edges.values())
    lost = sum(v["lost"] for v in edges.values())
    runs = sum(v["loss_runs"] for v in edges.values())
    lam = 1 - ge.p - ge.r
    sigma = math.sqrt(ge.mean_loss * (1 - ge.mean_loss) / received * (1 + lam) / (1 - lam))
    assert abs(lost / received - ge.mean_loss) < 5 * sigma, (lost, received)
    burst_sigma = math.sqrt(1 - ge.r) / ge.r / math.sqrt(runs)
    assert abs(lost / runs - ge.mean_burst) < 5 * burst_sigma, (lost, runs)
    assert results[0].ok and results[0].max_formation_error_m(after_s=15) < 0.05
    for name in ["summary.json", "events.jsonl", *(f"follower_{i}.npz" for i in range(1, 5))]:
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes(), name


@pytest.mark.unit
@given(
    seed=st.integers(0, 2**63 - 1),
    entry=st.integers(0, 200),
    channel=st.integers(0, 2**34),
    step=st.one_of(st.integers(0, 10**6), st.integers(0, 2**40)),
    salt=st.integers(0, 16),
)
def test_a_draw_read_from_its_table_is_the_draw_hashed_alone(seed, entry, channel, step, salt):
    """``uniform_at`` hashes a block of steps at once with numpy's uint64 arithmetic: the same
    number, bit for bit, as ``uniform`` of the same keys in Python's integers, at the block's
    edges too."""
    from swarm_sitl.faults.draws import BLOCK, uniform, uniform_at

    for s in (step, step - step % BLOCK, step - step % BLOCK + BLOCK - 1):
        assert uniform_at(seed, entry, channel, s, salt) == uniform(seed, entry, channel, s, salt)
