"""The spring bones a VRM avatar defines in its glTF: the chains its author tuned to swing (hair, skirts, tails,
ears), read so that rig.character.chains takes them as the file says.

Two versions of the extension exist:

- VRM 1.0, ``extensions.VRMC_springBone`` (vrm-c/vrm-specification, VRMC_springBone-1.0): ``springs[]``, each
  an ordered list of ``joints[]`` ({node, hitRadius, stiffness, gravityPower, gravityDir, dragForce}; each
  joint an ancestor of the next), the collider groups it collides with, and a center node; ``colliders[]``
  ({node, shape: {sphere: {offset, radius}} or {capsule: {offset, radius, tail}}}) and ``colliderGroups[]``
  ({colliders: indices}). Defaults are the schema's: hitRadius 0, stiffness 1, gravityPower 0, gravityDir
  (0, -1, 0), dragForce 0.5; offsets and tails (0, 0, 0), radii 0.
- VRM 0.x, ``extensions.VRM.secondaryAnimation``: ``boneGroups[]`` ({comment, stiffiness (sic), gravityPower,
  gravityDir {x, y, z}, dragForce, hitRadius, bones: node indices, colliderGroups}), each bone the root of a
  chain down its descendants, and ``colliderGroups[]`` ({node, colliders: [{offset {x, y, z}, radius}]}).
  The schema gives no defaults; UniVRM's (the tool that writes these files) are used: stiffness 1, gravity 0,
  (0, -1, 0), drag 0.4, hit radius 0.02 m. As in three-vrm, a collider offset's z is negated (VRM 0.x wrote
  it in Unity's left-handed axes) and gravityDir is taken as written.

When a file has both, VRM 1.0 wins (as three-vrm reads it).

Readings, in jiggle's units and axes (the reader's edge):
- Joints: a node maps to the character's joint of the same name (rig.motion.gltf_io's unique node names,
  which rig.character.gltf_character gives its joints); a node that is not a joint (an end node outside the
  skin) is left out. A VRM 1.0 chain is its joints that are character joints, in order; a VRM 0.x chain runs
  from the bone down its first child (the first that is a joint or has one below it) to the last joint.
- Settings: a chain carries its root joint's settings (VRM 1.0 sets them per joint; authoring tools write one
  value per spring; the tail joint's are unused by the spec).
- Lengths: hitRadius and collider radii are world lengths (as three-vrm uses them), so they are times the
  character's unit scale (metres per file unit). Collider offsets and tails are in the node's local space, so
  they are also times the node's world scale (a centimetre armature's 0.01): metres in the joint's rigid frame.
  The joint's frame keeps the node's axes (the bind rotation is Z_UP @ the node's), so offsets are not turned.
- Gravity direction: glTF's world is Y-up, jiggle's Z-up: turned by rig.motion.gltf_io.Z_UP ((x, y, z) ->
  (x, -z, y)) and normalised (a zero vector stays zero).

A malformed extension is an InputError naming the file and the field (``VRMC_springBone.springs[2].joints[0]
.node``) and what was expected.
"""
from __future__ import annotations

import math
import os

import numpy as np

from jiggle.rig.base.errors import InputError
from jiggle.rig.motion.gltf_io import Z_UP, GltfDocument, trs_matrix, world_chain

VRM1_DEFAULTS = {"hitRadius": 0.0, "stiffness": 1.0, "gravityPower": 0.0, "gravityDir": (0.0, -1.0, 0.0),
                 "dragForce": 0.5}
"""VRMC_springBone-1.0's joint defaults (VRMC_springBone.joint.schema.json): metres, -, -, glTF world, -."""
VRM0_DEFAULTS = {"hitRadius": 0.02, "stiffiness": 1.0, "gravityPower": 0.0, "gravityDir": (0.0, -1.0, 0.0),
                 "dragForce": 0.4}
"""VRM 0.x has no schema defaults: UniVRM's VRMSpringBone component defaults."""


def read_vrm_springs(path: str | os.PathLike, joint_names, unit_scale: float = 1.0,
                     doc: GltfDocument | None = None) -> list[dict]:
    """The VRM spring bones of a glTF/GLB file as chains of the character's joints (see the module).

    joint_names : (J,) the character's joint names (its glTF node names). unit_scale : metres per file unit
    (Character.meta["unit_scale"]). doc : the file already parsed, or None to read `path`.

    Returns one dict per chain, JSON-able: {"name": str, "joints": [joint index, root first], "stiffness": float,
    "gravity_power": float, "gravity_dir": [x, y, z] unit vector, Z-up world, "drag": float in [0, 1],
    "hit_radius": float metres, "colliders": [{"joint": int, "shape": "sphere" | "capsule", "offset": [3] metres
    in the joint's frame, "tail": [3] metres or None, "radius": metres}], "source": "VRMC_springBone" | "VRM0"};
    [] when the file defines none (or none of its spring joints is a joint of the character).
    """
    doc = doc if doc is not None else GltfDocument(path)
    ext = doc.gltf.extensions or {}
    reader = _Reader(doc, joint_names, float(unit_scale))
    if ext.get("VRMC_springBone") is not None:
        return reader.vrm1(ext["VRMC_springBone"])
    vrm = ext.get("VRM")
    if vrm is not None:
        _obj(vrm, "VRM", doc.path)
        if vrm.get("secondaryAnimation") is not None:
            return reader.vrm0(vrm["secondaryAnimation"])
    return []


def scaled_springs(springs: list[dict], factor: float) -> list[dict]:
    """`springs` (read_vrm_springs' dicts) with every length times `factor` (for Character.scaled)."""
    f = float(factor)
    vec = lambda v: None if v is None else [float(x) * f for x in v]  # noqa: E731
    return [{**s, "hit_radius": float(s["hit_radius"]) * f,
             "colliders": [{**c, "offset": vec(c["offset"]), "tail": vec(c.get("tail")),
                            "radius": float(c["radius"]) * f} for c in s.get("colliders", ())]}
            for s in springs]


# ------------------------------------------------------------------------------------------ checks
def _fail(path, field: str, expected: str, value) -> InputError:
    shown = repr(value)
    shown = shown if len(shown) <= 60 else shown[:57] + "..."
    return InputError(f"expected {expected}, found {shown}", path, field=field)


def _obj(value, field: str, path) -> dict:
    if not isinstance(value, dict):
        raise _fail(path, field, "an object", value)
    return value


def _list(parent: dict, key: str, field: str, path, required: bool = False) -> list:
    if key not in parent or parent[key] is None:
        if required:
            raise InputError("missing: expected a list", path, field=field)
        return []
    if not isinstance(parent[key], list):
        raise _fail(path, field, "a list", parent[key])
    return parent[key]


def _number(parent: dict, key: str, default: float, field: str, path, lo: float | None = None,
            hi: float | None = None) -> float:
    v = parent.get(key)
    if v is None:
        return float(default)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise _fail(path, field, "a finite number", v)
    if (lo is not None and v < lo) or (hi is not None and v > hi):
        span = f"from {lo:g} to {hi:g}" if hi is not None else f"at least {lo:g}"
        raise _fail(path, field, f"a number {span}", v)
    return float(v)


def _index(value, size: int, field: str, path, what: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value < size:
        raise _fail(path, field, f"an index of {what} (0..{size - 1})" if size else f"an index of {what} "
                    "(the file has none)", value)
    return int(value)


def _array3(parent: dict, key: str, default, field: str, path) -> np.ndarray:
    """VRM 1.0's vectors: [x, y, z]."""
    v = parent.get(key)
    if v is None:
        return np.array(default, np.float64)
    if not isinstance(v, list) or len(v) != 3 or any(isinstance(x, bool) or not isinstance(x, (int, float))
                                                     or not math.isfinite(x) for x in v):
        raise _fail(path, field, "3 finite numbers [x, y, z]", v)
    return np.array(v, np.float64)


def _xyz(parent: dict, key: str, default, field: str, path) -> np.ndarray:
    """VRM 0.x's vectors: {"x": .., "y": .., "z": ..}, each 0 when left out."""
    v = parent.get(key)
    if v is None:
        return np.array(default, np.float64)
    _obj(v, field, path)
    return np.array([_number(v, a, 0.0, f"{field}.{a}", path) for a in "xyz"])


# ------------------------------------------------------------------------------------------ reading
class _Reader:
    def __init__(self, doc: GltfDocument, joint_names, unit_scale: float):
        self.doc, self.path, self.s = doc, doc.path, unit_scale
        self.nodes = len(doc.gltf.nodes)
        at = {n: j for j, n in enumerate(joint_names)}
        # glTF node -> the character's joint (-1: not a joint), through the names both sides share
        self.joint = np.array([at.get(doc.node_names[i], -1) for i in range(self.nodes)], np.int64)
        self.holds = np.zeros(self.nodes, bool)   # the node is a joint or has one below it
        for i in np.nonzero(self.joint >= 0)[0]:
            k = int(i)
            while k >= 0 and not self.holds[k]:
                self.holds[k] = True
                k = int(doc.node_parent[k])

    # ---- helpers
    def node(self, value, field: str) -> int:
        return _index(value, self.nodes, field, self.path, "nodes")

    def gravity(self, v: np.ndarray) -> list:
        # glTF Y-up world -> jiggle Z-up world; Z_UP is an exact axis permutation (its float noise rounded off)
        g = Z_UP[:3, :3].round() @ v
        n = float(np.linalg.norm(g))
        return [float(x) for x in (g / n if n > 0 else g)]

    def node_scale(self, i: int) -> float:
        """The node's accumulated world scale in the rest pose (uniform for a joint: gltf_io checks it)."""
        chain = ([i] + self.doc.ancestors(i))[::-1]
        loc = {}
        for k in chain:
            t, r, sc, m = self.doc.node_trs(k)
            loc[k] = m if m is not None else trs_matrix(t, r, sc)
        return float(np.cbrt(abs(np.linalg.det(world_chain(chain, loc)[:3, :3]))))

    def collider(self, node: int, shape: str, offset: np.ndarray, tail, radius: float) -> dict:
        c = self.node_scale(node) * self.s        # node-local lengths -> metres in the joint's rigid frame
        return {"joint": int(self.joint[node]), "shape": shape, "offset": [float(x) * c for x in offset],
                "tail": None if tail is None else [float(x) * c for x in tail], "radius": radius * self.s}

    def spring(self, name: str, joints: list[int], settings: dict, colliders: list[dict], source: str) -> dict:
        return {"name": name, "joints": [int(j) for j in joints], "stiffness": settings["stiffness"],
                "gravity_power": settings["gravity_power"], "gravity_dir": self.gravity(settings["gravity_dir"]),
                "drag": settings["drag"], "hit_radius": settings["hit_radius"] * self.s,
                "colliders": colliders, "source": source}

    def children(self, i: int) -> list[int]:
        return [int(c) for c in (self.doc.gltf.nodes[i].children or [])]

    # ---- VRM 1.0
    def vrm1(self, ext) -> list[dict]:
        p, top = self.path, "VRMC_springBone"
        _obj(ext, top, p)
        if ext.get("specVersion") is not None and not isinstance(ext["specVersion"], str):
            raise _fail(p, f"{top}.specVersion", 'a string ("1.0")', ext["specVersion"])
        colliders = []
        for i, c in enumerate(_list(ext, "colliders", f"{top}.colliders", p)):
            f = f"{top}.colliders[{i}]"
            _obj(c, f, p)
            if "node" not in c:
                raise InputError("missing: expected the index of the node the collider rides", p, field=f"{f}.node")
            node = self.node(c["node"], f"{f}.node")
            if "shape" not in c:
                raise InputError("missing: expected {sphere: ..} or {capsule: ..}", p, field=f"{f}.shape")
            shape = _obj(c["shape"], f"{f}.shape", p)
            kinds = [k for k in ("sphere", "capsule") if shape.get(k) is not None]
            if len(kinds) != 1:
                raise _fail(p, f"{f}.shape", "exactly one of 'sphere' or 'capsule'", shape)
            kind = kinds[0]
            body = _obj(shape[kind], f"{f}.shape.{kind}", p)
            offset = _array3(body, "offset", (0.0, 0.0, 0.0), f"{f}.shape.{kind}.offset", p)
            tail = _array3(body, "tail", (0.0, 0.0, 0.0), f"{f}.shape.{kind}.tail", p) if kind == "capsule" else None
            radius = _number(body, "radius", 0.0, f"{f}.shape.{kind}.radius", p, lo=0.0)
            colliders.append((node, kind, offset, tail, radius))
        groups = []
        for i, g in enumerate(_list(ext, "colliderGroups", f"{top}.colliderGroups", p)):
            f = f"{top}.colliderGroups[{i}]"
            _obj(g, f, p)
            members = _list(g, "colliders", f"{f}.colliders", p, required=True)
            groups.append([_index(k, len(colliders), f"{f}.colliders[{n}]", p, f"{top}.colliders")
                           for n, k in enumerate(members)])
        out = []
        for i, s in enumerate(_list(ext, "springs", f"{top}.springs", p)):
            f = f"{top}.springs[{i}]"
            _obj(s, f, p)
            name = s.get("name")
            if name is not None and not isinstance(name, str):
                raise _fail(p, f"{f}.name", "a string", name)
            if s.get("center") is not None:
                self.node(s["center"], f"{f}.center")
            joints = _list(s, "joints", f"{f}.joints", p, required=True)
            if not joints:
                raise _fail(p, f"{f}.joints", "at least one joint", joints)
            nodes, settings = [], []
            for n, jt in enumerate(joints):
                fj = f"{f}.joints[{n}]"
                _obj(jt, fj, p)
                if "node" not in jt:
                    raise InputError("missing: expected the index of the joint's node", p, field=f"{fj}.node")
                node = self.node(jt["node"], f"{fj}.node")
                if nodes and nodes[-1] not in self.doc.ancestors(node):
                    raise InputError(f"node {node} is not below joints[{n - 1}]'s node {nodes[-1]}: each joint of a "
                                     "spring must be an ancestor of the next", p, field=f"{fj}.node")
                nodes.append(node)
                settings.append({
                    "hit_radius": _number(jt, "hitRadius", VRM1_DEFAULTS["hitRadius"], f"{fj}.hitRadius", p, lo=0.0),
                    "stiffness": _number(jt, "stiffness", VRM1_DEFAULTS["stiffness"], f"{fj}.stiffness", p, lo=0.0),
                    "gravity_power": _number(jt, "gravityPower", VRM1_DEFAULTS["gravityPower"],
                                             f"{fj}.gravityPower", p, lo=0.0),
                    "gravity_dir": _array3(jt, "gravityDir", VRM1_DEFAULTS["gravityDir"], f"{fj}.gravityDir", p),
                    "drag": _number(jt, "dragForce", VRM1_DEFAULTS["dragForce"], f"{fj}.dragForce", p, lo=0.0,
                                    hi=1.0)})
            used = []
            for n, k in enumerate(_list(s, "colliderGroups", f"{f}.colliderGroups", p)):
                for c in groups[_index(k, len(groups), f"{f}.colliderGroups[{n}]", p, f"{top}.colliderGroups")]:
                    if c not in used:
                        used.append(c)
            kept = [n for n, node in enumerate(nodes) if self.joint[node] >= 0]
            if not kept:
                continue                          # no joint of this spring is a joint of the character
            out.append(self.spring(name or f"spring{i}", [self.joint[nodes[n]] for n in kept], settings[kept[0]],
                                   [self.collider(*colliders[c]) for c in used if self.joint[colliders[c][0]] >= 0],
                                   "VRMC_springBone"))
        return out

    # ---- VRM 0.x
    def vrm0(self, sec) -> list[dict]:
        p, top = self.path, "VRM.secondaryAnimation"
        _obj(sec, top, p)
        groups = []
        for i, g in enumerate(_list(sec, "colliderGroups", f"{top}.colliderGroups", p)):
            f = f"{top}.colliderGroups[{i}]"
            _obj(g, f, p)
            if "node" not in g:
                raise InputError("missing: expected the index of the node the colliders ride", p, field=f"{f}.node")
            node = self.node(g["node"], f"{f}.node")
            members = []
            for n, c in enumerate(_list(g, "colliders", f"{f}.colliders", p)):
                fc = f"{f}.colliders[{n}]"
                _obj(c, fc, p)
                offset = _xyz(c, "offset", (0.0, 0.0, 0.0), f"{fc}.offset", p)
                offset[2] = -offset[2]            # VRM 0.x wrote Unity's left-handed z (three-vrm does the same)
                members.append((node, "sphere", offset, None, _number(c, "radius", 0.0, f"{fc}.radius", p, lo=0.0)))
            groups.append(members)
        out = []
        for i, b in enumerate(_list(sec, "boneGroups", f"{top}.boneGroups", p)):
            f = f"{top}.boneGroups[{i}]"
            _obj(b, f, p)
            comment = b.get("comment")
            if comment is not None and not isinstance(comment, str):
                raise _fail(p, f"{f}.comment", "a string", comment)
            # the spec's spelling first; a file that corrected it is read too
            key = "stiffiness" if "stiffiness" in b or "stiffness" not in b else "stiffness"
            settings = {
                "stiffness": _number(b, key, VRM0_DEFAULTS["stiffiness"], f"{f}.{key}", p),
                "gravity_power": _number(b, "gravityPower", VRM0_DEFAULTS["gravityPower"], f"{f}.gravityPower", p),
                "gravity_dir": _xyz(b, "gravityDir", VRM0_DEFAULTS["gravityDir"], f"{f}.gravityDir", p),
                "drag": _number(b, "dragForce", VRM0_DEFAULTS["dragForce"], f"{f}.dragForce", p),
                "hit_radius": _number(b, "hitRadius", VRM0_DEFAULTS["hitRadius"], f"{f}.hitRadius", p, lo=0.0)}
            if b.get("center") is not None:       # -1 (UniVRM's "none") or a node
                c = b["center"]
                if c != -1:
                    self.node(c, f"{f}.center")
            used = []
            for n, k in enumerate(_list(b, "colliderGroups", f"{f}.colliderGroups", p)):
                for c in groups[_index(k, len(groups), f"{f}.colliderGroups[{n}]", p, f"{top}.colliderGroups")]:
                    used.append(c)
            bones = [self.node(v, f"{f}.bones[{n}]") for n, v in enumerate(_list(b, "bones", f"{f}.bones", p))]
            base = comment or f"boneGroup{i}"
            for root in bones:
                joints = self.strand(root)
                if joints:
                    name = base if len(bones) == 1 else f"{base} ({self.doc.node_names[root]})"
                    cols = [self.collider(*c) for c in used if self.joint[c[0]] >= 0]
                    out.append(self.spring(name, joints, settings, cols, "VRM0"))
        return out

    def strand(self, root: int) -> list[int]:
        """The character's joints from `root` down its first child (the first that is or holds a joint)."""
        out, k = [], root
        while k is not None:
            if self.joint[k] >= 0:
                out.append(int(self.joint[k]))
            k = next((c for c in self.children(k) if self.holds[c]), None)
        return out
