"""Fly the paper's scenario with two laws, with and without a cut edge, and draw them side by side.

    python examples/compare_laws.py [OUT.png]     (default docs/figures/laws_compare.png)

The paper's law (``configs/paper.yaml``) and the consensus/PD law (``configs/consensus_pd.yaml``,
``examples/laws/consensus_pd.py``), each as a lockstep run of processes for 45 s through the
``Swarm`` API: once as configured, once with the edge 0 -> 1 cut from 20 s to 30 s. It plots
each follower's formation error |p_i - p_r - delta_i| (log scale) and prints per run the final
error, when the largest error falls below 1 cm for good, and the peak of followers 1 and 4 during
the cut and from 10 s after it.
"""

import sys
import tempfile
from pathlib import Path

import numpy as np

from swarm_sitl import Swarm

ROOT = Path(__file__).resolve().parents[1]
LAWS = {
    "paper's law (Zou & Meng)": ROOT / "configs/paper.yaml",
    "consensus + PD": ROOT / "configs/consensus_pd.yaml",
}
CUT = [{"edge": [0, 1], "drop": True, "from_s": 20, "until_s": 30}]
DURATION_S = 45.0


def below_for_good(t: np.ndarray, err: np.ndarray, bound: float) -> float:
    above = np.nonzero(~(err < bound))[0]
    return (
        float(t[0])
        if not len(above)
        else (float(t[above[-1] + 1]) if above[-1] + 1 < len(t) else float("nan"))
    )


def main() -> int:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT / "docs/figures/laws_compare.png"
    fig, axes = plt.subplots(2, 2, figsize=(11, 7), sharex=True, sharey=True)
    with tempfile.TemporaryDirectory() as tmp:
        for col, (law, cfg) in enumerate(LAWS.items()):
            for row, faults in enumerate((None, CUT)):
                with Swarm(cfg, faults=faults, out=Path(tmp) / f"{col}{row}") as swarm:
                    r = swarm.run(duration_s=DURATION_S)
                assert r.ok, r.failure
                ax = axes[row][col]
                worst = None
                for i, f in sorted(r.followers.items()):
                    e = f.formation_error_m
                    ax.semilogy(f.t_s, np.maximum(e, 1e-6), label=f"follower {i}", lw=1)
                    worst = e if worst is None else np.maximum(worst, e)
                t = r.followers[1].t_s
                if faults:
                    ax.axvspan(20, 30, color="0.9", zorder=0, label="0 -> 1 cut")
                name = f"{law}, {'0 -> 1 cut 20-30 s' if faults else 'no fault'}"
                ax.set_title(name, fontsize=10)
                cut = max(r.followers[i].max_formation_error_m(20, 30) for i in (1, 4))
                after = max(r.followers[i].max_formation_error_m(after_s=40) for i in (1, 4))
                print(
                    f"{name}: final {worst[-1] * 1000:.3g} mm; below 1 cm for good at "
                    f"{below_for_good(t, worst, 0.01):.2f} s; followers 1, 4 peak in the cut {cut:.3g} m"
                    + (f", from 40 s on {after * 1000:.3g} mm" if faults else "")
                )
    for ax in axes[1]:
        ax.set_xlabel("t [s]")
    for ax in axes[:, 0]:
        ax.set_ylabel("|p_i - p_r - delta_i| [m]")
    axes[0][0].legend(fontsize=8, loc="upper right")
    axes[1][0].legend(fontsize=8, loc="upper right")
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
