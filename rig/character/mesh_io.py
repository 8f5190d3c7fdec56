"""Reading an unskinned mesh (OBJ, PLY, STL, or a glTF without a skin) into jiggle's world.

OBJ/PLY/STL go through `trimesh.load(path, process=False)` so vertex indices stay as the file has
them. Those formats carry no axis convention: `up` says which file axis is up, "auto" takes the
longer of the y and z extents (a standing body is taller than it is deep; x is not looked at since a
T-pose's arm span matches its height). glTF is Y-up by its spec; every mesh node is placed by its
node transforms. Units: `unit`, or found from the height (rig.character.character.resolve_unit); an implausible height warns.
"""
from __future__ import annotations

import logging
import os
from dataclasses import dataclass

import numpy as np

from jiggle.rig.base.errors import InputError, require_file
from jiggle.rig.character.character import check_height, drop_degenerate_faces, require_finite_positions, resolve_unit
from jiggle.rig.character.gltf_character import _node_world, triangles
from jiggle.rig.motion.gltf_io import GltfDocument

MESH_EXTENSIONS = (".obj", ".ply", ".stl", ".off")

# file axes -> Z-up: y-up files turn (x, y, z) -> (x, -z, y), as glTF and BVH do
_Y_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


@dataclass(frozen=True, eq=False)
class Mesh:
    """A triangle mesh in jiggle's world.

    vertices : (V, 3) float64 metres, Z-up.
    faces : (F, 3) int32 (degenerate faces dropped with a warning).
    uvs : (V, 2) float32 or None.
    name, source : file stem and path.
    unit_scale : metres per file unit applied.
    up : the file axis taken as up ("y" or "z").
    """

    vertices: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray | None
    name: str
    source: str
    unit_scale: float
    up: str


def read_mesh(path: str | os.PathLike, unit: str | float | None = None, up: str = "auto") -> Mesh:
    """Read an OBJ, PLY, STL, OFF or glTF/GLB mesh (see the module docstring)."""
    p = require_file(path, "mesh file")
    ext = os.path.splitext(p)[1].lower()
    if up not in ("auto", "y", "z"):
        raise InputError(f"up must be 'auto', 'y' or 'z', got {up!r}", p, field="up")
    uvs = None
    if ext in (".glb", ".gltf"):
        v, f, uvs = _read_gltf_meshes(p)
        axis = "y"
    elif ext in MESH_EXTENSIONS:
        v, f, uvs = read_trimesh(p)
        axis = up if up != "auto" else ("y" if np.ptp(v[:, 1]) > np.ptp(v[:, 2]) else "z") if len(v) else "z"
        if axis == "y":
            v = v @ _Y_UP.T
    else:
        raise InputError(f"unknown mesh format {ext or '(no extension)'!r}; expected .glb, .gltf or one of "
                         f"{', '.join(MESH_EXTENSIONS)}", p)
    if len(v) == 0 or len(f) == 0:
        raise InputError("the file holds no triangles", p)
    require_finite_positions(v, p)
    f = np.asarray(f, dtype=np.int64)
    if f.min() < 0 or f.max() >= len(v):
        raise InputError(f"a face refers to vertex {int(f.max())} but the file has {len(v)} vertices", p,
                         field="faces")
    s = resolve_unit(unit, float(np.ptp(v[:, 2])), p)
    v = v * s
    f = drop_degenerate_faces(v, f, p)
    check_height(float(np.ptp(v[:, 2])), p)
    return Mesh(vertices=v, faces=f.astype(np.int32), uvs=uvs, name=os.path.splitext(os.path.basename(p))[0],
                source=p, unit_scale=s, up=axis)


def read_trimesh(p: str) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """(vertices (V, 3) float64 as in the file, faces (F, 3), uvs (V, 2) float32 or None) of an OBJ, PLY,
    STL or OFF file through trimesh, its logged tracebacks silenced; InputError for a file it cannot read."""
    import trimesh
    log = logging.getLogger("trimesh")   # trimesh logs its fallbacks with tracebacks; jiggle reports itself
    was = log.level
    log.setLevel(logging.CRITICAL + 1)   # its modules' loggers inherit the level
    try:
        m = trimesh.load(p, process=False, force="mesh")
    except Exception as e:  # trimesh raises many types on malformed files
        raise InputError(f"cannot read the mesh ({type(e).__name__}: {e})", p) from None
    finally:
        log.setLevel(was)
    if not isinstance(m, trimesh.Trimesh):
        raise InputError("the file holds no triangle mesh", p)
    uv = getattr(m.visual, "uv", None)
    v = np.asarray(m.vertices, dtype=np.float64)
    uvs = np.asarray(uv, np.float32)[:, :2] if uv is not None and len(uv) == len(v) else None
    return v, np.asarray(m.faces), uvs


def _read_gltf_meshes(p: str) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    doc = GltfDocument(p)
    g = doc.gltf
    pos, faces, uv = [], [], []
    has_uv, offset = True, 0
    for ni, nd in enumerate(g.nodes):
        if nd.mesh is None or not 0 <= nd.mesh < len(g.meshes):
            continue
        place = _node_world(doc, ni)
        for pi, prim in enumerate(g.meshes[nd.mesh].primitives):
            what = f"meshes[{nd.mesh}].primitives[{pi}]"
            mode = 4 if prim.mode is None else prim.mode
            if mode not in (4, 5, 6) or getattr(prim.attributes, "POSITION", None) is None:
                continue
            v = doc.accessor(prim.attributes.POSITION, f"{what}.attributes.POSITION")
            require_finite_positions(v, p, f"{what}.attributes.POSITION")
            idx = doc.accessor(prim.indices, f"{what}.indices")[:, 0].astype(np.int64) \
                if prim.indices is not None else np.arange(len(v))
            if len(idx) and idx.max() >= len(v):
                raise InputError(f"index {int(idx.max())} is past the primitive's {len(v)} vertices", p,
                                 field=f"{what}.indices")
            pos.append(v @ place[:3, :3].T + place[:3, 3])
            faces.append(triangles(mode, idx) + offset)
            t = getattr(prim.attributes, "TEXCOORD_0", None)
            if t is not None:
                uv.append(doc.accessor(t)[:, :2])
            else:
                has_uv = False
            offset += len(v)
    if not pos:
        raise InputError(f"the file has no triangle mesh (it holds {doc.contents()})", p, field="meshes")
    return np.concatenate(pos), np.concatenate(faces), (np.concatenate(uv).astype(np.float32)
                                                       if has_uv and uv else None)
