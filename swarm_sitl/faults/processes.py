"""The supervisor's side of a fault plan: killing, freezing and restarting processes, and telling
a planned exit from a failure.

Real time: at the plan's run second the supervisor sends SIGKILL (every victim: a lost vehicle's
controller too, unless ``with_controller: false``) or SIGSTOP (then SIGCONT ``freeze_s`` later),
and starts a killed controller or leader again ``restart_after_s`` later; the new process joins at
the current tick.

Lockstep: a controller or the leader the plan kills at tick k kills itself when it gets there
(``edges``: the run is then the same every time); the supervisor sees it exit with SIGKILL,
knows it was planned, starts it again at once with ``--resume-tick`` (its restart tick) if the plan
restarts it, and kills a lost aircraft's vehicle with it. A freeze stops a process for ``freeze_s``
of wall time once the swarm has reached ``from_s``: no simulated time passes meanwhile.

Every action is an event in ``procs/supervisor.events`` (``process_killed``, ``process_restarted``,
``process_frozen``, ``process_thawed``, ``vehicle_lost``), at the plan's time in lockstep and at the
run second it happened in real time. A lost vehicle ends the run if ``run.stop_on_loss``.
"""

import contextlib
import os
import signal
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from sim_vehicles.runtime.event_log import EventLog
from swarm_sitl.faults.plan import FaultEntry, FaultPlan, tick_of


class Incarnation(Protocol):
    """One process as the supervisor runs it (``running.supervisor.Child``)."""

    process: str  #: the process it is an incarnation of (``controller_2`` for ``controller_2.1``)
    retired: bool  #: gone as the fault plan said (killed, or replaced by a restart)

    @property
    def pid(self) -> int: ...


class Processes(Protocol):
    """What the plan acts on: the supervisor's children (``running.supervisor.Supervisor``)."""

    def child(self, process: str) -> Incarnation | None:
        """The live incarnation of ``process``, if any."""
        ...

    def spawn(self, name: str, argv: list[str], must_finish: bool, process: str | None = None) -> Any:
        """Start ``argv`` as incarnation ``name`` of ``process``."""
        ...


class LostAircraftError(RuntimeError):
    """A vehicle was lost and ``run.stop_on_loss`` says the run ends with it."""


@dataclass
class _Action:
    spec: FaultEntry
    at_s: float  #: when it happens [s]: simulated (lockstep) or run seconds (real time)
    kind: str  #: "kill", "freeze", "thaw", "restart"
    done: bool = False


class ProcessFaults:
    """Carries out ``plan``'s process faults on ``processes``, at ticks of ``period_s`` in
    lockstep. The supervisor asks ``planned_exit`` and ``frozen`` whether what it sees is planned.
    ``stop_on_loss``: a lost vehicle ends the run (``LostAircraftError``). What differs between the
    two clocks is one of each subclass's methods (``LockstepFaults``, ``WallClockFaults``;
    ``process_faults`` makes the one of a run)."""

    def __init__(
        self,
        plan: FaultPlan,
        period_s: float,
        stop_on_loss: bool,
        processes: Processes,
        events_path: Path,
    ):
        self.sup = processes
        self.stop_on_loss = stop_on_loss
        self.events = EventLog(events_path, "supervisor")
        self.incarnation: dict[str, int] = {}
        self.lost: set[int] = set()  #: followers whose vehicle is lost
        self.down: set[int] = set()  #: followers whose controller is down now
        self._frozen: dict[str, float] = {}  #: process -> when it is thawed [monotonic s]
        self._actions: list[_Action] = []
        self._restart_argv: Callable[[str, int, int], list[str]] | None = None
        for _, f in plan.process_faults():
            if f.kill:
                self._actions.append(_Action(f, f.from_s, "kill"))
            else:
                self._actions.append(_Action(f, f.from_s, "freeze"))
        self._dt = period_s

    def set_restart(self, argv: Callable[[str, int, int], list[str]]) -> None:
        """``argv(process, incarnation, resume_tick)``: how to start a process again."""
        self._restart_argv = argv

    # -- acting --------------------------------------------------------------------------------
    def act(self, run_s: float, min_step: int) -> None:
        """Real time: what is due at run second ``run_s``. Lockstep: the freezes due once every
        live follower has reached ``min_step``; kills are the nodes' own."""
        now = time.monotonic()
        for name, until in list(self._frozen.items()):
            if now >= until:
                del self._frozen[name]
                self._signal(name, signal.SIGCONT)
                self._event("process_thawed", name, run_s)
        for a in self._actions:
            if a.done or not self._due(a, run_s, min_step):
                continue
            a.done = True
            if a.kind == "freeze":
                assert a.spec.freeze_s is not None
                self._frozen[a.spec.process] = now + a.spec.freeze_s
                self._signal(a.spec.process, signal.SIGSTOP)
                self._event("process_frozen", a.spec.process, self._when(a, run_s), freeze_s=a.spec.freeze_s)
            elif a.kind == "kill":
                for name in a.spec.victims():
                    self._kill(name, a.spec, run_s)
            elif a.kind == "restart":
                self._restart(a.spec.process, a.spec, run_s)

    def _kill(self, name: str, spec: FaultEntry, run_s: float) -> None:
        child = self.sup.child(name)
        if child is None:
            return
        child.retired = True
        with contextlib.suppress(ProcessLookupError):
            os.killpg(child.pid, self.KILL)
        self._after_death(name, spec, run_s)

    def _after_death(self, name: str, spec: FaultEntry, t_s: float) -> None:
        self._event("process_killed", name, t_s)
        node = _follower_of(name)
        if name.startswith("vehicle_") and node is not None:
            self.lost.add(node)
            self._event("vehicle_lost", name, t_s, vehicle=node)
            if self.stop_on_loss:
                raise LostAircraftError(f"{name} lost at {t_s:g} s (run.stop_on_loss)")
        if name.startswith("controller_") and node is not None:
            self.down.add(node)
        if spec.restart_after_s is not None and name == spec.process:
            self._restart_later(name, spec, t_s)

    def _restart(self, name: str, spec: FaultEntry, t_s: float) -> None:
        assert self._restart_argv is not None and spec.restart_after_s is not None
        n = self.incarnation.get(name, 0) + 1
        self.incarnation[name] = n
        self.sup.spawn(f"{name}.{n}", self._restart_argv(name, n, self._resume_tick(spec)), True, name)
        self._event("process_restarted", name, t_s)
        node = _follower_of(name)
        if node is not None:
            self.down.discard(node)

    def planned_exit(self, child: Incarnation, code: int) -> bool:
        """Whether ``child``'s exit with ``code`` is one the plan made (else it is a failure)."""
        return child.retired

    def frozen(self, name: str) -> bool:
        return name in self._frozen

    # -- what each clock does -------------------------------------------------------------------
    #: how a victim is killed
    KILL = signal.SIGKILL

    def _due(self, a: _Action, run_s: float, min_step: int) -> bool:
        """Whether action ``a`` is due (``act``'s arguments)."""
        raise NotImplementedError

    def _when(self, a: _Action, run_s: float) -> float:
        """The time action ``a``'s event says it happened at [s]."""
        raise NotImplementedError

    def _restart_later(self, name: str, spec: FaultEntry, t_s: float) -> None:
        """``name``, killed at ``t_s`` by ``spec``, started again ``restart_after_s`` later."""
        raise NotImplementedError

    def _resume_tick(self, spec: FaultEntry) -> int:
        """The tick a process restarted by ``spec`` resumes at (0: the tick the swarm is at)."""
        raise NotImplementedError

    # -- helpers -------------------------------------------------------------------------------
    def _signal(self, name: str, sig: signal.Signals) -> None:
        child = self.sup.child(name)
        if child is not None:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(child.pid, sig)

    def _event(self, kind: str, name: str, t_s: float, **fields: object) -> None:
        self.events.add(round(t_s, 3), kind, process=name, **fields)

    def close(self) -> None:
        for name in list(self._frozen):  # never leave a stopped process behind
            self._signal(name, signal.SIGCONT)
        self._frozen.clear()
        self.events.close()


class WallClockFaults(ProcessFaults):
    """Real time: each action at its run second; a victim killed with SIGKILL, a crash; a restart
    ``restart_after_s`` after the kill, joining at the tick the swarm's clock is at."""

    def _due(self, a: _Action, run_s: float, min_step: int) -> bool:
        return run_s >= a.at_s

    def _when(self, a: _Action, run_s: float) -> float:
        return run_s

    def _restart_later(self, name: str, spec: FaultEntry, t_s: float) -> None:
        assert spec.restart_after_s is not None
        self._actions.append(_Action(spec, t_s + spec.restart_after_s, "restart"))

    def _resume_tick(self, spec: FaultEntry) -> int:
        return 0


class LockstepFaults(ProcessFaults):
    """Lockstep: a kill is the node's own at its planned tick (``planned_exit`` knows it), and its
    restart is started at once, resuming at its restart tick; a freeze once every live follower has
    reached its tick; events at the plan's times."""

    #: a lost aircraft's vehicle, idle since its controller died at the planned tick, is ended with
    #: SIGTERM, so it keeps what it recorded up to the loss (as ``sim`` records it); no simulated
    #: time passes meanwhile
    KILL = signal.SIGTERM

    def _due(self, a: _Action, run_s: float, min_step: int) -> bool:
        return a.kind == "freeze" and min_step >= tick_of(a.at_s, self._dt)

    def _when(self, a: _Action, run_s: float) -> float:
        return a.at_s

    def _restart_later(self, name: str, spec: FaultEntry, t_s: float) -> None:
        assert spec.restart_after_s is not None
        self._restart(name, spec, spec.from_s + spec.restart_after_s)

    def _resume_tick(self, spec: FaultEntry) -> int:
        assert spec.restart_after_s is not None
        return tick_of(spec.from_s, self._dt) + round(spec.restart_after_s / self._dt)

    def planned_exit(self, child: Incarnation, code: int) -> bool:
        """Also a node that killed itself at its planned tick (SIGKILL): its death, its restart,
        and a lost aircraft's vehicle killed with it."""
        if child.retired:
            return True
        if code != -signal.SIGKILL:
            return False
        for a in self._actions:
            if a.kind == "kill" and not a.done and child.process in a.spec.victims():
                a.done = True
                child.retired = True
                t_s = tick_of(a.spec.from_s, self._dt) * self._dt
                self._after_death(child.process, a.spec, t_s)
                for other in a.spec.victims():  # a lost aircraft: its vehicle goes with it
                    if other != child.process:
                        self._kill(other, a.spec, t_s)
                return True
        return False


def process_faults(
    plan: FaultPlan,
    period_s: float,
    stop_on_loss: bool,
    processes: Processes,
    lockstep: bool,
    events_path: Path,
) -> ProcessFaults:
    """The plan's process faults for a run of this clock: ``LockstepFaults`` or ``WallClockFaults``."""
    cls = LockstepFaults if lockstep else WallClockFaults
    return cls(plan, period_s, stop_on_loss, processes, events_path)


def _follower_of(name: str) -> int | None:
    head, _, num = name.partition("_")
    return int(num) if head in ("controller", "vehicle") and num.isdigit() else None
