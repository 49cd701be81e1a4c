"""Where ``falsify``'s plans fly: worker processes of this machine, or a Dask cluster's workers.

Each evaluator flies a batch of plans (of the space's items, ``space.plan_of``) in ``sim`` and
returns their robustness in the order asked, whichever worker ran what, so the study is the same
for a seed on any number of cores and on a cluster.
"""

import concurrent.futures
import concurrent.futures.process
import math
import multiprocessing
import signal
from typing import Any

from swarm_sitl.config.schema import SwarmConfig
from swarm_sitl.falsify.evaluate import evaluate
from swarm_sitl.falsify.space import expand

#: a robustness Optuna is told for a run with none (a follower lost): it takes no infinities
NO_ROBUSTNESS = -1e9


def fly(cfg: SwarmConfig, name: str, plan: dict[str, Any]) -> float:
    """A plan of the space's items (``space.plan_of``) flown in ``sim``: its robustness, as the
    study takes it (no infinities: ``NO_ROBUSTNESS`` where nothing was recorded, ``-NO_ROBUSTNESS``
    at most where it holds vacuously)."""
    r = evaluate(cfg, name, expand(plan, cfg))
    if math.isnan(r) or r == -math.inf:  # nothing recorded where the requirement looks: a violation
        return NO_ROBUSTNESS
    return min(r, -NO_ROBUSTNESS)


_WORKER: tuple[SwarmConfig, str] | None = None


def _init(cfg: SwarmConfig, name: str) -> None:
    """A worker's start: Ctrl-C at a terminal reaches every process of the group, and the search
    (its parent) is the one that stops; a worker finishes the plan it flies."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    global _WORKER
    _WORKER = (cfg, name)


def _fly(plan: dict[str, Any]) -> float:
    assert _WORKER is not None
    return fly(_WORKER[0], _WORKER[1], plan)


class Local:
    """Plans flown by ``jobs`` worker processes of this machine (spawned: nothing of this
    process's state but the config and requirement goes with them)."""

    def __init__(self, jobs: int, cfg: SwarmConfig, name: str):
        self.jobs, self.cfg, self.name = jobs, cfg, name
        self.ended = 0  #: evaluations that ended their worker (a law held in compiled code)
        self.pool = self._pool()

    def _pool(self) -> concurrent.futures.ProcessPoolExecutor:
        ctx = multiprocessing.get_context("spawn")
        return concurrent.futures.ProcessPoolExecutor(
            self.jobs, mp_context=ctx, initializer=_init, initargs=(self.cfg, self.name)
        )

    def _renew(self) -> None:
        """A new pool in place of a broken one."""
        self.pool.shutdown(cancel_futures=True)
        self.pool = self._pool()

    def map(self, plans: list[dict[str, Any]]) -> list[float]:
        """Their robustness. A plan whose run ended its worker process (a user's law held in
        compiled code past its guard, ``nodes.law_guard``: the process ends) is a violation
        (``NO_ROBUSTNESS``), found by flying the batch again one plan at a time in a new pool."""
        try:
            return list(self.pool.map(_fly, plans))
        except concurrent.futures.process.BrokenProcessPool:
            self._renew()
            if len(plans) == 1:  # the one that ended it
                self.ended += 1
                return [NO_ROBUSTNESS]
        out = []
        for plan in plans:
            try:
                out.append(self.pool.submit(_fly, plan).result())
            except concurrent.futures.process.BrokenProcessPool:
                self.ended += 1
                out.append(NO_ROBUSTNESS)
                self._renew()
        return out

    def close(self) -> None:
        self.pool.shutdown(cancel_futures=True)


class Dask:
    """Plans flown on a Dask cluster's workers, gathered in the order asked (the study is the same
    whichever worker ran what). A plug-in's file (a law, a link model) must be at the same path on
    the workers."""

    def __init__(self, address: str, cfg: SwarmConfig, name: str):
        from swarm_sitl.campaigns.runner import connect

        self.client = connect(address)
        self.cfg, self.name = cfg, name

    def map(self, plans: list[dict[str, Any]]) -> list[float]:
        futures = [self.client.submit(fly, self.cfg, self.name, p, pure=False) for p in plans]
        return [float(x) for x in self.client.gather(futures)]

    def close(self) -> None:
        self.client.close()
