"""A running swarm's document, grown as it flies: ``LiveFeed``.

The run's supervisor hands the feed what it already reads (``running.run``): each follower's
newest status (its tick, the time of the sample it used, where it is: the status keys), which
nodes are down, and, every half second, the new lines of the processes' event files. The feed
makes at most ``replay.FRAME_HZ`` frames a second of simulated time from them, in the document
``frames`` declares (so the page draws a live run as a finished one), and keeps the newest
``MAX_FRAMES`` (a bounded queue that drops the oldest: a run of hours costs the feed no more than
ten minutes of frames). The server's threads read it under a lock held only to copy; nothing here
ever waits for a browser.

Live, an edge's age is that of its sender's newest status at its receiver's tick (how long the
sender has been silent on the bus: what the run publishes; the age of the estimate the receiver
holds is recorded, and shown by ``view`` afterwards); the leader publishes no status, so its edges
are coloured by the plan alone until the run is over.
"""

import json
import math
import threading
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any, Protocol

from swarm_sitl.bus.codec import Status
from swarm_sitl.bus.hold import LockstepHold
from swarm_sitl.config.schema import SwarmConfig
from swarm_sitl.rundir.events import EventTail, plan_events
from swarm_sitl.rundir.layout import procs_dir
from swarm_sitl.view.frames import DOWN, FAILSAFE, FollowerAt, Frame, columns, event_line, num, xyz
from swarm_sitl.view.replay import FRAME_HZ, static_part


class Sink(Protocol):
    """Where else the feed's frames and events go as they are made (``foxglove_live``)."""

    def frame(self, frame: Frame) -> None: ...
    def events(self, events: list[dict[str, Any]]) -> None: ...


MAX_FRAMES = int(600 * FRAME_HZ)  #: frames kept (ten minutes of simulated time)
EVENTS_EVERY_S = 0.5  #: how often the processes' event files are read [s]


class LiveFeed:
    """The document of the run of ``cfg`` writing to ``run_dir``, as it goes."""

    def __init__(self, cfg: SwarmConfig, run_dir: Path, lockstep: bool):
        self.cfg, self.run_dir = cfg, run_dir
        self._trajectory = cfg.trajectory()
        self._ids = [f.id for f in cfg.followers]
        self._edges = [(s, d) for s, d in cfg.graph_edges() if s != 0]
        self._static = {**static_part(cfg, None), "live": True, "lockstep": lockstep}
        self._lock = threading.Lock()
        self._frames: deque[Frame] = deque(maxlen=MAX_FRAMES)
        self._dropped = 0  #: frames dropped from the front (the first kept is frame ``_dropped``)
        self._events: list[dict[str, Any]] = []
        self._plan_events = sorted(plan_events(cfg), key=lambda e: e["t_s"])
        self._tail = EventTail(procs_dir(run_dir))
        self._failsafe: set[int] = set()
        self._next_events = 0.0
        self._wall0: float | None = None
        self._last_t = -math.inf
        self.rtf: float | None = None
        self.done = False
        #: a lockstep run's pause and step (the run puts it on the bus; None in real time)
        self.hold = LockstepHold(cfg.n_control_steps) if lockstep else None
        #: where else each frame and event goes, as it is made (on the supervisor's thread)
        self.sinks: list[Sink] = []
        self.sink_errors: list[str] = []  #: a sink that failed, one line each (it gets no more)

    # -- fed by the supervisor -------------------------------------------------------------------
    def started(self, epoch_unix_s: float) -> None:
        """The run's start signal went out (its epoch: vehicles stamp their events with it)."""
        self._tail.epoch_unix_s = epoch_unix_s
        self._wall0 = time.monotonic()

    def update(self, statuses: dict[int, Status], errors_m: dict[int, float], down: set[int]) -> None:
        """The newest status of each follower, its formation error at it (``RunMonitor.errors_m``),
        and the nodes down now: a frame if one is due."""
        if not statuses:
            return
        t = min(s.t_s for i, s in statuses.items() if i not in down) if set(statuses) - down else None
        stepped = self.hold is not None and self.hold.paused and t is not None and t > self._last_t
        if t is None or (t < self._last_t + 1.0 / FRAME_HZ - 1e-9 and not stepped):
            self._read_events()
            return
        self._last_t = t
        p_r = self._trajectory.derivatives(t)[0]
        followers: dict[str, FollowerAt] = {}
        for i in self._ids:
            s = statuses.get(i)
            state = (DOWN if i in down or s is None else 0) | (FAILSAFE if i in self._failsafe else 0)
            if s is None or i in down:
                followers[str(i)] = FollowerAt([None, None, None], None, state)
                continue
            err = errors_m.get(i, math.nan)
            # (its own tick's instant: in lockstep the followers' newest statuses are of other ticks)
            followers[str(i)] = FollowerAt(xyz(s.p_W.tolist()), num(err, 4), state, s.t_s)
        ages = {}
        for src, dst in self._edges:
            a, b = statuses.get(src), statuses.get(dst)
            ages[f"{src}->{dst}"] = None if a is None or b is None or src in down else num(b.t_s - a.t_s, 3)
        frame = Frame(t_s=num(t, 4), leader=xyz(p_r.tolist()), followers=followers, edge_age_s=ages)
        with self._lock:
            if len(self._frames) == MAX_FRAMES:
                self._dropped += 1
            self._frames.append(frame)
            if self._wall0 is not None and time.monotonic() > self._wall0:
                self.rtf = t / (time.monotonic() - self._wall0)
        self._to_sinks(lambda s: s.frame(frame))
        self._read_events()

    def _read_events(self) -> None:
        now = time.monotonic()
        if now < self._next_events:
            return
        self._next_events = now + EVENTS_EVERY_S
        new: list[dict[str, Any]] = []
        while self._plan_events and self._plan_events[0]["t_s"] <= self._last_t:
            new.append(self._plan_events.pop(0))
        new += self._tail.read()
        for e in new:
            v = e.get("vehicle")
            if e["kind"] == "failsafe_enter" and isinstance(v, int):
                self._failsafe.add(v)
            elif e["kind"] == "failsafe_exit" and isinstance(v, int):
                self._failsafe.discard(v)
        if new:
            lines = [event_line(e) for e in sorted(new, key=lambda e: e["t_s"])]
            with self._lock:
                self._events += lines
            self._to_sinks(lambda s: s.events(lines))

    def _to_sinks(self, give: Callable[[Sink], None]) -> None:
        """``give(sink)`` for each sink; one that raises is dropped with its line kept (the run
        flies on: a sink is never worth a run)."""
        for sink in list(self.sinks):
            try:
                give(sink)
            except Exception as e:
                self.sinks.remove(sink)
                self.sink_errors.append(f"{type(sink).__name__}: {type(e).__name__}: {e}")

    def finish(self) -> None:
        self._next_events = 0.0
        self._read_events()
        self.done = True

    # -- read by the server ----------------------------------------------------------------------
    def document(self) -> bytes:
        with self._lock:
            frames, first, events = list(self._frames), self._dropped, list(self._events)
        return json.dumps(
            {
                **self._static,
                "frame0": first,
                "frames": columns(frames, self._ids),
                "events": events,
                "done": self.done,
            },
            separators=(",", ":"),
        ).encode()

    def frames_since(self, frame: int, event: int) -> bytes:
        held = None if self.hold is None else self.hold.held_at
        with self._lock:
            skip = max(0, frame - self._dropped)
            frames, events = list(self._frames)[skip:], self._events[event:]
        return json.dumps(
            {
                "frames": columns(frames, self._ids),
                "events": events,
                "done": self.done,
                "rtf": self.rtf,
                "paused": self.hold is not None and self.hold.paused,
                "held_s": None if held is None else round(held * self.cfg.control_dt_s, 9),
            },
            separators=(",", ":"),
        ).encode()

    def control(self, pause: str | None, step: int) -> tuple[int, str]:
        """The page's pause or step: an HTTP status and one line."""
        if self.done:
            return 409, "the run is over"
        if self.hold is None:
            return 409, "a real-time run flies on the wall clock: pause and step are for a lockstep run"
        return self.hold.control(pause, step)
