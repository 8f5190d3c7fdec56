"""Pose shapes in scenes ([[pose_shapes]], rig/muscle/pose_shapes.py): a bake of the demo's jumping jacks
whose left quadriceps is keyed to grow with the left knee's bend takes exactly that shape in its static
muscles frame by frame, while every other muscle (static and jiggled) is the plain bake's bit for bit;
bad tables are one line naming the scene's line, exit code 2."""
import shutil
from pathlib import Path

import numpy as np
import pytest

from jiggle.sim.app.cli import main

SCENES = Path(__file__).resolve().parents[2] / "scenes"
SHAPE = """
[[pose_shapes]]
muscle = "left_quad*"
joint = "l_shin"
angles = [0, 60]
scales = [1.0, [1.0, 1.3, 1.5, 1.3, 1.0]]
"""
ARGS = ["--frames", "24", "--formats", "npz", "--resolution", "4000", "--chunk", "8", "--activation", "off"]


def scene_with(tmp_path, extra: str) -> Path:
    """The demo scene (its motion beside it) with `extra` TOML appended."""
    shutil.copytree(SCENES / "motions", tmp_path / "motions")
    p = tmp_path / "shaped.toml"
    p.write_text((SCENES / "default.toml").read_text() + extra)
    return p


@pytest.mark.slow
def test_a_keyed_quadriceps_grows_with_the_knee_and_nothing_else_changes(tmp_path):
    from jiggle.rig.muscle.pose_shapes import SECTIONS
    from jiggle.sim.bake.caches import read_npz
    shaped = scene_with(tmp_path, SHAPE)
    assert main(["bake", str(shaped), "--out", str(tmp_path / "shaped"), *ARGS]) == 0
    assert main(["bake", str(SCENES / "default.toml"), "--out", str(tmp_path / "plain"), *ARGS]) == 0
    a, b = read_npz(tmp_path / "shaped" / "bake.npz"), read_npz(tmp_path / "plain" / "bake.npz")
    names = list(a.muscle_names)
    m = names.index("left_quadriceps")
    lo, hi = a.muscle_cv_offsets[m], a.muscle_cv_offsets[m + 1]
    others = np.r_[0:lo, hi:a.muscle_cvs_static.shape[1]]
    np.testing.assert_array_equal(a.muscle_cvs_static[:, others], b.muscle_cvs_static[:, others])
    np.testing.assert_array_equal(a.muscle_cvs_dynamic[:, others], b.muscle_cvs_dynamic[:, others])
    # the knee's bend from the bake's own joints: the shin's rotation against the thigh's (the generated
    # body's bind pose is the motion's rest pose, every joint unrotated)
    j = list(a.joint_names)
    R = a.joint_world[:, :, :3, :3].astype(np.float64)
    local = np.einsum("tji,tjk->tik", R[:, j.index("l_thigh")], R[:, j.index("l_shin")])
    bend = np.degrees(np.arccos(np.clip((np.trace(local, axis1=1, axis2=2) - 1) / 2, -1, 1)))
    import json
    params = json.loads(str(a.params))
    assert params["pose_shapes"] == [{"muscle": "left_quadriceps", "joint": "l_shin", "angles_deg": [0.0, 60.0],
                                      "scales": [[1.0] * 5, [1.0, 1.3, 1.5, 1.3, 1.0]]}]
    # the shaped sections, about the plain ones' centres (the action curve is not shaped): mean radius ratio
    x_a = a.muscle_cvs_static[:, lo:hi].reshape(len(a.times), SECTIONS, -1, 3).astype(np.float64)
    x_b = b.muscle_cvs_static[:, lo:hi].reshape(len(b.times), SECTIONS, -1, 3).astype(np.float64)
    ratio = np.linalg.norm(np.diff(x_a, axis=2), axis=-1).sum(axis=2) / np.linalg.norm(np.diff(x_b, axis=2),
                                                                                       axis=-1).sum(axis=2)
    # a section scaled about its centre scales its ring's perimeter alike: ratio (T, 5) = interp(bend, key)
    for s, key in enumerate([1.0, 1.3, 1.5, 1.3, 1.0]):
        np.testing.assert_allclose(ratio[:, s], np.interp(bend, [0.0, 60.0], [1.0, key]), atol=1e-4)
    assert bend.max() > 30.0 and np.ptp(ratio[:, 2]) > 0.1       # the knee bends and the muscle follows it


@pytest.mark.parametrize("extra, expected", [
    ('\n[[pose_shapes]]\nmuscle = "left_quadriceps"\njoint = "l_shin"\nangles = [0, 60]\n', "missing scales"),
    ('\n[[pose_shapes]]\nmuscle = "x"\njoint = "l_shin"\nangles = [0, 60]\nscales = [1]\n', "one scale per angle"),
    ('\n[[pose_shapes]]\nmuscle = "x"\njoint = "l_shin"\nangles = "wide"\nscales = [1]\n', "a list of degrees"),
    ('\n[[pose_shapes]]\nmuscle = "x"\njoint = "l_shin"\nangles = [0]\nscales = [1]\nsize = 2\n', "unknown key 'size'"),
])
def test_bad_pose_shape_tables_name_their_line(capsys, tmp_path, extra, expected):
    scene = scene_with(tmp_path, extra)
    line = len((SCENES / "default.toml").read_text().splitlines()) + 2
    assert main(["bake", str(scene), "--out", str(tmp_path / "out"), *ARGS]) == 2
    err = capsys.readouterr().err
    assert f"shaped.toml:{line}: pose_shapes[1]" in err and expected in err and len(err.strip().splitlines()) == 1, err


@pytest.mark.slow
def test_a_pose_shape_for_an_unknown_muscle_or_joint_is_exit_2(capsys, tmp_path):
    scene = scene_with(tmp_path, SHAPE.replace('"l_shin"', '"l_knee"'))
    assert main(["bake", str(scene), "--out", str(tmp_path / "out"), *ARGS]) == 2
    err = capsys.readouterr().err
    assert "no joint 'l_knee'" in err and "shaped.toml:" in err and "Traceback" not in err, err
