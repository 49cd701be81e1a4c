"""Spawn, supervise and tear down the processes of a swarm; the one place that owns child processes.

``Supervisor`` starts each child in its own session with its output in ``RUN_DIR/logs/<name>.log``
and ``SWARM_SITL_PARENT_PID`` set (children die with it, ``sim_vehicles.runtime.lifeline``),
forked from the fork server where it has one (``fork_server``). ``check`` raises
``RunFailedError`` naming a child that exited before the run's end, with any code (a node that
exits 0 without having finished its ticks too), unless the fault plan made it; the line names its
code, its last tick and why, from its log. How a run judges its children's exits is one object
given at construction (``ExitRules``; a run's: ``ends.RunExits``). When the rules ride through
an unplanned exit, it is recorded (``on_lost``) and the run flies on without it; ``lost`` keeps
the lines. Whatever happens (completion, Ctrl-C, a child
failing, an exception here), ``close()`` sends SIGTERM to every child still running, waits, then
SIGKILLs: no orphan process, no port left bound.
"""

import contextlib
import math
import os
import signal
import subprocess
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

from swarm_sitl.running.children import PARENT_ENV, child_env, module_argv
from swarm_sitl.running.fork_server import ENTRY_MODULES, ForkedProcess, ForkServer, ForkServerError

TERM_GRACE_S = 5.0
SUPERVISE_EVERY_S = 0.05  #: how often a run looks at its children (each look polls every one of them)


class RunFailedError(RuntimeError):
    """A process of the run failed; the message names it."""


STOPPED_GRACE_S = 0.5  #: a child stopped (SIGSTOP) this long, unplanned, fails the run [s]


@dataclass
class Child:
    name: str
    proc: "subprocess.Popen[bytes] | ForkedProcess"
    log_path: Path
    must_finish: bool  #: leader/controllers end by themselves; vehicles run until torn down
    process: str = ""  #: the process it is an incarnation of (``controller_2`` for ``controller_2.1``)
    retired: bool = False  #: gone as the fault plan said (killed, or replaced by a restart), or lost
    first_tick: int = 0  #: the tick it starts at (``--resume-tick``: a restarted node's)
    stopped_since: float = math.inf  #: when it was first seen stopped [monotonic s]

    @property
    def pid(self) -> int:
        return self.proc.pid

    def stopped(self) -> bool:
        """Whether the process is stopped (SIGSTOP, or a debugger), from ``/proc`` (Linux)."""
        try:
            stat = Path(f"/proc/{self.proc.pid}/stat").read_text()
        except OSError:
            return False
        return stat.rsplit(")", 1)[-1].split()[0] in ("T", "t")

    def last_line(self) -> str:
        try:
            lines = [ln for ln in self.log_path.read_text(errors="replace").splitlines() if ln.strip()]
        except OSError:
            return ""
        return lines[-1].strip() if lines else ""


class ExitRules:
    """How a supervisor judges its children's exits. These defaults: an exit 0 of a child that
    must finish is its end, every other exit fails the run, and the line says no tick."""

    def completed(self, child: Child) -> bool:
        """Whether a node that exited 0 had done all its ticks (a vehicle: not asked)."""
        return True

    def planned_exit(self, child: Child, code: int) -> bool:
        """Whether a child's exit (with its code) is one a fault plan made (``faults.processes``)."""
        return False

    def planned_stop(self, process: str) -> bool:
        """Whether a stopped child was stopped by the plan."""
        return False

    def last_tick(self, child: Child) -> str:
        """What a child's last tick was, for the line (``""``: unknown)."""
        return ""

    def ride_through(self) -> bool:
        """Whether an unplanned exit is recorded and ridden through, not the run's end (real
        time, ``run.stop_on_loss: false``)."""
        return False

    def on_lost(self, child: Child, code: int, line: str) -> None:
        """An exit ridden through, with its line."""


@dataclass
class Supervisor:
    run_dir: Path
    children: list[Child] = field(default_factory=list)
    _logs: list[IO[bytes]] = field(default_factory=list)
    #: how this supervisor judges its children's exits
    rules: "ExitRules" = field(default_factory=lambda: ExitRules())
    #: environment a process's children get besides ``child_env()`` (its zenoh credentials)
    env_for: Callable[[str], dict[str, str]] = lambda process: {}
    #: when set, children that run ``python -P -m sim_vehicles|swarm_sitl`` are forked from it
    fork_server: ForkServer | None = None
    lost: list[str] = field(default_factory=list)  #: the lines of the exits ridden through

    def child(self, process: str) -> Child | None:
        """The live incarnation of ``process``, if any."""
        live = [c for c in self.children if c.process == process and not c.retired]
        return live[-1] if live else None

    def spawn(self, name: str, argv: list[str], must_finish: bool, process: str | None = None) -> Child:
        log_dir = self.run_dir / "logs"
        log_dir.mkdir(parents=True, exist_ok=True)
        log_path = log_dir / f"{name}.log"
        env = {
            **child_env(),
            PARENT_ENV: str(os.getpid()),
            "PYTHONUNBUFFERED": "1",
            **self.env_for(process or name),
        }
        proc: subprocess.Popen[bytes] | ForkedProcess
        prefix = module_argv("")[:-1]
        if (
            self.fork_server is not None
            and argv[: len(prefix)] == prefix
            and argv[len(prefix)] in ENTRY_MODULES
        ):
            try:
                proc = self.fork_server.spawn(argv[len(prefix)], argv[len(prefix) + 1 :], env, log_path)
            except ForkServerError as e:
                raise RunFailedError(f"{name}: {e}") from None
        else:
            log = open(log_path, "wb")  # noqa: SIM115  (closed in close())
            self._logs.append(log)
            proc = subprocess.Popen(
                argv,
                stdout=log,
                stderr=subprocess.STDOUT,
                stdin=subprocess.DEVNULL,
                env=env,
                start_new_session=True,
            )
        first = int(argv[argv.index("--resume-tick") + 1]) if "--resume-tick" in argv else 0
        child = Child(name, proc, log_path, must_finish, process or name, first_tick=first)
        self.children.append(child)
        return child

    def check(self) -> None:
        """Raise ``RunFailedError`` if a child failed, or a vehicle stopped while it was needed,
        or a child is stopped (SIGSTOP) that the plan did not stop: named first, since the others
        are only waiting on it."""
        now = time.monotonic()
        for c in self.children:
            if c.retired or c.proc.poll() is not None:
                continue
            if not c.stopped() or self.rules.planned_stop(c.process):
                c.stopped_since = math.inf
                continue
            c.stopped_since = min(c.stopped_since, now)
            if now - c.stopped_since > STOPPED_GRACE_S:
                raise RunFailedError(
                    f"{c.name} is stopped (SIGSTOP or a debugger) and no fault plan stopped it; "
                    "the others wait on it"
                )
        for c in self.children:
            if c.retired:
                continue
            code = c.proc.poll()
            if code is None:
                continue
            if code == 0 and c.must_finish and self.rules.completed(c):
                continue
            if self.rules.planned_exit(c, code):
                continue
            line = self.exit_line(c, code)
            if not self.rules.ride_through():
                raise RunFailedError(line)
            c.retired = True
            self.lost.append(line)
            self.rules.on_lost(c, code, line)

    def exit_line(self, c: Child, code: int) -> str:
        """One line: who exited, with what code, where it was, and why (its log's last line)."""
        why = getattr(c.proc, "error", "") or c.last_line()
        where = self.rules.last_tick(c)
        before = " before the run's end" if code == 0 else ""
        return (
            f"{c.name} exited with code {code}{before}"
            + (f" ({where})" if where else "")
            + (f": {why}" if why and code != 0 else "")
        )

    def finished(self) -> bool:
        return all(
            c.proc.poll() == 0 and self.rules.completed(c)
            for c in self.children
            if c.must_finish and not c.retired
        )

    def close(self) -> None:
        alive = [c for c in self.children if c.proc.poll() is None]
        for c in alive:
            with contextlib.suppress(ProcessLookupError):
                c.proc.send_signal(signal.SIGCONT)  # a stopped process takes SIGTERM only once it runs
                c.proc.send_signal(signal.SIGTERM)
        end = time.monotonic() + TERM_GRACE_S
        for c in alive:
            try:
                c.proc.wait(timeout=max(0.0, end - time.monotonic()))
            except subprocess.TimeoutExpired:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(c.proc.pid, signal.SIGKILL)
                c.proc.wait()
        for log in self._logs:
            log.close()
        self._logs.clear()
        if self.fork_server is not None:
            self.fork_server.close()
            self.fork_server = None
