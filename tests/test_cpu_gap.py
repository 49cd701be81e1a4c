"""``bench --split N --empty``'s gap: what a run costs beyond the empty swarm and ``sim``, as parts
that account for all of it, over random figures."""

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from swarm_sitl.bench.cost_split import ACTIVITIES
from swarm_sitl.bench.cpu_gap import NODE_KINDS, PARTS, cpu_gap

pytestmark = pytest.mark.unit

cpu = st.floats(0.0, 10.0)


@st.composite
def measured(draw):
    """A scale row (CPU s per simulated s) and the profiled run's shares (each kind's sum to 1)."""
    # (a kind's main thread always runs: the laws' share of sim is theirs; none is NaN)
    row = {
        f"{t}_{k}": draw(st.floats(0.01, 10.0) if t == "main" else cpu)
        for k in NODE_KINDS
        for t in ("main", "other")
    }
    row.update({f"empty_{k}": draw(cpu) for k in (*NODE_KINDS, "router")})
    row["cpu_supervisor"] = draw(cpu)
    row["sim_cpu_per_sim_s"] = draw(cpu)
    shares = {}
    for k in NODE_KINDS:
        w = [draw(st.floats(0.0, 1.0)) for _ in ACTIVITIES]
        w[0] += 1e-3  # (every kind runs some of its steps)
        shares[k] = {a: x / sum(w) for a, x in zip(ACTIVITIES, w, strict=True)}
    return row, shares


@settings(max_examples=200, deadline=None)
@given(measured())
def test_the_parts_account_for_the_whole_run_and_the_gap(m):
    row, shares = m
    gap = cpu_gap(row, shares)
    total = gap["total"]
    scale = 1.0 + sum(abs(v) for v in row.values())
    tol = 1e-12 * scale * 64  # (sums of a few dozen terms, each rounded once)
    for k in NODE_KINDS:  # a kind's run is its activities and its other threads, nothing else
        parts = sum(gap[k][a] for a in ACTIVITIES) + gap[k]["other threads"]
        assert parts == pytest.approx(row[f"main_{k}"] + row[f"other_{k}"], abs=tol)
        assert gap[k]["empty"] == row[f"empty_{k}"]
    for kind in gap.values():
        assert kind["gap"] == pytest.approx(kind["run"] - kind["empty"] - kind["sim"], abs=tol)
    # sim's CPU is shared out whole, in proportion to each kind's own physics and laws
    assert total["sim"] == pytest.approx(row["sim_cpu_per_sim_s"], abs=tol)
    laws = [shares[k]["physics and laws"] * row[f"main_{k}"] for k in NODE_KINDS]
    for k, w in zip(NODE_KINDS, laws, strict=True):
        assert gap[k]["sim"] * sum(laws) == pytest.approx(row["sim_cpu_per_sim_s"] * w, abs=tol * scale)
    assert total["run"] == pytest.approx(
        sum(row[f"{t}_{k}"] for k in NODE_KINDS for t in ("main", "other")) + row["cpu_supervisor"], abs=tol
    )
    assert total["empty"] == pytest.approx(sum(row[f"empty_{k}"] for k in (*NODE_KINDS, "router")), abs=tol)
    assert total["gap"] == pytest.approx(sum(total[p] for p in PARTS), abs=tol)


@settings(max_examples=50, deadline=None)
@given(measured())
def test_a_run_that_is_its_floor_has_no_gap(m):
    """A run whose processes do exactly the empty swarm's transport and sim's work, and nothing
    else (no MAVLink, logs or loop of their own): a gap of zero in every part."""
    row, shares = m
    for k in NODE_KINDS:
        floor = {a: shares[k][a] for a in ("physics and laws", "zenoh", "waking up")}
        shares[k] = {a: floor.get(a, 0.0) / sum(floor.values()) for a in ACTIVITIES}
        moved = (shares[k]["zenoh"] + shares[k]["waking up"]) * row[f"main_{k}"] + row[f"other_{k}"]
        row[f"empty_{k}"] = moved
    row["sim_cpu_per_sim_s"] = sum(shares[k]["physics and laws"] * row[f"main_{k}"] for k in NODE_KINDS)
    row["empty_router"] = row["cpu_supervisor"]
    total = cpu_gap(row, shares)["total"]
    tol = 1e-12 * 64 * (1 + total["run"])
    assert all(math.isclose(total[p], 0.0, abs_tol=tol) for p in PARTS), total
    assert math.isclose(total["gap"], 0.0, abs_tol=tol)
