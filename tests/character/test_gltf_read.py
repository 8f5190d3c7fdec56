"""Reading skinned glTF characters as the spec poses them, checked against tests/gltf_reference.py (an
independent NumPy evaluation of v' = sum_k w_k * G_k(t) @ IBM_k @ v, turned Z-up), on the synthetic
figure of tests/gltf_reference.write_figure: a centimetre armature (scale 0.01, turned about X), a
scaled joint, a node in the tree outside the skin, a joint without weight, two skinned meshes (one of
two primitives, one on a node with a transform of its own), and the bad input a reader must refuse.
"""
from __future__ import annotations

import json
import warnings

import gltf_reference
import numpy as np
import pytest

from jiggle.rig.base.errors import InputError, JiggleWarning
from jiggle.rig.character.gltf_character import read_gltf_character
from jiggle.rig.character.load import load_character
from jiggle.rig.motion.clip import transforms
from jiggle.rig.motion.gltf_anim import read_gltf_animation
from jiggle.rig.motion.gltf_skeleton import read_gltf_skeleton
from jiggle.rig.skin.skinning import pose_character
from jiggle.sim.app.cli import main


def read(path, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("error", JiggleWarning)  # the figure needs no repair and no unit guess
        return read_gltf_character(path, **kw), read_gltf_animation(path)


def posed(c, clip, t: float) -> np.ndarray:
    order = [clip.joint_names.index(n) for n in c.joint_names]
    world = transforms(*clip.world(*clip.sample(np.array([t - clip.meta["start_time"]]))))[0][order]
    return pose_character(c, world)


@pytest.mark.parametrize("spine_scale", [1.0, 1.1])
@pytest.mark.parametrize("turn", [-90.0, 90.0, 0.0])
def test_centimetre_armature_is_posed_as_the_spec_says(tmp_path, spine_scale, turn):
    """Armature scale 0.01 (and a turn about X): the skin comes out in metres, its bind matrices rigid,
    and posed by the file's animation it is the spec's skin; a uniform scale on a joint is folded."""
    path = gltf_reference.write_figure(tmp_path / "f.glb", armature_turn_deg=turn, spine_scale=spine_scale)
    c, clip = read(path)
    ref_rest = gltf_reference.skinned_vertices(path, None)
    np.testing.assert_allclose(c.vertices, ref_rest, atol=1e-6)
    extent = np.ptp(c.vertices, axis=0)
    assert extent.max() == pytest.approx(1.67, abs=1e-5)  # the cap's top at 170 cm, the feet at 3 cm
    if turn == -90.0:  # the usual export: the figure stands up, Z-up metres
        assert c.height == pytest.approx(1.67, abs=1e-5) and c.vertices[:, 2].min() == pytest.approx(0.03, abs=1e-6)
    assert c.meta["unit_scale"] == 1.0
    np.testing.assert_allclose(c.bind_matrices, c.bind_world, atol=1e-6)  # 0.01 and 1.1 folded out
    np.testing.assert_allclose(np.linalg.det(c.bind_world[:, :3, :3]), 1.0, atol=1e-9)
    assert c.joint_names == gltf_reference.FIGURE_JOINTS and clip.joint_names == c.joint_names
    # the bind skeleton stands where the nodes' rest pose puts it (joint positions in metres)
    _, rest_pos = clip.rest_world()
    np.testing.assert_allclose(c.bind_positions, rest_pos, atol=1e-6)
    assert c.bind_positions[c.index("neck"), :].max() < 2.0
    for t in (0.25, 0.5, 0.8, 1.0):
        ref = gltf_reference.skinned_vertices(path, t)
        assert np.abs(ref - ref_rest).max() > 0.1
        np.testing.assert_allclose(posed(c, clip, t), ref, atol=1e-5)


def test_the_skinned_mesh_node_transform_is_ignored(tmp_path):
    """The Cap's node has a translation of 3 m, a turn and a scale of 2: the spec ignores them, so the
    character is the same as without them (also when the Cap's node comes first in the file)."""
    a, clip = read(gltf_reference.write_figure(tmp_path / "a.glb", mesh_node_transform=True))
    b, _ = read(gltf_reference.write_figure(tmp_path / "b.glb", mesh_node_transform=False))
    np.testing.assert_allclose(a.vertices, b.vertices, atol=1e-7)
    np.testing.assert_allclose(a.bind_matrices, b.bind_matrices, atol=1e-7)
    np.testing.assert_allclose(posed(a, clip, 0.5), gltf_reference.skinned_vertices(tmp_path / "a.glb", 0.5),
                               atol=1e-5)


def test_several_meshes_and_primitives_keep_their_names(tmp_path):
    c, _ = read(gltf_reference.write_figure(tmp_path / "f.glb"))
    parts = c.meta["parts"]
    assert parts == [["Body.0", 0, 48], ["Body.1", 48, 48], ["Cap", 96, 48]]
    assert json.loads(json.dumps(parts)) == parts
    assert sum(n for _, _, n in parts) == c.num_vertices
    # the legs primitive is on the legs: below the hips
    assert c.vertices[48:96, 2].max() < c.bind_positions[c.index("hips"), 2]


def test_joints_without_weight_or_outside_the_skin_still_pose(tmp_path):
    path = gltf_reference.write_figure(tmp_path / "f.glb")
    sk = read_gltf_skeleton(path)
    assert sk.skin_joint[sk.joint_names.index("chest_offset")] == -1
    c, clip = read(path)
    assert not np.any(c.joints[c.weights > 0] == c.index("head_end"))
    # The spine scale of 1.1 and the armature's 0.01: c_k of each joint.
    np.testing.assert_allclose(sk.joint_scale, [0.01, 0.011, 0.011, 0.011, 0.011, 0.01, 0.01], rtol=1e-6)


@pytest.mark.parametrize("kw, field, message", [
    ({"armature_scale": (0.01, 0.02, 0.01)}, 'nodes[0] "Armature"', r"non-uniform scale \[0.01, 0.02, 0.01\] is not"),
    ({"armature_scale": (-0.01, 0.01, 0.01)}, 'nodes[0] "Armature"', r"negative scale \[-0.01, 0.01, 0.01\]"),
    ({"joint_scale_override": {"Armature": (0, 0, 0)}}, 'nodes[0] "Armature"', r"zero scale"),
    ({"joint_scale_override": {"leg_L": (1, 2, 1)}}, 'nodes[6] "leg_L"', r"non-uniform scale \[1, 2, 1\]"),
    ({"joint_scale_override": {"knee_L": (-1, -1, -1)}}, 'nodes[7] "knee_L"', r"negative scale"),
])
def test_scale_that_rigid_joints_cannot_pose_is_refused(tmp_path, kw, field, message):
    path = gltf_reference.write_figure(tmp_path / "bad.glb", **kw)
    for reader in (read_gltf_character, read_gltf_animation, read_gltf_skeleton):
        with pytest.raises(InputError, match=message) as e:
            reader(path)
        assert e.value.path == path and e.value.field == field
        assert str(e.value).startswith(f"{path}: {field}: ")
    if "armature_scale" in kw:  # a mocap-only reading (no skin) is not refused for a scale above it
        clip = read_gltf_animation(path, skin=None)
        assert "Armature" not in clip.joint_names


# ---------------------------------------------------------------------------------- bad input
def test_a_file_without_skin_is_not_a_character(tmp_path, capsys):
    path = gltf_reference.write_figure(tmp_path / "statue.glb", skin=False)
    with pytest.raises(InputError, match=r"no skin \(it holds .*0 skin\(s\).*a character needs a skinned mesh") as e:
        read_gltf_character(path)
    assert e.value.path == path and e.value.field == "skins"
    with pytest.raises(InputError, match="has no skin: give a skeleton"):
        load_character(path)
    code = main(["bake", "--character", path, "--out", str(tmp_path / "o"), "--formats", "npz"])
    err = capsys.readouterr().err
    assert code == 2 and "statue.glb" in err and "no skin" in err and "Traceback" not in err, err


def test_a_skin_without_animation_when_one_is_asked(tmp_path, capsys):
    path = gltf_reference.write_figure(tmp_path / "still.glb", animate=False)
    read_gltf_character(path)  # a character it is
    with pytest.raises(InputError, match=r"no animation \(it holds .*1 skin\(s\), 0 animation") as e:
        read_gltf_animation(path)
    assert e.value.path == path and e.value.field == "animations"
    code = main(["bake", "--character", path, "--out", str(tmp_path / "o"), "--formats", "npz"])
    err = capsys.readouterr().err
    assert code == 2 and "still.glb" in err and "no animation" in err and "Traceback" not in err, err


def test_an_animation_name_not_found_lists_the_animations(tmp_path):
    path = gltf_reference.write_figure(tmp_path / "f.glb")
    with pytest.raises(InputError, match=r"no animation named 'walk'; the file has 0: 'wave'") as e:
        read_gltf_animation(path, "walk")
    assert e.value.path == path and e.value.field == "animation"


def test_channels_on_nodes_outside_the_skeleton_are_ignored_with_a_warning(tmp_path):
    """Decision: an animation may also move a prop, a camera or another character; the skeleton's
    clip ignores those channels and says so (an error would refuse ordinary scenes)."""
    path = gltf_reference.write_figure(tmp_path / "prop.glb", prop=True)
    with pytest.warns(JiggleWarning, match=r"drives 1 node\(s\) that are not joints of skin 0 .*'Prop' \(translation\)"):
        clip = read_gltf_animation(path)
    plain = read_gltf_animation(gltf_reference.write_figure(tmp_path / "plain.glb"))
    np.testing.assert_allclose(clip.world()[1], plain.world()[1], atol=1e-12)
    assert read_gltf_animation(path, skin=None).joint_names[-1] == "Prop"  # mocap reading: every animated node


@pytest.mark.parametrize("times, message", [
    ((0.0, float("nan"), 1.0), r"key time 1 is nan; key times must be finite"),
    ((0.0, 0.5, 0.5), r"increase strictly .* key 2 is at 0.5 s after key 1 at 0.5 s"),
    ((0.0, 0.7, 0.5), r"increase strictly .* key 2 is at 0.5 s after key 1 at 0.7 s"),
    ((-0.5, 0.0, 0.5), r"first key time is -0.5 s; glTF key times start at or after 0"),
])
def test_bad_key_times_name_the_accessor(tmp_path, times, message):
    path = gltf_reference.write_figure(tmp_path / "keys.glb", key_times=times)
    with pytest.raises(InputError, match=message) as e:
        read_gltf_animation(path)
    assert e.value.path == path
    assert e.value.field.startswith("animations[0].samplers[0].input (accessors[")


def _mutated_cesium(tmp_path, name, change):
    """CesiumMan's GLB with its JSON changed by `change(doc)`, written to tmp_path/name."""
    import copy
    import json
    import struct

    from conftest import asset
    data = open(asset("characters/CesiumMan.glb"), "rb").read()
    jlen = struct.unpack("<I", data[12:16])[0]
    doc = copy.deepcopy(json.loads(data[20:20 + jlen]))
    rest = data[20 + jlen:]
    change(doc)
    j = json.dumps(doc).encode()
    j += b" " * ((4 - len(j) % 4) % 4)
    p = tmp_path / name
    p.write_bytes(struct.pack("<III", 0x46546C67, 2, 20 + len(j) + len(rest)) + struct.pack("<II", len(j), 0x4E4F534A)
                  + j + rest)
    return str(p)


@pytest.mark.parametrize("case, change, field, says", [
    ("indices", lambda d: d["meshes"][0]["primitives"][0].__setitem__("indices", 999),
     "meshes[0].primitives[0].indices", "999: past the 83 accessors"),
    ("joint", lambda d: d["skins"][0]["joints"].__setitem__(0, 999), "skins[0].joints[0]", "past the 22 nodes"),
    ("view", lambda d: d["accessors"][0].__setitem__("bufferView", 999), "accessors[0].bufferView",
     "past the 9 bufferViews"),
    ("sampler", lambda d: d["animations"][0]["channels"][0].__setitem__("sampler", 99),
     "animations[0].channels[0].sampler", "past the"),
    ("count", lambda d: d["accessors"][0].__setitem__("count", d["accessors"][0]["count"] * 1000), "accessors[0]",
     "reads"),
    ("float", lambda d: d["nodes"][0].__setitem__("mesh", 0.5), "nodes[0].mesh", "is not an index"),
])
def test_every_index_and_byte_range_is_checked_before_use(tmp_path, capsys, case, change, field, says):
    """A dangling index anywhere in the JSON, or an accessor reading past its buffer, is exit 2 naming the
    JSON path, from inspect and from bake alike: no IndexError from deep inside a reader."""
    from jiggle.sim.app.cli import main
    path = _mutated_cesium(tmp_path, f"{case}.glb", change)
    for argv in (["inspect", path], ["bake", "--character", path, "--frames", "2", "--formats", "npz",
                                     "--out", str(tmp_path / "out")]):
        code = main(argv)
        err = capsys.readouterr().err
        assert code == 2 and "Traceback" not in err and f"{field}: " in err and says in err, err


@pytest.mark.parametrize("turn", [-90.0, 0.0])
def test_inspect_measures_the_skin_the_bake_reads(tmp_path, capsys, turn):
    """A centimetre skin under an armature node scaled by 0.01 (Blender's and Maya's export), a second skinned
    mesh on a node with a transform of its own: `jiggle inspect` gives the height and bounds of the skin as
    glTF's skinning rule places it, the character the bake reads (and the independent reference), so its unit
    hint is about that skin; before, it placed each mesh by its node and reported 2.18 m for this 1.67 m figure."""
    path = gltf_reference.write_figure(tmp_path / "f.glb", armature_turn_deg=turn)
    c, _ = read(path)
    ref = gltf_reference.skinned_vertices(path, None)
    assert main(["inspect", str(path), "--json"]) == 0
    seen = json.loads(capsys.readouterr().out)
    assert seen["height_m"] == pytest.approx(c.height, abs=1e-4) == pytest.approx(np.ptp(ref[:, 2]), abs=1e-4)
    np.testing.assert_allclose(seen["bounds_m"], np.r_[c.vertices.min(0), c.vertices.max(0)], atol=1e-4)
    assert seen["unit"].startswith("metres") if turn == -90.0 else "unknown" not in seen["unit"]
