"""Where ``falsify``'s plans fly: worker processes of this machine, or a Dask cluster's workers.

Each evaluator flies a batch of plans (of the space's items, ``space.plan_of``) in ``sim`` and
returns their robustness in the order asked, whichever worker ran what, so the study is the same
for a seed on any number of cores and on a cluster.

**What a worker takes** (``Shipment``): the config as YAML text with each plug-in file it names
(a law, a vehicle model, a link model) as bytes beside it (``rundir.plugins.pack``, as ``sweep``
ships a campaign's runs), and the files of the users' link models the space searches, never a
Python object: a plug-in's class lives in a module its worker imports from that file, wherever the
worker is. A plan naming a searched model by its file on this machine flies the shipped copy.

**A worker that fails is an error, never a robustness** (``WorkerError``: one line naming the
plan, the worker and its last line): a plan whose flight raised, a config the worker could not
load, a worker process that died. The one exception is the law's own guard (``nodes.law_guard``):
a user's law held in compiled code past ``run.tick_timeout_s`` ends its process on purpose, after
saying so, and that plan is a violation (``NO_ROBUSTNESS``), as a law that raises under it is; the
batch is flown again one plan at a time, each in a process of its own, to find which.
"""

import atexit
import concurrent.futures
import concurrent.futures.process
import hashlib
import json
import math
import multiprocessing
import os
import shutil
import signal
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from sim_vehicles.common.entry import one_line
from swarm_sitl.config.schema import SwarmConfig
from swarm_sitl.falsify.evaluate import evaluate
from swarm_sitl.falsify.space import flown_plan

#: a robustness Optuna is told for a run with none (a follower lost): it takes no infinities
NO_ROBUSTNESS = -1e9
STOPPED = ".stopped"  #: beside a worker's log: its law's guard ended it (the guard's line)


class WorkerError(RuntimeError):
    """A worker could not fly a plan (it raised, or its process died): one line naming the plan,
    the worker and the worker's last line. The search stops without a verdict."""


#: this process's unpacked shipments' directories, by digest (``Shipment.unpack``)
_UNPACKED: dict[str, Path] = {}


@dataclass(frozen=True)
class Shipment:
    """What a worker flies plans of: the config (YAML, its plug-ins named ``plugins/...``), the
    plug-ins' files, and the requirement's name."""

    config_yaml: str
    files: dict[str, bytes]
    name: str
    #: a searched user's link model: its entry as the space names it (a file of this machine)
    #: -> the shipped copy's, relative to the unpacked config (``plugins/NAME.py:Class``)
    models: dict[str, str] = field(default_factory=dict)

    @classmethod
    def of(cls, cfg: SwarmConfig, name: str, models: Sequence[str] = ()) -> "Shipment":
        """``cfg`` and its plug-ins, with the files of ``models`` (the space's users' link
        models, ``Space.user_models``) packed beside them, one copy per file."""
        from swarm_sitl.rundir.plugins import pack_with_models

        packed, files, copies = pack_with_models(cfg.data(), models)
        return cls(yaml.safe_dump(packed, sort_keys=False), files, name, copies)

    def plan_here(self, plan: dict[str, Any]) -> dict[str, Any]:
        """``plan`` with each searched user's model named by its copy in this process's unpacked
        shipment (``unpack``'s directory)."""
        if not self.models:
            return plan
        where = self._where()
        entries = []
        for f in plan["plan"]:
            m = f.get("model")
            if isinstance(m, dict) and m.get("entry") in self.models:
                f = {**f, "model": {**m, "entry": str(where / self.models[m["entry"]])}}
            entries.append(f)
        return {**plan, "plan": entries}

    def _where(self) -> Path:
        return _UNPACKED[self.digest]

    @property
    def digest(self) -> str:
        """What it is: the config's text and each plug-in file's bytes."""
        h = hashlib.sha256(self.config_yaml.encode())
        for rel in sorted(self.files):
            h.update(rel.encode() + b"\0" + self.files[rel])
        return h.hexdigest()

    def unpack(self, under: str | None = None) -> SwarmConfig:
        """The config, its plug-ins written beside it in a directory of this process's (one per
        shipment, kept for the process's life: a plug-in module stays importable). It is made in
        ``under`` (the search's own temporary directory, removed when the search ends, whichever
        way its workers ended), else in a temporary directory removed when this process exits
        (a Dask worker's)."""
        from swarm_sitl.config.load import load_config

        where = _UNPACKED.get(self.digest)
        if where is None:
            if under is not None:
                where = Path(under) / f"shipment-{os.getpid()}-{self.digest[:16]}"
            else:
                where = Path(tempfile.mkdtemp(prefix="swarm-sitl-shipment-"))
                atexit.register(shutil.rmtree, where, True)
            _UNPACKED[self.digest] = where
        for rel, body in self.files.items():
            (where / rel).parent.mkdir(parents=True, exist_ok=True)
            (where / rel).write_bytes(body)
        where.mkdir(parents=True, exist_ok=True)
        (where / "config.yaml").write_text(self.config_yaml)
        return load_config(where / "config.yaml")


def fly(cfg: SwarmConfig, name: str, plan: dict[str, Any], on_hard_stop: Any = None) -> float:
    """A plan of the space's items (``space.plan_of``) flown in ``sim``, with the config's own
    plan under it (``space.flown_plan``): its robustness, as the study takes it (no infinities:
    ``NO_ROBUSTNESS`` where nothing was recorded, ``-NO_ROBUSTNESS`` at most where it holds
    vacuously)."""
    r = evaluate(cfg, name, flown_plan(plan, cfg), on_hard_stop)
    if math.isnan(r) or r == -math.inf:  # nothing recorded where the requirement looks: a violation
        return NO_ROBUSTNESS
    return min(r, -NO_ROBUSTNESS)


def shown(plan: dict[str, Any]) -> str:
    """A plan in one line, for an error."""
    text = json.dumps(plan, sort_keys=True)
    return text if len(text) <= 300 else text[:297] + "..."


# -- a worker process's side --------------------------------------------------------------------
_WORKER: dict[str, Any] = {}


def _init(ship: Shipment, log_dir: str) -> None:
    """A worker's start: its stderr to its own log (the last line of a worker that dies is read
    from there), its config unpacked. Ctrl-C at a terminal reaches every process of the group, and
    the search (its parent) is the one that stops; a worker finishes the plan it flies. A config
    it cannot load is kept to be said with the first plan (an initializer that raises would only
    break the pool). Every other signal does what it does to a new process (a forked worker
    would otherwise keep the search's own handlers: SIGTERM noted by its ``_Stop``, not obeyed)."""
    for sig in signal.valid_signals():
        if callable(signal.getsignal(sig)):  # (a handler of the search's: Python set no other)
            signal.signal(sig, signal.SIG_DFL)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    log = Path(log_dir) / f"worker_{os.getpid()}.log"
    fd = os.open(log, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o600)
    os.dup2(fd, 2)
    os.close(fd)
    _WORKER.update(log=log, name=ship.name, cfg=None, error=None, ship=ship)
    try:
        _WORKER["cfg"] = ship.unpack(log_dir)
    except Exception as e:
        _WORKER["error"] = f"its config did not load: {one_line(e)}"


def _law_stopped(line: str, _recorded: Any) -> None:
    """The law's guard is about to end this process: say why beside the log, for the parent."""
    Path(str(_WORKER["log"]) + STOPPED).write_text(line + "\n")


def _fly(plan: dict[str, Any]) -> tuple[float | None, str]:
    """``(robustness, "")``, or ``(None, why)`` where the worker could not fly the plan."""
    if _WORKER.get("error"):
        return None, f"worker {os.getpid()}: {_WORKER['error']}"
    try:
        return fly(_WORKER["cfg"], _WORKER["name"], _WORKER["ship"].plan_here(plan), _law_stopped), ""
    except Exception as e:
        return None, f"worker {os.getpid()}: {one_line(e)}"


def _alone(ship: Shipment, log_dir: str, plan: dict[str, Any], conn: Any) -> None:
    """One plan in a process of its own (``Local._fly_alone``): the answer down ``conn``."""
    _init(ship, log_dir)
    conn.send(_fly(plan))
    conn.close()


def _last_line(log: Path) -> str:
    try:
        lines = [x for x in log.read_text(errors="replace").splitlines() if x.strip()]
    except OSError:
        return "(no output)"
    return lines[-1].strip()[:300] if lines else "(no output)"


def _start_method() -> str:
    """How a worker process starts: forked from this process where that is safe (one thread, no
    zenoh session: ``fork_server.can_fork_here``; a search opens none), so a worker begins with
    numpy, numba, the config's modules and the laws imported (about a second of CPU each, paid
    once); else spawned. Either way a worker flies only what the shipment says: ``_init`` unpacks
    the config from it, as a Dask worker does, and reads nothing else of this process's."""
    from swarm_sitl.running.fork_server import can_fork_here

    return "fork" if can_fork_here() else "spawn"


class Local:
    """Plans flown by ``jobs`` worker processes of this machine (``_start_method``)."""

    def __init__(self, jobs: int, cfg: SwarmConfig, name: str, models: Sequence[str] = ()):
        self.jobs = jobs
        self.ship = Shipment.of(cfg, name, models)
        self._logs = tempfile.TemporaryDirectory(prefix="swarm-sitl-falsify-")
        self.log_dir = self._logs.name
        self.ended = 0  #: evaluations that ended their worker (a law held in compiled code)
        self.pool = self._pool()

    def _pool(self) -> concurrent.futures.ProcessPoolExecutor:
        # (a forking pool starts every process at its first batch, before its own thread)
        ctx = multiprocessing.get_context(_start_method())
        return concurrent.futures.ProcessPoolExecutor(
            self.jobs, mp_context=ctx, initializer=_init, initargs=(self.ship, self.log_dir)
        )

    def map(self, plans: list[dict[str, Any]]) -> list[float]:
        """Their robustness (``WorkerError`` for a plan a worker could not fly). A batch whose
        pool broke (a worker process ended) is flown again one plan at a time, each alone."""
        try:
            answers = list(self.pool.map(_fly, plans))
        except concurrent.futures.process.BrokenProcessPool:
            self.pool.shutdown(cancel_futures=True)
            self.pool = self._pool()
            return [self._fly_alone(plan) for plan in plans]
        return [_robustness(plan, r, why) for plan, (r, why) in zip(plans, answers, strict=True)]

    def _fly_alone(self, plan: dict[str, Any]) -> float:
        """``plan`` in a process of its own: its robustness; ``NO_ROBUSTNESS`` if its law's guard
        ended it; ``WorkerError`` naming the process and its last line if it died otherwise."""
        ctx: Any = multiprocessing.get_context(_start_method())  # (a fork or spawn context)
        recv, send = ctx.Pipe(duplex=False)
        proc = ctx.Process(target=_alone, args=(self.ship, self.log_dir, plan, send), daemon=True)
        proc.start()
        send.close()
        try:
            answer = recv.recv()
        except EOFError:  # it died before it answered
            answer = None
        finally:
            recv.close()
        proc.join()
        if answer is not None:
            return _robustness(plan, *answer)
        log = Path(self.log_dir) / f"worker_{proc.pid}.log"
        stopped = Path(str(log) + STOPPED)
        if stopped.is_file():  # the law's guard ended it: the plan broke the law
            self.ended += 1
            return NO_ROBUSTNESS
        raise WorkerError(
            f"plan {shown(plan)}: worker {proc.pid} died (exit code {proc.exitcode}); "
            f"its last line: {_last_line(log)}"
        )

    def close(self) -> None:
        self.pool.shutdown(cancel_futures=True)
        self._logs.cleanup()


def _robustness(plan: dict[str, Any], r: float | None, why: str) -> float:
    if r is None:
        raise WorkerError(f"plan {shown(plan)}: {why}")
    return r


_SHIPPED: dict[str, SwarmConfig] = {}  #: a Dask worker's unpacked shipments, by digest


def fly_shipped(ship: Shipment, plan: dict[str, Any]) -> tuple[float | None, str]:
    """A Dask worker's task: ``plan`` flown on the shipment's config (unpacked once per worker
    process); ``(None, why)`` where it could not be."""
    try:
        cfg = _SHIPPED.get(ship.digest)
        if cfg is None:
            cfg = _SHIPPED[ship.digest] = ship.unpack()
        return fly(cfg, ship.name, ship.plan_here(plan)), ""
    except Exception as e:
        return None, f"Dask worker pid {os.getpid()}: {one_line(e)}"


class Dask:
    """Plans flown on a Dask cluster's workers, gathered in the order asked (the study is the same
    whichever worker ran what). Plug-in files, and the searched users' link models, are shipped with
    the config (``Shipment``)."""

    def __init__(self, address: str, cfg: SwarmConfig, name: str, models: Sequence[str] = ()):
        from swarm_sitl.campaigns.runner import connect

        self.client = connect(address)
        self.ship = Shipment.of(cfg, name, models)

    def map(self, plans: list[dict[str, Any]]) -> list[float]:
        futures = [self.client.submit(fly_shipped, self.ship, p, pure=False) for p in plans]
        try:
            answers = self.client.gather(futures)
        except Exception as e:  # a worker lost, a task killed: no robustness of ours
            raise WorkerError(f"a Dask worker failed: {one_line(e)}") from None
        return [_robustness(p, r, why) for p, (r, why) in zip(plans, answers, strict=True)]

    def close(self) -> None:
        self.client.close()
