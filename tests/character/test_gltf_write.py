"""Writing a skinned character as glTF (rig.character.gltf_write): what jiggle reads back is what it wrote."""
import dataclasses
import os
import warnings

import numpy as np
import pygltflib
import pytest
from conftest import asset

from jiggle.rig.base.errors import InputError, JiggleWarning
from jiggle.rig.character.character import Character, bind_clip
from jiggle.rig.character.gltf_write import write_character
from jiggle.rig.character.load import load_character
from jiggle.rig.motion import quat
from jiggle.rig.skin.skinning import pose_character

CESIUM = "characters/CesiumMan.glb"


def cesium():
    return load_character(asset(CESIUM))


def dense_weights(c: Character) -> np.ndarray:
    """(V, J) weight of every joint at every vertex, so influences of equal weight compare in any order."""
    out = np.zeros((c.num_vertices, c.num_joints))
    np.add.at(out, (np.arange(c.num_vertices)[:, None].repeat(c.influences, 1), c.joints), c.weights)
    return out


def assert_same_character(a: Character, b: Character, uvs: bool = True):
    assert b.joint_names == a.joint_names
    np.testing.assert_array_equal(b.parents, a.parents)
    np.testing.assert_allclose(b.vertices, a.vertices, atol=1e-6)
    np.testing.assert_array_equal(b.faces, a.faces)
    np.testing.assert_allclose(b.normals, a.normals, atol=1e-6)
    if uvs:
        np.testing.assert_allclose(b.uvs, a.uvs, atol=1e-7)
    else:
        assert a.uvs is None and b.uvs is None
    np.testing.assert_allclose(b.bind_world, a.bind_world, atol=1e-6)
    np.testing.assert_allclose(b.bind_matrices, a.bind_matrices, atol=1e-6)
    np.testing.assert_allclose(dense_weights(b), dense_weights(a), atol=1e-6)
    live = a.weights > 1e-6
    np.testing.assert_array_equal(np.sort(np.where(live, b.joints, -1), 1), np.sort(np.where(live, a.joints, -1), 1))


def bend(c: Character, joint: str, angle_deg: float = 50.0, axis=(1.0, 0.0, 0.0)) -> np.ndarray:
    """(J, 4, 4) bind pose with `joint` and everything below it turned about the joint."""
    j = c.index(joint)
    below = np.zeros(c.num_joints, bool)
    below[j] = True
    for i, p in enumerate(c.parents):  # parents first
        if p >= 0 and below[p]:
            below[i] = True
    turn = np.eye(4)
    turn[:3, :3] = quat.to_matrix(quat.from_axis_angle(np.asarray(axis), np.radians(angle_deg)))
    pivot = np.eye(4)
    pivot[:3, 3] = c.bind_world[j, :3, 3]
    world = c.bind_world.copy()
    world[below] = pivot @ turn @ np.linalg.inv(pivot) @ world[below]
    return world


def no_leftovers(folder) -> list[str]:
    return sorted(f for f in os.listdir(folder) if f.startswith("."))


# ---------------------------------------------------------------------------------- CesiumMan
@pytest.mark.parametrize("ext", [".glb", ".gltf"])
def test_cesiumman_round_trip(tmp_path, ext):
    c = cesium()
    path = write_character(c, tmp_path / f"man{ext}", source=asset(CESIUM))
    assert path == os.fspath(tmp_path / f"man{ext}")
    back = load_character(path)
    assert back.num_vertices == 3273 and len(back.faces) == 4672 and back.num_joints == 19
    assert_same_character(c, back)
    assert no_leftovers(tmp_path) == []
    # one self-contained file: GLB magic, or JSON whose only buffer is a data URI
    with open(path, "rb") as fh:
        head = fh.read(4)
    g = pygltflib.GLTF2().load(path)
    assert (head == b"glTF") == (ext == ".glb")
    assert len(g.buffers) == 1 and (g.buffers[0].uri is None) == (ext == ".glb")
    assert g.asset.generator == "jiggle"
    assert g.asset.extras == {"jiggle": {"from": "CesiumMan.glb"}}


def test_spec_details(tmp_path):
    """POSITION bounds, aligned views with targets, IBM affine rows, unit normals and weights."""
    c = cesium()
    g = pygltflib.GLTF2().load(write_character(c, tmp_path / "man.glb"))
    prim = g.meshes[0].primitives[0]
    a = g.accessors[prim.attributes.POSITION]
    blob = g.binary_blob()

    def read(i, dtype, n):
        acc = g.accessors[i]
        bv = g.bufferViews[acc.bufferView]
        return np.frombuffer(blob, dtype, acc.count * n, bv.byteOffset + (acc.byteOffset or 0)).reshape(-1, n)

    pos = read(prim.attributes.POSITION, "<f4", 3)
    assert a.min == pos.min(0).tolist() and a.max == pos.max(0).tolist()
    assert all(bv.byteOffset % 4 == 0 for bv in g.bufferViews)
    assert sum(bv.byteLength for bv in g.bufferViews) <= g.buffers[0].byteLength <= len(blob)
    targets = {g.accessors[i].bufferView: t for i, t in
               [(prim.attributes.POSITION, 34962), (prim.attributes.JOINTS_0, 34962), (prim.indices, 34963)]}
    assert all(g.bufferViews[v].target == t for v, t in targets.items())
    assert g.accessors[prim.attributes.JOINTS_0].componentType == 5123
    assert g.accessors[prim.indices].componentType == 5125
    np.testing.assert_allclose(np.linalg.norm(read(prim.attributes.NORMAL, "<f4", 3), axis=1), 1.0, atol=1e-6)
    np.testing.assert_allclose(read(prim.attributes.WEIGHTS_0, "<f4", 4).sum(1), 1.0, atol=1e-6)
    ibm = read(g.skins[0].inverseBindMatrices, "<f4", 16).reshape(-1, 4, 4)
    np.testing.assert_array_equal(ibm[:, :, 3], np.tile([0, 0, 0, 1], (len(ibm), 1)))  # column-major
    assert g.skins[0].skeleton == 0 and g.skins[0].joints == list(range(19))
    assert g.nodes[-1].skin == 0 and g.nodes[-1].mesh == 0 and len(g.nodes) == 20
    assert g.scenes[0].nodes == [0, 19]
    # the Y-up file: the man stands along +y, 1.51 m tall
    assert np.ptp(pos[:, 1]) == pytest.approx(1.51, abs=0.01) and np.ptp(pos[:, 2]) < 0.5


def test_nodes_rest_pose_is_the_bind_pose(tmp_path):
    """Blender and other viewers show the nodes' TRS: it is the bind pose, the skin undeformed."""
    from jiggle.rig.motion.gltf_skeleton import read_gltf_skeleton
    c = cesium()
    s = read_gltf_skeleton(write_character(c, tmp_path / "man.glb"))
    np.testing.assert_allclose(s.rest_translations, s.bind_translations, atol=1e-6)
    np.testing.assert_allclose(np.abs(np.sum(s.rest_rotations * s.bind_rotations, 1)), 1.0, atol=1e-6)


def test_texture_is_carried_over_from_the_source(tmp_path):
    c = cesium()
    src = pygltflib.GLTF2().load(asset(CESIUM))
    bv = src.bufferViews[src.images[0].bufferView]
    jpeg = src.binary_blob()[bv.byteOffset or 0:(bv.byteOffset or 0) + bv.byteLength]
    for ext in (".glb", ".gltf"):
        out = write_character(c, tmp_path / f"man{ext}", source=asset(CESIUM))
        g = pygltflib.GLTF2().load(out)
        data = g.binary_blob() if ext == ".glb" else g.get_data_from_buffer_uri(g.buffers[0].uri)
        img = g.images[0]
        view = g.bufferViews[img.bufferView]
        assert data[view.byteOffset:view.byteOffset + view.byteLength] == jpeg
        assert img.mimeType == "image/jpeg"
        mat = g.materials[g.meshes[0].primitives[0].material]
        assert mat.name == "Cesium_Man-effect"
        assert g.textures[mat.pbrMetallicRoughness.baseColorTexture.index].source == 0
        assert g.samplers[g.textures[0].sampler].magFilter == src.samplers[0].magFilter
    # a character without uvs keeps the material's factors but not the texture, and says so
    with pytest.warns(JiggleWarning, match="no texture coordinates"):
        g = pygltflib.GLTF2().load(write_character(_tiny_character(), tmp_path / "tiny.glb", source=asset(CESIUM)))
    assert not g.images and not g.textures and g.materials[0].name == "Cesium_Man-effect"
    assert g.materials[0].pbrMetallicRoughness.baseColorTexture is None


def test_plain_material_without_a_textured_source(tmp_path):
    c = cesium()
    g = pygltflib.GLTF2().load(write_character(c, tmp_path / "plain.glb"))
    assert len(g.materials) == 1 and not g.images and not g.textures
    assert g.materials[0].pbrMetallicRoughness.baseColorTexture is None
    # a source without any material (the plain file, its material removed) is no error either
    bare = pygltflib.GLTF2().load(tmp_path / "plain.glb")
    bare.materials = []
    bare.meshes[0].primitives[0].material = None
    bare.save(tmp_path / "bare.glb")
    g = pygltflib.GLTF2().load(write_character(c, tmp_path / "again.glb", source=tmp_path / "bare.glb"))
    assert len(g.materials) == 1 and not g.images
    with pytest.raises(InputError, match="not found"):
        write_character(c, tmp_path / "x.glb", source=tmp_path / "missing.glb")
    assert not (tmp_path / "x.glb").exists()


def test_extras_and_name(tmp_path):
    c = cesium()
    g = pygltflib.GLTF2().load(write_character(c, tmp_path / "m.gltf", name="Morphed",
                                               extras={"jiggle": {"morphed_from": "CesiumMan.glb"}}))
    assert g.asset.extras == {"jiggle": {"morphed_from": "CesiumMan.glb"}}
    assert g.meshes[0].name == "Morphed" and g.scenes[0].name == "Morphed"
    with pytest.raises(InputError) as e:
        write_character(c, tmp_path / "n.glb", extras={"bad": float("nan")})
    assert e.value.field == "extras" and not (tmp_path / "n.glb").exists()


# ---------------------------------------------------------------------------------- changed characters
def test_scaled_character_round_trips(tmp_path):
    c = cesium()
    grow = np.diag([1.1, 1.1, 1.1, 1.0])

    def scale_translation(m):
        m = m.copy()
        m[:, :3, 3] *= 1.1
        return m

    big = dataclasses.replace(c, vertices=c.vertices * 1.1, bind_world=scale_translation(c.bind_world),
                              bind_matrices=scale_translation(c.bind_matrices))
    back = load_character(write_character(big, tmp_path / "big.glb", source=asset(CESIUM)))
    assert_same_character(big, back)
    np.testing.assert_allclose(back.bind_positions, (grow[:3, :3] @ c.bind_positions.T).T, atol=1e-6)
    assert back.height == pytest.approx(1.1 * c.height, abs=1e-6)


def test_written_character_is_animatable(tmp_path):
    """Posed before writing and after reading back: the same skin."""
    c = cesium()
    back = load_character(write_character(c, tmp_path / "man.glb"))
    for joint, axis in (("Skeleton_arm_joint_L__4_", (0.0, 1.0, 0.0)), ("leg_joint_R_1", (1.0, 0.0, 0.0))):
        world = bend(c, joint, 60.0, axis)
        before = pose_character(c, world)
        assert np.abs(before - c.vertices).max() > 0.1  # the bend moves the skin
        np.testing.assert_allclose(pose_character(back, world), before, atol=1e-5)
    # glTF skinning of the file (node world @ IBM on the file's vertices) is the same map
    world = bend(c, "leg_joint_R_1")
    g = pygltflib.GLTF2().load(tmp_path / "man.glb")
    from jiggle.rig.motion.gltf_io import Z_UP, GltfDocument
    doc = GltfDocument(tmp_path / "man.glb")
    prim = g.meshes[0].primitives[0]
    v = doc.accessor(prim.attributes.POSITION)
    ibm = doc.accessor(g.skins[0].inverseBindMatrices).reshape(-1, 4, 4).transpose(0, 2, 1)
    skin = (Z_UP.T @ world) @ ibm  # node global transforms are in the file's Y-up world
    j, w = doc.accessor(prim.attributes.JOINTS_0).astype(int), doc.accessor(prim.attributes.WEIGHTS_0)
    m = np.einsum("vk,vkij->vij", w, skin[j])
    posed = np.einsum("vij,vj->vi", m[:, :3, :3], v) + m[:, :3, 3]
    np.testing.assert_allclose(posed @ Z_UP[:3, :3].T, pose_character(c, world), atol=1e-5)


def _tiny_character(scale_bind: bool = False) -> Character:
    """Two roots and a child listed after the second root (not depth-first): a strip of 4 quads."""
    x = np.linspace(0.0, 1.0, 5)
    vertices = np.array([[xi, y, 0.1 * xi] for xi in x for y in (0.0, 0.2)])
    faces = np.array([[2 * i, 2 * i + 2, 2 * i + 1] for i in range(4)] +
                     [[2 * i + 1, 2 * i + 2, 2 * i + 3] for i in range(4)], np.int32)
    from jiggle.rig.character.normals import vertex_normals
    names, parents = ("a", "b", "c"), np.array([-1, -1, 0])
    rot = quat.from_axis_angle(np.array([0.0, 0.0, 1.0]), np.array([0.3, -0.2, 1.0]))
    pos = np.array([[0.0, 0.1, 0.0], [1.0, 0.1, 0.1], [0.5, 0.1, 0.05]])
    from jiggle.rig.motion.clip import transforms
    bind = transforms(rot, pos)
    bind_m = bind @ np.diag([1.2, 0.9, 1.0, 1.0]) if scale_bind else bind
    t = np.clip(vertices[:, 0], 0, 1)
    joints = np.stack([np.where(t < 0.5, 0, 2), np.where(t < 0.5, 2, 1), np.full(len(t), 0)], 1)
    weights = np.stack([1 - np.abs(t - 0.5), np.abs(t - 0.5), np.zeros(len(t))], 1)
    return Character(vertices=vertices, faces=faces, normals=vertex_normals(vertices, faces), uvs=None,
                     joint_names=names, parents=parents, bind_world=bind, bind_matrices=bind_m, joints=joints,
                     weights=weights, skeleton=bind_clip(names, parents, bind, name="tiny"), name="tiny")


@pytest.mark.parametrize("scale_bind", [False, True])
def test_tiny_forest_round_trips_in_depth_first_order(tmp_path, scale_bind):
    """A forest, a joint order that is not depth-first, k=3 and bind matrices that scale: the joints
    come back depth-first (same names, same tree) and the posed skin is the same."""
    c = _tiny_character(scale_bind)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the strip is 1 m long: an implausible body height
        back = load_character(write_character(c, tmp_path / "tiny.gltf"), k=3)
    assert back.joint_names == ("a", "c", "b")
    order = [c.joint_names.index(n) for n in back.joint_names]
    assert [back.joint_names[p] if p >= 0 else None for p in back.parents] == \
        [c.joint_names[c.parents[i]] if c.parents[i] >= 0 else None for i in order]
    np.testing.assert_allclose(back.vertices, c.vertices, atol=1e-6)
    np.testing.assert_allclose(back.bind_matrices, c.bind_matrices[order], atol=1e-6)
    world = c.bind_world.copy()
    world[2] = world[2] @ np.block([[quat.to_matrix(quat.from_axis_angle(np.array([1.0, 0, 0]), 0.7)),
                                     np.zeros((3, 1))], [np.zeros((1, 3)), np.ones((1, 1))]])
    np.testing.assert_allclose(pose_character(back, world[order]), pose_character(c, world), atol=1e-5)


def test_weights_are_written_normalised_without_repeated_joints(tmp_path):
    """Rows scaled off 1 and one joint listed twice: the file has rows summing to 1 and each joint
    once per vertex with weight (as the spec asks), the same skinning as the character's."""
    c = _tiny_character()
    joints = c.joints.copy()
    weights = c.weights * 0.8
    joints[:, 2], weights[:, 2] = joints[:, 0], 0.1  # the strongest joint again, with more weight
    odd = dataclasses.replace(c, joints=joints, weights=weights)
    from jiggle.rig.motion.gltf_io import GltfDocument
    doc = GltfDocument(write_character(odd, tmp_path / "odd.glb"))
    attrs = doc.gltf.meshes[0].primitives[0].attributes
    j, w = doc.accessor(attrs.JOINTS_0).astype(int), doc.accessor(attrs.WEIGHTS_0)
    np.testing.assert_allclose(w.sum(1), 1.0, atol=1e-6)
    for row_j, row_w in zip(j, w):
        live = row_j[row_w > 0]
        assert len(set(live.tolist())) == len(live)
    expect = np.zeros((c.num_vertices, 3))
    np.add.at(expect, (np.arange(c.num_vertices)[:, None].repeat(3, 1), joints), weights)
    got = np.zeros((c.num_vertices, 3))
    np.add.at(got, (np.arange(c.num_vertices)[:, None].repeat(4, 1), j), w)
    np.testing.assert_allclose(got, expect / expect.sum(1, keepdims=True), atol=1e-6)


def test_generated_body_round_trips_without_uvs(tmp_path):
    from jiggle.rig.character.body import BodyOptions
    from jiggle.rig.character.load import body_character
    from jiggle.sim.bake.scene import load_scene
    clip = load_scene("scenes/default.toml").clip
    c = body_character(clip, BodyOptions(resolution=2000), k=5)  # k=5: JOINTS_0/1 and WEIGHTS_0/1
    assert c.uvs is None
    path = write_character(c, tmp_path / "body.glb")
    g = pygltflib.GLTF2().load(path)
    attrs = g.meshes[0].primitives[0].attributes
    assert attrs.TEXCOORD_0 is None and attrs.JOINTS_1 is not None and attrs.WEIGHTS_1 is not None
    back = load_character(path, k=5)
    assert_same_character(c, back, uvs=False)
    world = bend(c, "l_forearm", 70.0)
    np.testing.assert_allclose(pose_character(back, world), pose_character(c, world), atol=1e-5)


# ---------------------------------------------------------------------------------- bad input
def test_bad_input_leaves_no_file(tmp_path, monkeypatch):
    c = cesium()
    with pytest.raises(InputError, match=r"\.glb.*\.gltf") as e:
        write_character(c, tmp_path / "man.obj")
    assert "man.obj" in str(e.value)
    v = c.vertices.copy()
    v[17, 1] = np.nan
    with pytest.raises(InputError, match="row 17") as e:
        write_character(dataclasses.replace(c, vertices=v), tmp_path / "nan.glb")
    assert e.value.field == "vertices"
    b = c.bind_world.copy()
    b[3, 0, 3] = np.inf
    with pytest.raises(InputError) as e:
        write_character(dataclasses.replace(c, bind_world=b), tmp_path / "inf.gltf")
    assert e.value.field == "bind_world"
    with pytest.raises(InputError, match="does not exist") as e:
        write_character(c, tmp_path / "no" / "such" / "man.glb")
    assert not (tmp_path / "no").exists()
    assert sorted(os.listdir(tmp_path)) == []
    # an existing file survives a failed write, and a failure while writing leaves no temporary file
    good = write_character(c, tmp_path / "man.glb")
    before = open(good, "rb").read()
    with pytest.raises(InputError):
        write_character(dataclasses.replace(c, vertices=v), good)
    import jiggle.rig.character.gltf_write as gw

    def broken(path, doc):
        raise RuntimeError("simulated failure after the bytes were written")

    monkeypatch.setattr(gw, "_verify", broken)
    with pytest.raises(RuntimeError):
        write_character(c, good)
    assert open(good, "rb").read() == before
    assert os.listdir(tmp_path) == ["man.glb"]
