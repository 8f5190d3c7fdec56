"""`jiggle bake`: an end-to-end bake of a tiny scene, the caches read back (USD equals npz), a killed
bake resumed equals an unbroken one bit for bit, blend 0 gives the static skin exactly, and bad
input (missing files, unwritable folders, a full disk, other parameters on --resume) is one clear
line with exit code 2 and leaves no cache that looks complete."""
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from jiggle.sim.app.cli import main
from jiggle.sim.bake.caches import read_npz

ROOT = Path(__file__).resolve().parents[2]
ARM = str(ROOT / "scenes" / "simple_arm.toml")
KEYS = ("skin_static", "skin_final", "times", "joint_world", "muscle_cvs_static", "muscle_cvs_dynamic",
        "muscle_cv_offsets", "faces", "muscle_faces")


def run(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def bake_arm(capsys, out, *extra):
    code, o, err = run(capsys, "bake", ARM, "--out", str(out), "--fps", "60", "--chunk", "16", *extra)
    assert code == 0, err
    return o, err


@pytest.fixture(scope="module")
def arm_bake(tmp_path_factory):
    """One unbroken bake of the simple arm (93 frames at 60 fps, chunks of 16), with every format."""
    out = tmp_path_factory.mktemp("arm")
    assert main(["bake", ARM, "--out", str(out), "--fps", "60", "--chunk", "16",
                 "--formats", "npz,usda,pc2"]) == 0
    return out


def same_bake(a: Path, b: Path) -> None:
    da, db = read_npz(a / "bake.npz"), read_npz(b / "bake.npz")
    for k in KEYS:
        np.testing.assert_array_equal(getattr(da, k), getattr(db, k), err_msg=k)
    assert da.params == db.params and da.fps == db.fps


def test_bake_writes_every_cache_and_the_arm_jiggles(arm_bake):
    files = {p.name for p in arm_bake.iterdir()}
    assert {"bake.npz", "bake.usda", "bake.pc2", "bake.json"} <= files and ".partial" not in files
    assert not [f for f in files if ".tmp" in f]
    d = read_npz(arm_bake / "bake.npz")
    assert d.num_frames == 93 and d.fps == 60.0
    np.testing.assert_allclose(d.times, np.arange(93) / 60.0, atol=1e-12)
    assert d.joint_names == ("shoulder", "elbow", "wrist") or len(d.joint_names) == 3
    assert d.muscle_names == ("biceps",) and d.muscle_cvs_dynamic.shape == (93, 40, 3)
    move = np.linalg.norm(d.skin_final - d.skin_static, axis=2).max(axis=1)
    cv = np.linalg.norm(d.muscle_cvs_dynamic - d.muscle_cvs_static, axis=2).max(axis=1)
    assert move[0] < 1e-6 and cv[0] < 1e-6               # starts settled on the static shape
    assert cv.max() > 3e-3 and move.max() > 1e-3         # the biceps overshoots by mm, the skin follows
    params = json.loads(d.params)
    assert params["muscles"]["biceps"]["mass_kg"] > 0 and params["fps"] == 60.0
    summary = json.loads((arm_bake / "bake.json").read_text())
    assert summary["frames"] == 93 and summary["chunks"] == 6 and summary["timings"]["frames_per_s"] > 0


def test_usd_read_back_equals_npz(arm_bake):
    from pxr import Usd, UsdGeom
    d = read_npz(arm_bake / "bake.npz")
    stage = Usd.Stage.Open(str(arm_bake / "bake.usda"))
    assert stage.GetTimeCodesPerSecond() == 60.0 and UsdGeom.GetStageUpAxis(stage) == "Z"
    for name in ("skin_static", "skin_final"):
        mesh = UsdGeom.Mesh(stage.GetPrimAtPath(f"/jiggle/{name}"))
        assert np.array_equal(np.array(mesh.GetFaceVertexIndicesAttr().Get()).reshape(-1, 3), d.faces)
        for k in (0, 17, 50, 92):
            pts = np.array(mesh.GetPointsAttr().Get(k), dtype=np.float32)
            np.testing.assert_array_equal(pts, getattr(d, name)[k], err_msg=f"{name} frame {k}")
        assert len(mesh.GetNormalsAttr().Get(10)) == d.skin_static.shape[1]
    biceps = UsdGeom.Mesh(stage.GetPrimAtPath("/jiggle/muscles/biceps"))
    assert biceps and len(biceps.GetPointsAttr().Get(40)) > 40


def test_pc2_holds_the_final_skin(arm_bake):
    from jiggle.sim.bake.caches import read_pc2
    pc = read_pc2(arm_bake / "bake.pc2")
    np.testing.assert_array_equal(pc.points, read_npz(arm_bake / "bake.npz").skin_final)


def test_interrupted_bake_resumes_to_the_same_caches(capsys, tmp_path, arm_bake, monkeypatch):
    """Ctrl-C in chunk 3: exit 130, a message naming --resume, no cache; --resume finishes it equal."""
    from jiggle.sim.bake import baker as bake_mod
    real = bake_mod.Baker.chunk

    def chunk(self, c, state):
        if c == 3:
            raise KeyboardInterrupt
        return real(self, c, state)
    monkeypatch.setattr(bake_mod.Baker, "chunk", chunk)
    code, out, err = run(capsys, "bake", ARM, "--out", str(tmp_path), "--fps", "60", "--chunk", "16",
                         "--formats", "npz,usda,pc2")
    assert code == 130 and "--resume" in err
    assert sorted(p.name for p in (tmp_path / ".partial").glob("chunk_*")) == [f"chunk_0000{i}.npz" for i in range(3)]
    assert not (tmp_path / "bake.npz").exists()
    monkeypatch.setattr(bake_mod.Baker, "chunk", real)
    code, out, err = run(capsys, "bake", ARM, "--out", str(tmp_path), "--fps", "60", "--chunk", "16",
                         "--formats", "npz,usda,pc2", "--resume")
    assert code == 0, err
    assert "3 of 6 chunks already baked" in err
    same_bake(tmp_path, arm_bake)
    assert (tmp_path / "bake.pc2").read_bytes() == (arm_bake / "bake.pc2").read_bytes()
    summary = json.loads((tmp_path / "bake.json").read_text())
    assert summary["resumed_after_chunks"] == 3
    # the tissue law's hard stops: per muscle over all chunks, the first three read back from their markers
    assert summary["tissue"] == json.loads((arm_bake / "bake.json").read_text())["tissue"]
    assert summary["tissue"]["hard_stops"] == {"biceps": 0} and summary["tissue"]["hard_stops_total"] == 0


@pytest.mark.slow
def test_killed_bake_resumes_to_the_same_caches(tmp_path, arm_bake):
    """A real kill (SIGKILL, no clean-up at all) between chunks, then --resume in a new process."""
    cmd = [sys.executable, "-m", "jiggle", "bake", ARM, "--out", str(tmp_path), "--fps", "60", "--chunk", "16",
           "--formats", "npz,usda,pc2"]
    env = {**os.environ, "JIGGLE_BAKE_PAUSE": "0.5", "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    target = tmp_path / ".partial" / "chunk_00001.npz"
    deadline = time.time() + 120
    while not target.exists() and proc.poll() is None and time.time() < deadline:
        time.sleep(0.02)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert target.exists(), proc.stderr.read().decode()
    assert not (tmp_path / "bake.npz").exists()
    env.pop("JIGGLE_BAKE_PAUSE")
    done = subprocess.run(cmd + ["--resume"], cwd=ROOT, env=env, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert "chunks already baked" in done.stderr
    same_bake(tmp_path, arm_bake)


def test_blend_zero_bakes_the_static_skin_exactly(capsys, tmp_path):
    (tmp_path / "report.html").write_text("the user's own report")
    bake_arm(capsys, tmp_path, "--blend", "0", "--formats", "npz")
    assert (tmp_path / "report.html").read_text() == "the user's own report"    # no compare wrote it: kept
    d = read_npz(tmp_path / "bake.npz")
    np.testing.assert_array_equal(d.skin_final, d.skin_static)
    np.testing.assert_array_equal(d.muscle_cvs_dynamic, d.muscle_cvs_static)


def test_preroll_and_gravity_reach_the_bake(capsys, tmp_path, arm_bake):
    """--preroll S starts the particles at rest at the bind pose S seconds early (so the first frame is
    already jiggling), --gravity lets them sag; both are the bake's parameters (bake.json)."""
    bake_arm(capsys, tmp_path, "--preroll", "0.2", "--gravity", "--formats", "npz", "--frames", "20")
    d, plain = read_npz(tmp_path / "bake.npz"), read_npz(arm_bake / "bake.npz")
    settings = json.loads(d.params)["settings"]
    assert settings["preroll"] == 0.2 and settings["gravity"] is True
    assert np.abs(d.muscle_cvs_dynamic[0] - d.muscle_cvs_static[0]).max() > 1e-5       # not settled
    assert np.abs(plain.muscle_cvs_dynamic[0] - plain.muscle_cvs_static[0]).max() < 1e-6
    with pytest.raises(SystemExit) as e:
        main(["bake", ARM, "--preroll=-1", "--out", str(tmp_path / "x")])
    assert e.value.code == 2 and "--preroll must be zero or more" in capsys.readouterr().err


def test_mush_cleans_the_smooth_skin_in_the_bake(capsys, tmp_path, arm_bake):
    """--mush N runs Delta Mush on the smooth skin under the shells: a parameter of the bake, the skin
    changes where the elbow bends, and the rest pose is still the artist's."""
    bake_arm(capsys, tmp_path, "--mush", "5", "--formats", "npz", "--frames", "40")
    d, plain = read_npz(tmp_path / "bake.npz"), read_npz(arm_bake / "bake.npz")
    assert json.loads(d.params)["skinning"]["mush"] == 5 and json.loads(plain.params)["skinning"]["mush"] == 0
    assert np.abs(d.skin_static[0] - plain.skin_static[0]).max() < 1e-5           # bent 0 deg: the rest
    assert np.abs(d.skin_lbs[-1] - plain.skin_lbs[39]).max() > 1e-3               # the bent elbow mushed


def test_compare_prints_the_skin_quality_verdict(capsys, tmp_path):
    """`jiggle compare` on a bake says in one line whether the skin keeps its quality targets."""
    bake_arm(capsys, tmp_path, "--formats", "npz", "--frames", "30")
    code, out, _ = run(capsys, "compare", str(tmp_path), "--no-render")
    assert code == 0
    line = next(x for x in out.splitlines() if x.startswith("skin quality:"))
    for target in ("final_folded_edges", "folds_added_over_lbs", "torn_edges", "gradient_p999"):
        assert target in line
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    verdicts = [("ok" if t["pass"] else "FAIL") for t in metrics["skin_quality"]["targets"].values()]
    assert line.count(" ok") + line.count(" FAIL") == len(verdicts)


def test_a_gltf_character_alone_bakes_its_own_animation(capsys, tmp_path):
    """`jiggle bake --character X.glb` without a clip bakes the character's own animation, with no joint
    map: the smooth skin in the cache is the glTF posed by its own animation (LBS with its joints'
    world transforms), to float32 rounding."""
    from conftest import asset

    from jiggle.rig.character.load import load_character
    from jiggle.rig.motion.clip import transforms
    from jiggle.rig.motion.mocap import load_clip
    from jiggle.rig.skin.skinning import pose_character
    path = str(asset("characters/CesiumMan.glb"))
    code, out, err = run(capsys, "bake", "--character", path, "--out", str(tmp_path), "--formats", "npz",
                         "--frames", "20")
    assert code == 0, err
    assert "no retargeting" in err
    d = read_npz(tmp_path / "bake.npz")
    assert json.loads(d.params)["clip"]["file"].endswith("CesiumMan.glb")
    assert d.part_names == ("Cesium_Man",) and d.part_offsets.tolist() == [0, 3273]  # the glTF's mesh, named
    c, clip = load_character(path), load_clip(path)
    world = transforms(*clip.world(*clip.sample(d.times)))[:, [clip.joint_names.index(n) for n in c.joint_names]]
    for k in (0, 10, 19):
        assert np.abs(d.skin_lbs[k] - pose_character(c, world[k])).max() < 1e-5


def test_a_centimetre_character_with_unit_cm_bakes_as_in_metres(capsys, tmp_path):
    """CesiumMan written in centimetres (every length x 100) and baked with --unit cm, or with --unit auto
    (the default, which reads the height of 150 units as centimetres), lands where the metre original
    does; inspect says the file is probably in centimetres: the skeleton the clip is retargeted onto is scaled like the skin (before, the
    skin was read in metres and its bones in centimetres: the posed skin was 130 m off)."""
    from dataclasses import replace

    from conftest import asset

    from jiggle.rig.character.gltf_write import write_character
    from jiggle.rig.character.load import load_character
    path = str(asset("characters/CesiumMan.glb"))
    c = load_character(path)
    bind_world, bind_matrices = np.array(c.bind_world), np.array(c.bind_matrices)
    bind_world[:, :3, 3] *= 100.0
    bind_matrices[:, :3, 3] *= 100.0
    skeleton = replace(c.skeleton, offsets=c.skeleton.offsets * 100.0, translations=c.skeleton.translations * 100.0)
    cm = str(tmp_path / "cesium_cm.glb")
    write_character(replace(c, vertices=c.vertices * 100.0, bind_world=bind_world, bind_matrices=bind_matrices,
                            skeleton=skeleton), cm)
    clip = str(asset("mocap/cmu_bvh/02_03.bvh"))
    for name, extra in (("cm", ["--character", cm, "--unit", "cm"]), ("m", ["--character", path]),
                        ("auto", ["--character", cm])):
        code, _, err = run(capsys, "bake", "--clip", clip, *extra, "--out", str(tmp_path / name), "--formats", "npz",
                           "--frames", "12")
        assert code == 0, err
        # --unit auto (the default) finds the centimetres from the height and says so
        assert ("read in centimetres" in err) == (name == "auto"), err
    b = read_npz(tmp_path / "m" / "bake.npz")
    for name in ("cm", "auto"):
        a = read_npz(tmp_path / name / "bake.npz")
        assert np.abs(a.skin_final - b.skin_final).max() < 1e-5
        assert np.abs(a.skin_lbs - b.skin_lbs).max() < 1e-5
    code, out, err = run(capsys, "inspect", cm)
    assert code == 0 and "height_m: 150.6" in out and "unit: probably centimetres" in out and "--unit cm" in out, out


def test_jiggle_zero_stays_static(capsys, tmp_path):
    bake_arm(capsys, tmp_path, "--jiggle", "0", "--formats", "npz", "--frames", "40")
    d = read_npz(tmp_path / "bake.npz")
    assert np.abs(d.muscle_cvs_dynamic - d.muscle_cvs_static).max() < 1e-5


def test_chunk_size_does_not_change_the_motion(capsys, tmp_path, arm_bake):
    """Chunks only split the work: 16 and 50 frames per chunk agree to float32 rounding."""
    bake_arm(capsys, tmp_path, "--chunk", "50", "--formats", "npz")
    a, b = read_npz(tmp_path / "bake.npz"), read_npz(arm_bake / "bake.npz")
    assert np.abs(a.muscle_cvs_dynamic - b.muscle_cvs_dynamic).max() < 1e-5
    assert np.abs(a.skin_final - b.skin_final).max() < 1e-5


def test_resume_with_other_parameters_is_refused(capsys, tmp_path, monkeypatch):
    from jiggle.sim.bake import baker as bake_mod
    real = bake_mod.Baker.chunk

    def chunk(self, c, state):
        if c == 1:
            raise KeyboardInterrupt
        return real(self, c, state)
    monkeypatch.setattr(bake_mod.Baker, "chunk", chunk)
    assert run(capsys, "bake", ARM, "--out", str(tmp_path), "--chunk", "16", "--formats", "npz")[0] == 130
    monkeypatch.setattr(bake_mod.Baker, "chunk", real)
    code, out, err = run(capsys, "bake", ARM, "--out", str(tmp_path), "--chunk", "16", "--formats", "npz",
                         "--substeps", "7", "--resume")
    assert code == 2 and "other parameters" in err and "settings.substeps" in err
    assert (tmp_path / ".partial" / "chunk_00000.npz").exists()      # nothing lost


def test_resume_without_an_unfinished_bake(capsys, tmp_path, arm_bake):
    code, out, err = run(capsys, "bake", ARM, "--out", str(tmp_path), "--resume")
    assert code == 2 and "no unfinished bake" in err and str(tmp_path) in err
    code, out, err = run(capsys, "bake", ARM, "--out", str(arm_bake), "--fps", "60", "--chunk", "16",
                         "--formats", "npz,usda,pc2", "--resume")
    assert code == 2 and "already finished" in err


def test_full_disk_leaves_no_cache_that_looks_complete(capsys, tmp_path, monkeypatch):
    """ENOSPC while the third chunk goes into the npz: exit 2 naming the file, no bake.npz, the chunks
    before it kept; --resume then finishes a bake equal to an unbroken one."""
    import errno

    from jiggle.sim.bake import caches

    write = caches.NpzInPlace.write

    def full(self, name, first, block):
        if first >= 32:
            raise OSError(errno.ENOSPC, "No space left on device")
        write(self, name, first, block)
    monkeypatch.setattr(caches.NpzInPlace, "write", full)
    argv = ("bake", ARM, "--chunk", "16", "--formats", "npz,pc2")
    code, out, err = run(capsys, *argv, "--out", str(tmp_path))
    assert code == 2 and "No space left on device" in err and "--resume" in err
    assert not (tmp_path / "bake.npz").exists() and not (tmp_path / "bake.pc2").exists()
    assert not (tmp_path / "bake.json").exists() and not list(tmp_path.glob(".bake*"))
    assert (tmp_path / ".partial" / "chunk_00001.npz").exists()
    monkeypatch.undo()
    code, out, err = run(capsys, *argv, "--out", str(tmp_path), "--resume")
    assert code == 0, err
    assert run(capsys, *argv, "--out", str(tmp_path / "whole"))[0] == 0
    a, b = read_npz(tmp_path / "bake.npz"), read_npz(tmp_path / "whole" / "bake.npz")
    assert np.array_equal(a.skin_final, b.skin_final) and np.array_equal(a.muscle_cvs_dynamic, b.muscle_cvs_dynamic)
    assert (tmp_path / "bake.pc2").read_bytes() == (tmp_path / "whole" / "bake.pc2").read_bytes()


def test_bad_input_is_one_line_with_exit_code_2(capsys, tmp_path):
    (tmp_path / "file").write_text("x")
    cases = [
        (["bake", "--clip", str(tmp_path / "missing.bvh"), "--out", str(tmp_path / "o")], "missing.bvh"),
        (["bake", ARM, "--out", str(tmp_path / "file" / "sub")], "file"),
        (["bake", ARM, "--out", str(tmp_path / "o"), "--formats", "npz,fbx"], "fbx"),
        (["bake", ARM, "--out", str(tmp_path / "o"), "--formats", "usdc,usda"], "pick one"),
        (["bake", ARM, "--clip", str(ROOT / "scenes" / "motions" / "jumping_jacks.toml"),
          "--out", str(tmp_path / "o")], "--clip"),
        (["bake", ARM, "--out", str(tmp_path / "o"), "--start", "5"], "start"),
        (["bake", str(ROOT / "scenes" / "belly_bvh.toml"), "--out", str(tmp_path / "o")], "--clip"),
        (["compare", str(tmp_path / "nothing_baked")], "jiggle bake"),
    ]
    for argv, needle in cases:
        code, out, err = run(capsys, *argv)
        assert code == 2, (argv, err)
        assert needle in err and "Traceback" not in err, (argv, err)
        assert len(err.strip().splitlines()) <= 3, err


def test_unknown_scene_key_lists_the_valid_ones(capsys, tmp_path):
    p = tmp_path / "s.toml"
    p.write_text('builtin = "simple_arm"\n[output]\nfps = 30\nformat = ["npz"]\n')
    code, out, err = run(capsys, "bake", str(p), "--out", str(tmp_path / "o"))
    assert code == 2 and "s.toml:4:" in err and "output.format" in err
    assert "chunk, focus, formats, fps" in err
    p.write_text('[charactr]\nfile = "x.glb"\n')
    code, out, err = run(capsys, "bake", str(p), "--out", str(tmp_path / "o"))
    assert code == 2 and "character" in err and "motion" in err


def test_a_nan_skin_stops_the_bake_before_any_cache(capsys, tmp_path, monkeypatch):
    """A skin that turns NaN (say a degenerate deformer) stops at its frame: exit 2 naming the frame,
    the chunks before it kept, no cache written."""
    from jiggle.sim.bake import baker as bake_mod
    real = bake_mod.skin_frames

    def poisoned(skin, world, cvs_sets, curve, frames, defer=False, smooth=False, reuse=False):
        pending = real(skin, world, cvs_sets, curve, frames, defer=True, smooth=smooth, reuse=reuse)

        def finish():
            out = pending()
            if frames[0] == 32:
                out[1][5, 7] = np.nan
            return out
        return finish if defer else finish()
    monkeypatch.setattr(bake_mod, "skin_frames", poisoned)
    code, out, err = run(capsys, "bake", ARM, "--out", str(tmp_path), "--chunk", "16", "--formats", "npz")
    assert code == 2 and "skin_final" in err and "frame 37" in err and "vertex 7" in err
    assert not (tmp_path / "bake.npz").exists()
    assert (tmp_path / ".partial" / "chunk_00001.npz").exists()


def test_bake_and_compare_replace_only_their_own_files(capsys, tmp_path):
    """A folder with the user's own report.html, notes and a subfolder: bake, compare, bake again with
    other formats, compare again. The user's files stay byte for byte; the bake's and compare's old
    outputs are replaced (compare writes its report beside the user's, under another name) or removed."""
    mine = {"report.html": b"<p>my own report</p>", "bake_notes.txt": b"notes\n",
            "metrics.json": b'{"mine": true}', "compare.json": b'{"also": "mine"}',
            "sub/bake.json": b"{}", "sub/report.html": b"sub"}
    for name, data in mine.items():
        (tmp_path / name).parent.mkdir(exist_ok=True)
        (tmp_path / name).write_bytes(data)

    def user_files_intact():
        for name, data in mine.items():
            assert (tmp_path / name).read_bytes() == data, name

    bake_arm(capsys, tmp_path, "--formats", "npz,usda", "--frames", "30")
    user_files_intact()
    code, out, err = run(capsys, "compare", str(tmp_path), "--no-render")
    assert code == 0, err
    user_files_intact()
    metrics = json.loads((tmp_path / "metrics.jiggle.json").read_text())
    assert metrics["files"]["report"] == "report.jiggle.html" and "report.jiggle.html" in out
    record = json.loads((tmp_path / "compare.jiggle.json").read_text())
    assert {"metrics.jiggle.json", "report.jiggle.html", "amplitude.png", "compare.jiggle.json"} <= set(record["files"])
    first_report = (tmp_path / "report.jiggle.html").stat().st_ino
    code, _, err = run(capsys, "compare", str(tmp_path), "--no-render")      # again: its own files, same names
    assert code == 0, err
    user_files_intact()
    assert sorted(p.name for p in tmp_path.glob("report*")) == ["report.html", "report.jiggle.html"]
    assert (tmp_path / "report.jiggle.html").stat().st_ino != first_report  # written anew (atomically)

    bake_arm(capsys, tmp_path, "--formats", "npz,pc2", "--frames", "20")
    user_files_intact()
    left = sorted(p.name for p in tmp_path.iterdir())
    assert left == sorted(["bake.json", "bake.npz", "bake.pc2", "bake_notes.txt", "compare.json", "metrics.json",
                           "report.html", "sub"]), left                     # bake.usda and the comparison gone
    assert read_npz(tmp_path / "bake.npz").num_frames == 20
    assert sorted(p.name for p in (tmp_path / "sub").iterdir()) == ["bake.json", "report.html"]


def test_a_listed_file_outside_the_folder_or_a_symlink_is_never_removed(capsys, tmp_path):
    """Records that name files outside the folder (tampered), or a listed name that is now a symlink to
    a file elsewhere: a new bake removes neither them nor what the link points at."""
    out, outside = tmp_path / "out", tmp_path / "outside"
    outside.mkdir()
    victims = {n: outside / n for n in ("a.txt", "b.txt", "c.txt", "d.txt", "e.txt")}
    for p in victims.values():
        p.write_text("keep me")
    bake_arm(capsys, out, "--formats", "npz", "--frames", "20")
    summary = json.loads((out / "bake.json").read_text())
    summary["files"]["usda"] = str(victims["a.txt"])                        # an absolute path
    summary["files"]["pc2"] = "../outside/b.txt"                             # a way out
    (out / "bake.json").write_text(json.dumps(summary))
    (out / "compare.json").write_text(json.dumps({"format": "jiggle.compare-files/1",
                                                  "files": [str(victims["c.txt"]), "../outside/d.txt",
                                                            "amplitude.png"]}))
    (out / "amplitude.png").symlink_to(victims["e.txt"])                    # a listed name, now a symlink
    bake_arm(capsys, out, "--formats", "npz", "--frames", "20")
    for p in victims.values():
        assert p.read_text() == "keep me", p
    assert (out / "amplitude.png").is_symlink() and not (out / "compare.json").exists()


def test_a_foreign_partial_folder_is_not_removed(capsys, tmp_path):
    (tmp_path / ".partial").mkdir()
    (tmp_path / ".partial" / "mine.txt").write_text("mine")
    code, _, err = run(capsys, "bake", ARM, "--out", str(tmp_path), "--fps", "60", "--chunk", "16",
                       "--formats", "npz", "--frames", "20")
    assert code == 2 and ".partial" in err
    assert (tmp_path / ".partial" / "mine.txt").read_text() == "mine"


KEYED = ("--strength", "biceps=[[0,1],[0.5,0.3]]", "--frequency", "*=smooth:[[0,5],[1.5,9]]",
         "--goal-scale", "b*=[[0,1],[1,1.3]]")


def test_a_keyed_bake_resumes_bit_for_bit(capsys, tmp_path, monkeypatch):
    """Keyed strength, frequency and goal scale (issue 23): Ctrl-C in chunk 2, --resume, equal to an unbroken
    keyed bake bit for bit; bake.json records the curves; the keys change the motion."""
    from jiggle.sim.bake import baker as bake_mod
    whole = tmp_path / "whole"
    bake_arm(capsys, whole, *KEYED, "--formats", "npz", "--frames", "60")
    real = bake_mod.Baker.chunk

    def chunk(self, c, state):
        if c == 2:
            raise KeyboardInterrupt
        return real(self, c, state)
    monkeypatch.setattr(bake_mod.Baker, "chunk", chunk)
    code, out, err = run(capsys, "bake", ARM, "--out", str(tmp_path / "cut"), "--fps", "60", "--chunk", "16",
                         *KEYED, "--formats", "npz", "--frames", "60")
    assert code == 130, err
    monkeypatch.setattr(bake_mod.Baker, "chunk", real)
    bake_arm(capsys, tmp_path / "cut", *KEYED, "--formats", "npz", "--frames", "60", "--resume")
    same_bake(tmp_path / "cut", whole)
    muscle = json.loads((whole / "bake.json").read_text())["params"]["muscles"]["biceps"]
    assert muscle["strength"] == {"times": [0.0, 0.5], "values": [1.0, 0.3], "interpolation": "linear"}
    assert muscle["frequency"]["interpolation"] == "smooth" and muscle["goal_scale"]["values"] == [1.0, 1.3]
    bake_arm(capsys, tmp_path / "plain", "--formats", "npz", "--frames", "60")
    a, b = read_npz(whole / "bake.npz"), read_npz(tmp_path / "plain" / "bake.npz")
    assert np.abs(a.muscle_cvs_dynamic - b.muscle_cvs_dynamic).max() > 1e-3


def test_a_keyed_constant_bakes_as_the_plain_number(capsys, tmp_path):
    bake_arm(capsys, tmp_path / "a", "--jiggle", "biceps=[[0,0.6],[9,0.6]]", "--damping", "[[0,0.4],[1,0.4]]",
             "--formats", "npz", "--frames", "40")
    bake_arm(capsys, tmp_path / "b", "--jiggle", "0.6", "--damping", "0.4", "--formats", "npz", "--frames", "40")
    da, db = read_npz(tmp_path / "a" / "bake.npz"), read_npz(tmp_path / "b" / "bake.npz")
    for k in KEYS:
        np.testing.assert_array_equal(getattr(da, k), getattr(db, k), err_msg=k)


@pytest.mark.parametrize("argv, what", [
    (["--damping", "tail=0.3"], "--damping tail=0.3: the rig has no muscle 'tail'; its muscles are biceps"),
    (["--jiggle", "*_fat=[[0,1],[2,0.2]]"], "--jiggle *_fat=[[0,1],[2,0.2]]: the glob '*_fat' matches no muscle"),
    (["--frequency", "biceps=[[0,5],[1,-2]]"], "argument --frequency: biceps=[[0,5],[1,-2]]: frequency must be in "
                                               "(0, inf) Hz, got -2 at t = 1 s (key 2)"),
])
def test_bad_keyed_flags_exit_2_naming_the_flag(capsys, tmp_path, argv, what):
    try:                                   # a bad value stops argparse (SystemExit), a bad name the bake
        code, out, err = run(capsys, "bake", ARM, "--out", str(tmp_path), "--frames", "4", *argv)
    except SystemExit as e:
        code, err = e.code, capsys.readouterr().err
    assert code == 2 and what in err, err
    assert "Traceback" not in err
