"""An independent glTF 2.0 skinning evaluation for the tests, straight from the spec and pygltflib.

No jiggle code: accessors are read from the GLB's binary chunk, the animation is sampled with LINEAR
interpolation (lerp, slerp for rotations), node global transforms are multiplied down from the
scene roots, and each vertex is

    v' = sum_i w_i * (global(joint_i) @ inverseBindMatrix_i) @ v          (glTF 2.0, section 3.7.3)

in the file's Y-up world; the result is turned to Z-up with (x, y, z) -> (x, -z, y).

`write_figure` builds a small skinned figure as a centimetre export from Blender or Maya would: an
armature node scaling by 0.01 and turning -90 degrees about X (its content is Z-up centimetres), a
uniform scale on one joint, a node in the joint tree that is not a skin joint, a skin joint that no
vertex weights, two skinned meshes (one with two primitives, one on a node with its own transform,
which the spec ignores) and a LINEAR animation.
"""
from __future__ import annotations

import numpy as np
import pygltflib

_DTYPE = {5121: np.uint8, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}
_N = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}


def _accessor(g: pygltflib.GLTF2, blob: bytes, i: int) -> np.ndarray:
    a = g.accessors[i]
    v = g.bufferViews[a.bufferView]
    dt = np.dtype(_DTYPE[a.componentType])
    n = _N[a.type]
    stride = v.byteStride or dt.itemsize * n
    start = (v.byteOffset or 0) + (a.byteOffset or 0)
    out = np.ndarray((a.count, n), dt, blob, start, (stride, dt.itemsize)).astype(np.float64)
    if a.normalized:
        out /= np.iinfo(dt).max
    if a.sparse is not None:
        raise NotImplementedError("sparse accessors")
    return out


def _quat_matrix(q):  # x, y, z, w as glTF stores it
    x, y, z, w = q / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def _slerp(a, b, u):
    d = float(np.dot(a, b))
    if d < 0:
        b, d = -b, -d
    if d > 0.9995:
        r = a + u * (b - a)
        return r / np.linalg.norm(r)
    th = np.arccos(d)
    return (np.sin((1 - u) * th) * a + np.sin(u * th) * b) / np.sin(th)


def _sample(times, values, t, rotation):
    if t <= times[0]:
        return values[0]
    if t >= times[-1]:
        return values[-1]
    k = int(np.searchsorted(times, t, side="right")) - 1
    u = (t - times[k]) / (times[k + 1] - times[k])
    return _slerp(values[k], values[k + 1], u) if rotation else values[k] + u * (values[k + 1] - values[k])


def skinned_vertices(path, t: float | None, animation: int = 0) -> np.ndarray:
    """(V, 3) Z-up positions of every skinned primitive (in file order) at animation time t seconds
    (t None: the rest pose, the nodes' own transforms)."""
    g = pygltflib.GLTF2().load(str(path))
    blob = g.binary_blob()
    trs = []
    for nd in g.nodes:
        trs.append({"translation": np.array(nd.translation or [0, 0, 0], float),
                    "rotation": np.array(nd.rotation or [0, 0, 0, 1], float),
                    "scale": np.array(nd.scale or [1, 1, 1], float),
                    "matrix": None if nd.matrix is None else np.array(nd.matrix, float).reshape(4, 4).T})
    an = g.animations[animation] if t is not None else None
    for ch in an.channels if an is not None else []:
        s = an.samplers[ch.sampler]
        assert s.interpolation in (None, "LINEAR"), "the reference only does LINEAR"
        kt = _accessor(g, blob, s.input)[:, 0]
        kv = _accessor(g, blob, s.output)
        trs[ch.target.node][ch.target.path] = _sample(kt, kv, t, ch.target.path == "rotation")

    def local(i):
        d = trs[i]
        if d["matrix"] is not None:
            return d["matrix"]
        m = np.eye(4)
        m[:3, :3] = _quat_matrix(d["rotation"]) * d["scale"]
        m[:3, 3] = d["translation"]
        return m

    glob = {}

    def visit(i, parent):
        glob[i] = parent @ local(i)
        for c in g.nodes[i].children or []:
            visit(c, glob[i])

    for r in g.scenes[g.scene or 0].nodes:
        visit(r, np.eye(4))
    out = []
    for nd in g.nodes:
        if nd.mesh is None or nd.skin is None:
            continue
        sk = g.skins[nd.skin]
        ibm = _accessor(g, blob, sk.inverseBindMatrices).reshape(-1, 4, 4).transpose(0, 2, 1)
        jm = np.stack([glob[j] @ ibm[k] for k, j in enumerate(sk.joints)])
        for p in g.meshes[nd.mesh].primitives:
            v = _accessor(g, blob, p.attributes.POSITION)
            jj = _accessor(g, blob, p.attributes.JOINTS_0).astype(int)
            ww = _accessor(g, blob, p.attributes.WEIGHTS_0)
            vh = np.c_[v, np.ones(len(v))]
            m = np.einsum("vk,vkij->vij", ww, jm[jj])
            out.append(np.einsum("vij,vj->vi", m, vh)[:, :3])
    y = np.concatenate(out)
    return np.c_[y[:, 0], -y[:, 2], y[:, 1]]


# ---------------------------------------------------------------------------------- a synthetic figure
def _q_xyzw(axis, deg):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    h = np.radians(deg) / 2
    return [*(np.sin(h) * axis), np.cos(h)]


def _trs(node: dict) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = _quat_matrix(np.asarray(node.get("rotation", [0, 0, 0, 1]), float)) * np.asarray(
        node.get("scale", [1, 1, 1]), float)
    m[:3, 3] = node.get("translation", [0, 0, 0])
    return m


def _tube(z0, z1, radius, x=0.0, rings=6, sides=8):
    """Vertices (rings * sides, 3) and triangles of an open tube along z, centimetres."""
    zs = np.linspace(z0, z1, rings)
    a = np.linspace(0, 2 * np.pi, sides, endpoint=False)
    v = np.array([[x + radius * np.cos(t), radius * np.sin(t), z] for z in zs for t in a])
    f = []
    for r in range(rings - 1):
        for k in range(sides):
            i, j = r * sides + k, r * sides + (k + 1) % sides
            f += [[i, j, j + sides], [i, j + sides, i + sides]]
    return v, np.array(f)


def _weights(v, anchors):
    """Two joints per vertex blended linearly between anchor heights [(z, joint), ...] (cm)."""
    zs = np.array([a[0] for a in anchors], float)
    js = [a[1] for a in anchors]
    k = np.clip(np.searchsorted(zs, v[:, 2]) - 1, 0, len(zs) - 2)
    u = np.clip((v[:, 2] - zs[k]) / (zs[k + 1] - zs[k]), 0, 1)
    joints = np.zeros((len(v), 4), np.uint8)
    weights = np.zeros((len(v), 4), np.float32)
    joints[:, 0], joints[:, 1] = np.array(js)[k], np.array(js)[k + 1]
    weights[:, 0], weights[:, 1] = 1 - u, u
    return joints, weights


FIGURE_JOINTS = ("hips", "spine", "chest_offset", "neck", "head_end", "leg_L", "knee_L")
"""Joint tree of `write_figure`, parents first; chest_offset is not a skin joint, head_end weighs
nothing."""


def write_figure(path, armature_scale=(0.01, 0.01, 0.01), armature_turn_deg: float = -90.0,
                 spine_scale: float = 1.1, mesh_node_transform: bool = True, animate: bool = True,
                 joint_scale_override: dict | None = None, key_times=(0.0, 0.5, 1.0), prop: bool = False,
                 skin: bool = True) -> str:
    """Write the synthetic figure (module docstring) as a GLB at `path`; returns the path.

    armature_scale, armature_turn_deg : the Armature node's scale and rotation about X.
    spine_scale : uniform scale of the 'spine' joint (its children's offsets are scaled by it).
    mesh_node_transform : give the second skinned mesh's node a transform of its own (the spec
        ignores it: the skin must not move).
    joint_scale_override : {joint name: scale (3,)} set on those joints after the inverse bind matrices
        are computed without it (to build bad files).
    key_times : the animation's three key times (written as given, to build bad files).
    prop : add a scene root node "Prop" that the animation also moves (not part of the skeleton).
    skin : False writes the meshes without skin, joints or weights.
    """
    nodes = [
        {"name": "Armature", "children": [1, 8, 9], "rotation": _q_xyzw([1, 0, 0], armature_turn_deg),
         "scale": list(armature_scale)},
        {"name": "hips", "children": [2, 6], "translation": [0, 0, 90]},
        {"name": "spine", "children": [3], "translation": [0, 0, 25], "scale": [spine_scale] * 3},
        {"name": "chest_offset", "children": [4], "translation": [0, 0, 10]},
        {"name": "neck", "children": [5], "translation": [0, 0, 20]},
        {"name": "head_end", "translation": [0, 0, 25]},
        {"name": "leg_L", "children": [7], "translation": [10, 0, -5]},
        {"name": "knee_L", "translation": [0, 0, -42]},
        {"name": "Body", "mesh": 0, "skin": 0},
        {"name": "Cap", "mesh": 1, "skin": 0},
    ]
    if mesh_node_transform:
        nodes[9].update(translation=[300, 40, -20], rotation=_q_xyzw([0, 1, 1], 70), scale=[2, 2, 2])
    joints = [1, 2, 4, 5, 6, 7]  # chest_offset (3) is in the tree but not in the skin
    parent = {c: i for i, n in enumerate(nodes) for c in n.get("children", [])}

    def world(i):
        m = _trs(nodes[i])
        while i in parent:
            i = parent[i]
            m = _trs(nodes[i]) @ m
        return m

    # Mesh space = the armature's space (the Body node sits at the armature with no transform of its own).
    ibm = np.stack([np.linalg.inv(world(j)) @ world(0) for j in joints])
    for name, sc in (joint_scale_override or {}).items():
        nodes[[n["name"] for n in nodes].index(name)]["scale"] = list(sc)
    # Joint index in the skin: hips 0, spine 1, neck 2, head_end 3, leg_L 4, knee_L 5.
    ht = 115.0  # spine joint height in cm (hips at 90); the neck 30 cm * spine_scale above it
    neck_z = ht + 30 * spine_scale
    torso_v, torso_f = _tube(85, neck_z, 14)
    torso_j, torso_w = _weights(torso_v, [(85, 0), (ht, 1), (neck_z, 2)])
    leg_v, leg_f = _tube(3, 85, 6, x=10)
    leg_j, leg_w = _weights(leg_v, [(3, 5), (43, 5), (85, 4)])
    cap_v, cap_f = _tube(neck_z, 170, 9)
    cap_j, cap_w = _weights(cap_v, [(neck_z, 2), (170, 2)])
    blob = bytearray()
    views, accs = [], []

    def add(arr, ctype, typ, target=None, minmax=False):
        arr = np.ascontiguousarray(arr)
        off = len(blob)
        blob.extend(arr.tobytes() + b"\0" * (-arr.nbytes % 4))
        views.append(pygltflib.BufferView(buffer=0, byteOffset=off, byteLength=arr.nbytes, target=target))
        kw = {"min": arr.min(0).tolist(), "max": arr.max(0).tolist()} if minmax else {}
        accs.append(pygltflib.Accessor(bufferView=len(views) - 1, componentType=ctype, type=typ,
                                       count=len(arr), **kw))
        return len(accs) - 1

    F = pygltflib.FLOAT

    def prim(v, f, j, w):
        return pygltflib.Primitive(
            attributes=pygltflib.Attributes(POSITION=add(v.astype(np.float32), F, "VEC3", 34962, True),
                                            JOINTS_0=add(j, pygltflib.UNSIGNED_BYTE, "VEC4", 34962),
                                            WEIGHTS_0=add(w, F, "VEC4", 34962)),
            indices=add(f.astype(np.uint16).reshape(-1), pygltflib.UNSIGNED_SHORT, "SCALAR", 34963))

    meshes = [pygltflib.Mesh(name="BodyMesh", primitives=[prim(torso_v, torso_f, torso_j, torso_w),
                                                          prim(leg_v, leg_f, leg_j, leg_w)]),
              pygltflib.Mesh(name="CapMesh", primitives=[prim(cap_v, cap_f, cap_j, cap_w)])]
    skin_ = pygltflib.Skin(name="FigureSkin", joints=joints, skeleton=1,
                          inverseBindMatrices=add(ibm.transpose(0, 2, 1).reshape(-1, 16).astype(np.float32), F,
                                                  "MAT4"))
    animations = []
    if animate:
        times = np.array(key_times, np.float32)
        t_acc = add(times, F, "SCALAR")
        accs[t_acc].min, accs[t_acc].max = [float(np.nanmin(times))], [float(np.nanmax(times))]
        chans = [
            (1, "translation", [[0, 0, 90], [6, -4, 84], [12, 0, 90]]),
            (1, "rotation", [_q_xyzw([0, 0, 1], 0), _q_xyzw([0, 0, 1], 35), _q_xyzw([0, 1, 0], 20)]),
            (2, "rotation", [_q_xyzw([1, 0, 0], 0), _q_xyzw([1, 0, 0], 40), _q_xyzw([1, 1, 0], -30)]),
            (4, "rotation", [_q_xyzw([0, 1, 0], 0), _q_xyzw([0, 1, 0], -30), _q_xyzw([0, 1, 0], 25)]),
            (6, "rotation", [_q_xyzw([1, 0, 0], 0), _q_xyzw([1, 0, 0], -60), _q_xyzw([1, 0, 0], 45)]),
            (7, "rotation", [_q_xyzw([1, 0, 0], 0), _q_xyzw([1, 0, 0], 70), _q_xyzw([1, 0, 0], 20)]),
        ] + ([(10, "translation", [[0, 0, 0], [1, 0, 0], [2, 0, 0]])] if prop else [])
        samplers, channels = [], []
        for node, path_, vals in chans:
            typ = "VEC4" if path_ == "rotation" else "VEC3"
            samplers.append(pygltflib.AnimationSampler(input=t_acc, output=add(np.array(vals, np.float32), F, typ),
                                                       interpolation="LINEAR"))
            channels.append(pygltflib.AnimationChannel(sampler=len(samplers) - 1,
                                                       target=pygltflib.AnimationChannelTarget(node=node, path=path_)))
        animations = [pygltflib.Animation(name="wave", samplers=samplers, channels=channels)]
    roots = [0]
    if prop:
        nodes.append({"name": "Prop", "translation": [0, 0, 0]})
        roots.append(10)
    if not skin:
        for m in meshes:
            for pr in m.primitives:
                pr.attributes.JOINTS_0 = pr.attributes.WEIGHTS_0 = None
        for n in nodes:
            n.pop("skin", None)
    g = pygltflib.GLTF2(asset=pygltflib.Asset(version="2.0", generator="jiggle tests"), scene=0,
                        scenes=[pygltflib.Scene(nodes=roots)], nodes=[pygltflib.Node(**n) for n in nodes],
                        meshes=meshes, skins=[skin_] if skin else [], animations=animations, accessors=accs, bufferViews=views,
                        buffers=[pygltflib.Buffer(byteLength=len(blob))])
    g.set_binary_blob(bytes(blob))
    g.save_binary(str(path))
    return str(path)
