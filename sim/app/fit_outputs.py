"""What `jiggle fit` writes: the fitted musculature as TOML, its facts as JSON, and a picture.

muscles.toml  per muscle: kind, bone, attachments (joint names and bind points), ellipsoid, fit error,
              volume, default jiggle parameters and the 5 x 8 rest section CVs (metres, Z-up)
fit.png       segmentation (skin coloured by region), then the translucent skin over the lofted
              muscles (one colour each, fat in yellow) and their tendons, from the front, side and back
"""
from __future__ import annotations

import dataclasses
import os

import numpy as np

from rig.base.atomic import atomic_path
from rig.muscle.fit import Musculature
from sim.app.mesh_render import SKIN, VIEWS, frame_camera

os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")


def musculature_facts(mus: Musculature) -> dict:
    """JSON-ready summary: counts, timings, per-muscle volume and fit error."""
    rig = mus.rig
    names = mus.character.joint_names
    return {
        "character": mus.character.name, "template": mus.template.name,
        "muscles": len(mus.muscles), "fat": sum(m.kind == "fat" for m in mus.muscles),
        "skipped": [{"name": n, "reason": r} for n, r in mus.skipped],
        "segments": len(mus.segmentation.segments.labels),
        "vertices_rejected_by_normal_test": int((~mus.segmentation.accepted).sum()),
        "seconds": {k: round(float(v), 3) for k, v in mus.timings.items()},
        "per_muscle": [{"name": m.name, "kind": m.kind, "bone": m.bone_label,
                        "joints": [names[j] for j in m.joints],
                        "volume_cm3": round(float(rig.rest_volume[i]) * 1e6, 2),
                        "fit_rms_mm": round(float(rig.fit_rms[i]) * 1e3, 3),
                        "fit_max_mm": round(float(rig.fit_max[i]) * 1e3, 3),
                        "rays_missed": m.report.misses}
                       for i, m in enumerate(mus.muscles)],
    }


def _toml_value(v) -> str:
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        return repr(round(float(v), 7))
    if isinstance(v, np.ndarray):
        v = v.tolist()
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {type(v)} to TOML")


def musculature_toml(mus: Musculature) -> str:
    """The fitted musculature as TOML text (see the module docstring)."""
    names = mus.character.joint_names
    rig = mus.rig
    lines = ["# jiggle fitted musculature: metres, Z-up, bind pose", f"character = {_toml_value(mus.character.name)}",
             f"source = {_toml_value(mus.character.source)}", f"template = {_toml_value(mus.template.name)}",
             f"cvs_per_muscle = {rig.cv_offsets[1] - rig.cv_offsets[0]}", ""]
    for i, m in enumerate(mus.muscles):
        cvs = rig.rest_cvs[rig.cv_offsets[i]:rig.cv_offsets[i + 1]]
        e = m.ellipsoid
        jig = dataclasses.asdict(m.spec.jiggle) if dataclasses.is_dataclass(m.spec.jiggle) else {}
        lines += ["[[muscle]]", f"name = {_toml_value(m.name)}", f"kind = {_toml_value(m.kind)}",
                  f"group = {_toml_value(m.group)}", f"side = {_toml_value(m.side)}",
                  f"bone = {_toml_value(m.bone_label)}",
                  f"joints = {_toml_value([names[j] for j in m.joints])}  # origin, oHinge, iHinge, insertion",
                  f"points = {_toml_value(np.round(m.points, 6))}",
                  f"ellipsoid_centre = {_toml_value(np.round(e.centre, 6))}",
                  f"ellipsoid_axes = {_toml_value(np.round(e.axes, 6))}",
                  f"ellipsoid_radii = {_toml_value(np.round(e.radii, 6))}",
                  f"volume_m3 = {_toml_value(float(rig.rest_volume[i]))}",
                  f"fit_rms_m = {_toml_value(float(rig.fit_rms[i]))}",
                  f"fit_max_m = {_toml_value(float(rig.fit_max[i]))}",
                  f"jiggle = {{ {', '.join(f'{k} = {_toml_value(v)}' for k, v in jig.items())} }}",
                  f"section_cvs = {_toml_value(np.round(cvs, 6))}", ""]
    return "\n".join(lines)


def write_fit_outputs(mus: Musculature, toml_path: str | None, png_path: str | None,
                      json_path: str | None = None) -> dict:
    """Write whichever of muscles TOML, PNG and JSON paths are given (atomically); returns {kind: path}."""
    import json
    out = {}
    if toml_path:
        with atomic_path(toml_path) as tmp, open(tmp, "w") as fh:
            fh.write(musculature_toml(mus))
        out["muscles"] = toml_path
    if json_path:
        with atomic_path(json_path) as tmp, open(tmp, "w") as fh:
            json.dump(musculature_facts(mus), fh, indent=1)
        out["facts"] = json_path
    if png_path:
        render_musculature(mus, png_path)
        out["picture"] = png_path
    return out


def render_musculature(mus: Musculature, path: str, size: tuple[int, int] = (1800, 800),
                       views=("front", "side", "back")) -> str:
    """PNG: the segmentation, then the skin (translucent) over coloured muscles and tendons per view."""
    import matplotlib
    import pyvista as pv

    ch = mus.character
    v, f = np.asarray(ch.vertices), np.asarray(ch.faces, np.int64)
    skin = pv.PolyData(v, np.hstack([np.full((len(f), 1), 3), f]).ravel())
    skin.point_data["region"] = mus.segmentation.region % 20
    rig = mus.rig
    surf = rig.surface(rig.rest_cvs)
    sf = np.asarray(rig.surface_faces, np.int64)
    cmap = matplotlib.colormaps["tab20"]
    meshes = []
    for i, m in enumerate(mus.muscles):
        colour = (0.95, 0.8, 0.2) if m.kind == "fat" else cmap(i % 20)[:3]
        meshes.append((pv.PolyData(surf[i], np.hstack([np.full((len(sf), 1), 3), sf]).ravel()), colour))
    scale = float(np.ptp(v, axis=0).max())
    pts = np.concatenate([t.reshape(-1, 3) for m in mus.muscles for t in m.tendons])
    lines = np.hstack([[3, 3 * k, 3 * k + 1, 3 * k + 2] for k in range(len(pts) // 3)])
    tendons = pv.PolyData(pts, lines=lines).tube(radius=0.0025 * scale)

    panels = [("segmentation", "front")] + [(view, view) for view in views]
    pl = pv.Plotter(off_screen=True, shape=(1, len(panels)), window_size=list(size), border=False)
    for i, (title, view) in enumerate(panels):
        pl.subplot(0, i)
        pl.set_background("white")
        if title == "segmentation":
            pl.add_mesh(skin.copy(deep=False), scalars="region", cmap="tab20", clim=(-0.5, 19.5), n_colors=20,
                        show_scalar_bar=False, smooth_shading=True)
        else:
            for mesh, colour in meshes:
                pl.add_mesh(mesh, color=colour, smooth_shading=True, specular=0.3)
            pl.add_mesh(tendons, color=(0.92, 0.92, 0.85))
            pl.add_mesh(skin.copy(deep=False), color=SKIN, opacity=0.22, smooth_shading=True)
        frame_camera(pl, v, np.asarray(VIEWS[view], float), np.array([0.0, 0.0, 1.0]), size[0] / len(panels) / size[1])
        pl.add_text(title, position="lower_left", font_size=10, color="black")
        if i == 0:
            pl.add_text(f"{ch.name or 'character'}: {len(mus.muscles)} muscles", position="upper_left",
                        font_size=11, color="black")
    with atomic_path(path) as tmp:
        pl.screenshot(tmp)
    pl.close()
    return path
