"""Painted maps read with the character (rig/character/painted_maps.py, gltf_character.py, load.py) and
written as a starting point (rig/character/gltf_maps.py, `jiggle fit`), and the round trip through a
real painting tool: Blender (the `bpy` extra, skipped without it) imports the copy `jiggle fit` wrote,
sets the _JIGGLE attribute on some vertices as a painter would, exports with attributes, and jiggle
reads the same values back.
"""
from __future__ import annotations

import contextlib
import io
import json
import subprocess
import warnings

import numpy as np
import pygltflib
import pytest
from conftest import asset
from scipy.spatial import cKDTree

from jiggle.rig.base.errors import InputError, JiggleWarning
from jiggle.rig.character.gltf_write import write_character
from jiggle.rig.character.load import load_character
from jiggle.rig.character.painted_maps import PaintedMaps, read_maps, save_maps
from jiggle.rig.muscle.simple_arm import simple_arm


@pytest.fixture(scope="module")
def arm_char():
    return simple_arm(rings=16, around=12).character


def quiet_load(path, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", JiggleWarning)
        return load_character(path, **kw)


def ramp(c):
    """(V,) in [0, 1]: the height along the arm, a map with every value different."""
    z = c.vertices[:, 2]
    return ((z - z.min()) / np.ptp(z)).astype(np.float32)


def set_accessor(path, out, attr, values, component=5126, normalized=False, kind="SCALAR"):
    """Copy glTF `path` to `out` with attribute `attr` of its first primitive set to `values` stored
    as `component` (5126 float, 5121 ubyte, 5123 ushort) of type `kind`."""
    g = pygltflib.GLTF2().load(str(path))
    blob = bytearray(g.binary_blob())
    dtype = {5126: "<f4", 5121: "u1", 5123: "<u2"}[component]
    data = np.ascontiguousarray(values).astype(dtype).tobytes()
    blob += b"\0" * (-len(blob) % 4)
    g.bufferViews.append(pygltflib.BufferView(buffer=0, byteOffset=len(blob), byteLength=len(data)))
    blob += data + b"\0" * (-len(data) % 4)
    n = len(values)
    g.accessors.append(pygltflib.Accessor(bufferView=len(g.bufferViews) - 1, componentType=component, count=n,
                                          type=kind, normalized=normalized or None))
    setattr(g.meshes[0].primitives[0].attributes, attr, len(g.accessors) - 1)
    g.buffers[0].byteLength = len(blob)
    g.set_binary_blob(bytes(blob))
    g.save_binary(str(out))
    return out


# ---------------------------------------------------------------------------------- glTF attributes
def test_gltf_attributes_are_read_with_the_character(arm_char, tmp_path):
    j = ramp(arm_char)
    p = write_character(arm_char, tmp_path / "arm.glb", attributes={"_JIGGLE": j, "_SHELL_BICEPS": 1 - j})
    c = quiet_load(p)
    assert c.maps is not None and np.array_equal(c.maps.jiggle, j)
    assert list(c.maps.influence) == ["biceps"] and np.array_equal(c.maps.influence["biceps"], 1 - j)
    # no attribute, no sidecar: no maps
    assert quiet_load(write_character(arm_char, tmp_path / "plain.glb")).maps is None


@pytest.mark.parametrize("component, scale", [(5121, 255), (5123, 65535)])
def test_normalized_integer_attribute(arm_char, tmp_path, component, scale):
    j = ramp(arm_char)
    plain = write_character(arm_char, tmp_path / "plain.glb")
    p = set_accessor(plain, tmp_path / "int.glb", "_JIGGLE", np.round(j * scale), component, normalized=True)
    c = quiet_load(p)
    assert np.abs(c.maps.jiggle - j).max() <= 0.5 / scale + 1e-7


def test_jiggle_map_from_a_colour_channel(arm_char, tmp_path):
    j = ramp(arm_char)
    rgba = np.stack([np.zeros_like(j), j, np.ones_like(j), np.ones_like(j)], 1)
    plain = write_character(arm_char, tmp_path / "plain.glb")
    p = set_accessor(plain, tmp_path / "col.glb", "COLOR_0", rgba, kind="VEC4")
    assert quiet_load(p).maps is None                                   # colours are not read unasked
    assert np.allclose(quiet_load(p, jiggle_attribute="COLOR_0.g").maps.jiggle, j)
    with pytest.raises(InputError, match="jiggle_attribute"):
        quiet_load(p, jiggle_attribute="COLOR_0.x")


@pytest.mark.parametrize("case", ["range", "nan", "count", "type", "unnormalized"])
def test_bad_gltf_maps_name_the_file_and_attribute(arm_char, tmp_path, case):
    V = arm_char.num_vertices
    plain = write_character(arm_char, tmp_path / "plain.glb")
    values, component, normalized, kind = np.full(V, 0.5), 5126, False, "SCALAR"
    if case == "range":
        values[3] = 1.5
    elif case == "nan":
        values[3] = np.nan
    elif case == "count":
        values = values[:-1]
    elif case == "type":
        values, kind = np.full((V, 2), 0.5), "VEC2"
    else:
        values, component = np.full(V, 1), 5121
    p = set_accessor(plain, tmp_path / "bad.glb", "_JIGGLE", values, component, normalized, kind)
    with pytest.raises(InputError) as e:
        quiet_load(p)
    msg = str(e.value)
    assert "bad.glb" in msg and "_JIGGLE" in msg
    if case in ("range", "nan"):
        assert "vertex 3" in msg and "[0, 1]" in msg


# ---------------------------------------------------------------------------------- sidecars
def test_npz_sidecar(arm_char, tmp_path):
    j = ramp(arm_char)
    p = write_character(arm_char, tmp_path / "arm.glb")
    np.savez(tmp_path / "arm.jiggle_map.npz", jiggle=j)          # the least a user writes by hand
    c = quiet_load(p)
    assert np.array_equal(c.maps.jiggle, j) and not c.maps.influence
    save_maps(tmp_path / "arm.jiggle_map.npz", PaintedMaps(jiggle=1 - j, influence={"biceps": j}), len(j))
    c = quiet_load(p)
    assert np.array_equal(c.maps.jiggle, 1 - j) and np.array_equal(c.maps.influence["biceps"], j)


def test_ply_sidecar(arm_char, tmp_path):
    j = ramp(arm_char)
    p = write_character(arm_char, tmp_path / "arm.glb")
    v = arm_char.vertices
    head = ("ply\nformat ascii 1.0\nelement vertex %d\nproperty float x\nproperty float y\nproperty float z\n"
            "property float quality\nproperty float shell_biceps\nelement face 0\n"
            "property list uchar int vertex_indices\nend_header\n" % len(v))
    (tmp_path / "arm.jiggle_map.ply").write_text(head + "".join(f"{a} {b} {c} {q!r} {1 - q!r}\n"
                                                                for (a, b, c), q in zip(v, j.tolist())))
    c = quiet_load(p)
    assert np.allclose(c.maps.jiggle, j) and np.allclose(c.maps.influence["biceps"], 1 - j)


def test_file_attribute_wins_over_the_sidecar(arm_char, tmp_path):
    j = ramp(arm_char)
    p = write_character(arm_char, tmp_path / "arm.glb", attributes={"_JIGGLE": j})
    np.savez(tmp_path / "arm.jiggle_map.npz", jiggle=1 - j, influence=j[:, None],
             influence_names=np.array(["biceps"]))
    with pytest.warns(JiggleWarning, match="sidecar are ignored"):
        c = load_character(p)
    assert np.array_equal(c.maps.jiggle, j) and np.array_equal(c.maps.influence["biceps"], j)


@pytest.mark.parametrize("bad, field", [({"jiggle": np.ones(5)}, "jiggle"),
                                        ({"jiggle": "range"}, "jiggle"),
                                        ({"other": np.ones(3)}, "jiggle"),
                                        ({"influence": "nonames"}, "influence_names")])
def test_bad_sidecars_are_input_errors(arm_char, tmp_path, bad, field):
    V = arm_char.num_vertices
    p = write_character(arm_char, tmp_path / "arm.glb")
    arrays = dict(bad)
    if isinstance(arrays.get("jiggle"), str):
        arrays["jiggle"] = np.full(V, 2.0)
    if isinstance(arrays.get("influence"), str):
        arrays["influence"] = np.ones((V, 1))
    np.savez(tmp_path / "arm.jiggle_map.npz", **arrays)
    with pytest.raises(InputError) as e:
        quiet_load(p)
    assert "arm.jiggle_map.npz" in str(e.value) and e.value.field == field


def test_bad_map_exits_2_from_the_cli(arm_char, tmp_path):
    from jiggle.sim.app.cli import main
    p = write_character(arm_char, tmp_path / "arm.glb", attributes={"_JIGGLE": np.full(arm_char.num_vertices, 1.5)})
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        code = main(["fit", str(p), "--out", str(tmp_path / "fit" / "m.toml"), "--no-render"])
    assert code == 2 and "_JIGGLE" in err.getvalue() and "arm.glb" in err.getvalue()


# ---------------------------------------------------------------------------------- fit's starting point
@pytest.fixture(scope="module")
def cesium_fit(tmp_path_factory):
    """`jiggle fit CesiumMan.glb` into a temporary folder: (folder, the character)."""
    from jiggle.sim.app.cli import main
    src = asset("characters/CesiumMan.glb")
    out = tmp_path_factory.mktemp("fit")
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["fit", str(src), "--out", str(out / "muscles.toml"), "--no-render"]) == 0
    return out, quiet_load(src)


@pytest.mark.slow
def test_fit_writes_a_starting_point_that_reads_back(cesium_fit):
    from jiggle.rig.muscle.fit import FitOptions, fit_musculature
    from jiggle.rig.skin.painted_maps import shell_regions
    out, c = cesium_fit
    painted = quiet_load(out / "CesiumMan.painted.glb")
    assert np.array_equal(painted.vertices, c.vertices) and np.array_equal(painted.faces, c.faces)
    assert np.array_equal(painted.maps.jiggle, np.ones(c.num_vertices, np.float32))
    mus = fit_musculature(c, "human", FitOptions())
    table = shell_regions(c, mus.rig, [m.spec.shell for m in mus.muscles])
    got = painted.maps.influence_table(mus.rig.names)
    assert np.array_equal(got, table)                       # float32 written, float32 read: exact
    side = read_maps(out / "CesiumMan.glb", c.num_vertices)   # the npz, as the sidecar of the original
    assert np.array_equal(side.influence_table(mus.rig.names), table)
    # a fall-off, not a 0/1 mask: the shells' envelope (C1 in position; CesiumMan's triangles are coarse
    # enough that one edge may span the whole fade, so this is not checked edge by edge)
    assert ((table > 0.0) & (table < 1.0)).sum() > 0.1 * (table > 0.0).sum()


# ---------------------------------------------------------------------------------- Blender
BLENDER_PAINT = r'''
import json
import sys

import bpy
import numpy as np

src, out, info_path = sys.argv[-3], sys.argv[-2], sys.argv[-1]
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.import_scene.gltf(filepath=src)
obj = next(o for o in bpy.context.scene.objects if o.type == "MESH")
mesh = obj.data
names = [a.name for a in mesh.attributes]
attr = mesh.attributes["_JIGGLE"]
n = len(mesh.vertices)
val = np.empty(n, np.float32)
attr.data.foreach_get("value", val)
co = np.empty(n * 3)
mesh.vertices.foreach_get("co", co)
co = co.reshape(-1, 3) @ np.array(obj.matrix_world)[:3, :3].T + np.array(obj.matrix_world)[:3, 3]
# the painter: no jiggle above the waist (world z > 0.8 m, Blender is Z-up), a soft 0.25 on the left arm
val[co[:, 2] > 0.8] = 0.0
val[co[:, 0] > 0.4] = 0.25
attr.data.foreach_set("value", val)
mesh.update()
bpy.ops.export_scene.gltf(filepath=out, export_format="GLB", export_attributes=True, export_animations=False)
json.dump({"attributes": names, "vertices": n, "version": bpy.app.version_string}, open(info_path, "w"))
'''


@pytest.mark.slow
def test_blender_paints_the_jiggle_map_and_jiggle_reads_it_back(cesium_fit, tmp_path):
    """Blender imports the copy `jiggle fit` wrote (every _JIGGLE / _SHELL_ attribute comes in as a
    point attribute), a script paints _JIGGLE, Blender exports with attributes (it splits and reorders
    vertices and writes attribute names in capitals), and jiggle reads the painted values: every vertex
    of the exported character is matched to jiggle's own vertex at the same rest position and its map
    value is what the painter set there, the unpainted ones 1 and the _SHELL_ maps as written."""
    from test_blender import bpy_python
    py = bpy_python()
    if py is None:
        pytest.skip("bpy (Blender as a Python module) is not installed: ./dev.sh install puts it in "
                    ".venv/blender (extra 'blender'), or set JIGGLE_BPY_PYTHON")
    out, c = cesium_fit
    script, exported, info = tmp_path / "paint.py", tmp_path / "painted_in_blender.glb", tmp_path / "info.json"
    script.write_text(BLENDER_PAINT)
    r = subprocess.run([py, str(script), str(out / "CesiumMan.painted.glb"), str(exported), str(info)],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0 and exported.exists(), r.stdout[-2000:] + r.stderr[-2000:]
    facts = json.loads(info.read_text())
    assert "_JIGGLE" in facts["attributes"] and sum(a.startswith("_SHELL_") for a in facts["attributes"]) == 28
    back = quiet_load(exported)
    dist, idx = cKDTree(c.vertices).query(back.vertices)
    assert dist.max() < 1e-4 * c.height, "every exported vertex is one of jiggle's"
    v = c.vertices[idx]
    want = np.ones(len(v), np.float32)
    want[v[:, 2] > 0.8] = 0.0
    want[v[:, 0] > 0.4] = 0.25
    assert np.array_equal(back.maps.jiggle, want)
    assert 0 < (want == 0).sum() < len(want) and (want == 0.25).any()
    painted = quiet_load(out / "CesiumMan.painted.glb")
    assert set(back.maps.influence) == set(painted.maps.influence)       # names back in capitals, matched
    for name, a in painted.maps.influence.items():
        assert np.array_equal(back.maps.influence[name], a[idx]), name
