"""Marker sets (rig.anatomy.markers): found on any humanoid from its roles, written and read back, and every
kind of bad marker file refused with its file, marker and line."""
from __future__ import annotations

import numpy as np
import pytest
from conftest import asset

from jiggle.rig.anatomy.markers import HUMAN, WIDTHS, find_markers, read_markers, write_markers
from jiggle.rig.base.errors import InputError


@pytest.fixture(scope="module")
def cesium_markers():
    from jiggle.rig.character.load import load_character
    from jiggle.rig.motion.role_map import resolve_roles
    from jiggle.rig.muscle.segmentation import bone_segments
    c = load_character(asset("characters/CesiumMan.glb"))
    roles = resolve_roles(c.skeleton)
    return c, find_markers(c.vertices, c.faces, roles, c.bind_positions, bone_segments(c))


def test_markers_sit_where_their_names_say(cesium_markers):
    c, ms = cesium_markers
    assert ms.names == tuple(s.name for s in HUMAN) and len(set(ms.vertex)) == len(ms.names)
    p = dict(zip(ms.names, ms.positions))
    np.testing.assert_allclose(ms.positions, c.vertices[ms.vertex])
    H = c.height
    assert p["head_top"][2] > c.vertices[:, 2].max() - 0.03 * H                  # the top of the head
    assert p["left_toe"][2] < 0.05 * H and p["left_toe"][1] < -0.1               # the front of the foot (front = -Y)
    assert p["navel"][1] < 0 < p["lower_back"][1]                               # front and back
    assert p["left_waist"][0] > 0 > p["right_waist"][0]                          # left = +X
    assert p["left_hand_tip"][0] > p["left_wrist"][0] > p["left_elbow"][0] > p["left_shoulder"][0]
    assert p["left_knee"][2] < p["left_thigh_front"][2] < p["left_hip"][2]
    # left and right are mirror images on this symmetric character, to a few centimetres
    for n in ms.names:
        if n.startswith("left_"):
            q = p["right_" + n[5:]]
            assert abs(p[n][0] + q[0]) < 0.03 and abs(p[n][2] - q[2]) < 0.03, n
    for _, a, b, _, _ in WIDTHS:
        assert np.linalg.norm(p[a] - p[b]) > 0.02


def test_marker_file_round_trip(tmp_path, cesium_markers):
    _, ms = cesium_markers
    f = write_markers(tmp_path / "m.toml", ms.names, ms.positions, source="CesiumMan.glb")
    got = read_markers(f, ms.names)
    np.testing.assert_allclose(np.stack([got[n] for n in ms.names]), ms.positions, atol=1e-6)
    cm = tmp_path / "cm.json"
    cm.write_text('{"unit": "cm", "markers": {"a": [100, 0, 50], "b": [0, 1, 2]}}')
    got = read_markers(cm, ["a", "b"])
    np.testing.assert_allclose(got["a"], [1.0, 0.0, 0.5])


def _file(tmp_path, body: str):
    f = tmp_path / "t.toml"
    f.write_text("[markers]\n" + body)
    return f


def test_bad_marker_files(tmp_path):
    names = ["a", "b"]
    with pytest.raises(InputError, match=r"t\.toml:3.*unknown marker 'c'.*a, b"):
        read_markers(_file(tmp_path, "a = [0, 0, 0]\nc = [1, 1, 1]\nb = [0, 0, 1]\n"), names)
    with pytest.raises(InputError, match="missing markers: b"):
        read_markers(_file(tmp_path, "a = [0, 0, 0]\n"), names)
    with pytest.raises(InputError, match=r"t\.toml:3.*marker 'b'.*three finite numbers"):
        read_markers(_file(tmp_path, "a = [0, 0, 0]\nb = [0, nan, 1]\n"), names)
    with pytest.raises(InputError, match=r"marker 'b'.*three finite numbers"):
        read_markers(_file(tmp_path, "a = [0, 0, 0]\nb = [0, 1]\n"), names)
    with pytest.raises(InputError, match=r"marker 'a'.*three finite numbers"):
        read_markers(_file(tmp_path, "a = [0, inf, 0]\nb = [0, 1, 2]\n"), names)
    with pytest.raises(InputError, match="not valid TOML"):
        read_markers(_file(tmp_path, "a = [0, 0\n"), names)
    with pytest.raises(InputError, match="unit"):
        f = tmp_path / "u.toml"
        f.write_text('unit = "furlong"\n[markers]\na = [0, 0, 0]\nb = [0, 0, 0]\n')
        read_markers(f, names)
    with pytest.raises(InputError, match="expected a \\[markers\\] table"):
        f = tmp_path / "e.toml"
        f.write_text('a = [0, 0, 0]\n')
        read_markers(f, names)
    with pytest.raises(InputError, match="not found"):
        read_markers(tmp_path / "none.toml", names)
    with pytest.raises(InputError, match="NaN"):
        write_markers(tmp_path / "w.toml", names, np.array([[0, 0, 0], [np.nan, 0, 0]]))
    assert not (tmp_path / "w.toml").exists()
