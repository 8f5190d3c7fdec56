"""Matplotlib figures written to PNG (Agg backend, no display needed)."""
from __future__ import annotations

import numpy as np

from rig.base.atomic import atomic_path


def pyplot():
    """matplotlib.pyplot on the Agg backend (no display needed)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def save_figure(fig, path: str) -> str:
    """Lay out `fig`, write it to `path` as PNG (100 dpi) atomically, close it; return the path."""
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=100)
    pyplot().close(fig)
    return path


def plot_joint_trajectories(times: np.ndarray, positions: np.ndarray, names: list[str], path: str,
                            title: str = "") -> str:
    """World x, y, z of the named joints over time, one panel per axis.

    times : (N,) seconds; positions : (N, K, 3) metres of the K joints in `names`.
    """
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(3, 1, figsize=(10, 8), sharex=True)
    for a, ax in enumerate(axes):
        for k, n in enumerate(names):
            ax.plot(times, positions[:, k, a], label=n, lw=1.2)
        ax.set_ylabel(f"{'xyz'[a]} (m)")
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("time (s)")
    axes[0].legend(loc="upper right", fontsize=8, ncol=min(4, len(names)))
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
