"""The paper's figures (and a few more) drawn from a run directory, as PNG files."""

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from swarm_sitl.recording import Recording

_AXES = ("x (east)", "y (north)", "z (up)")


def formation_3d(rec: Recording, out: Path, every_s: float = 20.0) -> Path:
    fig = plt.figure(figsize=(8, 7))
    ax = fig.add_subplot(projection="3d")
    L = rec.leader
    ax.plot(*L["p_r"].T, "k--", lw=1, label="leader p_r")
    ids = sorted(rec.followers)
    for i in ids:
        ax.plot(*rec.followers[i]["p_W"].T, lw=0.8, label=f"follower {i}")
    t = L["t_s"]
    for ts in np.arange(0.0, t[-1] + 1e-9, every_s):
        k = int(np.argmin(np.abs(t - ts)))
        pts = np.array([rec.followers[i]["p_W"][k] for i in ids])
        loop = np.vstack([pts, pts[:1]])
        ax.plot(*loop.T, "-o", color="tab:gray", ms=4, lw=1)
        ax.scatter(*L["p_r"][k], color="k", marker="*", s=60)
        ax.text(*pts[0], f" t={t[k]:.0f}s", fontsize=8)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_zlabel("z [m]")
    ax.set_title(f"Formation every {every_s:.0f} s (grey: followers in id order; star: leader)")
    ax.legend(loc="upper left", fontsize=8)
    path = out / "formation_3d.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _components(rec: Recording, key: str, ylabel: str, title: str, path: Path) -> Path:
    ids = sorted(rec.followers)
    fig, axes = plt.subplots(len(ids), 1, figsize=(9, 2.2 * len(ids)), sharex=True, squeeze=False)
    for ax, i in zip(axes[:, 0], ids, strict=True):
        a = rec.followers[i]
        for c in range(3):
            ax.plot(a["t_s"], a[key][:, c], lw=1, label=_AXES[c])
        ax.axhline(0.0, color="k", lw=0.5)
        ax.set_ylabel(f"{i}: {ylabel}")
        ax.grid(alpha=0.3)
    axes[0, 0].legend(loc="upper right", fontsize=8, ncol=3)
    axes[0, 0].set_title(title)
    axes[-1, 0].set_xlabel("t [s]")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def estimator_errors(rec: Recording, path: Path) -> Path:
    fig, axes = plt.subplots(3, 1, figsize=(9, 8), sharex=True)
    for i in sorted(rec.followers):
        a = rec.followers[i]
        for ax, key in zip(axes, ("est_pos_err_m", "est_vel_err_mps", "est_acc_err_mps2"), strict=True):
            ax.semilogy(
                a["t_s"], np.maximum(np.linalg.norm(a[key], axis=1), 1e-12), lw=1, label=f"follower {i}"
            )
    for ax, lab in zip(
        axes, ("|p_hat - p_r| [m]", "|v_hat - v_r| [m/s]", "|a_hat - a_r| [m/s^2]"), strict=True
    ):
        ax.set_ylabel(lab)
        ax.grid(alpha=0.3, which="both")
    axes[0].legend(fontsize=8)
    axes[0].set_title("Distributed estimator errors")
    axes[-1].set_xlabel("t [s]")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def thrust(rec: Recording, path: Path, bound_N: dict[int, float] | None = None) -> Path:
    fig, ax = plt.subplots(figsize=(9, 4))
    for i in sorted(rec.followers):
        a = rec.followers[i]
        ax.plot(a["t_s"], a["thrust_N"], lw=1, label=f"follower {i}")
        if bound_N and i in bound_N:
            ax.axhline(bound_N[i], color="r", ls=":", lw=1)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("T [N]")
    ax.set_title("Commanded thrust (dotted: bound m(g + 2 sqrt3 k_eta + sqrt3 k_gamma))")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_run(rec: Recording, out_dir: Path, thrust_bound_N: dict[int, float] | None = None) -> list[Path]:
    out_dir.mkdir(parents=True, exist_ok=True)
    return [
        formation_3d(rec, out_dir),
        _components(
            rec,
            "pos_err_m",
            "p - p_r - delta [m]",
            "Position error of the followers",
            out_dir / "position_error.png",
        ),
        _components(
            rec,
            "vel_err_mps",
            "v - v_r [m/s]",
            "Velocity error of the followers",
            out_dir / "velocity_error.png",
        ),
        estimator_errors(rec, out_dir / "estimator_error.png"),
        thrust(rec, out_dir / "thrust.png", thrust_bound_N),
    ]
