"""A run held to its config's requirements (``spec:``, ``specs``): the signals of what it recorded,
and each requirement's robustness, per member and for the run, in ``summary.json``'s ``spec``.

The signals are sampled at the control ticks (``t_s``): a follower's ``FOLLOWER_SIGNALS`` from its
arrays (``failsafe`` from the run's ``failsafe_enter`` and ``failsafe_exit`` events: 1 from the
tick at or after the one, until the tick before the other), a pair's ``distance_m`` from the two
vehicles' positions at each tick, an edge's ``EDGE_SIGNALS`` from its receiver's ``in_age_s``
(``edge_signals``). A member with samples missing (a follower that was lost, a run
that ended early) has a robustness of NaN there, and NaN fails: a requirement is not held by what
was not recorded.
"""

import math
from typing import Any

import numpy as np

from swarm_sitl.config.schema import SwarmConfig
from swarm_sitl.rundir.events import failsafe_windows
from swarm_sitl.rundir.recording import Recording
from swarm_sitl.specs.requirement import Edge
from swarm_sitl.specs.robustness import robustness


def _norm(a: np.ndarray) -> np.ndarray:
    return np.linalg.norm(a, axis=1) if a.ndim == 2 else np.abs(a)


def failsafe_signal(t_s: np.ndarray, events: list[dict[str, Any]], vehicle: int) -> np.ndarray:
    """1 at the ticks vehicle ``vehicle`` was in its failsafe, else 0."""
    out = np.zeros(len(t_s))
    for start, end in failsafe_windows(events).get(vehicle, []):
        out[(t_s >= start - 1e-9) & (t_s < end - 1e-9)] = 1.0
    return out


def follower_signals(
    rec: Recording, cfg: SwarmConfig, i: int, events: list[dict[str, Any]]
) -> dict[str, np.ndarray]:
    a = rec.followers[i]
    out = {
        "pos_err_m": _norm(a["pos_err_m"]),
        "vel_err_mps": _norm(a["vel_err_mps"]),
        "altitude_m": a["p_W"][:, 2],
        "speed_mps": _norm(a["v_W"]),
        "thrust_frac": a["thrust_N"] / cfg.vehicle.max_thrust_N,
        "failsafe": failsafe_signal(a["t_s"], events, i),
    }
    if "est_pos_err_m" in a:
        out["est_pos_err_m"] = _norm(a["est_pos_err_m"])
    return out


def edge_signals(rec: Recording, cfg: SwarmConfig, edge: Edge) -> dict[str, np.ndarray]:
    """What ``edge.dst`` saw of ``edge.src``'s estimates at its ticks: ``age_s`` (the newest's age),
    ``delivered_frac`` (of its ticks so far after its first, the fraction at which a newer estimate
    than the tick before's had come; 1 at its first; NaN where it recorded no tick)."""
    a = rec.followers[edge.dst]
    sources = [int(s) for s, _ in cfg.build_graph().in_neighbours(edge.dst)]
    age = a["in_age_s"][:, sources.index(edge.src)]
    t = a["t_s"]
    made = t - age  # when the newest estimate was made [s]
    new = np.zeros(len(t), dtype=bool)
    # (t - age loses the last bit: one estimate's time from two ticks differs by an ulp, not 1 ns;
    # NaN compares False)
    new[1:] = made[1:] > np.where(np.isnan(made[:-1]), -np.inf, made[:-1]) + 1e-9
    ticked = np.isfinite(t)
    new[: int(np.argmax(ticked)) + 1] = False  # (its first recorded tick is not one "after its first")
    heard = np.cumsum(new & ticked)
    looked = np.cumsum(ticked) - 1  # ticks after the first one it recorded
    with np.errstate(invalid="ignore", divide="ignore"):
        frac = np.where(looked > 0, heard / np.maximum(looked, 1), 1.0)
    return {"age_s": age, "delivered_frac": np.where(ticked, frac, np.nan)}


def judge(cfg: SwarmConfig, rec: Recording, events: list[dict[str, Any]]) -> dict[str, Any]:
    """``summary.json``'s ``spec``: per requirement, its robustness for the run (the least of its
    members'), whether it holds, and each member's."""
    followers = sorted(rec.followers)
    graph = cfg.build_graph()
    dt = cfg.control_dt_s
    signals = {i: follower_signals(rec, cfg, i, events) for i in followers}
    out: dict[str, Any] = {}
    for req in cfg.spec:
        tree = req.tree
        per: dict[str, float] = {}
        for m in req.target.members(graph, followers):
            if isinstance(m, Edge):
                per[f"{m.src}->{m.dst}"] = float(robustness(tree, edge_signals(rec, cfg, m), dt)[0])
            elif isinstance(m, tuple):
                a, b = m
                d = np.linalg.norm(rec.followers[a]["p_W"] - rec.followers[b]["p_W"], axis=1)
                r = float(robustness(tree, {"distance_m": d}, dt)[0])
                per[f"{a}-{b}"] = r
            elif m in signals:
                per[str(m)] = float(robustness(tree, signals[m], dt)[0])
        values = list(per.values())
        worst = min(values, key=lambda v: -math.inf if math.isnan(v) else v) if values else math.nan
        out[req.name] = {
            "formula": req.formula,
            "over": req.over,
            "robustness": _json(worst),
            "holds": bool(values) and not math.isnan(worst) and worst >= 0,
            "members": {k: _json(v) for k, v in per.items()},
        }
    return out


def _json(v: float) -> float | None:
    return None if math.isnan(v) else float(v)


def spec_lines(summary: dict[str, Any]) -> list[str]:
    """One line per requirement that does not hold, naming its worst members."""
    lines = []
    for name, r in summary.get("spec", {}).items():
        if r["holds"]:
            continue
        worst = sorted(r["members"].items(), key=lambda kv: -math.inf if kv[1] is None else kv[1])[:3]
        shown = ", ".join(f"{k} {'not recorded' if v is None else f'{v:.4g}'}" for k, v in worst)
        rob = r["robustness"]
        lines.append(
            f"requirement {name} ({r['formula']}, over {r['over']}) fails: robustness "
            f"{'not recorded' if rob is None else f'{rob:.4g}'} ({shown})"
        )
    return lines
