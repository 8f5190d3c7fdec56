"""FBX 6.x (FBX 2006-2010 files, binary or ASCII) lifted into FBX 7.x's object model, for Blender's importer.

FBX 6 holds the same scene in an older layout: objects are named, not numbered ("Model::Hips"), and connected
by name; a mesh model carries its geometry inline; settings are `Properties60` lists (`Property: name, type,
flags, values`); the animation is a `Takes` section (per take, per model, nested `Channel: "Transform" > "T" >
"X"` curves whose `Key` list mixes times, values and interpolation letters). FBX 7 numbers every object, splits a
mesh model from its Geometry and a bone from its NodeAttribute, writes `Properties70` (`P: name, type, label,
flags, values`) and animation as AnimationStack > AnimationLayer > AnimationCurveNode > AnimationCurve objects.
`lift` rewrites the one into the other, keeping what a character needs: models (meshes, bones, nulls) with their
transforms and pivots, geometry with its layers (normals, UVs, materials, smoothing), skin deformers and
clusters (indexes, weights, bind matrices), bind poses, materials, global settings (units, axes, frame rate)
and every take's translation, rotation and scaling curves. Cameras, lights, textures and constraints are left
out. Keys keep their times and values; their cubic tangents are not carried (Blender's importer interpolates
every FBX curve linearly, so they would not be read), and the 6.x key formats are read as ufbx reads them
(ufbx/ufbx, `ufbxi_read_take_anim_channel`).
"""
from __future__ import annotations

import numpy as np

from jiggle.rig.base.errors import InputError
from jiggle.rig.motion.fbx_tree import CLASS_SEP, Node, _typed_array, property_value_type, split_name

_ARRAY_ELEMENTS = {"Vertices", "PolygonVertexIndex", "Edges", "Normals", "NormalsW", "NormalsIndex", "Binormals",
                   "BinormalsIndex", "Tangents", "TangentsIndex", "UV", "UVIndex", "Smoothing", "Materials",
                   "Colors", "ColorIndex", "Indexes", "Weights", "Transform", "TransformLink", "Matrix",
                   "TextureId", "EdgeCrease", "VertexCrease"}
_INT_ELEMENTS = {"PolygonVertexIndex", "Edges", "NormalsIndex", "BinormalsIndex", "TangentsIndex", "UVIndex",
                 "Smoothing", "Materials", "ColorIndex", "Indexes", "TextureId"}
_LABELS = {"double": "Number", "int": "Integer", "Vector3D": "Vector", "ColorRGB": "Color"}
_BONES = {"Limb", "LimbNode", "Root"}
_KEPT_MODELS = {"Mesh", "Null", "Root", "Limb", "LimbNode", "Skeleton", "Marker", ""}
_CHANNELS = {"T": "Lcl Translation", "R": "Lcl Rotation", "S": "Lcl Scaling"}
_LINEAR = 0x00000004                                # FBX 7's KeyAttrFlags: linear interpolation


def lift(nodes: list[Node], path: str) -> list[Node]:
    """The FBX 7.4 tree of an FBX 6.x tree (see the module's docstring); InputError for a tree that is not one."""
    top = {n.name: n for n in nodes}
    objects = top.get("Objects")
    if objects is None:
        raise InputError("FBX 6: the file has no Objects section", path)
    ids = _Ids()
    out_objects, conns, settings = Node("Objects"), Node("Connections"), None
    geometry_of: dict[str, int] = {}                 # mesh model key -> its new Geometry's id
    kept: set[str] = set()
    for o in objects.children:
        cls, name = split_name(str(o.props[0])) if o.props else ("", "")
        kind = str(o.props[1]) if len(o.props) > 1 else ""
        if o.name == "GlobalSettings":
            settings = Node("GlobalSettings", [], "", [_scalar("Version", 1000), _properties(o)])
        elif o.name == "Model" and kind in _KEPT_MODELS:
            key = _key(o.props[0])
            kept.add(key)
            _model(o, name, kind, ids.of(key), out_objects, conns, ids, geometry_of, key)
        elif o.name == "Deformer" and kind in ("Skin", "Cluster"):
            key = _key(o.props[0])
            kept.add(key)
            out_objects.children.append(_deformer(o, name, kind, ids.of(key)))
        elif o.name == "Pose" and kind == "BindPose":
            out_objects.children.append(_pose(o, name, ids.of(_key(o.props[0])), ids))
        elif o.name == "Material":
            key = _key(o.props[0])
            kept.add(key)
            out_objects.children.append(Node("Material", [ids.of(key), name + CLASS_SEP + "Material", ""], "LSS",
                                             [_scalar("Version", 102), _string("ShadingModel", "lambert"),
                                              _scalar("MultiLayer", 0), _properties(o)]))
    for c in (top["Connections"].all("Connect") if "Connections" in top else []):
        if len(c.props) < 3 or str(c.props[0]) != "OO":
            continue
        child, parent = _key(c.props[1]), _key(c.props[2])
        if child not in kept or (parent not in kept and split_name(parent)[1] != "Scene"):
            continue
        if split_name(child)[0] == "Deformer" and parent in geometry_of:
            parent_id = geometry_of[parent]          # FBX 7 hangs a skin on the mesh's Geometry, not its model
        else:
            parent_id = 0 if split_name(parent)[1] == "Scene" and parent not in kept else ids.of(parent)
        conns.children.append(Node("C", ["OO", ids.of(child), parent_id], "SLL"))
    _takes(top.get("Takes"), kept, ids, out_objects, conns, path)
    settings = _frame_rate(settings or Node("GlobalSettings", [], "", [_scalar("Version", 1000), Node("Properties70")]),
                           top.get("Version5"))
    head = top.get("FBXHeaderExtension") or Node("FBXHeaderExtension")
    head = Node(head.name, [], "", [c for c in head.children if c.name != "FBXVersion"] + [_scalar("FBXVersion", 7400)])
    defs = Node("Definitions", [], "", [_scalar("Version", 100), _scalar("Count", 0)])
    return [head, settings, defs, out_objects, conns]


# ----------------------------------------------------------------------------------------- objects

class _Ids:
    def __init__(self):
        self.ids: dict[str, int] = {}

    def of(self, key: str) -> int:
        return self.ids.setdefault(key, 1_000_000 + len(self.ids))

    def new(self) -> int:
        return self.of(f"\x00new{len(self.ids)}")


def _key(name) -> str:
    cls, n = split_name(str(name))
    return cls + "::" + n


def _scalar(name: str, v) -> Node:
    return Node(name, [v], "D" if isinstance(v, float) else "I")


def _string(name: str, s: str) -> Node:
    return Node(name, [s], "S")


def _properties(o: Node) -> Node:
    """Properties60 `Property: name, type, flags, values...` -> Properties70 `P: name, type, label, flags,
    values...`, values typed by the property's type as FBX 7 types them."""
    out = Node("Properties70")
    src = o.find("Properties60")
    for p in (src.children if src else []):
        if p.name != "Property" or len(p.props) < 3:
            continue
        name, kind, flags = str(p.props[0]), str(p.props[1]), str(p.props[2])
        types = [property_value_type(kind, v) for v in p.props[3:]]
        vals = [v if t == "S" else int(v) if t in "LIY" else float(v) for v, t in zip(p.props[3:], types)]
        if kind == "object":                          # a reference by connection in FBX 7: nothing to carry
            continue
        out.children.append(Node("P", [name, kind, _LABELS.get(kind, ""), flags] + vals, "SSSS" + "".join(types)))
    return out


def _array(o: Node) -> Node:
    """An element whose values are an array, as an FBX 7 array (6.x writes arrays as plain value lists)."""
    if o.types[:1] in ("f", "d", "i", "l"):
        return o
    vals = np.array([float(v) for v in o.props], dtype=np.float64)
    if o.name in _INT_ELEMENTS:
        vals = vals.astype(np.int64)
        props, t = [vals.astype(np.int32)], "i"
    else:
        props, t = _typed_array(o.name, vals)
    return Node(o.name, props, t)


def _copy(o: Node) -> Node:
    """A child element carried over: arrays as arrays, layer elements' children likewise."""
    if o.name in _ARRAY_ELEMENTS:
        return _array(o)
    return Node(o.name, list(o.props), o.types, [_copy(c) for c in o.children])


def _model(o, name, kind, mid, objs, conns, ids, geometry_of, key) -> None:
    mtype = "LimbNode" if kind in _BONES else ("Null" if kind in ("", "Marker", "Skeleton") else kind)
    kids = [_scalar("Version", 232), _properties(o), _scalar("MultiLayer", 0), _scalar("MultiTake", 0),
            Node("Shading", [ord("T")], "C"), _string("Culling", "CullingOff")]
    objs.children.append(Node("Model", [mid, name + CLASS_SEP + "Model", mtype], "LSS", kids))
    if mtype == "Mesh":
        gid = ids.new()
        geometry_of[key] = gid
        body = [_copy(c) for c in o.children if c.name in _ARRAY_ELEMENTS or c.name.startswith("Layer")
                or c.name == "GeometryVersion"]
        objs.children.append(Node("Geometry", [gid, name + CLASS_SEP + "Geometry", "Mesh"], "LSS",
                                  [Node("Properties70")] + body))
        conns.children.append(Node("C", ["OO", gid, mid], "SLL"))
    elif mtype in ("LimbNode", "Null"):
        aid = ids.new()
        attr = [Node("Properties70"), _string("TypeFlags", "Skeleton" if mtype == "LimbNode" else "Null")]
        objs.children.append(Node("NodeAttribute", [aid, name + CLASS_SEP + "NodeAttribute", mtype], "LSS", attr))
        conns.children.append(Node("C", ["OO", aid, mid], "SLL"))


def _deformer(o: Node, name: str, kind: str, did: int) -> Node:
    if kind == "Skin":
        return Node("Deformer", [did, name + CLASS_SEP + "Deformer", "Skin"], "LSS",
                    [_scalar("Version", 101), _scalar("Link_DeformAcuracy", 50.0)])
    body = [_scalar("Version", 100), Node("UserData", ["", ""], "SS")]
    body += [_array(o.find(k)) for k in ("Indexes", "Weights", "Transform", "TransformLink") if o.find(k)]
    return Node("Deformer", [did, name + CLASS_SEP + "SubDeformer", "Cluster"], "LSS", body)


def _pose(o: Node, name: str, pid: int, ids: _Ids) -> Node:
    nodes = []
    for pn in o.all("PoseNode"):
        ref, mat = pn.find("Node"), pn.find("Matrix")
        if ref and mat and ref.props:
            nodes.append(Node("PoseNode", [], "", [Node("Node", [ids.of(_key(ref.props[0]))], "L"), _array(mat)]))
    return Node("Pose", [pid, name + CLASS_SEP + "Pose", "BindPose"], "LSS",
                [_string("Type", "BindPose"), _scalar("Version", 100), _scalar("NbPoseNodes", len(nodes))] + nodes)


def _frame_rate(settings: Node, version5: Node | None) -> Node:
    """GlobalSettings with a frame rate: files that do not set TimeMode there (Blender 2.7x's FBX 6 exporter) give
    it in Version5 > Settings > FrameRate, carried as a custom rate (else the importer assumes its own)."""
    props = settings.find("Properties70")
    if any(p.props and p.props[0] == "TimeMode" for p in props.children):
        return settings
    s5 = version5.find("Settings") if version5 else None
    rate = s5.find("FrameRate") if s5 else None
    try:
        fps = float(rate.props[0]) if rate and rate.props else 0.0
    except ValueError:
        fps = 0.0
    if fps > 0:
        props.children += [Node("P", ["TimeMode", "enum", "", "", 14], "SSSSI"),
                           Node("P", ["CustomFrameRate", "double", "Number", "", fps], "SSSSD")]
    return settings


# --------------------------------------------------------------------------------------- animation

def _takes(takes: Node | None, kept: set[str], ids: _Ids, objs: Node, conns: Node, path: str) -> int:
    """Each take with keys as an AnimationStack with one layer; returns how many were written."""
    count = 0
    for take in (takes.all("Take") if takes else []):
        tname = str(take.props[0]) if take.props else f"Take {count + 1}"
        curves = []                                  # (model key, channel letter, {axis: (times, values)})
        for m in take.all("Model"):
            key = _key(m.props[0]) if m.props else ""
            if key not in kept:
                continue
            tr = next((c for c in m.all("Channel") if c.props and str(c.props[0]) == "Transform"), None)
            for ch in (tr.all("Channel") if tr else []):
                letter = str(ch.props[0]) if ch.props else ""
                if letter not in _CHANNELS:
                    continue
                axes = {}
                for ax in ch.all("Channel"):
                    a = str(ax.props[0]) if ax.props else ""
                    keys = _keys(ax, f"{tname}/{split_name(key)[1]}/{letter}{a}", path)
                    if a in ("X", "Y", "Z") and keys is not None:
                        axes[a] = keys
                if axes:
                    curves.append((key, letter, axes, ch))
        if not curves:
            continue
        times = np.concatenate([t for _, _, axes, _ in curves for t, _ in axes.values()])
        sid, lid = ids.new(), ids.new()
        start, stop = int(times.min()), int(times.max())
        objs.children.append(Node("AnimationStack", [sid, tname + CLASS_SEP + "AnimStack", ""], "LSS", [
            Node("Properties70", [], "", [
                Node("P", ["LocalStart", "KTime", "Time", "", start], "SSSSL"),
                Node("P", ["LocalStop", "KTime", "Time", "", stop], "SSSSL"),
                Node("P", ["ReferenceStart", "KTime", "Time", "", start], "SSSSL"),
                Node("P", ["ReferenceStop", "KTime", "Time", "", stop], "SSSSL")])]))
        objs.children.append(Node("AnimationLayer", [lid, "BaseLayer" + CLASS_SEP + "AnimLayer", ""], "LSS"))
        conns.children.append(Node("C", ["OO", lid, sid], "SLL"))
        for key, letter, axes, ch in curves:
            nid = ids.new()
            defaults = [_default(ch, a) for a in "XYZ"]
            objs.children.append(Node("AnimationCurveNode", [nid, letter + CLASS_SEP + "AnimCurveNode", ""], "LSS", [
                Node("Properties70", [], "", [Node("P", [f"d|{a}", "Number", "", "A", d], "SSSSD")
                                              for a, d in zip("XYZ", defaults)])]))
            conns.children.append(Node("C", ["OO", nid, lid], "SLL"))
            conns.children.append(Node("C", ["OP", nid, ids.of(key), _CHANNELS[letter]], "SLLS"))
            for a, (t, v) in axes.items():
                cid = ids.new()
                n = len(t)
                objs.children.append(Node("AnimationCurve", [cid, CLASS_SEP + "AnimCurve", ""], "LSS", [
                    Node("Default", [float(v[0])], "D"), Node("KeyVer", [4008], "I"),
                    Node("KeyTime", [t.astype(np.int64)], "l"), Node("KeyValueFloat", [v.astype(np.float32)], "f"),
                    Node("KeyAttrFlags", [np.array([_LINEAR], np.int32)], "i"),
                    Node("KeyAttrDataFloat", [np.zeros(4, np.float32)], "f"),
                    Node("KeyAttrRefCount", [np.array([n], np.int32)], "i")]))
                conns.children.append(Node("C", ["OP", cid, nid, f"d|{a}"], "SLLS"))
        count += 1
    return count


def _default(ch: Node, axis: str) -> float:
    for ax in ch.all("Channel"):
        if ax.props and str(ax.props[0]) == axis and ax.find("Default") and ax.find("Default").props:
            return float(ax.find("Default").props[0])
    return 0.0


def _letter(v) -> str:
    """An interpolation letter of a 6.x key list: a bare word in ASCII, a char code in binary."""
    if isinstance(v, str):
        return v[:1]
    return chr(int(v)) if isinstance(v, (int, np.integer)) and 0 < int(v) < 128 else ""


def _keys(ax: Node, where: str, path: str) -> tuple[np.ndarray, np.ndarray] | None:
    """(times in KTime, values) of one 6.x curve; None when it has no keys. The list is time, value, mode
    ('C' constant, 'L' linear, 'U' cubic) and the mode's own parameters (read to skip them)."""
    knode, cnode = ax.find("Key"), ax.find("KeyCount")
    if knode is None or not knode.props:
        return None
    data = list(knode.props[0]) if knode.types[:1] in ("d", "l", "i", "f") else list(knode.props)
    n = int(cnode.props[0]) if cnode and cnode.props else None
    ver = int(ax.find("KeyVer").props[0]) if ax.find("KeyVer") and ax.find("KeyVer").props else 4005
    times, values = [], []
    i = 0

    def need(k):
        if i + k > len(data):
            raise InputError(f"FBX 6 take {where}: its key list ends in the middle of a key", path)

    while i < len(data) and (n is None or len(times) < n):
        need(3)
        try:
            times.append(int(data[i]))
            values.append(float(data[i + 1]))
        except (TypeError, ValueError):
            raise InputError(f"FBX 6 take {where}: key {len(times)} has no time and value", path) from None
        mode = _letter(data[i + 2])
        i += 3
        if mode == "U":
            need(1)
            slope = _letter(data[i])
            i += 1
            weights = 1
            if slope in ("s", "b"):
                need(2)
                i += 2
                weights = 0 if ver == 4003 else 1
            elif slope == "a":
                weights = 0 if ver <= 4004 else 1
            elif slope in ("p", "q"):
                need(2)
                i += 2
                weights = 1 if ver <= 4004 else 2
            elif slope == "t":
                need(3)
                i += 3
                weights = 0
            elif slope == "d":
                need(1)
                i += 1
            else:
                raise InputError(f"FBX 6 take {where}: unknown tangent mode {slope!r} at key {len(times) - 1}", path)
            for _ in range(weights):
                need(1)
                w = _letter(data[i])
                i += 1
                if w == "a":
                    need(2)
                    i += 2
                elif w in ("l", "r"):
                    need(1)
                    i += 1
                elif w not in ("n", "c"):
                    raise InputError(f"FBX 6 take {where}: unknown weight mode {w!r} at key {len(times) - 1}", path)
        elif mode == "C":
            if ver >= 4004:
                need(1)
                i += 1
        elif mode != "L":
            raise InputError(f"FBX 6 take {where}: unknown key mode {mode!r} at key {len(times) - 1}", path)
    if n is not None and len(times) != n:
        raise InputError(f"FBX 6 take {where}: KeyCount says {n} keys, the list holds {len(times)}", path)
    if not times:
        return None
    values = np.array(values, dtype=np.float64)
    if not np.isfinite(values).all():
        raise InputError(f"FBX 6 take {where}: key {int(np.argmin(np.isfinite(values)))} is not a number (NaN or "
                         f"infinity): the file is damaged; export it again", path)
    return np.array(times, dtype=np.int64), values
