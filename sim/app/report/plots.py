"""Matplotlib figures written to PNG (Agg backend, no display needed)."""
from __future__ import annotations

import numpy as np

from jiggle.rig.base.atomic import atomic_path


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


def plot_activation(path: str, times: np.ndarray, activation: np.ndarray, amplitude: np.ndarray, names: list,
                    order: list) -> str:
    """activation.png of `jiggle compare` for a bake with activation (`--activation on`): above, the activation
    (0 to 1) of the muscles that work hardest (the 8 of largest mean); below, the same muscles' jiggle amplitude (mm),
    so a loaded muscle's stiffening shows beside its load. times (T,) s; activation (T, M); amplitude (T, M) metres;
    order : muscle indices, hardest working first."""
    plt = pyplot()
    top = order[:8]
    fig, (ax, bx) = plt.subplots(2, 1, figsize=(10, 6), sharex=True)
    for m in top:
        line, = ax.plot(times, activation[:, m], lw=1.3, label=names[m])
        bx.plot(times, 1e3 * amplitude[:, m], lw=1.0, color=line.get_color())
    ax.set_ylabel("activation (0 to 1)")
    ax.set_ylim(0.0, 1.02)
    ax.set_title("muscle activation from the clip's joint torques (the 8 hardest-working muscles)")
    ax.legend(loc="upper right", fontsize=8, ncol=2)
    bx.set_ylabel("jiggle amplitude (mm)")
    bx.set_xlabel("time (s)")
    for a in (ax, bx):
        a.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_contacts(path: str, times: np.ndarray, collisions: dict) -> str:
    """contacts.png of `jiggle compare` for a bake with collisions: left, the deepest penetration per frame
    (mm, before the projection corrected it; the summed contact impulse, N s, on the right axis); right,
    the skin vertices inside another body part's capsule per frame, static and final skin.

    times : (T,) seconds. collisions : metrics.json's "collisions" (sim.app.report.compare.collision_metrics);
    its "per_frame" lists of T values (a list absent or of another length is left out)."""
    plt = pyplot()
    per = collisions.get("per_frame") or {}
    T = len(times)

    def series(key):
        v = per.get(key)
        return np.array([np.nan if x is None else x for x in v], np.float64) if v is not None and len(v) == T else None
    fig, (ax, sx) = plt.subplots(1, 2, figsize=(12, 4))
    depth, impulse = series("max_penetration_mm"), series("impulse_Ns")
    if depth is not None:
        ax.plot(times, depth, lw=1.3, color=(0.8, 0.25, 0.1), label="deepest penetration")
        ax.fill_between(times, 0.0, depth, color=(0.8, 0.25, 0.1), alpha=0.15)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("deepest penetration per frame (mm)\nbefore correction")
    ax.set_title(f"particle contacts: {collisions.get('frames_in_contact', 0)} frames in contact, "
                 f"deepest {collisions.get('max_penetration_mm') or 0:.3g} mm")
    ax.set_ylim(bottom=0.0)
    ax.grid(alpha=0.3)
    if impulse is not None:
        ix = ax.twinx()
        ix.plot(times, impulse, lw=0.9, color="0.45", ls="--", label="impulse (N s)")
        ix.set_ylabel("summed contact impulse (N s)")
        ix.set_ylim(bottom=0.0)
        lines = ax.get_lines() + ix.get_lines()
        ax.legend(lines, [ln.get_label() for ln in lines], fontsize=8, loc="upper right")
    static, final = series("skin_inside_static"), series("skin_inside_final")
    if static is not None:
        sx.plot(times, static, lw=1.3, color=(0.2, 0.45, 0.8), label="static skin")
    if final is not None:
        sx.plot(times, final, lw=1.3, color=(0.85, 0.35, 0.1), ls="--", label="final skin")
    si = collisions.get("skin_inside") or {}
    sx.set_xlabel("time (s)")
    sx.set_ylabel("skin vertices inside\nanother part's capsule")
    sx.set_title(f"skin inside capsules: max static {si.get('max_static', '-')}, final {si.get('max_final', '-')}")
    sx.set_ylim(bottom=0.0)
    sx.grid(alpha=0.3)
    if static is not None or final is not None:
        sx.legend(fontsize=8, loc="upper right")
    return save_figure(fig, path)
