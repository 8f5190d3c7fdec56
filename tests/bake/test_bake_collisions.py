"""`jiggle bake --collisions`: contacts and the skin check reach bake.json, a killed (interrupted) bake
with collisions resumes to the same caches and contacts bit for bit, --no-collisions bakes what a bake
without colliders bakes, and bad input names the file, line and field."""
import json
from pathlib import Path

import numpy as np
import pytest
from test_bake import ARM, KEYS, run  # noqa: E402 - tests/bake is on the path (rootdir conftest)

from jiggle.sim.app.cli import main
from jiggle.sim.bake.caches import read_npz


def bake(capsys, out, *extra):
    code, o, err = run(capsys, "bake", ARM, "--out", str(out), "--fps", "60", "--chunk", "16", "--formats", "npz",
                       *extra)
    assert code == 0, err
    return json.loads((out / "bake.json").read_text())


@pytest.fixture(scope="module")
def arm_collide(tmp_path_factory):
    out = tmp_path_factory.mktemp("arm_collide")
    assert main(["bake", ARM, "--out", str(out), "--fps", "60", "--chunk", "16", "--formats", "npz",
                 "--collisions"]) == 0
    return out


def test_collisions_reach_bake_json(arm_collide):
    """bake.json names the colliders, the floor, per frame the deepest contact and the skin check."""
    summary = json.loads((arm_collide / "bake.json").read_text())
    c = summary["contacts"]
    assert summary["params"]["settings"]["collisions"] is True
    assert c["colliders"][-1] == "floor" and len(c["capsule_radius_mm"]) == len(c["colliders"]) - 1
    T = summary["frames"]
    assert len(c["per_frame"]["max_penetration_mm"]) == T
    assert len(c["skin_inside"]["static"]) == T and len(c["skin_inside"]["final"]) == T


def test_interrupted_bake_with_collisions_resumes_bit_for_bit(capsys, tmp_path, arm_collide, monkeypatch):
    """Ctrl-C in chunk 3 with collisions on, then --resume: the caches equal the unbroken bake's, and so do
    bake.json's contacts (kept with each chunk's state)."""
    from jiggle.sim.bake import baker as bake_mod
    real = bake_mod.Baker.chunk

    def chunk(self, c, state):
        if c == 3:
            raise KeyboardInterrupt
        return real(self, c, state)
    monkeypatch.setattr(bake_mod.Baker, "chunk", chunk)
    code, out, err = run(capsys, "bake", ARM, "--out", str(tmp_path), "--fps", "60", "--chunk", "16",
                         "--formats", "npz", "--collisions")
    assert code == 130
    monkeypatch.setattr(bake_mod.Baker, "chunk", real)
    code, out, err = run(capsys, "bake", ARM, "--out", str(tmp_path), "--fps", "60", "--chunk", "16",
                         "--formats", "npz", "--collisions", "--resume")
    assert code == 0, err
    da, db = read_npz(tmp_path / "bake.npz"), read_npz(arm_collide / "bake.npz")
    for k in KEYS:
        np.testing.assert_array_equal(getattr(da, k), getattr(db, k), err_msg=k)
    ca = json.loads((tmp_path / "bake.json").read_text())["contacts"]
    cb = json.loads((arm_collide / "bake.json").read_text())["contacts"]
    assert ca == cb


def test_no_collisions_bakes_what_a_bake_without_colliders_bakes(capsys, tmp_path, monkeypatch):
    """--no-collisions: the bake's arrays are those of the pipeline without any collider code (the
    simulate stage called as before issue 21), bit for bit."""
    a = bake(capsys, tmp_path / "a", "--no-collisions", "--frames", "40")
    assert "contacts" not in a and a["params"]["settings"]["collisions"] is False
    from jiggle.sim.jiggle import simulate as sim_mod
    real = sim_mod.run

    def plain(*args, colliders=None, contacts=None, **kw):
        assert colliders is None
        return real(*args, **kw)
    monkeypatch.setattr(sim_mod, "run", plain)
    bake(capsys, tmp_path / "b", "--no-collisions", "--frames", "40")
    da, db = read_npz(tmp_path / "a" / "bake.npz"), read_npz(tmp_path / "b" / "bake.npz")
    for k in KEYS:
        np.testing.assert_array_equal(getattr(da, k), getattr(db, k), err_msg=k)


def test_bad_collisions_value_names_file_line_and_field(capsys, tmp_path):
    p = tmp_path / "s.toml"
    p.write_text('builtin = "simple_arm"\n[jiggle]\nsubsteps = 2\ncollisions = "yes"\n')
    code, out, err = run(capsys, "bake", str(p), "--out", str(tmp_path / "o"))
    assert code == 2 and "s.toml:4:" in err and "jiggle.collisions" in err and "true or false" in err
    assert len(err.strip().splitlines()) <= 3
    with pytest.raises(SystemExit) as e:
        main(["bake", ARM, "--collisions=yes", "--out", str(tmp_path / "x")])
    assert e.value.code == 2


def test_the_jiggle_never_takes_the_skin_into_another_parts_capsule(tmp_path, monkeypatch):
    """CesiumMan on CMU 01_01, 6-7 s (a love handle jiggling against the upper arm's capsule): with the skin
    pull-back, no frame has more skin vertices inside another part's capsule in skin_final than in
    skin_static, and bake.json says how many vertices were pulled back and how far (mm); the same bake with
    the pull-back disabled (counting only) has frames where the final skin has more, so the test would fail
    without it. The pulled-back vertices moved by no more than their jiggle."""
    from conftest import asset

    from jiggle.sim.jiggle import colliders as col
    clip, cesium = str(asset("mocap/cmu_bvh/01_01.bvh")), str(asset("characters/CesiumMan.glb"))
    args = ["bake", "--clip", clip, "--character", cesium, "--start", "6.0", "--end", "7.0", "--formats", "npz"]
    assert main([*args, "--out", str(tmp_path / "on")]) == 0
    si = json.loads((tmp_path / "on" / "bake.json").read_text())["contacts"]["skin_inside"]
    assert si["frames_final_above_static"] == 0 and all(f <= s for f, s in zip(si["final"], si["static"]))
    assert si["max_kept_out"] >= 1 and 0.0 < si["max_pull_mm"] < 5.0
    real = col.SkinCheck.keep_out

    def count_only(self, world, static, final, device="cpu", rigid=None):
        out = real(self, world, static, final.copy(), device)
        out["final"] = real(self, world, final, final.copy(), device)["static"]     # SkinCheck.count, unpatched
        return out
    monkeypatch.setattr(col.SkinCheck, "keep_out", count_only)
    assert main([*args, "--out", str(tmp_path / "off")]) == 0
    off = json.loads((tmp_path / "off" / "bake.json").read_text())["contacts"]["skin_inside"]
    assert off["frames_final_above_static"] >= 1
    a, b = read_npz(tmp_path / "on" / "bake.npz"), read_npz(tmp_path / "off" / "bake.npz")
    np.testing.assert_array_equal(a.skin_static, b.skin_static)
    pulled = np.linalg.norm(a.skin_final - b.skin_final, axis=2)
    jiggle = np.linalg.norm(b.skin_final - b.skin_static, axis=2)
    assert 0 < (pulled > 0).sum() <= 2 * len(si["kept_out"]) and np.all(pulled <= jiggle + 1e-7)


def test_muscle_collisions_bake_resumes_bit_for_bit(capsys, tmp_path, monkeypatch):
    """--muscle-collisions on the demo scene (28 muscles, 334 pairs of muscles of different bones): bake.json
    says so and names the muscles among what a particle may hit, and a bake interrupted in chunk 2 and
    resumed equals the unbroken bake bit for bit (the particle state after each step is all a step carries)."""
    from jiggle.sim.bake import baker as bake_mod
    scene = str(Path(__file__).resolve().parents[2] / "scenes" / "default.toml")
    args = ["bake", scene, "--frames", "40", "--chunk", "16", "--formats", "npz", "--muscle-collisions"]
    code, _, err = run(capsys, *args, "--out", str(tmp_path / "a"))
    assert code == 0, err
    s = json.loads((tmp_path / "a" / "bake.json").read_text())
    mc = s["contacts"]["muscle_collisions"]
    assert s["params"]["settings"]["muscle_collisions"] is True and mc["muscle_pairs"] > 100
    real = bake_mod.Baker.chunk

    def chunk(self, c, state):
        if c == 2:
            raise KeyboardInterrupt
        return real(self, c, state)
    monkeypatch.setattr(bake_mod.Baker, "chunk", chunk)
    code, _, _ = run(capsys, *args, "--out", str(tmp_path / "b"))
    assert code == 130
    monkeypatch.setattr(bake_mod.Baker, "chunk", real)
    code, _, err = run(capsys, *args, "--out", str(tmp_path / "b"), "--resume")
    assert code == 0, err
    da, db = read_npz(tmp_path / "a" / "bake.npz"), read_npz(tmp_path / "b" / "bake.npz")
    for k in KEYS:
        np.testing.assert_array_equal(getattr(da, k), getattr(db, k), err_msg=k)
    assert json.loads((tmp_path / "b" / "bake.json").read_text())["contacts"] == s["contacts"]
