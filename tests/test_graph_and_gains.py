"""Graph, M, Lemma 2.1, and Theorem 1's conditions."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from swarm_sitl.laws.gain_conditions import check_gains
from swarm_sitl.laws.graph import Graph, GraphError
from swarm_sitl.laws.trajectories import Helix

pytestmark = pytest.mark.unit
PAPER_GAINS = dict(k_p=8.0, k_v=8.0, l_a=12.0, k_a=4.0, k_eta=4.0, k_gamma=0.5)
HELIX = Helix(5.0, 0.2, 1.0)


def test_M_of_the_paper_tree():
    g = Graph.from_edges(4, [(0, 1), (0, 2), (0, 3), (1, 4), (2, 4)])
    expected = np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [-1, -1, 0, 2]], dtype=float)
    np.testing.assert_array_equal(g.M(), expected)
    assert g.in_neighbours(4) == ((1, 1.0), (2, 1.0))


def test_missing_spanning_tree_names_the_unreachable_followers():
    with pytest.raises(GraphError, match=r"cannot reach follower\(s\) 3, 4"):
        Graph.from_edges(4, [(0, 1), (1, 2), (3, 4), (4, 3)])


@pytest.mark.parametrize(
    "edges, msg",
    [
        ([(0, 5)], "not 0..4"),
        ([(1, 1)], "self loop"),
        ([(1, 0)], "takes no input"),
        ([(0, 1), (0, 1)], "twice"),
        ([(0, 1, -1.0)], "weight"),
    ],
)
def test_bad_edges(edges, msg):
    with pytest.raises(GraphError, match=msg):
        Graph.from_edges(4, edges)


@st.composite
def spanning_graphs(draw, weights=(1.0,)):
    n = draw(st.integers(1, 7))
    edges = []
    for i in range(1, n + 1):  # a random spanning tree: each follower has a parent among earlier nodes
        edges.append((draw(st.integers(0, i - 1)), i, draw(st.sampled_from(weights))))
    extra = draw(st.lists(st.tuples(st.integers(1, n), st.integers(1, n)), max_size=2 * n))
    seen = {(s, d) for s, d, _ in edges}
    for s, d in extra:
        if s != d and (s, d) not in seen:
            seen.add((s, d))
            edges.append((s, d, 1.0))
    return Graph.from_edges(n, edges)


@given(spanning_graphs(weights=(1.0, 0.5, 2.0)))
def test_theta_makes_xi_positive_definite_on_every_spanning_graph(g):
    M, Th, Xi = g.M(), g.theta(), g.xi()
    assert np.all(np.real(np.linalg.eigvals(M)) > 0)  # non-singular M-matrix
    assert np.all(np.diag(Th) > 0) and np.count_nonzero(Th - np.diag(np.diag(Th))) == 0
    assert np.linalg.eigvalsh(Xi).min() > 0
    Tq = g.theta_qu()  # Qu's construction alone always works
    assert np.linalg.eigvalsh(M.T @ Tq + Tq @ M).min() > 0


def test_lemma_2_1_as_printed_can_leave_xi_indefinite():
    """Found by hypothesis: with [1/theta_i] = M^-1 1, Xi is indefinite on this weighted tree, and
    not diagonally dominant on the unit-weight ring. `check` then uses Qu's Theta and says so."""
    g = Graph.from_edges(6, [(0, 1, 1), (0, 2, 0.5), (0, 3, 1), (0, 4, 1), (2, 5, 1), (2, 6, 2)])
    Tp = g.theta_paper()
    assert np.linalg.eigvalsh(g.M().T @ Tp + Tp @ g.M()).min() < 0
    assert g.theta_source().startswith("Qu")
    tree = Graph.from_edges(4, [(0, 1), (0, 2), (0, 3), (1, 4), (2, 4)])
    assert tree.theta_source().startswith("paper")
    np.testing.assert_allclose(tree.theta(), np.diag([1, 1, 1, 2 / 3]))  # q = M^-1 1 = [1, 1, 1, 3/2]


def test_paper_gains_pass_on_the_tree_and_fail_on_the_ring():
    tree = Graph.from_edges(4, [(0, 1), (0, 2), (0, 3), (1, 4), (2, 4)])
    ring = Graph.from_edges(4, [(0, 1), (1, 2), (2, 3), (3, 4), (4, 1)])
    assert check_gains(tree, PAPER_GAINS, HELIX, 9.81, 100).all_hold
    r = check_gains(ring, PAPER_GAINS, HELIX, 9.81, 100)
    failing = {c.name.split()[0] for c in r.conditions if not c.holds}
    assert failing == {"l_a", "k_a"}
    assert check_gains(ring, {**PAPER_GAINS, **r.suggestion}, HELIX, 9.81, 100).all_hold


def test_l_a_bound_is_where_omega_stops_being_positive_definite():
    """docs/paper.md, erratum 5: with +l_a lmin(M^T Theta M) in Omega(3,3), Sylvester gives the
    printed bound."""
    ring = Graph.from_edges(4, [(0, 1), (1, 2), (2, 3), (3, 4), (4, 1)])
    r = check_gains(ring, PAPER_GAINS, HELIX, 9.81, 100)
    la = r.conditions[1].bound
    c = r.norm_theta

    def omega(l_a):
        return np.array(
            [[8 * r.lambda_min_xi, -c, 0], [-c, 8 * r.lambda_min_xi, -c], [0, -c, l_a * r.lambda_min_mtm]]
        )

    assert np.linalg.eigvalsh(omega(la * 1.001)).min() > 0
    assert np.linalg.eigvalsh(omega(la * 0.999)).min() < 0
    assert abs(np.linalg.det(omega(la))) < 1e-9


def test_theorem_1_bounds_on_a_two_follower_chain_worked_by_hand():
    """Leader -> 1 -> 2, unit weights, the paper's gains and helix, every number worked out by hand:

    M = L + diag(d_0) = [[1, 0], [-1, 1]];  M^-1 1 = [1, 2], so Theta = diag(1, 1/2) (Lemma 2.1).
    Xi = M^T Theta + Theta M = [[1, -1/2], [0, 1/2]] + [[1, 0], [-1/2, 1/2]] = [[2, -1/2], [-1/2, 1]]:
      eigenvalues (3 -+ sqrt(2)) / 2, lambda_min = (3 - sqrt 2)/2.
    M^T Theta M = [[3/2, -1/2], [-1/2, 1/2]]: eigenvalues 1 -+ sqrt(2)/2, lambda_min = 1 - sqrt(2)/2.
    ||.|| is the paper's F-norm (its notation section): ||Theta|| = sqrt(1 + 1/4) = sqrt(5)/2, and
      Theta M = [[1, 0], [-1/2, 1/2]] gives ||Theta M|| = sqrt(1 + 1/4 + 1/4) = sqrt(3/2).
    Helix R = 5, w = 0.2, l_a = 12: sup|N_p| = R w^3 sqrt(l_a^2 + w^2) = 0.04 sqrt(144.04);
      sup|pddot_r| = R w^2 = 0.2.
    Bounds: k_p k_v > ||Theta||^2 / lmin(Xi)^2;  l_a > k_p lmin(Xi) ||Theta||^2 / (lmin(MTM) (k_p k_v
    lmin(Xi)^2 - ||Theta||^2));  k_a > 2 sqrt(n) ||Theta M|| sup|N_p| / lmin(Xi);  k_eta < (g - k_gamma)/2.
    """
    lx = (3 - np.sqrt(2)) / 2
    lm = 1 - np.sqrt(2) / 2
    nt2 = 5 / 4  # ||Theta||^2
    ntm = np.sqrt(3 / 2)
    np_bar = 0.04 * np.sqrt(144.04)
    k_p = k_v = PAPER_GAINS["k_p"]
    expected = [
        nt2 / lx**2,
        k_p * lx * nt2 / (lm * (k_p * k_v * lx**2 - nt2)),
        2 * np.sqrt(2) * ntm * np_bar / lx,
        (9.81 - PAPER_GAINS["k_gamma"]) / 2,
        0.2,
    ]
    chain = Graph.from_edges(2, [(0, 1), (1, 2)])
    r = check_gains(chain, PAPER_GAINS, HELIX, 9.81, 100)
    assert r.lambda_min_xi == pytest.approx(lx, rel=1e-12) and r.lambda_min_mtm == pytest.approx(
        lm, rel=1e-12
    )
    assert r.norm_theta == pytest.approx(np.sqrt(nt2), rel=1e-12) and r.norm_theta_m == pytest.approx(
        ntm, rel=1e-12
    )
    assert r.sup_Np == pytest.approx(np_bar, rel=1e-12) and r.sup_acc == pytest.approx(0.2, rel=1e-12)
    for cond, bound in zip(r.conditions, expected, strict=True):
        assert cond.bound == pytest.approx(bound, rel=1e-9), cond.name


def test_out_neighbours_edges_as_objects_and_zero_weights():
    from swarm_sitl.laws.graph import Edge

    g = Graph.from_edges(4, [(0, 1), (0, 2), Edge(1, 3, 2.5), (2, 3), (3, 4), (1, 4)])
    assert [g.out_neighbours(i) for i in range(5)] == [(1, 2), (3, 4), (3,), (4,), ()]
    assert g.in_neighbours(3) == ((1, 2.5), (2, 1.0))
    with pytest.raises(GraphError, match="weight"):
        Graph.from_edges(2, [(0, 1), (1, 2, 0.0)])


def test_an_unreachable_first_follower_is_named():
    with pytest.raises(GraphError, match=r"cannot reach follower\(s\) 1$"):
        Graph.from_edges(3, [(0, 2), (1, 3), (2, 3)])


def test_qus_theta_is_p_over_q_and_the_report_says_whose_theta_it_uses():
    """Qu (2009): theta_i = p_i / q_i with p = M^-T 1, q = M^-1 1; on the weighted tree where the
    paper's Theta fails (above), check reports Qu's, and the report's Xi is M^T Theta + Theta M."""
    g = Graph.from_edges(6, [(0, 1, 1), (0, 2, 0.5), (0, 3, 1), (0, 4, 1), (2, 5, 1), (2, 6, 2)])
    M = g.M()
    p, q = np.linalg.solve(M.T, np.ones(6)), np.linalg.solve(M, np.ones(6))
    np.testing.assert_allclose(g.theta(), np.diag(p / q), rtol=1e-12)
    r = check_gains(g, PAPER_GAINS, HELIX, 9.81, 100)
    np.testing.assert_allclose(r.theta, np.diag(p / q), rtol=1e-12)
    np.testing.assert_allclose(r.xi, M.T @ r.theta + r.theta @ M, rtol=1e-12)
    assert r.theta_source == g.theta_source() and "(M^-T 1)/(M^-1 1)" in r.theta_source
    tree = Graph.from_edges(4, [(0, 1), (0, 2), (0, 3), (1, 4), (2, 4)])
    assert check_gains(tree, PAPER_GAINS, HELIX, 9.81, 100).theta_source == "paper: 1/theta = M^-1 1"


def test_conditions_are_named_as_the_paper_writes_them_and_compare_strictly():
    from swarm_sitl.laws.gain_conditions import Condition

    tree = Graph.from_edges(4, [(0, 1), (0, 2), (0, 3), (1, 4), (2, 4)])
    names = [c.name for c in check_gains(tree, PAPER_GAINS, HELIX, 9.81, 100).conditions]
    assert names == [
        "k_p k_v > ||Theta||^2 / lambda_min(Xi)^2",
        "l_a > k_p lmin(Xi) ||Theta||^2 / (lmin(M^T Theta M)(k_p k_v lmin(Xi)^2 - ||Theta||^2))",
        "k_a > 2 sqrt(n) ||Theta M|| sup|N_p| / lambda_min(Xi)",
        "k_eta < (g - k_gamma) / 2",
        "k_gamma >= sup |pddot_r|",
    ]
    assert [Condition("c", rel, 1.0, 1.0).holds for rel in (">", ">=", "<")] == [False, True, False]
    assert not Condition("c", ">", float("inf"), 1e300).holds
    with pytest.raises(ValueError, match="unknown relation"):
        _ = Condition("c", "<=", 1.0, 0.0).holds


def _la_bound(r, k):
    """The printed l_a bound at k_p = k_v = k (written again from the paper)."""
    den = r.lambda_min_mtm * (k * k * r.lambda_min_xi**2 - r.norm_theta**2)
    return k * r.lambda_min_xi * r.norm_theta**2 / den if den > 0 else np.inf


def _ka_bound(r, n, l_a):
    from swarm_sitl.laws.trajectories import sup_Np

    return 2 * np.sqrt(n) * r.norm_theta_m * sup_Np(HELIX, l_a, 100) / r.lambda_min_xi


def test_the_suggestion_keeps_what_holds_and_puts_what_fails_a_quarter_past_its_bound():
    tree = Graph.from_edges(4, [(0, 1), (0, 2), (0, 3), (1, 4), (2, 4)])
    gains = {**PAPER_GAINS, "k_gamma": 0.1, "k_eta": 5.0}  # k_gamma < sup|pddot_r| = 0.2, k_eta too big
    r = check_gains(tree, gains, HELIX, 9.81, 100)
    assert {c.name.split()[0] for c in r.conditions if not c.holds} == {"k_eta", "k_gamma"}
    s = r.suggestion
    assert s["k_gamma"] == pytest.approx(1.25 * 0.2, rel=1e-12)
    assert s["k_eta"] == pytest.approx(0.8 * (9.81 - 1.25 * 0.2) / 2, rel=1e-12)
    assert {k: s[k] for k in ("k_p", "k_v", "l_a", "k_a")} == {
        k: gains[k] for k in ("k_p", "k_v", "l_a", "k_a")
    }
    assert check_gains(tree, {**gains, **s}, HELIX, 9.81, 100).all_hold
    ok = check_gains(tree, PAPER_GAINS, HELIX, 9.81, 100).suggestion  # everything holds: nothing moves
    assert ok == {k: PAPER_GAINS[k] for k in ok}


@pytest.mark.parametrize(
    "edges, gains",
    [
        ([(0, 1), (1, 2), (2, 3), (3, 4), (4, 1)], PAPER_GAINS),  # ring: l_a and k_a fail
        ([(0, 1), (1, 2), (2, 3), (3, 4), (4, 1)], {**PAPER_GAINS, "k_p": 0.5, "k_v": 0.5}),  # k_p k_v too
        ([(0, 1), (0, 2), (1, 3), (2, 3), (3, 4)], {**PAPER_GAINS, "l_a": 0.05, "k_a": 0.5}),
        # k_p k_v = 1 fails, l_a = 12 holds from the grid's first point on: that point wins
        ([(0, 1), (0, 2), (0, 3), (1, 4), (2, 4)], {**PAPER_GAINS, "k_p": 1.0, "k_v": 1.0}),
    ],
)
def test_the_suggestion_is_the_smallest_k_a_on_its_documented_grid(edges, gains):
    """The search (gain_conditions.py): k_p = k_v = k over sqrt(k_p k_v) if its condition holds, and
    k0 2^j, j = 0..7, k0 = max(sqrt(k_p k_v), 1.25 ||Theta|| / lmin(Xi)); at each k, l_a kept if it
    holds, else 1.25 x its bound; k_a likewise against its bound at that l_a; the k of least k_a wins."""
    g = Graph.from_edges(4, edges)
    r = check_gains(g, gains, HELIX, 9.81, 100)
    assert not r.all_hold
    s = r.suggestion
    assert check_gains(g, {**gains, **s}, HELIX, 9.81, 100).all_hold
    k_now = np.sqrt(gains["k_p"] * gains["k_v"])
    ks = [k_now] if gains["k_p"] * gains["k_v"] > r.norm_theta**2 / r.lambda_min_xi**2 else []
    ks += list(max(k_now, 1.25 * r.norm_theta / r.lambda_min_xi) * 2.0 ** np.arange(8))
    las = [gains["l_a"] if gains["l_a"] > _la_bound(r, k) else 1.25 * _la_bound(r, k) for k in ks]
    kas = [gains["k_a"] if gains["k_a"] > (b := _ka_bound(r, 4, la)) else 1.25 * b for la in las]
    j = int(np.argmin(kas))
    assert s["k_a"] == pytest.approx(kas[j], rel=1e-3)  # the search samples sup|N_p| more coarsely
    assert s["l_a"] == pytest.approx(las[j], rel=1e-12)
    kept = ks[j] == k_now and gains["k_p"] * gains["k_v"] > r.norm_theta**2 / r.lambda_min_xi**2
    expected = (gains["k_p"], gains["k_v"]) if kept else (ks[j], ks[j])
    assert (s["k_p"], s["k_v"]) == pytest.approx(expected, rel=1e-12)


def test_a_line_leader_needs_no_acceleration_bound_and_its_k_a_bound_is_zero():
    from swarm_sitl.laws.trajectories import Line

    tree = Graph.from_edges(4, [(0, 1), (0, 2), (0, 3), (1, 4), (2, 4)])
    r = check_gains(tree, PAPER_GAINS, Line((0.0, 0.0, 0.0), (1.0, 2.0, 0.5)), 9.81, 100)
    assert r.sup_acc == 0.0 and r.sup_Np == 0.0 and r.conditions[2].bound == 0.0
    assert r.all_hold and r.suggestion == {k: PAPER_GAINS[k] for k in r.suggestion}


def test_the_l_a_bound_is_infinite_while_k_p_k_v_fails():
    """Below ||Theta||^2 / lmin(Xi)^2 the l_a bound's denominator is negative: no l_a is enough."""
    ring = Graph.from_edges(4, [(0, 1), (1, 2), (2, 3), (3, 4), (4, 1)])
    r = check_gains(ring, {**PAPER_GAINS, "k_p": 0.5, "k_v": 0.5, "l_a": 1e9}, HELIX, 9.81, 100)
    assert not r.conditions[0].holds
    assert r.conditions[1].bound == np.inf and not r.conditions[1].holds


@pytest.mark.parametrize("k_p, k_v, l_a", [(1.0, 4.0, 12.0), (0.5, 4.0, 100.0)])
def test_the_suggestion_keeps_unequal_k_p_and_k_v_when_they_already_hold(k_p, k_v, l_a):
    """On the tree ||Theta||^2 / lmin(Xi)^2 = 1.94: k_p k_v = 4, or 2 (just above), holds, and so
    does l_a; only k_a (3 < its bound) fails. The suggestion raises k_a alone."""
    tree = Graph.from_edges(4, [(0, 1), (0, 2), (0, 3), (1, 4), (2, 4)])
    gains = {**PAPER_GAINS, "k_p": k_p, "k_v": k_v, "l_a": l_a, "k_a": 3.0}
    r = check_gains(tree, gains, HELIX, 9.81, 100)
    assert [c.holds for c in r.conditions] == [True, True, False, True, True]
    s = r.suggestion
    assert (s["k_p"], s["k_v"], s["l_a"]) == (k_p, k_v, l_a)
    assert s["k_a"] == pytest.approx(1.25 * r.conditions[2].bound, rel=1e-3)


@given(spanning_graphs(), st.data())
def test_hops_from_a_node_are_the_fewest_edges_to_each_node_it_reaches(g, data):
    """Against a relaxation over the edge list (Bellman-Ford with unit lengths): each node a path
    reaches has its fewest edges, the node itself 0, and nothing else is listed."""
    start = data.draw(st.integers(0, g.n_followers))
    dist = {start: 0}
    for _ in range(g.n_followers + 1):
        for e in g.edges:
            if e.src in dist and dist[e.src] + 1 < dist.get(e.dst, g.n_followers + 2):
                dist[e.dst] = dist[e.src] + 1
    assert g.hops_from(start) == dist


@pytest.mark.parametrize(
    "edges", [[(0, 1), (0, 2), (0, 3), (1, 4), (2, 4)], [(0, 1), (1, 2), (2, 3), (3, 4), (4, 1)]]
)
@pytest.mark.parametrize("bracket", ["sliding_surface", "printed"])
def test_the_check_report_says_each_conditions_bound_value_and_verdict_as_computed(edges, bracket):
    """``swarm-sitl check``'s text read back: Xi row by row, each condition's bound and value (to
    the digits printed) and its verdict, the failing count and the suggested gains where some
    fail, "all conditions hold." where none does, and a warning where the config flies a bracket
    Theorem 1 does not cover."""
    import re

    from swarm_sitl.laws.gain_report import COVERED_BRACKET, render

    report = check_gains(Graph.from_edges(4, edges), PAPER_GAINS, HELIX, 9.81, 100)
    text = render(report, "mine", bracket)
    lines = text.splitlines()
    assert lines[0].startswith("config mine: Theorem 1")
    start = lines.index("  Xi = M^T Theta + Theta M =") + 1
    xi = np.array([[float(x) for x in line.split()] for line in lines[start : start + len(report.xi)]])
    np.testing.assert_allclose(xi, report.xi, atol=5e-5)  # (printed to 4 decimals)
    header = next(
        j for j, line in enumerate(lines) if line.split()[:4] == ["condition", "bound", "value", "verdict"]
    )
    rows = lines[header + 1 : header + 1 + len(report.conditions)]
    assert lines[header - 1] == "" and lines[header + 1 + len(report.conditions)] == ""  # a block apart
    theta = re.fullmatch(r"  Theta = diag\((.*)\)   \((.*)\)", lines[start - 2])
    assert theta is not None and theta.group(2) == report.theta_source, lines[start - 2]
    diag = [float(x) for x in theta.group(1).split(", ")]
    np.testing.assert_allclose(diag, np.diag(report.theta), rtol=5e-4)  # (4 significant digits)
    assert (
        f"  sup|pddot_r| = {report.sup_acc:.4g} m/s^2, sup|N_p| = {report.sup_Np:.4g} m/s^3 "
        "(N_p = -l_a p_r^(3) - p_r^(4), as derived)"
    ) in lines
    for c, row in zip(report.conditions, rows, strict=True):
        m = re.fullmatch(rf"  {re.escape(c.name)} +(\S+) +(\S+)  (ok|FAILS)", row)
        assert m is not None, row
        assert float(m.group(1)) == pytest.approx(c.bound, rel=5e-4, abs=1e-300)  # (4 significant digits)
        assert float(m.group(2)) == pytest.approx(c.value, rel=5e-4, abs=1e-300)
        assert (m.group(3) == "ok") == c.holds
    failing = [c for c in report.conditions if not c.holds]
    if failing:
        assert f"WARNING: {len(failing)} condition(s) fail" in text and "all conditions hold." not in text
        said = re.search(r"suggested gains that satisfy all conditions: (.*)", text).group(1)
        assert {kv.split("=")[0] for kv in said.split(", ")} == set(report.suggestion)
    else:
        assert "all conditions hold." in lines
    assert (f"WARNING: estimator.bracket is {bracket}" in text) == (bracket != COVERED_BRACKET)
    warnings = sum(line.startswith("WARNING: ") for line in lines)
    assert warnings == bool(failing) + (bracket != COVERED_BRACKET)


@pytest.mark.parametrize("value", [0.0, -1.0, float("inf"), float("nan")])
def test_a_gain_that_is_not_positive_and_finite_is_refused_at_load_naming_it(tmp_path, value):
    """Every gain of the paper's law, in a config file: zero, negative, infinite or not a number
    is one line naming ``gains.NAME`` at load (an infinite gain flew, and failed at the first tick)."""
    import yaml

    from swarm_sitl.config.load import ConfigError, load_config
    from swarm_sitl.laws.paper_gains import PaperGains
    from tests.support import config_data

    for name in PaperGains.model_fields:
        data = config_data("paper")
        data["gains"][name] = value
        path = tmp_path / f"{name}.yaml"
        path.write_text(yaml.safe_dump(data))
        with pytest.raises(ConfigError) as e:
            load_config(path)
        said = str(e.value)
        assert said.startswith(f"{path}: gains.{name}: ") and "\n" not in said, said
