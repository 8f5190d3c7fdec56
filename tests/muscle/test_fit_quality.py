"""Fit quality (rig.muscle.fit_quality): every fitted muscle of CesiumMan and the generated human body
lies inside the skin and its rms loft error is under RMS_OK (15%) of the local body radius; a muscle
moved out of the body is refused and named (dropped from the rig, or InputError when strict), a
muscle whose shape the loft cannot follow is warned about by name; the measures reach muscles.json,
`jiggle fit`'s summary line and fit.png's labels.

More characters plug in through CHARACTERS: a name and a function returning (Character, template).
"""
import dataclasses
import os
import warnings

import numpy as np
import pytest
import trimesh
from conftest import asset

import jiggle.rig.muscle.fit as fit
from jiggle.rig.base.errors import InputError, JiggleWarning
from jiggle.rig.muscle.fit import FitOptions, fit_musculature
from jiggle.rig.muscle.fit_quality import INSIDE_OK, RMS_OK, RMS_REFUSE, inside_skin, local_radius, thresholds
from jiggle.sim.app.outputs.fit import musculature_facts, quality_line


def cesium_man():
    from jiggle.rig.character.load import load_character
    return load_character(asset("characters/CesiumMan.glb")), "auto"


def generated_body():
    from jiggle.rig.character.load import body_character
    from jiggle.rig.motion.mocap import load_clip
    return body_character(load_clip("scenes/motions/jumping_jacks.toml")), "auto"


def quadruped():
    """The project's own dog (scenes/quadruped.py), written to glTF and read back, with template auto."""
    import tempfile

    from jiggle.rig.character.load import load_character
    from jiggle.scenes.quadruped import make_quadruped_gltf
    path = os.path.join(tempfile.mkdtemp(prefix="jiggle_dog_"), "dog.glb")
    make_quadruped_gltf(path, resolution=8000)
    return load_character(path), "auto"


CHARACTERS = {"CesiumMan": cesium_man, "generated": generated_body, "quadruped": quadruped}


def fit_quietly(character, template="auto", options=FitOptions()):
    """(Musculature, [JiggleWarning messages])."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        mus = fit_musculature(character, template, options)
    return mus, [str(w.message) for w in caught if issubclass(w.category, JiggleWarning)]


@pytest.fixture(scope="module")
def fits():
    cache = {}

    def get(name):
        if name not in cache:
            c, template = CHARACTERS[name]()
            cache[name] = (c, template, *fit_quietly(c, template))
        return cache[name]
    return get


@pytest.mark.parametrize("name", list(CHARACTERS))
def test_every_muscle_is_inside_and_its_loft_error_under_15_percent(fits, name):
    c, _, mus, warned = fits(name)
    assert mus.skipped == () and mus.refused == () and warned == []
    assert [q.name for q in mus.quality] == list(mus.names)
    worst = max(mus.quality, key=lambda q: q.rms_share)
    least = min(mus.quality, key=lambda q: q.inside)
    print(f"\n{name}: worst rms loft error {worst.rms_share:.1%} of the local radius ({worst.name}, "
          f"R {worst.radius * 1e3:.1f} mm); least inside {least.inside:.1%} ({least.name}); deepest outside "
          f"{max(q.depth for q in mus.quality) * 1e3:.1f} mm")
    for q in mus.quality:
        assert q.status == "ok" and q.reasons == (), (q.name, q.reasons)
        assert q.rms_share < RMS_OK and q.inside >= INSIDE_OK, q.name
        assert 0.01 < q.radius < 0.3, (q.name, q.radius)   # a limb's or a trunk's radius, metres
    # the inside test agrees with trimesh's on the closed generated body
    if name == "generated":
        skin = trimesh.Trimesh(c.vertices, c.faces, process=False)
        assert skin.is_watertight
        pts = mus.rig.surface(mus.rig.rest_cvs).reshape(-1, 3)
        assert np.mean(inside_skin(skin, pts) == skin.contains(pts)) > 0.999
    facts = musculature_facts(mus)
    assert facts["quality"]["thresholds"] == thresholds() and facts["quality"]["ok"] == len(mus.muscles)
    assert all(m["status"] == "ok" and m["loft_rms_share"] < RMS_OK for m in facts["per_muscle"])
    assert quality_line(mus).startswith(f"fit quality: {len(mus.muscles)} ok, 0 warned, 0 refused")


def _moved(name: str, by: np.ndarray):
    """A replacement for rig.muscle.fit._fit_one that moves muscle `name` by `by` (3,) metres."""
    original = fit._fit_one

    def fit_one(n, *args, **kw):
        f = original(n, *args, **kw)
        if n != name:
            return f
        return dataclasses.replace(f, vertices=f.vertices + by, points=f.points + by,
                                   ellipsoid=dataclasses.replace(f.ellipsoid, centre=f.ellipsoid.centre + by))
    return fit_one


def test_a_muscle_outside_the_body_is_refused_and_named(fits, monkeypatch):
    c, template, base, _ = fits("generated")
    # the left biceps 30 cm in front of the body: wholly outside
    monkeypatch.setattr(fit, "_fit_one", _moved("left_biceps", 0.3 * np.asarray(base.front)))
    mus, warned = fit_quietly(c, template)
    assert "left_biceps" not in mus.names and mus.rig.M == len(base.muscles) - 1
    assert [n for n, _ in mus.skipped] == ["left_biceps"] and "inside the skin" in mus.skipped[0][1]
    assert [q.name for q in mus.refused] == ["left_biceps"] and mus.refused[0].inside < 0.5
    assert any("left_biceps" in w and "skipped" in w for w in warned)
    # the other muscles are fitted exactly as before
    keep = [i for i, n in enumerate(base.names) if n != "left_biceps"]
    np.testing.assert_array_equal(mus.rig.rest_cvs.reshape(-1, 40, 3), base.rig.rest_cvs.reshape(-1, 40, 3)[keep])
    facts = musculature_facts(mus)
    assert facts["quality"]["refused"] == ["left_biceps"] and facts["refused"][0]["name"] == "left_biceps"
    assert "refused left_biceps" in quality_line(mus)
    with pytest.raises(InputError, match="left_biceps"):
        fit_musculature(c, template, FitOptions(strict=True))


def test_a_shape_the_loft_cannot_follow_is_warned_about_by_name(fits, monkeypatch):
    """A conformed mesh torn into spikes (rays slipping into folds): the loft averages them out, its rms
    error rises past RMS_OK of the radius (not past RMS_REFUSE); the muscle is kept and named in a warning."""
    c, template, base, _ = fits("generated")
    original = fit._fit_one

    def spiky(n, *args, **kw):
        f = original(n, *args, **kw)
        if n != "left_quadriceps":
            return f
        axis = f.ellipsoid.axes[0]
        # every other vertex moved by 90% of the local radius toward the bone (two shells, still inside the
        # thigh): no smooth loft passes near both
        inward = np.asarray(args[2].start) - f.ellipsoid.centre   # args[2]: the template bone (_Bone)
        inward -= (inward @ axis) * axis
        spike = np.arange(len(f.vertices)) % 2 == 1
        shift = 0.9 * f.radius * inward / np.linalg.norm(inward)
        return dataclasses.replace(f, vertices=f.vertices + spike[:, None] * shift)

    monkeypatch.setattr(fit, "_fit_one", spiky)
    mus, warned = fit_quietly(c, template)
    q = mus.quality[mus.names.index("left_quadriceps")]
    print(f"\nspiky quadriceps: {q.brief}")
    assert q.status == "warn" and RMS_OK < q.rms_share <= RMS_REFUSE and "rms loft error" in q.reasons[0]
    assert [x.name for x in mus.warned] == ["left_quadriceps"]
    assert any("left_quadriceps" in w and "fits poorly" in w for w in warned)
    assert "warn    left_quadriceps" in quality_line(mus)


def test_local_radius_and_inside_on_an_open_cylinder():
    """A capped cylinder of radius 5 cm around a 40 cm segment, with a few triangles cut out (an open
    mesh): its side's local radius is 5 cm; points inside and outside are told apart by the vote."""
    cyl = trimesh.creation.cylinder(radius=0.05, height=0.4, sections=64)
    start, end = np.array([0, 0, -0.2]), np.array([0, 0, 0.2])
    side = np.nonzero(np.abs(cyl.face_normals[:, 2]) < 0.1)[0]
    assert local_radius(cyl.vertices, cyl.faces[side], start, end) == pytest.approx(0.05, rel=0.01)
    holed = trimesh.Trimesh(cyl.vertices, np.delete(cyl.faces, side[::9], axis=0), process=False)
    assert not holed.is_watertight
    rng = np.random.default_rng(1)
    p = rng.uniform([-0.1, -0.1, -0.25], [0.1, 0.1, 0.25], (2000, 3))
    truth = (np.linalg.norm(p[:, :2], axis=1) < 0.05) & (np.abs(p[:, 2]) < 0.2)
    assert np.mean(inside_skin(holed, p) == truth) > 0.99
