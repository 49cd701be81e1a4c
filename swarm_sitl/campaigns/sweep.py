"""A campaign: every point of a grid of config or fault-plan values, times several seeds, each a
lockstep run whose metrics are one row of ``OUT/table.csv``; the error charts; the breaking point,
refined by bisection when asked. Resumable: the rows already in the table are not run again.

``swarm_sitl.sweep(...)`` is this from Python (a notebook, a test); ``swarm-sitl sweep`` the CLI.
"""

import hashlib
import json
import math
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from sim_vehicles.common.entry import absolute_entry
from swarm_sitl.campaigns import charts
from swarm_sitl.campaigns.breaking import breaking_point, toward
from swarm_sitl.campaigns.grid import (
    SweepSpecError,
    check_key,
    grid,
    parse_values,
    parse_vary,
    point_data,
    user_models,
)
from swarm_sitl.campaigns.runner import Task, connect, default_jobs, run_dask, run_local
from swarm_sitl.campaigns.table import SPEC, TABLE, TableWriter, read_rows, row_key, write_sorted
from swarm_sitl.config.load import ConfigError, load_config, parse_config, plan_data, with_spec
from swarm_sitl.config.schema import SwarmConfig
from swarm_sitl.rundir.plugins import pack_with_models

CAMPAIGN = "campaign.json"
POINTS = "points"


@dataclass
class Campaign:
    """A campaign's results: its table's rows (dicts: the swept keys, ``seed``, ``refined``, the
    metrics of ``point.METRICS``, ``config``) and where they are."""

    out: Path
    keys: list[str]
    bound_m: float
    rows: list[dict[str, Any]] = field(default_factory=list)
    figures: list[Path] = field(default_factory=list)
    interrupted: KeyboardInterrupt | None = None  #: what ended the campaign early (Ctrl-C, a signal)

    @property
    def table(self) -> Path:
        return self.out / TABLE

    @property
    def varied(self) -> list[str]:
        """The keys that take more than one value in the table (one value holds a key fixed)."""
        return [k for k in self.keys if len({float(r[k]) for r in self.rows}) > 1]

    def breaking_point(self, key: str | None = None) -> tuple[float | None, float | None]:
        """``(held, broke)`` for ``key`` (default: the only varied key): see ``breaking.breaking_point``."""
        return breaking_point(self.rows, key or (self.varied or self.keys)[0])


def _vary(vary: Any) -> list[tuple[str, list[float]]]:
    if isinstance(vary, dict):
        items = []
        for k, v in vary.items():
            values = parse_values(k, v) if isinstance(v, str) else sorted({float(x) for x in v})
            if not values:
                raise SweepSpecError(f"sweep {k}: no values")
            items.append((str(k), values))
    else:
        items = [parse_vary(s) for s in vary]
    if not items:
        raise SweepSpecError("sweep: nothing to vary (give KEY=VALUES, e.g. link.loss=0:0.9:0.1)")
    keys = [k for k, _ in items]
    if len(set(keys)) != len(keys):
        raise SweepSpecError(f"sweep: a key is given twice ({', '.join(keys)})")
    for k in keys:
        check_key(k)
    return items


def _seeds(seeds: int | Sequence[int]) -> list[int]:
    out = list(range(seeds)) if isinstance(seeds, int) else [int(s) for s in seeds]
    if not out or any(s < 0 for s in out):
        raise SweepSpecError(f"sweep: seeds must be a positive count or non-negative integers, got {seeds!r}")
    return sorted(set(out))


def _name(point: dict[str, float], seed: int) -> str:
    parts = [f"{k}-{v:.12g}" for k, v in point.items()] + [f"seed-{seed}"]
    return re.sub(r"[^A-Za-z0-9._-]", "_", "_".join(parts))


def _base(
    config: str | Path | SwarmConfig, faults: Any, duration_s: float | None, bound_m: float | None
) -> dict:
    cfg = config if isinstance(config, SwarmConfig) else load_config(config)
    data = cfg.data()
    plan = plan_data(faults)
    if plan is not None:
        data["faults"] = {**data["faults"], **plan}
    if duration_s is not None:
        data["duration_s"] = float(duration_s)
    if bound_m is not None:
        data["run"]["max_formation_error_m"] = float(bound_m)
    parse_config(data, "sweep")  # the base itself, before any point
    if not data["run"].get("max_formation_error_m"):
        raise SweepSpecError(
            "sweep: a campaign needs a pass/fail bound: run.max_formation_error_m in the config, or --bound"
        )
    return data


def _check_points(base: dict, points: list[dict[str, float]], seed: int) -> None:
    """Every point's config is valid (each value in its range) and settles before its run ends
    (``run.settle_s`` and ``duration_s`` as the point has them), before anything runs."""
    seen: set[tuple[str, float]] = set()
    for p in points:
        data = point_data(base, p, seed)
        end_s, settle_s = data["duration_s"], data["run"]["settle_s"]  # (either may be varied)
        if end_s <= settle_s:
            at = ", ".join(f"{k}={v:g}" for k, v in p.items())
            raise SweepSpecError(
                f"sweep {at}: the run ends at {end_s:g} s, before run.settle_s ({settle_s:g} s) from "
                "which the bound is judged; lengthen it (--duration) or settle sooner"
            )
        fresh = [(k, v) for k, v in p.items() if (k, v) not in seen]
        if not fresh:
            continue
        try:
            parse_config(data, "sweep")
        except ConfigError as e:
            values = ", ".join(f"{k}={v:g}" for k, v in p.items())
            raise SweepSpecError(f"sweep {values}: {e}") from None
        seen.update(fresh)


def _open_campaign(out: Path, spec: dict[str, Any]) -> None:
    """``out`` holds this campaign (or nothing yet); another campaign's directory is refused."""
    if out.exists() and not out.is_dir():
        raise SweepSpecError(f"--out {out}: exists and is not a directory")
    path = out / CAMPAIGN
    if path.is_file():
        try:
            old = json.loads(path.read_text())
        except (OSError, ValueError) as e:
            raise SweepSpecError(f"{path}: cannot read it ({e})") from None
        if old.get("base_sha256") != spec["base_sha256"] or old.get("keys") != spec["keys"]:
            raise SweepSpecError(
                f"--out {out} holds another campaign (its config, plan or swept keys differ); "
                "give another --out"
            )
        spec = {**spec, "values": _merge_values(old.get("values", {}), spec["values"])}
        spec["seeds"] = sorted(set(old.get("seeds", [])) | set(spec["seeds"]))
    try:
        (out / POINTS).mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(CAMPAIGN + ".tmp")
        tmp.write_text(json.dumps(spec, indent=1) + "\n")
        tmp.replace(path)
    except OSError as e:
        raise SweepSpecError(f"--out {out}: cannot write there ({e.strerror or e})") from None


@dataclass(frozen=True)
class Shipment:
    """What every run of a campaign takes: the base (its plug-ins named ``plugins/...``), the
    plug-ins' files, the wall budget of a run, and the entry each run names a swept link model of
    the user's by (``link.ENTRY.PARAM``: its copy, shipped as the base's are)."""

    base: dict[str, Any]
    files: dict[str, bytes]
    timeout_s: float
    models: dict[str, str] = field(default_factory=dict)


def _shipment(base: dict[str, Any], keys: list[str], point_timeout_s: float | None) -> Shipment:
    """The base's plug-ins and the swept users' link models packed at once (``rundir.plugins``:
    one copy per file, two files of one name told apart)."""
    swept = user_models(keys)
    here = {m: absolute_entry(m, Path.cwd()) for m in swept}
    packed, files, copies = pack_with_models(base, list(dict.fromkeys(here.values())))
    models = {m: copies[here[m]] for m in swept}
    return Shipment(packed, files, point_timeout_s or default_budget_s(base), models)


def default_budget_s(base: dict[str, Any]) -> float:
    """A run's wall budget unless ``--point-timeout`` says: its start (``run.start_timeout_s``),
    ten times its simulated duration (a lockstep run of the paper's swarm flies about twice as
    fast as real time on two busy cores), and a minute of teardown."""
    return float(base["run"]["start_timeout_s"]) + 10.0 * float(base["duration_s"]) + 60.0


def _base_sha256(packed: dict, files: dict[str, bytes]) -> str:
    """The campaign's identity: what its runs fly, and the bytes of each plug-in file."""
    h = hashlib.sha256(_flown(packed).encode())
    for rel in sorted(files):
        h.update(f"\n{rel} {hashlib.sha256(files[rel]).hexdigest()}".encode())
    return h.hexdigest()


def _flown(base: dict) -> str:
    """What the runs fly: the base config but its bound, which only judges them (a campaign run
    again with another ``--bound`` judges its rows again, flying none of them)."""
    data = {**base, "run": {k: v for k, v in base["run"].items() if k != "max_formation_error_m"}}
    return yaml.safe_dump(data, sort_keys=True)


def judge(rows: list[dict[str, Any]], bound_m: float) -> None:
    """Each row's ``passed`` against ``bound_m``: it completed and its largest error after settling
    is within the bound."""
    for r in rows:
        err = float(r["max_error_m"])
        held = all(float(v) >= 0 for k, v in r.items() if k.startswith(SPEC))  # NaN: not held
        r["passed"] = int(r["failure"] == "" and err == err and err <= bound_m and held)


def _merge_values(old: dict[str, list[float]], new: dict[str, list[float]]) -> dict[str, list[float]]:
    return {k: sorted(set(old.get(k, [])) | set(v)) for k, v in new.items()}


def sweep(
    config: str | Path | SwarmConfig,
    vary: dict[str, Any] | Iterable[str],
    *,
    out: str | Path,
    seeds: int | Sequence[int] = 3,
    faults: Any = None,
    duration_s: float | None = None,
    bound_m: float | None = None,
    jobs: int | None = None,
    scheduler: str | None = None,
    scheduler_timeout_s: float = 10.0,
    refine: int = 0,
    progress: bool = False,
    keep_runs: bool = False,
    point_timeout_s: float | None = None,
    spec: str | Path | None = None,
) -> Campaign:
    """Run a campaign and return its table (``Campaign.rows``).

    ``vary``: ``{"link.loss": "0:0.9:0.1", "gains.k_p": [1, 2]}`` or ``["link.loss=0:0.9:0.1"]``
    (keys: ``grid``'s docstring). ``seeds``: a count (0..n-1) or the seeds. ``faults``: a base
    plan under the swept entries. ``bound_m``: the pass/fail bound (default: the config's
    ``run.max_formation_error_m``). ``jobs``: runs at once here (default: one per core);
    ``scheduler``: a Dask scheduler's address instead (reached
    within ``scheduler_timeout_s``). ``refine``: bisection steps between the
    last value that holds and the first that breaks (one swept key). ``point_timeout_s``: each
    run's wall budget, past which its row fails ``timed out`` (default ``default_budget_s``).
    The plug-ins the config names go with every run as their files (``rundir.plugins.pack``), to a
    Dask worker too, and are kept in ``OUT/points/plugins/``. ``spec``: a file of requirements in
    place of the config's (``docs/specs.md``): each is a column of the table (its robustness), and
    a run passes only if every one holds."""
    items = _vary(vary)
    keys = [k for k, _ in items]
    seed_list = _seeds(seeds)
    varied = [k for k, v in items if len(v) > 1] or keys[:1]
    fixed = {k: v[0] for k, v in items if k not in varied}  # keys held at one value
    if refine and len(varied) != 1:
        raise SweepSpecError(
            "sweep: --refine bisects one varied key (others may hold one value); this campaign varies "
            + ", ".join(varied)
        )
    if jobs is not None and jobs < 1:
        raise SweepSpecError(f"sweep: --jobs must be at least 1, got {jobs}")
    if point_timeout_s is not None and not 0 < point_timeout_s < math.inf:
        raise SweepSpecError(f"sweep: --point-timeout must be a number of seconds > 0, got {point_timeout_s}")
    source = config
    if spec is not None:  # requirements in place of the config's
        config = with_spec(config if isinstance(config, SwarmConfig) else load_config(config), spec)
    base = _base(config, faults, duration_s, bound_m)
    bound = float(base["run"]["max_formation_error_m"])
    requirements = [r["name"] for r in base.get("spec", [])]  #: a column each: its robustness
    points = grid(items)
    _check_points(base, points, seed_list[0])
    out = Path(out)
    ship = _shipment(base, keys, point_timeout_s)
    packed, files = ship.base, ship.files
    base_text = yaml.safe_dump(packed, sort_keys=True)
    identity = {
        "config": str(source) if not isinstance(source, SwarmConfig) else source.name,
        "keys": keys,
        "values": {k: v for k, v in items},
        "seeds": seed_list,
        "bound_m": bound,
        "duration_s": base["duration_s"],
        "base_sha256": _base_sha256(packed, files),
    }
    client = connect(scheduler, scheduler_timeout_s) if scheduler else None  # before anything is written
    try:
        _open_campaign(out, identity)
        (out / "base.yaml").write_text(base_text)
        for rel, body in files.items():  # beside the points that name them
            (out / POINTS / rel).parent.mkdir(parents=True, exist_ok=True)
            (out / POINTS / rel).write_bytes(body)
    except BaseException:
        if client is not None:
            client.close()
        raise
    campaign = Campaign(out, keys, bound, read_rows(out / TABLE, keys))
    judge(campaign.rows, bound)
    writer = TableWriter(out / TABLE, keys, requirements)
    try:
        _run(campaign, ship, points, seed_list, 0, writer, client, jobs, progress, keep_runs)
        # the bisection from the grid's own values, each step's midpoint added: run again, the
        # same command takes the same steps (their rows are in the table) and flies nothing
        key = varied[0]
        values = {round(v, 12) for v in dict(items)[key]}
        for step in range(refine):
            so_far = [r for r in campaign.rows if round(r[key], 12) in values]
            held, broke = breaking_point(so_far, key)
            if held is None or broke is None:
                break
            mid = round((held + broke) / 2, 12)
            if mid in (held, broke):
                break
            mids = [{**fixed, key: mid}]
            _check_points(base, mids, seed_list[0])
            values.add(mid)
            _run(campaign, ship, mids, seed_list, step + 1, writer, client, jobs, progress, keep_runs)
    except KeyboardInterrupt as e:
        campaign.interrupted = e
    finally:
        writer.close()
        if client is not None:
            client.close()
    write_sorted(out / TABLE, keys, campaign.rows, requirements)
    campaign.rows = read_rows(out / TABLE, keys)
    if not campaign.interrupted and campaign.rows:
        campaign.figures = draw(campaign)
    return campaign


def _run(
    campaign: Campaign,
    ship: "Shipment",
    points: list[dict[str, float]],
    seeds: list[int],
    refined: int,
    writer: TableWriter,
    client: Any,
    jobs: int | None,
    progress: bool,
    keep_runs: bool,
) -> None:
    from tqdm import tqdm

    keys = campaign.keys
    done = {row_key(keys, r) for r in campaign.rows}
    tasks: list[Task] = []
    by_key: dict[tuple[Any, ...], dict[str, Any]] = {}
    for p in points:
        for s in seeds:
            row = {**p, "seed": s}
            key = row_key(keys, row)
            name = _name(p, s)
            text = yaml.safe_dump(point_data(ship.base, p, s, ship.models), sort_keys=False)
            (campaign.out / POINTS / f"{name}.yaml").write_text(text)  # a row's config, run or not
            if key in done:
                continue
            keep = str(campaign.out / "runs" / name) if keep_runs else None
            tasks.append(Task(key, name, text, keep, ship.files, ship.timeout_s))
            by_key[key] = {**row, "refined": int(refined > 0), "config": f"{POINTS}/{name}.yaml"}
    if not tasks:
        return
    runs = run_dask(tasks, client) if client is not None else run_local(tasks, jobs or default_jobs())
    with tqdm(total=len(tasks), unit="run", disable=not progress, desc=f"sweep {', '.join(keys)}") as bar:
        for task, metrics in runs:
            row = {**by_key[task.key], **metrics}
            judge([row], campaign.bound_m)
            # in memory first: an interrupt (Ctrl-C, SIGTERM) just after the row reaches the disk
            # must not lose it when the table is written again sorted from memory (``sweep``)
            campaign.rows.append(row)
            writer.add(row)
            bar.update(1)


def draw(campaign: Campaign) -> list[Path]:
    """The campaign's figures in its directory."""
    rows, keys, out = campaign.rows, campaign.keys, campaign.out
    title = out.name
    figs = []
    varied = campaign.varied
    if len(varied) == 2:
        figs.append(charts.heat_map(rows, varied, campaign.bound_m, out / "heat_map.png", title))
    for k in keys:
        if len(keys) == 1 or k in varied:
            figs.append(charts.error_chart(rows, k, campaign.bound_m, out / f"error_vs_{k}.png", title))
    return figs


def summary_lines(c: Campaign) -> list[str]:
    """What the CLI prints at the end: runs, passes, the breaking point."""
    n = len(c.rows)
    passed = sum(int(r["passed"]) for r in c.rows)
    lines = [f"{n} runs in {c.table} ({passed} held the bound of {c.bound_m:g} m)"]
    if len(c.keys) == 1 or len(c.varied) == 1:
        held, broke = c.breaking_point()
        k = (c.varied or c.keys)[0]
        way = toward(k)
        if held is None and broke is None:  # (no run finished: an interrupted campaign's first)
            lines.append(f"breaking point: no run of {k} finished")
        elif held is None:
            lines.append(f"breaking point: {k} breaks at its first value, {broke:g}")
        elif broke is None:
            lines.append(f"breaking point: none; every seed holds the bound {way} {k} = {held:g}")
        else:
            lines.append(
                f"breaking point: every seed holds the bound {way} {k} = {held:g}; a seed breaks at {broke:g}"
            )
    lines += [f"figure: {p}" for p in c.figures]
    return lines


__all__ = ["Campaign", "SweepSpecError", "draw", "summary_lines", "sweep"]
