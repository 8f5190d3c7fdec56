"""VRM spring bones (rig.character.vrm_springs): VRMC_springBone 1.0 and VRM 0.x secondaryAnimation read as chains
of the character's joints, in metres and Z-up, onto Character.meta["spring_bones"] and into find_chains."""
import copy
import json
import warnings

import numpy as np
import pygltflib
import pytest

from jiggle.rig.base.errors import InputError
from jiggle.rig.character.chains import find_chains
from jiggle.rig.character.character import Character, bind_clip
from jiggle.rig.character.gltf_character import _node_world
from jiggle.rig.character.gltf_write import write_character
from jiggle.rig.character.load import load_character
from jiggle.rig.character.normals import vertex_normals
from jiggle.rig.character.vrm_springs import read_vrm_springs
from jiggle.rig.motion import quat
from jiggle.rig.motion.clip import transforms
from jiggle.rig.motion.gltf_io import GltfDocument

# name, parent, bind position (Z-up metres): a body (hips, chest), a tail of three and a fin on the tail's root
JOINTS = [("hips", -1, (0.0, 0.0, 0.5)), ("chest", 0, (0.0, 0.0, 0.9)), ("tail1", 0, (0.0, -0.1, 0.5)),
          ("tail2", 2, (0.0, -0.3, 0.5)), ("tail3", 3, (0.0, -0.5, 0.5)), ("fin", 2, (0.15, -0.2, 0.5))]


def tiny(scale: float = 1.0) -> Character:
    """A small square of skin at every joint, bound to it alone; joints turned so that their frames are not the
    world's (an offset in a joint's frame then differs from one in the world)."""
    names = tuple(n for n, _, _ in JOINTS)
    parents = np.array([p for _, p, _ in JOINTS])
    pos = np.array([x for _, _, x in JOINTS]) * scale
    rng = np.random.default_rng(3)
    axes = rng.normal(size=(len(names), 3))
    rot = quat.from_axis_angle(axes / np.linalg.norm(axes, axis=1, keepdims=True), rng.uniform(0.3, 1.2, len(names)))
    bind = transforms(rot, pos)
    corner = np.array([[-1, 0, -1], [1, 0, -1], [1, 0, 1], [-1, 0, 1]]) * 0.02 * scale
    vertices = (pos[:, None] + corner[None]).reshape(-1, 3)
    faces = np.array([[4 * j, 4 * j + 1, 4 * j + 2] for j in range(len(names))] +
                     [[4 * j, 4 * j + 2, 4 * j + 3] for j in range(len(names))], np.int32)
    joints = np.repeat(np.arange(len(names)), 4)[:, None]
    return Character(vertices=vertices, faces=faces, normals=vertex_normals(vertices, faces), uvs=None,
                     joint_names=names, parents=parents, bind_world=bind, bind_matrices=bind, joints=joints,
                     weights=np.ones((len(vertices), 1)), skeleton=bind_clip(names, parents, bind, name="tiny"),
                     name="tiny")


def write(tmp_path, extensions: dict, name: str = "vrm.glb", scale: float = 1.0, armature: float | None = None):
    """The tiny character as a GLB with `extensions` (a function of {node name: index}) added, a node "tail_end"
    outside the skin below tail3, and tail1's children in the order tail2, fin. armature: a scale node put above
    the hips (a centimetre export's 0.01)."""
    path = write_character(tiny(scale), tmp_path / name)
    g = pygltflib.GLTF2().load(path)
    nodes = {n.name: i for i, n in enumerate(g.nodes)}
    g.nodes.append(pygltflib.Node(name="tail_end", translation=[0.0, 0.2 * scale, 0.0]))
    nodes["tail_end"] = len(g.nodes) - 1
    g.nodes[nodes["tail3"]].children = (g.nodes[nodes["tail3"]].children or []) + [nodes["tail_end"]]
    g.nodes[nodes["tail1"]].children = [nodes["tail2"], nodes["fin"]]
    if armature is not None:
        g.nodes.append(pygltflib.Node(name="Armature", scale=[armature] * 3, children=[nodes["hips"]]))
        nodes["Armature"] = len(g.nodes) - 1
        scene = g.scenes[g.scene or 0]
        scene.nodes = [nodes["Armature"] if n == nodes["hips"] else n for n in scene.nodes]
    ext = extensions(nodes)
    g.extensions = {**(g.extensions or {}), **ext}
    g.extensionsUsed = list(g.extensionsUsed or []) + list(ext)
    g.save(path)
    return path, nodes


def load(path, **kw) -> Character:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a scaled tiny character has an implausible height
        return load_character(path, **kw)


def vrm1(n):
    return {"VRMC_springBone": {
        "specVersion": "1.0",
        "colliders": [{"node": n["chest"], "shape": {"sphere": {"offset": [0.01, 0.02, 0.03], "radius": 0.05}}},
                      {"node": n["hips"], "shape": {"capsule": {"offset": [0.0, 0.01, 0.0], "radius": 0.04,
                                                                "tail": [0.0, 0.1, 0.02]}}},
                      {"node": n["tail_end"], "shape": {"sphere": {"radius": 0.01}}}],
        "colliderGroups": [{"name": "body", "colliders": [0, 1]}, {"colliders": [2, 0]}],
        "springs": [
            {"name": "Tail", "colliderGroups": [0, 1], "center": n["hips"],
             "joints": [{"node": n["tail1"], "hitRadius": 0.03, "stiffness": 0.8, "gravityPower": 0.3,
                         "gravityDir": [0.0, 0.0, -1.0], "dragForce": 0.25},
                        {"node": n["tail2"], "hitRadius": 0.9, "stiffness": 3.0},
                        {"node": n["tail3"]}, {"node": n["tail_end"]}]},
            {"joints": [{"node": n["fin"]}]},
            {"name": "outside", "joints": [{"node": n["tail_end"]}]}]}}


def vrm0(n):
    return {"VRM": {"specVersion": "0.0", "secondaryAnimation": {
        "colliderGroups": [{"node": n["chest"], "colliders": [{"offset": {"x": 0.01, "y": 0.02, "z": 0.03},
                                                               "radius": 0.05}]},
                           {"node": n["hips"], "colliders": [{"radius": 0.07}]}],
        "boneGroups": [
            {"comment": "tail", "stiffiness": 0.7, "gravityPower": 0.2, "gravityDir": {"x": 1, "y": 0, "z": 0},
             "dragForce": 0.3, "center": -1, "hitRadius": 0.04, "bones": [n["tail1"]], "colliderGroups": [1, 0]},
            {"bones": [n["fin"], n["chest"]]}]}}}


# ------------------------------------------------------------------------------------------ VRM 1.0
def test_vrm1_chain_joints_and_values(tmp_path):
    path, n = write(tmp_path, vrm1)
    c = load(path)
    springs = c.meta["spring_bones"]
    json.dumps(springs)  # lands in bake.json
    # "outside" has no joint of the character: left out; tail_end (not a skin joint) is left out of "Tail"
    assert [s["name"] for s in springs] == ["Tail", "spring1"]
    tail = springs[0]
    assert tail["joints"] == [c.index("tail1"), c.index("tail2"), c.index("tail3")]
    assert tail["source"] == "VRMC_springBone"
    # the root joint's settings (the second joint's 0.9 and 3.0 are not taken)
    assert tail["stiffness"] == pytest.approx(0.8) and tail["gravity_power"] == pytest.approx(0.3)
    assert tail["drag"] == pytest.approx(0.25) and tail["hit_radius"] == pytest.approx(0.03)
    # glTF's -Z (backwards, Y-up) is jiggle's +Y (Z-up): (x, y, z) -> (x, -z, y)
    np.testing.assert_allclose(tail["gravity_dir"], [0.0, 1.0, 0.0], atol=1e-12)
    # groups 0 and 1: sphere on chest, capsule on hips (collider 0 once), the tail_end sphere left out
    cols = tail["colliders"]
    assert [(k["joint"], k["shape"]) for k in cols] == [(c.index("chest"), "sphere"), (c.index("hips"), "capsule")]
    np.testing.assert_allclose(cols[0]["offset"], [0.01, 0.02, 0.03], atol=1e-7)
    assert cols[0]["tail"] is None and cols[0]["radius"] == pytest.approx(0.05)
    np.testing.assert_allclose(cols[1]["offset"], [0.0, 0.01, 0.0], atol=1e-7)
    np.testing.assert_allclose(cols[1]["tail"], [0.0, 0.1, 0.02], atol=1e-7)
    assert cols[1]["radius"] == pytest.approx(0.04)


def test_vrm1_defaults(tmp_path):
    """Values the file leaves out take the schema's defaults."""
    path, n = write(tmp_path, vrm1)
    c = load(path)
    fin = c.meta["spring_bones"][1]
    assert fin["joints"] == [c.index("fin")] and fin["colliders"] == []
    assert fin["stiffness"] == 1.0 and fin["gravity_power"] == 0.0 and fin["drag"] == 0.5
    assert fin["hit_radius"] == 0.0
    assert fin["gravity_dir"] == [0.0, 0.0, -1.0]  # glTF's down (0, -1, 0) is jiggle's down


def test_collider_offsets_are_in_the_joint_frame_in_metres(tmp_path):
    """A centimetre export (numbers x100 under an armature scaled 0.01): offsets are node-local, so they come
    back x0.01 in metres, and placed by the joint's bind transform they land where the file's node places them;
    radii are world lengths (kept)."""
    path, n = write(tmp_path, vrm1, scale=100.0, armature=0.01)
    c = load(path)
    assert c.meta["unit_scale"] == 1.0
    np.testing.assert_allclose(c.bind_world[c.index("tail2"), :3, 3], [0.0, -0.3, 0.5], atol=1e-6)
    doc = GltfDocument(path)
    tail = c.meta["spring_bones"][0]
    for k, (node, local) in zip(tail["colliders"], [("chest", [0.01, 0.02, 0.03]), ("hips", [0.0, 0.01, 0.0])]):
        np.testing.assert_allclose(k["offset"], np.array(local) * 0.01, atol=1e-9)
        in_file = _node_world(doc, n[node]) @ np.append(local, 1.0)
        np.testing.assert_allclose(c.bind_world[k["joint"]] @ np.append(k["offset"], 1.0), in_file, atol=1e-7)
    assert tail["colliders"][0]["radius"] == pytest.approx(0.05)
    assert tail["hit_radius"] == pytest.approx(0.03)


def test_unit_option_scales_the_lengths(tmp_path):
    path, n = write(tmp_path, vrm1)
    c = load(path, unit="cm")
    assert c.meta["unit_scale"] == pytest.approx(0.01)
    tail = c.meta["spring_bones"][0]
    assert tail["hit_radius"] == pytest.approx(0.0003)
    np.testing.assert_allclose(tail["colliders"][1]["tail"], [0.0, 0.001, 0.0002], atol=1e-9)
    assert tail["colliders"][1]["radius"] == pytest.approx(0.0004)
    assert tail["stiffness"] == pytest.approx(0.8)  # not a length


def test_scaled_character_scales_the_spring_lengths(tmp_path):
    path, n = write(tmp_path, vrm1)
    c = load(path)
    big = c.scaled(2.0)
    a, b = c.meta["spring_bones"][0], big.meta["spring_bones"][0]
    assert b["joints"] == a["joints"] and b["stiffness"] == a["stiffness"] and b["gravity_dir"] == a["gravity_dir"]
    assert b["hit_radius"] == pytest.approx(2 * a["hit_radius"])
    for ka, kb in zip(a["colliders"], b["colliders"]):
        np.testing.assert_allclose(kb["offset"], 2 * np.array(ka["offset"]))
        assert kb["radius"] == pytest.approx(2 * ka["radius"])
    np.testing.assert_allclose(b["colliders"][1]["tail"], 2 * np.array(a["colliders"][1]["tail"]))
    assert a["hit_radius"] == pytest.approx(0.03)  # the original is untouched


# ------------------------------------------------------------------------------------------ VRM 0.x
def test_vrm0_chains_follow_the_first_child(tmp_path):
    path, n = write(tmp_path, vrm0)
    c = load(path)
    springs = c.meta["spring_bones"]
    json.dumps(springs)
    assert [s["name"] for s in springs] == ["tail", "boneGroup1 (fin)", "boneGroup1 (chest)"]
    tail = springs[0]
    # tail1 has two children (tail2, fin): the chain follows the first; tail_end is not a joint
    assert tail["joints"] == [c.index("tail1"), c.index("tail2"), c.index("tail3")]
    assert tail["source"] == "VRM0"
    assert tail["stiffness"] == pytest.approx(0.7) and tail["gravity_power"] == pytest.approx(0.2)
    assert tail["drag"] == pytest.approx(0.3) and tail["hit_radius"] == pytest.approx(0.04)
    np.testing.assert_allclose(tail["gravity_dir"], [1.0, 0.0, 0.0], atol=1e-12)
    assert [k["joint"] for k in tail["colliders"]] == [c.index("hips"), c.index("chest")]  # groups 1, 0
    assert all(k["shape"] == "sphere" and k["tail"] is None for k in tail["colliders"])
    np.testing.assert_allclose(tail["colliders"][1]["offset"], [0.01, 0.02, -0.03], atol=1e-7)  # VRM 0.x's z
    np.testing.assert_allclose(tail["colliders"][0]["offset"], [0.0, 0.0, 0.0])
    assert tail["colliders"][0]["radius"] == pytest.approx(0.07)
    # UniVRM's defaults where the group says nothing
    fin = springs[1]
    assert fin["joints"] == [c.index("fin")]
    assert (fin["stiffness"], fin["gravity_power"], fin["drag"], fin["hit_radius"]) == (1.0, 0.0, 0.4, 0.02)
    assert fin["gravity_dir"] == [0.0, 0.0, -1.0] and fin["colliders"] == []
    assert springs[2]["joints"] == [c.index("chest")]


def test_vrm1_wins_over_vrm0(tmp_path):
    path, n = write(tmp_path, lambda n: {**vrm0(n), **vrm1(n)})
    assert {s["source"] for s in load(path).meta["spring_bones"]} == {"VRMC_springBone"}


def test_no_extension_no_springs(tmp_path):
    path, n = write(tmp_path, lambda n: {})
    c = load(path)
    assert not c.meta.get("spring_bones")
    assert read_vrm_springs(path, c.joint_names) == []


# ------------------------------------------------------------------------------------------ errors
def _set(field: str, value):
    """A function that sets the JSON field ("a.b[2].c") of an extension dict to `value` (None deletes it)."""
    def edit(ext):
        parts = [p for p in field.replace("[", ".").replace("]", "").split(".")]
        obj = ext
        for p in parts[:-1]:
            obj = obj[int(p)] if isinstance(obj, list) else obj[p]
        last = int(parts[-1]) if isinstance(obj, list) else parts[-1]
        if value is None:
            del obj[last]
        else:
            obj[last] = value
        return ext
    return edit


BAD = [
    (vrm1, "VRMC_springBone.springs[0].joints[0].node", 999, "index of nodes"),
    (vrm1, "VRMC_springBone.springs[0].joints[1].node", None, "missing"),
    (vrm1, "VRMC_springBone.springs[1].joints", None, "missing"),
    (vrm1, "VRMC_springBone.springs[0].joints[0].gravityDir", [0, 1], "3 finite numbers"),
    (vrm1, "VRMC_springBone.springs[0].joints[0].dragForce", 1.5, "from 0 to 1"),
    (vrm1, "VRMC_springBone.springs[0].joints[0].stiffness", "stiff", "a finite number"),
    (vrm1, "VRMC_springBone.springs[0].colliderGroups[1]", 7, "index of VRMC_springBone.colliderGroups"),
    (vrm1, "VRMC_springBone.colliderGroups[0].colliders[1]", 5, "index of VRMC_springBone.colliders"),
    (vrm1, "VRMC_springBone.colliders[1].shape", {"box": {}}, "exactly one of 'sphere' or 'capsule'"),
    (vrm1, "VRMC_springBone.colliders[0].shape.sphere.radius", -1.0, "at least 0"),
    (vrm1, "VRMC_springBone.springs", {"joints": []}, "a list"),
    (vrm0, "VRM.secondaryAnimation.boneGroups[0].bones[0]", "tail1", "index of nodes"),
    (vrm0, "VRM.secondaryAnimation.boneGroups[0].colliderGroups[0]", 2, "index of VRM.secondaryAnimation"),
    (vrm0, "VRM.secondaryAnimation.colliderGroups[0].node", None, "missing"),
    (vrm0, "VRM.secondaryAnimation.boneGroups[0].gravityDir.y", "down", "a finite number"),
]


@pytest.mark.parametrize("make, field, value, says", BAD, ids=[f"{b[1]}={b[2]!r}" for b in BAD])
def test_malformed_extension_names_the_field(tmp_path, make, field, value, says):
    path, n = write(tmp_path, lambda n: _set(field, value)(copy.deepcopy(make(n))))
    with pytest.raises(InputError) as e:
        load(path)
    assert e.value.field == field
    assert e.value.path == path and says in e.value.message
    assert path in str(e.value) and field in str(e.value)


def test_joints_out_of_order_are_refused(tmp_path):
    def swapped(n):
        ext = vrm1(n)
        joints = ext["VRMC_springBone"]["springs"][0]["joints"]
        joints[0], joints[1] = joints[1], joints[0]
        return ext
    path, n = write(tmp_path, swapped)
    with pytest.raises(InputError, match="ancestor of the next") as e:
        load(path)
    assert e.value.field == "VRMC_springBone.springs[0].joints[1].node"


# ------------------------------------------------------------------------------------------ chains
def test_find_chains_takes_the_springs(tmp_path):
    """A spring rooted at tail2: without it the name rule roots the tail at tail1; with it the file's chain comes
    first, rooted at the spring's first joint, carrying the spring's settings."""
    def from_tail2(n):
        ext = vrm1(n)
        ext["VRMC_springBone"]["springs"][0]["joints"] = [{"node": n["tail2"], "stiffness": 0.6},
                                                          {"node": n["tail3"]}]
        return ext
    path, n = write(tmp_path, from_tail2)
    c = load(path)
    plain = find_chains(c)
    assert plain.chains[0].source == "name" and plain.chains[0].joints[0] == c.index("tail1")
    found = find_chains(c, springs=c.meta["spring_bones"])
    first = found.chains[0]
    assert first.source == "vrm" and first.joints[0] == c.index("tail2") and first.name == "tail2"
    assert c.index("tail3") in first.joints and first.spring["stiffness"] == pytest.approx(0.6)
    # the rest of the tail (tail1 and its fin) is still found by its name, without tail2's joints
    rest = [ch for ch in found.chains if ch.source == "name"]
    assert rest and rest[0].joints[0] == c.index("tail1") and c.index("tail2") not in rest[0].joints
