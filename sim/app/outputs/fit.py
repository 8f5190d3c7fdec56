"""What `jiggle fit` writes: the fitted musculature as TOML, its facts as JSON, and a picture.

muscles.toml  per muscle: kind, bone, attachments (joint names and bind points), ellipsoid, fit error,
              volume, default jiggle parameters and the 5 x 8 rest section CVs (metres, Z-up)
muscles.json  counts, timings, skipped muscles, and the fit quality (rig.muscle.fit_quality): its
              thresholds, a summary and per muscle the verdict, local radius, loft error as a share of
              it and the share inside the skin; refused muscles listed with their measures
fit.png       segmentation (skin coloured by region), then the translucent skin over the lofted
              muscles (one colour each, fat in yellow) and their tendons, from the front, side and back;
              a muscle that fits poorly is solid red, a refused one (not in the rig) a red wireframe,
              each labelled with its name, and listed with the reasons in the top left; with the bone
              capsules the particles collide with (sim.jiggle.colliders.collider_model: as a bake builds
              them, shrunk inside the muscles), a panel of them, one colour per body part, inside the
              translucent skin from the front (from the side for a quadruped), and muscles.json lists
              each capsule's bone, radius and length
"""
from __future__ import annotations

import dataclasses
import os

import numpy as np

from jiggle.rig.base.atomic import atomic_path
from jiggle.rig.muscle.fit import Musculature
from jiggle.sim.app.report.mesh_render import SKIN, VIEWS, frame_camera

os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")

POOR = (0.95, 0.05, 0.05)  # a muscle kept with a poor fit (rig.muscle.fit_quality "warn"), solid red
REFUSED = (0.8, 0.0, 0.0)  # a muscle the quality check refused (not in the rig), a red wireframe


def quality_summary(mus: Musculature) -> dict:
    """JSON-ready fit quality: thresholds, counts, the worst loft error and inside share and their muscles."""
    from jiggle.rig.muscle.fit_quality import thresholds
    q = list(mus.quality) + list(mus.refused)
    out = {"thresholds": thresholds(), "ok": sum(x.status == "ok" for x in q),
           "warned": [x.name for x in q if x.status == "warn"], "refused": [x.name for x in mus.refused]}
    if q:
        worst, least = max(q, key=lambda x: x.rms_share), min(q, key=lambda x: x.inside)
        out.update(worst_loft_rms_share=round(worst.rms_share, 4), worst_loft_rms_muscle=worst.name,
                   least_inside_share=round(least.inside, 4), least_inside_muscle=least.name)
    return out


def quality_line(mus: Musculature) -> str:
    """One line summing up the fit quality, naming the worst muscles, e.g. for `jiggle fit`."""
    s = quality_summary(mus)
    if "worst_loft_rms_share" not in s:
        return "fit quality: no muscles"
    line = (f"fit quality: {s['ok']} ok, {len(s['warned'])} warned, {len(s['refused'])} refused; worst rms loft "
            f"error {s['worst_loft_rms_share']:.1%} of the local radius ({s['worst_loft_rms_muscle']}; ok <= "
            f"{s['thresholds']['rms_ok']:.0%}), least inside the skin {s['least_inside_share']:.1%} "
            f"({s['least_inside_muscle']}; ok >= {s['thresholds']['inside_ok']:.0%})")
    for q in list(mus.warned) + list(mus.refused):
        line += f"\n  {q.status:7s} {q.name}: {'; '.join(q.reasons)}"
    return line


def musculature_facts(mus: Musculature) -> dict:
    """JSON-ready summary: counts, timings, per-muscle volume, fit error and fit quality."""
    rig = mus.rig
    names = mus.character.joint_names
    quality = mus.quality or (None,) * len(mus.muscles)
    return {
        "character": mus.character.name, "template": mus.template.name,
        "body_plan": mus.plan.to_json() if mus.plan is not None else None,
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
                        "rays_missed": m.report.misses, **(q.facts() if q is not None else {})}
                       for i, (m, q) in enumerate(zip(mus.muscles, quality))],
        "quality": quality_summary(mus),
        "refused": [{"name": q.name, **q.facts()} for q in mus.refused],
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
        # what the template leaves to the part's material (None) is left out: the material sets it at the bake's size
        jig = {k: v for k, v in (dataclasses.asdict(m.spec.jiggle) if dataclasses.is_dataclass(m.spec.jiggle)
                                 else {}).items() if v is not None}
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


def capsule_facts(capsules, bind_world: np.ndarray) -> list[dict]:
    """JSON-ready bone capsules (rig.character.capsules.BoneCapsules): per capsule its bone ("joint>child"),
    radius and axis length in mm at bind (bind_world (J, 4, 4))."""
    ends = capsules.ends(bind_world)
    return [{"bone": n, "radius_mm": round(1e3 * float(r), 2),
             "length_mm": round(1e3 * float(np.linalg.norm(e[1] - e[0])), 2)}
            for n, r, e in zip(capsules.names, capsules.radius, ends)]


def capsule_meshes(capsules, bind_world: np.ndarray) -> list:
    """pyvista PolyData per bone capsule at bind (bind_world (J, 4, 4)): a cylinder on the axis with
    hemispherical caps, of the capsule's radius."""
    import pyvista as pv
    out = []
    for (a, b), r in zip(capsules.ends(bind_world), capsules.radius):
        axis = b - a
        L = float(np.linalg.norm(axis))
        out.append(pv.Capsule(center=0.5 * (a + b), direction=axis / L if L > 0 else (0.0, 0.0, 1.0),
                              radius=float(r), cylinder_length=max(L, 1e-6), resolution=20))
    return out


def write_fit_outputs(mus: Musculature, toml_path: str | None, png_path: str | None,
                      json_path: str | None = None, maps: dict | None = None, capsules=None,
                      capsules_title: str = "bone capsules (collisions)") -> dict:
    """Write whichever of muscles TOML, PNG and JSON paths are given (atomically); returns {kind: path}.
    maps: {panel title: (V,) values in [0, 1]} drawn as extra panels of the PNG (the painted maps).
    capsules: the capsules the particles collide with (rig.character.capsules.BoneCapsules), drawn in a panel
    of the PNG titled `capsules_title` and listed in the JSON; None: neither."""
    import json
    out = {}
    if toml_path:
        with atomic_path(toml_path) as tmp, open(tmp, "w") as fh:
            fh.write(musculature_toml(mus))
        out["muscles"] = toml_path
    if json_path:
        facts = musculature_facts(mus)
        if capsules is not None:
            facts["capsules"] = capsule_facts(capsules, mus.character.bind_world)
        with atomic_path(json_path) as tmp, open(tmp, "w") as fh:
            json.dump(facts, fh, indent=1)
        out["facts"] = json_path
    if png_path:
        render_musculature(mus, png_path, maps=maps, capsules=capsules, capsules_title=capsules_title)
        out["picture"] = png_path
    return out


def render_musculature(mus: Musculature, path: str, size: tuple[int, int] | None = None, views=None,
                       maps: dict | None = None, capsules=None,
                       capsules_title: str = "bone capsules (collisions)") -> str:
    """PNG: the segmentation, then the skin (translucent) over coloured muscles and tendons per view.
    An upright body is drawn in a row, from the front, side and back (1800 x 800); a long one (a
    quadruped) in a 2 x 2 grid, the segmentation and the muscles from its side, then from above and
    from its right (1800 x 1100). Then the painted maps (`maps`), then the bone capsules (`capsules`,
    rig.character.capsules.BoneCapsules) in the translucent skin, each panel as wide as the others."""
    import matplotlib
    import pyvista as pv

    ch = mus.character
    v, f = np.asarray(ch.vertices), np.asarray(ch.faces, np.int64)
    skin = pv.PolyData(v, np.hstack([np.full((len(f), 1), 3), f]).ravel())
    skin.point_data["region"] = mus.segmentation.region % 20
    rig = mus.rig
    surf = rig.surface(rig.rest_cvs)
    sf = np.asarray(rig.surface_faces, np.int64)
    # tab20 without its reds and oranges, kept for the muscles that fit poorly or were refused
    palette = [c[:3] for k, c in enumerate(matplotlib.colormaps["tab20"].colors) if k not in (2, 3, 6, 7)]
    quality = mus.quality or (None,) * len(mus.muscles)
    meshes, flagged = [], []
    for i, (m, q) in enumerate(zip(mus.muscles, quality)):
        colour = (0.95, 0.8, 0.2) if m.kind == "fat" else palette[i % len(palette)]
        if q is not None and q.status != "ok":
            colour = POOR
            flagged.append((q, "poor fit"))
        meshes.append((pv.PolyData(surf[i], np.hstack([np.full((len(sf), 1), 3), sf]).ravel()), colour))
    for q in mus.refused:  # not in the rig: drawn from the loft the quality check saw
        meshes.append((pv.PolyData(np.asarray(q.surface), np.hstack([np.full((len(sf), 1), 3), sf]).ravel()),
                       REFUSED))
        flagged.append((q, "refused"))
    scale = float(np.ptp(v, axis=0).max())
    pts = np.concatenate([t.reshape(-1, 3) for m in mus.muscles for t in m.tendons])
    lines = np.hstack([[3, 3 * k, 3 * k + 1, 3 * k + 2] for k in range(len(pts) // 3)])
    tendons = pv.PolyData(pts, lines=lines).tube(radius=0.0025 * scale)

    long = mus.plan is not None and mus.plan.kind == "quadruped"
    views = views or (("side", "top", "right") if long else ("front", "side", "back"))
    size = size or ((1800, 1100) if long else (1800, 800))
    panels = [("segmentation", views[0] if long else "front")] + [(view, view) for view in views]
    # the painted maps (rig.character.painted_maps), each a panel of the skin coloured 0 (dark) to 1 (bright)
    panels += [(title, views[0] if long else "front") for title in (maps or {})]
    CAPSULES = capsules_title
    extra = len(maps or {})
    if capsules is not None and capsules.count:
        panels.append((CAPSULES, views[0] if long else "front"))
        extra += 1
        cap_meshes = capsule_meshes(capsules, ch.bind_world)
    if extra and not long:
        size = (size[0] * len(panels) // (len(panels) - extra), size[1])
    rows, cols = (2, (len(panels) + 1) // 2) if long else (1, len(panels))
    pl = pv.Plotter(off_screen=True, shape=(rows, cols), window_size=list(size), border=False)
    for i, (title, view) in enumerate(panels):
        pl.subplot(i // cols, i % cols)
        pl.set_background("white")
        if title == "segmentation":
            pl.add_mesh(skin.copy(deep=False), scalars="region", cmap="tab20", clim=(-0.5, 19.5), n_colors=20,
                        show_scalar_bar=False, smooth_shading=True)
        elif title == CAPSULES:
            # one colour per body part (the joint a capsule rides), the skin over them as over the muscles
            for c, mesh in enumerate(cap_meshes):
                pl.add_mesh(mesh, color=palette[int(capsules.joint[c]) % len(palette)], smooth_shading=True,
                            specular=0.3, opacity=0.85)
            pl.add_mesh(skin.copy(deep=False), color=SKIN, opacity=0.18, smooth_shading=True)
        elif maps and title in maps:
            painted = skin.copy(deep=False)
            painted.point_data["map"] = np.asarray(maps[title], np.float32)
            pl.add_mesh(painted, scalars="map", cmap="viridis", clim=(0.0, 1.0), smooth_shading=True,
                        show_scalar_bar=False)    # the panel's title says what 0 and 1 look like
        else:
            for mesh, colour in meshes:
                # a refused muscle is not in the rig: drawn as a wireframe
                pl.add_mesh(mesh, color=colour, smooth_shading=True, specular=0.3,
                            style="wireframe" if colour is REFUSED else "surface")
            pl.add_mesh(tendons, color=(0.92, 0.92, 0.85))
            pl.add_mesh(skin.copy(deep=False), color=SKIN, opacity=0.22, smooth_shading=True)
            if flagged:
                label = pl.add_point_labels(np.array([np.asarray(q.surface).mean(axis=0) for q, _ in flagged]),
                                            [f"{q.name}: {why}" for q, why in flagged], font_size=10,
                                            text_color="black",
                                            point_color=POOR, point_size=6, shape_opacity=0.4,
                                            always_visible=True)
                label.GetMapper().SetPlaceAllLabels(True)  # VTK otherwise drops labels it finds crowded
        # from above: the character's right side up, so its head points the way it does from its side
        up = np.cross(mus.front, [0.0, 0.0, 1.0]) if view == "top" else np.array([0.0, 0.0, 1.0])
        frame_camera(pl, v, np.asarray(VIEWS[view], float), up, (size[0] / cols) / (size[1] / rows))
        pl.add_text(title, position="lower_left", font_size=10, color="black")
        if i == 0:
            # one text block: the title, then the flagged muscles with their measures
            pl.add_text("\n".join([f"{ch.name or 'character'}: {len(mus.muscles)} muscles"]
                                  + [f"{why}: {q.name} ({q.brief})" for q, why in flagged]),
                        position="upper_left", font_size=11 if not flagged else 9, color="black")
    with atomic_path(path) as tmp:
        pl.screenshot(tmp)
    pl.close()
    return path
