"""A run's outputs: the run directory written from what was recorded, and the run's verdict.

``write_outputs`` writes ``config.yaml``, the arrays and ``summary.json`` (for a multi-process run
also ``events.jsonl`` and, in the summary, each follower's inputs and each edge's traffic).
``record_run`` runs the swarm as processes and writes its outputs whatever happened (completed,
failed, interrupted); ``bound_failures`` (``metrics``) judges it against
``run.max_formation_error_m``. The CLI prints an ``Outcome``; ``swarm_sitl.api`` returns it as objects.
"""

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from swarm_sitl.config.schema import SwarmConfig
from swarm_sitl.rundir.recording import Recording


def write_outputs(cfg: SwarmConfig, rec: Recording, run_dir: Path, processes: bool = False) -> dict:
    """The run directory's config, arrays and summary; ``processes``: a multi-process run, whose
    events (``events.jsonl``), links and per-follower inputs are merged in too."""
    from swarm_sitl.rundir.metrics import summarize
    from swarm_sitl.rundir.recording import write_run

    masses = {f.id: cfg.vehicle.mass_kg for f in cfg.followers}
    summary = summarize(rec, cfg.gain_dict(), masses, cfg.gravity_mps2, cfg.run.settle_s)
    if processes:
        from swarm_sitl.rundir.events import write_events
        from swarm_sitl.rundir.merge import inputs_and_links, run_events, vehicle_refusals

        events = run_events(cfg, run_dir)
        write_events(run_dir / "events.jsonl", events)
        summary["inputs"], summary["links"] = inputs_and_links(cfg, run_dir)
        summary["vehicles"] = vehicle_refusals(cfg, run_dir)
        summary["faults"] = {
            "seed": cfg.faults.seed,
            "plan": [f"{f.what}: {f.how}" for f in cfg.faults.plan],
            "events": len(events),
        }
        summary["lost"] = sorted(e["vehicle"] for e in events if e["kind"] == "vehicle_lost")
    write_run(run_dir, cfg.to_yaml(), rec, summary)
    return summary


@dataclass
class Outcome:
    """How a multi-process run ended, and what it recorded."""

    summary: dict[str, Any]
    failure: str | None  #: the process that failed, in one line (None: none did)
    interrupted: bool  #: Ctrl-C (or SIGTERM) ended it
    run_wall_s: float  #: from the start signal to the last controller done (nan if it did not end)
    startup_wall_s: float  #: from spawning to every process ready (nan if it did not start)
    bound_failures: list[str]  #: followers past ``run.max_formation_error_m``, one line each


def record_run(
    cfg: SwarmConfig,
    run_dir: Path,
    lockstep: bool,
    mavlink: dict[int, str] | None = None,
    on_progress: Callable[[int, dict[int, float]], None] | None = None,
    base_port: int = 0,
    on_vehicles: Callable[[list[str]], None] | None = None,
) -> Outcome:
    """Run the swarm as processes (``supervisor.run_swarm``) and write its run directory from
    what the processes recorded, however the run ended (a ``KeyboardInterrupt`` is caught and
    reported as ``interrupted``)."""
    from swarm_sitl.rundir.merge import merge_run
    from swarm_sitl.rundir.metrics import bound_failures
    from swarm_sitl.supervisor import RunFailedError, run_swarm

    failure: str | None = None
    interrupted = False
    run_wall = startup = float("nan")
    try:
        result = run_swarm(cfg, run_dir, lockstep, mavlink, on_progress, base_port, on_vehicles)
        run_wall, startup = result.run_wall_s, result.startup_wall_s
    except RunFailedError as e:
        failure = str(e)
    except KeyboardInterrupt:
        interrupted = True
    summary = write_outputs(cfg, merge_run(cfg, run_dir), run_dir, processes=True)
    bound = bound_failures(summary, cfg.run.max_formation_error_m) if failure is None else []
    return Outcome(summary, failure, interrupted, run_wall, startup, bound)
