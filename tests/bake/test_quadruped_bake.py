"""Any creature: the project's own dog (scenes/quadruped.py), written to glTF with its walk and trot,
read back and baked with its own animation. The body plan is found from the skeleton, the quadruped
template is picked, the smooth skin is the glTF posed by its animation, and the skin holds up."""
from __future__ import annotations

import json

import numpy as np
import pytest

from jiggle.sim.app.cli import main


def run(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def dog(tmp_path_factory):
    from jiggle.scenes.quadruped import make_quadruped_gltf
    path = tmp_path_factory.mktemp("dog") / "dog.glb"
    make_quadruped_gltf(path, resolution=6000)
    return str(path)


@pytest.mark.slow
def test_the_dog_bakes_its_own_trot_with_the_quadruped_template(capsys, tmp_path, dog):
    from jiggle.rig.character.load import load_character
    from jiggle.rig.motion.clip import transforms
    from jiggle.rig.motion.mocap import load_clip
    from jiggle.rig.skin.quality import SkinQuality
    from jiggle.rig.skin.skinning import pose_character
    from jiggle.sim.bake.caches import read_npz
    code, out, err = run(capsys, "bake", "--character", dog, "--animation", "trot", "--out", str(tmp_path),
                         "--formats", "npz", "--frames", "30")
    assert code == 0, err
    assert "no retargeting" in err and "body plan: quadruped" in err
    d = read_npz(tmp_path / "bake.npz")
    params = json.loads(d.params)
    assert params["body_plan"]["kind"] == "quadruped" and params["body_plan"]["tail"]
    assert params["template"] == "quadruped"
    names = set(d.muscle_names)
    # fat where animals jiggle most (belly, neck, haunches), the back, every leg, the tail's root
    assert {"belly_fat", "neck_fat", "left_haunch_fat", "right_haunch_fat", "left_back", "left_shoulder",
            "right_front_triceps", "left_quadriceps", "right_gaskin", "left_tail_base"} <= names
    # section 1's round trip: the cache's smooth skin is the glTF posed by its own animation
    c, clip = load_character(dog), load_clip(dog, animation="trot")
    world = transforms(*clip.world(*clip.sample(d.times)))[:, [clip.joint_names.index(n) for n in c.joint_names]]
    for k in (0, 15, 29):
        assert np.abs(d.skin_lbs[k] - pose_character(c, world[k])).max() < 1e-5
    # the tissue's jiggle shows (measured from the skin that follows the swung tail), and the skin over it folds no
    # more than the smooth skin does, and never tears
    swung = d.skin_swung()
    amp = np.linalg.norm(d.skin_final - swung, axis=2).max()
    assert 1e-3 < amp < 0.05
    q = SkinQuality(d.skin_rest, d.faces)
    folds_final = q.skin(d.skin_final)["folded_edges"].sum()
    folds_lbs = q.skin(d.skin_lbs)["folded_edges"].sum()
    assert folds_final <= 1.1 * folds_lbs + 5
    assert q.jiggle(swung, d.skin_final)["torn_edges"].max() == 0
    # its tail swings as a chain below the tail's root muscle: its tip moves beyond the animation's
    assert d.chain_tip_names and any("tail" in n.lower() for n in d.chain_tip_names), d.chain_tip_names
    tip = np.linalg.norm(d.chain_tips_final - d.chain_tips_static, axis=2).max(axis=0)
    assert tip.max() > 1e-3


@pytest.mark.slow
def test_the_human_template_on_the_dog_is_refused_with_the_one_that_fits(capsys, tmp_path, dog):
    code, _, err = run(capsys, "bake", "--character", dog, "--animation", "walk", "--template", "human",
                       "--out", str(tmp_path), "--formats", "npz", "--frames", "5")
    assert code == 2, err
    assert "left_upper_arm" in err and "quadruped" in err and "--template auto" in err, err
    assert not (tmp_path / "bake.npz").exists()


def test_inspect_tells_the_dogs_body_plan(capsys, dog):
    code, out, err = run(capsys, "inspect", dog, "--json")
    assert code == 0, err
    report = json.loads(out)
    assert report["body_plan"]["kind"] == "quadruped" and report["body_plan"]["template"] == "quadruped"
    assert [a["name"] for a in report["animations"]] == ["walk", "trot"]
    assert report["unit"].startswith("metres")
