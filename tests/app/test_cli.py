"""The command line: help, inspect, play outputs, and bad input as one line with exit code 2."""
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import asset

from jiggle.sim.app.cli import main


def run(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.parametrize("argv", [["--help"], ["inspect", "--help"], ["play", "--help"], ["demo", "--help"],
                                  ["body", "--help"]])
def test_help_is_complete(capsys, argv):
    with pytest.raises(SystemExit) as e:
        main(argv)
    assert e.value.code == 0
    out = capsys.readouterr().out
    assert "usage: jiggle" in out
    if argv[0] == "play":
        for opt in ("--out", "--start", "--end", "--fps", "--speed", "--drive", "--skeleton", "--animation",
                    "--scale", "--tpose"):
            assert opt in out


def test_inspect_bvh_text_and_json(capsys):
    path = str(asset("mocap/cmu_bvh/01_01.bvh"))
    code, out, _ = run(capsys, "inspect", path)
    assert code == 0 and "tpose: detected and skipped" in out and "frames: 2751" in out
    code, out, _ = run(capsys, "inspect", path, "--json")
    rep = json.loads(out)
    assert rep["joints"] == 31 and rep["fps"] == 120.0 and rep["duration_s"] == pytest.approx(2750 / 120)
    assert rep["units"].startswith("CMU units")


def test_inspect_mjcf(capsys):
    code, out, _ = run(capsys, "inspect", str(asset("mjcf/humanoid_CMU.xml")), "--json")
    rep = json.loads(out)
    assert code == 0 and rep["nq"] == 63 and rep["joint_types"] == {"free": 1, "hinge": 56}


@pytest.mark.slow
def test_play_writes_pictures_and_motion(capsys, tmp_path):
    """`jiggle play` on the demo's own keyframed motion (the demo itself bakes: tests/app/test_demo.py)."""
    out_dir = tmp_path / "play"
    motion = Path(__file__).resolve().parents[2] / "scenes" / "motions" / "jumping_jacks.toml"
    code, out, err = run(capsys, "play", str(motion), "--out", str(out_dir), "--fps", "60", "--end", "0.65",
                         "--poses", "4")
    assert code == 0, err
    for f in ("skeleton.png", "trajectories.png", "motion.npz", "summary.json", "character.png"):
        assert (out_dir / f).stat().st_size > 0
    summary = json.loads((out_dir / "summary.json").read_text())
    assert summary["character"]["weights"] == "bone heat" and 10000 <= summary["character"]["vertices"] <= 40000
    data = np.load(out_dir / "motion.npz")
    assert data["joint_world"].shape == (40, 21, 4, 4) and data["times"].shape == (40,)
    assert np.all(np.isfinite(data["joint_world"]))
    # the render smoke test: without working GL, VTK crashes or draws nothing
    import imageio.v3 as iio
    img = iio.imread(out_dir / "skeleton.png")
    assert img.shape[0] > 100 and len(np.unique(img.reshape(-1, img.shape[-1]), axis=0)) > 50
    assert not list(out_dir.glob(".*tmp*")), "temporary files left behind"


def test_play_clip_range_and_fps(capsys, tmp_path):
    path = str(asset("mocap/cmu_bvh/09_11.bvh"))
    code, _, err = run(capsys, "play", path, "--out", str(tmp_path), "--start", "0.2", "--end", "0.7",
                       "--fps", "30", "--no-render")
    assert code == 0, err
    data = np.load(tmp_path / "motion.npz")
    np.testing.assert_allclose(data["times"], np.arange(16) / 30.0)
    assert json.loads((tmp_path / "summary.json").read_text())["frames"] == 16


def test_bad_input_is_one_line_and_exit_2(capsys, tmp_path):
    bad = tmp_path / "bad.bvh"
    bad.write_text("HIERARCHY\nROOT a\n{\nOFFSET 0 0 0\nCHANNELS 3 Xrotation Yrotation Zrotation\n}\n"
                   "MOTION\nFrames: 2\nFrame Time: 0.1\n0 0 0\n0 x 0\n")
    code, out, err = run(capsys, "inspect", str(bad))
    assert code == 2 and out == ""
    assert err.strip() == f"jiggle: error: {bad}:11: expected a number for a channel value, found 'x'"
    code, _, err = run(capsys, "play", str(tmp_path / "missing.bvh"))
    assert code == 2 and "missing.bvh: clip file not found" in err
    code, _, err = run(capsys, "inspect", str(tmp_path / "notes.txt"))
    assert code == 2
    (tmp_path / "notes.txt").write_text("hi")
    code, _, err = run(capsys, "inspect", str(tmp_path / "notes.txt"))
    assert code == 2 and "unknown file type" in err
    with pytest.raises(SystemExit) as e:
        main(["play", str(bad), "--fps", "-3"])
    assert e.value.code == 2


def test_an_output_path_under_a_file_is_one_line_and_exit_2(capsys, tmp_path):
    """`jiggle body --out a_file/sub`: the folder cannot be made under a file; one line naming the path, exit 2,
    no traceback (it was a FileExistsError's traceback)."""
    blocker = tmp_path / "taken"
    blocker.write_text("the user's file")
    code, out, err = run(capsys, "-q", "body", "--out", str(blocker / "sub"), "--no-render")
    assert code == 2 and "Traceback" not in err and err.count("\n") == 1 and str(blocker) in err, err
    assert err.startswith("jiggle: error: ") and "give another path" in err
    assert blocker.read_text() == "the user's file"


def test_console_script_exit_code_without_traceback(tmp_path):
    exe = shutil.which("jiggle", path=os.path.dirname(sys.executable))
    if exe is None:
        pytest.skip("the jiggle console script is not installed in this environment")
    bad = tmp_path / "zero.bvh"
    bad.write_text("HIERARCHY\nROOT a\n{\nOFFSET 0 0 0\nCHANNELS 3 Xrotation Yrotation Zrotation\n}\n"
                   "MOTION\nFrames: 0\nFrame Time: 0.1\n")
    r = subprocess.run([exe, "inspect", str(bad)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2
    assert "Traceback" not in r.stderr and f"{bad}:8:" in r.stderr


def test_play_retargeted_onto_a_character(capsys, tmp_path):
    clip = str(asset("mocap/cmu_bvh/02_03.bvh"))
    code, out, err = run(capsys, "play", clip, "--character", str(asset("characters/CesiumMan.glb")),
                         "--out", str(tmp_path), "--no-render", "--end", "0.5")
    assert code == 0, err
    assert "cmu map" in out and "cesiumman map" in out
    data = np.load(tmp_path / "motion.npz")
    assert list(data["joint_names"][:2]) == ["Skeleton_torso_joint_1", "Skeleton_torso_joint_2"]
    assert data["joint_world"].shape == (61, 19, 4, 4)
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["character"]["weights"] == "file" and summary["character"]["vertices"] == 3273
    # no preset fits RiggedFigure: its roles are found from its shape
    code, out, err = run(capsys, "play", clip, "--character", str(asset("characters/RiggedFigure.glb")),
                         "--out", str(tmp_path), "--no-render", "--end", "0.2")
    assert code == 0 and "found from the shape map" in out, err
    # a map file that does not exist names the option
    code, _, err = run(capsys, "play", clip, "--character", str(asset("characters/RiggedFigure.glb")),
                       "--character-map", str(tmp_path / "none.toml"), "--out", str(tmp_path), "--no-render")
    assert code == 2 and "none.toml" in err, err


def test_play_drives_a_user_mjcf(capsys, tmp_path):
    amc = str(asset("mocap/cmu_amc/01_01.amc"))
    xml = str(asset("mjcf/humanoid_CMU.xml"))
    code, _, err = run(capsys, "play", amc, "--mjcf", xml, "--end", "0.25", "--out", str(tmp_path), "--no-render")
    assert code == 0, err
    data = np.load(tmp_path / "motion.npz")
    assert data["joint_world"].shape == (31, 31, 4, 4) and "lfemur" in list(data["joint_names"])
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["mjcf"].endswith("humanoid_CMU.xml") and summary["mapped_joints"] >= 25
    bad_map = tmp_path / "map.toml"
    bad_map.write_text('[joints]\nlfemur = "no_such_body"\n')
    code, _, err = run(capsys, "play", amc, "--mjcf", xml, "--joint-map", str(bad_map), "--out", str(tmp_path))
    assert code == 2 and "no_such_body" in err and "lfemur" in err
    code, _, err = run(capsys, "play", amc, "--mjcf", xml, "--drive", "physics", "--out", str(tmp_path))
    assert code == 2 and "--drive" in err


def test_play_physics_drive_saves_foot_forces(capsys, tmp_path):
    code, out, err = run(capsys, "play", str(asset("mocap/cmu_bvh/09_11.bvh")), "--drive", "physics",
                         "--end", "0.6", "--out", str(tmp_path), "--no-render")
    assert code == 0, err
    assert "tracking error: RMS" in out
    data = np.load(tmp_path / "motion.npz")
    n = data["times"].shape[0]
    assert data["foot_force"].shape == (n, 2) and data["joint_error"].shape == (n, 31)
    assert np.all(np.isfinite(data["joint_world"])) and data["foot_force"].max() > 0
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["drive"] == "physics" and summary["rms_joint_error_m"] < 0.05


@pytest.mark.slow
def test_body_command_writes_mesh_pictures_and_facts(capsys, tmp_path):
    code, out, err = run(capsys, "body", "--out", str(tmp_path), "--resolution", "10000", "--belly", "0.03")
    assert code == 0, err
    facts = json.loads((tmp_path / "body.json").read_text())
    assert facts["watertight"] and facts["euler_number"] == 2 and facts["weights"] == "bone heat"
    assert facts["options"]["belly"] == 0.03 and any(f["name"] == "belly" for f in facts["fat"])
    import trimesh
    mesh = trimesh.load(tmp_path / "body.ply", process=False)
    assert len(mesh.vertices) == facts["vertices"] and mesh.is_watertight
    import imageio.v3 as iio
    for f in ("body.png", "weights.png"):
        img = iio.imread(tmp_path / f)
        assert len(np.unique(img.reshape(-1, img.shape[-1]), axis=0)) > 50, f
    code, _, err = run(capsys, "body", str(tmp_path / "missing.bvh"), "--out", str(tmp_path))
    assert code == 2 and "missing.bvh" in err
    with pytest.raises(SystemExit) as e:
        main(["body", "--belly", "-1", "--out", str(tmp_path)])
    assert e.value.code == 2 and "--belly must be zero or more" in capsys.readouterr().err


def test_play_with_a_mesh_character_warns_and_skins(capsys, tmp_path):
    """An OBJ standing in the clip's rest pose, in centimetres: read so by --unit auto (the default) with
    a notice, automatic weights, a warning on stderr; read in metres (--unit m) it misses the skeleton."""
    from jiggle.rig.character.body import BodyOptions, generate_body
    from jiggle.rig.motion.keyframes import read_keyframes
    scene = os.path.join(os.path.dirname(__file__), "..", "..", "scenes", "motions", "jumping_jacks.toml")
    clip = read_keyframes(scene)
    body = generate_body(clip, BodyOptions(resolution=10000))
    import trimesh
    obj = tmp_path / "me.obj"
    trimesh.Trimesh(body.vertices * 100, body.faces, process=False).export(obj)
    code, out, err = run(capsys, "play", scene, "--character", str(obj), "--unit", "m", "--out", str(tmp_path),
                         "--no-render", "--end", "0.3")
    assert code == 2 and "does not fit the mesh" in err and "--unit" in err, err
    code, out, err = run(capsys, "play", scene, "--character", str(obj), "--out", str(tmp_path), "--no-render",
                         "--end", "0.3")
    assert code == 0 and "read in centimetres" in err, err
    code, out, err = run(capsys, "play", scene, "--character", str(obj), "--unit", "cm", "--up", "z",
                         "--out", str(tmp_path), "--no-render", "--end", "0.3")
    assert code == 0, err
    assert "jiggle: warning:" in err and "automatic weights" in err
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["character"]["vertices"] == len(body.vertices)


def test_deform_renders_lbs_against_shells_on_the_simple_arm(capsys, tmp_path):
    """`jiggle deform` with no character bends the thesis's simple arm and writes the comparison."""
    from PIL import Image
    code, out, err = run(capsys, "deform", "--angle", "90", "--out", str(tmp_path))
    assert code == 0, err
    facts = json.loads((tmp_path / "deform.json").read_text())
    assert facts["pose"] == {"scene": "simple arm", "elbow_deg": 90.0}
    assert facts["skinning"] == "shell" and facts["pairs"] > 0 and facts["max_displacement_mm"] > 1.0
    img = np.asarray(Image.open(tmp_path / "deform.png").convert("L"), float)
    assert img.shape == (800, 1600) and img.std() > 10          # something drawn, not a blank frame
    assert (tmp_path / "deform.ply").stat().st_size > 1000
    code, out, err = run(capsys, "deform", "--skinning", "influence", "--no-render", "--out", str(tmp_path / "i"))
    assert code == 0 and json.loads((tmp_path / "i" / "deform.json").read_text())["skinning"] == "influence"


def test_deform_on_cesiumman_with_a_run_frame(capsys, tmp_path):
    code, out, err = run(capsys, "deform", str(asset("characters/CesiumMan.glb")), "--clip",
                         str(asset("mocap/cmu_bvh/02_03.bvh")), "--time", "0.5", "--no-render", "--out", str(tmp_path))
    assert code == 0, err
    facts = json.loads((tmp_path / "deform.json").read_text())
    assert facts["muscles"] == 28 and facts["pose"]["time_s"] == 0.5 and 0.0 < facts["max_displacement_mm"] < 60.0


@pytest.mark.parametrize("argv, what", [
    (["deform", "--clip", "x.bvh"], "--clip"),
    (["deform", "--weights", "missing.npz"], "missing.npz"),
])
def test_deform_bad_input_is_one_line_and_exit_2(capsys, tmp_path, argv, what):
    code, out, err = run(capsys, *argv, "--out", str(tmp_path))
    assert code == 2 and what in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


@pytest.mark.parametrize("command", ["bake", "simulate", "deform", "morph"])
def test_one_name_for_the_character_map(command):
    """--character-map names the character's roles in every command (the template's and the
    retargeting's); --joint-map, its old name, is the same option."""
    from jiggle.sim.app.cli import build_parser
    p = build_parser()
    extra = ["x.glb"] if command == "morph" else []
    a = p.parse_args([command, *extra, "--character-map", "m.toml"])
    b = p.parse_args([command, *extra, "--joint-map", "m.toml"])
    assert a.character_map == b.character_map == "m.toml"
    assert not hasattr(a, "joint_map")


# ------------------------------------------------------------------ python -m jiggle, --quiet, --verbose
ROOT = Path(__file__).resolve().parents[2]
ARM = str(ROOT / "scenes" / "simple_arm.toml")
TINY_ASF = """:version 1.10
:name tiny
:units
  mass 1.0
  length 1.0
  angle deg
:root
   order TX TY TZ RX RY RZ
   axis XYZ
   position 0 0 0
   orientation 0 0 0
:bonedata
  begin
     id 1
     name a
     direction {direction}
     length 1
     axis 0 0 0  XYZ
  end
:hierarchy
  begin
    root a
  end
"""


def jiggle_module(*argv, **kw):
    """`python -m jiggle ARGV` in a new process (PYTHONPATH: the checkout, whatever the install maps)."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    return subprocess.run([sys.executable, "-m", "jiggle", *argv], cwd=kw.pop("cwd", ROOT), env=env,
                          capture_output=True, text=True, timeout=300, **kw)


def test_python_m_jiggle_is_the_cli(tmp_path):
    done = jiggle_module("--help", cwd=tmp_path)
    assert done.returncode == 0 and "usage: jiggle" in done.stdout and "--quiet" in done.stdout, done.stderr
    assert "--verbose" in done.stdout and "python -m jiggle" in done.stdout
    done = jiggle_module("inspect", str(tmp_path / "missing.bvh"))
    assert done.returncode == 2 and done.stderr.startswith("jiggle: error:") and "missing.bvh" in done.stderr
    assert len(done.stderr.strip().splitlines()) == 1 and done.stdout == ""


@pytest.mark.parametrize("before", [True, False])
def test_quiet_prints_nothing_but_errors(capsys, tmp_path, before):
    """--quiet (before or after the command): no progress, notices or files listed; the bake is written;
    an error is still its one line."""
    argv = ["bake", ARM, "--out", str(tmp_path), "--frames", "8", "--chunk", "4", "--formats", "npz"]
    code, out, err = run(capsys, *(["--quiet", *argv] if before else [*argv, "-q"]))
    assert code == 0 and out == "" and err == ""
    assert (tmp_path / "bake.npz").is_file() and (tmp_path / "bake.json").is_file()
    code, out, err = run(capsys, "-q", "bake", "--clip", str(tmp_path / "missing.bvh"), "--out", str(tmp_path))
    assert code == 2 and out == "" and err.startswith("jiggle: error:") and len(err.strip().splitlines()) == 1


def test_quiet_and_verbose_are_exclusive(capsys):
    with pytest.raises(SystemExit) as e:
        main(["--quiet", "inspect", "x.bvh", "--verbose"])
    assert e.value.code == 2 and "--quiet and --verbose" in capsys.readouterr().err


def test_a_warning_before_an_error_is_not_printed(capsys, tmp_path):
    """An ASF whose bone direction overflows: NumPy's overflow warning then the exit-2 line, which alone
    is printed (with --verbose too)."""
    asf = tmp_path / "huge.asf"
    asf.write_text(TINY_ASF.format(direction="1e300 1e300 1e300"))
    for extra in ([], ["--verbose"]):
        code, out, err = run(capsys, "inspect", str(asf), *extra)
        assert code == 2 and err.startswith("jiggle: error:") and len(err.strip().splitlines()) == 1, err
        assert "RuntimeWarning" not in err and "overflow" not in err


def warn_then(monkeypatch, fail: bool):
    """`jiggle inspect` replaced by a command that issues a JiggleWarning and a NumPy overflow, then
    fails with an InputError or succeeds."""
    from jiggle.rig.base.errors import InputError, JiggleWarning
    from jiggle.sim.app.commands import inspect as inspect_cmd

    def fake(args):
        import warnings
        warnings.warn("first notice", JiggleWarning, stacklevel=1)
        with np.errstate(over="warn"):
            np.float64(1e300) * np.float64(1e300)
        warnings.warn("second notice", JiggleWarning, stacklevel=1)
        if fail:
            raise InputError("cannot read it", args.file)
        print("report")
        return 0
    monkeypatch.setattr(inspect_cmd, "run", fake)


def test_jiggle_warnings_before_an_input_error_are_not_printed(capsys, monkeypatch):
    warn_then(monkeypatch, fail=True)
    code, out, err = run(capsys, "inspect", "some.bvh")
    assert code == 2 and err == "jiggle: error: some.bvh: cannot read it\n"


def test_warnings_follow_a_success_in_order_numpy_ones_only_with_verbose(capsys, monkeypatch):
    warn_then(monkeypatch, fail=False)
    code, out, err = run(capsys, "inspect", "some.bvh")
    assert code == 0 and out == "report\n"
    assert err == "jiggle: warning: first notice\njiggle: warning: second notice\n"
    code, out, err = run(capsys, "inspect", "some.bvh", "--verbose")
    assert code == 0 and err.index("first notice") < err.index("overflow") < err.index("second notice")
    assert "jiggle: inspect took" in err
    code, out, err = run(capsys, "--quiet", "inspect", "some.bvh")
    assert code == 0 and out == "" and err == ""


def test_interrupt_counts_the_frames_kept_on_disk(capsys, tmp_path, monkeypatch):
    """Ctrl-C in chunk 3 of 16-frame chunks: 48 frames kept (the progress bar, off when stderr is not a
    terminal, counted 0), said in one line with the --resume command."""
    from jiggle.sim.bake import baker as bake_mod
    real = bake_mod.Baker.chunk

    def chunk(self, c, state):
        if c == 3:
            raise KeyboardInterrupt
        return real(self, c, state)
    monkeypatch.setattr(bake_mod.Baker, "chunk", chunk)
    code, out, err = run(capsys, "bake", ARM, "--out", str(tmp_path), "--fps", "60", "--chunk", "16",
                         "--formats", "npz", "--quiet")
    assert code == 130 and len(err.strip().splitlines()) == 1, err
    frames = json.loads((tmp_path / ".partial" / "manifest.json").read_text())["frames"]
    assert err.startswith(f"jiggle: interrupted after 48 of {frames} frames: the 3 finished chunks (of ")
    assert f"--resume --out {tmp_path}" in err


@pytest.mark.slow
def test_warp_lines_only_with_verbose(tmp_path):
    """By default a bake's output has no Warp start-up or kernel-load lines; --verbose shows them, with
    their timings and the command's time."""
    argv = ["bake", ARM, "--frames", "8", "--chunk", "4", "--formats", "npz"]
    quiet = jiggle_module(*argv, "--out", str(tmp_path / "a"))
    assert quiet.returncode == 0, quiet.stderr
    assert "Warp" not in quiet.stdout + quiet.stderr and "Module " not in quiet.stdout + quiet.stderr
    loud = jiggle_module("--verbose", *argv, "--out", str(tmp_path / "b"))
    assert loud.returncode == 0, loud.stderr
    assert "Warp" not in loud.stdout                 # on stderr, not mixed with the command's output
    assert "Warp " in loud.stderr and "initialized" in loud.stderr
    assert "Module " in loud.stderr and " ms" in loud.stderr and "jiggle: bake took" in loud.stderr
