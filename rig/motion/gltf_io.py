"""Reading glTF 2.0 files (.glb, .gltf): buffers (GLB binary chunk, external files, data URIs),
accessors (byteStride, normalized integers, sparse), node transforms, and which nodes form a
skeleton's joint tree. Shared by :mod:`rig.motion.gltf_skeleton` and :mod:`rig.motion.gltf_anim`.

Readings where glTF leaves a choice, stated once here:
- Axes and units: glTF is Y-up metres; jiggle's world is Z-up, so every world transform is turned
  by ``rig.motion.bvh.Y_TO_Z_UP`` ((x, y, z) -> (x, -z, y)), as BVH files are.
- Joints: the skin's joints plus the nodes needed to join them into a tree (every node on the path
  from a joint up to the lowest common ancestor of the skin's joints in the same scene tree),
  ordered parents-first (depth-first from that ancestor, children in file order). A joint's name is
  its node's name; unnamed nodes are called ``node<index>`` and a repeated name gets ``_<index>``.
- Transforms above the tree (scene roots such as a Z-up fix or an armature's scale) are accumulated
  into the root joint.
- Rigid frames: a Clip is rigid, glTF nodes may scale. A joint's world *position* is taken from the
  full glTF matrices (exact for any scale); its world *rotation* is the product of the node rotations
  from the root down (a ``matrix`` node contributes the rotation of its polar decomposition). A
  child's local translation is its world offset from the parent expressed in the parent's rigid
  frame, so scale is folded into the children's translations. Under uniform positive scale this is
  exact: the joint's full glTF world matrix is its rigid transform times a uniform scale c, which a
  character folds into its bind matrices and rest skin (rig.motion.gltf_skeleton), so a centimetre
  export whose armature node scales by 0.01 comes out in metres.
- Scale a skeleton may carry: uniform and positive, on the joints and on every node above them
  (:func:`check_uniform_scale`, relative tolerance ``SCALE_RTOL`` for float32 noise). Non-uniform,
  negative (mirroring) or zero scale cannot be a rigid joint times a uniform scale, so skinning with
  it would differ from the spec; readers of skins refuse it naming the node. A clip read without a
  skin (``skin=None``, mocap only) keeps joint positions exact under any scale and drops the shear
  from the bone frames.
"""
from __future__ import annotations

import base64
import json
import os
import struct
import urllib.parse

import numpy as np

from jiggle.rig.base.errors import InputError, require_file
from jiggle.rig.motion import quat
from jiggle.rig.motion.bvh import Y_TO_Z_UP

_COMPONENT = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}
_NORM_DIV = {5120: 127.0, 5121: 255.0, 5122: 32767.0, 5123: 65535.0, 5125: 4294967295.0}
_NCOMP = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
Z_UP = np.eye(4)
Z_UP[:3, :3] = quat.to_matrix(Y_TO_Z_UP)  # glTF world (Y-up) -> jiggle world (Z-up)
Z_UP.setflags(write=False)


# ---------------------------------------------------------------------------------- the document
# (JSON path pattern, the array its index points into); "*" is every item of an array or every value of
# an object. Checked on the raw JSON before anything reads it, so no reader meets a dangling index.
_REFERENCES = (
    ("scenes.*.nodes.*", "nodes"), ("scene", "scenes"),
    ("nodes.*.children.*", "nodes"), ("nodes.*.mesh", "meshes"), ("nodes.*.skin", "skins"),
    ("nodes.*.camera", "cameras"),
    ("meshes.*.primitives.*.attributes.*", "accessors"), ("meshes.*.primitives.*.indices", "accessors"),
    ("meshes.*.primitives.*.material", "materials"), ("meshes.*.primitives.*.targets.*.*", "accessors"),
    ("skins.*.joints.*", "nodes"), ("skins.*.inverseBindMatrices", "accessors"), ("skins.*.skeleton", "nodes"),
    ("accessors.*.bufferView", "bufferViews"), ("accessors.*.sparse.indices.bufferView", "bufferViews"),
    ("accessors.*.sparse.values.bufferView", "bufferViews"), ("bufferViews.*.buffer", "buffers"),
    ("animations.*.channels.*.target.node", "nodes"),
    ("materials.*.pbrMetallicRoughness.baseColorTexture.index", "textures"),
    ("materials.*.pbrMetallicRoughness.metallicRoughnessTexture.index", "textures"),
    ("materials.*.normalTexture.index", "textures"), ("materials.*.occlusionTexture.index", "textures"),
    ("materials.*.emissiveTexture.index", "textures"),
    ("textures.*.sampler", "samplers"), ("textures.*.source", "images"), ("images.*.bufferView", "bufferViews"),
)


def _walk(obj, parts: list[str], path: str):
    """(JSON path, value) of every value at `parts` below obj ("*": every item or value)."""
    if not parts:
        yield path, obj
        return
    head, rest = parts[0], parts[1:]
    if head == "*":
        items = enumerate(obj) if isinstance(obj, list) else obj.items() if isinstance(obj, dict) else ()
        for k, v in items:
            yield from _walk(v, rest, f"{path}[{k}]" if isinstance(obj, list) else f"{path}.{k}")
    elif isinstance(obj, dict) and head in obj:
        yield from _walk(obj[head], rest, f"{path}.{head}" if path else head)


# Arrays of objects, and the keys the spec requires of their items ("*" as in _REFERENCES).
_OBJECTS = (
    ("scenes.*", ()), ("nodes.*", ()), ("meshes.*", ("primitives",)), ("meshes.*.primitives.*", ("attributes",)),
    ("skins.*", ("joints",)), ("accessors.*", ("componentType", "count", "type")),
    ("bufferViews.*", ("buffer", "byteLength")), ("buffers.*", ("byteLength",)),
    ("animations.*", ("channels", "samplers")), ("animations.*.channels.*", ("sampler", "target")),
    ("animations.*.channels.*.target", ("path",)), ("animations.*.samplers.*", ("input", "output")),
    ("materials.*", ()), ("textures.*", ()), ("images.*", ()), ("samplers.*", ()),
)


def check_structure(doc: dict, path: str) -> None:
    """InputError naming the JSON path of the first item of a glTF array that is not an object, or lacks a
    key the spec requires (an accessor without componentType, a channel without target, ...)."""
    for pattern, required in _OBJECTS:
        parent, last = pattern.rsplit(".", 1)
        for where, value in _walk(doc, parent.split("."), "") if last == "*" else ():
            if not isinstance(value, list):
                raise InputError(f"expected an array, got {type(value).__name__}", path, field=where)
        for where, value in _walk(doc, pattern.split("."), ""):
            if not isinstance(value, dict):
                raise InputError(f"expected an object, got {json.dumps(value)[:40]}", path, field=where)
            missing = [k for k in required if value.get(k) is None]
            if missing:
                raise InputError(f"the required {', '.join(missing)} is missing", path, field=f"{where}.{missing[0]}")


def check_indices(doc: dict, path: str) -> None:
    """InputError naming the JSON path of the first index in the glTF JSON `doc` that points past its
    array (`meshes[0].primitives[0].indices = 999: past the 83 accessors`), or is not a whole number;
    also an animation channel's sampler and a sampler's input/output accessors."""
    if not isinstance(doc, dict):
        return
    checks = list(_REFERENCES)
    for a, anim in enumerate(doc.get("animations") or []):
        if not isinstance(anim, dict):
            continue
        samplers = anim.get("samplers") or []
        for c, ch in enumerate(anim.get("channels") or []):
            if isinstance(ch, dict) and "sampler" in ch:
                _check(ch["sampler"], len(samplers), f"animations[{a}].samplers",
                       f"animations[{a}].channels[{c}].sampler", path)
    for pattern, target in checks:
        size = len(doc.get(target) or [])
        for where, value in _walk(doc, pattern.split("."), ""):
            _check(value, size, target, where, path)
    n_acc = len(doc.get("accessors") or [])
    for a, anim in enumerate(doc.get("animations") or []):
        for k, smp in enumerate((anim or {}).get("samplers") or [] if isinstance(anim, dict) else []):
            for key in ("input", "output"):
                if isinstance(smp, dict) and key in smp:
                    _check(smp[key], n_acc, "accessors", f"animations[{a}].samplers[{k}].{key}", path)


def _check(value, size: int, target: str, where: str, path: str) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value < size:
        raise InputError(f"{value!r}: past the {size} {target}" if isinstance(value, int) and not isinstance(
            value, bool) else f"{value!r} is not an index into the {size} {target}", path, field=where)


_PARSED: dict = {}
"""(real path, inode, size, mtime) -> (pygltflib.GLTF2, GLB binary chunk): the last files parsed, shared read-only by
GltfDocuments of the same unchanged file (a character and its clip read from one file parse it once; pygltflib's
parse is most of a read)."""
_PARSED_KEEP = 4


class GltfDocument:
    """A parsed glTF file: the pygltflib model plus its buffers as bytes.

    Attributes
    ----------
    path : the file.
    gltf : pygltflib.GLTF2.
    node_parent : (N,) int, parent node of each node or -1.
    node_names : (N,) unique names (see module docstring).
    """

    def __init__(self, path: str | os.PathLike):
        self.path = require_file(path, "glTF file")
        st = os.stat(self.path)
        key = (os.path.realpath(self.path), st.st_ino, st.st_size, st.st_mtime_ns)
        if key not in _PARSED:
            _PARSED[key] = self._parse()
            while len(_PARSED) > _PARSED_KEEP:
                _PARSED.pop(next(iter(_PARSED)))
        self.gltf, self._bin = _PARSED[key]
        self._buffers: dict[int, bytes] = {}
        self._accessors: dict[int, np.ndarray] = {}
        self._index()

    def _parse(self):
        """(pygltflib.GLTF2, the GLB binary chunk or None) of the file, checked."""
        import pygltflib
        with open(self.path, "rb") as fh:
            data = fh.read()
        bin_chunk = None
        if data[:4] == b"glTF":
            json_text, bin_chunk = self._split_glb(data)
        else:
            try:
                json_text = data.decode("utf-8-sig")
                obj = json.loads(json_text)
            except (UnicodeDecodeError, json.JSONDecodeError):
                raise InputError("not a glTF file: neither a GLB binary (magic 'glTF') nor JSON text",
                                 self.path) from None
            if not isinstance(obj, dict) or "asset" not in obj:
                raise InputError("not a glTF file: JSON without the required 'asset' object", self.path,
                                 field="asset")
        try:
            gltf = pygltflib.GLTF2.from_json(json_text)
        except Exception as e:  # pygltflib/dataclasses_json raise many types for malformed JSON
            raise InputError(f"not a valid glTF document ({type(e).__name__}: {e})", self.path) from None
        version = str(getattr(gltf.asset, "version", "") or "")
        if not version.startswith("2"):
            raise InputError(f"glTF version {version or '(none)'} is not supported; expected 2.x", self.path,
                             field="asset.version")
        raw = json.loads(json_text)
        check_structure(raw, self.path)
        check_indices(raw, self.path)
        return gltf, bin_chunk

    def _index(self) -> None:
        g = self.gltf
        n = len(g.nodes)
        parent = np.full(n, -1, dtype=np.int64)
        for i, nd in enumerate(g.nodes):
            for c in nd.children or []:
                if not 0 <= c < n:
                    raise InputError(f"child {c} is not a node index (0..{n - 1})", self.path,
                                     field=f"nodes[{i}].children")
                if parent[c] >= 0:
                    raise InputError(f"node {c} has two parents ({parent[c]} and {i}); glTF nodes form trees",
                                     self.path, field=f"nodes[{i}].children")
                parent[c] = i
        for i in range(n):  # a cycle never reaches a root
            k, steps = i, 0
            while k >= 0:
                k, steps = parent[k], steps + 1
                if steps > n:
                    raise InputError(f"node {i} is in a cycle of the node hierarchy", self.path, field="nodes")
        self.node_parent = parent
        for i in range(n):  # every node's transform is numbers of the right count, before any reader uses it
            self.node_trs(i)
        names, seen = [], set()
        for i, nd in enumerate(g.nodes):
            s = nd.name or f"node{i}"
            if s in seen:
                s = f"{s}_{i}"
            seen.add(s)
            names.append(s)
        self.node_names = names

    def _split_glb(self, data: bytes) -> tuple[str, bytes | None]:
        if len(data) < 20:
            raise InputError("GLB file is shorter than its 12-byte header and first chunk", self.path)
        _, version, length = struct.unpack_from("<4sII", data, 0)
        if version != 2:
            raise InputError(f"GLB container version {version}; expected 2", self.path, field="header")
        length = min(length, len(data))
        pos, json_text, bin_chunk = 12, None, None
        while pos + 8 <= length:
            size, kind = struct.unpack_from("<II", data, pos)
            body = data[pos + 8:pos + 8 + size]
            if len(body) < size:
                raise InputError(f"GLB chunk at byte {pos} is truncated ({len(body)} of {size} bytes)", self.path)
            if kind == 0x4E4F534A:  # "JSON"
                json_text = body.decode("utf-8", errors="replace")
            elif kind == 0x004E4942 and bin_chunk is None:  # "BIN\0"
                bin_chunk = body
            pos += 8 + size + (-size % 4)
        if json_text is None:
            raise InputError("GLB file has no JSON chunk", self.path)
        return json_text, bin_chunk

    # -------------------------------------------------------------------------------- buffers
    def buffer(self, i: int) -> bytes:
        if i in self._buffers:
            return self._buffers[i]
        g = self.gltf
        if not 0 <= i < len(g.buffers):
            raise InputError(f"buffer {i} does not exist ({len(g.buffers)} buffers)", self.path, field="buffers")
        b = g.buffers[i]
        where = f"buffers[{i}]"
        if b.uri is None:
            if self._bin is None:
                raise InputError("buffer without a uri, but the file has no GLB binary chunk", self.path, field=where)
            data = self._bin
        elif b.uri.startswith("data:"):
            head, _, payload = b.uri.partition(",")
            if ";base64" not in head:
                raise InputError("data URI is not base64", self.path, field=f"{where}.uri")
            try:
                data = base64.b64decode(payload, validate=False)
            except ValueError as e:
                raise InputError(f"data URI is not valid base64 ({e})", self.path, field=f"{where}.uri") from None
        else:
            ext = os.path.join(os.path.dirname(self.path), urllib.parse.unquote(b.uri))
            if not os.path.isfile(ext):
                raise InputError(f"external buffer file {b.uri!r} not found (looked for {ext})", self.path,
                                 field=f"{where}.uri")
            with open(ext, "rb") as fh:
                data = fh.read()
        if b.byteLength is not None and len(data) < b.byteLength:
            raise InputError(f"buffer holds {len(data)} bytes, byteLength says {b.byteLength}", self.path, field=where)
        self._buffers[i] = data
        return data

    def _view(self, i: int, what: str) -> tuple[bytes, int, int, int | None]:
        g = self.gltf
        if not 0 <= i < len(g.bufferViews):
            raise InputError(f"bufferView {i} does not exist", self.path, field=what)
        bv = g.bufferViews[i]
        data = self.buffer(bv.buffer)
        start = bv.byteOffset or 0
        if start + bv.byteLength > len(data):
            raise InputError(f"bufferView {i} ends at byte {start + bv.byteLength}, past its buffer's "
                             f"{len(data)} bytes", self.path, field=f"bufferViews[{i}]")
        return data, start, bv.byteLength, bv.byteStride

    def _read(self, view: int, offset: int, count: int, ctype: int, ncomp: int, what: str) -> np.ndarray:
        data, start, length, stride = self._view(view, what)
        dt = np.dtype(_COMPONENT[ctype]).newbyteorder("<")
        elem = dt.itemsize * ncomp
        stride = stride or elem
        need = offset + stride * (count - 1) + elem if count else 0
        if need > length:
            raise InputError(f"reads {need} bytes from bufferView {view}, which holds {length}", self.path, field=what)
        arr = np.ndarray((count, ncomp), dtype=dt, buffer=data, offset=start + offset, strides=(stride, dt.itemsize))
        return np.array(arr)

    def accessor(self, i: int, what: str = "") -> np.ndarray:
        """(count, components) float64 values of accessor `i` (normalized integers mapped to [-1, 1]
        or [0, 1] as the spec says; sparse substitution applied). Cached; do not modify."""
        if i in self._accessors:
            return self._accessors[i]
        g = self.gltf
        what = what or f"accessors[{i}]"
        if i is None or not 0 <= i < len(g.accessors):
            raise InputError(f"accessor {i} does not exist ({len(g.accessors)} accessors)", self.path, field=what)
        a = g.accessors[i]
        if a.componentType not in _COMPONENT or a.type not in _NCOMP:
            raise InputError(f"unknown componentType {a.componentType} / type {a.type!r}", self.path,
                             field=f"accessors[{i}]")
        nc = _NCOMP[a.type]
        if a.type in ("MAT2", "MAT3") and np.dtype(_COMPONENT[a.componentType]).itemsize < 4:
            raise InputError("MAT2/MAT3 accessors of 1- or 2-byte components (column padding) are not supported",
                             self.path, field=f"accessors[{i}]")
        if a.bufferView is None:
            out = np.zeros((a.count, nc), dtype=np.float64)
        else:
            out = self._read(a.bufferView, a.byteOffset or 0, a.count, a.componentType, nc,
                             f"accessors[{i}]").astype(np.float64)
        sp = a.sparse
        if sp is not None and sp.count:
            idx = self._read(sp.indices.bufferView, sp.indices.byteOffset or 0, sp.count,
                             sp.indices.componentType, 1, f"accessors[{i}].sparse.indices")[:, 0].astype(np.int64)
            val = self._read(sp.values.bufferView, sp.values.byteOffset or 0, sp.count, a.componentType, nc,
                             f"accessors[{i}].sparse.values").astype(np.float64)
            if np.any(idx >= a.count):
                raise InputError("sparse index past the accessor's count", self.path, field=f"accessors[{i}].sparse")
            out[idx] = val
        if a.normalized and a.componentType in _NORM_DIV:
            out = out / _NORM_DIV[a.componentType]
            if a.componentType in (5120, 5122):
                out = np.maximum(out, -1.0)
        out.setflags(write=False)
        self._accessors[i] = out
        return out

    # -------------------------------------------------------------------------------- nodes
    def node_trs(self, i: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
        """Rest local transform of node `i`: translation (3,), rotation (4,) w,x,y,z, scale (3,), and the
        node's 4x4 `matrix` when it gives one (then T, R, S are its decomposition, R the polar rotation)."""
        nd = self.gltf.nodes[i]
        if nd.matrix is not None:
            m = np.asarray(nd.matrix, dtype=float)
            if m.shape != (16,) or not np.all(np.isfinite(m)):
                raise InputError("matrix must be 16 finite numbers", self.path, field=f"nodes[{i}].matrix")
            m = m.reshape(4, 4).T  # glTF stores column-major
            r = polar_rotation(m[:3, :3])
            s = np.einsum("ij,ij->j", quat.to_matrix(r), m[:3, :3])
            return m[:3, 3].copy(), r, s, m
        t = np.zeros(3) if nd.translation is None else np.asarray(nd.translation, float)
        r = quat.IDENTITY.copy() if nd.rotation is None else quat.from_xyzw(np.asarray(nd.rotation, float))
        s = np.ones(3) if nd.scale is None else np.asarray(nd.scale, float)
        if t.shape != (3,) or r.shape != (4,) or s.shape != (3,) or not np.all(np.isfinite(np.r_[t, r, s])):
            raise InputError("translation/rotation/scale must be 3/4/3 finite numbers", self.path, field=f"nodes[{i}]")
        if np.linalg.norm(r) < 1e-12:
            raise InputError("rotation is a zero quaternion", self.path, field=f"nodes[{i}].rotation")
        return t, quat.normalize(r), s, None

    def ancestors(self, i: int) -> list[int]:
        """Nodes above `i`, nearest first."""
        out = []
        k = self.node_parent[i]
        while k >= 0:
            out.append(int(k))
            k = self.node_parent[k]
        return out

    def skin_users(self, skin: int) -> list[int]:
        return [i for i, nd in enumerate(self.gltf.nodes) if nd.skin == skin]

    def contents(self) -> str:
        """One line saying what the file holds, for error messages."""
        g = self.gltf
        return (f"{len(g.scenes)} scene(s), {len(g.nodes)} node(s), {len(g.meshes)} mesh(es), "
                f"{len(g.skins)} skin(s), {len(g.animations)} animation(s)")


SCALE_RTOL = 1e-4
"""Relative spread of a node's three scale factors still read as uniform (float32 exports write
0.99999994 or 1.0000001 for 1; an FBX gone through Maya and Blender writes 1.00002: 0.1 mm on a 1 m bone)."""


def scale_problem(linear: np.ndarray) -> tuple[str, int] | None:
    """Why linear maps (..., 3, 3) are not all a rotation times a uniform positive scale, or None.
    Returns (kind, index of the first offending map); kind is "zero", "negative" or "non-uniform"."""
    lin = np.asarray(linear, dtype=float).reshape(-1, 3, 3)
    det = np.linalg.det(lin)
    cols = np.linalg.norm(lin, axis=-2)  # column lengths: the scale factors of T @ R @ S
    for k in range(len(lin)):
        c = np.cbrt(abs(det[k]))
        if not c > 1e-12 * max(float(cols[k].max()), 1e-300):
            return "zero", k
        if det[k] < 0:
            return "negative", k
        if np.abs(lin[k].T @ lin[k] / (c * c) - np.eye(3)).max() > 2 * SCALE_RTOL:
            return "non-uniform", k
    return None


def check_uniform_scale(doc: "GltfDocument", i: int, scales: np.ndarray | None = None,
                        field: str | None = None, when: str = "") -> None:
    """InputError naming node `i` unless its scale is uniform and positive.

    scales : (T, 3) sampled scale factors of a TRS node (default its own `scale`); a `matrix` node is
        checked on its linear part.
    field : where to point (default ``nodes[i] "name"``); when : added to the message (e.g. a time).
    """
    nd = doc.gltf.nodes[i]
    if nd.matrix is not None and scales is None:
        lin = np.asarray(nd.matrix, dtype=float).reshape(4, 4).T[:3, :3][None]
        what, shown = "matrix", np.linalg.norm(lin[0], axis=0) * np.sign(np.linalg.det(lin[0]) or 1.0)
    else:
        s = np.atleast_2d(np.ones(3) if scales is None and nd.scale is None else
                          np.asarray(nd.scale if scales is None else scales, dtype=float))
        lin, what, shown = s[:, None, :] * np.eye(3), "scale", None
    bad = scale_problem(lin)
    if bad is None:
        return
    kind, k = bad
    if shown is None:
        shown = s[k]
    text = ", ".join(f"{v:.6g}" for v in shown)
    label = "column lengths" if what == "matrix" else "scale"
    raise InputError(f"{kind} {label} [{text}]{when} is not supported: joints and the nodes above a skeleton "
                     f"must scale uniformly and positively to be posed as rigid joints (a mirror or a stretch "
                     f"is not); apply the scale in the exporting tool (Blender: Object > Apply > Scale)",
                     doc.path, field=field or f'nodes[{i}] "{doc.node_names[i]}"')


def polar_rotation(m: np.ndarray) -> np.ndarray:
    """The rotations (..., 4) w,x,y,z nearest to linear maps (..., 3, 3) (polar factor, det fixed to +1)."""
    u, _, vt = np.linalg.svd(m)
    d = np.where(np.linalg.det(u @ vt) < 0, -1.0, 1.0)
    u = u.copy()
    u[..., :, 2] *= d[..., None]
    return quat.from_matrix(u @ vt)


def trs_matrix(t: np.ndarray, r: np.ndarray, s: np.ndarray) -> np.ndarray:
    """(..., 4, 4) = T @ R @ S from translation (..., 3), rotation (..., 4) w,x,y,z, scale (..., 3)."""
    m = np.zeros(t.shape[:-1] + (4, 4))
    m[..., :3, :3] = quat.to_matrix(r) * s[..., None, :]
    m[..., :3, 3] = t
    m[..., 3, 3] = 1.0
    return m


def joint_tree(doc: GltfDocument, joints: list[int]) -> tuple[list[int], np.ndarray]:
    """The tree holding `joints`: node indices ordered parents-first, and (J,) int32 parent index in
    that order (-1 for a root). See the module docstring for which nodes are added."""
    groups: dict[int, list[int]] = {}
    for j in dict.fromkeys(int(x) for x in joints):
        chain = [j] + doc.ancestors(j)
        groups.setdefault(chain[-1], []).append(j)
    keep: set[int] = set()
    tops = []
    for top, members in sorted(groups.items()):
        chains = [([m] + doc.ancestors(m))[::-1] for m in members]  # top first
        depth = 0
        while all(len(c) > depth for c in chains) and len({c[depth] for c in chains}) == 1:
            depth += 1
        lca = chains[0][depth - 1]
        tops.append(lca)
        for c in chains:
            keep.update(c[depth - 1:])
    order: list[int] = []
    parents: list[int] = []
    pos: dict[int, int] = {}

    def visit(i: int, parent: int):
        pos[i] = len(order)
        order.append(i)
        parents.append(parent)
        for c in doc.gltf.nodes[i].children or []:
            if c in keep:
                visit(c, pos[i])

    for t in tops:
        visit(t, -1)
    return order, np.asarray(parents, dtype=np.int32)


def world_chain(nodes: list[int], local_m: dict[int, np.ndarray]) -> np.ndarray:
    """Product of local matrices along `nodes` (root first): (4, 4), or (T, 4, 4) when some
    `local_m[i]` is (T, 4, 4)."""
    m = np.eye(4)
    for i in nodes:
        m = m @ local_m[i]
    return m


def rigid_locals(parents: np.ndarray, above: np.ndarray, local_m: np.ndarray, local_r: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rigid local transforms of a joint tree whose glTF transforms may scale.

    Parameters
    ----------
    parents : (J,) int, parents first.
    above : (T, J, 4, 4) world matrix (Z-up) of each root joint's parent node, used for roots only.
    local_m : (T, J, 4, 4) glTF local matrix of each joint (T @ R @ S or the node's matrix).
    local_r : (T, J, 4) w,x,y,z rotation of each joint's local transform.

    Returns
    -------
    rotations (T, J, 4), translations (T, J, 3) metres in the Clip convention, and the full world
    matrices (T, J, 4, 4).
    """
    T, J = local_r.shape[:2]
    world_m = np.empty((T, J, 4, 4))
    world_r = np.empty((T, J, 4))
    rot = np.empty((T, J, 4))
    tra = np.empty((T, J, 3))
    for j, p in enumerate(parents):
        if p < 0:
            world_m[:, j] = above[:, j] @ local_m[:, j]
            up = polar_rotation(above[:, j, :3, :3])
            world_r[:, j] = quat.mul(up, local_r[:, j])
            rot[:, j] = world_r[:, j]
            tra[:, j] = world_m[:, j, :3, 3]
        else:
            world_m[:, j] = world_m[:, p] @ local_m[:, j]
            world_r[:, j] = quat.mul(world_r[:, p], local_r[:, j])
            rot[:, j] = local_r[:, j]
            # Scale above this joint lives in the parent's matrix: fold it into the translation.
            tra[:, j] = quat.rotate(quat.conj(world_r[:, p]), world_m[:, j, :3, 3] - world_m[:, p, :3, 3])
    return rot, tra, world_m
