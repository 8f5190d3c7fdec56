"""compare's look at a bake's glb (`jiggle bake --formats glb`): the file read back as an engine reads it
(jiggle's glTF reader: its skin, weights and animation), played at every frame and measured against skin_final
(sim.bake.glb.report: RMS, p99, max per frame, the share of the muscles' motion the bones make), and the worst
frame drawn close up: skin_final | played from the glb, coloured by the distance between them.
"""
from __future__ import annotations

import os

import numpy as np


def glb_check(out_dir: str, data, png: str | None) -> tuple[dict, str | None]:
    """(metrics, the close-up's path or None) of OUT_DIR/bake.glb against the bake's data (BakeData)."""
    from jiggle.rig.character.gltf_character import read_gltf_character
    from jiggle.sim.bake.glb import GLB_NAME, played_from_file, report
    path = os.path.join(out_dir, GLB_NAME)
    played = played_from_file(path, len(data.times))
    T = len(played)
    final = np.asarray(data.skin_final[:T], np.float64)
    lbs = np.asarray(data.skin_lbs[:T] if data.skin_lbs is not None else data.skin_static[:T], np.float64)
    rep = report(played, lbs, final)
    bones = [n for n in read_gltf_character(path).joint_names if "_jiggle_" in n]
    out = {"file": GLB_NAME, "bytes": os.path.getsize(path), "bones": len(bones), "frames": T,
           "read_as": "jiggle's glTF reader: the file's own skin, weights and keys", **rep}
    drawn = _closeup(data, played, final, rep["worst_frame"], png) if png else None
    return out, drawn


def _closeup(data, played: np.ndarray, final: np.ndarray, k: int, path: str) -> str:
    from jiggle.sim.app.report.compare_render import SideBySide, write_png
    err = np.linalg.norm(played[k] - final[k], axis=1)
    v = int(np.argmax(err))
    extent = np.ptp(final[k], axis=0).max()
    half = 0.12 * extent
    c = final[k][v]
    box = np.stack([c - half, c + half])
    centre = final[k].mean(axis=0)
    side = (c - centre)[:2]
    side = side / np.linalg.norm(side) if np.linalg.norm(side) > 1e-9 else np.array([0.0, -1.0])
    direction = np.array([side[0], side[1], 0.35])
    direction /= np.linalg.norm(direction)
    r = SideBySide(data.faces, final.shape[1], (0.0, max(3.0, float(err.max()) * 1e3)), panel=(520, 440))
    try:
        image = r.draw(final[k], played[k], box, direction,
                       f"skin_final  frame {k}, t = {data.times[k]:.2f} s",
                       f"played from the glb  (colour: mm from skin_final; here up to {err.max() * 1e3:.1f} mm)")
    finally:
        r.close()
    return write_png(image, path)
