"""jiggle's skinning of glTF characters against a real client: Blender (the `bpy` wheel, extra
`blender`), which imports the same file, plays the same animation and gives its evaluated meshes.

Blender runs in a subprocess (its own interpreter: the bpy wheels pin numpy < 2, so ./dev.sh installs
them in .venv/blender; JIGGLE_BPY_PYTHON names another interpreter), so a crash in Blender does not
take pytest down and its global state stays out of the test process.

What is compared, per file, within 1e-4 of the character's height:
- the rest skin: Blender's bind-pose mesh (object data in world space) is jiggle's rest skin (every
  Blender vertex has a jiggle vertex there; Blender drops unused vertices and may reorder, so the
  vertices are matched by rest position);
- the posed skin at three key times of the file's first animation: Blender's evaluated mesh
  (depsgraph, armature modifier, world matrix) is jiggle's LBS posed by the clip read from the file.
  Key times and midpoints between keys, because between keys Blender interpolates each quaternion
  component of a rotation linearly (then normalises), where the spec says slerp and jiggle slerps;
  the two agree at keys and half-way (RiggedFigure a quarter of the way between its two keys: 0.8 mm
  apart).
Both worlds are Z-up metres: Blender's importer turns glTF's Y-up (x, y, z) into (x, -z, y), which is
rig.motion.gltf_io.Z_UP.

Known difference, not tested here: a uniform scale on a joint's own node (not an armature above the
skeleton). At the rest pose every joint matrix G_k @ IBM_k of tests/gltf_reference.write_figure with
spine_scale=1.1 is the armature's transform, so the spec's skin is the file's mesh placed by the
armature, as jiggle gives (tests/character/test_gltf_read.py); Blender 5.0.1 drops the joint's rest
scale from its bind pose and the skin moves up to 4 cm.
"""
from __future__ import annotations

import functools
import json
import os
import subprocess
import sys
import warnings
from pathlib import Path

import gltf_reference
import numpy as np
import pygltflib
import pytest
from conftest import asset
from scipy.spatial import cKDTree

from jiggle.rig.base.errors import JiggleWarning
from jiggle.rig.character.gltf_character import read_gltf_character
from jiggle.rig.motion.clip import transforms
from jiggle.rig.motion.gltf_anim import read_gltf_animation
from jiggle.rig.skin.skinning import pose_character

ROOT = Path(__file__).resolve().parents[2]

BLENDER_SCRIPT = r'''
import json
import sys

import bpy
import numpy as np

glb, out, times = sys.argv[-3], sys.argv[-2], json.loads(sys.argv[-1])
bpy.ops.wm.read_factory_settings(use_empty=True)
scene = bpy.context.scene
scene.render.fps, scene.render.fps_base = 24, 1.0  # the importer keys frame = seconds * fps
bpy.ops.import_scene.gltf(filepath=glb, merge_vertices=False)
skinned = sorted((o for o in scene.objects if o.type == "MESH" and any(m.type == "ARMATURE" for m in o.modifiers)),
                 key=lambda o: o.name)
arms = [o for o in scene.objects if o.type == "ARMATURE"]
info = {"version": bpy.app.version_string, "objects": [o.name for o in skinned],
        "actions": [a.animation_data.action.name if a.animation_data and a.animation_data.action else None
                    for a in arms]}


def placed(mesh, obj):
    co = np.empty(len(mesh.vertices) * 3)
    mesh.vertices.foreach_get("co", co)
    m = np.array(obj.matrix_world)
    return co.reshape(-1, 3) @ m[:3, :3].T + m[:3, 3]


bpy.context.view_layer.update()
rest = np.concatenate([placed(o.data, o) for o in skinned])  # the bind-pose mesh
posed = []
for t in times:
    f = t * scene.render.fps / scene.render.fps_base
    scene.frame_set(int(np.floor(f)), subframe=float(f - np.floor(f)))
    dg = bpy.context.evaluated_depsgraph_get()
    frame = []
    for o in skinned:
        ev = o.evaluated_get(dg)
        frame.append(placed(ev.to_mesh(), ev))
        ev.to_mesh_clear()
    posed.append(np.concatenate(frame))
np.savez(out, rest=rest, posed=np.stack(posed), info=json.dumps(info))
'''


@functools.lru_cache(maxsize=1)
def bpy_python() -> str | None:
    """An interpreter that imports bpy: JIGGLE_BPY_PYTHON, this one, or ./dev.sh's .venv/blender."""
    env = os.environ.get("JIGGLE_BPY_PYTHON")
    for py in [env] if env else [sys.executable, str(ROOT / ".venv" / "blender" / "bin" / "python")]:
        if not py or not os.path.exists(py):
            continue
        try:
            ok = subprocess.run([py, "-c", "import bpy"], capture_output=True, timeout=300).returncode == 0
        except (OSError, subprocess.TimeoutExpired):
            ok = False
        if ok:
            return py
    return None


pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(bpy_python() is None, reason="bpy (Blender as a Python module) is not installed: "
                                 "./dev.sh install puts it in .venv/blender (extra 'blender'), or set "
                                 "JIGGLE_BPY_PYTHON")]


def blender_pose(path, times, tmp_path) -> tuple[np.ndarray, np.ndarray, dict]:
    """Blender's rest skin (V', 3), posed skins (T, V', 3) in world space, metres, and what it imported."""
    script, out = tmp_path / "blender_pose.py", tmp_path / "blender.npz"
    script.write_text(BLENDER_SCRIPT)
    r = subprocess.run([bpy_python(), str(script), str(path), str(out), json.dumps([float(t) for t in times])],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0 and out.exists(), r.stdout[-2000:] + r.stderr[-2000:]
    d = np.load(out)
    return d["rest"], d["posed"], json.loads(str(d["info"]))


def key_times(path, n: int = 3) -> list[float]:
    """n times of the first animation where Blender's interpolation and the spec's agree: key times
    and midpoints between neighbouring keys (there the normalised lerp of two quaternions is their slerp)."""
    g = pygltflib.GLTF2().load(str(path))
    blob = g.binary_blob()
    keys = set()
    for s in g.animations[0].samplers:
        a = g.accessors[s.input]
        bv = g.bufferViews[a.bufferView]
        keys.update(np.frombuffer(blob, "<f4", a.count, (bv.byteOffset or 0) + (a.byteOffset or 0)).tolist())
    keys = np.array(sorted(keys))
    # Not the last key: a clip ends on the last whole frame at or before it (rig.motion.gltf_anim).
    cand = np.sort(np.r_[keys[:-1], (keys[1:] + keys[:-1]) / 2])
    pick = np.unique(np.round(np.array([0.3, 0.55, 0.8])[:n] * (len(cand) - 1)).astype(int))
    return [float(cand[i]) for i in pick]


def compare_with_blender(path, tmp_path, times=None) -> dict:
    """Assert Blender's rest and posed skins equal jiggle's; returns the largest differences."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", JiggleWarning)
        c = read_gltf_character(path)
        clip = read_gltf_animation(path)
    times = key_times(path) if times is None else times
    rest, posed, info = blender_pose(path, times, tmp_path)
    tol = 1e-4 * c.height
    dist, idx = cKDTree(c.vertices).query(rest)
    assert dist.max() < tol, f"Blender's bind-pose skin is {dist.max():.3g} m from jiggle's rest skin"
    back, _ = cKDTree(rest).query(c.vertices)
    assert back.max() < tol, "every jiggle vertex has a Blender vertex there"
    order = [clip.joint_names.index(n) for n in c.joint_names]
    errs = []
    for k, t in enumerate(times):
        world = transforms(*clip.world(*clip.sample(np.array([t - clip.meta["start_time"]]))))[0][order]
        ours = pose_character(c, world)
        errs.append(float(np.abs(ours[idx] - posed[k]).max()))
        assert errs[-1] < tol, f"{path} at {t} s: jiggle vs Blender {errs[-1]:.3g} m (tolerance {tol:.3g} m)"
    assert np.abs(posed - rest).max() > 0.03 * c.height, "the poses must move the skin"
    report = {"blender": info["version"], "height_m": round(c.height, 4), "rest_m": float(dist.max()),
              "posed_m": errs, "times_s": times, "blender_bounds_m": rest.min(0).tolist() + rest.max(0).tolist()}
    print(f"{Path(path).name}: {report}")
    return report


@pytest.mark.parametrize("name", ["CesiumMan", "RiggedFigure"])
def test_shared_characters_agree_with_blender(name, tmp_path):
    compare_with_blender(asset(f"characters/{name}.glb"), tmp_path)


@pytest.mark.parametrize("turn", [-90.0, 0.0])
def test_centimetre_armature_agrees_with_blender(tmp_path, turn):
    """The Blender/Maya centimetre export (armature scale 0.01, turned about X), a second skinned mesh
    on a node with its own transform, a node in the tree outside the skin and a joint without weight:
    Blender's skin is jiggle's, in metres, 1.67 m tall."""
    path = gltf_reference.write_figure(tmp_path / "figure.glb", armature_turn_deg=turn, spine_scale=1.0)
    report = compare_with_blender(path, tmp_path, times=[0.0, 0.5, 1.0])
    assert report["height_m"] == pytest.approx(1.67 if turn == -90.0 else 0.28, abs=1e-3)
    # `jiggle inspect` measures the skin Blender imports (not the mesh nodes placed by their own transforms)
    from jiggle.sim.app.outputs.inspect import inspect_file
    seen = inspect_file(str(path))
    np.testing.assert_allclose(seen["bounds_m"], report["blender_bounds_m"], atol=1e-3)
    assert seen["height_m"] == pytest.approx(report["blender_bounds_m"][5] - report["blender_bounds_m"][2], abs=1e-3)


def test_written_character_agrees_with_blender(tmp_path):
    """CesiumMan as jiggle writes it (rig.character.gltf_write, with its animation) plays in Blender as
    jiggle plays it."""
    from jiggle.rig.character.gltf_write import write_character
    src = asset("characters/CesiumMan.glb")
    c, clip = read_gltf_character(src), read_gltf_animation(src)
    kw = {"animations": {"walk": clip}}
    try:
        path = write_character(c, tmp_path / "man.glb", source=src, **kw)
    except TypeError:  # a writer without animations: Blender then checks the rest skin only
        pytest.skip("rig.character.gltf_write.write_character does not write animations")
    compare_with_blender(path, tmp_path)
