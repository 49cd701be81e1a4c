"""How a run tells a process that ended early or stopped ticking, and names it in one line.

- ``completed``: a node (leader, controller) that exits 0 has finished its ticks only if it wrote
  its figures (``procs/<name>.stats.json``), which it does after its last tick; one that exits 0
  without them (a ``sys.exit`` the law guard did not see, a library that ends the process) left
  early.
- ``last_tick``: a node's last tick, the newest it published (``procs/<name>.tick``, a counter
  file that outlives a kill).
- ``TickWatch`` (real time): a controller whose published ticks stop for ``run.tick_timeout_s``
  (plus the law guard's ``HARD_STOP_S`` and a second: a law that hangs is named by its own
  controller first) while the run goes on is named, with its law and its last tick; and a run
  still going that long after its duration ends, naming who has not finished.
- ``LostLog``: the exits ridden through (real time, ``run.stop_on_loss: false``), as
  ``process_lost`` events in ``procs/lost.events`` (``rundir.merge`` reads them into the run's
  events); ``lost_line``: the run's last line of them, the first ``WHOLE_LOST`` whole and the rest
  by name (32 followers on too small a machine lose a dozen controllers, each with the same advice).
"""

import time
from pathlib import Path
from typing import Protocol

from sim_vehicles.runtime.counter_file import read_counter
from sim_vehicles.runtime.event_log import EventLog
from swarm_sitl.config.schema import SwarmConfig
from swarm_sitl.nodes.law_guard import HARD_STOP_S
from swarm_sitl.rundir.layout import lost_events_path, procs_dir, tick_path
from swarm_sitl.running.supervisor import Child, ExitRules, RunFailedError


def _files(run_dir: Path, child: Child) -> tuple[Path, Path] | None:
    """A node's figures at its end and its newest tick; None for a vehicle."""
    if not (child.process == "leader" or child.process.startswith("controller_")):
        return None
    return procs_dir(run_dir) / f"{child.name}.stats.json", tick_path(run_dir, child.name)


def completed(run_dir: Path, child: Child) -> bool:
    files = _files(run_dir, child)
    return files is None or files[0].exists()


def newest_tick(run_dir: Path, child: Child) -> int | None:
    """The newest tick node ``child`` published (-1: none yet; None: a vehicle, or no file)."""
    files = _files(run_dir, child)
    n = None if files is None else read_counter(files[1])
    return None if n is None else n - 1


def last_tick(run_dir: Path, dt_s: float, child: Child) -> str:
    """``"its last tick 49, t=0.490 s"`` (``"before its first tick"``; ``""`` for a vehicle)."""
    k = newest_tick(run_dir, child)
    if k is None:
        return ""
    if k < 0:
        return "before its first tick"
    return f"its last tick {k}, t={k * dt_s:.3f} s"


class TickWatch:
    """Real time: the controllers' ticks as they publish them, watched for a stop."""

    def __init__(self, cfg: SwarmConfig, run_dir: Path, epoch_mono: float):
        self.cfg = cfg
        self.run_dir = run_dir
        self.epoch_mono = epoch_mono
        self.timeout_s = cfg.run.tick_timeout_s
        #: a law that hangs is stopped by its guard and its controller says so first
        self.allowed_s = self.timeout_s + HARD_STOP_S + 1.0
        self._seen: dict[str, tuple[int, float]] = {}  #: child -> (published, when it last grew)

    def check(self, children: list[Child], now: float) -> None:
        """``RunFailedError`` naming a controller whose ticks stopped, or the run past its end."""
        last = self.cfg.n_control_steps
        for c in children:
            if c.retired or not c.process.startswith("controller_") or c.proc.poll() is not None:
                continue
            k = newest_tick(self.run_dir, c)
            if k is None or k >= last:
                continue
            old = self._seen.get(c.name)
            if old is None or k != old[0]:
                self._seen[c.name] = (k, now)
                continue
            start = max(old[1], self.epoch_mono)
            if k >= 0 and now - start > self.allowed_s:
                t = k * self.cfg.control_dt_s
                raise RunFailedError(
                    f"{c.name} (law {self.cfg.law.entry}) has not ticked for {now - start:.1f} s "
                    f"(run.tick_timeout_s {self.timeout_s:g}): its last tick {k}, t={t:.3f} s"
                )
        over = now - self.epoch_mono - self.cfg.duration_s
        if over > self.allowed_s:
            going = [c.name for c in children if c.must_finish and not c.retired and c.proc.poll() is None]
            raise RunFailedError(
                f"the run did not end {self.allowed_s:g} s after its duration {self.cfg.duration_s:g} s "
                f"(run.tick_timeout_s + {self.allowed_s - self.timeout_s:g} s): "
                f"{', '.join(going) or 'no process'} still running"
            )


class LostLog:
    """Exits ridden through, as events of the run (``process_lost``)."""

    def __init__(self, run_dir: Path, epoch_unix_s: float | None):
        self.events = EventLog(lost_events_path(run_dir), "supervisor")
        self.epoch_unix_s = epoch_unix_s

    def add(self, child: Child, code: int, line: str) -> None:
        t_s = time.time() - self.epoch_unix_s if self.epoch_unix_s is not None else 0.0
        self.events.add(round(t_s, 3), "process_lost", process=child.name, code=code, line=line)

    def close(self) -> None:
        self.events.close()


#: of the exits ridden through, how many the run's last line gives whole (the rest by name: each
#: whole line is a ``process_lost`` event of the run): every controller of the paper's swarm
WHOLE_LOST = 4


def lost_line(lost: list[str]) -> str:
    """The exits ridden through (each ``"<process> exited with code ..."``) in one line: the first
    ``WHOLE_LOST`` whole, then how many more and their processes' names."""
    if len(lost) <= WHOLE_LOST:
        return "; ".join(lost)
    rest = [line.split(" ", 1)[0] for line in lost[WHOLE_LOST:]]
    return (
        "; ".join(lost[:WHOLE_LOST])
        + f"; and {len(rest)} more lost: {', '.join(rest)} (each line is a process_lost event of the run)"
    )


class PlannedExits(Protocol):
    """What the exit rules ask of a run's process fault plan (``faults.processes``)."""

    def planned_exit(self, child: Child, code: int) -> bool: ...

    def frozen(self, process: str) -> bool: ...


class RunExits(ExitRules):
    """A run's exit rules: a node has completed when its tick file says so, its line names its
    last tick, the fault plan's kills and freezes are planned (``faults``, once the run has one),
    and an unplanned exit is ridden through while a lost log is kept (``lost``: real time,
    ``run.stop_on_loss: false``, once the run has started)."""

    def __init__(self, run_dir: Path, dt_s: float):
        self.run_dir = run_dir
        self.dt_s = dt_s
        self.faults: PlannedExits | None = None
        self.lost: LostLog | None = None

    def completed(self, child: Child) -> bool:
        return completed(self.run_dir, child)

    def last_tick(self, child: Child) -> str:
        return last_tick(self.run_dir, self.dt_s, child)

    def planned_exit(self, child: Child, code: int) -> bool:
        return self.faults is not None and self.faults.planned_exit(child, code)

    def planned_stop(self, process: str) -> bool:
        return self.faults is not None and self.faults.frozen(process)

    def ride_through(self) -> bool:
        return self.lost is not None

    def on_lost(self, child: Child, code: int, line: str) -> None:
        if self.lost is not None:
            self.lost.add(child, code, line)
