"""What `jiggle body` writes: pictures of a generated body and its weights, the mesh, and facts.

body.png      front, side and three-quarter views, the skeleton drawn through the skin
weights.png   front and back, each vertex coloured by its dominant joint
body.ply      the rest mesh (metres, Z-up)
body.json     vertices, faces, height, volume, closedness, fat volumes, timings
"""
from __future__ import annotations

import dataclasses
import json
import os

import numpy as np

from jiggle.rig.base.atomic import atomic_path
from jiggle.rig.character.character import Character


def _bones(character: Character) -> np.ndarray:
    """(B, 2, 3) metres, parent-child segments of the bind pose, end sites included."""
    pos = character.bind_positions
    segs = [(pos[p], pos[j]) for j, p in enumerate(character.parents) if p >= 0]
    clip = character.skeleton
    if len(clip.end_parents):
        rot, wp = clip.rest_world()
        for e, tip in zip(clip.end_parents, clip.end_world(rot[None], wp[None])[0]):
            segs.append((wp[e], tip))
    return np.array(segs, float).reshape(-1, 2, 3)


def body_facts(character: Character) -> dict:
    """JSON-ready facts about a (generated) character's rest mesh."""
    import trimesh
    mesh = trimesh.Trimesh(character.vertices, character.faces, process=False)
    facts = {
        "name": character.name, "vertices": character.num_vertices, "faces": int(len(character.faces)),
        "joints": character.num_joints, "height_m": round(character.height, 4),
        "volume_l": round(float(mesh.volume) * 1000, 2), "watertight": bool(mesh.is_watertight),
        "winding_consistent": bool(mesh.is_winding_consistent), "euler_number": int(mesh.euler_number),
        "weights": character.meta.get("weights", ""),
    }
    body = character.meta.get("body")
    if body is not None:
        facts["options"] = dataclasses.asdict(character.meta["body_options"])
        facts["fat"] = [{"name": f.name, "joint": character.joint_names[f.joint],
                         "center_m": np.round(f.center, 4).tolist(), "radii_m": np.round(f.radii, 4).tolist()}
                        for f in body.fat]
        facts["body_seconds"] = {k: round(float(v), 3) for k, v in body.timings.items()}
    report = character.meta.get("bone_heat")
    if report is not None:
        facts["bone_heat"] = {k: (round(v, 3) if isinstance(v, float) else v)
                              for k, v in dataclasses.asdict(report).items()}
    return facts


def write_body_outputs(character: Character, out_dir: str, render: bool = True) -> dict:
    """Write body.png, weights.png, body.ply and body.json into `out_dir`; returns {kind: file name}."""
    import trimesh
    os.makedirs(out_dir, exist_ok=True)
    files = {}
    if render:
        from jiggle.sim.app.report.mesh_render import render_mesh
        title = f"{character.name}: {character.num_vertices} vertices, {character.height:.2f} m"
        with atomic_path(os.path.join(out_dir, "body.png")) as tmp:
            render_mesh(character.vertices, character.faces, tmp, views=("front", "side", "iso"), title=title,
                        size=(1500, 700), overlay_lines=_bones(character))
        files["body"] = "body.png"
        with atomic_path(os.path.join(out_dir, "weights.png")) as tmp:
            render_mesh(character.vertices, character.faces, tmp, scalars=character.dominant_joint(),
                        views=("front", "back"), title=f"{character.name}: dominant joint "
                        f"({character.meta.get('weights', '')})", size=(1200, 700))
        files["weights"] = "weights.png"
    with atomic_path(os.path.join(out_dir, "body.ply")) as tmp:
        trimesh.Trimesh(character.vertices, character.faces, process=False).export(tmp)
    files["mesh"] = "body.ply"
    with atomic_path(os.path.join(out_dir, "body.json")) as tmp:
        with open(tmp, "w") as fh:
            json.dump({**body_facts(character), "files": files}, fh, indent=2)
    files["facts"] = "body.json"
    return files
