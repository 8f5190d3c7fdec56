"""FBX's node tree (rig/motion/fbx_tree.py) and FBX 6 lifted to 7 (rig/motion/fbx_legacy.py), without Blender:
binary read and written back unchanged, ASCII read with the types binary has, 6.x key lists read in each of their
layouts, and broken text refused naming the line."""
from __future__ import annotations

import numpy as np
import pytest
from conftest import asset
from fbx_text import KTIME, ascii_fbx, bar_fbx61

from jiggle.rig.base.errors import InputError
from jiggle.rig.motion.fbx_legacy import _keys, lift
from jiggle.rig.motion.fbx_tree import Node, read_tree, split_name, write_binary


def same(a: list[Node], b: list[Node], where: str = "") -> None:
    """Assert two trees are equal: names, types and values (arrays exactly; char values, which ASCII spells as
    letters, by type only)."""
    assert [n.name for n in a] == [n.name for n in b], where
    for x, y in zip(a, b):
        here = f"{where}/{x.name}"
        assert x.types == y.types, (here, x.types, y.types, x.props[:6], y.props[:6])
        for u, v, t in zip(x.props, y.props, x.types):
            if t == "C":
                continue
            if isinstance(u, np.ndarray):
                assert u.dtype == v.dtype and np.array_equal(u, v), here
            else:
                assert u == v, (here, u, v)
        same(x.children, y.children, here)


def test_binary_fbx_reads_back_the_same_after_writing(tmp_path):
    """Maya's FBX 7.7 (64-bit record offsets, compressed arrays) read, written as FBX 7.4 and read again: the same
    tree, value for value (the written file is a different size: 32-bit offsets)."""
    src = asset("characters/fbx/maya_kenney_character_7700_binary.fbx")
    nodes, version, is_ascii = read_tree(str(src))
    assert version == 7700 and not is_ascii and [n.name for n in nodes][:2] == ["FBXHeaderExtension", "FileId"]
    out = tmp_path / "again.fbx"
    out.write_bytes(write_binary(nodes))
    again, v2, _ = read_tree(str(out))
    assert v2 == 7400
    same(nodes, again)


@pytest.mark.parametrize("name", ["maya_kenney_character_7700_binary.fbx", "maya_human_ik_7400_binary.fbx",
                                  "CesiumMan_blender5.fbx"])
def test_ascii_fbx_reads_as_the_binary_file_it_was_written_from(tmp_path, name):
    """A binary FBX written as ASCII in the FBX SDK's layout and read back is the binary file's tree: every value
    with the type the binary file gives it (the types ASCII does not carry come from where the value sits)."""
    nodes, version, _ = read_tree(str(asset(f"characters/fbx/{name}")))
    text = tmp_path / "a.fbx"
    text.write_text(ascii_fbx(nodes, version))
    back, v2, is_ascii = read_tree(str(text))
    assert is_ascii and v2 == version
    nodes = [n for n in nodes if n.name != "FileId"]               # not in ASCII files
    for n in nodes + back:      # HumanIK's solver settings: numbers Maya types as it likes, which nobody reads
        if n.name == "Objects":
            n.children = [c for c in n.children if c.name != "Constraint"]
    same(nodes, back)


def test_fbx61_key_lists_in_each_layout():
    """FBX 6 keys are time, value, mode and the mode's parameters: cubic (`U`) with slopes and weights, linear
    (`L`), constant (`C` and a next/previous letter from KeyVer 4004); times and values read, parameters skipped."""
    def channel(keys, count, ver=4005):
        return Node("Channel", ["X"], "S", [Node("KeyVer", [ver], "I"), Node("KeyCount", [count], "I"),
                                            Node("Key", keys, "")])
    t, v = _keys(channel([0, 1.0, "U", "s", 0.5, 0.25, "n", KTIME, 2.0, "L", 2 * KTIME, 3.0, "C", "n"], 3), "x", "f")
    assert list(t) == [0, KTIME, 2 * KTIME] and list(v) == [1.0, 2.0, 3.0]
    t, v = _keys(channel([0, 1.0, "U", "a", "n", KTIME, 4.0, "U", "s", 0, 0, "a", 0.3, 0.3], 2), "x", "f")
    assert list(v) == [1.0, 4.0]
    t, v = _keys(channel([0, 1.0, "C", KTIME, 2.0, "L"], 2, ver=4003), "x", "f")       # no letter after C
    assert list(v) == [1.0, 2.0]
    t, v = _keys(channel([0, 1.0, ord("L"), KTIME, 2.0, ord("L")], 2), "x", "f")          # binary: char codes
    assert list(v) == [1.0, 2.0]
    with pytest.raises(InputError, match="KeyCount says 3 keys, the list holds 2"):
        _keys(channel([0, 1.0, "L", KTIME, 2.0, "L"], 3), "take/bone/TX", "f")
    with pytest.raises(InputError, match="ends in the middle of a key"):
        _keys(channel([0, 1.0, "U", "s", 0.5], 1), "take/bone/TX", "f")
    with pytest.raises(InputError, match="unknown key mode 'Q'"):
        _keys(channel([0, 1.0, "Q"], 1), "take/bone/TX", "f")


def test_fbx61_is_lifted_into_fbx7s_object_model(tmp_path):
    """The FBX 6.1 bar (tests/fbx_text.py): numbered objects, the mesh's geometry split from its model and the skin
    hung on it, bones with node attributes, clusters with their matrices, the bind pose by id, and the take as a
    stack, a layer, curve nodes and curves carrying its keys (times in FBX time)."""
    text, _ = bar_fbx61()
    p = tmp_path / "bar.fbx"
    p.write_text(text)
    nodes, version, _ = read_tree(str(p))
    assert version == 6100
    out = lift(nodes, str(p))
    every = next(n for n in out if n.name == "Objects").children
    objs = {(o.name, split_name(o.props[1])[1]): o for o in every}
    key = {o.props[0]: (o.name, split_name(o.props[1])[1]) for o in every}
    links = {(key.get(c.props[1]), key.get(c.props[2], c.props[2])) + tuple(c.props[3:])
             for c in next(n for n in out if n.name == "Connections").children}
    assert objs[("Model", "bar")].props[2] == "Mesh" and objs[("Model", "tip")].props[2] == "LimbNode"
    assert (("Geometry", "bar"), ("Model", "bar")) in links
    assert (("Deformer", "Skin bar"), ("Geometry", "bar")) in links               # on the geometry, as in FBX 7
    assert (("Model", "tip"), ("Model", "root")) in links and (("Model", "root"), 0) in links
    assert (("Model", "tip"), ("Deformer", "Cluster tip")) in links
    cluster = objs[("Deformer", "Cluster tip")]
    assert cluster.find("TransformLink").types == "d" and cluster.find("TransformLink").props[0][13] == 1.0
    assert list(cluster.find("Indexes").props[0]) == [4, 5, 6, 7, 8, 9, 10, 11]
    assert objs[("Geometry", "bar")].find("Vertices").props[0].shape == (36,)
    curves = [o for o in every if o.name == "AnimationCurve"]
    assert sorted(len(c.find("KeyTime").props[0]) for c in curves) == [1, 2, 3]
    bend = next(c for c in curves if list(c.find("KeyValueFloat").props[0]) == [0.0, 90.0])
    assert list(bend.find("KeyTime").props[0]) == [0, KTIME]
    node_of = {c.props[1]: c for c in next(n for n in out if n.name == "Connections").children if c.props[0] == "OP"}
    assert node_of[bend.props[0]].props[3] == "d|Z"
    rnode = node_of[bend.props[0]].props[2]
    assert node_of[rnode].props[3] == "Lcl Rotation" and key[node_of[rnode].props[2]] == ("Model", "tip")
    assert next(o for o in every if o.name == "AnimationStack").props[1].startswith("bend")
    roundtrip, v2, _ = read_tree(str(_written(tmp_path, out)))
    same(out, roundtrip)


def _written(tmp_path, nodes):
    p = tmp_path / "lifted.fbx"
    p.write_bytes(write_binary(nodes))
    return p


@pytest.mark.parametrize("text, says", [
    ("; FBX 7.4.0 project file\nObjects:  {\n\tModel: 1, \"Model::a\", \"Null\" {\n", "never closed"),
    ("; FBX 7.4.0 project file\nObjects:  {\n}\n}\n", "closes nothing"),
    ("; FBX 7.4.0 project file\nGeometry: 1, \"Geometry::g\", \"Mesh\" {\n\tVertices: *4 {\n\t\ta: 1,2,3\n\t}\n}\n",
     "says \\*4 values and holds 3"),
    ("; FBX 7.4.0 project file\nA: 1 @ 2\n", "unexpected text"),
])
def test_broken_ascii_fbx_is_refused_naming_the_line(tmp_path, text, says):
    p = tmp_path / "broken.fbx"
    p.write_text(text)
    with pytest.raises(InputError, match=says) as e:
        read_tree(str(p))
    assert "line" in str(e.value) and "broken.fbx" in str(e.value)


def test_truncated_binary_fbx_is_refused_naming_the_byte(tmp_path):
    src = asset("characters/fbx/maya_kenney_character_7700_binary.fbx").read_bytes()
    p = tmp_path / "cut.fbx"
    p.write_bytes(src[:len(src) // 3])
    with pytest.raises(InputError, match="cut short or corrupt"):
        read_tree(str(p))
