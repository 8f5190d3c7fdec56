"""Loop-aware bakes (`jiggle bake --loop`, sim/bake/loop.py): a cycle baked in its periodic steady state.

- The cycle written is simulated motion: equal, within 0.1 mm, to the same cycle repeated many times in a row
  (root travel and all) and baked plainly, taken well after the start.
- auto judges a closed cycle, an open one (the character's own animation ending a key before its start) and a
  mocap take (not a cycle); bake.json records it with the warm-up; compare's metrics.json the wrap.
- The last frame's jiggle equals the first's; a resumed loop bake equals an unbroken one bit for bit.
- three.js loops the glb across the wrap without a jump.
"""
from __future__ import annotations

import json
import shutil
import subprocess
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from conftest import asset

from jiggle.rig.motion import quat
from jiggle.sim.app.cli import main
from jiggle.sim.bake.caches import read_npz

JS = Path(__file__).resolve().parents[1] / "js"
PERIOD, KEY_FPS, FPS = 0.5, 60.0, 30.0
TRAVEL = np.array([0.6, 0.0, 0.0])          # metres of root travel per cycle: a walk moving forward


def run(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def offset(bake_dir: Path) -> np.ndarray:
    d = read_npz(bake_dir / "bake.npz")
    return np.asarray(d.skin_final, np.float64) - d.skin_static


# ---------------------------------------------------------------------------------------- the cycle
def cycle_clip(base, repeats: int):
    """`repeats` periods of a synthetic cycle on the skeleton of `base` (a rig.motion.clip.Clip): every joint's
    first-frame rotation turned by sinusoids of the period (a different phase and axis per joint), the root
    bobbing and travelling TRAVEL per period; keys at KEY_FPS, the last repeating the first pose (closed)."""
    n = int(round(PERIOD * KEY_FPS)) * repeats + 1
    t = np.arange(n) / KEY_FPS
    J = base.num_joints
    rng = np.random.default_rng(3)
    axes = rng.normal(size=(J, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    amp, phase = rng.uniform(0.05, 0.35, J), rng.uniform(0, 2 * np.pi, J)
    w = 2 * np.pi / PERIOD
    ang = amp[None] * (np.sin(w * t[:, None] + phase[None]) + 0.4 * np.sin(2 * w * t[:, None] + 2 * phase[None]))
    turn = np.concatenate([np.cos(ang / 2)[..., None], np.sin(ang / 2)[..., None] * axes[None]], axis=-1)
    rot = quat.mul(np.broadcast_to(base.rotations[:1], (n, J, 4)), turn)
    rot[:, base.parents < 0] = base.rotations[:1, base.parents < 0]
    tra = np.repeat(base.translations[:1], n, axis=0)
    roots = base.parents < 0
    tra[:, roots] += (t / PERIOD)[:, None, None] * TRAVEL + np.array([0, 0, 0.03])[None, None] * np.sin(w * t)[:, None, None]
    return replace(base, rotations=rot, translations=tra, fps=KEY_FPS, name=f"cycle x{repeats}")


@pytest.fixture(scope="module")
def cesium():
    from jiggle.rig.character.load import load_character
    from jiggle.rig.motion.mocap import load_clip
    from jiggle.rig.muscle.fit import fit_musculature
    path = str(asset("characters/CesiumMan.glb"))
    character = load_character(path)
    base = load_clip(path)
    assert base.joint_names == tuple(character.joint_names)
    return character, base, fit_musculature(character, "auto")


def bake_clip(clip, cesium, out: Path, **req):
    from jiggle.sim.bake.baker import bake
    from jiggle.sim.bake.setup import BakeRequest, prepare_from
    character, _, mus = cesium
    setup = prepare_from(clip, character, mus, BakeRequest(fps=FPS, formats=("npz",), **req))
    return setup, bake(setup, str(out))


def test_the_written_cycle_is_the_steady_state_of_the_clip_repeated(cesium, tmp_path):
    """--loop on of one period equals, within 0.1 mm, a period of the same cycle repeated 12 times in a row (its
    root travelling on) and baked plainly (--loop off) from the quasi-static start, taken after 10 periods: by then
    the start has decayed. Its last frame repeats the first: pose shifted by the travel, jiggle equal."""
    character, base, _ = cesium
    setup, summary = bake_clip(cycle_clip(base, 1), cesium, tmp_path / "loop", loop="auto")
    lp = summary["loop"]
    assert lp["on"] and lp["kind"] == "closed" and lp["period_s"] == pytest.approx(PERIOD)
    assert lp["root_travel_m"] == pytest.approx(TRAVEL.tolist(), abs=1e-6)
    assert lp["warmup"]["converged"] and 2 <= lp["warmup"]["cycles"] <= 12
    n = int(round(PERIOD * FPS))
    loop = read_npz(tmp_path / "loop" / "bake.npz")
    assert loop.skin_final.shape[0] == n + 1 and loop.times[-1] == pytest.approx(PERIOD)
    _, plain_summary = bake_clip(cycle_clip(base, 12), cesium, tmp_path / "plain", loop="off")
    assert plain_summary["loop"]["on"] is False
    plain = read_npz(tmp_path / "plain" / "bake.npz")
    k = 10
    seg = slice(k * n, (k + 1) * n + 1)
    np.testing.assert_allclose(plain.times[seg] - k * PERIOD, loop.times, atol=1e-9)
    shift = (k * TRAVEL)[None, None]
    err_final = np.abs(plain.skin_final[seg] - shift - loop.skin_final).max() * 1000
    d_plain = plain.skin_final[seg].astype(np.float64) - plain.skin_static[seg]
    d_loop = offset(tmp_path / "loop")
    err_d = np.abs(d_plain - d_loop).max() * 1000
    jiggle = np.linalg.norm(d_loop, axis=2).max() * 1000
    assert jiggle > 2.0, f"the cycle barely jiggles ({jiggle:.2f} mm): the test would prove nothing"
    assert err_d < 0.1 and err_final < 0.1, (err_d, err_final)
    # the seam: the last frame's pose is the first's moved by the travel, its jiggle the first's
    np.testing.assert_allclose(loop.skin_static[-1] - loop.skin_static[0], np.broadcast_to(TRAVEL, (len(
        loop.skin_static[0]), 3)), atol=1e-4)
    assert np.linalg.norm(d_loop[-1] - d_loop[0], axis=1).max() * 1000 < 0.05
    assert summary["loop"]["seam"]["wrap_mm"] < 0.05


# ---------------------------------------------------------------------------------------- the judge
def test_auto_judges_closed_open_and_plain_and_records_it(capsys, tmp_path):
    """Cat's Walk (last key = first pose): closed, period = its length, frames 0..n. Frog's Walk (last key a step
    before the first): open, period one key longer, the frame at the period the first again. A CMU take on
    CesiumMan: not a cycle, baked plainly. bake.json and the npz's params record each; metrics.json the wrap."""
    cat, frog = asset("characters/zoo/Cat.glb"), asset("characters/zoo/Frog.glb")
    code, _, err = run(capsys, "bake", "--character", str(cat), "--animation", "Walk", "--out", str(tmp_path / "cat"),
                       "--formats", "npz", "--chunk", "4")
    assert code == 0, err
    lp = json.loads((tmp_path / "cat" / "bake.json").read_text())["loop"]
    assert lp["mode"] == "auto" and lp["on"] and lp["kind"] == "closed" and lp["closed"] and lp["own_animation"]
    assert lp["period_s"] == pytest.approx(13 / 30) and lp["cycle_frames"] == 13 and lp["fps"] == 30.0
    assert lp["warmup"]["converged"] and lp["warmup"]["change_mm"] < 0.01
    d = offset(tmp_path / "cat")
    steps = np.linalg.norm(np.diff(d, axis=0), axis=2).max(axis=1) * 1000
    wrap = np.linalg.norm(d[-1] - d[0], axis=1).max() * 1000
    assert d.shape[0] == 14 and wrap <= max(0.25 * np.median(steps), 0.5)
    assert json.loads(read_npz(tmp_path / "cat" / "bake.npz").params)["loop"]["kind"] == "closed"
    code, _, err = run(capsys, "compare", str(tmp_path / "cat"), "--no-render", "-q")
    assert code == 0, err
    m = json.loads((tmp_path / "cat" / "metrics.json").read_text())["loop"]
    assert m["looped"] and m["repeats_first"] and m["wrap_mm"] == pytest.approx(wrap, abs=1e-3)
    assert m["wrap_step_mm"] <= m["step_max_mm"] and m["wrap_ratio"] < 0.25

    code, _, err = run(capsys, "bake", "--character", str(frog), "--animation", "Walk", "--out",
                       str(tmp_path / "frog"), "--formats", "npz")
    assert code == 0, err
    lp = json.loads((tmp_path / "frog" / "bake.json").read_text())["loop"]
    assert lp["kind"] == "open" and not lp["closed"] and lp["period_s"] == pytest.approx(31 / 30)
    assert lp["end_gap_pct_of_height"] > 1.0 and lp["end_gap_pct_of_height"] <= lp["largest_key_step_pct_of_height"]
    f = read_npz(tmp_path / "frog" / "bake.npz")
    assert len(f.times) == 31 and f.times[-1] == pytest.approx(30 / 30)        # the clip's own frames, 0..n-1
    d = offset(tmp_path / "frog")
    steps = np.linalg.norm(np.diff(d, axis=0), axis=2).max(axis=1)
    assert np.linalg.norm(d[0] - d[-1], axis=1).max() <= steps.max()          # wraps no harder than its steps
    assert lp["seam"]["wrap_step_mm"] == lp["seam"]["wrap_mm"] <= steps.max() * 1000 + 1e-3

    code, _, err = run(capsys, "bake", "--character", str(asset("characters/CesiumMan.glb")), "--clip",
                       str(asset("mocap/cmu_bvh/09_11.bvh")), "--out", str(tmp_path / "cmu"), "--formats", "npz",
                       "--frames", "6")
    assert code == 0, err
    lp = json.loads((tmp_path / "cmu" / "bake.json").read_text())["loop"]
    assert lp["on"] is False and lp["kind"] is None and lp["why"].startswith("not a cycle")


def test_loop_flag_reaches_the_api_and_is_checked(capsys, tmp_path):
    """jiggle.bake(..., loop="off") parses through the command's parser; a bad value is a usage error; --loop on
    of the built-in scene (a single motion) is refused naming --loop."""
    import jiggle
    from jiggle.rig.base.errors import InputError
    b = jiggle.bake(character=str(asset("characters/zoo/Cat.glb")), animation="Walk", loop="off", frames=4,
                    out=str(tmp_path / "api"), formats="npz", progress=False)
    assert json.loads((tmp_path / "api" / "bake.json").read_text())["loop"]["on"] is False
    del b
    with pytest.raises(InputError, match="loop"):
        jiggle.bake(character=str(asset("characters/zoo/Cat.glb")), loop="sometimes", out=str(tmp_path / "bad"),
                    progress=False)
    arm = Path(__file__).resolve().parents[2] / "scenes" / "simple_arm.toml"
    code, _, err = run(capsys, "bake", str(arm), "--loop", "on", "--out", str(tmp_path / "arm"), "--frames", "3")
    assert code == 2 and "--loop" in err


def test_a_resumed_loop_bake_equals_an_unbroken_one(capsys, tmp_path, monkeypatch):
    """Ctrl-C in chunk 2 of a looping bake (the warm-up stored in .partial/loop.npz), then --resume: the caches and
    the loop record equal an unbroken bake's bit for bit."""
    from jiggle.sim.bake import baker as bake_mod
    cat = str(asset("characters/zoo/Cat.glb"))
    argv = ["bake", "--character", cat, "--animation", "Dance", "--formats", "npz,pc2", "--chunk", "6"]
    code, _, err = run(capsys, *argv, "--out", str(tmp_path / "whole"))
    assert code == 0, err
    real = bake_mod.Baker.chunk

    def chunk(self, c, state):
        if c == 2:
            raise KeyboardInterrupt
        return real(self, c, state)
    monkeypatch.setattr(bake_mod.Baker, "chunk", chunk)
    code, _, err = run(capsys, *argv, "--out", str(tmp_path / "cut"))
    assert code == 130 and (tmp_path / "cut" / ".partial" / "loop.npz").is_file()
    monkeypatch.setattr(bake_mod.Baker, "chunk", real)
    code, _, err = run(capsys, *argv, "--out", str(tmp_path / "cut"), "--resume")
    assert code == 0, err
    a, b = read_npz(tmp_path / "whole" / "bake.npz"), read_npz(tmp_path / "cut" / "bake.npz")
    for k in ("skin_final", "skin_static", "muscle_cvs_dynamic", "times"):
        np.testing.assert_array_equal(getattr(a, k), getattr(b, k), err_msg=k)
    assert (tmp_path / "whole" / "bake.pc2").read_bytes() == (tmp_path / "cut" / "bake.pc2").read_bytes()
    la = json.loads((tmp_path / "whole" / "bake.json").read_text())["loop"]
    lb = json.loads((tmp_path / "cut" / "bake.json").read_text())["loop"]
    la["warmup"].pop("seconds"), lb["warmup"].pop("seconds")
    assert la == lb


# ---------------------------------------------------------------------------------------- three.js
def test_three_js_loops_the_glb_without_a_jump(tmp_path):
    """three.js (AnimationMixer, LoopRepeat, as an engine loops a clip) plays Cat's looping Walk glb on through
    the wrap: the animation lasts one period; the skin just past the wrap is the skin just past the start, and
    the jump across the wrap (period - e to period + e) is no larger than across any key inside the cycle."""
    if shutil.which("node") is None or not (JS / "node_modules" / "three").is_dir():
        pytest.skip("Node.js or tests/js/node_modules/three not found (./dev.sh install)")
    out = tmp_path / "cat"
    assert main(["-q", "bake", "--character", str(asset("characters/zoo/Cat.glb")), "--animation", "Walk", "--out",
                 str(out), "--formats", "glb"]) == 0
    d = read_npz(out / "bake.npz")
    P, h, e = float(d.times[-1]), 1.0 / d.fps, 0.25 / d.fps
    keys = d.times[1:-1]
    times = [P - e, P + e, e, P + 3 * h, 3 * h] + [float(t) + s for t in keys for s in (-e, e)]
    res = tmp_path / "played.json"
    p = subprocess.run(["node", str(JS / "play_glb.mjs"), str(out / "bake.glb"), json.dumps(times), str(res), "loop"],
                       capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    got = json.loads(res.read_text())
    assert got["duration"] == pytest.approx(P, abs=1e-4)
    f = [np.asarray(x, np.float64).reshape(-1, 3) for x in got["frames"]]
    jump = lambda a, b: float(np.linalg.norm(a - b, axis=1).max()) * 1000        # noqa: E731
    assert jump(f[1], f[2]) < 0.05 and jump(f[3], f[4]) < 0.05                   # past the wrap = past the start
    wrap = jump(f[0], f[1])
    inside = [jump(f[5 + 2 * i], f[6 + 2 * i]) for i in range(len(keys))]
    assert wrap <= max(inside) + 1e-6, (wrap, max(inside))
