"""The summary's figures of a follower (``rundir.metrics``, ``rundir.settling``): against their
definitions computed here row by row, and the same however the rows are cut into blocks (a run
streamed to disk gives them block by block: ``sim``'s flat memory)."""

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from swarm_sitl.rundir.metrics import follower_figures, summarize
from swarm_sitl.rundir.recording import Recording
from swarm_sitl.rundir.settling import Settling, time_to_converge

pytestmark = pytest.mark.unit

GAINS = {"k_eta": 0.5, "k_gamma": 1.0}


def _settles_at(t, err, tol):
    """The definition: the first time t_j from which every error is within ``tol`` to the end."""
    for j in range(len(t)):
        if all(e <= tol for e in err[j:]):
            return float(t[j])
    return None


def _cuts(rng, n):
    """Random places to cut ``n`` rows into blocks (empty blocks among them)."""
    return sorted(rng.integers(0, n + 1, size=rng.integers(0, 6)).tolist())


@settings(max_examples=300, deadline=None)
@given(st.lists(st.sampled_from([0.0, 0.05, 0.1, 0.2, math.nan]), max_size=30), st.integers(0, 2**32 - 1))
def test_settling_is_its_definition_whole_or_in_blocks(errors, seed):
    err = np.array(errors, dtype=float)
    t = np.arange(len(err)) * 0.01
    expected = _settles_at(t, err, 0.1)  # (a NaN is not within the tolerance)
    assert time_to_converge(t, err, 0.1) == expected
    s = Settling(0.1)
    edges = [0, *_cuts(np.random.default_rng(seed), len(err)), len(err)]
    for a, b in itertools.pairwise(edges):
        s.add(t[a:b], err[a:b])
    assert s.result() == expected


def _rows(rng, n, est: bool):
    rows = {
        "t_s": np.arange(n) * 0.01 + rng.choice([0.0, 0.003]),
        "pos_err_m": rng.normal(0, 0.1, (n, 3)) * rng.exponential(1.0, (n, 1)),
        "vel_err_mps": rng.normal(0, 0.1, (n, 3)),
        "u": rng.normal(9.0, 1.0, (n, 3)),
        "thrust_N": rng.uniform(5.0, 20.0, n),
    }
    if est:
        rows["est_pos_err_m"] = rng.normal(0, 0.01, (n, 3))
    skipped = rng.random(n) < 0.2  # ticks not recorded: NaN rows
    rows["t_s"][skipped & (rng.random(n) < 0.5)] = np.nan
    rows["pos_err_m"][skipped] = np.nan
    return rows


@settings(max_examples=100, deadline=None)
@given(st.integers(0, 400), st.booleans(), st.booleans(), st.integers(0, 2**32 - 1))
def test_a_followers_figures_are_their_definitions_and_the_same_in_blocks(n, est, paper, seed):
    rng = np.random.default_rng(seed)
    rows = _rows(rng, n, est)
    settle = float(rng.uniform(0.0, n * 0.01 + 0.5))
    make = lambda: follower_figures(GAINS if paper else None, 1.5, 9.81, settle, 30.0)  # noqa: E731
    whole = make().add(rows).result()
    blocks = make()
    edges = [0, *_cuts(rng, n), n]
    for a, b in itertools.pairwise(edges):
        blocks.add({k: v[a:b] for k, v in rows.items()})
    assert blocks.result() == whole
    ok = [j for j in range(n) if np.isfinite(rows["t_s"][j]) and np.all(np.isfinite(rows["pos_err_m"][j]))]
    assert whole["recorded_ticks"] == len(ok)
    if not ok:
        assert whole == {"recorded_ticks": 0}
        return
    pe = [math.sqrt(sum(c * c for c in rows["pos_err_m"][j])) for j in ok]
    t = [float(rows["t_s"][j]) for j in ok]
    ulps = {"rel": 1e-15}  # (a norm summed in another order: a few ulps apart)
    assert whole["final_pos_err_m"] == pytest.approx(pe[-1], **ulps)
    assert whole["peak_pos_err_m"] == pytest.approx(max(pe), **ulps)
    late = [e for e, tj in zip(pe, t, strict=True) if tj >= settle]
    assert whole["peak_pos_err_after_settle_m"] == (pytest.approx(max(late), **ulps) if late else None)
    assert whole["time_to_0.1m_s"] == _settles_at(t, pe, 0.1)
    assert whole["max_thrust_N"] == max(rows["thrust_N"][j] for j in ok)
    assert ("min_u_z_mps2" in whole) == paper and ("final_est_pos_err_m" in whole) == est
    if paper:
        assert whole["min_u_z_mps2"] == min(rows["u"][j][2] for j in ok)
        assert whole["thrust_bound_N"] == pytest.approx(1.5 * (9.81 + 2 * math.sqrt(3) * 0.5 + math.sqrt(3)))


@settings(max_examples=50, deadline=None)
@given(st.integers(1, 5), st.integers(0, 2**32 - 1))
def test_the_swarms_figures_are_the_worst_of_its_followers(n_followers, seed):
    rng = np.random.default_rng(seed)
    followers = {i: _rows(rng, int(rng.integers(0, 200)), False) for i in range(1, n_followers + 1)}
    rec = Recording({}, followers, {}, [])
    s = summarize(rec, GAINS, dict.fromkeys(followers, 1.5), 9.81, 0.5, 30.0)
    flown = [f for f in s["followers"].values() if f["recorded_ticks"]]
    assert s["swarm"]["final_pos_err_m"] == max([0.0] + [f["final_pos_err_m"] for f in flown])
    lates = [f["peak_pos_err_after_settle_m"] for f in flown if f["peak_pos_err_after_settle_m"] is not None]
    assert s["swarm"]["peak_pos_err_after_settle_m"] == (max(lates) if lates else None)
    assert s["swarm"]["min_u_z_mps2"] == min([math.inf] + [f["min_u_z_mps2"] for f in flown])
    times = [f["time_to_0.1m_s"] for f in flown]
    assert s["swarm"]["time_to_0.1m_s"] == (None if None in times else max([0.0, *times]))
