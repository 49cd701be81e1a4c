"""A run's outputs: the run directory written from what was recorded.

``write_outputs`` writes ``config.yaml`` (naming the copies of its plug-ins it keeps in
``plugins/``: ``rundir.plugins``), the arrays and ``summary.json`` (for a multi-process run
also ``events.jsonl`` and, in the summary, each follower's inputs and each edge's traffic);
``running.run.record_run`` calls it however a run ended. ``write_spooled_outputs`` writes the
same files, byte for byte, from a recording spooled to disk (``spool``: ``sim``'s), a block of
rows at a time.
"""

import json
import shutil
from pathlib import Path

import numpy as np

from swarm_sitl.config.schema import SwarmConfig
from swarm_sitl.rundir.events import write_events
from swarm_sitl.rundir.load import load_run
from swarm_sitl.rundir.merge import inputs_and_links, run_events, vehicle_refusals
from swarm_sitl.rundir.metrics import follower_figures, summarize, swarm_summary, uz_floor
from swarm_sitl.rundir.plugins import keep, manifest_of
from swarm_sitl.rundir.provenance import provenance
from swarm_sitl.rundir.recording import Recording, leader_series, write_run
from swarm_sitl.rundir.rejoins import judge_rejoins
from swarm_sitl.rundir.requirements import judge
from swarm_sitl.rundir.spool import NpzBlocks, SpooledRecording
from swarm_sitl.rundir.whole_files import write_text_whole


def write_outputs(cfg: SwarmConfig, rec: Recording, run_dir: Path, processes: bool = False) -> dict:
    """The run directory's config, arrays and summary; ``processes``: a multi-process run, whose
    events (``events.jsonl``), links and per-follower inputs are merged in too."""
    masses = {f.id: cfg.vehicle.mass_kg for f in cfg.followers}
    gains = cfg.gain_dict() if cfg.law.is_paper else None
    summary = summarize(rec, gains, masses, cfg.gravity_mps2, cfg.run.settle_s, cfg.vehicle.max_thrust_N)
    config_text = keep(cfg, run_dir)  # the plug-ins copied in, config.yaml naming the copies
    summary["provenance"] = provenance(cfg, manifest_of(run_dir))
    events: list = list(rec.events)  # sim's (its vehicles' failsafe)
    if processes:
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
        summary["rejoins"] = judge_rejoins(
            rec.followers,
            events,
            cfg.build_graph(),
            cfg.duration_s,
            cfg.run.max_formation_error_m,
            cfg.run.rejoin_within_s,
            set(summary["lost"]),
        )
    if cfg.spec:  # the config's requirements, each with its robustness
        summary["spec"] = judge(cfg, rec, events)
    write_run(run_dir, config_text, rec, summary)
    return summary


def write_spooled_outputs(cfg: SwarmConfig, rec: SpooledRecording, run_dir: Path) -> dict:
    """``write_outputs`` of a recording spooled to disk (``sim``'s): the same files, byte for
    byte, written a block of rows at a time, so memory does not grow with the run (but for a
    config's ``spec:``, whose signals are judged whole: read back from the arrays written)."""
    trajectory = cfg.trajectory()
    gains = cfg.gain_dict() if cfg.law.is_paper else None
    work = rec.spool_dir / "npz"
    leader = NpzBlocks(run_dir / "leader.npz", work / "leader")
    per = {}
    arrays = {}
    for n, (i, spooled) in enumerate(rec.followers.items()):
        figures = follower_figures(
            gains, cfg.vehicle.mass_kg, cfg.gravity_mps2, cfg.run.settle_s, cfg.vehicle.max_thrust_N
        )
        out = arrays[i] = NpzBlocks(
            run_dir / f"follower_{i}.npz", work / str(i), {"offset_m": rec.offsets[i]}
        )
        for a, block in spooled.blocks():
            series = leader_series(trajectory, np.arange(a, a + len(block["t_s"])) * rec.dt_s)
            rows = Recording(series, {i: block}, {i: rec.offsets[i]}).with_errors(trajectory).followers[i]
            figures.add(rows)
            out.add(rows)
            if n == 0:
                leader.add(series)
        per[i] = figures.result()
    summary = swarm_summary(per, uz_floor(gains, cfg.gravity_mps2), cfg.run.settle_s)
    config_text = keep(cfg, run_dir)
    summary["provenance"] = provenance(cfg, manifest_of(run_dir))
    run_dir.mkdir(parents=True, exist_ok=True)
    write_text_whole(run_dir / "config.yaml", config_text)
    leader.close()
    for out in arrays.values():
        out.close()
    if cfg.spec:
        summary["spec"] = judge(cfg, load_run(run_dir), list(rec.events))
    write_text_whole(run_dir / "summary.json", json.dumps(summary, indent=2) + "\n")
    shutil.rmtree(rec.spool_dir, ignore_errors=True)
    return summary
