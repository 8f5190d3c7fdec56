"""Close-ups of two bakes of the same character and clip, before and after a change to the defaults, at each one's
hardest frames: one row per frame, static | before | after, zoomed on where the skin moved most, on one colour scale.

    python benchmarks/before_after.py BEFORE_DIR AFTER_DIR --out docs/images/NAME.png [--title TEXT] [--frames N]
                                      [--parts MUSCLE,...]

BEFORE_DIR and AFTER_DIR are `jiggle bake --out` folders with bake.npz (a bake of an earlier revision: check it out
with `git archive REV | tar -x -C DIR` and run its `jiggle bake` there). The frames are the N (default 2) with the
largest skin jiggle in either bake; the box is a hand's width (0.12 of the body's extent) around the vertex that
moved most in that frame in either, seen along its normal made level. The figure says each frame's largest jiggle:
the skin's move from where the swung chains alone put it (BakeData.skin_swung; the static skin without chains).
"""
from __future__ import annotations

import argparse
import sys

import numpy as np


def hardest_frames(a: np.ndarray, b: np.ndarray, count: int) -> list[int]:
    """Frame indices: the `count` frames whose largest jiggle (of either displacement (T, V)) is largest, at least
    a tenth of the clip apart."""
    top = np.maximum(a.max(axis=1), b.max(axis=1))
    gap = max(len(top) // 10, 1)
    out = []
    for k in np.argsort(-top):
        if all(abs(int(k) - j) >= gap for j in out):
            out.append(int(k))
        if len(out) == count:
            break
    return sorted(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("before")
    ap.add_argument("after")
    ap.add_argument("--out", required=True)
    ap.add_argument("--title", default="")
    ap.add_argument("--frames", type=int, default=2)
    ap.add_argument("--parts", default=None, help="comma-separated muscles: only the skin nearest them (its nearest "
                    "control point theirs, at the first frame) picks the frames and the box")
    args = ap.parse_args(argv)
    from jiggle.rig.character.normals import VertexNormals
    from jiggle.sim.app.report.compare_render import SideBySide, write_png
    from jiggle.sim.bake.caches import read_npz
    before, after = read_npz(f"{args.before}/bake.npz"), read_npz(f"{args.after}/bake.npz")
    if before.skin_static.shape != after.skin_static.shape:
        print("the two bakes have different skins or frames", file=sys.stderr)
        return 2
    # the tissue's jiggle: against the skin that follows the swung chains (tails, ears) without it
    refs = [d.skin_swung() for d in (before, after)]
    disp = [np.linalg.norm(d.skin_final - r, axis=2) for d, r in zip((before, after), refs)]
    if args.parts:
        from scipy.spatial import cKDTree
        names = list(after.muscle_names)
        want = [names.index(n.strip()) for n in args.parts.split(",")]
        owner = np.repeat(np.arange(len(names)), np.diff(after.muscle_cv_offsets))
        _, near = cKDTree(after.muscle_cvs_static[0]).query(refs[1][0])
        keep = np.isin(owner[near], want)
        disp = [np.where(keep[None], d, 0.0) for d in disp]
    top = 1e3 * max(float(d.max()) for d in disp)
    static = refs[1]
    extent = float(np.ptp(static[0], axis=0).max())
    half = 0.12 * extent
    normals = VertexNormals(after.faces, static.shape[1])
    r = SideBySide(after.faces, static.shape[1], (0.0, max(top, 1e-3)), panel=(420, 380))
    rows = []
    try:
        for k in hardest_frames(disp[0], disp[1], args.frames):
            v = int(np.argmax(np.maximum(disp[0][k], disp[1][k])))
            c = static[k][v].astype(np.float64)
            n = normals(static[k].astype(np.float64))[v]
            side = n[:2] / np.linalg.norm(n[:2]) if np.linalg.norm(n[:2]) > 0.2 else np.array([0.0, -1.0])
            direction = np.array([side[0], side[1], 0.35])
            direction /= np.linalg.norm(direction)
            box = np.stack([c - half, c + half])
            t = f"frame {k}, t = {after.times[k]:.2f} s"
            left = r.draw(refs[0][k], before.skin_final[k], box, direction, f"static  {t}",
                          f"before  largest {1e3 * disp[0][k].max():.1f} mm")
            right = r.draw(static[k], after.skin_final[k], box, direction, f"static  {t}",
                           f"after  largest {1e3 * disp[1][k].max():.1f} mm")
            rows.append(np.concatenate([left, right[:, right.shape[1] // 2:]], axis=1))
    finally:
        r.close()
    image = np.concatenate(rows, axis=0)
    if args.title:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        h, w = image.shape[:2]
        fig = plt.figure(figsize=(w / 100, (h + 40) / 100), dpi=100)
        fig.text(0.01, 1 - 20 / (h + 40), args.title, fontsize=12, va="center")
        ax = fig.add_axes((0, 0, 1, h / (h + 40)))
        ax.imshow(image)
        ax.axis("off")
        fig.canvas.draw()
        image = np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()
        plt.close(fig)
    write_png(image, args.out)
    print(args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
