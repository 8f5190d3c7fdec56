"""Loading and making characters: from a file (skinned glTF, or any mesh with automatic weights), or a
body generated around a skeleton.

:func:`load_character` reads a skinned .glb/.gltf (rig/character/gltf_character.py) or an unskinned
mesh (rig/character/mesh_io.py) that gets bone-heat weights (:func:`auto_weighted`) from a skeleton
file (:func:`load_skeleton`); :func:`body_character` wraps the generated body: rig/character/body.py's
for a biped (or any skeleton), rig/character/quadruped_body.py's for a four-legged one.
"""
from __future__ import annotations

import os
import warnings
from dataclasses import replace

import numpy as np

from jiggle.rig.base.errors import InputError, JiggleWarning, require_file
from jiggle.rig.character.body import BodyOptions, generate_body
from jiggle.rig.character.bone_heat import bone_heat_weights
from jiggle.rig.character.character import Character, drop_degenerate_faces, end_sites, require_finite_positions
from jiggle.rig.character.gltf_character import gltf_has_skin, read_gltf_character
from jiggle.rig.character.mesh_io import MESH_EXTENSIONS, read_mesh
from jiggle.rig.character.normals import vertex_normals
from jiggle.rig.character.quadruped_body import generate_quadruped_body, is_quadruped
from jiggle.rig.character.quadruped_body import heat_bones as quadruped_heat_bones
from jiggle.rig.motion.clip import Clip, transforms
from jiggle.rig.motion.gltf_skeleton import read_gltf_skeleton
from jiggle.rig.motion.keyframes import read_keyframes
from jiggle.rig.motion.mjcf_skeleton import read_mjcf_skeleton
from jiggle.rig.motion.mocap import load_clip


def load_character(path: str | os.PathLike, *, skeleton: str | os.PathLike | Clip | None = None,
                   k: int = 4, unit: str | float | None = None, up: str = "auto", skin: int = 0,
                   jiggle_attribute: str | None = None) -> Character:
    """Read a character from a file.

    path : a skinned .glb/.gltf or .fbx (6.1/7.x, binary or ASCII, through Blender's importer: rig.motion.fbx)
        with its own skeleton and weights, or an unskinned .glb/.gltf, .obj, .ply
        or .stl mesh, which gets automatic weights (bone heat) from `skeleton`: a clip file (its rest
        pose), an MJCF .xml, a skinned glTF, or a Clip. An unskinned glTF with no skeleton given
        is an error that says so.
    k : influences kept per vertex.
    unit : metres per file unit ("m", "cm", "mm", "in", "ft" or a number); None or "auto": metres
        unless the height says centimetres or millimetres (rig.character.character.resolve_unit).
    up : axis that is up in an OBJ/PLY/STL file, "y", "z" or "auto" (the longer of the y and z
        extents, since a standing body is taller than it is deep); glTF is always Y-up.
    jiggle_attribute : the glTF vertex attribute the jiggle map is read from (default ``_JIGGLE``, or a
        vertex colour's channel "COLOR_0.r").

    The painted maps (rig.character.painted_maps: the jiggle map and each muscle's influence map) come
    with the character in ``Character.maps``: a skinned glTF's own vertex attributes, completed by a
    sidecar ``<stem>.jiggle_map.npz`` / ``.ply`` beside the file (checked against the vertex count).
    """
    return with_sidecar_maps(_load_character(path, skeleton=skeleton, k=k, unit=unit, up=up, skin=skin,
                                             jiggle_attribute=jiggle_attribute), path)


def with_sidecar_maps(character: Character, path: str | os.PathLike) -> Character:
    """`character` (read from `path`) with its own maps completed by the sidecar beside `path`."""
    from jiggle.rig.character.painted_maps import read_maps
    maps = read_maps(path, character.num_vertices, character.maps)
    return character if maps is character.maps else replace(character, maps=maps)


def _load_character(path, *, skeleton, k, unit, up, skin, jiggle_attribute) -> Character:
    p = os.fspath(path)
    ext = os.path.splitext(p)[1].lower()
    if ext == ".fbx":           # FBX through Blender's importer (rig.motion.fbx), read as its glTF
        from jiggle.rig.motion.fbx import through_gltf
        return through_gltf(p, _load_character, skeleton=skeleton, k=k, unit=unit, up=up, skin=skin,
                            jiggle_attribute=jiggle_attribute)
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 1 <= k <= 8:
        raise InputError(f"k (influences per vertex) must be a whole number from 1 to 8, got {k!r}", field="k")
    if ext in (".glb", ".gltf"):
        skinned = gltf_has_skin(p)
        if skinned and skeleton is None:
            return read_gltf_character(p, skin=skin, k=k, unit=unit, jiggle_attribute=jiggle_attribute)
        if skinned:
            warnings.warn(f"{p}: the file's own skin is ignored: weights are computed from the given skeleton",
                          JiggleWarning, stacklevel=2)
    elif ext not in MESH_EXTENSIONS:
        raise InputError(f"unknown character format {ext or '(no extension)'!r}; expected .glb, .gltf or one of "
                         f"{', '.join(MESH_EXTENSIONS)}", p)
    mesh = read_mesh(p, unit=unit, up=up)
    if skeleton is None:
        raise InputError("the mesh has no skin: give a skeleton (a clip, an MJCF or a skinned glTF) to compute "
                         "automatic weights from", p, field="skeleton")
    clip = skeleton if isinstance(skeleton, Clip) else load_skeleton(skeleton)
    warnings.warn(f"{p}: no skin in the file; computing automatic weights (bone heat) from the skeleton of "
                  f"{clip.source or clip.name or 'the given clip'}", JiggleWarning, stacklevel=2)
    return auto_weighted(mesh.vertices, mesh.faces, clip, k=k, name=mesh.name, source=p, uvs=mesh.uvs,
                         meta={"unit_scale": mesh.unit_scale, "up": mesh.up})


def load_skeleton(path: str | os.PathLike) -> Clip:
    """The rest pose of a skeleton file as a one-frame Clip: a clip (.bvh, .amc, .asf, .toml, glTF
    animation), an MJCF model (.xml, bodies at qpos0) or a skinned glTF (its bind pose)."""
    p = require_file(path, "skeleton file")
    ext = os.path.splitext(p)[1].lower()
    if ext == ".xml":
        return read_mjcf_skeleton(p)
    if ext in (".glb", ".gltf"):
        if gltf_has_skin(p):
            return read_gltf_skeleton(p).to_clip()
    if ext == ".toml":
        c = read_keyframes(p)
    else:
        c = load_clip(p)
    return rest_pose(c)


def rest_pose(clip: Clip) -> Clip:
    """A one-frame clip of `clip`'s rest pose (offsets, rest rotations)."""
    return replace(clip, rotations=clip.rest_rotations[None], translations=clip.offsets[None])


def auto_weighted(vertices: np.ndarray, faces: np.ndarray, clip: Clip, k: int = 4, name: str = "",
                  source: str = "", uvs: np.ndarray | None = None, meta: dict | None = None,
                  heat_bones: tuple | None = None) -> Character:
    """A Character from a mesh (V, 3) / (F, 3) standing in the rest pose of `clip`'s skeleton (same
    space: Z-up metres), with automatic weights by bone heat diffusion (rig.character.bone_heat).

    heat_bones : None, or extra heat sources (parents (K,) int, starts (K, 3), ends (K, 3) metres):
        bones that belong to joint parents[i], each a segment from that joint to starts[i] and one on
        to ends[i] (a quadruped's keel, rig.character.quadruped_body.heat_bones). They are given to
        bone heat as joints it may not weight (``bone_mask``), so their heat goes to their parents.
    """
    path = source or None
    v = np.asarray(vertices, dtype=np.float64)
    require_finite_positions(v, path)
    f = drop_degenerate_faces(v, faces, path)
    bind = transforms(*clip.rest_world())
    check_overlap(v, bind[:, :3, 3], path)
    rot, pos = clip.rest_world()
    parents, ends, mask = clip.parents, end_sites(clip), None
    if heat_bones is not None:
        hp, hs, he = (np.asarray(x) for x in heat_bones)
        J = clip.num_joints
        pos, parents = np.concatenate([pos, hs]), np.concatenate([parents, hp]).astype(int)
        ends, mask = np.concatenate([ends, he]), np.arange(len(pos)) < J
    joints, weights, report = bone_heat_weights(v, f, pos, parents, k=k, end_positions=ends, bone_mask=mask)
    if heat_bones is not None:     # a row with fewer than k joints pads with zero weights on any index
        joints = np.where(joints < clip.num_joints, joints, 0).astype(joints.dtype)
    return Character(vertices=v, faces=f, normals=vertex_normals(v, f), uvs=uvs, joint_names=clip.joint_names,
                     parents=clip.parents, bind_world=bind, bind_matrices=bind, joints=joints, weights=weights,
                     skeleton=rest_pose(clip), name=name or clip.name, source=source,
                     meta={"weights": "bone heat", "bone_heat": report, **(meta or {})})


def body_character(clip: Clip, options=None, k: int = 4) -> Character:
    """A body generated around `clip`'s skeleton (rig.character.body; rig.character.quadruped_body when the
    skeleton is four-legged, rig.motion.body_plan) with automatic weights, bound in the pose it was built
    in (`Body.bind`: the rest pose, a biped's hanging arms swung out); its fat volumes and how it was made
    are in meta["body"]."""
    options = options or BodyOptions()
    quadruped = is_quadruped(clip)
    body = generate_quadruped_body(clip, options) if quadruped else generate_body(clip, options)
    return auto_weighted(body.vertices, body.faces, body.bind, k=k, name=f"{clip.name} body" if clip.name else "body",
                         meta={"generated": True, "body": body, "body_options": options},
                         heat_bones=quadruped_heat_bones(body.bind, options) if quadruped else None)


def check_overlap(vertices: np.ndarray, joint_positions: np.ndarray, path: str | None) -> None:
    """InputError when the skeleton does not sit inside the mesh's bounds, or is of another size
    (a unit or axis mix-up)."""
    lo, hi = vertices.min(0), vertices.max(0)
    pad = 0.1 * (hi - lo).max()
    inside = np.all((joint_positions >= lo - pad) & (joint_positions <= hi + pad), axis=1)
    size_mesh = float((hi - lo).max())
    size_skel = float(np.ptp(joint_positions, axis=0).max())
    if inside.mean() < 0.5 or not 0.3 <= size_skel / max(size_mesh, 1e-12) <= 2.0:
        h_mesh = float(hi[2] - lo[2])
        h_skel = float(np.ptp(joint_positions[:, 2]))
        raise InputError(f"the skeleton does not fit the mesh: {int(inside.sum())} of {len(inside)} joints lie "
                         f"within the mesh's bounds (mesh {h_mesh:.4g} m tall, skeleton {h_skel:.4g} m); check "
                         f"the mesh's unit and up axis (--unit, --up)", path, field="skeleton")
