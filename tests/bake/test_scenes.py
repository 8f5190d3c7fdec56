"""Every scene in scenes/ runs (reduced), and the built-in keyframed motion is smooth and sound."""
from pathlib import Path

import numpy as np
import pytest

from jiggle.rig.base.errors import InputError
from jiggle.rig.motion.keyframes import read_keyframes
from jiggle.sim.bake.scene import load_scene
from jiggle.sim.drive.motion import drive_kinematic

SCENES = sorted((Path(__file__).resolve().parents[2] / "scenes").glob("*.toml"))
MOTIONS = sorted((Path(__file__).resolve().parents[2] / "scenes" / "motions").glob("*.toml"))


@pytest.fixture(autouse=True)
def _assets_variable(request, monkeypatch):
    """Scenes whose motion lives in the shared assets name it "${JIGGLE_ASSETS}/...": point the variable
    at the assets the tests use, and skip such a scene when they are absent."""
    from conftest import ASSETS
    monkeypatch.setenv("JIGGLE_ASSETS", str(ASSETS))
    path = getattr(request.node, "callspec", None) and request.node.callspec.params.get("path")
    if path is not None and "${JIGGLE_ASSETS}" in Path(path).read_text() and not ASSETS.exists():
        pytest.skip(f"scene {Path(path).name} needs the shared assets, not found under {ASSETS}")


def test_there_is_a_default_scene():
    assert any(p.name == "default.toml" for p in SCENES)


@pytest.mark.slow
@pytest.mark.parametrize("path", SCENES, ids=lambda p: p.stem)
def test_scene_bakes_reduced(path, tmp_path):
    """Every scene bakes (8 frames, a coarse generated body) into a cache with finite, moving skin;
    a scene without [motion] takes the clip from --clip (a CMU BVH when present, else the demo's)."""
    from conftest import ASSETS

    from jiggle.sim.app.cli import main
    from jiggle.sim.bake.caches import read_npz
    scene = load_scene(path)
    argv = ["bake", str(path), "--out", str(tmp_path), "--frames", "8", "--formats", "npz"]
    if scene.clip is None and scene.builtin is None:
        bvh = ASSETS / "mocap" / "cmu_bvh" / "02_04.bvh"
        argv += ["--clip", str(bvh if bvh.exists() else MOTIONS[0])]
    if scene.builtin is None and scene.character.file is None:
        argv += ["--resolution", "6000"]
    assert main(argv) == 0
    d = read_npz(tmp_path / "bake.npz")
    assert d.num_frames == 8 and np.isfinite(d.skin_final).all()
    assert np.ptp(d.skin_static[:, :, 2], axis=0).max() > 1e-3       # the skin follows the motion
    if scene.clip is not None:
        motion = drive_kinematic(scene.clip.frames(0, 12), scene.clip.times[:12])
        assert np.all(np.isfinite(motion.positions))


@pytest.mark.parametrize("path", MOTIONS, ids=lambda p: p.stem)
def test_built_in_motion_is_smooth_loops_and_stays_above_the_floor(path):
    """Every built-in motion stays above the floor and is smooth; a looping one (the jumping jacks)
    closes its cycle; the gaits that travel (the quadruped's) are keyed cycle after cycle."""
    clip = read_keyframes(path)
    rot, pos = clip.world()
    ends = clip.end_world(rot, pos)
    lowest = np.concatenate([pos, ends], axis=1)[..., 2].min(axis=1)
    assert lowest.min() > -0.01  # toes may touch, not sink: 1 cm
    inside = np.abs(pos[2:] - 2 * pos[1:-1] + pos[:-2]).max()
    if clip.meta["loop"]:
        # loops: the last frame is the first pose, and velocity is continuous across the seam
        np.testing.assert_allclose(pos[-1], pos[0], atol=1e-9)
        # C2 across the seam: its second difference is no larger than those inside the cycle
        seam = np.abs(pos[1] - 2 * pos[0] + pos[-2]).max()
        assert seam <= inside + 1e-9
    else:
        # smooth: no joint jumps; a trotting dog's paws swing at up to ~40 m/s^2, 100 is a jump
        assert inside * clip.fps ** 2 < 100.0
    # energetic: the hands (paws) travel, which is what jiggle needs to show (up and down in the jumping jacks,
    # out and back in the punches)
    assert np.linalg.norm(np.ptp(pos, axis=0), axis=-1).max() > (0.5 if clip.meta["loop"] else 0.05)


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


def _jiggle_scene(tmp_path, text: str) -> Path:
    p = tmp_path / "j.toml"
    p.write_text(f'[motion]\nfile = "{MOTIONS[0].as_posix()}"\n\n{text}')
    return p


def test_scene_without_jiggle_keeps_defaults(tmp_path):
    scene = load_scene(_jiggle_scene(tmp_path, ""))
    assert scene.jiggle is None and dict(scene.muscle_jiggle) == {} and scene.focus == ()
    assert scene.character.file is None and scene.formats is None and scene.builtin is None


def test_jiggle_section_with_keyed_blends(tmp_path):
    from jiggle.sim.jiggle.params import BlendCurve, JiggleSettings
    p = _jiggle_scene(tmp_path, """[jiggle]
substeps = 2
goal_rate = 240
gravity = true
preroll = 0.5
strength = 0.7
blend = [[0.0, 0.0], [0.5, 1.0], [2.0, 0.25]]
cut_ratio = 6.0
cut_jump = 0.2

[jiggle.muscles.belly_fat]
frequency = 4.0
blend = [[0.0, 1.0], [1.0, 0.0]]

[jiggle.muscles.left_biceps]
blend = 0.5
goal = [0.9, 0.5, 0.3, 0.5, 0.9]
""")
    scene = load_scene(p)
    s = scene.jiggle
    assert isinstance(s, JiggleSettings)
    assert (s.substeps, s.goal_rate, s.gravity, s.preroll, s.strength, s.cut_ratio, s.cut_jump) == \
        (2, 240.0, True, 0.5, 0.7, 6.0, 0.2)
    # linear between keys, held outside them
    np.testing.assert_allclose(s.blend(np.array([-1.0, 0.25, 0.5, 1.25, 5.0])), [0.0, 0.5, 1.0, 0.625, 0.25])
    belly = scene.muscle_jiggle["belly_fat"]
    assert belly["frequency"] == 4.0 and isinstance(belly["blend"], BlendCurve)
    np.testing.assert_allclose(belly["blend"](np.array([0.0, 0.5, 2.0])), [1.0, 0.5, 0.0])
    assert isinstance(scene.muscle_jiggle["left_biceps"]["blend"], BlendCurve)
    with pytest.raises(TypeError):
        scene.muscle_jiggle["x"] = {}                                 # read-only


def test_apply_jiggle_checks_muscle_names_against_the_rig(tmp_path):
    from jiggle.rig.muscle.simple_arm import simple_arm
    from jiggle.sim.jiggle.materials import default_jiggles
    arm = simple_arm(rings=8, around=8)
    jiggles = default_jiggles(arm.rig)
    p = _jiggle_scene(tmp_path, "[jiggle.muscles.biceps]\ndamping = 0.9\nblend = [[0.0, 0.0], [1.0, 1.0]]\n")
    (out,) = load_scene(p).apply_jiggle(jiggles)
    assert out.damping_ratio == 0.9 and out.frequency_hz == jiggles[0].frequency_hz
    np.testing.assert_allclose(out.blend(np.array([0.5])), [0.5])
    p = _jiggle_scene(tmp_path, "[jiggle.muscles.tricep]\nblend = 0.5\n[jiggle.muscles.biceps]\nblend = 0.5\n")
    with pytest.raises(InputError, match=r"j.toml:\d+: jiggle.muscles.tricep: the rig has no muscle 'tricep'; its muscles are biceps"):
        load_scene(p).apply_jiggle(jiggles)


@pytest.mark.parametrize("text, match", [
    ("[jiggle]\nsubsteps = 0\n", r"j.toml:5: jiggle.substeps: expected a whole number >= 1"),
    ("[jiggle]\nblend = 1.5\n", r"j.toml:5: jiggle.blend: blend must be in \[0, 1\]"),
    ("[jiggle]\nblend = [[1.0, 0.0], [0.5, 1.0]]\n", r"jiggle.blend: blend key times must increase"),
    ("[jiggle]\ngravity = 1\n", r"jiggle.gravity: expected true or false"),
    ("[jiggle]\ncollisions = \"yes\"\n", r"j.toml:5: jiggle.collisions: expected true or false, found 'yes'"),
    ("[jiggle]\npreroll = -1.0\n", r"jiggle.preroll: expected seconds >= 0"),
    ("[jiggle]\nwobble = 1\n", r"j.toml:5: jiggle.wobble: unknown key; expected one of blend, colliders, collisions, cut_jump, "
                                 r"cut_ratio, goal_rate, gravity, muscle_collisions, muscles, preroll, strength, substeps"),
    ("[jiggle]\ncolliders = \"geoms\"\n", r"j.toml:5: jiggle.colliders: expected one of 'bone', 'model', found 'geoms'"),
    ("[jiggle]\nmuscle_collisions = 1\n", r"j.toml:5: jiggle.muscle_collisions: expected true or false, found 1"),
    ("[jiggle.muscles.belly_fat]\nblend = [[0.0, -0.5]]\n", r"j.toml:5: jiggle.muscles.belly_fat.blend: blend must be in"),
    ("[jiggle.muscles.belly_fat]\ndamping = -0.1\n", r"j.toml:5: jiggle.muscles.belly_fat.damping: damping "
                                                       r"must be >= 0"),
    ("[jiggle.muscles.belly_fat]\nfrequency = nan\n", r"jiggle.muscles.belly_fat.frequency: frequency is NaN"),
    ("[jiggle.muscles.belly_fat]\ngoal = 1.5\n", r"jiggle.muscles.belly_fat.goal: .*goal weight of CV 0 must be in "
                                                   r"\[0, 1\], got 1.5"),
    ("[jiggle.muscles.belly_fat]\nstiffness = 3\n", r"j.toml:5: jiggle.muscles.belly_fat.stiffness: unknown key; "
                                                      r"expected one of frequency, damping, strength"),
    ("[output]\nfocus = 3\n", r"j.toml:5: output.focus: expected a muscle name"),
])
def test_jiggle_section_errors_name_file_line_and_key(tmp_path, text, match):
    with pytest.raises(InputError, match=match):
        load_scene(_jiggle_scene(tmp_path, text))


def test_motion_file_takes_environment_variables(tmp_path, monkeypatch):
    motions = tmp_path / "assets" / "motions"
    motions.mkdir(parents=True)
    (motions / "jj.toml").write_text(MOTIONS[0].read_text())
    p = tmp_path / "scenes" / "s.toml"
    p.parent.mkdir()
    p.write_text('[motion]\nfile = "${MY_ASSETS}/motions/jj.toml"\n')
    # a relative value is taken from the current directory, as the shell would
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("MY_ASSETS", "assets")
    assert load_scene(p).clip.num_joints == read_keyframes(MOTIONS[0]).num_joints
    monkeypatch.delenv("MY_ASSETS")
    with pytest.raises(InputError, match=r"s.toml:2: motion.file: environment variable MY_ASSETS is not set"):
        load_scene(p)
    monkeypatch.setenv("MY_ASSETS", str(tmp_path / "elsewhere"))
    with pytest.raises(InputError, match=r"s.toml:2: motion.file: motion file .*elsewhere/motions/jj.toml not found"):
        load_scene(p)


def _fake_jiggles(names):
    from jiggle.sim.jiggle.params import MuscleJiggle, section_goals
    return [MuscleJiggle(n, 7.0, 0.5, section_goals(0.9, 0.4), 1000.0) for n in names]


def test_keyed_parameters_and_globs_in_a_scene(tmp_path):
    """Curves (linear, smooth), globs (an exact name beats a glob, a later glob an earlier one) and the global
    strength under the muscles' own tables (issue 23)."""
    from jiggle.sim.jiggle.keyed import Curve
    p = _jiggle_scene(tmp_path, '[jiggle]\nstrength = [[0.0, 1.0], [2.0, 0.5]]\n'
                                '[jiggle.muscles."*_fat"]\ndamping = 0.2\nstrength = 0.8\n'
                                'goal_scale = {keys = [[0.0, 1.0], [1.0, 0.5]], interpolation = "smooth"}\n'
                                '[jiggle.muscles.belly_fat]\nstrength = [[0.0, 1.0], [1.0, 1.0]]\n'
                                '[jiggle.muscles."belly_*"]\ndamping = 0.4\nfrequency = [[0.0, 3.0], [1.0, 6.0]]\n')
    scene = load_scene(p)
    assert isinstance(scene.jiggle.strength, Curve)
    belly, glute, biceps = scene.apply_jiggle(_fake_jiggles(["belly_fat", "glute_fat", "biceps"]))
    assert belly.strength == 1.0 and belly.damping_ratio == 0.4 and isinstance(belly.frequency_hz, Curve)
    assert glute.strength == 0.8 and glute.damping_ratio == 0.2 and glute.goal_scale.interpolation == "smooth"
    assert biceps.strength == scene.jiggle.strength and biceps.damping_ratio == 0.5


@pytest.mark.parametrize("text, match", [
    ('[jiggle.muscles."*_fat"]\nstrength = [[0.0, 1.0], [0.0, 0.5]]\n',
     r"j.toml:5: jiggle.muscles.\*_fat.strength: strength key times must increase"),
    ('[jiggle.muscles."*_fat"]\ngoal_scale = [[0.0, 1.0], [1.0, -0.5]]\n',
     r"j.toml:5: jiggle.muscles.\*_fat.goal_scale: goal_scale must be in \[0, inf\), got -0.5 at t = 1 s"),
    ('[jiggle]\nstrength = [[0.0, 1.0], [1.0, 2.0]]\n', r"j.toml:5: jiggle.strength: jiggle strength must be in"),
    ('[jiggle.muscles.belly_fat]\nfrequency = {keys = [[0, 1]], interpolation = "cubic"}\n',
     r"j.toml:5: jiggle.muscles.belly_fat.frequency: interpolation must be one of linear, smooth"),
])
def test_bad_keys_in_a_scene_name_file_line_and_key(tmp_path, text, match):
    with pytest.raises(InputError, match=match):
        load_scene(_jiggle_scene(tmp_path, text))


def test_a_glob_matching_no_muscle_names_its_table(tmp_path):
    p = _jiggle_scene(tmp_path, '[jiggle.muscles."left_*"]\ndamping = 0.2\n')
    with pytest.raises(InputError, match=r"j.toml:4: jiggle.muscles.left_\*: the glob 'left_\*' matches no muscle"):
        load_scene(p).apply_jiggle(_fake_jiggles(["belly_fat"]))
