"""Tissue on any body (rig.muscle.generic) and defaults that depend on the body's shape and motion, not its file.

- the parts' judgement: roundness (a ring of normals vs a two-sided membrane), appendage names, and on the shared
  zoo: a blob's stacked joints are one fat mass, a winged creature's wings get no tissue and its body does;
- choose_template: auto falls back to the generic template where no plan fits, a named template that does not fit
  is refused with the reason;
- the human template's size: a CesiumMan written at 0.12 of its size bakes the same relative jiggle.
"""
import json
import warnings

import numpy as np
import pytest
from conftest import asset

from jiggle.rig.base.errors import InputError, JiggleWarning
from jiggle.rig.character.character import template_scale
from jiggle.rig.character.load import load_character
from jiggle.rig.muscle.fit import choose_template, fit_musculature
from jiggle.rig.muscle.generic import _roundness, _thin_name


def quiet(f, *a, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", JiggleWarning)
        return f(*a, **kw)


def test_roundness_tells_a_ring_from_a_membrane():
    t = np.linspace(0, 2 * np.pi, 40, endpoint=False)
    ring = np.stack([np.cos(t), np.sin(t), np.zeros_like(t)], 1)           # a limb around the z bone
    assert _roundness(ring, [0, 0, 1]) > 0.95
    sheet = np.repeat([[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]], 20, axis=0)    # both sides of a wing along z
    sheet[:, 1] += np.random.default_rng(0).normal(0, 0.05, 40)
    assert _roundness(sheet, [0, 0, 1]) < 0.05
    assert _roundness(sheet[:5], [0, 0, 1]) == 1.0                          # too few to call it flat


@pytest.mark.parametrize("name, word", [("Wing1.L", "wing"), ("LeftEar", "ear"), ("Tail3", "tail"),
                                        ("mixamorig:LeftForeArm", None), ("Forearm", None), ("Head", None),
                                        ("hair_02", "hair"), ("FinBack", "fin"), ("Finger1", None)])
def test_appendage_names(name, word):
    assert _thin_name(name) == word


@pytest.fixture(scope="module")
def cat():
    return quiet(load_character, asset("characters/zoo/Cat.glb"))


def test_a_blob_gets_one_fat_mass_over_its_stacked_joints(cat):
    mus = quiet(fit_musculature, cat)
    assert mus.template.name == "generic" and "no built-in body plan fits" in mus.why
    assert [m.kind for m in mus.muscles] == ["fat"]
    core = [p for p in mus.parts if p.segments]
    assert len(core) == 1 and len(core[0].segments) == 4          # Armature > Head > Head2 > Head3 > end
    assert all("merged into" in p.reason for p in mus.parts if not p.segments)
    # sizes from the skin, none in metres: the fat layer is a share of the part's radius
    assert mus.muscles[0].spec.depth == pytest.approx(0.15 * core[0].radius)


def test_the_generic_template_is_the_same_at_any_scale(cat):
    a, b = quiet(fit_musculature, cat), quiet(fit_musculature, cat.scaled(0.01))
    assert [p.kind for p in a.parts] == [p.kind for p in b.parts]
    assert [m.spec.jiggle.frequency_hz for m in a.muscles] == pytest.approx([m.spec.jiggle.frequency_hz
                                                                             for m in b.muscles])
    assert b.muscles[0].spec.depth == pytest.approx(0.01 * a.muscles[0].spec.depth)


def test_wings_get_no_tissue_and_the_body_does():
    demon = quiet(load_character, asset("characters/zoo/Demon.glb"))
    mus = quiet(fit_musculature, demon)
    wings = [p for p in mus.parts if p.label.startswith("Wing")]
    assert wings and all(p.kind is None and "wing" in p.reason for p in wings)
    assert {"fat", "muscle"} <= {m.kind for m in mus.muscles}
    names = demon.joint_names
    assert not any(names[m.bone].startswith("Wing") for m in mus.muscles)


def test_choose_template_falls_back_only_when_asked_for_auto(cat):
    assert quiet(choose_template, cat).template is None
    with pytest.raises(InputError):                                 # the user named it: say why it does not fit
        quiet(choose_template, cat, "human")
    man = quiet(load_character, asset("characters/CesiumMan.glb"))
    assert quiet(choose_template, man).template.name == "human"
    assert quiet(choose_template, man, "generic").template is None


def test_template_scale():
    assert template_scale("human", 1.5) == 1.0
    assert template_scale("human", 0.22) == pytest.approx(1.7 / 0.22)
    assert template_scale("generic", 0.22) == 1.0 and template_scale("quadruped", 8.0) == 1.0


def _relative_peak(out) -> float:
    z = np.load(out / "bake.npz")
    d = np.linalg.norm(z["skin_final"] - z["skin_static"], axis=2).max()
    return float(d / np.ptp(z["skin_rest"][:, 2]))


def test_a_small_human_jiggles_as_much_as_a_full_size_one(tmp_path):
    """CesiumMan written at 0.12 of its size (0.18 m): simulated at the human template's size and written back at
    the file's, its relative jiggle on a CMU run is within 5% of the unscaled one's."""
    from jiggle.rig.character.gltf_write import write_character
    from jiggle.sim.app.cli import main
    man = quiet(load_character, asset("characters/CesiumMan.glb"))
    small = tmp_path / "small.glb"
    write_character(man.scaled(0.12), small)
    clip = asset("mocap/cmu_bvh/09_11.bvh")
    for name, character in (("full", asset("characters/CesiumMan.glb")), ("small", small)):
        assert main(["bake", "--clip", str(clip), "--character", str(character), "--out", str(tmp_path / name),
                     "--formats", "npz", "-q"]) == 0
    params = json.loads((tmp_path / "small" / "bake.json").read_text())["params"]
    assert params["size_scale"] == pytest.approx(1.7 / 0.1808, rel=0.01)
    z = np.load(tmp_path / "small" / "bake.npz")
    np.testing.assert_allclose(z["skin_rest"], 0.12 * np.asarray(man.vertices), atol=1e-6)   # the file's size
    full, scaled = _relative_peak(tmp_path / "full"), _relative_peak(tmp_path / "small")
    assert scaled == pytest.approx(full, rel=0.05), (full, scaled)


def test_a_blob_bakes_with_the_defaults_and_visibly_jiggles(tmp_path):
    """The shared Cat (a blob of four joints, refused before the generic template) bakes its own Walk with the
    defaults: its peak skin jiggle is between 0.3% and 1.5% of its size (the probe's calibration aims at 0.8%),
    bake.json lists its parts, and the calibrated frequencies do not depend on the output rate."""
    from jiggle.sim.app.cli import main
    cat = asset("characters/zoo/Cat.glb")
    freq = {}
    for fps in (30, 60):
        out = tmp_path / f"cat{fps}"
        assert main(["bake", "--character", str(cat), "--animation", "Walk", "--out", str(out), "--formats", "npz",
                     "--fps", str(fps), "-q"]) == 0
        params = json.loads((out / "bake.json").read_text())["params"]
        assert params["template"] == "generic" and params["parts"][0]["tissue"] == "fat"
        freq[fps] = {k: v["frequency"] for k, v in params["muscles"].items()}
        z = np.load(out / "bake.npz")
        peak = np.linalg.norm(z["skin_final"] - z["skin_static"], axis=2).max()
        share = peak / np.ptp(z["skin_rest"], axis=0).max()
        assert 0.003 <= share <= 0.015, share
    assert freq[30] == pytest.approx(freq[60])
