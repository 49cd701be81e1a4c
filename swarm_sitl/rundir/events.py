"""What happened during a run, as events: one JSON object per line, each with its time.

A process appends its events to ``procs/<process>.events`` as they happen
(``sim_vehicles.runtime.event_log``: one flushed line each, so a killed process keeps what it
wrote); the run's ``events.jsonl`` merges them with the fault plan's own intervals, in time order.
Every event has ``t_s`` (simulated seconds in lockstep, run seconds
in real time), ``kind`` and ``source`` (the process that saw it), plus fields of its kind:

    fault_start, fault_end     fault (plan entry), what, how          (from the plan)
    neighbour_lost             follower, neighbour, age_s             (its estimate is past staleness)
    neighbour_regained         follower, neighbour, age_s
    no_live_in_edge            follower                               (its estimator runs on its own)
    failsafe_enter             vehicle, action, p_W                   (its setpoints stopped)
    failsafe_exit              vehicle                                (a valid setpoint came)

A vehicle stamps its events with its boot time and the UNIX time; in real time the merge puts
them on the run's clock (``t_s`` = UNIX time - the start epoch).
"""

import json
import math
from pathlib import Path
from typing import Any

from swarm_sitl.config.schema import SwarmConfig
from swarm_sitl.rundir.whole_files import write_text_whole


def plan_events(cfg: SwarmConfig) -> list[dict[str, Any]]:
    """The start and end of every entry of the config's fault plan."""
    out = []
    for j, f in enumerate(cfg.faults.plan):
        common = {"source": "plan", "fault": j, "what": f.what, "how": f.how}
        lasts = f.restart_after_s or f.freeze_s
        end = f.until_s if f.until_s is not None else (f.from_s + lasts if lasts else cfg.duration_s)
        out.append({"t_s": f.from_s, "kind": "fault_start", **common})
        out.append({"t_s": end, "kind": "fault_end", **common})
    return out


def failsafe_windows(events: list[dict[str, Any]]) -> dict[int, list[tuple[float, float]]]:
    """Per vehicle, when it was in its setpoint-loss failsafe: from a ``failsafe_enter`` (the first,
    where it enters again while in it) to the ``failsafe_exit`` after it, ``math.inf`` for one
    still in it at the end; events taken in time order (ties as given). What the page shows, the
    ``failsafe`` signal of a spec and a campaign row's ``failsafe_s`` are read from it."""
    out: dict[int, list[tuple[float, float]]] = {}
    open_at: dict[int, float] = {}
    for e in sorted(events, key=lambda e: float(e.get("t_s", 0.0))):
        v = e.get("vehicle")
        if not isinstance(v, int) or isinstance(v, bool):
            continue
        if e.get("kind") == "failsafe_enter":
            open_at.setdefault(v, float(e["t_s"]))
        elif e.get("kind") == "failsafe_exit" and v in open_at:
            out.setdefault(v, []).append((open_at.pop(v), float(e["t_s"])))
    for v, start in open_at.items():
        out.setdefault(v, []).append((start, math.inf))
    return out


def read_events(path: Path) -> list[dict[str, Any]]:
    """The complete lines of an event file (a line cut short by a kill is left out)."""
    try:
        return parse_events(path.read_text())
    except OSError:
        return []


def parse_events(text: str) -> list[dict[str, Any]]:
    """The events of complete lines of an event file's text: each a mapping with a time and a kind."""
    out: list[dict[str, Any]] = []
    for line in text.splitlines():
        try:
            e = json.loads(line)
        except ValueError:
            continue
        if isinstance(e, dict) and isinstance(e.get("t_s"), int | float) and "kind" in e:
            out.append(e)
    return out


def merge_events(
    cfg: SwarmConfig, files: list[Path], epoch_unix_s: float | None = None
) -> list[dict[str, Any]]:
    """The plan's events and every file's, in time order (ties: plan first, then by source).
    ``epoch_unix_s``: a real-time run's start, which puts events stamped with the UNIX time
    (``unix_s``, a vehicle's) on the run's clock; the UNIX time is dropped either way, so a
    lockstep run's events are the same twice."""
    events = plan_events(cfg)
    for p in sorted(files):
        events += [on_run_clock(e, epoch_unix_s) for e in read_events(p)]
    events.sort(key=lambda e: (e["t_s"], e.get("source") != "plan", str(e.get("source")), e["kind"]))
    return events


def on_run_clock(e: dict[str, Any], epoch_unix_s: float | None) -> dict[str, Any]:
    """``e`` without its UNIX time (``unix_s``, a vehicle's), which puts it on the run's clock
    (``t_s`` from ``epoch_unix_s``, a real-time run's start) where that is given."""
    unix_s = e.pop("unix_s", None)
    if epoch_unix_s is not None and isinstance(unix_s, int | float):
        e["t_s"] = round(unix_s - epoch_unix_s, 6)
    return e


class EventTail:
    """The processes' event files of a running run (``*.events`` in ``directory``), read as they
    grow: each ``read`` gives the complete lines written since the last, put on the run's clock
    (``epoch_unix_s``, once the run has started: a vehicle stamps its events with the UNIX time)."""

    def __init__(self, directory: Path):
        self.directory = directory
        self.epoch_unix_s: float | None = None
        self._offsets: dict[Path, int] = {}

    def read(self) -> list[dict[str, Any]]:
        new: list[dict[str, Any]] = []
        for path in sorted(self.directory.glob("*.events")):
            new += self._tail(path)
        return new

    def _tail(self, path: Path) -> list[dict[str, Any]]:
        at = self._offsets.get(path, 0)
        try:
            with path.open("rb") as f:
                f.seek(at)
                chunk = f.read()
        except OSError:
            return []
        end = chunk.rfind(b"\n") + 1
        self._offsets[path] = at + end
        text = chunk[:end].decode(errors="replace")
        return [on_run_clock(e, self.epoch_unix_s) for e in parse_events(text)]


def write_events(path: Path, events: list[dict[str, Any]]) -> None:
    write_text_whole(path, "".join(json.dumps(e, sort_keys=True) + "\n" for e in events))
