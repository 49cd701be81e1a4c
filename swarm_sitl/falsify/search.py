"""``falsify``: the search for the cheapest fault plan that breaks a requirement, and its outputs.

The search is an Optuna study (kept in ``OUT/study.db``, so a run that stopped resumes where it
was) with two objectives to minimise, the plan's cost and the requirement's robustness, and Optuna's
multi-objective TPE sampler seeded by ``seed``. Why Optuna: its samplers take a space of mixed
parameters (an entry on or off, a loss, a window's start) with conditional ones, keep a Pareto
front of both objectives, and store a study a second run takes up; CMA-ES takes neither the
categorical nor the conditional parameters. Trials are asked for in batches of ``batch``, flown
in ``sim`` by ``jobs`` worker processes or on a Dask cluster (``workers``), and told in order:
the study, and so ``front.csv``, is the same for a seed whatever the cores or how fast each run was.

A config's own ``faults:`` is flown under every searched plan (``space.flown_plan``): the search
looks for what breaks the requirement on top of it, and the counterexample file holds both. A
worker that cannot fly a plan (``workers.WorkerError``) ends the search with no verdict.

Then the cheapest violating plan is shrunk (``shrink``), written as a plan file
(``counterexamples/NAME.yaml``, which ``swarm-sitl run CONFIG --faults`` replays) and confirmed as
a lockstep run of processes: its robustness there must be the same, bit for bit. Outputs in
``OUT`` (``outputs``): ``front.csv`` (the Pareto front of cost and robustness over every evaluation),
``evaluations.csv``, ``robustness_cost.png``, ``edges.png`` (the graph, each edge with its share
of the violating plans), ``report.md``.
"""

import math
import multiprocessing
import signal
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import yaml

from swarm_sitl.config.load import load_config, section_file, with_duration, with_spec
from swarm_sitl.config.schema import SwarmConfig
from swarm_sitl.falsify.evaluate import requirement_config
from swarm_sitl.falsify.outputs import (
    Found,
    chart,
    confirm_in_lockstep,
    edge_picture,
    failed_report,
    front,
    order,
    report,
    write_csv,
)
from swarm_sitl.falsify.shrink import shrink
from swarm_sitl.falsify.space import (
    COSTS,
    Space,
    SpaceEntry,
    cost,
    default_space,
    entries_relative_to,
    expand,
    flown_plan,
    items,
    plan_of,
)
from swarm_sitl.falsify.workers import Dask, Local, WorkerError


class FalsifyError(ValueError):
    """Bad input, found before anything is flown: one line."""


class _InterruptedError(Exception):
    """The search was asked to stop (``_Stop``)."""


class _Stop:
    """Ctrl-C (SIGINT) or SIGTERM during a search, noted: the search stops before its next batch
    and writes what it found. (A KeyboardInterrupt raised wherever the signal lands can be
    swallowed there: in a library's garbage-collection callback, a search once went on.)"""

    def __init__(self) -> None:
        self.signum = 0
        self._saved: dict[int, Any] = {}
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                self._saved[sig] = signal.signal(sig, self._note)

    def _note(self, signum: int, frame: Any) -> None:
        self.signum = signum

    def close(self) -> None:
        for sig, handler in self._saved.items():
            signal.signal(sig, handler)


def _studies(db: Path, seed: int, batch: int) -> tuple[Any, Any]:
    """The search's study, in memory, and its record on disk (``db``, which a search of the same
    ``OUT`` takes up: its trials are the new study's first). The sampler works on the one in
    memory: on Optuna's SQLite storage each suggested value was a transaction of its own, and
    every suggestion read the trials back (measured, with the flights stood in for: a search of
    budget 8, 4.4 CPU s on disk and 0.8 in memory; of budget 40, 17 CPU s on disk even with
    SQLite's write-ahead log, 2.5 in memory)."""
    import optuna

    directions = [optuna.study.StudyDirection.MINIMIZE] * 2
    record = optuna.create_study(
        study_name="falsify", storage=f"sqlite:///{db}", load_if_exists=True, directions=directions
    )
    study = optuna.create_study(
        directions=directions, sampler=optuna.samplers.TPESampler(seed=seed, n_startup_trials=max(4, batch))
    )
    study.add_trials(record.get_trials(deepcopy=False, states=[optuna.trial.TrialState.COMPLETE]))
    return study, record


def _rows(study: Any) -> list[dict[str, Any]]:
    """Every evaluation the study holds: its cost, robustness and plan (of the space's items)."""
    import optuna

    return [
        {"cost": t.values[0], "robustness": t.values[1], "plan": t.user_attrs["plan"]}
        for t in study.get_trials(states=[optuna.trial.TrialState.COMPLETE])
    ]


def load_inputs(
    config: str | Path,
    space: str | Path | None,
    spec: str | Path | None,
    requirement: str | None,
    bound_m: float | None,
    duration_s: float | None,
    budget: int,
    cost_how: str,
) -> tuple[SwarmConfig, Space, str]:
    """Everything checked before anything is flown: ``FalsifyError`` (one line) if not."""
    if budget < 1:
        raise FalsifyError(f"--budget {budget}: at least one evaluation")
    if cost_how not in COSTS:
        raise FalsifyError(f"--cost {cost_how}: one of {', '.join(COSTS)}")
    try:
        cfg = with_spec(with_duration(load_config(config), duration_s), spec)
        if spec is not None and not cfg.spec:
            raise FalsifyError(f"{spec}: the spec names no requirement")
        cfg, name = requirement_config(cfg, requirement, bound_m)
        if space is None:
            sp = default_space(cfg)
        else:
            data = section_file(Path(space), "space")
            if isinstance(data, list):
                data = {"entries": data}
            sp = Space.model_validate(entries_relative_to(data, Path(space).parent))
        sp.check_against(cfg)
    except FalsifyError:
        raise
    except ValueError as e:  # pydantic's errors and ours, made one line
        errors = getattr(e, "errors", None)
        if callable(errors):
            first = errors()[0]
            loc = [str(x) for x in first["loc"]]
            if first["type"] == "extra_forbidden":
                keys = ", ".join(SpaceEntry.model_fields) if "entries" in loc else "seeds, entries"
                what = f"{loc[-1]} is not a key here (known: {keys})"
                loc = loc[:-1]
            else:
                what = first["msg"].removeprefix("Value error, ")
            raise FalsifyError(f"{space}: {'.'.join(loc) or 'the file'}: {what}") from None
        raise FalsifyError(f"{space}: {str(e).splitlines()[0]}") from None
    return cfg, sp, name


def falsify(
    config: str | Path,
    out: str | Path,
    space: str | Path | None = None,
    spec: str | Path | None = None,
    requirement: str | None = None,
    bound_m: float | None = None,
    duration_s: float | None = None,
    budget: int = 60,
    cost_how: str = "severity",
    seed: int = 0,
    jobs: int | None = None,
    batch: int = 4,
    confirm: bool = True,
    scheduler: str | None = None,
    say: Callable[[str], None] = print,
) -> Found:
    """Search ``space`` for the cheapest plan that breaks the requirement (module docstring)."""
    import optuna  # (0.5 s to import: only here)

    cfg, sp, name = load_inputs(config, space, spec, requirement, bound_m, duration_s, budget, cost_how)
    its = items(sp, cfg)
    out = Path(out)
    (out / "counterexamples").mkdir(parents=True, exist_ok=True)
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    study, record = _studies(out / "study.db", seed, batch)
    jobs = jobs or min(batch, multiprocessing.cpu_count())
    t0 = time.monotonic()
    flown = 0
    found = Found(name, 0, base_entries=len(cfg.faults.plan))
    rows: list[dict[str, Any]] = []
    models = sp.user_models()  # (shipped to the workers: a cluster's need not have their files)
    ev: Local | Dask = (
        Local(jobs, cfg, name, models) if scheduler is None else Dask(scheduler, cfg, name, models)
    )
    stop = _Stop()

    def fly_all(plans: list[dict[str, Any]]) -> list[float]:
        if stop.signum:
            raise _InterruptedError
        return ev.map(plans)

    try:
        try:
            # the requirement must hold without a searched fault (the config's own plan flies
            # under every plan: ``space.flown_plan``), or there is nothing to search for
            found.baseline = fly_all([{"seed": sp.seeds[0], "plan": []}])[0]
            flown += 1
            if found.baseline < 0:
                without = "the config's own plan alone" if cfg.faults.plan else "any fault"
                say(f"falsify: {name} fails with {without} (robustness {found.baseline:.4g})")
                budget = 0
            done = len(study.get_trials(states=[optuna.trial.TrialState.COMPLETE]))
            while done < budget:
                trials = [study.ask() for _ in range(min(batch, budget - done))]
                plans = [plan_of(t, sp, its, cfg) for t in trials]
                robs = fly_all(plans)
                told = []
                for t, plan, r in zip(trials, plans, robs, strict=True):
                    t.set_user_attr("plan", plan)
                    told.append(study.tell(t, [cost(expand(plan, cfg), cfg, cost_how), r]))
                record.add_trials(told)  # (flown and told: kept for a search that takes it up)
                done += len(trials)
                flown += len(trials)
                say(f"falsify: {done}/{budget} evaluations, {sum(r < 0 for r in robs)} of the last violating")
            rows = _rows(study)
            violating = sorted((r for r in rows if r["robustness"] < 0), key=order)
            if violating and found.baseline >= 0:

                def ranges(f: dict[str, Any]) -> list[tuple[tuple[str, ...], tuple[float, float]]]:
                    return next((e.searched(f) for e in sp.entries if e.makes(f)), [])

                held = [r["plan"] for r in rows if r["robustness"] >= 0]
                plan, r, spent = shrink(
                    violating[0]["plan"], fly_all, ranges, cfg.control_dt_s, sp.seeds, held, width=jobs
                )
                flown += spent
                rows.append({"cost": cost(expand(plan, cfg), cfg, cost_how), "robustness": r, "plan": plan})
                found.plan, found.robustness, found.cost = flown_plan(plan, cfg), r, rows[-1]["cost"]
            if stop.signum:
                raise _InterruptedError
        except (KeyboardInterrupt, _InterruptedError):
            say("falsify: interrupted; what was found is kept")
            found.interrupted = True
            found.signum = stop.signum or signal.SIGINT
            rows = _rows(study)
        except WorkerError as e:  # no verdict: the swarm was not what failed
            failed_report(out / "report.md", cfg, name, str(e))
            raise
    finally:
        stop.close()
        ev.close()
    wall = time.monotonic() - t0
    found.evaluations = flown
    found.per_minute = flown / wall * 60 if wall > 0 else math.nan
    found.front = front(rows)
    write_csv(out / "front.csv", found.front, cfg)
    write_csv(out / "evaluations.csv", sorted(rows, key=order), cfg)
    if found.plan is not None:
        path = out / "counterexamples" / f"{name}.yaml"
        path.write_text(yaml.safe_dump(found.plan, sort_keys=False))
        found.counterexample = path
        if confirm and not found.interrupted:
            found.confirmed = confirm_in_lockstep(cfg, name, path, out / "confirm" / name, found.robustness)
    chart(out / "robustness_cost.png", rows, found)
    edge_picture(out / "edges.png", rows, cfg)
    report(out / "report.md", cfg, name, found, wall)
    return found


def assert_no_counterexample(
    config: str | Path,
    out: str | Path,
    max_cost: float,
    space: str | Path | None = None,
    spec: str | Path | None = None,
    requirement: str | None = None,
    bound_m: float | None = None,
    budget: int = 40,
    seed: int = 0,
    duration_s: float | None = None,
    jobs: int | None = None,
) -> Found:
    """For a test: search ``space`` and fail (``AssertionError``) if a plan of cost at most
    ``max_cost`` breaks the requirement, naming the counterexample's file (a plan
    ``swarm-sitl run CONFIG --faults FILE`` replays)."""
    found = falsify(
        config,
        out,
        space=space,
        spec=spec,
        requirement=requirement,
        bound_m=bound_m,
        budget=budget,
        seed=seed,
        duration_s=duration_s,
        jobs=jobs,
        confirm=False,
        say=lambda line: None,
    )
    if found.plan is not None and found.cost <= max_cost:
        raise AssertionError(
            f"a plan of cost {found.cost:.4g} (<= {max_cost:g}) breaks requirement {found.requirement}: "
            f"robustness {found.robustness:.4g}; the plan is {found.counterexample} "
            f"(swarm-sitl run {config} --faults {found.counterexample})"
        )
    return found
