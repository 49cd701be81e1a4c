"""Run a swarm from Python, with a fault plan, and get its results as objects.

For fault-injection tests in a user's own pytest suite::

    from swarm_sitl import Swarm

    def test_formation_holds_with_half_the_edge_lost(tmp_path):
        with Swarm("configs/paper.yaml", faults=[{"edge": [1, 4], "loss": 0.5}], seed=3,
                   out=tmp_path / "run") as swarm:
            result = swarm.run(duration_s=40)
        assert result.ok, result.failure
        assert result.max_formation_error_m(after_s=20) < 0.05

``Swarm`` runs the same processes as ``swarm-sitl run`` (lockstep unless ``realtime=True``) and
returns a ``SwarmResult``: the summary, each follower's series, the events and the per-edge
traffic, read back from the run directory. A run that fails (a process exits unexpectedly) does
not raise: ``result.failure`` names the process, so a test can assert on it. The package also
installs a pytest plugin with a ``swarm`` fixture (``swarm_sitl.pytest_plugin``).
"""

import json
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from swarm_sitl.config.load import load_config, parse_config, plan_data
from swarm_sitl.config.schema import SwarmConfig


@dataclass
class FollowerResult:
    """One follower's recorded series (``recording``: one row per control tick)."""

    id: int
    arrays: dict[str, np.ndarray]  #: every series of ``follower_<i>.npz``

    @property
    def t_s(self) -> np.ndarray:
        return self.arrays["t_s"]

    @property
    def formation_error_m(self) -> np.ndarray:
        """``|p - p_r - delta|`` per tick [m] (NaN where nothing was recorded)."""
        return np.linalg.norm(self.arrays["pos_err_m"], axis=1)

    def max_formation_error_m(self, after_s: float = 0.0, until_s: float = np.inf) -> float:
        """The largest formation error recorded in ``[after_s, until_s)`` [m] (NaN if none)."""
        t = self.t_s
        e = self.formation_error_m[(t >= after_s) & (t < until_s)]
        e = e[np.isfinite(e)]
        return float(e.max()) if e.size else float("nan")


@dataclass
class SwarmResult:
    run_dir: Path
    summary: dict[str, Any]
    followers: dict[int, FollowerResult]
    events: list[dict[str, Any]]
    failure: str | None  #: one line naming the process that failed, or None
    interrupted: bool
    bound_failures: list[str]  #: followers past ``run.max_formation_error_m``

    @property
    def ok(self) -> bool:
        """The run completed, and held its bound if it has one."""
        return self.failure is None and not self.interrupted and not self.bound_failures

    @property
    def links(self) -> dict[str, dict[str, Any]]:
        """Per edge ``"src->dst"``: received, delivered, lost, corrupt, delayed, duplicated."""
        return dict(self.summary.get("links", {}))

    def max_formation_error_m(self, after_s: float = 0.0, followers: list[int] | None = None) -> float:
        """The largest formation error of ``followers`` (default: all) from ``after_s`` on [m]."""
        ids = sorted(self.followers) if followers is None else followers
        return max(self.followers[i].max_formation_error_m(after_s) for i in ids)

    def events_of(self, kind: str) -> list[dict[str, Any]]:
        return [e for e in self.events if e["kind"] == kind]


class Swarm:
    """A swarm to run: a config (path or ``SwarmConfig``), a fault plan, a clock.

    ``faults``: a list of plan entries, a ``{seed, plan}`` mapping or a YAML file; ``seed``: the
    run's seed, of every random stream whose section does not pin its own (``config.seeds``).
    ``out``: the run directory (default: a temporary one, removed when the
    ``with`` block ends unless ``keep=True``)."""

    def __init__(
        self,
        config: str | Path | SwarmConfig,
        *,
        faults: Any = None,
        seed: int | None = None,
        realtime: bool = False,
        out: str | Path | None = None,
        keep: bool = False,
        **run: Any,
    ):
        cfg = config if isinstance(config, SwarmConfig) else load_config(config)
        data = cfg.data()
        plan = plan_data(faults)
        if plan is not None:
            data["faults"] = {**data["faults"], **plan}
        if seed is not None:  # the run's seed: every stream whose section does not pin its own
            data["seed"] = seed
        if run:  # run.* settings, e.g. max_formation_error_m=0.05
            data["run"] = {**data["run"], **run}
        self.config = parse_config(data, "Swarm")
        self.realtime = realtime
        self._tmp: Path | None = None
        if out is None:
            self._tmp = Path(tempfile.mkdtemp(prefix=f"swarm-{self.config.name}-"))
        self.out = Path(out) if out is not None else self._tmp
        self.keep = keep
        self._runs = 0

    def __enter__(self) -> "Swarm":
        return self

    def __exit__(self, *exc: object) -> None:
        if self._tmp is not None and not self.keep:
            shutil.rmtree(self._tmp, ignore_errors=True)

    def run(self, duration_s: float | None = None) -> SwarmResult:
        """Run the swarm (``duration_s`` overrides the config's) and return what it recorded;
        ``OSError`` (one line, saying how to rebuild it) if its run directory could not be written."""
        from swarm_sitl.running.run import RunRequest, record_run

        cfg = self.config
        if duration_s is not None:
            cfg = parse_config({**cfg.data(), "duration_s": float(duration_s)}, "duration_s")
        assert self.out is not None
        self._runs += 1
        run_dir = self.out if self._runs == 1 else self.out.with_name(f"{self.out.name}-{self._runs}")
        outcome = record_run(RunRequest(cfg, run_dir, lockstep=not self.realtime))
        if outcome.lost_outputs is not None:  # a full disk: nothing to read back
            raise OSError(outcome.lost_outputs)
        return load_result(run_dir, outcome.failure, outcome.interrupted, outcome.bound_failures)


def load_result(
    run_dir: str | Path,
    failure: str | None = None,
    interrupted: bool = False,
    bound_failures: list[str] | None = None,
) -> SwarmResult:
    """A run directory's results as objects."""
    from swarm_sitl.rundir.load import load_run

    d = Path(run_dir)
    rec = load_run(d)
    events: list[dict[str, Any]] = []
    if (d / "events.jsonl").is_file():
        events = [json.loads(line) for line in (d / "events.jsonl").read_text().splitlines() if line]
    summary = json.loads((d / "summary.json").read_text())
    followers = {i: FollowerResult(i, a) for i, a in rec.followers.items()}
    return SwarmResult(d, summary, followers, events, failure, interrupted, list(bound_failures or []))
