"""`jiggle simulate`: the simple arm's biceps overshoots and settles, the outputs are written, the belly
jiggles on a runner, and bad input is one line with exit code 2."""
import json
from pathlib import Path

import numpy as np
import pytest
from conftest import ASSETS, asset

from jiggle.sim.app.cli import main

ROOT = Path(__file__).resolve().parents[2]
JUMPING_JACKS = ROOT / "scenes" / "motions" / "jumping_jacks.toml"


def run(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_arm_biceps_overshoots_at_the_stop_and_rings_down():
    """A goal-spring particle (y'' = -w^2 y - 2 z w y' - g'' for the offset y = x - goal, w ~ 2 pi 5.7 Hz
    at the belly, z = 0.5) lags the goal while the forearm speeds up and runs past it while it slows
    down: the offset peaks as the flex stops, swings back past the static shape (an underdamped ring,
    about exp(-pi z / sqrt(1 - z^2)) = 16% of the peak per half cycle before the neighbour springs), and
    decays as exp(-z w t): < 2% of the peak within half a second of the stop."""
    from jiggle.rig.muscle.simple_arm import FLEX_HOLD, FLEX_RISE, FLEX_START, simple_arm
    from jiggle.sim.jiggle.params import JiggleSettings
    from jiggle.sim.jiggle.materials import default_jiggles
    from jiggle.sim.jiggle.secondary import jiggle_rig
    arm = simple_arm(rings=24, around=16)
    stop = FLEX_START + FLEX_RISE
    times = np.arange(0.0, stop + FLEX_HOLD, 1.0 / 240.0)
    res = jiggle_rig(arm.rig, default_jiggles(arm.rig), arm.world_at, times, JiggleSettings(substeps=2))
    amp = res.amplitude()[:, 0]
    k = int(np.argmax(amp))
    assert 5e-3 < amp[k] < 3e-2                                   # clearly visible: several mm to cm
    assert stop - 0.01 <= times[k] <= stop + 0.05                 # at the stop, not while speeding up
    off = (res.dynamic - res.static).reshape(len(times), -1)
    swing = off @ (off[k] / np.linalg.norm(off[k]))               # signed, along the peak's offset
    assert swing[times > times[k]].min() < -0.2 * amp[k]          # swings back past the static shape
    assert amp[times > stop + 0.5].max() < 0.02 * amp[k]          # and settles during the hold
    assert amp[-1] < 0.01 * amp[k]


def test_arm_default_run_writes_facts_and_plot(capsys, tmp_path):
    code, out, err = run(capsys, "simulate", "--no-render", "--fps", "120", "--out", str(tmp_path))
    assert code == 0, err
    assert "simple arm: 1 muscle, 40 particles" in out and "biceps" in out
    facts = json.loads((tmp_path / "jiggle.json").read_text())
    b = facts["muscles"]["biceps"]
    assert b["peak_mm"] > 5.0 and b["end_mm"] < 0.05 * b["peak_mm"] and b["settle_s"] is not None
    assert facts["frames_written"]["count"] == 0 and facts["settings"]["substeps"] == 4
    assert (tmp_path / "amplitude.png").stat().st_size > 0
    assert not list(tmp_path.glob(".*tmp*")), "temporary files left behind"


def test_arm_renders_side_by_side_frames(capsys, tmp_path):
    """The one render smoke test: every 5th of 12 frames, both panels drawn, the heat map coloured."""
    from PIL import Image

    from jiggle.sim.app.outputs.simulate import PANEL
    code, out, err = run(capsys, "simulate", "--frames", "12", "--every", "5", "--out", str(tmp_path))
    assert code == 0, err
    facts = json.loads((tmp_path / "jiggle.json").read_text())
    assert facts["frames_written"]["files"] == [f"frames/frame_{k:04d}.png" for k in (0, 5, 10)]
    assert facts["skin"]["peak_move_mm"] > 0.1
    img = np.asarray(Image.open(tmp_path / "frames" / "frame_0010.png").convert("RGB"), float)
    assert img.shape == (PANEL[1], 2 * PANEL[0], 3)
    for half in (img[:, :PANEL[0]], img[:, PANEL[0]:]):
        assert half.std() > 10                                    # each panel draws something
    assert not list(tmp_path.rglob(".*tmp*")), "temporary files left behind"


def test_blend_zero_gives_the_static_skin_and_replaces_earlier_frames(capsys, tmp_path):
    frames = tmp_path / "frames"
    frames.mkdir()
    for k in (0, 5, 10):                      # an earlier run's pictures
        (frames / f"frame_{k:04d}.png").write_bytes(b"old")
    (frames / "notes.txt").write_text("mine")
    code, out, err = run(capsys, "simulate", "--blend", "0", "--frames", "3", "--every", "2", "--out", str(tmp_path))
    assert code == 0, err
    facts = json.loads((tmp_path / "jiggle.json").read_text())
    assert facts["muscles"]["biceps"]["blended_peak_mm"] == 0.0 and facts["skin"]["peak_move_mm"] == 0.0
    assert facts["settings"]["blend"] == [[0.0, 0.0]]
    assert sorted(p.name for p in frames.iterdir()) == ["frame_0000.png", "frame_0002.png", "notes.txt"]
    assert (frames / "frame_0000.png").stat().st_size > 1000


def _scene(tmp_path, jiggle: str) -> str:
    p = tmp_path / "scene.toml"
    p.write_text(f'[motion]\nfile = "{JUMPING_JACKS.as_posix()}"\n\n[jiggle]\n{jiggle}\n')
    return str(p)


@pytest.mark.parametrize("argv, what", [
    (["--blend", "1.5"], "argument --blend: blend must be in [0, 1], got 1.5"),
    (["--jiggle", "-1"], "argument --jiggle: strength must be in [0, 1], got -1"),
    (["--damping", "*_fat=[[0,0.3],[0,0.2]]"], "argument --damping: *_fat=[[0,0.3],[0,0.2]]: damping key times must "
                                               "increase"),
    (["--substeps", "0"], "--substeps must be at least 1, got '0'"),
    (["--every", "0"], "--every must be at least 1"),
])
def test_bad_options_exit_2(capsys, tmp_path, argv, what):
    with pytest.raises(SystemExit) as e:
        main(["simulate", *argv, "--out", str(tmp_path)])
    err = capsys.readouterr().err
    assert e.value.code == 2 and what in err and "Traceback" not in err


@pytest.mark.parametrize("jiggle, what", [
    ("substep = 2", "scene.toml:5: jiggle.substep: unknown key; expected one of blend, colliders, collisions, "
                    "cut_jump"),
    ("blend = [[0.0, 0.0], [1.0, 1.5]]", "scene.toml:5: jiggle.blend: blend must be in [0, 1], got 1.5 at t = 1 s"),
    ("[jiggle.muscles.belly_fat]\ndensity = -900.0", "jiggle.muscles.belly_fat.density: density must be > 0"),
    ("[jiggle.muscles.belly_fat]\ndampin = 0.3", "scene.toml:6: jiggle.muscles.belly_fat.dampin: unknown key; "
                                                 "expected one of frequency, damping"),
])
def test_bad_scene_exits_2_naming_file_line_and_key(capsys, tmp_path, jiggle, what):
    code, out, err = run(capsys, "simulate", _scene(tmp_path, jiggle), "--no-render", "--out", str(tmp_path))
    assert code == 2 and what in err, err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_unknown_muscle_in_scene_names_it_and_lists_the_rig(capsys, tmp_path):
    scene = _scene(tmp_path, "[jiggle.muscles.belly_fatt]\nblend = 0.5")
    code, out, err = run(capsys, "simulate", scene, "--no-render", "--frames", "2", "--resolution", "10000",
                         "--out", str(tmp_path))
    assert code == 2, err
    line = err.strip().splitlines()[-1]
    assert "scene.toml:5: jiggle.muscles.belly_fatt: the rig has no muscle 'belly_fatt'" in line
    assert "belly_fat," in line and "left_biceps" in line


@pytest.mark.parametrize("argv, what", [
    (["--clip", "MISSING"], "missing.bvh: clip file not found"),
    (["--character", "x.obj"], "--character: a CHARACTER needs a motion"),
    (["--character", "MISSING.glb"], "missing.bvh.glb"),
    (["--template", "human"], "--template"),
    (["--end", "9"], "--start/--end"),
])
def test_bad_sources_exit_2(capsys, tmp_path, argv, what):
    argv = [str(tmp_path / "missing.bvh") + a[7:] if a.startswith("MISSING") else a for a in argv]
    code, out, err = run(capsys, "simulate", *argv, "--no-render", "--out", str(tmp_path))
    assert code == 2 and what in err and "Traceback" not in err, err


def test_scene_with_an_unset_variable_says_which(capsys, tmp_path, monkeypatch):
    monkeypatch.delenv("JIGGLE_ASSETS", raising=False)
    code, out, err = run(capsys, "simulate", str(ROOT / "scenes" / "belly_run.toml"), "--no-render",
                         "--out", str(tmp_path))
    assert code == 2 and "motion.file: environment variable JIGGLE_ASSETS is not set" in err


@pytest.mark.slow
def test_belly_scene_jiggles_on_the_runner(capsys, tmp_path, monkeypatch):
    asset("mocap/cmu_bvh/09_11.bvh")
    monkeypatch.setenv("JIGGLE_ASSETS", str(ASSETS))
    code, out, err = run(capsys, "simulate", str(ROOT / "scenes" / "belly_run.toml"), "--frames", "24",
                         "--resolution", "10000", "--no-render", "--out", str(tmp_path))
    assert code == 0, err
    facts = json.loads((tmp_path / "jiggle.json").read_text())
    belly = facts["muscles"]["belly_fat"]
    assert np.isfinite(belly["peak_mm"]) and 1.0 < belly["peak_mm"] < 100.0
    assert 0.0 < belly["blended_peak_mm"] <= belly["peak_mm"]
    assert belly["blend"] == [[0.0, 0.0], [0.3, 1.0]]            # the scene's keyed blend
    assert facts["muscles"]["left_glute_fat"]["blended_peak_mm"] == 0.0      # the scene's global blend 0
    assert facts["frames"] == 24 and facts["focus"] == ["belly_fat"]
    assert "belly_fat" in out and "blended out" in out
