"""glTF animations -> Clip, checked against an independent evaluation of the raw file.

The reference below shares no code with rig.motion.gltf_anim: it reads accessors with its own numpy view,
builds every node's 4x4 local matrix T @ R @ S, multiplies them down the node hierarchy, and
interpolates keys as the glTF 2.0 spec (Appendix C) says, with its own slerp in x,y,z,w order.
"""
from __future__ import annotations

import base64
import json
import struct

import numpy as np
import pygltflib
import pytest
from conftest import asset

from jiggle.rig.base.errors import InputError, JiggleWarning
from jiggle.rig.motion import quat
from jiggle.rig.motion.gltf_anim import read_gltf_animation
from jiggle.rig.motion.gltf_skeleton import describe_gltf, read_gltf_skeleton
from jiggle.rig.motion.mocap import load_clip

Y_UP_TO_Z_UP = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])  # (x, y, z) -> (x, -z, y)


# ------------------------------------------------------------------ independent reference
def _accessor(g: pygltflib.GLTF2, blob: bytes, i: int) -> np.ndarray:
    a = g.accessors[i]
    assert a.componentType == 5126 and a.sparse is None  # the shared assets store floats only
    n = {"SCALAR": 1, "VEC3": 3, "VEC4": 4, "MAT4": 16}[a.type]
    bv = g.bufferViews[a.bufferView]
    stride = bv.byteStride or 4 * n
    start = (bv.byteOffset or 0) + (a.byteOffset or 0)
    return np.array([np.frombuffer(blob, "<f4", n, start + k * stride) for k in range(a.count)], dtype=float)


def _slerp_xyzw(q0, q1, s):
    d = float(np.dot(q0, q1))
    if d < 0:
        q1, d = -q1, -d
    if d > 1 - 1e-12:
        q = (1 - s) * q0 + s * q1
    else:
        th = np.arccos(d)
        q = (np.sin((1 - s) * th) * q0 + np.sin(s * th) * q1) / np.sin(th)
    return q / np.linalg.norm(q)


def _rot_xyzw(q):
    x, y, z, w = q / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def _reference_world(path, times):
    """{node name: (N, 4, 4) glTF world matrices (Y-up)} at animation times (seconds)."""
    g = pygltflib.GLTF2().load(str(path))
    blob = g.binary_blob()
    anim = g.animations[0]
    chans = []
    for ch in anim.channels:
        s = anim.samplers[ch.sampler]
        assert s.interpolation == "LINEAR"
        chans.append((ch.target.node, ch.target.path, _accessor(g, blob, s.input)[:, 0], _accessor(g, blob, s.output)))
    parent = {c: i for i, n in enumerate(g.nodes) for c in (n.children or [])}
    out = {n.name: [] for n in g.nodes}
    for t in times:
        trs = {}
        for i, n in enumerate(g.nodes):
            trs[i] = {"translation": np.array(n.translation or [0, 0, 0], float),
                      "rotation": np.array(n.rotation or [0, 0, 0, 1], float),
                      "scale": np.array(n.scale or [1, 1, 1], float)}
        for node, kind, kt, kv in chans:
            if t <= kt[0]:
                v = kv[0]
            elif t >= kt[-1]:
                v = kv[-1]
            else:
                k = int(np.searchsorted(kt, t, side="right")) - 1
                s = (t - kt[k]) / (kt[k + 1] - kt[k])
                v = _slerp_xyzw(kv[k], kv[k + 1], s) if kind == "rotation" else (1 - s) * kv[k] + s * kv[k + 1]
            trs[node][kind] = v
        local = {}
        for i, n in enumerate(g.nodes):
            if n.matrix is not None:
                local[i] = np.array(n.matrix, float).reshape(4, 4).T
            else:
                m = np.eye(4)
                m[:3, :3] = _rot_xyzw(trs[i]["rotation"]) @ np.diag(trs[i]["scale"])
                m[:3, 3] = trs[i]["translation"]
                local[i] = m
        for i, n in enumerate(g.nodes):
            m, k = local[i], i
            while k in parent:
                k = parent[k]
                m = local[k] @ m
            out[n.name].append(m)
    return {k: np.array(v) for k, v in out.items()}


# ------------------------------------------------------------------ real assets
@pytest.mark.parametrize("name", ["CesiumMan", "RiggedFigure"])
@pytest.mark.parametrize("fps", [None, 37.0])  # key rate/default, and frames falling between keys
def test_world_positions_match_independent_evaluation(name, fps):
    path = asset(f"characters/{name}.glb")
    clip = read_gltf_animation(path, fps=fps)
    assert clip.num_joints == 19
    frames = np.unique(np.linspace(0, clip.num_frames - 1, 7).round().astype(int))
    t_anim = clip.meta["start_time"] + clip.times[frames]
    ref = _reference_world(path, t_anim)
    wr, wp = clip.world()
    for j, n in enumerate(clip.joint_names):
        m = ref[n]
        pos = m[:, :3, 3] @ Y_UP_TO_Z_UP.T
        np.testing.assert_allclose(wp[frames, j], pos, atol=1e-6, err_msg=f"{name} joint {n}")
        # Scales in these files are 1 within float32 noise, so the normalised frame is the rotation.
        lin = Y_UP_TO_Z_UP @ m[:, :3, :3]
        lin = lin / np.linalg.norm(lin, axis=1, keepdims=True)
        np.testing.assert_allclose(quat.to_matrix(wr[frames, j]), lin, atol=1e-5)


def test_cesiumman_facts():
    clip = read_gltf_animation(asset("characters/CesiumMan.glb"))
    # 48 keys every 1/24 s from 1/24 to 2.0 s: frames land on keys.
    assert clip.fps == 24.0 and clip.num_frames == 48
    assert clip.meta["start_time"] == pytest.approx(1 / 24, abs=1e-6)
    assert clip.joint_names[0] == "Skeleton_torso_joint_1" and clip.parents[0] == -1
    # Z-up: the hips sit about 0.68 m above the feet.
    _, wp = clip.world()
    assert 0.6 < wp[:, 0, 2].min() and wp[:, 0, 2].max() < 0.75
    assert np.all(wp[..., 2] > -0.01)
    fig = read_gltf_animation(asset("characters/RiggedFigure.glb"))
    assert fig.fps == 30.0 and fig.meta["fps_rule"].startswith("default")  # two keys 1.25 s apart
    assert load_clip(asset("characters/RiggedFigure.glb")).num_frames == fig.num_frames


def test_describe_and_skeleton_of_cesiumman():
    p = asset("characters/CesiumMan.glb")
    d = describe_gltf(p)
    assert (d["vertices"], d["faces"], d["joints"]) == (3273, 4672, 19)
    assert d["animations"] == [{"name": "animation0", "duration_s": 2.0, "channels": 57}]
    assert d["height_m"] == pytest.approx(1.51, abs=0.01)
    sk = read_gltf_skeleton(p)
    assert sk.joint_names == tuple(d["joint_names"])
    # The bind pose FK of its one-frame clip reproduces the bind world positions.
    clip = sk.to_clip()
    _, pos = clip.rest_world()
    np.testing.assert_allclose(pos, sk.bind_positions, atol=1e-9)
    # CesiumMan is bound in its rest pose: the inverse bind matrices agree with the node TRS.
    _, rest = clip.world(sk.rest_rotations[None], sk.rest_translations[None])
    np.testing.assert_allclose(rest[0], sk.bind_positions, atol=1e-5)
    with pytest.raises(ValueError):
        sk.bind_world[0, 0, 0] = 2.0


# ------------------------------------------------------------------ tiny files built here
def _f32(a):
    return np.asarray(a, np.float32).tobytes()


def _tiny(layout: str = "plain") -> tuple[pygltflib.GLTF2, bytes]:
    """A 3-node chain Armature (scale 2) > hip > knee > foot with two animations.

    'step': hip translation STEP at t = 0, 1, 2 with x = 0, 1, 2.
    'armature': the Armature (above the skin's joints) moves 1 unit up (+Y) in 1 s, LINEAR.
    'cubic': hip translation CUBICSPLINE t = 0, 1: x from 0 to 1, out-tangent 2 at the first key,
             knee rotation CUBICSPLINE about +Z, t = 0, 2: identity to 90 degrees, out-tangent
             (0, 0, 0.3, 0) at the first key, in-tangent (0, 0, 0.1, 0) at the second.
    layout 'interleaved': the knee's rotation keys are normalized SHORTs, interleaved with the hip's
    translation floats in one strided bufferView.
    """
    s45 = np.sqrt(0.5)
    chunks: list[bytes] = []
    views, accs = [], []

    def add(data: bytes, ctype, typ, count, stride=None, offset=0, view=None, normalized=False, minmax=None):
        if view is None:
            off = sum(len(c) for c in chunks)
            chunks.append(data + b"\0" * (-len(data) % 4))
            views.append(pygltflib.BufferView(buffer=0, byteOffset=off, byteLength=len(data), byteStride=stride))
            view = len(views) - 1
        kw = {} if minmax is None else {"min": [minmax[0]], "max": [minmax[1]]}
        accs.append(pygltflib.Accessor(bufferView=view, byteOffset=offset, componentType=ctype, type=typ,
                                       count=count, normalized=normalized, **kw))
        return len(accs) - 1

    F, S = pygltflib.FLOAT, pygltflib.SHORT
    t_step = add(_f32([0, 1, 2]), F, "SCALAR", 3, minmax=(0, 2))
    v_step = add(_f32([[0, 0, 0], [1, 0, 0], [2, 0, 0]]), F, "VEC3", 3)
    t_c1 = add(_f32([0, 1]), F, "SCALAR", 2, minmax=(0, 1))
    t_c2 = add(_f32([0, 2]), F, "SCALAR", 2, minmax=(0, 2))
    v_arm = add(_f32([[0, 0, 0], [0, 1, 0]]), F, "VEC3", 2)
    # CUBICSPLINE output per key: in-tangent, value, out-tangent.
    hip_cubic = [[0, 0, 0], [0, 0, 0], [2, 0, 0], [0, 0, 0], [1, 0, 0], [0, 0, 0]]
    knee_cubic = [[0, 0, 0, 0], [0, 0, 0, 1], [0, 0, 0.3, 0], [0, 0, 0.1, 0], [0, 0, s45, s45], [0, 0, 0, 0]]
    if layout == "plain":
        v_hip = add(_f32(hip_cubic), F, "VEC3", 6)
        v_knee = add(_f32(knee_cubic), F, "VEC4", 6)
    else:
        rows = b"".join(np.round(np.array(r) * 32767).astype("<i2").tobytes() + _f32(h)
                        for r, h in zip(knee_cubic, hip_cubic))  # 8 + 12 = 20 bytes per element
        v_knee = add(rows, S, "VEC4", 6, stride=20, normalized=True)
        v_hip = add(b"", F, "VEC3", 6, offset=8, view=accs[v_knee].bufferView)
    blob = b"".join(chunks)
    g = pygltflib.GLTF2(
        asset=pygltflib.Asset(version="2.0"), scene=0, scenes=[pygltflib.Scene(nodes=[0])],
        nodes=[pygltflib.Node(name="Armature", children=[1], scale=[2, 2, 2]),
               pygltflib.Node(name="hip", children=[2]),
               pygltflib.Node(name="knee", children=[3], translation=[0, -1, 0]),
               pygltflib.Node(name="foot", translation=[0, 1, 0])],
        skins=[pygltflib.Skin(joints=[1, 2, 3])],
        animations=[
            pygltflib.Animation(name="step", samplers=[pygltflib.AnimationSampler(input=t_step, output=v_step,
                                                                                  interpolation="STEP")],
                                channels=[pygltflib.AnimationChannel(
                                    sampler=0, target=pygltflib.AnimationChannelTarget(node=1, path="translation"))]),
            pygltflib.Animation(name="cubic", samplers=[
                pygltflib.AnimationSampler(input=t_c1, output=v_hip, interpolation="CUBICSPLINE"),
                pygltflib.AnimationSampler(input=t_c2, output=v_knee, interpolation="CUBICSPLINE")],
                channels=[pygltflib.AnimationChannel(sampler=0, target=pygltflib.AnimationChannelTarget(
                    node=1, path="translation")),
                    pygltflib.AnimationChannel(sampler=1, target=pygltflib.AnimationChannelTarget(
                        node=2, path="rotation"))]),
            pygltflib.Animation(name="armature", samplers=[pygltflib.AnimationSampler(input=t_c1, output=v_arm)],
                                channels=[pygltflib.AnimationChannel(
                                    sampler=0, target=pygltflib.AnimationChannelTarget(node=0, path="translation"))])],
        accessors=accs, bufferViews=views, buffers=[pygltflib.Buffer(byteLength=len(blob))])
    return g, blob


def _write(tmp_path, kind: str, layout: str = "plain"):
    g, blob = _tiny(layout)
    if kind == "glb":
        g.set_binary_blob(blob)
        p = tmp_path / "tiny.glb"
        g.save_binary(str(p))
    elif kind == "datauri":
        g.buffers[0].uri = "data:application/octet-stream;base64," + base64.b64encode(blob).decode()
        p = tmp_path / "tiny.gltf"
        p.write_text(g.to_json())
    else:
        (tmp_path / "tiny data.bin").write_bytes(blob)
        g.buffers[0].uri = "tiny%20data.bin"
        p = tmp_path / "tiny.gltf"
        p.write_text(g.to_json())
    return p


@pytest.mark.parametrize("kind", ["glb", "datauri", "external"])
def test_step_interpolation_by_hand(tmp_path, kind):
    clip = read_gltf_animation(_write(tmp_path, kind), "step", fps=4)
    assert clip.joint_names == ("hip", "knee", "foot") and list(clip.parents) == [-1, 0, 1]
    assert clip.num_frames == 9  # 0 .. 2 s at 4 fps
    _, wp = clip.world()
    # STEP holds the key at or before t; the Armature's scale 2 doubles the hip's x.
    expect_x = 2.0 * np.array([0, 0, 0, 0, 1, 1, 1, 1, 2])
    np.testing.assert_allclose(wp[:, 0, 0], expect_x, atol=1e-12)
    # Knee 1 unit below the hip in Y-up = -2 m in z after the scale; the foot back up at the hip.
    np.testing.assert_allclose(wp[:, 1, 2], -2.0, atol=1e-12)
    np.testing.assert_allclose(wp[:, 2], wp[:, 0], atol=1e-12)
    # Scale folded into the children's translations: the knee's offset, in the hip's own frame (the
    # file's axes: 1 unit down its -Y), is 2 m long.
    np.testing.assert_allclose(clip.offsets[1], [0, -2, 0], atol=1e-12)


@pytest.mark.parametrize("layout", ["plain", "interleaved"])
def test_cubicspline_by_hand(tmp_path, layout):
    clip = read_gltf_animation(_write(tmp_path, "glb", layout), animation=1, fps=4)
    assert clip.meta["animation"] == "cubic" and clip.num_frames == 9
    _, wp = clip.world()
    # Hip x at s = t / 1 s: h00*0 + h10*dt*2 + h01*1 + h11*dt*0 with dt = 1.
    #   t = 0.25: h10 = 0.140625, h01 = 0.15625  -> 2*0.140625 + 0.15625 = 0.4375
    #   t = 0.5:  h10 = 0.125,    h01 = 0.5      -> 0.75;    t = 0.75: h10 = 0.046875, h01 = 0.84375 -> 0.9375
    #   t >= 1: the last key, 1.  All doubled by the Armature's scale.
    hip = np.array([0, 0.4375, 0.75, 0.9375, 1, 1, 1, 1, 1]) * 2
    tol = 1e-12 if layout == "plain" else 1e-6
    np.testing.assert_allclose(wp[:, 0, 0], hip, atol=tol)
    # Knee rotation at t = 1 s (s = 0.5, dt = 2): 0.5*(0,0,0,1) + 0.125*2*(0,0,.3,0) + 0.5*(0,0,.7071,.7071)
    #   - 0.125*2*(0,0,.1,0) = (0, 0, 0.403553, 0.853553) -> angle 2*atan2(0.403553, 0.853553) = 50.60884 deg.
    # The foot, 1 unit along the knee's +Y (2 m after scale), turns about +Z(glTF) = -Y(Z-up):
    #   foot - knee = 2 * (-sin a, 0, cos a) in Z-up.
    a = np.radians(50.60884)
    d = wp[4, 2] - wp[4, 1]
    np.testing.assert_allclose(d, 2 * np.array([-np.sin(a), 0, np.cos(a)]), atol=2e-6 if layout == "plain" else 2e-4)
    np.testing.assert_allclose(wp[8, 2] - wp[8, 1], [-2, 0, 0], atol=1e-12 if layout == "plain" else 1e-4)
    np.testing.assert_allclose(wp[0, 2] - wp[0, 1], [0, 0, 2], atol=1e-12 if layout == "plain" else 1e-4)


def test_animated_node_above_the_skeleton_moves_the_root(tmp_path):
    clip = read_gltf_animation(_write(tmp_path, "glb"), "armature", fps=4)
    _, wp = clip.world()
    # The Armature's own translation is not scaled by its scale; +Y (glTF up) is +Z.
    np.testing.assert_allclose(wp[:, 0], [[0, 0, z] for z in (0, 0.25, 0.5, 0.75, 1.0)], atol=1e-12)
    np.testing.assert_allclose(wp[:, 1, 2], wp[:, 0, 2] - 2.0, atol=1e-12)
    # Without the skin, the joints are the animated nodes and what joins them: only the Armature.
    alone = read_gltf_animation(_write(tmp_path, "datauri"), "cubic", skin=None)
    assert alone.joint_names == ("hip", "knee")
    assert read_gltf_animation(_write(tmp_path, "glb"), "armature", skin=None).joint_names == ("Armature",)


# ------------------------------------------------------------------ errors
def test_errors(tmp_path):
    p = _write(tmp_path, "glb")
    with pytest.raises(InputError, match=r"no animation named 'walk'.*0: 'step', 1: 'cubic', 2: 'armature'") as e:
        read_gltf_animation(p, "walk")
    assert e.value.path == str(p) and e.value.field == "animation"
    with pytest.raises(InputError, match=r"index 5 is out of range.*2: 'armature'"):
        read_gltf_animation(p, 5)
    assert read_gltf_animation(p, "1").meta["animation"] == "cubic"  # an index typed as text
    with pytest.raises(InputError, match=r"index 7 is out of range"):
        read_gltf_animation(p, "7")
    with pytest.raises(InputError, match="fps must be a positive number"):
        read_gltf_animation(p, fps=0)
    with pytest.raises(InputError, match="not found"):
        read_gltf_animation(tmp_path / "absent.glb")
    bad = tmp_path / "bad.glb"
    bad.write_text("solid cube\nendsolid\n")
    with pytest.raises(InputError, match="not a glTF file"):
        read_gltf_animation(bad)
    js = tmp_path / "bad.gltf"
    js.write_text(json.dumps({"nodes": []}))
    with pytest.raises(InputError, match="asset"):
        read_gltf_animation(js)
    g, blob = _tiny()
    g.animations = []
    g.set_binary_blob(blob)
    still = tmp_path / "still.glb"
    g.save_binary(str(still))
    with pytest.raises(InputError, match=r"no animation \(it holds .*4 node\(s\).*1 skin") as e:
        read_gltf_animation(still)
    assert e.value.field == "animations"
    # A truncated GLB names its chunk problem rather than failing inside numpy.
    data = p.read_bytes()
    cut = tmp_path / "cut.glb"
    cut.write_bytes(data[:len(data) - 40])
    with pytest.raises(InputError):
        read_gltf_animation(cut)
    # Output count disagreeing with the key count names the sampler.
    g, blob = _tiny()
    g.accessors[g.animations[0].samplers[0].output].count = 2
    g.set_binary_blob(blob)
    odd = tmp_path / "odd.glb"
    g.save_binary(str(odd))
    with pytest.raises(InputError, match=r"expected 3 values") as e:
        read_gltf_animation(odd, "step")
    assert e.value.field == "animations[0].samplers[0].output"


def test_glb_header_is_checked(tmp_path):
    p = tmp_path / "v1.glb"
    p.write_bytes(struct.pack("<4sII", b"glTF", 1, 20) + b"\0" * 8)
    with pytest.raises(InputError, match="version 1"):
        read_gltf_animation(p)


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("uniform", [True, False])
def test_scaled_chain_positions_are_exact(tmp_path, seed, uniform):
    """Random 5-node chain with scale on every node, two LINEAR keys: at the key times the clip's
    joint positions equal the product of the glTF matrices, for uniform and non-uniform scale; the
    joint rotations equal the normalised matrix frames when the scale is uniform. For a skin, an
    animated uniform scale is read with a warning (rigid joints cannot scale the skin) and a
    non-uniform one is refused naming the channel; without a skin (mocap) it is read."""
    rng = np.random.default_rng(seed)
    n, keys = 5, 2
    trs = []
    for _ in range(n):
        t = rng.uniform(-0.5, 0.5, (keys, 3))
        q = rng.normal(size=(keys, 4))
        q /= np.linalg.norm(q, axis=1, keepdims=True)
        sc = rng.uniform(0.5, 2.0, (keys, 1)) * np.ones((1, 3)) if uniform else rng.uniform(0.5, 2.0, (keys, 3))
        trs.append((t, q, sc))
    times = _f32([0.0, 0.5])
    blob = times + b"".join(_f32(a) for tr in trs for a in tr)
    F = pygltflib.FLOAT
    views = [pygltflib.BufferView(buffer=0, byteOffset=0, byteLength=8)]
    accs = [pygltflib.Accessor(bufferView=0, componentType=F, type="SCALAR", count=2, min=[0], max=[0.5])]
    samplers, channels, off = [], [], 8
    for i, tr in enumerate(trs):
        for a, path in zip(tr, ("translation", "rotation", "scale")):
            views.append(pygltflib.BufferView(buffer=0, byteOffset=off, byteLength=a.size * 4))
            accs.append(pygltflib.Accessor(bufferView=len(views) - 1, componentType=F,
                                           type="VEC4" if path == "rotation" else "VEC3", count=2))
            off += a.size * 4
            samplers.append(pygltflib.AnimationSampler(input=0, output=len(accs) - 1))
            channels.append(pygltflib.AnimationChannel(sampler=len(samplers) - 1,
                                                       target=pygltflib.AnimationChannelTarget(node=i, path=path)))
    g = pygltflib.GLTF2(asset=pygltflib.Asset(version="2.0"), scenes=[pygltflib.Scene(nodes=[0])],
                        nodes=[pygltflib.Node(name=f"j{i}", children=[i + 1] if i + 1 < n else []) for i in range(n)],
                        skins=[pygltflib.Skin(joints=list(range(1, n)))],
                        animations=[pygltflib.Animation(samplers=samplers, channels=channels)],
                        accessors=accs, bufferViews=views, buffers=[pygltflib.Buffer(byteLength=len(blob))])
    g.set_binary_blob(blob)
    p = tmp_path / "chain.glb"
    g.save_binary(str(p))
    if uniform:
        with pytest.warns(JiggleWarning, match=r"scales 'j0' .*joints are rigid"):
            clip = read_gltf_animation(p, fps=2.0)  # frames at the two keys
        assert clip.joint_names == tuple(f"j{i}" for i in range(1, n)) and clip.num_frames == 2
        first = 1
    else:
        with pytest.raises(InputError, match=r"non-uniform scale \[.*\] at 0 s is not supported") as e:
            read_gltf_animation(p, fps=2.0)
        assert e.value.field.startswith('animations[0].channels[2] (node 0 "j0"')
        clip = read_gltf_animation(p, fps=2.0, skin=None)
        assert clip.joint_names == tuple(f"j{i}" for i in range(n))
        first = 0
    wr, wp = clip.world()
    for k in range(keys):
        m = np.eye(4)
        for i, (t, q, sc) in enumerate(trs):
            local = np.eye(4)
            tq = np.asarray(np.float32(q[k]), float)
            local[:3, :3] = _rot_xyzw(tq) @ np.diag(np.float32(sc[k]))
            local[:3, 3] = np.float32(t[k])
            m = m @ local
            if i < first:
                continue  # j0 is above the skin's joints: folded into the root
            np.testing.assert_allclose(wp[k, i - first], Y_UP_TO_Z_UP @ m[:3, 3], atol=1e-9)
            if uniform:
                lin = Y_UP_TO_Z_UP @ m[:3, :3]
                np.testing.assert_allclose(quat.to_matrix(wr[k, i - first]), lin / np.linalg.norm(lin[:, 0]),
                                           atol=1e-9)
