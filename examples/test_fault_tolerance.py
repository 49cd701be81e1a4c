"""Fault-injection tests as a user of swarm-sitl writes them (the project's CI runs this file too).

Each test runs the paper's swarm as real processes (one simulated vehicle and one controller per
follower, the leader, zenoh between them) in lockstep, with a fault plan, through the ``swarm``
fixture that ``pip install swarm-sitl`` adds to pytest. Lockstep runs are deterministic: the same
plan and seed give the same run.
"""

from pathlib import Path

import pytest

PAPER = Path(__file__).resolve().parents[1] / "configs" / "paper.yaml"

#: its system tests run in lockstep or ``sim`` only (no wall clock): free to run beside others
pytestmark = [pytest.mark.system, pytest.mark.lockstep]


def test_formation_holds_with_half_of_an_edge_lost(swarm):
    """ "If the edge 1 -> 4 drops half its messages, does the formation still hold within 5 cm?" """
    r = swarm(PAPER, duration_s=30, faults=[{"edge": [1, 4], "loss": 0.5}], seed=3)
    assert r.ok, r.failure
    assert 0.4 < r.links["1->4"]["lost"] / r.links["1->4"]["received"] < 0.6
    assert r.max_formation_error_m(after_s=20) < 0.05


def test_a_cut_edge_costs_formation_and_the_swarm_recovers(swarm):
    """The leader's edge to follower 1 is cut for 10 s: followers 1 and 4 (which hears 1) drift,
    and come back within 15 s of the edge's return; followers 2 and 3 never notice."""
    r = swarm(PAPER, duration_s=50, faults=[{"edge": [0, 1], "drop": True, "from_s": 20, "until_s": 30}])
    assert r.ok, r.failure
    f = r.followers
    assert f[1].max_formation_error_m(20, 30) > 0.1
    assert f[4].max_formation_error_m(20, 30) > 0.05
    assert max(f[i].max_formation_error_m(after_s=30 + 15) for i in (1, 4)) < 0.05  # over 45..50 s
    assert max(f[i].max_formation_error_m(after_s=20) for i in (2, 3)) < 0.01
    lost = r.events_of("neighbour_lost")
    assert [(e["follower"], e["neighbour"]) for e in lost] == [(1, 0)]
    assert 20 < lost[0]["t_s"] <= 20 + 0.5 + 0.011  # once its last estimate is past staleness


def test_a_killed_controller_is_restarted_and_flies_back_into_formation(swarm):
    """Controller 2 is killed at 20 s and started again at 22 s: its vehicle holds on its own in
    between (failsafe), and follower 2 is back in formation well within 20 s of the restart."""
    r = swarm(
        PAPER, duration_s=45, faults=[{"controller": 2, "kill": True, "from_s": 20, "restart_after_s": 2}]
    )
    assert r.ok, r.failure
    fs = [
        (e["kind"], e["t_s"]) for e in r.events if e.get("vehicle") == 2 and e["kind"].startswith("failsafe")
    ]
    assert fs == [("failsafe_enter", 20.5), ("failsafe_exit", 22.0)]  # 0.5 s: its setpoint timeout
    assert [e["kind"] for e in r.events if e.get("process") == "controller_2"] == [
        "process_killed",
        "process_restarted",
    ]
    assert r.followers[2].max_formation_error_m(after_s=22 + 20) < 0.05
    assert r.followers[2].max_formation_error_m(after_s=30) < 0.05  # in fact within 8 s
    assert max(r.followers[i].max_formation_error_m(after_s=20) for i in (1, 3)) < 0.01


def test_a_lost_aircraft_is_recorded_and_the_rest_fly_on(swarm):
    """Vehicle 1 is lost at 20 s, and its controller with it: follower 4 still hears follower 2."""
    r = swarm(PAPER, duration_s=35, faults=[{"vehicle": 1, "kill": True, "from_s": 20}])
    assert r.ok, r.failure
    assert r.summary["lost"] == [1] and r.events_of("vehicle_lost")[0]["t_s"] == 20.0
    assert r.max_formation_error_m(after_s=20, followers=[2, 3, 4]) < 0.05
    assert r.followers[1].max_formation_error_m(after_s=20) != r.followers[1].max_formation_error_m(
        after_s=20
    )  # NaN: none recorded
