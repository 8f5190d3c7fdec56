"""Parse 01_01.bvh (2 MB, 2752 frames) and evaluate world transforms of every frame through MuJoCo,
against a straightforward NumPy forward kinematics of the same clip (per frame, per joint, 4x4
matrices from the channel values), all measured in this one run.

    .venv/bin/python benchmarks/bench_mocap_fk.py [path/to/clip.bvh]

Prints the times (best of a few repeats) and the ratios; the budget in the issue is 0.5 s for parse
plus MuJoCo evaluation together.
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from rig.bvh import read_bvh  # noqa: E402
from sim.skeleton import Skeleton  # noqa: E402

DEFAULT = ROOT.parent / "shared" / "assets" / "mocap" / "cmu_bvh" / "01_01.bvh"


def best(fn, repeats=3):
    times, out = [], None
    for _ in range(repeats):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return min(times), out


def _axis_matrix(axis: str, deg: np.ndarray) -> np.ndarray:
    a = np.radians(deg)
    c, s = np.cos(a), np.sin(a)
    m = np.eye(4)
    i, j = {"X": (1, 2), "Y": (2, 0), "Z": (0, 1)}[axis]
    m[i, i], m[i, j], m[j, i], m[j, j] = c, -s, s, c
    return m


def numpy_fk(clip_values: np.ndarray, layout, parents) -> np.ndarray:
    """The straightforward reference: a loop over frames and joints with 4x4 matrix products.

    clip_values : (F, C) raw channel values; layout : per joint (offset, [(channel, column)]).
    Returns (F, J, 4, 4) world matrices in file units and axes.
    """
    F, J = clip_values.shape[0], len(layout)
    out = np.empty((F, J, 4, 4))
    for f in range(F):
        for j, (offset, chans) in enumerate(layout):
            local = np.eye(4)
            local[:3, 3] = offset
            for name, col in chans:
                if name.endswith("position"):
                    local[{"X": 0, "Y": 1, "Z": 2}[name[0]], 3] = clip_values[f, col]
                else:
                    local = local @ _axis_matrix(name[0], clip_values[f, col])
            out[f, j] = local if parents[j] < 0 else out[f, parents[j]] @ local
    return out


def raw_layout(path: Path):
    """Channel layout and values straight from the file, for the reference."""
    tok = path.read_text().split()
    layout, parents, stack, col, i = [], [], [], 0, 0
    while tok[i] != "MOTION":
        t = tok[i]
        if t in ("ROOT", "JOINT"):
            parents.append(stack[-1] if stack else -1)
            layout.append([None, []])
            stack.append(len(layout) - 1)
            i += 3
        elif t == "End":
            i += 8
        elif t == "OFFSET":
            layout[stack[-1]][0] = np.array(tok[i + 1:i + 4], float)
            i += 4
        elif t == "CHANNELS":
            n = int(tok[i + 1])
            layout[stack[-1]][1] = [(c, col + k) for k, c in enumerate(tok[i + 2:i + 2 + n])]
            col += n
            i += 2 + n
        elif t == "}":
            stack.pop()
            i += 1
        else:
            i += 1
    frames = int(tok[i + 2])
    values = np.array(tok[i + 6:], float).reshape(frames, -1)
    return layout, parents, values


def main(path: Path = DEFAULT) -> None:
    if not path.exists():
        print(f"skipped: {path} not found (../shared/assets is absent)")
        return
    t_parse, clip = best(lambda: read_bvh(path, tpose="keep"))
    t_build, sk = best(lambda: Skeleton(clip))
    t_mj, (rot, pos) = best(lambda: sk.world())
    t_np_vec, _ = best(lambda: clip.world())
    layout, parents, values = raw_layout(path)
    t_ref, ref = best(lambda: numpy_fk(values, layout, parents), repeats=1)
    scale = clip.meta["metres_per_unit"]
    ref_pos = np.stack([ref[..., 0, 3], -ref[..., 2, 3], ref[..., 1, 3]], -1) * scale
    err = np.abs(ref_pos - pos).max()
    total = t_parse + t_build + t_mj
    F, J = clip.num_frames, clip.num_joints
    print(f"clip: {path.name}, {F} frames x {J} joints ({path.stat().st_size / 1e6:.1f} MB)")
    print(f"{'stage':44s} {'seconds':>9s}")
    print(f"{'parse BVH (rig.bvh.read_bvh)':44s} {t_parse:9.4f}")
    print(f"{'build MuJoCo model (sim.skeleton)':44s} {t_build:9.4f}")
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
