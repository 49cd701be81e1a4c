"""The paper's figures (and a few more) drawn from a run directory, as PNG files."""

from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from swarm_sitl.rundir.recording import Recording

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


Interval = tuple[float, float, str]  #: a fault's [start, end) [s] and what it was


def fault_intervals(events: list[dict]) -> list[Interval]:
    """The plan's faults as intervals, from a run's ``events.jsonl`` (``fault_start``/``_end``)."""
    starts = {e["fault"]: e for e in events if e["kind"] == "fault_start"}
    out = []
    for e in events:
        if e["kind"] == "fault_end" and e["fault"] in starts:
            s = starts[e["fault"]]
            out.append((float(s["t_s"]), float(e["t_s"]), f"{s['what']}: {s['how']}"))
    return out


def _shade(ax: Any, intervals: list[Interval]) -> None:
    for j, (t0, t1, _) in enumerate(intervals):
        ax.axvspan(t0, max(t1, t0 + 0.05), color=f"C{3 + j % 6}", alpha=0.12, lw=0)


def _components(
    rec: Recording, key: str, ylabel: str, title: str, path: Path, intervals: list[Interval] | None = None
) -> Path:
    intervals = intervals or []
    ids = sorted(rec.followers)
    fig, axes = plt.subplots(len(ids), 1, figsize=(9, 2.2 * len(ids)), sharex=True, squeeze=False)
    for ax, i in zip(axes[:, 0], ids, strict=True):
        a = rec.followers[i]
        for c in range(3):
            ax.plot(a["t_s"], a[key][:, c], lw=1, label=_AXES[c])
        ax.axhline(0.0, color="k", lw=0.5)
        ax.set_ylabel(f"{i}: {ylabel}")
        ax.grid(alpha=0.3)
        _shade(ax, intervals)
    axes[0, 0].legend(loc="upper right", fontsize=8, ncol=3)
    shaded = "; ".join(f"{t0:g}-{t1:g} s {what}" for t0, t1, what in intervals[:4])
    axes[0, 0].set_title(
        title + (f"\n(shaded: faults {shaded})" if intervals else ""), fontsize=9 if intervals else None
    )
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
    ax.set_title("Commanded thrust (dotted: its bound)" if bound_N else "Commanded thrust")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def link_graph(
    edges: list[tuple[int, int]], links: dict[str, dict], lost: list[int], n_followers: int, path: Path
) -> Path:
    """The communication graph, each edge labelled with the fraction of its estimates delivered
    (``summary.json``'s ``links``; "n/a" where its receiver counted nothing: it did not finish) and
    drawn redder the more it lost. The leader is above the followers' circle."""
    delivered: dict[tuple[int, int], float | None] = {}
    for src, dst in edges:
        st = links.get(f"{src}->{dst}", {})
        delivered[(src, dst)] = st["delivered"] / st["received"] if st.get("received") else None
    return edge_graph(edges, delivered, lost, n_followers, path, "Estimates delivered per edge (L: leader)")


def edge_graph(
    edges: list[tuple[int, int]],
    good: dict[tuple[int, int], float | None],
    lost: list[int],
    n_followers: int,
    path: Path,
    title: str,
    worse_when_high: bool = False,
) -> Path:
    """The communication graph, each edge labelled with its value in ``good`` (a fraction: 1 drawn
    green, 0 red, or the reverse with ``worse_when_high``; None: "n/a", grey). The leader is above
    the followers' circle."""
    fig, ax = plt.subplots(figsize=(6.5, 7.5))
    pos: dict[int, tuple[float, float]] = {0: (0.0, 1.55)}
    for i in range(1, n_followers + 1):
        a = np.pi / 2 + np.pi / n_followers - 2 * np.pi * (i - 1) / n_followers
        pos[i] = (float(np.cos(a)), float(np.sin(a)) - 0.2)
    for src, dst in edges:
        frac = good.get((src, dst))
        shade = None if frac is None else (1.0 - frac if worse_when_high else frac)
        colour = plt.get_cmap("RdYlGn")(shade) if shade is not None else "grey"
        (x0, y0), (x1, y1) = pos[src], pos[dst]
        d = float(np.hypot(x1 - x0, y1 - y0))
        ux, uy = (x1 - x0) / d * 0.12, (y1 - y0) / d * 0.12
        arrow = {"arrowstyle": "-|>", "color": colour, "lw": 2.5}
        ax.annotate("", xy=(x1 - ux, y1 - uy), xytext=(x0 + ux, y0 + uy), arrowprops=arrow)
        box = {"fc": "white", "ec": colour, "lw": 1}
        label = f"{frac:.0%}" if frac is not None else "n/a"
        ax.text((x0 + x1) / 2, (y0 + y1) / 2, label, fontsize=9, ha="center", va="center", bbox=box)
    for node, (x, y) in pos.items():
        gone = node in lost
        ax.scatter([x], [y], s=900, c="lightgrey" if gone else ("k" if node == 0 else "tab:blue"), zorder=3)
        label = ("L" if node == 0 else str(node)) + (" (lost)" if gone else "")
        ax.text(x, y, label, color="k" if gone else "white", ha="center", va="center", zorder=4)
    ax.set_xlim(-1.4, 1.4)
    ax.set_ylim(-1.5, 1.85)
    ax.set_aspect("equal")
    ax.axis("off")
    ax.set_title(title)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_run(
    rec: Recording,
    out_dir: Path,
    thrust_bound_N: dict[int, float] | None = None,
    events: list[dict] | None = None,
    summary: dict | None = None,
    edges: list[tuple[int, int]] | None = None,
) -> list[Path]:
    """Every figure of a run; with its ``events`` the error plots shade the faults, and with its
    ``summary`` and graph ``edges`` a figure of the graph shows each edge's delivered fraction."""
    out_dir.mkdir(parents=True, exist_ok=True)
    intervals = fault_intervals(events or [])
    extra = []
    if summary is not None and edges is not None:
        extra.append(
            link_graph(
                edges,
                summary.get("links", {}),
                summary.get("lost", []),
                len(rec.followers),
                out_dir / "links.png",
            )
        )
    return [
        *extra,
        formation_3d(rec, out_dir),
        _components(
            rec,
            "pos_err_m",
            "p - p_r - delta [m]",
            "Position error of the followers",
            out_dir / "position_error.png",
            intervals,
        ),
        _components(
            rec,
            "vel_err_mps",
            "v - v_r [m/s]",
            "Velocity error of the followers",
            out_dir / "velocity_error.png",
            intervals,
        ),
        *(
            [estimator_errors(rec, out_dir / "estimator_error.png")]
            if all("est_pos_err_m" in a for a in rec.followers.values())
            else []
        ),
        thrust(rec, out_dir / "thrust.png", thrust_bound_N),
    ]
