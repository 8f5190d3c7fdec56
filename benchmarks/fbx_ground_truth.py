"""FBX read against the authoring tool's own meshes, in every FBX form: ufbx's test files (github.com/ufbx/ufbx,
`data/`), where Maya, 3ds Max and Blender wrote one scene as FBX 6.1 and 7.x, binary and ASCII, and exported the
skinned mesh at given frames as OBJ. jiggle reads each FBX (rig.motion.fbx: ASCII and 6.x through
rig.motion.fbx_tree / fbx_legacy, then Blender's importer), poses its skin at the frame, and measures the largest
distance to the OBJ's vertices (both ways, as point sets: the glTF splits vertices at UV seams). OBJ files carry no
unit: the OBJ's unit is the common unit (mm, cm, inch, m, ...) nearest to the one that makes the two meshes' median
radii equal, and reported (a unit read
wrongly from the FBX shows there, not in the distance).

    python benchmarks/fbx_ground_truth.py --data UFBX_CHECKOUT/data [--out benchmarks/results/fbx_ground_truth]

The files are not shipped (ufbx's test data is not ours to copy); fetch the ufbx repository and point --data at its
data folder. Prints a table and writes OUT.md / OUT.json.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

# (scene, its FBX forms, OBJ frames, fps, OBJ axes: "y" Y-up or "z" Z-up, the take's name or None for the first)
CASES = [
    ("maya_game_sausage", ["6100_ascii_wiggle", "6100_binary_wiggle", "7500_ascii_wiggle", "7500_binary_wiggle"],
     [("maya_game_sausage_wiggle_10", 10), ("maya_game_sausage_wiggle_18", 18)], 24.0, "y", None),
    ("blender_279_sausage", ["6100_ascii", "7400_binary"],
     [("blender_279_sausage_wiggle_20", 20)], 24.0, "y", "Wiggle"),
    ("max_transformed_skin", ["6100_ascii", "6100_binary", "7500_ascii", "7500_binary"],
     [("max_transformed_skin_5", 5), ("max_transformed_skin_15", 15)], 30.0, "z", None),
]


UNITS = (0.001, 0.01, 0.0254, 0.1, 0.3048, 1.0, 10.0, 100.0)
"""Units an OBJ may be in (mm, cm, inch, dm, foot, m, ...): the median-radius guess is snapped to one."""


def obj(path: Path, axes: str) -> np.ndarray:
    v = np.array([[float(x) for x in ln.split()[1:4]] for ln in open(path) if ln.startswith("v ")])
    return np.column_stack([v[:, 0], -v[:, 2], v[:, 1]]) if axes == "y" else v


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", required=True, help="ufbx's data folder")
    ap.add_argument("--out", default=None, help="write OUT.md and OUT.json")
    a = ap.parse_args(argv)
    from scipy.spatial import cKDTree

    from jiggle.rig.base.errors import InputError, JiggleWarning
    from jiggle.rig.character.load import load_character
    from jiggle.rig.motion.clip import transforms
    from jiggle.rig.motion.fbx import fbx_to_gltf
    from jiggle.rig.motion.mocap import load_clip
    from jiggle.rig.skin.skinning import pose_character
    warnings.simplefilter("ignore", JiggleWarning)
    data = Path(a.data)
    rows = []
    for scene, forms, frames, fps, axes, take in CASES:
        for form in forms:
            p = data / f"{scene}_{form}.fbx"
            if not p.is_file():
                print(f"{p.name}: absent, skipped")
                continue
            t0 = time.perf_counter()
            try:
                c = load_character(p)
                anim = None
                if take:
                    import pygltflib
                    names = [x.name for x in pygltflib.GLTF2().load(fbx_to_gltf(p)).animations]
                    anim = next(i for i, n in enumerate(names) if take in n)
                clip = load_clip(p, animation=anim)
            except InputError as e:
                rows.append({"file": p.name, "error": str(e)})
                print(f"{p.name}: {e}")
                continue
            secs = time.perf_counter() - t0
            order = [clip.joint_names.index(n) for n in c.joint_names]
            for ref_name, f in frames:
                ref = obj(data / f"{ref_name}.obj", axes)
                t = min(f / fps - clip.meta["start_time"], clip.duration)
                world = transforms(*clip.world(*clip.sample(np.array([t]))))[0][order]
                ours = pose_character(c, world)
                guess = np.median(np.linalg.norm(ours - ours.mean(0), axis=1)) / \
                    np.median(np.linalg.norm(ref - ref.mean(0), axis=1))   # the OBJ is in the tool's own unit
                scale = min(UNITS, key=lambda u: abs(np.log(u / guess)))
                ref = ref * scale
                d = max(cKDTree(ours).query(ref)[0].max(), cKDTree(ref).query(ours)[0].max())
                rows.append({"file": p.name, "frame": f, "max_m": float(d), "height_m": float(c.height),
                             "relative": float(d / c.height), "obj_unit_m": float(scale), "read_s": round(secs, 2)})
                print(f"{p.name:45s} frame {f:3d}: {d:.2e} m ({d / c.height:.1e} of the height; OBJ unit read as "
                      f"{scale:.4g} m)")
    if a.out:
        Path(a.out).parent.mkdir(parents=True, exist_ok=True)
        Path(a.out + ".json").write_text(json.dumps(rows, indent=1))
        lines = ["| file | frame | max distance (m) | of the height | OBJ unit (m) | read (s) |",
                 "| --- | --- | --- | --- | --- | --- |"]
        lines += [f"| {r['file']} | {r['frame']} | {r['max_m']:.2e} | {r['relative']:.1e} | {r['obj_unit_m']:.4g} | "
                  f"{r['read_s']} |" if "max_m" in r else f"| {r['file']} | | {r['error']} | | | |" for r in rows]
        Path(a.out + ".md").write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    os.environ.setdefault("JIGGLE_CACHE", os.path.join(os.environ.get("TMPDIR", "/tmp"), "jiggle_fbx_gt"))
    raise SystemExit(main())
