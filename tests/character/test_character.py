"""Skinned characters: glTF loading, posing from the MuJoCo driver against an independent spec
evaluation, meshes with automatic weights, and bad input."""
from __future__ import annotations

import warnings

import gltf_reference
import numpy as np
import pytest
import trimesh
from conftest import asset

from jiggle.rig.base.errors import InputError, JiggleWarning
from jiggle.rig.character.character import Character, bind_clip
from jiggle.rig.character.load import auto_weighted, load_character, load_skeleton
from jiggle.rig.motion.clip import transforms
from jiggle.rig.motion.gltf_anim import read_gltf_animation
from jiggle.rig.skin.skinning import pose_character
from jiggle.sim.drive.skeleton import Skeleton

CHARACTERS = ["CesiumMan", "RiggedFigure"]


def _driver_world(character: Character, clip, t: float) -> np.ndarray:
    """(J, 4, 4) joint world transforms at clip time t from the MuJoCo skeleton driver, in the
    character's joint order."""
    rot, pos = Skeleton(clip).world(np.array([t]))
    order = character.joint_order(clip.joint_names)
    return transforms(rot[0, order], pos[0, order])


# ------------------------------------------------------------------------------------ glTF
@pytest.mark.parametrize("name", CHARACTERS)
def test_gltf_character_fields(name):
    path = asset(f"characters/{name}.glb")
    with warnings.catch_warnings():
        warnings.simplefilter("error", JiggleWarning)  # the shared files need no repair
        c = load_character(path)
    V = c.num_vertices
    assert c.vertices.shape == (V, 3) and c.normals.shape == (V, 3) and c.faces.shape[1] == 3
    assert c.faces.min() == 0 and c.faces.max() < V
    assert c.joints.shape == c.weights.shape == (V, 4)
    np.testing.assert_allclose(c.weights.sum(1), 1.0, atol=1e-6)
    assert np.all(np.diff(c.weights, axis=1) <= 1e-7), "influences are sorted strongest first"
    assert c.joints.min() >= 0 and c.joints.max() < c.num_joints
    np.testing.assert_allclose(np.linalg.norm(c.normals, axis=1), 1.0, atol=1e-5)
    assert 1.0 < c.height < 2.0 and c.vertices[:, 2].min() > -0.05, "Z-up metres, standing on z = 0"
    assert not c.vertices.flags.writeable and not c.weights.flags.writeable
    assert c.meta["weights"] == "file"
    # vertices are never merged: the file's vertex count is kept
    import pygltflib
    g = pygltflib.GLTF2().load(str(path))
    assert V == sum(g.accessors[p.attributes.POSITION].count for m in g.meshes for p in m.primitives)
    if name == "CesiumMan":
        assert c.uvs is not None and c.uvs.shape == (V, 2)


@pytest.mark.parametrize("name", CHARACTERS)
def test_pose_from_mujoco_equals_gltf_spec(name):
    """Posed through the MuJoCo skeleton driver at t = 1.0 s of the file's own animation, the skin
    equals the spec's skinning (joint matrix = global transform x inverse bind matrix) within 1e-4 m."""
    path = asset(f"characters/{name}.glb")
    c = load_character(path)
    clip = read_gltf_animation(path)
    t = 1.0
    world = _driver_world(c, clip, t - clip.meta["start_time"])
    ours = pose_character(c, world)
    ref = gltf_reference.skinned_vertices(path, t)
    err = np.linalg.norm(ours - ref, axis=1).max()
    moved = np.linalg.norm(ref - c.vertices, axis=1).max()
    print(f"{name}: max |ours - spec| = {err:.2e} m at t = {t} s (the skin moved up to {moved:.3f} m)")
    assert moved > 0.05, "the test pose must differ from the bind pose"
    assert err < 1e-4
    dq = pose_character(c, world, method="dqs")
    assert np.linalg.norm(dq - ref, axis=1).max() < 0.05, "DQS stays near LBS on a mild pose"


def test_bind_pose_reproduces_rest_skin():
    c = load_character(asset("characters/CesiumMan.glb"))
    np.testing.assert_allclose(pose_character(c, c.bind_world), c.vertices, atol=1e-5)
    # the skeleton clip's rest pose is the bind pose
    r, p = c.skeleton.rest_world()
    np.testing.assert_allclose(p, c.bind_positions, atol=1e-9)


def test_joint_order_names_missing_joint():
    c = load_character(asset("characters/CesiumMan.glb"))
    with pytest.raises(InputError, match="retarget"):
        c.joint_order(c.joint_names[1:])


# ------------------------------------------------------------------------------------ meshes
def _two_bone_tube():
    """A closed tube along x (0..0.4 m) plus a separate small sphere near its end, and a 3-joint chain."""
    tube = trimesh.creation.cylinder(radius=0.05, height=0.4, sections=24)
    tube = trimesh.Trimesh(*trimesh.remesh.subdivide_to_size(tube.vertices, tube.faces, 0.03), process=False)
    tube.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0]))
    tube.apply_translation([0.2, 0, 1.0])
    ball = trimesh.creation.icosphere(subdivisions=2, radius=0.03)
    ball.apply_translation([0.45, 0.0, 1.0])
    mesh = trimesh.util.concatenate([tube, ball])
    pos = np.array([[0.0, 0, 1.0], [0.2, 0, 1.0], [0.4, 0, 1.0]])
    bind = np.tile(np.eye(4), (3, 1, 1))
    bind[:, :3, 3] = pos
    clip = bind_clip(["a", "b", "c"], np.array([-1, 0, 1]), bind, name="chain")
    return mesh, clip


@pytest.mark.filterwarnings("ignore:.*m tall:rig.base.errors.JiggleWarning")  # a 0.1 m tube, on purpose
def test_auto_weighted_mesh_from_obj(tmp_path):
    mesh, clip = _two_bone_tube()
    # an OBJ written Y-up (as DCC tools do) and in centimetres
    yup = mesh.copy()
    yup.vertices = np.c_[mesh.vertices[:, 0], mesh.vertices[:, 2], -mesh.vertices[:, 1]] * 100
    path = tmp_path / "tube.obj"
    yup.export(path)
    with pytest.warns(JiggleWarning, match="no skin"):
        c = load_character(path, skeleton=clip, unit="cm", up="y")
    np.testing.assert_allclose(c.vertices, mesh.vertices, atol=1e-6)
    assert c.meta["weights"] == "bone heat"
    np.testing.assert_allclose(c.weights.sum(1), 1.0, atol=1e-5)
    near_a = c.vertices[:, 0] < 0.1
    assert np.mean(c.joints[near_a, 0] == 0) > 0.9
    # bending joint b moves the far end, not the start
    world = c.bind_world.copy()
    rot = trimesh.transformations.rotation_matrix(np.pi / 2, [0, 0, 1], point=[0.2, 0, 1.0])
    world[1:] = rot @ world[1:]
    posed = pose_character(c, world)
    start = c.vertices[:, 0] < 0.05  # heat diffuses: a little of joint b's weight reaches the start
    assert np.abs(posed[start] - c.vertices[start]).max() < 0.01
    assert np.abs(posed[c.vertices[:, 0] > 0.39] - c.vertices[c.vertices[:, 0] > 0.39]).max() > 0.1


def test_unit_auto_reads_centimetres_and_says_so(tmp_path):
    """A 170-unit body: --unit auto (the default) reads it in centimetres with a notice naming the
    option that keeps metres; --unit m keeps metres and the height check names --unit cm; --unit cm
    is silent."""
    tall = trimesh.creation.box(extents=[0.4, 0.3, 1.7])
    tall.apply_translation([0, 0, 0.85])
    tall.vertices = tall.vertices * 100
    path = tmp_path / "body.stl"
    tall.export(path)
    from jiggle.rig.character.mesh_io import read_mesh
    with pytest.warns(JiggleWarning, match=r"170 units tall: read in centimetres \(1.7 m\); pass --unit m"):
        auto = read_mesh(path)
    assert abs(np.ptp(auto.vertices[:, 2]) - 1.7) < 1e-6 and auto.unit_scale == 0.01
    with pytest.warns(JiggleWarning, match=r"170 m tall, outside the plausible 0.05-10 m; the file is probably in "
                                           r"centimetres: pass --unit cm"):
        m = read_mesh(path, unit="m")
    assert abs(np.ptp(m.vertices[:, 2]) - 170) < 1e-6
    with warnings.catch_warnings():
        warnings.simplefilter("error", JiggleWarning)
        m = read_mesh(path, unit="cm")
    assert abs(np.ptp(m.vertices[:, 2]) - 1.7) < 1e-6 and m.up == "z"
    with pytest.raises(InputError, match="unit"):
        read_mesh(path, unit="furlong")


def test_guess_unit():
    from jiggle.rig.character.character import guess_unit, resolve_unit
    assert guess_unit(1.7) is None and guess_unit(0.06) is None and guess_unit(9.0) is None  # plausible: metres
    assert guess_unit(79.03) == "cm" and guess_unit(170.0) == "cm" and guess_unit(1700.0) == "mm"
    assert guess_unit(1e7) is None and guess_unit(float("nan")) is None
    assert resolve_unit("m", 170.0) == 1.0 and resolve_unit(0.5, 3.0) == 0.5
    with pytest.warns(JiggleWarning, match="millimetres"):
        assert resolve_unit("auto", 1700.0, "x.glb") == 0.001


def test_skeleton_that_misses_the_mesh_is_an_error(tmp_path):
    mesh, clip = _two_bone_tube()
    with pytest.raises(InputError, match="does not fit the mesh"):
        auto_weighted(mesh.vertices * 100, mesh.faces, clip)


def test_load_skeleton_sources():
    mjcf = load_skeleton(asset("mjcf/humanoid_CMU.xml"))
    assert mjcf.num_joints == 31 and mjcf.num_frames == 1 and len(mjcf.end_parents) > 0
    glb = load_skeleton(asset("characters/CesiumMan.glb"))
    assert glb.num_joints >= 19
    bvh = load_skeleton(asset("mocap/cmu_bvh/01_01.bvh"))
    np.testing.assert_allclose(bvh.rotations[0], bvh.rest_rotations)


# ------------------------------------------------------------------------------------ bad input
def _glb(tmp_path, positions, faces, joints=None, weights=None, name="bad.glb"):
    """A minimal GLB: one triangle mesh, optionally skinned to a two-joint chain."""
    import pygltflib as G
    blob = b""
    views, accessors = [], []

    def add(arr, ctype, typ, target=None):
        nonlocal blob
        data = np.ascontiguousarray(arr).tobytes()
        views.append(G.BufferView(buffer=0, byteOffset=len(blob), byteLength=len(data), target=target))
        blob += data + b"\0" * (-len(data) % 4)
        acc = G.Accessor(bufferView=len(views) - 1, componentType=ctype, count=len(arr), type=typ)
        if typ == "VEC3" and ctype == 5126:
            acc.min = np.nan_to_num(arr).min(0).tolist()
            acc.max = np.nan_to_num(arr).max(0).tolist()
        accessors.append(acc)
        return len(accessors) - 1

    pos = add(np.asarray(positions, np.float32), 5126, "VEC3")
    idx = add(np.asarray(faces, np.uint32).ravel(), 5125, "SCALAR")
    attrs = G.Attributes(POSITION=pos)
    nodes = [G.Node(name="mesh", mesh=0)]
    skins = []
    if joints is not None:
        attrs.JOINTS_0 = add(np.asarray(joints, np.uint16), 5123, "VEC4")
        attrs.WEIGHTS_0 = add(np.asarray(weights, np.float32), 5126, "VEC4")
        ibm = np.stack([np.eye(4), np.linalg.inv(np.array([[1, 0, 0, 0], [0, 1, 0, 0.5], [0, 0, 1, 0], [0, 0, 0, 1.0]]))])
        ibm_acc = add(ibm.transpose(0, 2, 1).reshape(2, 16).astype(np.float32), 5126, "MAT4")
        nodes = [G.Node(name="mesh", mesh=0, skin=0), G.Node(name="hip", children=[2]),
                 G.Node(name="spine", translation=[0, 0.5, 0])]
        skins = [G.Skin(joints=[1, 2], inverseBindMatrices=ibm_acc)]
    g = G.GLTF2(asset=G.Asset(version="2.0"), scene=0,
                scenes=[G.Scene(nodes=[0] + ([1] if joints is not None else []))], nodes=nodes,
                meshes=[G.Mesh(primitives=[G.Primitive(attributes=attrs, indices=idx)])], skins=skins,
                accessors=accessors, bufferViews=views, buffers=[G.Buffer(byteLength=len(blob))])
    g.set_binary_blob(blob)
    path = tmp_path / name
    g.save_binary(str(path))
    return path


# a standing "body": a 2 m-ish column of quads, two joints at y = 0 and 0.5 (glTF Y-up)
_COL = np.array([[x, y, z] for y in (0.0, 0.5, 1.0, 1.6) for x, z in ((-.1, -.1), (.1, -.1), (.1, .1), (-.1, .1))], float)
_FACES = np.array([[i + a, i + b, i + c] for i in (0, 4, 8) for q in range(4)
                   for a, b, c in (((q), (q + 1) % 4, (q + 1) % 4 + 4), ((q), (q + 1) % 4 + 4, q + 4))])
_J = np.tile([0, 1, 0, 0], (16, 1))
_W = np.tile([0.5, 0.5, 0.0, 0.0], (16, 1))


def test_glb_good_minimal(tmp_path):
    with warnings.catch_warnings():
        warnings.simplefilter("error", JiggleWarning)
        c = load_character(_glb(tmp_path, _COL, _FACES, _J, _W))
    assert c.num_vertices == 16 and c.num_joints == 2 and c.influences == 4


def test_weights_not_summing_to_one_are_renormalised(tmp_path):
    w = _W * 0.8
    with pytest.warns(JiggleWarning, match="do not sum to 1.*renormalised"):
        c = load_character(_glb(tmp_path, _COL, _FACES, _J, w))
    np.testing.assert_allclose(c.weights.sum(1), 1.0, atol=1e-6)


def test_joint_index_out_of_range(tmp_path):
    j = _J.copy()
    j[5, 1] = 7
    with pytest.raises(InputError, match=r"joint index 7 at vertex 5 is out of range.*2 joints"):
        load_character(_glb(tmp_path, _COL, _FACES, j, _W))


def test_nan_positions(tmp_path):
    p = _COL.copy()
    p[3, 1] = np.nan
    with pytest.raises(InputError, match=r"not finite.*vertex 3"):
        load_character(_glb(tmp_path, p, _FACES, _J, _W))


def test_degenerate_faces_dropped(tmp_path):
    f = np.r_[_FACES, [[0, 0, 1], [0, 1, 2]]]
    p = _COL.copy()
    p[2] = p[0] + 0.5 * (p[1] - p[0])  # 0, 1, 2 collinear: zero area
    with pytest.warns(JiggleWarning, match="degenerate"):
        c = load_character(_glb(tmp_path, p, f, _J, _W))
    assert len(c.faces) < len(f)


def test_glb_without_skin_needs_a_skeleton(tmp_path):
    path = _glb(tmp_path, _COL, _FACES)
    with pytest.raises(InputError, match="no skin: give a skeleton"):
        load_character(path)
    bind = np.tile(np.eye(4), (2, 1, 1))
    bind[1, :3, 3] = [0, 0, 0.5]
    clip = bind_clip(["hip", "spine"], np.array([-1, 0]), bind)
    with pytest.warns(JiggleWarning, match="no skin in the file; computing automatic weights"):
        c = load_character(path, skeleton=clip)
    assert c.meta["weights"] == "bone heat" and c.num_vertices == 16


def test_not_a_mesh(tmp_path):
    p = tmp_path / "x.obj"
    p.write_text("this is not an obj\n")
    with pytest.raises(InputError):
        load_character(p, skeleton=_two_bone_tube()[1])
    with pytest.raises(InputError, match="unknown character format"):
        load_character(tmp_path / "x.abc")
    with pytest.raises(InputError, match="not found"):          # FBX is a format now (rig/motion/fbx.py)
        load_character(tmp_path / "x.fbx")
