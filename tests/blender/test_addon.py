"""The Blender extension (blender/jiggle_blender, built by blender/build.py) in real Blender (bpy, .venv/blender):
installed from its zip and enabled as a user would, CesiumMan imported, its action baked from the operator with
the project's jiggle command, and the evaluated mesh checked against the bake's skin_final; the bake equals
`jiggle bake` on the file the add-on exported; a missing or failing jiggle command is a report and leaves the
scene and the folder as they were. Skipped without bpy."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest
from conftest import ROOT, asset
from scipy.spatial import cKDTree

from jiggle.sim.bake.caches import read_npz

SETUP = r'''
import json, os, sys
import bpy
import numpy as np
zip_path, glb, out, jiggle, result = sys.argv[-5:]
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.extensions.package_install_files(filepath=zip_path, repo="user_default", enable_on_install=True)
name = "bl_ext.user_default.jiggle_blender"
report = {"enabled": name in bpy.context.preferences.addons}
bpy.context.preferences.addons[name].preferences.jiggle_path = jiggle
bpy.ops.import_scene.gltf(filepath=glb)
arm = [o for o in bpy.data.objects if o.type == "ARMATURE"][0]
mesh = [o for o in bpy.data.objects if o.type == "MESH"][0]
bpy.context.view_layer.objects.active = arm
sc = bpy.context.scene
sc.render.fps = 30
act = arm.animation_data.action
sc.frame_start, sc.frame_end = int(act.frame_range[0]), int(act.frame_range[1])


def evaluated(frames):
    """The mesh's evaluated world positions (F, V, 3) at scene frames."""
    skins = []
    for f in frames:
        sc.frame_set(f)
        ev = mesh.evaluated_get(bpy.context.evaluated_depsgraph_get())
        me = ev.to_mesh()
        M = np.array(ev.matrix_world)
        skins.append([(M @ np.r_[v.co[:], 1.0])[:3] for v in me.vertices])
        ev.to_mesh_clear()
    return np.array(skins)
'''
"""What every script below starts with: the add-on installed from its zip into a fresh user folder and enabled,
its jiggle command set, CesiumMan imported, its armature active, the scene at 30 fps over the action's frames."""


DRIVE = r'''
sc.jiggle.out_dir = out
report["before"] = [m.type for m in mesh.modifiers]
try:
    report["result"] = sorted(bpy.ops.jiggle.bake())
except RuntimeError as e:                      # an operator's ERROR report raises in a script: its message
    report["result"], report["error"] = ["CANCELLED"], str(e)
report["after"] = [(m.name, m.type) for m in mesh.modifiers]
report["frames"] = []
if os.path.isfile(os.path.join(out, "bake.npz")) and "Jiggle" in mesh.modifiers:
    with np.load(os.path.join(out, "bake.npz")) as d:
        T, t0 = len(d["times"]), float(d["times"][0])
    report["frames"] = [0, T // 2, T - 1]
    np.save(result + ".npy", evaluated([int(round(t0 * 30)) + k for k in report["frames"]]))
    # the result rendered headless (Workbench), at the middle frame, as the viewport plays it
    sc.render.engine = "BLENDER_WORKBENCH"
    sc.render.resolution_x, sc.render.resolution_y = 480, 640
    cam = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
    sc.collection.objects.link(cam)
    sc.camera = cam
    cam.location, cam.rotation_euler = (0.4, -3.0, 1.0), (1.45, 0.0, 0.13)
    sc.frame_set(int(round(t0 * 30)) + T // 2)
    sc.render.filepath = result + ".png"
    bpy.ops.render.render(write_still=True)
    bpy.ops.jiggle.compare()
    report["compare"] = mesh.modifiers["Jiggle"].filepath
    import webbrowser
    opened = []
    webbrowser.open = lambda url, *a, **k: opened.append(url)     # no browser here: what it would open
    report["report_op"] = sorted(bpy.ops.jiggle.open_report())
    report["opened"] = opened
json.dump(report, open(result + ".json", "w"))
'''


@pytest.fixture(scope="module")
def addon(tmp_path_factory):
    from jiggle.rig.motion.fbx import blender_command
    if blender_command("x.py") is None:
        pytest.skip("no Blender here (bpy in .venv/blender, JIGGLE_BPY_PYTHON or JIGGLE_BLENDER_EXE)")
    sys.path.insert(0, str(ROOT / "blender"))
    import build
    return build.build(tmp_path_factory.mktemp("dist"))


def jiggle_exe() -> str:
    exe = shutil.which("jiggle", path=os.path.dirname(sys.executable)) or shutil.which("jiggle")
    if exe is None:
        pytest.skip("the jiggle command is not installed in this environment")
    return exe


def in_blender(addon, body: str, out, tmp_path, jiggle: str | None = None, setup: str = SETUP,
               args: tuple = (), glb=None) -> tuple[dict, np.ndarray | None]:
    """Run setup + body in Blender (its user folder in tmp_path), with the zip, the character (`glb`, default
    CesiumMan), `out`, the jiggle command and RESULT as its last arguments (after `args`): (RESULT.json,
    RESULT.npy or None)."""
    from jiggle.rig.motion.fbx import blender_command
    script, result = tmp_path / "script.py", tmp_path / "result"
    script.write_text(setup + body)
    r = subprocess.run(blender_command(str(script)) + [*map(str, args), str(addon),
                                                        str(glb or asset("characters/CesiumMan.glb")), str(out),
                                                        jiggle or jiggle_exe(), str(result)],
                       capture_output=True, text=True, timeout=900,
                       env={**os.environ, "BLENDER_USER_RESOURCES": str(tmp_path / "user")})
    assert r.returncode == 0 and Path(str(result) + ".json").exists(), r.stdout[-2500:] + r.stderr[-2500:]
    rep = json.loads(Path(str(result) + ".json").read_text())
    skins = np.load(str(result) + ".npy") if Path(str(result) + ".npy").exists() else None
    return rep, skins


def drive(addon, out, jiggle, tmp_path) -> tuple[dict, np.ndarray | None]:
    return in_blender(addon, DRIVE, out, tmp_path, jiggle)


def test_the_zip_is_an_extension_of_the_projects_version(addon):
    import zipfile
    names = zipfile.ZipFile(addon).namelist()
    assert sorted(names) == ["__init__.py", "blender_manifest.toml"]
    manifest = tomllib.loads(zipfile.ZipFile(addon).read("blender_manifest.toml").decode())
    import jiggle
    assert manifest["version"] == jiggle.__version__ and manifest["type"] == "add-on"


def test_bake_from_blender_plays_the_baked_skin(addon, tmp_path):
    """Installed from the zip and enabled; the operator bakes CesiumMan's action: a Mesh Cache modifier right after
    the Armature one, and Blender's evaluated mesh is skin_final within 0.1 mm at the first, middle and last frame
    (every Blender vertex on its baked place, and every baked vertex under a Blender vertex); Compare switches
    to the static skin; the bake is `jiggle bake` of the exported file, bit for bit."""
    out = tmp_path / "bake"
    rep, skins = drive(addon, out, jiggle_exe(), tmp_path)
    assert rep["enabled"] and rep["result"] == ["FINISHED"], rep
    assert rep["after"] == [["Armature", "ARMATURE"], ["Jiggle", "MESH_CACHE"]]
    d = read_npz(out / "bake.npz")
    for k, f in enumerate(rep["frames"]):
        a = cKDTree(d.skin_final[f]).query(skins[k])[0].max()
        b = cKDTree(skins[k]).query(d.skin_final[f])[0].max()
        assert a < 1e-4 and b < 1e-4, (f, a, b)
    assert rep["compare"].endswith("blender_static.pc2")
    assert rep["report_op"] == ["FINISHED"] and rep["opened"] == ["file://" + str(out / "report.html")]
    assert (out / "report.html").is_file() and (out / "metrics.json").is_file()     # `jiggle compare` made them
    png = Path(str(tmp_path / "result") + ".png")
    assert png.is_file() and png.stat().st_size > 20_000            # Workbench drew the played skin
    exported = next(out.glob("*.jiggle.glb"))
    again = tmp_path / "again"
    summary = json.loads((out / "bake.json").read_text())
    code = subprocess.run([jiggle_exe(), "-q", "bake", "--character", str(exported), "--out", str(again), "--formats",
                           "npz,pc2", "--fps", f"{summary['fps']:g}"], capture_output=True, text=True).returncode
    assert code == 0
    e = read_npz(again / "bake.npz")
    assert np.array_equal(e.skin_final, d.skin_final) and np.array_equal(e.skin_static, d.skin_static)


@pytest.mark.parametrize("scale, unit_m", [(100.0, 0.01), (0.12, 1.0)])
def test_a_character_in_centimetres_or_tiny_plays_on_its_own_mesh(addon, tmp_path, scale, unit_m):
    """CesiumMan written 100 times larger (a glTF in centimetres: 150 units tall, which the bake reads as 1.5 m)
    and 0.12 times smaller (0.18 m, which the bake simulates at the human template's 1.7 m): imported and baked
    in Blender, its evaluated mesh is the bake's skin_final brought back to the file's units (params' file_unit_m)
    within 0.1 mm of the mesh's size, on its own mesh."""
    import warnings

    from jiggle.rig.base.errors import JiggleWarning
    from jiggle.rig.character.gltf_write import write_character
    from jiggle.rig.character.load import load_character
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", JiggleWarning)
        man = load_character(asset("characters/CesiumMan.glb"))
    from dataclasses import replace

    from jiggle.rig.motion.mocap import load_clip
    walk = load_clip(asset("characters/CesiumMan.glb"))
    walk = replace(walk, offsets=walk.offsets * scale, translations=walk.translations * scale)
    glb = tmp_path / "scaled.glb"
    write_character(man.scaled(scale), glb, animations={"walk": walk})
    out = tmp_path / "bake"
    rep, skins = in_blender(addon, DRIVE, out, tmp_path, glb=glb)
    assert rep["result"] == ["FINISHED"], rep
    d = read_npz(out / "bake.npz")
    params = json.loads(d.params)
    assert params["file_unit_m"] == pytest.approx(unit_m)
    for k, f in enumerate(rep["frames"]):
        baked = d.skin_final[f] / unit_m
        assert cKDTree(baked).query(skins[k])[0].max() < 1e-4 * scale, f


ANY_BODY = ["zoo/Cat.glb", "zoo/Orc.glb", "zoo/Demon.glb", "zoo/Goleling.glb", "zoo/Hywirl.glb", "zoo/Frog.glb",
            "zoo/Horse.glb", "zoo/Cow.glb", "RobotExpressive.glb"]


@pytest.mark.parametrize("name", ANY_BODY)
def test_any_character_bakes_from_blender_on_its_own_mesh(addon, tmp_path, name):
    """Every shared zoo character and RobotExpressive, imported into Blender and baked with the defaults from the
    add-on (the glTF Blender exports of it, with its active action): baked, not refused, and Blender's evaluated
    mesh is the bake's skin_final (in the file's units) at the first, middle and last frame."""
    out = tmp_path / "bake"
    rep, skins = in_blender(addon, DRIVE, out, tmp_path, glb=asset(f"characters/{name}"))
    assert rep["result"] == ["FINISHED"], rep
    d = read_npz(out / "bake.npz")
    unit = json.loads(d.params).get("file_unit_m", 1.0)
    size = float(np.ptp(d.skin_rest, axis=0).max()) / unit
    for k, f in enumerate(rep["frames"]):
        assert cKDTree(d.skin_final[f] / unit).query(skins[k])[0].max() < 1e-4 * max(size, 1.0), (name, f)


def test_a_missing_or_failing_jiggle_is_a_report_and_changes_nothing(addon, tmp_path):
    """No jiggle command at the given path: an error report saying so, no modifier, no folder. A jiggle that
    fails (a rig it refuses): its own one-line message as the report, no modifier, the folder it made removed."""
    out = tmp_path / "bake"
    rep, _ = drive(addon, out, str(tmp_path / "no_such_jiggle"), tmp_path)
    assert rep["result"] == ["CANCELLED"] and "jiggle command was not found" in rep["error"]
    assert rep["after"] == [[n, t] for n, t in zip(["Armature"], rep["before"])] and not out.exists()
    fake = tmp_path / "failing_jiggle"
    fake.write_text("#!/bin/sh\necho 'jiggle: error: character.glb: no built-in template for this body plan' >&2\n"
                    "exit 2\n")
    fake.chmod(0o755)
    rep, _ = drive(addon, out, str(fake), tmp_path)
    assert rep["result"] == ["CANCELLED"] and "no built-in template for this body plan" in rep["error"]
    assert [t for _, t in rep["after"]] == rep["before"] and not out.exists()


CANCEL = r'''
import json, os, sys, time
import bpy
clip, zip_path, glb, out, jiggle, result = sys.argv[-6:]
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.extensions.package_install_files(filepath=zip_path, repo="user_default", enable_on_install=True)
addon = sys.modules["bl_ext.user_default.jiggle_blender"]
job = addon.BakeJob([jiggle, "bake", "--character", glb, "--clip", clip, "--out", out, "--formats", "npz,pc2",
                     "--progress", "json", "--chunk", "8"], out)
job.start(env={**os.environ, "JIGGLE_BAKE_PAUSE": "0.3"})        # slow enough to be stopped mid-bake
seen, t0 = [], time.time()
while time.time() - t0 < 300 and not any(e.get("event") == "progress" for e in seen):
    seen += job.events()
    time.sleep(0.05)
mid = {"partial": os.path.isdir(os.path.join(out, ".partial")), "running": job.running()}
job.cancel()
json.dump({"events": [e.get("event") for e in seen], "mid": mid, "after": os.path.exists(out),
           "code": job.proc.returncode}, open(result + ".json", "w"))
'''


def test_cancelling_mid_bake_leaves_nothing(addon, tmp_path):
    """The add-on's bake job (what Esc stops): started on CesiumMan with a walk, stopped after its first progress
    line while the bake is writing; the process ends and the output folder it made is gone."""
    out = tmp_path / "bake"
    rep, _ = in_blender(addon, CANCEL, out, tmp_path, setup="", args=(asset("mocap/cmu_bvh/05_02.bvh"),))
    assert rep["events"][:2] == ["preparing", "start"] and "progress" in rep["events"], rep
    assert rep["mid"] == {"partial": True, "running": True}, rep
    assert rep["code"] != 0 and rep["after"] is False and not out.exists()


BONES = r'''
user_keys = {fc.data_path + str(fc.array_index): [tuple(k.co) for k in fc.keyframe_points]
             for fc in __import__("bpy_extras.anim_utils", fromlist=["x"]).action_get_channelbag_for_slot(
                 act, arm.animation_data.action_slot).fcurves}
bones_before = len(arm.data.bones)
tracks_before = [t.name for t in arm.animation_data.nla_tracks]
sc.jiggle.out_dir = out
sc.jiggle.result = "BONES"
report["result"] = sorted(bpy.ops.jiggle.bake())
report["bones_added"] = len(arm.data.bones) - bones_before
report["action_same"] = arm.animation_data.action == act
after = {fc.data_path + str(fc.array_index): [tuple(k.co) for k in fc.keyframe_points]
         for fc in __import__("bpy_extras.anim_utils", fromlist=["x"]).action_get_channelbag_for_slot(
             act, arm.animation_data.action_slot).fcurves}
report["user_keys_same"] = after == user_keys
report["tracks"] = [t.name for t in arm.animation_data.nla_tracks]
report["tracks_before"] = tracks_before
report["modifiers"] = [m.type for m in mesh.modifiers]
with np.load(os.path.join(out, "bake.npz")) as d:
    T, t0 = len(d["times"]), float(d["times"][0])
report["frames"] = [0, T // 2, T - 1]
np.save(result + ".npy", evaluated([int(round(t0 * 30)) + k for k in report["frames"]]))
json.dump(report, open(result + ".json", "w"))
'''


def test_bones_result_adds_jiggle_bones_blender_plays(addon, tmp_path):
    """Result "bones": the bake's glb jiggle bones join the armature (children of their hosts), their keys in an
    action of their own on an NLA track, their weights on the mesh; the armature's action and its keys are
    untouched, no Mesh Cache modifier; Blender's evaluated mesh (its Armature modifier alone) is skin_final within
    RMS 1 mm and p99 3 mm, as the glb plays in an engine."""
    out = tmp_path / "bake"
    rep, skins = in_blender(addon, BONES, out, tmp_path)
    assert rep["result"] == ["FINISHED"] and rep["bones_added"] == 51, rep
    assert rep["action_same"] and rep["user_keys_same"] and rep["tracks"] == rep["tracks_before"] + ["jiggle"]
    assert rep["modifiers"] == ["ARMATURE"]
    d = read_npz(out / "bake.npz")
    for k, f in enumerate(rep["frames"]):
        e = cKDTree(skins[k]).query(d.skin_final[f])[0] * 1000
        lbs = np.linalg.norm(d.skin_lbs[f] - d.skin_final[f], axis=1) * 1000     # what the bones have to make
        assert np.sqrt((e ** 2).mean()) <= 1.0 and np.percentile(e, 99) <= 3.0, (f, e.max())
        assert np.percentile(e, 99) < 0.5 * np.percentile(lbs, 99), (f, np.percentile(e, 99), np.percentile(lbs, 99))


UNDO = r'''
A = lambda: [o for o in bpy.data.objects if o.type == "ARMATURE"][0]          # noqa: E731 (undo swaps the data)
M = lambda: [o for o in bpy.data.objects if o.type == "MESH"][0]              # noqa: E731
state = lambda: {"bones": len(A().data.bones), "groups": len(M().vertex_groups), "actions": len(bpy.data.actions),
                 "tracks": len(A().animation_data.nla_tracks), "modifiers": [m.type for m in M().modifiers]}
for mode in ("EXACT", "BONES"):
    sc = bpy.context.scene                           # undo swaps the data: look everything up again
    bpy.context.view_layer.objects.active = A()
    sc.jiggle.out_dir = out + "_" + mode.lower()
    sc.jiggle.result = mode
    bpy.ops.ed.undo_push(message="before jiggle")
    before = state()
    bpy.ops.jiggle.bake()
    bpy.ops.ed.undo_push(message="Bake jiggle")      # what the UI does after an UNDO operator; a script must
    baked = state()
    bpy.ops.ed.undo()
    report[mode] = {"before": before, "baked": baked, "undone": state()}
json.dump(report, open(result + ".json", "w"))
'''


def test_undo_returns_the_scene_as_it_was(addon, tmp_path):
    """Ctrl-Z after a bake, exact or bones: the modifier, the bones, their vertex groups, the action and the NLA
    track all go; the scene is as before the bake (the bake's files stay on disk, as any export's would)."""
    rep, _ = in_blender(addon, UNDO, tmp_path / "bake", tmp_path)
    assert rep["EXACT"]["baked"]["modifiers"] == ["ARMATURE", "MESH_CACHE"]
    assert rep["BONES"]["baked"]["bones"] == rep["BONES"]["before"]["bones"] + 51
    for mode in ("EXACT", "BONES"):
        assert rep[mode]["undone"] == rep[mode]["before"], (mode, rep[mode])


RATE = r'''
sc.frame_start, sc.frame_end = 1, 250
s = sc.jiggle
s.out_dir, s.fps, s.use_range, s.frame_start, s.frame_end = out, 60.0, True, 10, 30
report.update(result=sorted(bpy.ops.jiggle.bake()), scene_range=[sc.frame_start, sc.frame_end])
with np.load(os.path.join(out, "bake.npz")) as d:
    report["fps"], report["times"] = float(d["fps"]), [float(d["times"][0]), float(d["times"][-1])]
report["frame_scale"] = mesh.modifiers["Jiggle"].frame_scale
np.save(result + ".npy", evaluated((10, 20, 30)))
json.dump(report, open(result + ".json", "w"))
'''


def test_frame_range_and_output_rate_from_the_panel(addon, tmp_path):
    """Frames 10-30 of a 30 fps scene baked at 60 fps: the bake covers those 20 frames' 2/3 s at 60 frames/s, the
    scene's own range is left as it was, and the cache plays scene frame f at bake frame 2 (f - 10)."""
    out = tmp_path / "bake"
    rep, skins = in_blender(addon, RATE, out, tmp_path)
    assert rep["result"] == ["FINISHED"] and rep["scene_range"] == [1, 250] and rep["fps"] == 60.0
    assert abs(rep["times"][1] - rep["times"][0] - 20 / 30) < 1e-6 and rep["frame_scale"] == 2
    d = read_npz(out / "bake.npz")
    for k, f in enumerate((10, 20, 30)):
        assert cKDTree(d.skin_final[2 * (f - 10)]).query(skins[k])[0].max() < 1e-4, f


ACTIVATION = r'''
s = sc.jiggle
s.out_dir, s.use_range, s.frame_start, s.frame_end = out, True, 1, 12
report["default_args"] = sys.modules[name].bake_arguments(bpy.context, s, glb, out)
s.activation = "ON"
report["on_args"] = sys.modules[name].bake_arguments(bpy.context, s, glb, out)
report["result"] = sorted(bpy.ops.jiggle.bake())
with np.load(os.path.join(out, "bake.npz")) as d:
    report["activation"] = d["activation"].shape if "activation" in d.files else None
json.dump(report, open(result + ".json", "w"))
'''


def test_the_panels_activation_reaches_the_bake(addon, tmp_path):
    """The panel's Activation: Default leaves --activation out (jiggle's own default), On bakes with the muscles'
    activation (bake.npz's activation, frames x muscles)."""
    out = tmp_path / "bake"
    rep, _ = in_blender(addon, ACTIVATION, out, tmp_path)
    assert "--activation" not in rep["default_args"] and rep["on_args"][-2:] == ["--activation", "on"]
    assert rep["result"] == ["FINISHED"] and rep["activation"] is not None and rep["activation"][1] > 10


CHAINS = r'''
from bpy_extras.anim_utils import action_get_channelbag_for_slot
addon = sys.modules["bl_ext.user_default.jiggle_blender"]
ad = arm.animation_data
ad.action = act = bpy.data.actions["Gallop"]                     # the Horse's gallop: its tail and ears keyed
sc.frame_start, sc.frame_end = int(act.frame_range[0]), int(act.frame_range[1])


def user_state():
    """Every key of every action but the add-on's (co, handles, interpolation), the active action, the other NLA
    tracks and the bones' constraints other than the add-on's: what a bake must leave bit for bit."""
    keys = {}
    for a in bpy.data.actions:
        if a.get("jiggle") == "chains":
            continue
        for slot in a.slots:
            bag = action_get_channelbag_for_slot(a, slot)
            for fc in (bag.fcurves if bag else []):
                keys[f"{a.name}/{slot.identifier}/{fc.data_path}[{fc.array_index}]"] = [
                    (*k.co, *k.handle_left, *k.handle_right, k.interpolation) for k in fc.keyframe_points]
    tracks = [(t.name, t.mute, [(s.name, s.action and s.action.name, s.frame_start, s.frame_end) for s in t.strips])
              for t in ad.nla_tracks if t.name != "jiggle chains"]
    cons = [(pb.name, c.name) for pb in arm.pose.bones for c in pb.constraints if c.name != "jiggle chains"]
    return {"keys": keys, "tracks": tracks, "action": ad.action.name, "slot": ad.action_slot.identifier,
            "constraints": cons}


def bones_at(frames, names):
    """(F, B, 2, 3): each bone's head and tail in world space at scene frames, as Blender evaluates them."""
    out = []
    for f in frames:
        sc.frame_set(f)
        M = arm.matrix_world
        out.append([[(M @ arm.pose.bones[n].head)[:], (M @ arm.pose.bones[n].tail)[:]] for n in names])
    return np.array(out)


sc.jiggle.out_dir = out
sc.jiggle.chain_damping = "Ear*=0.6"          # a chain parameter from the panel reaches the bake
before = user_state()
report["result"] = sorted(bpy.ops.jiggle.bake())
report["user_same"] = user_state() == before
track = ad.nla_tracks["jiggle chains"]
ours = track.strips[0].action
report["tracks"] = [t.name for t in ad.nla_tracks]
report["keys"] = {}
for slot in ours.slots:
    for fc in action_get_channelbag_for_slot(ours, slot).fcurves:
        if fc.data_path.endswith(".rotation_quaternion"):
            report["keys"][fc.data_path.split('"')[1]] = len(fc.keyframe_points)
report["constraints"] = {pb.name: [c.name for c in pb.constraints if c.name == "jiggle chains"]
                         for pb in arm.pose.bones}
with np.load(os.path.join(out, "bake.npz")) as d:
    names, T = [str(n) for n in d["chain_names"]], len(d["times"])
    data = {k: d[k] for k in d.files}
report["names"], report["first"] = names, sc.frame_start
report["frames"] = [0, 1, T // 2, T - 1]
report["lengths"] = [arm.pose.bones[n].length * arm.matrix_world.to_scale()[0] for n in names]
swung = bones_at([sc.frame_start + k for k in report["frames"]], names)
bpy.ops.jiggle.compare()                                   # static: the chains' track muted, the user's animation
report["muted"] = track.mute
unswung = bones_at([sc.frame_start + k for k in report["frames"]], names)
bpy.ops.jiggle.compare()
report["unmuted"] = not track.mute
np.save(result + ".npy", np.stack([swung, unswung]))
# a second bake replaces the add-on's track, action and constraints; the user's are still as they were
report["again"] = sorted(bpy.ops.jiggle.bake())
report["tracks_again"] = [t.name for t in ad.nla_tracks]
report["ours_again"] = sorted(a.name for a in bpy.data.actions if a.get("jiggle") == "chains")
report["constraints_again"] = {pb.name: [c.name for c in pb.constraints if c.name == "jiggle chains"]
                               for pb in arm.pose.bones}
report["user_same_again"] = user_state() == before
# a chain bone the armature lacks is skipped (and reported by the operator), the others still keyed
data["chain_names"] = np.array(names + ["NoSuchBone"])
data["chain_world"] = np.concatenate([data["chain_world"], data["chain_world"][:, :1]], axis=1)
bases, skipped = addon.chain_bases(arm, data)
report["skipped"], report["bases"] = skipped, len(bases)
json.dump(report, open(result + ".json", "w"))
'''


def test_a_tail_swings_on_the_addons_own_track(addon, tmp_path):
    """The Horse (its ears and tail are chains), imported with Blender's glTF importer, its Gallop baked from the
    add-on: the NLA track "jiggle chains" holds an action with one key per bake frame on every tail and ear bone;
    Blender's evaluated tail and ear bones put their heads and tails where bake.npz's chain_world says (head = its
    translation, tail = head + length along its Y axis) within 1 mm of the file's scale at the first, second,
    middle and last frame, although the user's action keys those bones too; Compare mutes the track and the bones
    follow the user's animation again (joint_world); every key of the user's actions, the active action, the other
    NLA tracks and the bones' own constraints are bit for bit as before, after one bake and after a second, which
    adds no second track, action or constraint; a chain bone the armature lacks is skipped."""
    out = tmp_path / "bake"
    rep, bones = in_blender(addon, CHAINS, out, tmp_path, glb=asset("characters/zoo/Horse.glb"))
    assert rep["result"] == ["FINISHED"] and rep["user_same"], rep
    assert rep["tracks"].count("jiggle chains") == 1 and rep["tracks"][-1] == "jiggle chains"
    d = read_npz(out / "bake.npz")
    names = rep["names"]
    tail = [n for n in names if n.startswith("Tail")]
    assert len(tail) >= 4 and set(rep["keys"]) == set(names), rep["keys"]
    assert all(v == len(d.times) for v in rep["keys"].values())
    assert all(rep["constraints"][n] == ["jiggle chains"] for n in names)
    by_chain = {c["chain"]: c for c in json.loads(d.params)["chains"]["chains"]}
    assert by_chain["Ear1.L"]["damping"] == 0.6 and by_chain["Tail1"]["damping"] != 0.6   # the panel's Ear*=0.6
    unit = json.loads(d.params).get("file_unit_m", 1.0)
    swung, unswung = bones
    joints = list(d.joint_names)
    for k, f in enumerate(rep["frames"]):
        W = d.chain_world[f].astype(np.float64)
        head = W[:, :3, 3] / unit
        tip = head + W[:, :3, 1] * np.array(rep["lengths"])[:, None]
        err = max(np.abs(swung[k, :, 0] - head).max(), np.abs(swung[k, :, 1] - tip).max())
        assert err < 1e-3 / unit, (f, err)
        A = d.joint_world[f][[joints.index(n) for n in names]].astype(np.float64)
        assert np.abs(unswung[k, :, 0] - A[:, :3, 3] / unit).max() < 1e-3 / unit, f     # Compare: the animation
    moved = np.linalg.norm(d.chain_world[:, :, :3, 3] - d.joint_world[:, [joints.index(n) for n in names], :3, 3],
                           axis=-1).max()
    assert moved > 1e-2, moved                                    # the check above is not the animation's
    assert rep["muted"] and rep["unmuted"]
    assert rep["again"] == ["FINISHED"] and rep["tracks_again"] == rep["tracks"] and rep["user_same_again"]
    assert rep["ours_again"] == ["AnimalArmature.jiggle_chains"], rep["ours_again"]
    assert rep["constraints_again"] == rep["constraints"]
    assert rep["skipped"] == ["NoSuchBone"] and rep["bases"] == len(names)
