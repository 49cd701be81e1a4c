"""Text rendering of ``swarm-sitl check``."""

import numpy as np

from swarm_sitl.laws.gain_conditions import GainReport

COVERED_BRACKET = "sliding_surface"  #: the estimator form Theorem 1's proof is written for


def render(report: GainReport, name: str, bracket: str = COVERED_BRACKET) -> str:
    """``bracket``: the config's ``estimator.bracket``, the form the run will fly."""
    lines = [
        f"config {name}: Theorem 1 and section 3.3 conditions (sufficient, not necessary)",
        f"  they cover the estimator with bracket {COVERED_BRACKET} (the proof's surface "
        f"s = (M x I3)(l_a abar + abardot)); this config flies bracket {bracket}",
        f"  Theta = diag({', '.join(f'{x:.4g}' for x in np.diag(report.theta))})   ({report.theta_source})",
        "  Xi = M^T Theta + Theta M =",
        *("    " + "  ".join(f"{x:8.4f}" for x in row) for row in report.xi),
        f"  lambda_min(Xi) = {report.lambda_min_xi:.4g}, "
        f"lambda_min(M^T Theta M) = {report.lambda_min_mtm:.4g}, "
        f"||Theta|| = {report.norm_theta:.4g}, ||Theta M|| = {report.norm_theta_m:.4g}",
        f"  sup|pddot_r| = {report.sup_acc:.4g} m/s^2, sup|N_p| = {report.sup_Np:.4g} m/s^3 "
        "(N_p = -l_a p_r^(3) - p_r^(4), as derived)",
        "",
    ]
    w = max(len(c.name) for c in report.conditions)
    lines.append(f"  {'condition':<{w}}  {'bound':>10}  {'value':>10}  verdict")
    for c in report.conditions:
        verdict = "ok" if c.holds else "FAILS"
        lines.append(f"  {c.name:<{w}}  {c.bound:>10.4g}  {c.value:>10.4g}  {verdict}")
    failing = [c.name for c in report.conditions if not c.holds]
    lines.append("")
    if failing:
        lines.append(
            f"WARNING: {len(failing)} condition(s) fail; convergence is not guaranteed by Theorem 1 "
            f"(it may still converge: the conditions are sufficient, not necessary)."
        )
        lines.append(
            "  suggested gains that satisfy all conditions: "
            + ", ".join(f"{k}={v:.4g}" for k, v in report.suggestion.items())
        )
    else:
        lines.append("all conditions hold.")
    if bracket != COVERED_BRACKET:
        lines.append(
            f"WARNING: estimator.bracket is {bracket}: Theorem 1 does not cover it "
            f"(docs/paper.md, erratum 7), so the verdicts above are not a guarantee for this run; "
            f"bracket {COVERED_BRACKET} is."
        )
    return "\n".join(lines)
