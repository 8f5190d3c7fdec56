"""Parse 01_01.bvh (2 MB, 2752 frames) and evaluate world transforms of every frame through MuJoCo,
against a straightforward NumPy forward kinematics of the same clip (tests/bvh_reference.py: per
frame, per joint, 4x4 matrices from the channel values), all measured in this one run.

    .venv/bin/python benchmarks/bench_mocap_fk.py [path/to/clip.bvh]

Prints the times (best of a few repeats) and the ratios; the budget in the issue is 0.5 s for parse
plus MuJoCo evaluation together.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

import bvh_reference  # noqa: E402  the tests' independent FK: 4x4 matrices per joint per frame
from timing import best  # noqa: E402  (benchmarks/timing.py)

from jiggle.rig.motion.bvh import read_bvh  # noqa: E402
from jiggle.sim.drive.skeleton import Skeleton  # noqa: E402

DEFAULT = ROOT.parent / "shared" / "assets" / "mocap" / "cmu_bvh" / "01_01.bvh"


def main(path: Path = DEFAULT) -> None:
    if not path.exists():
        print(f"skipped: {path} not found (../shared/assets is absent)")
        return
    t_parse, clip = best(lambda: read_bvh(path, tpose="keep"))
    t_build, sk = best(lambda: Skeleton(clip))
    t_mj, (rot, pos) = best(lambda: sk.world())
    t_np_vec, _ = best(lambda: clip.world())
    joints, _, values, _ = bvh_reference.parse(path.read_text())
    t_ref, ref = best(lambda: bvh_reference.world_positions(joints, values), repeats=1)
    err = np.abs(bvh_reference.to_zup_metres(ref, clip.meta["metres_per_unit"]) - pos).max()
    total = t_parse + t_build + t_mj
    F, J = clip.num_frames, clip.num_joints
    print(f"clip: {path.name}, {F} frames x {J} joints ({path.stat().st_size / 1e6:.1f} MB)")
    print(f"{'stage':44s} {'seconds':>9s}")
    print(f"{'parse BVH (rig.motion.bvh.read_bvh)':44s} {t_parse:9.4f}")
    print(f"{'build MuJoCo model (sim.drive.skeleton)':44s} {t_build:9.4f}")
    print(f"{'world transforms, all frames (mj_kinematics)':44s} {t_mj:9.4f}")
    print(f"{'parse + build + MuJoCo FK (budget 0.5 s)':44s} {total:9.4f}")
    print(f"{'NumPy vectorised FK (Clip.world)':44s} {t_np_vec:9.4f}")
    print(f"{'straightforward NumPy FK (4x4 per joint)':44s} {t_ref:9.4f}")
    print(f"ratio straightforward NumPy FK / MuJoCo FK:            {t_ref / t_mj:7.1f}x")
    print(f"ratio straightforward NumPy FK / (parse + MuJoCo FK):  {t_ref / total:7.1f}x")
    print(f"ratio vectorised NumPy FK / MuJoCo FK:                 {t_np_vec / t_mj:7.2f}x")
    print(f"max |MuJoCo - reference| = {err:.2e} m; per frame MuJoCo {1e6 * t_mj / F:.1f} us")


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else DEFAULT)
