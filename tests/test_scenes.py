"""Every scene in scenes/ runs (reduced), and the built-in keyframed motion is smooth and sound."""
from pathlib import Path

import numpy as np
import pytest

from rig.errors import InputError
from rig.keyframes import read_keyframes
from sim.play import drive_kinematic
from sim.scene import load_scene

SCENES = sorted((Path(__file__).resolve().parents[1] / "scenes").glob("*.toml"))
MOTIONS = sorted((Path(__file__).resolve().parents[1] / "scenes" / "motions").glob("*.toml"))


def test_there_is_a_default_scene():
    assert any(p.name == "default.toml" for p in SCENES)


@pytest.mark.parametrize("path", SCENES, ids=lambda p: p.stem)
def test_scene_runs_reduced(path):
    scene = load_scene(path)
    clip = scene.clip.frames(0, 12)
    motion = drive_kinematic(clip, clip.times)
    assert motion.positions.shape == (12, clip.num_joints, 3)
    assert np.all(np.isfinite(motion.positions))


@pytest.mark.parametrize("path", MOTIONS, ids=lambda p: p.stem)
def test_built_in_motion_is_smooth_loops_and_stays_above_the_floor(path):
    clip = read_keyframes(path)
    rot, pos = clip.world()
    ends = clip.end_world(rot, pos)
    lowest = np.concatenate([pos, ends], axis=1)[..., 2].min(axis=1)
    assert lowest.min() > -0.01  # toes may touch, not sink: 1 cm
    # loops: the last frame is the first pose, and velocity is continuous across the seam
    np.testing.assert_allclose(pos[-1], pos[0], atol=1e-9)
    # C2 across the seam: its second difference is no larger than those inside the cycle
    seam = np.abs(pos[1] - 2 * pos[0] + pos[-2]).max()
    inside = np.abs(pos[2:] - 2 * pos[1:-1] + pos[:-2]).max()
    assert seam <= inside + 1e-9
    # energetic: the hands travel (what jiggle needs to show)
    assert np.ptp(pos[..., 2], axis=0).max() > 0.8


def test_keyframe_errors_name_the_field(tmp_path):
    base = read_keyframes(MOTIONS[0])
    assert base.num_joints > 10
    text = MOTIONS[0].read_text()
    bad = tmp_path / "bad.toml"
    bad.write_text(text.replace('l_upper_arm = [0.0, -160.0, 0.0]', 'l_upper_armm = [0.0, -160.0, 0.0]'))
    with pytest.raises(InputError, match=r"keys\[2\].rotate.l_upper_armm"):
        read_keyframes(bad)
    bad.write_text(text.replace("time = 0.5", "time = 0.2"))
    with pytest.raises(InputError, match="increase"):
        read_keyframes(bad)
    bad.write_text(text.replace("fps = 60", "fps = [60"))
    with pytest.raises(InputError, match="TOML"):
        read_keyframes(bad)


def test_scene_errors(tmp_path):
    p = tmp_path / "s.toml"
    p.write_text('[motion]\nfile = "nowhere.bvh"\n')
    with pytest.raises(InputError, match="not found"):
        load_scene(p)
    p.write_text('[motion]\nfile = "x.bvh"\nspeed = 2\n')
    with pytest.raises(InputError, match="motion.speed"):
        load_scene(p)
