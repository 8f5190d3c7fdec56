"""Bake CesiumMan on a CMU clip from Python and plot how much its belly jiggles: the five lines a notebook needs.

    python examples/bake_from_python.py [OUT_DIR]      # writes OUT_DIR/belly.png (default: out/examples)

The character and clip are the shared assets (../shared/assets beside the repository, or $JIGGLE_ASSETS).
"""
import os
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")                      # no window: the plot goes to a file
ASSETS = Path(os.environ.get("JIGGLE_ASSETS", Path(__file__).resolve().parents[2] / "shared" / "assets"))
out = Path(sys.argv[1] if len(sys.argv) > 1 else "out/examples")
out.mkdir(parents=True, exist_ok=True)

# --- the five lines ---
import jiggle  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402

bake = jiggle.bake(ASSETS / "mocap/cmu_bvh/02_04.bvh", ASSETS / "characters/CesiumMan.glb", out=out / "cesium_02_04",
                   muscles={"belly_fat": {"strength": 0.8}})
jiggle_mm = 1000 * abs(bake.muscle("belly_fat") - bake.muscle("belly_fat", "static")).max(axis=(1, 2))
plt.plot(bake.times, jiggle_mm), plt.xlabel("clip time (s)"), plt.ylabel("belly jiggle (mm)")
plt.savefig(out / "belly.png", dpi=120)
# ---

print(f"{bake}\nbelly jiggle: up to {jiggle_mm.max():.1f} mm; plot: {out / 'belly.png'}")
