"""FBX in (rig/motion/fbx.py): binary FBX 7.1+ read through Blender's importer as a glTF, against ground truth in
../shared/assets/characters/fbx (its README): Maya's own skinned meshes of the Kenney character at frames 4 and
9, CesiumMan exported to FBX by Blender against CesiumMan.glb and against Blender's evaluation of that FBX, a
skeleton-only HumanIK file read as a clip, and bad files refused in one line with exit code 2.

Blender is the `bpy` module ./dev.sh installs in .venv/blender (or JIGGLE_BPY_PYTHON / JIGGLE_BLENDER_EXE); the
tests skip, saying so, without it or without the shared FBX folder."""
from __future__ import annotations

import os
import subprocess
import warnings

import numpy as np
import pytest
from blender_eval import blender_frames
from conftest import asset
from scipy.spatial import cKDTree

from jiggle.rig.base.errors import JiggleWarning
from jiggle.rig.motion.clip import transforms
from jiggle.rig.skin.skinning import pose_character
from jiggle.sim.app.cli import main


@pytest.fixture(autouse=True)
def blender(tmp_path, monkeypatch):
    from jiggle.rig.motion.fbx import blender_command
    if blender_command("x.py") is None:
        pytest.skip("no Blender here (bpy in .venv/blender, JIGGLE_BPY_PYTHON or JIGGLE_BLENDER_EXE): FBX is read "
                    "through its importer")
    monkeypatch.setenv("JIGGLE_CACHE", str(tmp_path / "cache"))      # every test converts afresh


def read(path):
    from jiggle.rig.character.load import load_character
    from jiggle.rig.motion.mocap import load_clip
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", JiggleWarning)
        return load_character(path), load_clip(path)


def posed(c, clip, t: float) -> np.ndarray:
    """The character posed by its clip at animation time t (seconds of the file's own timeline)."""
    order = [clip.joint_names.index(n) for n in c.joint_names]
    world = transforms(*clip.world(*clip.sample(np.array([t - clip.meta["start_time"]]))))[0][order]
    return pose_character(c, world)


def maya_obj(path) -> np.ndarray:
    """(V, 3) of an OBJ Maya exported (centimetres, Y-up) in jiggle's world (metres, Z-up)."""
    v = np.array([[float(x) for x in ln.split()[1:4]] for ln in open(path) if ln.startswith("v ")])
    return np.column_stack([v[:, 0], -v[:, 2], v[:, 1]]) / 100.0


@pytest.mark.parametrize("form", ["binary", "ascii"])
@pytest.mark.parametrize("frame", [4, 9])
def test_kenney_matches_maya_at_its_frames(frame, form, tmp_path):
    """Maya's FBX 7.7 (centimetres, Y-up, 58 bones, one take at 24 fps) read and posed by jiggle at frame f (FBX
    time f / 24 s) is the mesh Maya exported at that frame, within 1e-4 of its height (measured: 1.2e-5 m,
    3e-6 of it): units, axes, bind pose, weights and the take all read as Maya has them. The vertices are
    compared as point sets (the glTF Blender writes splits them at UV seams: 1029 for Maya's 804). The same file
    written as ASCII FBX (the FBX SDK's layout, tests/fbx_text.py) reads the same."""
    src = asset("characters/fbx/maya_kenney_character_7700_binary.fbx")
    if form == "ascii":
        from fbx_text import ascii_fbx
        from jiggle.rig.motion.fbx_tree import read_tree
        nodes, version, _ = read_tree(str(src))
        src = tmp_path / "kenney_ascii.fbx"
        src.write_text(ascii_fbx(nodes, version))
    c, clip = read(src)
    assert clip.fps == 24.0 and clip.meta["format"] == "glTF" and c.source.endswith(".fbx")
    ref = maya_obj(asset(f"characters/fbx/maya_kenney_character_{frame}.obj"))
    ours = posed(c, clip, frame / 24.0)
    tol = 1e-4 * c.height
    assert cKDTree(ours).query(ref)[0].max() < tol and cKDTree(ref).query(ours)[0].max() < tol
    other = posed(c, clip, (frame + 1) / 24.0)
    assert cKDTree(other).query(ref)[0].max() > 100 * tol        # the frame is told apart from the next one


@pytest.mark.parametrize("form", ["ascii", "binary"])
def test_an_fbx61_character_poses_as_its_take_says(tmp_path, form, capsys):
    """An FBX 6.1 file (the skinned bar of tests/fbx_text.py, in Maya 2009's layout: named objects, inline
    geometry, Properties60, a take with cubic, linear and constant keys), as ASCII and as binary FBX 6.1: jiggle
    poses it at the take's key times where the bones put it (within 1e-6 m), and `jiggle inspect` gives its
    height (2 m) from the posed skin."""
    from fbx_text import bar_fbx61
    from jiggle.rig.motion.fbx_tree import read_tree, write_binary
    text, pose = bar_fbx61()
    src = tmp_path / "bar.fbx"
    src.write_text(text)
    if form == "binary":
        nodes, version, _ = read_tree(str(src))
        src.write_bytes(write_binary(nodes, version=6100))
        assert src.read_bytes()[:18] == b"Kaydara FBX Binary"
    c, clip = read(src)
    assert c.joint_names == ("root", "tip") and clip.fps == 24.0
    for t in (0.0, 0.5, 1.0):
        ours = posed(c, clip, t)
        assert cKDTree(ours).query(pose(t))[0].max() < 1e-6, t
    assert main(["inspect", str(src)]) == 0
    out = capsys.readouterr().out
    assert "height_m: 2.0" in out and "FBX 6.1" in out, out


def test_cesiumman_fbx_is_the_gltf_character_and_blender_plays_it_alike(tmp_path):
    """CesiumMan exported to FBX by Blender 5: its rest skin is CesiumMan.glb's (vertex for vertex, within 1e-6
    m), and posed by its take it is Blender's own evaluation of the FBX within 1e-5 m. Against the glTF's
    animation (aligned at the clips' first keys) it is within 5 mm: the FBX's curves are Blender's re-bake of
    the glTF's, not its keys (the FBX itself is that far from the glTF; jiggle reads the FBX as Blender does)."""
    c, clip = read(asset("characters/fbx/CesiumMan_blender5.fbx"))
    g, gclip = read(asset("characters/CesiumMan.glb"))
    assert c.num_vertices == g.num_vertices == 3273 and c.joint_names == g.joint_names
    assert np.abs(c.vertices - g.vertices).max() < 1e-6
    frames = [5, 20, 40]
    theirs = blender_frames(asset("characters/fbx/CesiumMan_blender5.fbx"), frames, tmp_path)
    for k, f in enumerate(frames):
        ours = posed(c, clip, f / clip.fps)
        assert cKDTree(ours).query(theirs[k])[0].max() < 1e-5
        glb = posed(g, gclip, gclip.meta["start_time"] + (f / clip.fps - clip.meta["start_time"]))
        assert np.abs(ours - glb).max() < 5e-3


def test_a_skeleton_only_fbx_is_a_clip(capsys):
    """Maya's HumanIK skeleton (62 bones, `Character1_*`, no mesh) is a clip: load_clip reads its skeleton and
    its take, the built-in HumanIK map finds its roles, and `jiggle inspect` describes it as a clip. (Its take has curve
    nodes and no key curve: the file holds one pose.)"""
    from jiggle.rig.motion.mocap import load_clip
    from jiggle.rig.motion.role_map import resolve_roles
    clip = load_clip(asset("characters/fbx/maya_human_ik_7400_binary.fbx"))
    assert clip.num_joints == 62 and "Character1_Hips" in clip.joint_names
    roles = resolve_roles(clip)
    assert clip.joint_names[roles["hips"]] == "Character1_Hips"
    assert clip.joint_names[roles["left_foot"]] == "Character1_LeftFoot"
    assert main(["inspect", str(asset("characters/fbx/maya_human_ik_7400_binary.fbx"))]) == 0
    out = capsys.readouterr().out
    assert "kind: clip" in out and "FBX 7.4 binary" in out


def bad_files(folder) -> dict:
    src = asset("characters/fbx/maya_kenney_character_7700_binary.fbx").read_bytes()
    files = {"empty_ascii.fbx": b"; FBX 7.4.0 project file\nFBXHeaderExtension:  {\n}\n",
             "cut_ascii.fbx": b"; FBX 7.4.0 project file\nObjects:  {\n\tModel: 1, \"Model::a\", \"Null\" {\n",
             "truncated.fbx": src[:4000], "garbage.fbx": b"\x00\x01 not an fbx at all" * 50,
             "empty61.fbx": b"Kaydara FBX Binary  \x00\x1a\x00" + (6100).to_bytes(4, "little") + b"\x00" * 64,
             "fbx5.fbx": b"Kaydara FBX Binary  \x00\x1a\x00" + (5000).to_bytes(4, "little") + b"\x00" * 64,
             "nan_keys.fbx": src.replace(b"KeyValueFloat", b"KeyValueFloaX")}
    from fbx_text import bar_fbx61
    bar = bar_fbx61()[0].encode()
    files.update({"bar61_cut.fbx": bar[:len(bar) // 2], "bar61_count.fbx": bar.replace(b"KeyCount: 3", b"KeyCount: 4"),
                  "bar61_nan.fbx": bar.replace(b",90,L", b",-1.#IND,L")})
    out = {}
    for name, data in files.items():
        p = os.path.join(folder, name)
        with open(p, "wb") as fh:
            fh.write(data)
        out[name] = p
    return out


@pytest.mark.parametrize("command", ["inspect", "bake"])
def test_bad_fbx_files_are_one_line_and_exit_2(tmp_path, capsys, command):
    """An ASCII FBX with no objects, one cut off inside a record, an FBX 6.1 with nothing in it, an FBX 5, a
    truncated file, bytes that are no FBX, a file whose key curves are broken; an FBX 6.1 ASCII file cut in half,
    with a wrong key count, with a NaN key: one line naming the file and what to do, exit code 2, no traceback;
    nothing written."""
    for name, p in bad_files(tmp_path).items():
        argv = ["inspect", p] if command == "inspect" else ["bake", "--character", p, "--out", str(tmp_path / "o"),
                                                            "--formats", "npz", "--frames", "4"]
        code = main(argv)
        err = capsys.readouterr().err.strip()
        if name == "nan_keys.fbx" and code == 0:     # Blender may read past a broken curve: then it is a file
            continue
        assert code == 2, (name, err)
        assert err.count("\n") == 0 and "Traceback" not in err and name in err, (name, err)
        assert not (tmp_path / "o" / "bake.npz").exists()


@pytest.mark.slow
def test_an_fbx_character_bakes_its_own_take_with_no_flags(tmp_path):
    """`jiggle bake --character CesiumMan_blender5.fbx`: its take baked with the human template; against the bake
    of CesiumMan.glb frame for frame the jiggle (final - static skin) agrees within a quarter of its largest (and 1 mm),
    and the skins within the 5 mm the FBX's own curves are from the glTF's."""
    from jiggle.sim.bake.caches import read_npz
    for name, path in (("fbx", asset("characters/fbx/CesiumMan_blender5.fbx")), ("glb", asset("characters/CesiumMan.glb"))):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", JiggleWarning)
            assert main(["-q", "bake", "--character", str(path), "--out", str(tmp_path / name), "--formats", "npz"]) == 0
    a, b = read_npz(tmp_path / "fbx" / "bake.npz"), read_npz(tmp_path / "glb" / "bake.npz")
    T = min(len(a.times), len(b.times))
    assert T >= 50
    jig = lambda d: d.skin_final[:T] - d.skin_static[:T]        # noqa: E731
    top = float(np.abs(jig(a)).max())
    assert top > 5e-4                                              # it does jiggle (relaxed tissue on a walk: ~0.8 mm)
    assert np.linalg.norm(jig(a) - jig(b), axis=2).max() < min(1e-3, 0.25 * top)
    assert np.linalg.norm(a.skin_final[:T] - b.skin_final[:T], axis=2).max() < 5e-3


def test_a_cache_that_cannot_be_made_is_one_line(tmp_path, capsys, monkeypatch):
    """JIGGLE_CACHE on a file (no folder can be made there): one line naming the FBX and what to set, exit 2."""
    blocker = tmp_path / "not_a_folder"
    blocker.write_text("x")
    monkeypatch.setenv("JIGGLE_CACHE", str(blocker))
    fbx = str(asset("characters/fbx/CesiumMan_blender5.fbx"))
    assert main(["inspect", fbx]) == 2
    err = capsys.readouterr().err.strip()
    assert "JIGGLE_CACHE" in err and "CesiumMan_blender5.fbx" in err and "\n" not in err, err


@pytest.mark.slow
def test_the_barbarian_bakes_its_own_take(tmp_path):
    """Blender 2.93's FBX of a game character with a light (which stopped Blender 5's importer), IK foot controls
    and knee poles off its root, and a two-bone trunk (no joint between the pelvis and the chest: the trunk's
    muscles then ride hips > chest): its first take bakes with no flag, the human template fitted."""
    import json

    from jiggle.sim.bake.caches import read_npz
    out = tmp_path / "barbarian"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", JiggleWarning)
        assert main(["-q", "bake", "--character", str(asset("characters/fbx/blender_293_barbarian_7400_binary.fbx")),
                     "--out", str(out), "--formats", "npz", "--frames", "30"]) == 0
    summary = json.loads((out / "bake.json").read_text())
    assert summary["params"]["template"] == "human" and summary["muscles"] >= 15
    d = read_npz(out / "bake.npz")
    assert np.isfinite(d.skin_final).all()


POISON = r'''
import sys
import bpy
src, out = sys.argv[-2], sys.argv[-1]
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.import_scene.fbx(filepath=src, anim_offset=0.0)
act = bpy.data.actions[0]
curves = list(act.fcurves) if hasattr(act, "fcurves") else \
    [fc for layer in act.layers for strip in layer.strips for bag in strip.channelbags for fc in bag.fcurves]
fc = curves[len(curves) // 2]
fc.keyframe_points[len(fc.keyframe_points) // 2].co[1] = float("nan")
bpy.ops.export_scene.fbx(filepath=out, bake_anim=True)
'''


def test_an_fbx_with_a_nan_key_never_reaches_a_cache(tmp_path, capsys):
    """CesiumMan's FBX with one animation key set to NaN by Blender and written again: the bake refuses it in one
    line naming the file and what is wrong, exit 2, and writes no cache."""
    from jiggle.rig.motion.fbx import blender_command
    script, poisoned = tmp_path / "poison.py", tmp_path / "nan_key.fbx"
    script.write_text(POISON)
    r = subprocess.run(blender_command(str(script)) + [str(asset("characters/fbx/CesiumMan_blender5.fbx")),
                                                       str(poisoned)], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0 and poisoned.exists(), r.stdout[-1500:] + r.stderr[-1500:]
    out = tmp_path / "bake"
    assert main(["bake", "--character", str(poisoned), "--out", str(out), "--formats", "npz"]) == 2
    err = capsys.readouterr().err.strip()
    assert "nan_key.fbx" in err and "\n" not in err and "Traceback" not in err, err
    assert not (out / "bake.npz").exists()
