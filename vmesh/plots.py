"""Pictures: quality histograms (matplotlib, no screen needed)."""

from __future__ import annotations

import numpy as np

from .io.atomic import atomic_path


def quality_histogram(sj: np.ndarray, path, title: str = "", bins: int = 50) -> None:
    """Histogram of scaled Jacobians (like the paper's Fig. 10), with min/mean marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3.6), dpi=120)
    plot_quality_axes(ax, sj, bins=bins)
    if title:
        ax.set_title(title, fontsize=10)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)


def plot_quality_axes(ax, sj, bins=50, label=None):
    sj = np.asarray(sj)
    ax.hist(sj, bins=np.linspace(min(0.0, sj.min() if len(sj) else 0), 1, bins + 1), color="#3b75af", edgecolor="white", linewidth=0.3, label=label)
    ax.set_yscale("log")
    ax.set_xlabel("scaled Jacobian")
    ax.set_ylabel("elements")
    if len(sj):
        ax.axvline(sj.min(), color="#c0392b", lw=1, ls="--")
        ax.axvline(sj.mean(), color="#27ae60", lw=1, ls="--")
        ax.text(0.02, 0.95, f"min {sj.min():.3f}\nmean {sj.mean():.3f}\nn = {len(sj)}", transform=ax.transAxes, va="top", fontsize=8)
