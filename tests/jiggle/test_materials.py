"""Tissue materials in physical units (rig/muscle/material.py, sim/jiggle/materials.py) and one tissue per character
(sim.bake.setup._character_tissue): a material's goal springs, the material a part's springs stand for, --material
on the command line, and the generic template's tissue the same on every clip of a character."""
from __future__ import annotations

import json
from dataclasses import replace
import math
import os

import numpy as np
import pytest

from jiggle.rig.base.errors import InputError
from jiggle.rig.muscle.material import FAT, MUSCLE, Material, parse_material
from jiggle.sim.jiggle.materials import (FEM_C, MODAL_GAIN, fem_frequency, material_of, particle_damping,
                                         ring_damping, ring_factor, sway_mode, with_material)
from jiggle.sim.jiggle.params import MuscleJiggle, section_goals

ASSETS = os.path.join(os.path.dirname(__file__), "..", "..", "..", "shared", "assets")


def _jiggle(tendon=0.9, belly=0.4):
    return MuscleJiggle(name="m", frequency_hz=10.0, damping_ratio=0.5, goal=section_goals(tendon, belly), density=1000.0)


def test_the_rule_is_the_shear_speed_over_the_radius():
    # f_fem = C sqrt(mu / rho) / r, mu = E / (2 (1 + nu)): four times the modulus doubles it, twice the radius halves it
    m = Material(youngs_pa=12e3, poisson=0.49, density=1000.0, damping_ratio=0.2)
    f = fem_frequency(m, 0.05)
    assert f == pytest.approx(FEM_C * math.sqrt(12e3 / (2 * 1.49) / 1000.0) / 0.05)
    stiff = Material(youngs_pa=48e3, poisson=0.49, density=1000.0, damping_ratio=0.2)
    assert fem_frequency(stiff, 0.05) == pytest.approx(2 * f) and fem_frequency(m, 0.1) == pytest.approx(f / 2)


def test_the_slender_rule_takes_the_length_in():
    """With the part's length, f = FEM_C_SLENDER (r / L)^FEM_A c / r: a part four times as long as another of the same
    radius rings (1/4)^0.203 = 0.75 times as fast; the springs and the material read back through the same rule."""
    from jiggle.sim.jiggle.materials import FEM_A, FEM_C_SLENDER, shape_constant
    assert shape_constant(0.03, None) == FEM_C and shape_constant(0.03, 0.0) == FEM_C
    assert shape_constant(0.03, 0.3) == pytest.approx(FEM_C_SLENDER * 0.1 ** FEM_A)
    assert fem_frequency(FAT, 0.03, 0.4) / fem_frequency(FAT, 0.03, 0.1) == pytest.approx(0.25 ** FEM_A)
    # a typical thigh muscle (r/L ~ 0.07) rings below the r rule's, a short wide belly (r/L ~ 0.25) above it
    assert fem_frequency(MUSCLE, 0.023, 0.33) < 0.92 * fem_frequency(MUSCLE, 0.023)
    assert fem_frequency(FAT, 0.029, 0.116) > 1.1 * fem_frequency(FAT, 0.029)
    out = with_material(_jiggle(), FAT, 0.04, 0.2)
    assert out.frequency_hz * ring_factor(out) == pytest.approx(fem_frequency(FAT, 0.04, 0.2))
    back = material_of(out, "fat", 0.04, 0.2)
    assert back.name == "fat" and back.youngs_pa == pytest.approx(FAT.youngs_pa, rel=1e-9)


def test_a_material_sets_the_springs_and_reads_back():
    j = _jiggle()
    out = with_material(j, FAT, 0.04)
    # the belly (goal weight 0.4) rings at frequency_hz sqrt(w / (1 - w)): that is the FEM's frequency
    assert out.frequency_hz * ring_factor(out) == pytest.approx(fem_frequency(FAT, 0.04))
    assert out.damping_ratio == FAT.damping_ratio and out.density == FAT.density    # no CVs: the ratio as it is
    back = material_of(out, "fat", 0.04)
    assert back.name == "fat" and back.youngs_pa == pytest.approx(FAT.youngs_pa, rel=1e-9)
    assert material_of(with_material(j, MUSCLE, 0.03), "muscle", 0.03).name == "muscle"
    # a template's 11 Hz muscle of 2 cm radius stands for some E, which gives 11 Hz back
    t = _jiggle()
    e = material_of(t, "muscle", 0.02)
    assert e.name == "custom" and with_material(t, e, 0.02).frequency_hz == pytest.approx(10.0)


def _part(length=0.2, radius=0.025):
    """The rest CVs (40, 3) of a lofted ellipsoid part (sim.fem.experiments.ellipsoid_rig)."""
    from jiggle.sim.fem.experiments import ellipsoid_rig
    return ellipsoid_rig(length, (radius, radius)).rest_cvs[:40]


def test_the_sway_mode_is_the_particles_linear_model():
    """sway_mode: a part of even goal weights and no neighbour springs is 40 copies of one oscillator (its sway rings at
    frequency_hz with the springs' own ratio); undamped neighbour springs stiffen the sway without damping it, and
    their dampers add to its damping."""
    cvs = _part()
    even = MuscleJiggle(name="m", frequency_hz=5.0, damping_ratio=0.3, goal=np.full(40, 0.5), density=1000.0,
                        spring_frequency_hz=0.0)
    f, z = sway_mode(even, cvs)
    assert f == pytest.approx(5.0, rel=1e-6) and z == pytest.approx(0.3, rel=1e-6)
    stiff_ends = MuscleJiggle(name="m", frequency_hz=5.0, damping_ratio=0.3, goal=section_goals(0.95, 0.3),
                              density=1000.0, spring_frequency_hz=8.0, spring_damping_ratio=0.0)
    sprung = MuscleJiggle(name="m", frequency_hz=5.0, damping_ratio=0.3, goal=section_goals(0.95, 0.3), density=1000.0,
                          spring_frequency_hz=8.0, spring_damping_ratio=0.5)
    loose = replace(stiff_ends, spring_frequency_hz=0.0)          # uncoupled: the belly's CVs carry the most mass
    assert sway_mode(loose, cvs)[0] == pytest.approx(5.0 * math.sqrt(0.3 / 0.7), rel=1e-6)
    # undamped neighbour springs stiffen the sway without damping it; their dampers add to it
    assert sway_mode(stiff_ends, cvs)[1] < 0.3 < sway_mode(sprung, cvs)[1]


def test_the_damping_rule_takes_the_particles_own_damping_off():
    """particle_damping sets the goal springs' ratio so the part rings down with the material's (MODAL_GAIN x its sway
    mode's); a part that damps more on its own gets less; reading back gives the material's; none below what it
    damps with none."""
    cvs = _part()
    j = replace(_jiggle(), spring_frequency_hz=4.0, spring_damping_ratio=0.2)     # the templates' neighbour springs
    for zeta in (0.3, 0.5, 0.8):
        d = particle_damping(zeta, j, cvs)
        assert ring_damping(replace(j, damping_ratio=d), cvs) == pytest.approx(zeta, abs=1e-5)
    even = replace(j, goal=np.full(40, 0.5), spring_frequency_hz=0.0)
    assert particle_damping(0.3, j, cvs) < particle_damping(0.3, even, cvs) == pytest.approx(0.3 / MODAL_GAIN)
    assert particle_damping(5.0, j, cvs) >= 1.0             # past critical: the most it can, no error
    floor = ring_damping(replace(j, damping_ratio=0.0), cvs)
    assert floor > 0 and particle_damping(0.5 * floor, j, cvs) == 0.0
    out = with_material(j, FAT, 0.025, 0.2, cvs)
    back = material_of(out, "fat", 0.025, 0.2, cvs)
    assert back.name == "fat" and back.damping_ratio == pytest.approx(FAT.damping_ratio, rel=1e-4)


@pytest.mark.parametrize("text, expect", [("fat", FAT), ("muscle", MUSCLE),
                                          ("E=5kPa,zeta=0.2", {"youngs_pa": 5e3, "damping_ratio": 0.2}),
                                          ("E=2e4,nu=0.45,rho=1100", {"youngs_pa": 2e4, "poisson": 0.45, "density": 1100})])
def test_materials_parse(text, expect):
    got = parse_material(text)
    if isinstance(expect, Material):
        assert got == expect
    else:
        assert all(getattr(got, k) == pytest.approx(v) for k, v in expect.items())
        assert got.name == "custom"


@pytest.mark.parametrize("text, part", [("wood", "expected fat, muscle"), ("E=abc", "E must be a number"),
                                        ("E=-3", "youngs_pa must be > 0"), ("nu=0.5", "poisson must be in [0, 0.5)"),
                                        ("G=3", "unknown material key 'G'")])
def test_bad_materials_say_what_was_expected(text, part):
    with pytest.raises(InputError, match=part.replace("[", r"\[").replace("(", r"\(").replace(")", r"\)")):
        parse_material(text)


def _asset(*parts):
    path = os.path.join(ASSETS, *parts)
    if not os.path.isfile(path):
        pytest.skip(f"{os.path.join(*parts)} is not in ../shared/assets")
    return path


@pytest.mark.slow
def test_material_on_the_command_line(tmp_path, capsys):
    """jiggle bake --material: the glob's muscles get the material's springs (bake.json records it, and the material
    each other part's springs stand for); --frequency still overrides; a glob matching nothing is exit 2."""
    from jiggle.sim.app.cli import main
    clip = _asset("mocap", "cmu_bvh", "09_11.bvh")
    out = tmp_path / "m"
    args = ["bake", "--clip", clip, "--frames", "4", "--formats", "npz", "-q"]
    assert main([*args, "--out", str(out), "--material", "*_fat=fat", "--material", "left_biceps=E=40kPa",
                 "--frequency", "right_biceps=9"]) == 0
    p = json.loads((out / "bake.json").read_text())
    params = p.get("params", p)
    muscles = params["muscles"]
    fats = [n for n in muscles if n.endswith("_fat")]
    assert fats and all(muscles[n]["material"]["name"] == "fat" for n in fats)
    assert all(params["tissue"]["materials"][n]["entry"] == "*_fat=fat" for n in fats)
    assert muscles["left_biceps"]["material"]["youngs_pa"] == pytest.approx(40e3, rel=1e-6)
    assert muscles["right_biceps"]["frequency"] == 9.0 and muscles["right_biceps"]["material"]["youngs_pa"] > 0
    f = muscles[fats[0]]            # its belly rings at the FEM's frequency for fat of its radius
    j = MuscleJiggle(name="x", frequency_hz=f["frequency"], damping_ratio=f["damping"], goal=f["goal"], density=1.0)
    assert f["frequency"] * ring_factor(j) == pytest.approx(fem_frequency(FAT, f["radius_m"], f["length_m"]), rel=1e-6)
    # the springs' ratio is less than the material's (the particles damp on their own); the part rings down with it
    assert f["damping"] < FAT.damping_ratio and f["density"] == FAT.density
    assert f["material"]["damping_ratio"] == pytest.approx(FAT.damping_ratio, rel=1e-3)
    assert main([*args, "--out", str(tmp_path / "bad"), "--material", "nosuch*=fat"]) == 2
    assert "no muscle is named or matches 'nosuch*'" in capsys.readouterr().err


@pytest.mark.slow
def test_one_tissue_for_every_clip_of_a_character(tmp_path):
    """The shared Cat (the generic template) baked on its Idle, Walk and Dance: the same goal springs in every
    bake.json (its fat's material at its real size, held once on all its cycles: stiffened where its Dance would
    jiggle past the limit), and the Idle peaks below the Walk, the Walk below the Dance (it was retuned per clip:
    1.5 Hz on Idle, 7 on Walk, 11 on Dance)."""
    from jiggle.sim.app.cli import main
    from jiggle.sim.bake.caches import read_npz
    cat = _asset("characters", "zoo", "Cat.glb")
    freqs, peaks = {}, {}
    from jiggle.sim.bake import setup
    for clip in ("Idle", "Walk", "Dance"):
        setup._TISSUE.clear()       # each bake finds the reference cycle itself, as separate processes do
        out = tmp_path / clip
        assert main(["bake", "--character", cat, "--animation", clip, "--out", str(out), "--formats", "npz",
                     "-q"]) == 0
        p = json.loads((out / "bake.json").read_text())
        params = p.get("params", p)
        tissue = params["tissue"]
        assert tissue["held_on"] == "its own cycles: Dance, Idle, Walk" and tissue["held_factor"] > 1.0
        assert max(tissue["cycles_peak_size"].values()) <= setup.PEAK_LIMIT
        assert all(m["springs_from"].startswith("material, held x") for m in params["muscles"].values())
        freqs[clip] = {n: m["frequency"] for n, m in params["muscles"].items()}
        b = read_npz(out / "bake.npz")
        peaks[clip] = float(np.linalg.norm(b.skin_final - b.skin_static, axis=2).max())
    assert freqs["Idle"] == freqs["Walk"] == freqs["Dance"]
    assert peaks["Idle"] < peaks["Walk"] < peaks["Dance"], peaks


@pytest.mark.slow
def test_the_materials_set_a_default_bake(tmp_path):
    """A default bake on the human template: every part's springs come from its kind's material at the character's
    real size (bake.json: springs_from "material", the material named); --frequency overrides one and says so."""
    from jiggle.rig.muscle.material import material_for
    from jiggle.sim.app.cli import main
    clip = _asset("mocap", "cmu_bvh", "09_11.bvh")
    out = tmp_path / "d"
    assert main(["bake", "--clip", clip, "--frames", "4", "--formats", "npz", "-q", "--out", str(out),
                 "--frequency", "right_biceps=9"]) == 0
    p = json.loads((out / "bake.json").read_text())
    params = p.get("params", p)
    scale = params["tissue"]["real_size"]["scale"]
    muscles = params["muscles"]
    assert muscles["right_biceps"]["springs_from"] == "overridden: frequency_hz"
    assert muscles["right_biceps"]["frequency"] == 9.0 and muscles["right_biceps"]["material"]["name"] == "custom"
    rest = {n: m for n, m in muscles.items() if n != "right_biceps"}
    assert {m["kind"] for m in rest.values()} == {"fat", "muscle"}
    for name, m in rest.items():
        mat = material_for(m["kind"])
        assert m["springs_from"] == "material" and m["material"]["name"] == mat.name, name
        j = MuscleJiggle(name=name, frequency_hz=m["frequency"], damping_ratio=m["damping"], goal=m["goal"],
                         density=m["density"])
        f_fem = fem_frequency(mat, m["radius_m"] * scale, m["length_m"] * scale)
        assert m["frequency"] * ring_factor(j) == pytest.approx(f_fem, rel=1e-9) and m["density"] == mat.density
        assert m["material"]["damping_ratio"] == pytest.approx(mat.damping_ratio, rel=1e-3)
    assert "come from its material" in params["tissue"]["material_rule"]
