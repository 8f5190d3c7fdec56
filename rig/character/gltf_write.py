"""Writing a skinned character as glTF 2.0 (.glb or .gltf), the inverse of rig.character.gltf_character.

The file holds one scene: a node per joint (named as the character's joints, hierarchy from its
parents) and one skinned mesh node at the scene root, without a transform, as the spec asks.
Everything lives in one buffer: the GLB binary chunk, or a base64 data URI in a .gltf file, so
either way the character is a single file.

Readings, each the inverse of the reader's (rig.motion.gltf_io, rig.motion.gltf_skeleton, rig.character.gltf_character):
- Axes and units: jiggle's Z-up metres go back to glTF's Y-up metres through the inverse of
  ``rig.motion.gltf_io.Z_UP`` (positions, normals, root joint transforms, inverse bind matrices).
- Joint nodes: local translation and rotation (no scale) of the rigid `bind_world`, so the file's
  rest pose is the bind pose and Blender shows the skin undeformed. The reader orders joints
  depth-first, children in file order; a node's children are written in the character's order, so a
  character whose joints are in depth-first order (every character read from glTF, BVH or MJCF)
  reads back in the same order.
- Inverse bind matrices: ``inverse(bind_matrices) @ Z_UP``. The reader takes a joint's bind
  transform as mesh placement (``Z_UP``, the mesh node is at the root) @ inverse(IBM), which gives
  `bind_matrices` back, and its `bind_world` is the rigid part of that (exact when bind_matrices is
  rigid, as for any character read from glTF). Skinning by the file's node transforms and these
  matrices is the same map as `Character.pose`.
- Skin weights: JOINTS_n (UNSIGNED_SHORT) / WEIGHTS_n (FLOAT) sets of four, the character's k
  influences padded with weight 0 and joint 0; rows renormalised to sum 1 in float32.
- Precision: vertex data and inverse bind matrices are float32 as the spec requires (about 1e-7 m
  on a human-sized body); node transforms are float64 JSON numbers, exact.
- Animations (optional, ``animations={name: Clip}``): one glTF animation per clip, each joint node
  getting a rotation channel and, where its translation moves or differs from the bind pose's, a
  translation channel; LINEAR samplers with one key per clip frame at ``frame / fps`` seconds (float32,
  as the spec requires). The clip must be on the character's own skeleton (the same joint names,
  parents and order). Key values are the node-local transforms that make each joint's world
  transform the clip's (``Clip.world``), with the same axis change on the roots as the nodes, so that
  skinning the file's nodes at a key's time gives `Character.pose` of the clip's frame; reading the
  animation back (rig.motion.gltf_anim) gives the clip's world transforms to float32 precision.
  Rotation keys are kept on one hemisphere from key to key, so the reader's shortest-arc slerp
  follows the clip.
- Material: copied from `source` (the glTF the character came from) when its skinned mesh has a
  material with a base colour texture: the material's core fields, its textures (texture
  coordinate set 0 only, since only TEXCOORD_0 is written), samplers and image bytes, embedded.
  Material and texture extensions are dropped (the file declares none). Otherwise a plain grey
  material.
"""
from __future__ import annotations

import base64
import json
import os
import struct
import urllib.parse
import warnings

import numpy as np

from jiggle.rig.base.atomic import atomic_path
from jiggle.rig.base.errors import InputError, JiggleWarning, require_file
from jiggle.rig.motion import quat
from jiggle.rig.motion.bvh import Y_TO_Z_UP
from jiggle.rig.motion.clip import local_from_world
from jiggle.rig.motion.gltf_io import Z_UP, polar_rotation

EXTENSIONS = (".glb", ".gltf")
GENERATOR = "jiggle"

_FLOAT, _UINT16, _UINT32, _UINT8, _INT16 = 5126, 5123, 5125, 5121, 5122
_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963
_Y_UP = Z_UP.T  # jiggle world (Z-up) -> glTF world (Y-up); Z_UP is a rotation
_DEFAULT_MATERIAL = {"name": "jiggle default",
                     "pbrMetallicRoughness": {"baseColorFactor": [0.8, 0.8, 0.8, 1.0], "metallicFactor": 0.0,
                                              "roughnessFactor": 0.8}}
_PBR_TEXTURES = ("baseColorTexture", "metallicRoughnessTexture")
_MATERIAL_TEXTURES = ("normalTexture", "occlusionTexture", "emissiveTexture")


def write_character(character, path: str | os.PathLike, *, source: str | os.PathLike | None = None,
                    name: str | None = None, extras: dict | None = None, animations: dict | None = None,
                    attributes: dict | None = None, compact: bool = False) -> str:
    """Write `character` (rig.character.character.Character, Z-up metres) as a skinned glTF 2.0 file.

    Parameters
    ----------
    path : the file; ".glb" writes one binary GLB, ".gltf" one JSON file with the buffer embedded
        as a base64 data URI. Written atomically: a failed write leaves nothing under this name.
    source : the glTF the character came from, whose textured material (if any) is copied so the
        output looks like it; None (or a source without a textured material) gives a plain material.
        A missing source file is an InputError.
    name : the mesh, mesh node and scene name; default the character's name.
    extras : JSON-serialisable provenance stored as ``asset.extras`` (e.g.
        {"jiggle": {"morphed_from": "CesiumMan.glb"}}); default {"jiggle": {"from": <source file
        name>}} when the character has a source.
    animations : {name: rig.motion.clip.Clip} written as named glTF animations (module docstring);
        each clip must have the character's joint names and parents in the same order (InputError
        naming the animation otherwise).
    attributes : {name: (V,) float} custom vertex attributes written as SCALAR FLOAT (names starting
        with "_", as the spec asks: e.g. rig.character.gltf_maps' _JIGGLE and _SHELL_<MUSCLE>).
    compact : the smaller encodings core glTF allows, for files engines stream (sim/bake/glb.py): the
        rotation keys of leaf joints as normalized SHORT (3e-5 rad; a joint with children keeps FLOAT, as its
        error would reach every descendant), weights as normalized UNSIGNED_SHORT (rows summing
        to exactly 65535), joints as UNSIGNED_BYTE when there are fewer than 256.

    Returns the path written. InputError for an unknown extension, a missing folder, NaN or infinite
    values (naming the field), or indices out of range.
    """
    p = os.fspath(path)
    ext = os.path.splitext(p)[1].lower()
    if ext not in EXTENSIONS:
        raise InputError(f"cannot write a glTF character to {ext or '(no extension)'!r}; expected a path ending "
                         f"in .glb (binary) or .gltf (JSON with embedded data)", p, field="path")
    folder = os.path.dirname(os.path.abspath(p))
    if not os.path.isdir(folder):
        raise InputError(f"the folder {folder} does not exist; create it first", p, field="path")
    if os.path.isdir(p):
        raise InputError("expected a file name, found a directory", p, field="path")
    name = name if name is not None else (character.name or "character")
    arrays = _checked_arrays(character, p)
    material = _source_material(source, character.uvs is not None, character.meta.get("skin", 0)) \
        if source is not None else None
    if extras is None:
        extras = {"jiggle": {"from": os.path.basename(character.source)}} if character.source else None
    if extras is not None:
        try:
            json.dumps(extras, allow_nan=False)
        except (TypeError, ValueError) as e:
            raise InputError(f"extras must be JSON-serialisable with finite numbers ({e})", p, field="extras") \
                from None
    anims = {str(k): _animation_arrays(character, clip, p, str(k)) for k, clip in (animations or {}).items()}
    extra_attrs = {}
    for k, v in (attributes or {}).items():
        v = np.asarray(v, np.float32).reshape(-1)
        if not str(k).startswith("_") or len(v) != character.num_vertices:
            raise InputError(f"a custom attribute needs a name starting with '_' and one value per vertex "
                             f"({character.num_vertices}); got {k!r} with {len(v)}", p, field="attributes")
        extra_attrs[str(k)] = _finite(v, p, f"attributes.{k}").astype(np.float32)
    doc, blob = _document(character, arrays, material, name, extras, anims, extra_attrs, compact)
    with atomic_path(p) as tmp:
        if ext == ".glb":
            data = _glb(doc, blob)
        else:
            doc["buffers"][0]["uri"] = "data:application/octet-stream;base64," + base64.b64encode(blob).decode()
            data = json.dumps(doc, allow_nan=False, separators=(",", ":")).encode()
        with open(tmp, "wb") as fh:
            fh.write(data)
        _verify(tmp, doc)
    return p


# ---------------------------------------------------------------------------------- checks
def _finite(a: np.ndarray, path: str, field: str) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64)
    bad = ~np.isfinite(a.reshape(len(a), -1)).all(1) if a.size else np.zeros(len(a), bool)
    if np.any(bad):
        raise InputError(f"{int(bad.sum())} of {len(a)} rows are not finite (NaN or infinite), first at row "
                         f"{int(np.argmax(bad))}; nothing was written", path, field=field)
    return a


def _checked_arrays(c, path: str) -> dict:
    """The character's arrays converted to the file's types, glTF Y-up; InputError naming the field
    of the first problem."""
    V, J = c.num_vertices, c.num_joints
    if V == 0 or len(c.faces) == 0:
        raise InputError(f"the character has {V} vertices and {len(c.faces)} faces; a glTF mesh needs at "
                         f"least one triangle", path, field="faces")
    if J > 65536:
        raise InputError(f"{J} joints do not fit JOINTS_n as UNSIGNED_SHORT (at most 65536)", path, field="joints")
    vertices = _finite(c.vertices, path, "vertices")
    normals = _finite(c.normals, path, "normals")
    uvs = None if c.uvs is None else _finite(c.uvs, path, "uvs")
    bind_world = _finite(c.bind_world, path, "bind_world")
    bind_m = _finite(c.bind_matrices, path, "bind_matrices")
    weights = _finite(c.weights, path, "weights")
    faces = np.asarray(c.faces, dtype=np.int64)
    if faces.min() < 0 or faces.max() >= V:
        raise InputError(f"face indices must lie in [0, {V}), found [{faces.min()}, {faces.max()}]", path,
                         field="faces")
    joints = np.asarray(c.joints, dtype=np.int64).copy()
    live = weights > 0
    if np.any(weights < 0):
        raise InputError(f"negative weights, first at vertex {int(np.argwhere(weights < 0)[0, 0])}", path,
                         field="weights")
    if np.any(live & ((joints < 0) | (joints >= J))):
        v, k = np.argwhere(live & ((joints < 0) | (joints >= J)))[0]
        raise InputError(f"joint index {int(joints[v, k])} at vertex {int(v)} is out of range 0..{J - 1}", path,
                         field="joints")
    weights = np.where(live, weights, 0.0)
    joints = np.where(live, joints, 0)
    for a in range(joints.shape[1]):  # the spec forbids one joint twice with weight in a vertex: merge
        for b in range(a + 1, joints.shape[1]):
            dup = (joints[:, a] == joints[:, b]) & (weights[:, a] > 0) & (weights[:, b] > 0)
            weights[dup, a] += weights[dup, b]
            weights[dup, b] = 0.0
            joints[dup, b] = 0
    total = weights.sum(1)
    if np.any(total <= 0):
        raise InputError(f"{int((total <= 0).sum())} vertices have no weight, first vertex "
                         f"{int(np.argmax(total <= 0))}", path, field="weights")
    weights = (weights / total[:, None]).astype(np.float32)
    sets = -(-joints.shape[1] // 4)
    pad = 4 * sets - joints.shape[1]
    joints = np.pad(joints, ((0, 0), (0, pad))).astype(np.uint16)
    weights = np.pad(weights, ((0, 0), (0, pad)))

    length = np.linalg.norm(normals, axis=1, keepdims=True)
    if np.any(length[:, 0] <= 1e-12):  # the spec wants unit normals: recompute the degenerate ones
        from jiggle.rig.character.normals import vertex_normals
        normals = np.where(length > 1e-12, normals, vertex_normals(vertices, faces))
        length = np.linalg.norm(normals, axis=1, keepdims=True)
    normals = normals / length
    try:
        ibm = np.linalg.inv(bind_m) @ Z_UP
    except np.linalg.LinAlgError:
        raise InputError("a bind matrix is singular", path, field="bind_matrices") from None
    ibm[:, 3] = [0.0, 0.0, 0.0, 1.0]  # exact affine row, as the spec requires
    _finite(ibm, path, "bind_matrices")

    # Joint node transforms: rigid local transforms of the bind pose; roots carry the axis change.
    parents = np.asarray(c.parents)
    world_r = polar_rotation(bind_world[:, :3, :3])
    rot, tra = local_from_world(parents, world_r, bind_world[:, :3, 3])
    roots = parents < 0
    rot[roots] = quat.mul(quat.conj(Y_TO_Z_UP), rot[roots])
    tra[roots] = tra[roots] @ _Y_UP[:3, :3].T
    return {
        "positions": (vertices @ _Y_UP[:3, :3].T).astype(np.float32),
        "normals": (normals @ _Y_UP[:3, :3].T).astype(np.float32),
        "uvs": None if uvs is None else uvs.astype(np.float32),
        "faces": faces.astype(np.uint32),
        "joints": joints, "weights": weights,
        "ibm": ibm.transpose(0, 2, 1).reshape(-1, 16).astype(np.float32),  # column-major
        "rotations": quat.to_xyzw(quat.normalize(rot)), "translations": tra,
    }


# ---------------------------------------------------------------------------------- document
class _Buffer:
    """One binary buffer built view by view, each view starting on a 4-byte boundary."""

    def __init__(self):
        self.parts: list[bytes] = []
        self.size = 0
        self.views: list[dict] = []

    def view(self, data: bytes, target: int | None = None) -> int:
        v = {"buffer": 0, "byteOffset": self.size, "byteLength": len(data)}
        if target is not None:
            v["target"] = target
        self.views.append(v)
        pad = -len(data) % 4
        self.parts.append(data + b"\0" * pad)
        self.size += len(data) + pad
        return len(self.views) - 1

    def bytes(self) -> bytes:
        return b"".join(self.parts)


class _Accessors:
    """The document's accessors, each on a view of its own in the one buffer `buf`."""

    def __init__(self, buf: _Buffer):
        self.buf = buf
        self.accessors: list[dict] = []

    def add(self, arr: np.ndarray, ctype: int, kind: str, target: int | None, bounds: bool = False,
            normalized: bool = False) -> int:
        """The index of a new accessor over `arr` (count, ...) written little-endian, as glTF component type
        `ctype` and type `kind` ("SCALAR", "VEC3", ...); `bounds` adds its min and max."""
        arr = np.ascontiguousarray(arr)
        acc = {"bufferView": self.buf.view(arr.astype(arr.dtype.newbyteorder("<")).tobytes(), target),
               "componentType": ctype, "count": int(len(arr)), "type": kind}
        if normalized:
            acc["normalized"] = True
        if bounds:
            acc["min"] = np.atleast_1d(arr.min(0)).tolist()   # a list even for SCALAR accessors
            acc["max"] = np.atleast_1d(arr.max(0)).tolist()
        self.accessors.append(acc)
        return len(self.accessors) - 1


def _animation_arrays(c, clip, path: str, name: str) -> dict:
    """Key times (T,) float32 seconds, node rotations (T, J, 4) x,y,z,w and translations (T, J, 3)
    (glTF Y-up on the roots) of `clip` on character `c`, and which joints need a translation channel."""
    from jiggle.rig.motion.clip import Clip
    if not isinstance(clip, Clip):
        raise InputError(f"animation {name!r} must be a Clip, got {type(clip).__name__}", path, field="animations")
    if tuple(clip.joint_names) != tuple(c.joint_names) or not np.array_equal(clip.parents, c.parents):
        raise InputError(f"animation {name!r} is not on the character's skeleton: its joints must be the "
                         f"character's {c.num_joints} joints ({', '.join(c.joint_names[:4])}, ...) with the same "
                         f"parents in the same order; retarget it onto the character first", path,
                         field="animations")
    if not np.all(np.isfinite(clip.rotations)) or not np.all(np.isfinite(clip.translations)):
        raise InputError(f"animation {name!r} holds NaN or infinite values", path, field="animations")
    world_r, world_p = clip.world()
    rot, tra = local_from_world(clip.parents, world_r, world_p)       # every frame at once
    roots = np.asarray(c.parents) < 0
    rot[:, roots] = quat.mul(quat.conj(Y_TO_Z_UP), rot[:, roots])
    tra[:, roots] = tra[:, roots] @ _Y_UP[:3, :3].T
    rot = quat.make_continuous(quat.normalize(rot), axis=0)
    return {"times": (np.arange(len(rot)) / clip.fps).astype(np.float32), "rotations": quat.to_xyzw(rot),
            "translations": tra}


def _document(c, a: dict, material: dict | None, name: str, extras: dict | None,
              animations: dict | None = None, custom: dict | None = None,
              compact: bool = False) -> tuple[dict, bytes]:
    """The glTF JSON document of character `c` (its arrays `a` from _checked_arrays) and its binary buffer:
    the mesh's accessors first, then the material's images, then the animations' keys."""
    buf = _Buffer()
    acc = _Accessors(buf)
    attributes = _mesh_attributes(acc, a, c.num_joints, custom, compact)
    indices = acc.add(a["faces"].reshape(-1), _UINT32, "SCALAR", _ELEMENT_ARRAY_BUFFER)
    ibm = acc.add(a["ibm"], _FLOAT, "MAT4", None)

    doc: dict = {"asset": {"version": "2.0", "generator": GENERATOR}}
    if extras is not None:
        doc["asset"]["extras"] = extras
    mat = _embed_material(doc, buf, material)
    doc.update(_scene(c, a, name, {"attributes": attributes, "indices": indices, "mode": 4, "material": 0},
                      mat, ibm))
    anims = _animations(acc, c, a, animations, compact)
    if anims:
        doc["animations"] = anims
    doc.update({"accessors": acc.accessors, "bufferViews": buf.views, "buffers": [{"byteLength": buf.size}]})
    # keep the usual top-level order for a human reader
    order = ["asset", "scene", "scenes", "nodes", "meshes", "materials", "textures", "images", "samplers", "skins",
             "animations", "accessors", "bufferViews", "buffers"]
    return {k: doc[k] for k in order if k in doc}, buf.bytes()


def _mesh_attributes(acc: _Accessors, a: dict, J: int, custom: dict | None, compact: bool) -> dict:
    """{attribute: accessor} of the mesh primitive: POSITION, NORMAL, TEXCOORD_0 when there are UVs,
    JOINTS_n / WEIGHTS_n sets of four (joints as bytes and weights as normalized shorts when `compact`),
    then the `custom` (V,) float attributes."""
    attributes = {"POSITION": acc.add(a["positions"], _FLOAT, "VEC3", _ARRAY_BUFFER, bounds=True),
                  "NORMAL": acc.add(a["normals"], _FLOAT, "VEC3", _ARRAY_BUFFER)}
    if a["uvs"] is not None:
        attributes["TEXCOORD_0"] = acc.add(a["uvs"], _FLOAT, "VEC2", _ARRAY_BUFFER)
    small = compact and J < 256
    weights = _unit_shorts(a["weights"]) if compact else a["weights"]
    joints = np.where(weights > 0, a["joints"], 0)     # a weight rounded to 0 names joint 0, as padding does
    for n in range(joints.shape[1] // 4):
        jn = joints[:, 4 * n:4 * n + 4]
        attributes[f"JOINTS_{n}"] = acc.add(jn.astype(np.uint8) if small else jn, _UINT8 if small else _UINT16,
                                            "VEC4", _ARRAY_BUFFER)
        attributes[f"WEIGHTS_{n}"] = acc.add(weights[:, 4 * n:4 * n + 4], _UINT16 if compact else _FLOAT, "VEC4",
                                             _ARRAY_BUFFER, normalized=compact)
    for k, v in (custom or {}).items():
        attributes[k] = acc.add(v, _FLOAT, "SCALAR", _ARRAY_BUFFER, bounds=True)
    return attributes


def _embed_material(doc: dict, buf: _Buffer, material: dict | None) -> dict:
    """The mesh's material: the plain default, or the copied one (_source_material) whose images go into
    the buffer and whose copyright, images, textures and samplers go into `doc`."""
    mat = dict(_DEFAULT_MATERIAL)
    if material is not None:
        mat = material["material"]
        if material.get("copyright"):
            doc["asset"]["copyright"] = material["copyright"]
        images = []
        for data, mime, image_name in material["images"]:
            image = {"bufferView": buf.view(data), "mimeType": mime}
            if image_name:
                image["name"] = image_name
            images.append(image)
        if images:
            doc["images"] = images
            doc["textures"] = material["textures"]
            if material["samplers"]:
                doc["samplers"] = material["samplers"]
    return mat


def _scene(c, a: dict, name: str, primitive: dict, mat: dict, ibm: int) -> dict:
    """The document's scene, nodes (one per joint, then the skinned mesh node), mesh, material and skin."""
    J = c.num_joints
    parents = np.asarray(c.parents)
    nodes = []
    for j in range(J):
        node = {"name": c.joint_names[j], "translation": a["translations"][j].tolist(),
                "rotation": a["rotations"][j].tolist()}
        children = np.nonzero(parents == j)[0].tolist()
        if children:
            node["children"] = children
        nodes.append(node)
    nodes.append({"name": name, "mesh": 0, "skin": 0})
    roots = np.nonzero(parents < 0)[0].tolist()
    skin = {"name": f"{name} skin", "joints": list(range(J)), "inverseBindMatrices": ibm}
    if len(roots) == 1:
        skin["skeleton"] = roots[0]
    return {
        "scene": 0,
        "scenes": [{"name": name, "nodes": roots + [J]}],
        "nodes": nodes,
        "meshes": [{"name": name, "primitives": [primitive]}],
        "materials": [mat],
        "skins": [skin],
    }


def _animations(acc: _Accessors, c, a: dict, animations: dict | None, compact: bool) -> list:
    """One glTF animation per clip (arrays from _animation_arrays): a rotation channel per joint and a
    translation channel where the joint leaves its bind translation; leaf rotations as normalized shorts
    when `compact`."""
    J = c.num_joints
    anims = []
    inner = set(int(p) for p in c.parents if p >= 0)
    for aname, an in (animations or {}).items():
        samplers, channels = [], []
        times = acc.add(an["times"], _FLOAT, "SCALAR", None, bounds=True)
        for j in range(J):
            for kind, values in (("rotation", an["rotations"][:, j]), ("translation", an["translations"][:, j])):
                # a translation that stays at the node's own (the bind pose's) needs no channel
                if kind == "translation" and np.abs(values - a["translations"][j]).max() <= 1e-9:
                    continue
                if kind == "rotation" and compact and j not in inner:   # a leaf: no child amplifies it
                    out = acc.add(np.round(np.clip(values, -1, 1) * 32767).astype(np.int16), _INT16, "VEC4", None,
                                  normalized=True)
                else:
                    out = acc.add(values.astype(np.float32), _FLOAT, "VEC4" if kind == "rotation" else "VEC3", None)
                samplers.append({"input": times, "output": out, "interpolation": "LINEAR"})
                channels.append({"sampler": len(samplers) - 1, "target": {"node": j, "path": kind}})
        anims.append({"name": aname, "channels": channels, "samplers": samplers})
    return anims


def _unit_shorts(weights: np.ndarray) -> np.ndarray:
    """(V, k) weights (rows summing to 1) as uint16 rows summing to exactly 65535 over all the sets (the
    rounding's remainder on the row's largest weight), so the normalized weights sum to one exactly."""
    w = np.asarray(weights, np.float64)
    q = np.round(w * 65535.0).astype(np.int64)
    rows = np.arange(len(w))
    q[rows, np.argmax(w, axis=1)] += 65535 - q.sum(axis=1)
    return q.astype(np.uint16)


def _glb(doc: dict, blob: bytes) -> bytes:
    text = json.dumps(doc, allow_nan=False, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)  # the JSON chunk is padded with spaces, the binary one with zeros
    blob += b"\0" * (-len(blob) % 4)
    total = 12 + 8 + len(text) + 8 + len(blob)
    return (struct.pack("<4sII", b"glTF", 2, total) + struct.pack("<II", len(text), 0x4E4F534A) + text
            + struct.pack("<II", len(blob), 0x004E4942) + blob)


def _verify(path: str, doc: dict) -> None:
    """Load the written file with pygltflib and check it holds what was meant (a bug otherwise)."""
    import pygltflib
    g = pygltflib.GLTF2().load(path)
    ok = (g is not None and len(g.nodes) == len(doc["nodes"]) and len(g.accessors) == len(doc["accessors"])
          and len(g.skins) == 1 and g.buffers[0].byteLength == doc["buffers"][0]["byteLength"]
          and len(g.animations or []) == len(doc.get("animations", [])))
    if ok and path.lower().endswith(".glb"):
        ok = len(g.binary_blob() or b"") >= doc["buffers"][0]["byteLength"]
    if not ok:
        raise RuntimeError(f"{path}: the written glTF does not load back with pygltflib as written")


# ---------------------------------------------------------------------------------- material
def _source_material(source, has_uvs: bool, skin: int = 0) -> dict | None:
    """The textured material of `source`'s skinned mesh, ready to embed: {"material", "textures",
    "samplers", "images": [(bytes, mime, name)], "copyright"}; None when there is none to copy."""
    src = require_file(source, "source glTF")
    if os.path.splitext(src)[1].lower() not in EXTENSIONS:
        return None  # a mesh file has no glTF material to copy
    from jiggle.rig.motion.gltf_io import GltfDocument
    gdoc = GltfDocument(src)
    d = json.loads(gdoc.gltf.to_json())
    materials = d.get("materials") or []
    nodes = d.get("nodes") or []
    meshes = d.get("meshes") or []
    users = [nd for nd in nodes if nd.get("skin") is not None and nd.get("mesh") is not None]
    users.sort(key=lambda nd: nd.get("skin") != skin)  # the character's own skin first
    for nd in users:
        if not 0 <= nd["mesh"] < len(meshes):
            continue
        for prim in meshes[nd["mesh"]].get("primitives") or []:
            mi = prim.get("material")
            if mi is None or not 0 <= mi < len(materials):
                continue
            pbr = materials[mi].get("pbrMetallicRoughness") or {}
            if "baseColorTexture" not in pbr:
                continue
            out = _copy_material(gdoc, d, materials[mi], has_uvs)
            if out is not None:
                out["copyright"] = (d.get("asset") or {}).get("copyright")
                return out
    return None


def _copy_material(gdoc, d: dict, mat: dict, has_uvs: bool) -> dict | None:
    src = gdoc.path
    new = {k: v for k, v in mat.items() if k not in ("extensions",)}
    pbr = {k: v for k, v in (mat.get("pbrMetallicRoughness") or {}).items() if k != "extensions"}
    new["pbrMetallicRoughness"] = pbr
    textures, samplers, images = [], [], []
    tex_map, sampler_map, image_map = {}, {}, {}

    def copy_texture(i) -> int | None:
        if i in tex_map:
            return tex_map[i]
        texs = d.get("textures") or []
        if not isinstance(i, int) or not 0 <= i < len(texs) or texs[i].get("source") is None:
            return None
        tex = texs[i]
        img = tex["source"]
        if img not in image_map:
            got = _image_bytes(gdoc, d, img)
            if got is None:
                return None
            image_map[img] = len(images)
            images.append(got)
        t = {"source": image_map[img]}
        s = tex.get("sampler")
        if s is not None and 0 <= s < len(d.get("samplers") or []):
            if s not in sampler_map:
                sampler_map[s] = len(samplers)
                samplers.append({k: v for k, v in d["samplers"][s].items() if k != "extensions"})
            t["sampler"] = sampler_map[s]
        if tex.get("name"):
            t["name"] = tex["name"]
        tex_map[i] = len(textures)
        textures.append(t)
        return tex_map[i]

    for holder, keys in ((pbr, _PBR_TEXTURES), (new, _MATERIAL_TEXTURES)):
        for key in keys:
            info = holder.get(key)
            if info is None:
                continue
            k = copy_texture(info.get("index")) if has_uvs and info.get("texCoord", 0) == 0 else None
            if k is None:
                del holder[key]
                if key == "baseColorTexture":
                    why = "the character has no texture coordinates" if not has_uvs else \
                        "its image could not be read (or it uses a texture coordinate set other than 0)"
                    warnings.warn(f"{src}: the base colour texture is not copied: {why}", JiggleWarning,
                                  stacklevel=4)
            else:
                holder[key] = {kk: vv for kk, vv in info.items() if kk != "extensions"} | {"index": k}
    return {"material": new, "textures": textures, "samplers": samplers, "images": images}


def _image_bytes(gdoc, d: dict, i: int) -> tuple[bytes, str, str] | None:
    """(bytes, mime type, name) of image `i` of the source, or None when it cannot be embedded."""
    imgs = d.get("images") or []
    if not isinstance(i, int) or not 0 <= i < len(imgs):
        return None
    img = imgs[i]
    mime = img.get("mimeType")
    if img.get("bufferView") is not None:
        bv = (d.get("bufferViews") or [])[img["bufferView"]]
        start = bv.get("byteOffset", 0)
        data = gdoc.buffer(bv["buffer"])[start:start + bv["byteLength"]]
    elif str(img.get("uri", "")).startswith("data:"):
        head, _, payload = img["uri"].partition(",")
        data = base64.b64decode(payload) if ";base64" in head else urllib.parse.unquote_to_bytes(payload)
        mime = mime or head[5:].split(";")[0]
    elif img.get("uri"):
        f = os.path.join(os.path.dirname(gdoc.path), urllib.parse.unquote(img["uri"]))
        if not os.path.isfile(f):
            return None
        with open(f, "rb") as fh:
            data = fh.read()
    else:
        return None
    if data[:8] == b"\x89PNG\r\n\x1a\n":
        mime = "image/png"
    elif data[:3] == b"\xff\xd8\xff":
        mime = "image/jpeg"
    if mime not in ("image/png", "image/jpeg"):
        return None  # core glTF embeds only PNG and JPEG
    return bytes(data), mime, img.get("name") or ""
