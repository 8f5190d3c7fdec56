"""Read a finished bake (from `jiggle bake --out BAKE_DIR` or `jiggle.bake(out=...)`) and plot, per frame, how far
the final skin moves from the static one: where the jiggle is, and when.

    python examples/read_a_bake.py BAKE_DIR [PLOT.png]       # default PLOT: BAKE_DIR/skin_jiggle.png
"""
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import jiggle  # noqa: E402

folder = Path(sys.argv[1])
plot = Path(sys.argv[2]) if len(sys.argv) > 2 else folder / "skin_jiggle.png"
bake = jiggle.Bake.open(folder)
gap = np.linalg.norm(bake.skin_final - bake.skin_static, axis=2) * 1000          # (T, V) mm
fig, ax = plt.subplots(figsize=(7, 3.5))
ax.plot(bake.times, gap.max(axis=1), label="largest")
ax.plot(bake.times, np.percentile(gap, 95, axis=1), label="95th percentile")
ax.set_xlabel("clip time (s)"), ax.set_ylabel("final - static skin (mm)"), ax.legend()
ax.set_title(f"{bake.summary['name']}: {len(bake.times)} frames, {bake.skin_final.shape[1]} vertices")
fig.tight_layout()
fig.savefig(plot, dpi=120)
worst = int(gap.max(axis=1).argmax())
print(f"{bake}\nlargest jiggle {gap.max():.1f} mm at t = {bake.times[worst]:.2f} s; plot: {plot}")
