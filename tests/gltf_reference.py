"""An independent glTF 2.0 skinning evaluation for the tests, straight from the spec and pygltflib.

No jiggle code: accessors are read from the GLB's binary chunk, the animation is sampled with LINEAR
interpolation (lerp, slerp for rotations), node global transforms are multiplied down from the
scene roots, and each vertex is

    v' = sum_i w_i * (global(joint_i) @ inverseBindMatrix_i) @ v          (glTF 2.0, section 3.7.3)

in the file's Y-up world; the result is turned to Z-up with (x, y, z) -> (x, -z, y).
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


def skinned_vertices(path, t: float, animation: int = 0) -> np.ndarray:
    """(V, 3) Z-up positions of every skinned primitive (in file order) at animation time t seconds."""
    g = pygltflib.GLTF2().load(str(path))
    blob = g.binary_blob()
    trs = []
    for nd in g.nodes:
        trs.append({"translation": np.array(nd.translation or [0, 0, 0], float),
                    "rotation": np.array(nd.rotation or [0, 0, 0, 1], float),
                    "scale": np.array(nd.scale or [1, 1, 1], float),
                    "matrix": None if nd.matrix is None else np.array(nd.matrix, float).reshape(4, 4).T})
    an = g.animations[animation]
    for ch in an.channels:
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
