"""The swarm's figures from its followers' (``rundir.metrics.swarm_summary``): each the worst of
the followers that recorded a row, for any figures.

The lines a run fails with past its formation bound (``rundir.metrics.bound_failures``), for any
summary: one per follower not lost whose error after the settling time exceeds the bound (naming
its degraded inputs where its controller reported them), one per follower with nothing recorded
after a settling time to hold to the bound, in the followers' numeric order, none for a follower
lost, at the bound or under it; no bound, no line."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from swarm_sitl.rundir.metrics import bound_failures, describe_inputs, summarize, swarm_summary
from swarm_sitl.rundir.recording import Recording
from tests.strategies import FUZZ

pytestmark = pytest.mark.unit

BOUND_M = 2.0
reports = st.fixed_dictionaries(
    {"max_sample_age_s": st.just(0.03)},
    optional={
        "old_samples": st.integers(0, 5),
        "stale_estimates": st.integers(0, 5),
        "late_ticks": st.integers(0, 5),
    },
)


@st.composite
def summaries(draw):
    ids = draw(st.lists(st.integers(1, 12), unique=True, min_size=1, max_size=6))  # 10 < 9 as text
    followers, inputs = {}, {}
    for i in ids:
        f = {"peak_pos_err_after_settle_m": draw(st.one_of(st.none(), st.just(BOUND_M), st.floats(0, 5)))}
        recorded = draw(st.sampled_from([None, 0, 40]))
        if recorded is not None:
            f["recorded_ticks"] = recorded
        followers[str(i)] = f
        if draw(st.booleans()):
            inputs[str(i)] = draw(reports)
    lost = draw(st.lists(st.sampled_from(ids), unique=True))
    summary = {"swarm": {"settle_from_s": draw(st.sampled_from([0.0, 5.0]))}, "followers": followers}
    if inputs:
        summary["inputs"] = inputs
    if lost:
        summary["lost"] = lost
    return summary


@FUZZ
@given(summary=summaries())
def test_one_line_per_follower_past_its_bound_or_with_nothing_to_hold_to_it_in_numeric_order(summary):
    assert bound_failures(summary, None) == []
    settle = summary["swarm"]["settle_from_s"]
    expected = []
    for i in sorted(summary["followers"], key=int):
        f = summary["followers"][i]
        peak = f["peak_pos_err_after_settle_m"]
        if int(i) in summary.get("lost", []):
            continue
        if peak is None and (f.get("recorded_ticks", 0) == 0 or settle > 0):
            expected.append((i, "nothing recorded", ""))
        elif peak is not None and peak > BOUND_M:
            expected.append((i, "exceeds", describe_inputs(summary.get("inputs", {}).get(i, {}))))
    lines = bound_failures(summary, BOUND_M)
    assert len(lines) == len(expected), (lines, expected)
    for line, (i, what, why) in zip(lines, expected, strict=True):
        assert line.startswith(f"follower {i}: ") and what in line
        assert line.endswith(f"; stale inputs: {why}") if why else "stale inputs" not in line
        if what == "exceeds":
            peak = summary["followers"][i]["peak_pos_err_after_settle_m"]
            assert f"{peak:.3g} m after {settle:g} s" in line and f"= {BOUND_M:g} m" in line


@st.composite
def follower_figures(draw):
    recorded = draw(st.sampled_from([0, 40]))
    values = st.floats(0, 3)
    return {
        "recorded_ticks": recorded,
        "final_pos_err_m": draw(values),
        "peak_pos_err_after_settle_m": draw(st.one_of(st.none(), values)),
        "peak_vel_err_after_settle_mps": draw(st.one_of(st.none(), values)),
        "min_u_z_mps2": draw(st.floats(1, 12)),
        "max_thrust_N": draw(st.floats(0, 40)),
        "thrust_bound_N": draw(st.floats(10, 40)),
        "time_to_0.1m_s": draw(st.one_of(st.none(), st.floats(0, 0.9))),
        "time_to_0.01m_s": draw(st.one_of(st.none(), st.floats(0, 0.9))),
    }


def _worst(values, pick, empty):
    return pick(values) if values else empty


@FUZZ
@given(
    per=st.dictionaries(st.integers(1, 12), follower_figures(), max_size=5),
    floor=st.one_of(st.none(), st.floats(0.5, 2)),
    settle=st.sampled_from([0.0, 5.0]),
)
def test_the_swarms_figures_are_the_worst_of_its_recorded_followers(per, floor, settle):
    out = swarm_summary(per, floor, settle)
    assert out["followers"] == {str(i): f for i, f in per.items()}
    rec = [f for f in per.values() if f["recorded_ticks"] > 0]  # a follower with no row counts for nothing
    w = out["swarm"]
    assert w["final_pos_err_m"] == max([0.0] + [f["final_pos_err_m"] for f in rec])
    for key in ("peak_pos_err_after_settle_m", "peak_vel_err_after_settle_mps"):
        assert w[key] == _worst([f[key] for f in rec if f[key] is not None], max, None)
    assert w["max_thrust_over_bound"] == _worst(
        [f["max_thrust_N"] / f["thrust_bound_N"] for f in rec], max, -np.inf
    )
    for key in ("time_to_0.1m_s", "time_to_0.01m_s"):  # None once any follower never got there
        times = [f[key] for f in rec]
        assert w[key] == (None if None in times else max([0.0, *times]))
    assert w["settle_from_s"] == settle
    if floor is None:  # another law's: the paper's invariants are not its
        assert "min_u_z_mps2" not in w and "u_z_floor_mps2" not in w
    else:
        assert w["u_z_floor_mps2"] == floor
        assert w["min_u_z_mps2"] == _worst([f["min_u_z_mps2"] for f in rec], min, np.inf)


@FUZZ
@given(
    seed=st.integers(0, 2**32 - 1),
    paper=st.booleans(),
    max_thrust_N=st.floats(5, 60),
    mass_kg=st.floats(0.5, 3),
)
def test_each_followers_thrust_is_held_to_its_laws_bound(seed, paper, max_thrust_N, mass_kg):
    """The paper's law to its own bound (section 3.3: m (g + 2 sqrt(3) k_eta + sqrt(3) k_gamma)),
    another law to the vehicle's most thrust; the most thrust of the rows recorded."""
    rng = np.random.default_rng(seed)
    n, g = 30, 9.81
    gains = {"k_eta": float(rng.uniform(0.1, 2)), "k_gamma": float(rng.uniform(0.1, 2))} if paper else None
    followers = {}
    for i in (1, 2):
        t = np.where(rng.random(n) < 0.2, np.nan, np.arange(n) * 0.01)  # rows not recorded: left out
        followers[i] = {
            "t_s": t,
            "pos_err_m": rng.normal(size=(n, 3)),
            "vel_err_mps": rng.normal(size=(n, 3)),
            "thrust_N": rng.uniform(0, 50, n),
            "u": rng.normal(5, 1, (n, 3)),
        }
    rec = Recording({"t_s": np.arange(n) * 0.01}, followers, {1: np.zeros(3), 2: np.zeros(3)})
    out = summarize(rec, gains, {1: mass_kg, 2: mass_kg}, g, 0.1, max_thrust_N)
    for i, a in followers.items():
        f = out["followers"][str(i)]
        ok = np.isfinite(a["t_s"])
        if not ok.any():
            continue
        bound = (
            mass_kg * (g + 2 * np.sqrt(3) * gains["k_eta"] + np.sqrt(3) * gains["k_gamma"])
            if gains
            else max_thrust_N
        )
        assert f["thrust_bound_N"] == pytest.approx(bound, rel=1e-12)
        assert f["max_thrust_N"] == a["thrust_N"][ok].max()
