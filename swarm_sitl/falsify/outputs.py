"""What ``falsify`` found, and what it writes: the front, the tables, the charts, the report, and
the counterexample's lockstep confirmation."""

import csv
import json
import math
import subprocess
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from swarm_sitl.config.schema import SwarmConfig
from swarm_sitl.falsify.evaluate import robustness_of
from swarm_sitl.falsify.space import edges_of, expand
from swarm_sitl.falsify.workers import NO_ROBUSTNESS
from swarm_sitl.running.warm_commands import CLI


@dataclass
class Found:
    """What ``falsify`` found."""

    requirement: str
    evaluations: int  #: sim runs, the search's and the shrinking's
    counterexample: Path | None = None  #: the minimal violating plan's file
    plan: dict[str, Any] | None = None
    robustness: float = math.nan  #: of the counterexample
    cost: float = math.nan
    confirmed: bool | None = None  #: its lockstep run gave the same robustness (None: not run)
    front: list[dict[str, Any]] = field(default_factory=list)
    per_minute: float = math.nan
    interrupted: bool = False  #: Ctrl-C or SIGTERM: what was found up to it
    signum: int = 0  #: the signal that stopped it
    baseline: float = math.nan  #: the requirement's robustness without a searched fault
    base_entries: int = 0  #: the config's own plan's entries, flown under every searched plan


def order(row: dict[str, Any]) -> tuple[float, float]:
    return row["cost"], row["robustness"]


def front(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The rows no other row beats in both cost and robustness (both lower is better)."""
    rows = sorted(rows, key=lambda r: (r["cost"], r["robustness"]))
    out: list[dict[str, Any]] = []
    best = math.inf
    for r in rows:
        if r["robustness"] < best:
            out.append(r)
            best = r["robustness"]
    return out


def write_csv(path: Path, rows: list[dict[str, Any]], cfg: SwarmConfig) -> None:
    """One row per plan, each written as the fault plan it flew (``expand``)."""
    cols = ["cost", "robustness", "violates", "seed", "entries", "plan"]
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(cols)
        for r in rows:
            plan = expand(r["plan"], cfg)
            violates = int(r["robustness"] < 0)
            entries = len(plan["plan"])
            w.writerow(
                [repr(r["cost"]), repr(r["robustness"]), violates, plan["seed"], entries, json.dumps(plan)]
            )


def confirm_in_lockstep(
    cfg: SwarmConfig, name: str, plan_file: Path, run_dir: Path, robustness: float
) -> bool:
    """The counterexample as a lockstep run of processes: the same robustness, bit for bit."""
    from swarm_sitl.rundir.load import load_run

    config = run_dir.parent / f"{name}.config.yaml"
    config.parent.mkdir(parents=True, exist_ok=True)
    config.write_text(yaml.safe_dump(cfg.data(), sort_keys=False))
    cmd = [*CLI, "run", str(config), "--faults", str(plan_file)]
    subprocess.run([*cmd, "--out", str(run_dir), "--quiet"], capture_output=True, text=True, check=False)
    try:
        rec = load_run(run_dir)
    except Exception:  # a run that wrote nothing readable is not a confirmation
        return False
    flown = cfg.model_copy(update={"faults": _plan(plan_file)})
    r = robustness_of(flown, rec, name)
    return r == robustness or (math.isinf(r) and robustness <= NO_ROBUSTNESS)


def _plan(path: Path) -> Any:
    from swarm_sitl.faults.plan import FaultPlan

    return FaultPlan.model_validate(yaml.safe_load(path.read_text()))


def chart(path: Path, rows: list[dict[str, Any]], found: Found) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    ax.scatter([r["cost"] for r in rows], [r["robustness"] for r in rows], s=10, label="evaluations")
    fr = found.front
    ax.step([r["cost"] for r in fr], [r["robustness"] for r in fr], where="post", color="C1", label="front")
    if found.plan is not None:
        ax.scatter([found.cost], [found.robustness], marker="*", s=120, color="C3", label="counterexample")
    ax.axhline(0, color="k", lw=0.8)
    ax.set_xlabel("plan cost")
    ax.set_ylabel(f"robustness of {found.requirement}")
    ax.set_yscale("symlog", linthresh=1e-3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def edge_shares(rows: list[dict[str, Any]], cfg: SwarmConfig) -> dict[tuple[int, int], float | None]:
    """Per graph edge, the share of the violating plans that touch it (None: none violated; a
    plan's MAVLink and controller entries touch no edge)."""
    bad = [expand(r["plan"], cfg) for r in rows if r["robustness"] < 0]
    edges = cfg.graph_edges()
    if not bad:
        return dict.fromkeys(edges)
    touched = [{e for f in plan["plan"] for e in edges_of(f, cfg)} for plan in bad]
    return {e: sum(e in t for t in touched) / len(touched) for e in edges}


def edge_picture(path: Path, rows: list[dict[str, Any]], cfg: SwarmConfig) -> None:
    from swarm_sitl.rundir.plots import edge_graph

    n = sum(r["robustness"] < 0 for r in rows)
    title = f"Share of the {n} violating plans acting on each edge (L: leader)"
    edge_graph(cfg.graph_edges(), edge_shares(rows, cfg), [], len(cfg.followers), path, title, True)


def failed_report(path: Path, cfg: SwarmConfig, name: str, why: str) -> None:
    """``report.md`` of a search a worker ended: what failed, and no verdict on the swarm."""
    lines = [f"# falsify {cfg.name}: requirement {name}", ""]
    lines.append("The search stopped: a worker could not fly a plan. Nothing is said of the swarm.")
    lines.append("")
    lines.append(f"    {why}")
    path.write_text("\n".join(lines) + "\n")


def report(path: Path, cfg: SwarmConfig, name: str, found: Found, wall_s: float) -> None:
    lines = [f"# falsify {cfg.name}: requirement {name}", ""]
    lines.append(f"{found.evaluations} evaluations in {wall_s:.0f} s ({found.per_minute:.1f} per minute).")
    base = len(cfg.faults.plan)
    if base:
        lines.append(
            f"The config's own plan ({base} entries) is flown under every searched plan, and is in "
            "the counterexample."
        )
    without = "the config's own plan alone" if base else "a fault"
    lines.append(f"With {without} the requirement's robustness is {found.baseline:.4g}.")
    if found.baseline < 0:
        lines.append(f"It fails with {without}: there is nothing to search for.")
    elif found.plan is None:
        lines.append("No plan in the space broke the requirement.")
    else:
        lines.append(
            f"Minimal counterexample: {found.counterexample} (cost {found.cost:.4g}, robustness "
            f"{found.robustness:.4g}), {len(found.plan['plan'])} entries:"
        )
        lines += [f"- `{json.dumps(e, sort_keys=True)}`" for e in found.plan["plan"]]
        lines.append(f"Confirmed as a lockstep run of processes: {found.confirmed}.")
    path.write_text("\n".join(lines) + "\n")
