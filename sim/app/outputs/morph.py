"""What `jiggle morph` writes beside the target character: its report and a picture.

TARGET.glb        the morphed, skinned character (rig.character.gltf_write)
TARGET.morph.json marker errors, flipped triangles, feature points, RBF condition numbers, the jump
                  across zone boundaries, body dimensions measured, seconds per stage
TARGET.morph.png  canonical | target from the front and the side, markers as red dots (optional)
"""
from __future__ import annotations

import json
import os

import numpy as np

from jiggle.rig.base.atomic import atomic_path


def side_paths(out: str) -> tuple[str, str]:
    """(report JSON, picture PNG) beside the character file `out`."""
    stem = os.path.splitext(out)[0]
    return stem + ".morph.json", stem + ".morph.png"


def write_report(path: str, report: dict) -> str:
    """Strict JSON (no NaN), written atomically."""
    with atomic_path(path) as tmp:
        with open(tmp, "w") as fh:
            json.dump(report, fh, indent=1, allow_nan=False)
            fh.write("\n")
    return path


def render_morph(path: str, canonical_vertices, target_vertices, faces, markers: np.ndarray) -> str:
    """canonical (grey) and target (skin colour) side by side, front and side views; the target
    markers (n, 3) as red spheres on the target."""
    import pyvista as pv

    from jiggle.sim.app.report.mesh_render import frame_camera

    f = np.hstack([np.full((len(faces), 1), 3), np.asarray(faces, np.int64)]).ravel()
    a = np.asarray(canonical_vertices, float)
    b = np.asarray(target_vertices, float)
    gap = 1.2 * max(float(np.ptp(a[:, 0])), float(np.ptp(b[:, 0])))
    shift = np.array([gap, 0.0, 0.0])
    both = np.r_[a, b + shift]
    size = max(float(np.ptp(both, axis=0).max()), 1e-6)
    views = ((0.0, -1.0, 0.0), (1.0, 0.0, 0.0))
    pl = pv.Plotter(off_screen=True, shape=(1, 2), window_size=[1600, 900], border=False)
    for i, view in enumerate(views):
        pl.subplot(0, i)
        pl.set_background("white")
        if i == 0:
            pl.add_mesh(pv.PolyData(a, f), color=(0.75, 0.75, 0.78), smooth_shading=True)
            pl.add_mesh(pv.PolyData(b + shift, f), color=(0.93, 0.78, 0.66), smooth_shading=True)
            pl.add_mesh(pv.PolyData(np.asarray(markers, float) + shift).glyph(
                geom=pv.Sphere(radius=0.008 * size), scale=False, orient=False), color=(0.85, 0.1, 0.1))
            pts = both
            pl.add_text("canonical | target (front)", position="upper_left", font_size=11, color="black")
        else:
            pl.add_mesh(pv.PolyData(a, f), color=(0.75, 0.75, 0.78), smooth_shading=True, opacity=0.5)
            pl.add_mesh(pv.PolyData(b, f), color=(0.93, 0.78, 0.66), smooth_shading=True, opacity=0.7)
            pts = np.r_[a, b]
            pl.add_text("side, overlaid", position="upper_left", font_size=11, color="black")
        frame_camera(pl, pts, np.asarray(view), np.array([0.0, 0.0, 1.0]), 800 / 900)
    with atomic_path(path) as tmp:
        pl.screenshot(tmp)
    pl.close()
    return path
