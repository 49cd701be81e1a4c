"""A campaign's figures: the largest formation error after settling against each swept value,
its spread over the seeds, the bound and the breaking point; a heat map for two values."""

from pathlib import Path
from typing import Any

import numpy as np

from swarm_sitl.campaigns.breaking import breaking_point, toward


def _mpl() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def error_chart(rows: list[dict[str, Any]], key: str, bound_m: float, path: Path, title: str) -> Path:
    """Error against ``key``: each seed a dot, the median a line, min to max shaded."""
    plt = _mpl()
    values = sorted({float(r[key]) for r in rows})
    per = [[float(r["max_error_m"]) for r in rows if float(r[key]) == v] for v in values]
    lo = [np.nanmin(p) if np.isfinite(p).any() else np.nan for p in per]
    hi = [np.nanmax(p) if np.isfinite(p).any() else np.nan for p in per]
    med = [np.nanmedian(p) if np.isfinite(p).any() else np.nan for p in per]
    fig, ax = plt.subplots(figsize=(7, 4.2))
    ax.fill_between(values, lo, hi, alpha=0.25, color="C0", label="min to max over seeds")
    ax.plot(values, med, "-o", color="C0", ms=3, label="median")
    for v, p in zip(values, per, strict=True):
        ax.plot([v] * len(p), p, ".", color="C0", alpha=0.5, ms=4)
    ax.axhline(bound_m, color="C3", ls="--", lw=1, label=f"bound {bound_m:g} m")
    held, broke = breaking_point(rows, key)
    if held is not None and broke is not None:
        ax.axvline(held, color="C2", ls=":", lw=1.5, label=f"holds {toward(key)} {held:g}")
    ax.set_yscale("log")
    ax.set_xlabel(key)
    ax.set_ylabel("largest formation error after settling [m]")
    ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def heat_map(rows: list[dict[str, Any]], keys: list[str], bound_m: float, path: Path, title: str) -> Path:
    """The median error over the seeds for two swept keys; cells where a seed failed marked x."""
    plt = _mpl()
    from matplotlib.colors import LogNorm

    kx, ky = keys
    xs = sorted({float(r[kx]) for r in rows})
    ys = sorted({float(r[ky]) for r in rows})
    z = np.full((len(ys), len(xs)), np.nan)
    failed = np.zeros_like(z, dtype=bool)
    for j, y in enumerate(ys):
        for i, x in enumerate(xs):
            cell = [r for r in rows if float(r[kx]) == x and float(r[ky]) == y]
            errs = [float(r["max_error_m"]) for r in cell]
            if cell and np.isfinite(errs).any():
                z[j, i] = np.nanmedian(errs)
            failed[j, i] = any(not r["passed"] for r in cell)
    fig, ax = plt.subplots(figsize=(7, 5))
    positive = z[np.isfinite(z) & (z > 0)]
    norm = LogNorm(vmin=positive.min(), vmax=positive.max()) if positive.size else None
    im = ax.imshow(z, origin="lower", aspect="auto", norm=norm, cmap="viridis")
    for j, i in zip(*np.nonzero(failed), strict=True):
        ax.text(i, j, "x", ha="center", va="center", color="white", fontsize=9)
    ax.set_xticks(range(len(xs)), [f"{x:g}" for x in xs], rotation=45)
    ax.set_yticks(range(len(ys)), [f"{y:g}" for y in ys])
    ax.set_xlabel(kx)
    ax.set_ylabel(ky)
    ax.set_title(f"{title} (x: a seed past {bound_m:g} m)")
    fig.colorbar(im, ax=ax, label="median largest error after settling [m]")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
