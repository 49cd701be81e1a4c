"""Summary figures of a recorded run: final and peak errors, time to converge, invariants."""

from collections.abc import Mapping
from typing import Any

import numpy as np

from swarm_sitl.rundir.recording import Recording
from swarm_sitl.rundir.rejoins import rejoin_lines
from swarm_sitl.rundir.requirements import spec_lines
from swarm_sitl.rundir.settling import Settling


def _norm(a: np.ndarray) -> np.ndarray:
    return np.linalg.norm(a, axis=1)


class FollowerFigures:
    """One follower's figures in the summary, from its rows given block by block, in order (a
    run streamed to disk); its whole arrays at once are one block. Rows a run did not record
    (ticks skipped in real time, a run cut short) are NaN: left out. ``uz_floor``: the paper's
    law's floor of ``u_z`` (its ``u`` then checked), None for another law."""

    def __init__(self, settle_from_s: float, thrust_bound_N: float, uz_floor: float | None):
        self.settle_from_s, self.thrust_bound_N, self.uz_floor = settle_from_s, thrust_bound_N, uz_floor
        self.ticks = 0
        self.final = (np.nan, np.nan)
        self.final_est: float | None = None
        self.peak = (-np.inf, -np.inf)
        self.late: tuple[float, float] | None = None  #: the peaks after ``settle_from_s``
        self.settling = {"time_to_0.1m_s": Settling(0.1), "time_to_0.01m_s": Settling(0.01)}
        self.min_u_z = np.inf
        self.max_thrust = -np.inf

    def add(self, rows: Mapping[str, np.ndarray]) -> "FollowerFigures":
        ok = np.isfinite(rows["t_s"]) & np.isfinite(rows["pos_err_m"]).all(axis=1)
        if not ok.any():
            return self
        t = rows["t_s"][ok]
        pe, ve = _norm(rows["pos_err_m"][ok]), _norm(rows["vel_err_mps"][ok])
        self.ticks += int(ok.sum())
        self.final = (float(pe[-1]), float(ve[-1]))
        if "est_pos_err_m" in rows:
            self.final_est = float(_norm(rows["est_pos_err_m"][ok])[-1])
        # (np.maximum, np.minimum: a NaN among them is kept, as one max over the whole keeps it)
        self.peak = (float(np.maximum(self.peak[0], pe.max())), float(np.maximum(self.peak[1], ve.max())))
        late = t >= self.settle_from_s
        if late.any():
            was = self.late or (-np.inf, -np.inf)
            self.late = (float(np.maximum(was[0], pe[late].max())), float(np.maximum(was[1], ve[late].max())))
        for settling in self.settling.values():
            settling.add(t, pe)
        if self.uz_floor is not None:
            self.min_u_z = float(np.minimum(self.min_u_z, np.min(rows["u"][ok][:, 2])))
        self.max_thrust = float(np.maximum(self.max_thrust, np.max(rows["thrust_N"][ok])))
        return self

    def result(self) -> dict[str, Any]:
        if self.ticks == 0:
            return {"recorded_ticks": 0}
        late = self.late or (None, None)
        f: dict[str, Any] = {
            "recorded_ticks": self.ticks,
            "final_pos_err_m": self.final[0],
            "final_vel_err_mps": self.final[1],
            "peak_pos_err_m": self.peak[0],
            "peak_vel_err_mps": self.peak[1],
            "peak_pos_err_after_settle_m": late[0],
            "peak_vel_err_after_settle_mps": late[1],
        }
        if self.final_est is not None:
            f["final_est_pos_err_m"] = self.final_est
        f |= {key: settling.result() for key, settling in self.settling.items()}
        if self.uz_floor is not None:
            f["min_u_z_mps2"] = self.min_u_z
            f["u_z_floor_mps2"] = self.uz_floor
        f["max_thrust_N"] = self.max_thrust
        f["thrust_bound_N"] = float(self.thrust_bound_N)
        return f


def uz_floor(gains: dict[str, float] | None, g_mps2: float) -> float | None:
    """The paper's floor of ``u_z``, ``g - k_gamma - 2 k_eta`` (None for another law)."""
    return None if gains is None else g_mps2 - gains["k_gamma"] - 2 * gains["k_eta"]


def follower_figures(
    gains: dict[str, float] | None,
    mass_kg: float,
    g_mps2: float,
    settle_from_s: float = 20.0,
    max_thrust_N: float = np.inf,
) -> FollowerFigures:
    """A follower's ``FollowerFigures``: the paper's law (``gains``) is held to its own bound on
    the thrust (section 3.3) and its floor of ``u_z``; another law's thrust to the vehicle's most."""
    if gains is None:
        return FollowerFigures(settle_from_s, max_thrust_N, None)
    k_eta, k_gamma = gains["k_eta"], gains["k_gamma"]
    bound = mass_kg * (g_mps2 + 2 * np.sqrt(3) * k_eta + np.sqrt(3) * k_gamma)
    return FollowerFigures(settle_from_s, bound, uz_floor(gains, g_mps2))


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
    per = {
        i: follower_figures(gains, mass_kg[i], g_mps2, settle_from_s, max_thrust_N).add(full).result()
        for i, full in rec.followers.items()
    }
    return swarm_summary(per, uz_floor(gains, g_mps2), settle_from_s)


def swarm_summary(per: dict[int, dict[str, Any]], floor: float | None, settle_from_s: float) -> dict:
    """The summary of the followers' figures ``per`` (``FollowerFigures.result``): each, and the
    swarm's worst; ``floor``: the paper's floor of ``u_z`` (``uz_floor``)."""
    paper = floor is not None
    worst: dict[str, Any] = {
        "final_pos_err_m": 0.0,
        "peak_pos_err_after_settle_m": None,  # None: no follower recorded past settle_from_s
        "peak_vel_err_after_settle_mps": None,
        **({"min_u_z_mps2": np.inf} if paper else {}),
        "max_thrust_over_bound": -np.inf,
        "time_to_0.1m_s": 0.0,
        "time_to_0.01m_s": 0.0,
    }
    out: dict[str, Any] = {"followers": {}}
    for i, f in per.items():
        out["followers"][str(i)] = f
        if f["recorded_ticks"] == 0:
            continue
        worst["final_pos_err_m"] = max(worst["final_pos_err_m"], f["final_pos_err_m"])
        for key in ("peak_pos_err_after_settle_m", "peak_vel_err_after_settle_mps"):
            if f[key] is not None:
                worst[key] = f[key] if worst[key] is None else max(worst[key], f[key])
        if paper:
            worst["min_u_z_mps2"] = min(worst["min_u_z_mps2"], f["min_u_z_mps2"])
        worst["max_thrust_over_bound"] = max(
            worst["max_thrust_over_bound"], f["max_thrust_N"] / f["thrust_bound_N"]
        )
        for key in ("time_to_0.1m_s", "time_to_0.01m_s"):
            worst[key] = None if f[key] is None or worst[key] is None else max(worst[key], f[key])
    if paper:
        worst["u_z_floor_mps2"] = floor
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
