"""Summary figures of a recorded run: final and peak errors, time to converge, invariants."""

from typing import Any

import numpy as np

from swarm_sitl.rundir.recording import Recording
from swarm_sitl.rundir.rejoins import rejoin_lines
from swarm_sitl.rundir.requirements import spec_lines
from swarm_sitl.rundir.settling import time_to_converge


def _norm(a: np.ndarray) -> np.ndarray:
    return np.linalg.norm(a, axis=1)


def summarize(
    rec: Recording,
    gains: dict[str, float] | None,
    mass_kg: dict[int, float],
    g_mps2: float,
    settle_from_s: float = 20.0,
    max_thrust_N: float = np.inf,
) -> dict:
    """Per-follower and swarm-wide figures (all errors are 2-norms of the error vector).
    ``gains``: the paper's law's, whose invariants (the floor of ``u_z``, the thrust bound) are
    then checked; None for another law, whose thrust is set against ``max_thrust_N``."""
    out: dict[str, Any] = {"followers": {}}
    paper = gains is not None
    k_eta, k_gamma = (gains["k_eta"], gains["k_gamma"]) if gains is not None else (0.0, 0.0)
    uz_floor = g_mps2 - k_gamma - 2 * k_eta
    worst: dict[str, Any] = {
        "final_pos_err_m": 0.0,
        "peak_pos_err_after_settle_m": None,  # None: no follower recorded past settle_from_s
        "peak_vel_err_after_settle_mps": None,
        **({"min_u_z_mps2": np.inf} if paper else {}),
        "max_thrust_over_bound": -np.inf,
        "time_to_0.1m_s": 0.0,
        "time_to_0.01m_s": 0.0,
    }
    for i, full in rec.followers.items():
        # rows a run did not record (ticks skipped in real time, a run cut short) are NaN: left out
        ok = np.isfinite(full["t_s"]) & np.isfinite(full["pos_err_m"]).all(axis=1)
        if not ok.any():
            out["followers"][str(i)] = {"recorded_ticks": 0}
            continue
        a = {key: v[ok] for key, v in full.items()}
        t = a["t_s"]
        pe, ve = _norm(a["pos_err_m"]), _norm(a["vel_err_mps"])
        late = t >= settle_from_s
        # the paper's bound on its thrust (section 3.3), or the vehicle's most
        t_bound = max_thrust_N
        if paper:
            t_bound = mass_kg[i] * (g_mps2 + 2 * np.sqrt(3) * k_eta + np.sqrt(3) * k_gamma)
        f: dict[str, Any] = {
            "recorded_ticks": int(ok.sum()),
            "final_pos_err_m": float(pe[-1]),
            "final_vel_err_mps": float(ve[-1]),
            "peak_pos_err_m": float(pe.max()),
            "peak_vel_err_mps": float(ve.max()),
            "peak_pos_err_after_settle_m": float(pe[late].max()) if late.any() else None,
            "peak_vel_err_after_settle_mps": float(ve[late].max()) if late.any() else None,
        }
        if "est_pos_err_m" in a:
            f["final_est_pos_err_m"] = float(_norm(a["est_pos_err_m"])[-1])
        f["time_to_0.1m_s"] = time_to_converge(t, pe, 0.1)
        f["time_to_0.01m_s"] = time_to_converge(t, pe, 0.01)
        if paper:
            f["min_u_z_mps2"] = float(np.min(a["u"][:, 2]))
            f["u_z_floor_mps2"] = uz_floor
        f["max_thrust_N"] = float(np.max(a["thrust_N"]))
        f["thrust_bound_N"] = float(t_bound)
        out["followers"][str(i)] = f
        worst["final_pos_err_m"] = max(worst["final_pos_err_m"], f["final_pos_err_m"])
        for key in ("peak_pos_err_after_settle_m", "peak_vel_err_after_settle_mps"):
            if f[key] is not None:
                worst[key] = f[key] if worst[key] is None else max(worst[key], f[key])
        if paper:
            worst["min_u_z_mps2"] = min(worst["min_u_z_mps2"], f["min_u_z_mps2"])
        worst["max_thrust_over_bound"] = max(worst["max_thrust_over_bound"], f["max_thrust_N"] / t_bound)
        for key in ("time_to_0.1m_s", "time_to_0.01m_s"):
            worst[key] = None if f[key] is None or worst[key] is None else max(worst[key], f[key])
    if paper:
        worst["u_z_floor_mps2"] = uz_floor
    worst["settle_from_s"] = settle_from_s
    out["swarm"] = worst
    return out


def bound_failures(summary: dict, bound_m: float | None) -> list[str]:
    """One line per follower whose formation error after the settling time exceeds ``bound_m``
    (``run.max_formation_error_m``), naming its degraded inputs where the run recorded them, and
    one per follower that did not rejoin after a planned restart (``rejoins``), and one per
    requirement of the config's ``spec:`` that fails (``requirements``)."""
    lines = spec_lines(summary)  # the config's requirements, bound or not
    if bound_m is None:
        return lines
    return _past_bound(summary, bound_m) + rejoin_lines(summary)[1] + lines


def _past_bound(summary: dict, bound_m: float) -> list[str]:
    settle = summary["swarm"]["settle_from_s"]
    inputs = summary.get("inputs", {})
    lost = set(summary.get("lost", []))  # a lost aircraft is recorded, not held to the bound
    out = []
    for i, f in sorted(summary["followers"].items(), key=lambda kv: int(kv[0])):
        if int(i) in lost:
            continue
        peak = f.get("peak_pos_err_after_settle_m")
        if peak is None:
            if f.get("recorded_ticks", 0) == 0 or settle > 0:
                out.append(f"follower {i}: nothing recorded after {settle:g} s to hold to the bound")
            continue
        if peak > bound_m:
            line = (
                f"follower {i}: formation error {peak:.3g} m after {settle:g} s exceeds "
                f"run.max_formation_error_m = {bound_m:g} m"
            )
            why = describe_inputs(inputs.get(i, {}))
            out.append(line + (f"; stale inputs: {why}" if why else ""))
    return out


def describe_inputs(report: dict) -> str:
    """A controller's degraded inputs (``nodes.controller.NodeReport`` as a dict) in words, "" if none."""
    parts = []
    if report.get("old_samples"):
        parts.append(
            f"{report['old_samples']} ticks on an old vehicle sample "
            f"(none new since the tick before, or older than a control period; max age "
            f"{report['max_sample_age_s']:.3f} s)"
        )
    if report.get("stale_estimates"):
        parts.append(f"{report['stale_estimates']} neighbour estimates past staleness")
    if report.get("late_ticks"):
        parts.append(f"{report['late_ticks']} late ticks")
    return ", ".join(parts)
