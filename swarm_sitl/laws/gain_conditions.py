"""Theorem 1's sufficient conditions, and the command-force conditions of section 3.3.

Each condition is reported with its bound, the chosen value and a verdict. They are sufficient,
not necessary: a failed condition is a warning, not a refusal.
"""

from dataclasses import dataclass

import numpy as np

from swarm_sitl.laws.graph import Graph
from swarm_sitl.laws.trajectories import Trajectory, sup_norm, sup_Np


@dataclass(frozen=True)
class Condition:
    name: str
    relation: str  #: how value must compare to bound: ">", ">=" or "<"
    bound: float
    value: float

    @property
    def holds(self) -> bool:
        if not np.isfinite(self.bound):
            return False
        if self.relation == ">":
            return self.value > self.bound
        if self.relation == ">=":
            return self.value >= self.bound
        if self.relation == "<":
            return self.value < self.bound
        raise ValueError(f"condition {self.name!r}: unknown relation {self.relation!r}")


@dataclass(frozen=True)
class GainReport:
    theta: np.ndarray
    theta_source: str
    xi: np.ndarray
    lambda_min_xi: float
    lambda_min_mtm: float  #: lambda_min(M^T Theta M)
    norm_theta: float  #: Frobenius norm, the paper's ||.|| for matrices
    norm_theta_m: float
    sup_acc: float
    sup_Np: float
    conditions: tuple[Condition, ...]
    suggestion: dict[str, float]

    @property
    def all_hold(self) -> bool:
        return all(c.holds for c in self.conditions)


def _lmin_sym(A: np.ndarray) -> float:
    return float(np.min(np.linalg.eigvalsh(0.5 * (A + A.T))))


def check_gains(
    graph: Graph, gains: dict[str, float], trajectory: Trajectory, g_mps2: float, horizon_s: float
) -> GainReport:
    """Evaluate every condition for ``gains`` (keys k_p, k_v, l_a, k_a, k_eta, k_gamma)."""
    n = graph.n_followers
    M = graph.M()
    Th = graph.theta()
    Xi = graph.xi()
    lx = _lmin_sym(Xi)
    lm = _lmin_sym(M.T @ Th @ M)
    nt = float(np.linalg.norm(Th))
    ntm = float(np.linalg.norm(Th @ M))
    k_p, k_v, l_a, k_a = gains["k_p"], gains["k_v"], gains["l_a"], gains["k_a"]
    k_eta, k_gamma = gains["k_eta"], gains["k_gamma"]
    sup_a = sup_norm(trajectory, 2, horizon_s)
    np_bar = sup_Np(trajectory, l_a, horizon_s)

    def la_bound(kp: float, kv: float) -> float:
        den = lm * (kp * kv * lx**2 - nt**2)
        return kp * lx * nt**2 / den if den > 0 else float("inf")

    conds = (
        Condition("k_p k_v > ||Theta||^2 / lambda_min(Xi)^2", ">", nt**2 / lx**2, k_p * k_v),
        Condition(
            "l_a > k_p lmin(Xi) ||Theta||^2 / (lmin(M^T Theta M)(k_p k_v lmin(Xi)^2 - ||Theta||^2))",
            ">",
            la_bound(k_p, k_v),
            l_a,
        ),
        Condition(
            "k_a > 2 sqrt(n) ||Theta M|| sup|N_p| / lambda_min(Xi)",
            ">",
            2 * np.sqrt(n) * ntm * np_bar / lx,
            k_a,
        ),
        Condition("k_eta < (g - k_gamma) / 2", "<", (g_mps2 - k_gamma) / 2, k_eta),
        Condition("k_gamma >= sup |pddot_r|", ">=", sup_a, k_gamma),
    )
    # suggestion: keep what holds; otherwise search k_p = k_v on a geometric grid (a larger k_p k_v
    # lowers the l_a bound, and a smaller l_a lowers sup|N_p| and so the k_a bound), 25 % margins
    s_kgamma = k_gamma if k_gamma >= sup_a else 1.25 * sup_a
    s_keta = k_eta if k_eta < (g_mps2 - s_kgamma) / 2 else 0.8 * (g_mps2 - s_kgamma) / 2
    best: tuple[float, float, float, float] | None = None  # (k_a, k_p, l_a, ...)
    k0 = max(np.sqrt(k_p * k_v), 1.25 * nt / lx)
    for k in ([np.sqrt(k_p * k_v)] if k_p * k_v > nt**2 / lx**2 else []) + list(k0 * 2.0 ** np.arange(0, 8)):
        la = l_a if l_a > la_bound(k, k) else 1.25 * la_bound(k, k)
        ka_b = 2 * np.sqrt(n) * ntm * sup_Np(trajectory, la, horizon_s, 4001) / lx
        ka = k_a if k_a > ka_b else 1.25 * ka_b
        if best is None or ka < best[0] * 0.999:
            best = (ka, k, la, ka_b)
    assert best is not None
    same_k = k_p * k_v > nt**2 / lx**2 and best[1] == np.sqrt(k_p * k_v)
    s_kp, s_kv = (k_p, k_v) if same_k else (best[1], best[1])
    suggestion = {
        "k_p": float(s_kp),
        "k_v": float(s_kv),
        "l_a": float(best[2]),
        "k_a": float(best[0]),
        "k_eta": float(s_keta),
        "k_gamma": float(s_kgamma),
    }
    return GainReport(Th, graph.theta_source(), Xi, lx, lm, nt, ntm, sup_a, np_bar, conds, suggestion)
