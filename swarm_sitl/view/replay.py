"""A run directory as the page shows it: ``replay_document``.

The page draws frames of one document (declared in ``frames``, the same for a finished run and,
frame by frame, for a live one): at most ``FRAME_HZ`` frames a second of simulated time, each with the
leader's reference, every follower's position, formation error and state (flying, down: its
controller recorded nothing; in failsafe: its vehicle said so), and every edge's age (of the
newest estimate its receiver had, where the run recorded it: ``in_age_s``, since the edge
requirements; an older run has none, and its edges are coloured by the plan alone). Beside the
frames: the graph's layout (``layout``), the plan's windows per edge and process, each edge's
delivered fraction over the run (``summary.json``'s ``links``) and the events.

Nothing here is new in a run directory: a run made before the view reads as one made after.
"""

import json
from pathlib import Path
from typing import Any

import numpy as np

from swarm_sitl.config.load import ConfigError, load_recorded
from swarm_sitl.config.schema import SwarmConfig
from swarm_sitl.rundir.events import failsafe_windows, plan_events, read_events
from swarm_sitl.rundir.load import RunDirError, load_run
from swarm_sitl.view.frames import DOWN, FAILSAFE, event_line, follower_columns, frame_columns, no_frames, num
from swarm_sitl.view.layout import graph_layout

FRAME_HZ = 20.0  #: frames per second of simulated time, at most
GRAPH_PX = (560, 360)  #: the graph canvas's size on the page [px]
__all__ = ["DOWN", "FAILSAFE", "FRAME_HZ", "ReplaySource", "replay_document", "static_part"]


def frame_ticks(n_ticks: int, period_s: float) -> np.ndarray:
    """The ticks shown: every one ``1 / FRAME_HZ`` s apart or more, and the last."""
    stride = max(1, round(1.0 / (FRAME_HZ * period_s)))
    ticks = np.arange(0, n_ticks, stride)
    return ticks if ticks[-1] == n_ticks - 1 else np.append(ticks, n_ticks - 1)


def _xyz(a: np.ndarray) -> list[list[float | None]]:
    return [[num(v) for v in row] for row in a.tolist()]


def static_part(cfg: SwarmConfig, summary: dict[str, Any] | None) -> dict[str, Any]:
    """What does not change over a run: the swarm, its graph laid out, the plan's windows."""
    edges = cfg.graph_edges()
    layout = graph_layout(cfg.n_followers, edges, *GRAPH_PX)
    links = (summary or {}).get("links", {})
    edge_info = []
    for s, d in edges:
        c = links.get(f"{s}->{d}", {})
        sent = c.get("sent") or c.get("received")
        delivered = c.get("delivered", 0) - c.get("duplicated", 0)
        edge_info.append(
            {
                "src": s,
                "dst": d,
                "delivered_frac": num(delivered / sent) if sent else None,
                "faults": [
                    {"from_s": f.from_s, "until_s": f.until_s or cfg.duration_s, "how": f.how}
                    for f in cfg.faults.plan
                    if (s, d) in f.edges(edges)
                ],
            }
        )
    processes = [
        {"process": p, "from_s": f.from_s, "how": f.how}
        for f in cfg.faults.plan
        if f.is_process
        for p in f.victims()
    ]
    return {
        "name": cfg.name,
        "period_s": cfg.control_dt_s,
        "duration_s": cfg.duration_s,
        "followers": [f.id for f in cfg.followers],
        "offsets_m": {str(f.id): list(f.offset_m) for f in cfg.followers},
        "staleness_s": cfg.estimator.staleness_s,
        "graph": {"size_px": list(GRAPH_PX), "nodes": {str(k): v for k, v in layout.items()}},
        "edges": edge_info,
        "process_faults": processes,
    }


def replay_document(run_dir: str | Path) -> dict[str, Any]:
    """The page's document of a finished run; ``RunDirError`` (one line) if ``run_dir`` is not
    one that can be shown."""
    d = Path(run_dir)
    if not d.is_dir():
        raise RunDirError(f"{d}: no such directory")
    if not (d / "config.yaml").is_file():
        raise RunDirError(f"{d}: not a run directory (no config.yaml)")
    try:
        cfg = load_recorded(d)
    except ConfigError as e:
        raise RunDirError(f"{d}: {e}") from None
    rec = load_run(d)
    try:
        summary = json.loads((d / "summary.json").read_text())
    except (OSError, ValueError):
        summary = None
    # a run of processes wrote its events; ``sim`` writes none: the plan's windows, then
    events = (
        read_events(d / "events.jsonl") if (d / "events.jsonl").is_file() else _in_order(plan_events(cfg))
    )
    doc = static_part(cfg, summary)
    t = rec.leader["t_s"]
    ticks = frame_ticks(len(t), cfg.control_dt_s)
    graph = cfg.build_graph()
    failsafe = failsafe_windows(events)
    followers: dict[str, Any] = {}
    ages: dict[str, list[float | None]] = {}
    for i, a in rec.followers.items():
        n = len(a["t_s"])
        at = np.minimum(ticks, n - 1)
        p = a["p_W"][at]
        recorded = np.isfinite(a["t_s"][at]) & (ticks < n)
        err = np.linalg.norm(a["pos_err_m"][at], axis=1)
        state = np.where(recorded, 0, DOWN)
        for start, end in failsafe.get(i, []):
            state[(t[ticks] >= start) & (t[ticks] < end)] |= FAILSAFE
        followers[str(i)] = follower_columns(
            p=_xyz(p), err=[num(e, 4) for e in err.tolist()], state=state.tolist()
        )
        in_age = a.get("in_age_s")
        sources = [int(s) for s, _ in graph.in_neighbours(i)]
        if in_age is not None and in_age.ndim == 2 and in_age.shape[1] == len(sources):
            for j, s in enumerate(sources):
                ages[f"{s}->{i}"] = [num(x, 3) for x in in_age[at, j].tolist()]
    doc["frames"] = frame_columns(
        t_s=[num(x, 4) for x in t[ticks].tolist()],
        leader=_xyz(rec.leader["p_r"][ticks]),
        followers=followers,
        edge_age_s=ages,
    )
    doc["events"] = [event_line(e) for e in events]
    doc["live"] = False
    return doc


class ReplaySource:
    """A finished run's document, for the server (``server.DocumentSource``): whole at once."""

    NOTHING_MORE = json.dumps(
        {"frames": no_frames(), "events": [], "done": True}, separators=(",", ":")
    ).encode()

    def __init__(self, doc: dict[str, Any]):
        self._bytes = json.dumps(doc, separators=(",", ":"), allow_nan=False).encode()

    def document(self) -> bytes:
        return self._bytes

    def frames_since(self, frame: int, event: int) -> bytes:
        return self.NOTHING_MORE

    def control(self, pause: str | None, step: int) -> tuple[int, str]:
        return 409, "a finished run: its page plays and pauses itself (pause and step are for a lockstep run)"


def _in_order(events: list[dict[str, Any]]) -> list[dict[str, Any]]:
    return sorted(events, key=lambda e: e["t_s"])
