"""What `jiggle deform` writes: smooth skinning against muscle-driven skin at one pose.

deform.png    per view, LBS alone | LBS + muscles, the muscle-driven skin coloured by how far each vertex
              moved from LBS (millimetres), the muscles drawn through the skin on the left
deform.json   the pose, the skinning, pairs kept at bind, and the displacement from LBS (max, RMS,
              per muscle the largest move of a vertex it may touch)
deform.ply    the muscle-driven skin at that pose (metres, Z-up)
"""
from __future__ import annotations

import json
import os

import numpy as np

from jiggle.rig.base.atomic import atomic_path
from jiggle.rig.skin.muscle_skin import MuscleSkin
from jiggle.sim.app.report.mesh_render import SKIN, VIEWS, frame_camera

os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")


def deform_facts(skin: MuscleSkin, lbs: np.ndarray, deformed: np.ndarray) -> dict:
    """JSON-ready comparison of the muscle-driven skin with LBS at one pose (both (V, 3) metres)."""
    move = np.linalg.norm(np.asarray(deformed, np.float64) - lbs, axis=1)
    rig = skin.rig
    per = np.zeros(rig.M)
    np.maximum.at(per, skin.pair_muscle, move[np.repeat(np.arange(len(move)), np.diff(skin.pair_offsets))])
    return {
        "skinning": skin.skinning, "method": skin.method, "vertices": int(len(move)),
        "muscles": rig.M, "pairs": skin.num_pairs,
        "pairs_per_vertex": round(skin.num_pairs / max(len(move), 1), 3),
        "max_displacement_mm": round(float(move.max(initial=0.0)) * 1e3, 3),
        "rms_displacement_mm": round(float(np.sqrt(np.mean(move ** 2))) * 1e3 if len(move) else 0.0, 3),
        "vertices_moved_over_0.1mm": int((move > 1e-4).sum()),
        "per_muscle_max_mm": {n: round(float(v) * 1e3, 3) for n, v in zip(rig.names, per)},
    }


def render_comparison(lbs: np.ndarray, deformed: np.ndarray, faces: np.ndarray, path: str, *,
                      muscles: list[tuple[np.ndarray, np.ndarray]] = (), title: str = "",
                      views=("front", "side"), size: tuple[int, int] = (1600, 800)) -> str:
    """PNG: for each view, LBS (translucent over the muscle meshes) | muscle-driven skin coloured by
    its distance from LBS in millimetres (one colour scale for all panels). Written atomically."""
    import pyvista as pv

    f = np.hstack([np.full((len(faces), 1), 3), np.asarray(faces, np.int64)]).ravel()
    move = 1e3 * np.linalg.norm(np.asarray(deformed, np.float64) - lbs, axis=1)
    a = pv.PolyData(np.asarray(lbs, float), f)
    b = pv.PolyData(np.asarray(deformed, float), f)
    b.point_data["moved from LBS (mm)"] = move
    top = max(float(move.max(initial=0.0)), 1e-3)
    meshes = [pv.PolyData(np.asarray(v, float), np.hstack([np.full((len(t), 1), 3), np.asarray(t, np.int64)]).ravel())
              for v, t in muscles]
    both = np.concatenate([lbs, deformed])
    panels = [(view, side) for view in views for side in ("LBS", "muscles")]
    pl = pv.Plotter(off_screen=True, shape=(1, len(panels)), window_size=list(size), border=False)
    for i, (view, side) in enumerate(panels):
        pl.subplot(0, i)
        pl.set_background("white")
        if side == "LBS":
            for m in meshes:
                pl.add_mesh(m, color=(0.75, 0.2, 0.2), smooth_shading=True)
            pl.add_mesh(a, color=SKIN, opacity=0.35 if meshes else 1.0, smooth_shading=True)
        else:
            pl.add_mesh(b.copy(deep=False), scalars="moved from LBS (mm)", cmap="YlOrRd", clim=(0.0, top),
                        smooth_shading=True, show_scalar_bar=i == len(panels) - 1,
                        scalar_bar_args={"color": "black", "title_font_size": 12, "label_font_size": 10})
        frame_camera(pl, both, np.asarray(VIEWS[view], float), np.array([0.0, 0.0, 1.0]),
                     size[0] / len(panels) / size[1])
        pl.add_text(f"{side}, {view}", position="lower_left", font_size=10, color="black")
        if i == 0 and title:
            pl.add_text(title, position="upper_left", font_size=11, color="black")
    with atomic_path(path) as tmp:
        pl.screenshot(tmp)
    pl.close()
    return path


def write_deform_outputs(skin: MuscleSkin, world: np.ndarray, out_dir: str, *, pose: dict, render: bool = True,
                         views=("front", "side")) -> dict:
    """Pose the skin at joint world transforms `world` (J, 4, 4), write deform.json, deform.ply and
    (unless render is False) deform.png into `out_dir`; returns {"facts": ..., "files": {kind: path}}."""
    import trimesh
    os.makedirs(out_dir, exist_ok=True)
    lbs = skin.lbs(world)
    static = skin.rig.static(world)
    deformed = skin.pose(world, static.cvs, static.curve)
    facts = {"pose": pose, **deform_facts(skin, lbs, deformed)}
    files = {}
    ply = os.path.join(out_dir, "deform.ply")
    with atomic_path(ply) as tmp:
        trimesh.Trimesh(deformed, skin.character.faces, process=False).export(tmp)
    files["mesh"] = ply
    if render:
        surf = skin.rig.surface(static.cvs)
        muscles = [(s, skin.rig.surface_faces) for s in surf]
        title = (f"{skin.character.name or 'character'}: LBS | {skin.skinning} "
                 f"(max {facts['max_displacement_mm']:.1f} mm)")
        files["picture"] = render_comparison(lbs, deformed, skin.character.faces,
                                             os.path.join(out_dir, "deform.png"), muscles=muscles, title=title,
                                             views=views)
    js = os.path.join(out_dir, "deform.json")
    with atomic_path(js) as tmp, open(tmp, "w") as fh:
        json.dump(facts, fh, indent=2)
    files["facts"] = js
    return {"facts": facts, "files": files}
