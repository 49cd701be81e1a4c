"""A run of processes' summary is what its processes left in ``procs/`` (``rundir.outputs``'
``write_outputs(..., processes=True)``): every process's events merged in time order with the
plan's into ``events.jsonl``, the vehicles lost, each vehicle's refusals, each controller's report
and links summed over its incarnations, the plan as flown and the restarts judged. The files are
written here as the processes write them (``rundir.layout``'s paths), the rows are ``sim``'s."""

import json

import pytest
import yaml

from swarm_sitl.config.load import parse_config
from swarm_sitl.rundir.events import read_events
from swarm_sitl.rundir.layout import (
    controller_events_path,
    controller_rows_path,
    controller_stats_path,
    lost_events_path,
    procs_dir,
    supervisor_events_path,
    vehicle_events_path,
    vehicle_stats_path,
)
from swarm_sitl.rundir.merge import VEHICLE_REFUSALS
from swarm_sitl.rundir.outputs import write_outputs
from swarm_sitl.running.sim import run_sim
from tests.support import config

pytestmark = pytest.mark.integration


def _write(path, lines):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("".join(json.dumps(e) + "\n" for e in lines))


def test_a_runs_summary_is_what_its_processes_left(tmp_path):
    data = config("paper").data() | {"duration_s": 4.0}
    data["faults"] = {"seed": 11, "plan": [{"edge": [1, 4], "loss": 0.2}]}
    cfg = parse_config(data)
    rec = run_sim(cfg)
    run_dir = tmp_path / "run"
    procs_dir(run_dir).mkdir(parents=True)
    (run_dir / "config.yaml").write_text(yaml.safe_dump(cfg.data()))
    _write(
        supervisor_events_path(run_dir),
        [
            {"t_s": 1.0, "kind": "process_killed", "process": "controller_2", "source": "supervisor"},
            {"t_s": 1.5, "kind": "process_restarted", "process": "controller_2", "source": "supervisor"},
        ],
    )
    _write(
        lost_events_path(run_dir),
        [
            {"t_s": 3.0, "kind": "vehicle_lost", "vehicle": 4, "source": "supervisor"},
            {"t_s": 2.0, "kind": "vehicle_lost", "vehicle": 3, "source": "supervisor"},
        ],
    )
    _write(
        controller_events_path(run_dir, 1),
        [{"t_s": 0.7, "kind": "neighbour_lost", "follower": 1, "neighbour": 0}],
    )
    _write(
        vehicle_events_path(run_dir, 2),
        [{"t_s": 0.2, "kind": "failsafe_enter", "vehicle": 2, "action": "hold"}],
    )
    refusals = {k: n + 1 for n, k in enumerate(VEHICLE_REFUSALS)}
    vehicle_stats_path(run_dir, 1).write_text(json.dumps({**refusals, "tx_heartbeats": 99}))
    report = {"old_samples": 3, "stale_estimates": 2, "resends": 7}
    edge = {"received": 40, "delivered": 38, "lost": 2}
    for n in (0, 1):  # controller 1 flown twice (an incarnation is one with rows): its counts add up
        controller_rows_path(run_dir, 1, n).touch()
        controller_stats_path(run_dir, 1, n).write_text(
            json.dumps({"report": report, "in_edges": {"0": edge}})
        )

    summary = write_outputs(cfg, rec, run_dir, processes=True)

    events = read_events(run_dir / "events.jsonl")
    assert [e["t_s"] for e in events] == sorted(e["t_s"] for e in events)
    kinds = {(e["kind"], e.get("process") or e.get("vehicle") or e.get("follower")) for e in events}
    assert {
        ("process_killed", "controller_2"),
        ("process_restarted", "controller_2"),
        ("vehicle_lost", 3),
    } <= kinds
    assert {("vehicle_lost", 4), ("neighbour_lost", 1), ("failsafe_enter", 2)} <= kinds
    assert summary["faults"] == {
        "seed": 11,
        "plan": [f"{f.what}: {f.how}" for f in cfg.faults.plan],
        "events": len(events),
    }
    assert summary["lost"] == [3, 4]
    assert summary["vehicles"] == {"1": refusals}  # its refusals, not its heartbeats; 2-4 did not report
    assert summary["inputs"] == {"1": {"old_samples": 6, "stale_estimates": 4}}  # resends: the wall clock's
    assert summary["links"]["0->1"] == {k: 2 * v for k, v in edge.items()}
    (judged,) = summary["rejoins"]
    assert (judged["process"], judged["restart_s"]) == ("controller_2", 1.5)
    assert set(judged["followers"]) == {
        "2"
    }  # its dependants 2 and 4 (the paper's graph); 4's vehicle is lost
    assert json.loads((run_dir / "summary.json").read_text()) == json.loads(json.dumps(summary))
