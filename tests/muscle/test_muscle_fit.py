"""Fitting the musculoskeletal template to characters from the outside in (rig.muscle.fit).

The default "human" template (21 muscles and 5 fat masses; the abdomen has 3 bellies, so 28 fitted
muscles) on CesiumMan, RiggedFigure, the generated jumping-jacks body and a body generated for a CMU
clip: completeness, fit errors, muscles inside the skin, mirror symmetry, pair partition planes,
attachments, multi-belly strips and fat; volume kept over every frame of the CMU clip; bad input
(skipped regions, flat regions, zero-length bones, unknown labels, hostile XML, parameters out of
range); and the `jiggle fit` command with its TOML, JSON and picture.

Each character is fitted once per module (`fits`). Inside/outside is the generalized winding number,
which stays ~1 inside across the holes and seams of CesiumMan's open mesh.
"""
import json
import tomllib
import warnings

import numpy as np
import pytest
from conftest import asset
from meshes import winding_numbers

from jiggle.rig.base.errors import InputError, JiggleWarning
from jiggle.rig.character.character import Character, bind_clip
from jiggle.rig.character.load import body_character, load_character
from jiggle.rig.character.normals import vertex_normals
from jiggle.rig.muscle.fit import FitOptions, bone_frame, fit_musculature
from jiggle.rig.muscle.template import template_from_toml
from jiggle.sim.app.cli import main

CHARACTERS = ["CesiumMan", "RiggedFigure", "generated"]
FAT = {"left_glute_fat", "right_glute_fat", "belly_fat", "left_love_handle", "right_love_handle"}
FIT_RMS_MAX = 0.004   # m; measured worst 2.3 mm (CesiumMan), 2.9 mm (RiggedFigure's deltoid), 2.0 mm (body)
FIT_MAX_MAX = 0.016   # m; measured worst 11.3, 12.2 and 6.3 mm


def fit_quietly(character, template="human", options=FitOptions(), **kw):
    """(Musculature, [JiggleWarning messages]) of one fit."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        mus = fit_musculature(character, template, options, **kw)
    return mus, [str(w.message) for w in caught if issubclass(w.category, JiggleWarning)]


def make_character(name: str) -> Character:
    if name == "CesiumMan":
        return load_character(asset("characters/CesiumMan.glb"))
    if name == "RiggedFigure":
        return load_character(asset("characters/RiggedFigure.glb"))
    if name == "generated":
        from jiggle.rig.motion.mocap import load_clip
        return body_character(load_clip("scenes/motions/jumping_jacks.toml"))
    if name == "cmu":
        from jiggle.rig.motion.mocap import load_clip
        return body_character(load_clip(asset("mocap/cmu_bvh/02_03.bvh")))
    raise KeyError(name)


@pytest.fixture(scope="module")
def fits():
    """fits(name) -> (character, musculature, warnings), fitted once per module."""
    cache = {}

    def get(name):
        if name not in cache:
            c = make_character(name)
            cache[name] = (c, *fit_quietly(c))
        return cache[name]
    return get



def triangle_areas(vertices, faces) -> np.ndarray:
    t = np.asarray(vertices)[np.asarray(faces)]
    return 0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1)


# ------------------------------------------------------------------------------- the default template
@pytest.mark.parametrize("name", CHARACTERS)
def test_default_template_fits_completely(fits, name):
    c, mus, warned = fits(name)
    rig = mus.rig
    assert mus.skipped == ()
    # RiggedFigure's blocky shoulders: its deltoids poke out of the skin a little (rig.muscle.fit_quality
    # warns by name: 93-95% inside); the others fit cleanly (tests/muscle/test_fit_quality.py)
    poor = {"left_deltoid", "right_deltoid"} if name == "RiggedFigure" else set()
    assert {q.name for q in mus.warned} == poor and len(warned) == len(poor)
    assert all("fits poorly" in w and "inside the skin" in w for w in warned)
    assert len(mus.muscles) == 28 and rig.M == 28 and rig.names == mus.names
    assert {f"abdomen_{k}" for k in (1, 2, 3)} <= set(mus.names) and "abdomen" not in mus.names
    cvs = rig.rest_cvs.reshape(28, 40, 3)
    assert np.all(np.isfinite(cvs)) and np.all(rig.rest_volume > 1e-6)   # every muscle at least 1 cm^3
    lo, hi = c.vertices.min(axis=0) - 0.01, c.vertices.max(axis=0) + 0.01
    assert np.all((cvs >= lo) & (cvs <= hi)), "section CVs outside the character's bounds"
    print(f"\n{name}: fit rms worst {rig.fit_rms.max() * 1e3:.2f} mm ({mus.names[rig.fit_rms.argmax()]}), "
          f"rms over muscles {np.sqrt(np.mean(rig.fit_rms ** 2)) * 1e3:.2f} mm, max {rig.fit_max.max() * 1e3:.2f} mm; "
          f"{rig.rest_volume.sum() * 1e3:.2f} litres")
    assert rig.fit_rms.max() < FIT_RMS_MAX and rig.fit_max.max() < FIT_MAX_MAX
    # every conformed muscle mesh is the icosphere's (level 3) and was reached by rays
    for m in mus.muscles:
        assert m.vertices.shape == (642, 3) and np.all(np.isfinite(m.vertices))
        assert m.report.hits + m.report.misses == 642 and m.report.hits > 100, m.name


@pytest.mark.parametrize("name", CHARACTERS)
def test_ellipsoid_centres_lie_inside_the_skin(fits, name):
    c, mus, _ = fits(name)
    centres = np.array([m.ellipsoid.centre for m in mus.muscles])
    w = winding_numbers(c.vertices, c.faces, centres)
    outside = [(m.name, round(float(x), 3)) for m, x in zip(mus.muscles, w) if abs(abs(x) - 1.0) > 0.1]
    assert not outside, f"ellipsoid centres outside the skin: {outside}"


def test_conformed_muscles_stay_under_the_generated_skin(fits):
    """On the closed generated body, every conformed muscle lies (almost) wholly inside the skin; the
    thin abdomen bellies on the hollow between the belly and the ribs used to sit half outside."""
    import trimesh
    c, mus, _ = fits("generated")
    skin = trimesh.Trimesh(c.vertices, c.faces, process=False)
    assert skin.is_watertight
    inside = {m.name: float(skin.contains(m.vertices).mean()) for m in mus.muscles}
    worst = min(inside, key=inside.get)
    print(f"\nleast inside: {worst} {inside[worst]:.3f}")
    assert inside[worst] > 0.95


@pytest.mark.parametrize("name,tol", [("CesiumMan", 0.025), ("RiggedFigure", 0.006), ("generated", 0.005)])
def test_left_and_right_muscles_mirror_each_other(fits, name, tol):
    # CesiumMan's skin is symmetric about x = 0 to 1e-6 m but its skeleton is off by 5 mm in x (left
    # and right joints differ by 1 cm when mirrored), and its trunk triangles are large: a looser bound.
    # RiggedFigure's deltoid regions differ a little between its sides (their fitted axes by 8 degrees),
    # and where the axis leaves its blocky shoulder it is cut (rig.muscle.fit._axis_inside), which
    # makes it 5.4 mm and 13% in volume apart
    c, mus, _ = fits(name)
    pairs = [(n, "right_" + n[5:]) for n in mus.names if n.startswith("left_")]
    assert len(pairs) == 12
    flip = np.array([-1.0, 1.0, 1.0])
    worst = max(np.abs(mus.muscle(a).ellipsoid.centre * flip - mus.muscle(b).ellipsoid.centre).max() for a, b in pairs)
    assert worst < tol
    lb, rb = mus.muscle("left_biceps").ellipsoid.centre, mus.muscle("right_biceps").ellipsoid.centre
    assert lb[0] > 0.1 and abs(lb[0] + rb[0]) < 0.015      # the character's left is +x
    if name != "CesiumMan":
        v = dict(zip(mus.names, mus.rig.rest_volume))
        assert max(abs(v[a] / v[b] - 1.0) for a, b in pairs) < (0.15 if name == "RiggedFigure" else 0.1)


# ------------------------------------------------------------------------------- pairs and attachments
@pytest.mark.parametrize("name", CHARACTERS)
def test_pair_muscles_keep_to_their_side_of_the_partition_plane(fits, name):
    c, mus, _ = fits(name)
    V, F, _ = mus.skin
    centroids = V[F].mean(axis=1)
    pairs = [m for m in mus.muscles if m.side != "single"]
    assert len(pairs) == 12     # biceps/triceps, forearm flexors/extensors, quadriceps/hamstrings, x2
    for m in pairs:
        point, normal = m.plane
        partner = next(o for o in pairs if o.group == m.group and o is not m)
        np.testing.assert_allclose(partner.plane[1], -normal, atol=1e-12)
        np.testing.assert_allclose(partner.plane[0], point, atol=1e-12)
        assert (m.ellipsoid.centre - point) @ normal > 0.005, m.name
        assert np.all((centroids[m.region] - point) @ normal >= 0), m.name
        assert ((m.vertices - point) @ normal).min() > -5e-4, f"{m.name} crosses its partition plane"
    # partition 0: the biceps ("upper") takes the front, the triceps the back
    for side in ("left", "right"):
        for front_muscle, back_muscle in (("biceps", "triceps"), ("quadriceps", "hamstrings")):
            f, b = mus.muscle(f"{side}_{front_muscle}"), mus.muscle(f"{side}_{back_muscle}")
            assert f.side == "upper" and b.side == "lower"
            assert f.plane[1] @ mus.front > 0.9 and b.plane[1] @ mus.front < -0.9
            mid = f.plane[0]
            assert (f.ellipsoid.centre - mid) @ mus.front > 0.005 > (b.ellipsoid.centre - mid) @ mus.front


def test_partition_plane_holds_even_with_a_long_reach():
    """With the default reach, a ray toward the partner's side usually finds the far skin too far away
    and is ignored anyway; with reach 10 the plane is what keeps the pairs apart (without it they
    cross it by 2-5 cm on RiggedFigure)."""
    import dataclasses

    from jiggle.rig.muscle.template import load_template
    c = load_character(asset("characters/RiggedFigure.glb"))
    human = load_template("human")
    pairs_only = dataclasses.replace(human, pairs=tuple(p for p in human.pairs
                                                        if any(m.type != "single" for m in p.muscles)))
    mus, warned = fit_quietly(c, pairs_only, FitOptions(reach=10.0))
    halves = [m for m in mus.muscles if m.plane is not None]
    # only the fit quality's notices of RiggedFigure's deltoids poking out of its blocky shoulders
    assert len(halves) == 12 and all("deltoid" in w and "fits poorly" in w for w in warned)
    for m in halves:
        point, normal = m.plane
        assert ((m.vertices - point) @ normal).min() > -5e-4, f"{m.name} crosses its partition plane"


@pytest.mark.parametrize("name", CHARACTERS)
def test_attachments_ride_their_bones(fits, name):
    c, mus, _ = fits(name)
    pos, r = c.bind_positions, mus.roles
    for side in ("left", "right"):
        ua, la = r[f"{side}_upper_arm"], r[f"{side}_lower_arm"]
        b = mus.muscle(f"{side}_biceps")
        assert b.bone == ua and b.bone_label == f"{c.joint_names[ua]}>{c.joint_names[la]}"
        assert b.joints.tolist() == [ua, ua, ua, la]      # the insertion rides the forearm
        np.testing.assert_allclose(b.points[0], pos[ua], atol=1e-12)   # origin: the bone's start (default)
        # insertion: the template's relative (1.12, +-0.06 front, 0) in the upper arm's frame at bind
        e = bone_frame(pos[ua], pos[la], mus.front)
        L = np.linalg.norm(pos[la] - pos[ua])
        np.testing.assert_allclose(b.points[3], pos[ua] + L * (1.12 * e[0] + 0.06 * e[1]), atol=1e-9)
        # hinges (default) at the ellipsoid's major-axis ends; tendons origin -> hinge -> belly, back
        np.testing.assert_allclose(b.points[1:3], b.ellipsoid.ends, atol=1e-12)
        assert b.tendons.shape == (2, 3, 3)
        np.testing.assert_allclose(b.tendons[0], [b.points[0], b.points[1], b.ellipsoid.ends[0]])
        np.testing.assert_allclose(b.tendons[1], [b.ellipsoid.ends[1], b.points[2], b.points[3]])
        # the rig keeps the joints: origin slot 0 rides ua, insertion slot 1 rides la
        i = mus.names.index(b.name)
        assert mus.rig.joints[i, 0] == ua and mus.rig.joints[i, 1] == la
        # forearm flexors: on the forearm, origin on the humerus (explicit), insertion on the hand
        fl = mus.muscle(f"{side}_forearm_flexors")
        assert fl.bone == la and fl.joints.tolist() == [ua, la, la, r[f"{side}_hand"]]
        np.testing.assert_allclose(fl.points[0], pos[la], atol=1e-12)
        # the deltoid's origin rides the trunk
        assert mus.muscle(f"{side}_deltoid").joints[0] == r["chest"]


# ------------------------------------------------------------------------------- multi-belly and fat
@pytest.mark.parametrize("name", CHARACTERS)
def test_abdomen_is_three_disjoint_strips_of_equal_area(fits, name):
    c, mus, _ = fits(name)
    V, F, _ = mus.skin
    bellies = [mus.muscle(f"abdomen_{k}") for k in (1, 2, 3)]
    assert all(b.group == "abdomen" and b.kind == "muscle" and b.side == "single" for b in bellies)
    assert [mus.rig.groups[mus.names.index(b.name)] for b in bellies] == ["abdomen"] * 3
    regions = [set(b.region.tolist()) for b in bellies]
    assert all(len(x) >= 10 for x in regions)
    assert not (regions[0] & regions[1] or regions[1] & regions[2] or regions[0] & regions[2])
    areas = np.array([triangle_areas(V, F[b.region]).sum() for b in bellies])
    assert areas.max() / areas.min() < 1.15, areas
    # side by side across the trunk (e_side of spine > chest), the middle one in the middle
    r = mus.roles
    e = bone_frame(c.bind_positions[r["spine"]], c.bind_positions[r["chest"]], mus.front)
    across = np.array([b.ellipsoid.centre @ e[2] for b in bellies])
    assert np.all(np.diff(across) > 0.02) or np.all(np.diff(across) < -0.02), across
    # one main control: the same origin and insertion (the template gives both), same joints
    for b in bellies[1:]:
        np.testing.assert_allclose(b.points[[0, 3]], bellies[0].points[[0, 3]])
        assert b.joints[0] == bellies[0].joints[0] == r["hips"] and b.joints[3] == r["chest"]


@pytest.mark.parametrize("name", CHARACTERS)
def test_fat_masses_are_fat_and_at_least_their_depth_thick(fits, name):
    c, mus, _ = fits(name)
    kinds = dict(zip(mus.names, mus.rig.kinds))
    assert {n for n, k in kinds.items() if k == "fat"} == FAT
    assert {m.name for m in mus.muscles if m.kind == "fat"} == FAT
    assert sum(k == "muscle" for k in kinds.values()) == 23
    from jiggle.sim.jiggle.materials import default_jiggles
    springs = dict(zip(mus.names, (j.frequency_hz for j in default_jiggles(mus.rig, [m.spec.jiggle for m in mus.muscles]))))
    muscle_hz = np.median([f for n, f in springs.items() if kinds[n] == "muscle"])
    for n in FAT:
        m = mus.muscle(n)
        assert m.spec.kind == "fat" and m.spec.depth >= 0.02
        assert m.ellipsoid.radii.min() >= m.spec.depth - 1e-12
        # fat: its material's springs slower than the muscles', its goal weights looser
        assert m.spec.jiggle.material == "fat" and springs[n] < 0.8 * muscle_hz and m.spec.jiggle.goal_belly < 0.4


# ------------------------------------------------------------------------------- volume over a clip
@pytest.mark.slow
def test_volume_is_kept_over_every_frame_of_a_cmu_clip(fits):
    """The template fitted to a body generated around a CMU clip's skeleton, driven by that clip through
    MuJoCo (sim.drive.skeleton.Skeleton) over every frame: the default "exact" rule holds every muscle's
    lofted volume within 1%; the thesis rule (S = Sc Li / Lc, volume ~ Li / Lc) drifts far more."""
    from jiggle.rig.motion.clip import transforms
    from jiggle.rig.motion.mocap import load_clip
    from jiggle.sim.drive.skeleton import Skeleton
    c, mus, warned = fits("cmu")
    assert mus.skipped == () and warned == []   # love handles included although LowerBack sits on Hips
    clip = load_clip(asset("mocap/cmu_bvh/02_03.bvh"))
    assert c.joint_names == clip.joint_names
    world = transforms(*Skeleton(clip).world())               # every frame of the clip
    assert world.shape == (clip.num_frames, c.num_joints, 4, 4) and clip.num_frames > 100
    rig = mus.rig
    assert rig.volume == "exact" and np.abs(rig.static(c.bind_world).cvs - rig.rest_cvs).max() < 1e-12
    drift = {}
    for rule in ("exact", "thesis"):
        shape = rig.static(world) if rule == "exact" else rig.static(world, volume=rule)
        assert shape.cvs.shape == (clip.num_frames, 40 * rig.M, 3) and np.all(np.isfinite(shape.cvs))
        drift[rule] = np.abs(rig.volumes(shape.cvs) / rig.rest_volume - 1.0).max(axis=0)   # (M,) over frames
    print(f"\n{clip.name}: {clip.num_frames} frames, {rig.M} muscles; max |V / V0 - 1| over frames and muscles: "
          f"exact (default) {drift['exact'].max():.2e} ({rig.names[drift['exact'].argmax()]}), "
          f"thesis {drift['thesis'].max():.3f} ({rig.names[drift['thesis'].argmax()]})")
    assert drift["exact"].max() < 0.01
    assert drift["thesis"].max() > 0.05 and drift["thesis"].max() > 10 * drift["exact"].max()


# ------------------------------------------------------------------------------- bad input
ARM_TEMPLATE = """
name = "arm"
[[pair]]
bone = ["left_shoulder", "left_upper_arm"]
[[pair.muscle]]
name = "clavicle"
[[pair]]
bone = ["left_upper_arm", "left_lower_arm"]
[[pair.muscle]]
name = "whole"
[[pair.muscle]]
name = "front_sheet"
sector = [-30.0, 30.0]
thickness_min = 0.006
[[pair.muscle]]
name = "nowhere"
span = [1.3, 1.5]
"""


@pytest.fixture(scope="module")
def box_arm():
    """A square arm (5 cm box along +x) on joints shoulder, upper (on the shoulder: a zero-length
    link), elbow and wrist, with the roles of a left arm; front is -y."""
    import trimesh
    box = trimesh.creation.box(extents=(0.62, 0.05, 0.05))
    v, f = trimesh.remesh.subdivide_to_size(box.vertices, box.faces, 0.01)
    v = np.asarray(v) + [0.29, 0.0, 1.2]
    f = np.asarray(f)
    names, parents = ("shoulder", "upper", "elbow", "wrist"), np.array([-1, 0, 1, 2])
    bind = np.tile(np.eye(4), (4, 1, 1))
    bind[:, :3, 3] = [[0.0, 0.0, 1.2], [0.0, 0.0, 1.2], [0.3, 0.0, 1.2], [0.55, 0.0, 1.2]]
    dominant = np.where(v[:, 0] < 0.3, 0, 2)[:, None]
    c = Character(vertices=v, faces=f, normals=vertex_normals(v, f), uvs=None, joint_names=names, parents=parents,
                  bind_world=bind, bind_matrices=bind, joints=dominant, weights=np.ones((len(v), 1), np.float32),
                  skeleton=bind_clip(names, parents, bind))
    roles = {"left_shoulder": 0, "left_upper_arm": 1, "left_lower_arm": 2, "left_hand": 3}
    return c, roles, np.array([0.0, -1.0, 0.0])


def test_empty_zero_length_and_flat_regions(box_arm):
    c, roles, front = box_arm
    mus, warned = fit_quietly(c, template_from_toml(ARM_TEMPLATE), roles=roles, front=front)
    # a zero-length bone and a span that selects nothing: skipped, warned, listed
    assert [n for n, _ in mus.skipped] == ["clavicle", "nowhere"]
    assert "zero length" in mus.skipped[0][1] and "empty" in mus.skipped[1][1]
    assert len(warned) == 2 and "'clavicle' skipped" in warned[0] and "'nowhere' skipped" in warned[1]
    assert mus.names == ("whole", "front_sheet") and mus.rig.M == 2
    # the upper arm starts at a joint collapsed onto the shoulder: its region is the shoulder's segment
    whole = mus.muscle("whole")
    assert whole.bone == 1 and len(whole.region) > 1000 and whole.bone_label == "upper>elbow"
    # a flat region (the front face only): the thinnest radius is thickness_min, the sheet's outer
    # side stays on the face (y = -0.025) and it lies inside
    e = mus.muscle("front_sheet").ellipsoid
    V, F, _ = mus.skin
    assert np.allclose(V[F[mus.muscle("front_sheet").region]][..., 1], -0.025)
    assert e.radii[2] == pytest.approx(0.006, abs=1e-12) and e.radii[1] > 0.006
    assert e.axes[2] @ front == pytest.approx(1.0)
    assert e.centre[1] == pytest.approx(-0.025 + 0.006, abs=1e-9)
    assert mus.rig.rest_volume[1] > 0
    # nothing fittable at all: an error, not an empty musculature
    only_nowhere = ARM_TEMPLATE.split("[[pair.muscle]]\nname = \"whole\"")[0] + \
        '[[pair.muscle]]\nname = "nowhere"\nspan = [1.3, 1.5]\n'
    with pytest.raises(InputError, match="no muscle of the template could be fitted"):
        fit_quietly(c, template_from_toml(only_nowhere), roles=roles, front=front)


def test_unknown_labels_are_refused_with_the_known_ones(fits, tmp_path):
    c, _, _ = fits("CesiumMan")
    bad = tmp_path / "tail.toml"
    bad.write_text('[[pair]]\nbone = ["hips", "left_tail"]\n[[pair.muscle]]\nname = "wag"\n')
    with pytest.raises(InputError) as e:
        fit_musculature(c, bad)
    msg = str(e.value)
    assert "tail.toml" in msg and "'left_tail'" in msg and "pair[0].bone" in msg
    assert "hips" in msg and "left_upper_arm" in msg           # the labels a template may use
    # an optional role this skeleton lacks (CesiumMan has no clavicles): the pair is left out with a
    # notice; a required one it lacks (a quadruped's leg on a human) is refused with the known labels
    shoulder = tmp_path / "shoulder.toml"
    shoulder.write_text('[[pair]]\nbone = ["left_shoulder", "left_upper_arm"]\n[[pair.muscle]]\nname = "trap"\n'
                        '[[pair]]\nbone = ["left_upper_arm", "left_lower_arm"]\n[[pair.muscle]]\nname = "arm"\n')
    with pytest.warns(JiggleWarning, match="muscles trap left out: the skeleton has no left_shoulder"):
        mus = fit_musculature(c, shoulder)
    assert mus.names == ("arm",)
    leg = tmp_path / "leg.toml"
    leg.write_text('[[pair]]\nbone = ["left_hind_upper_leg", "left_hind_lower_leg"]\n[[pair.muscle]]\nname = "q"\n')
    with pytest.raises(InputError) as e:
        fit_musculature(c, leg)
    msg = str(e.value)
    assert "'left_hind_upper_leg'" in msg and "known labels:" in msg
    assert "hips (Skeleton_torso_joint_1)" in msg and "left_upper_arm (" in msg
    assert "the skeleton is a biped" in msg and "'human'" in msg


def test_parameters_out_of_range_are_refused():
    for kw, field in (({"lam": 2.0}, "lambda"), ({"lam": -0.1}, "lambda"), ({"iterations": -1}, "iterations"),
                      ({"iterations": 2.5}, "iterations"), ({"subdivisions": 0}, "subdivisions"),
                      ({"subdivisions": 6}, "subdivisions"), ({"reach": 0.0}, "reach")):
        with pytest.raises(InputError) as e:
            FitOptions(**kw)
        assert field in str(e.value)
    with pytest.raises(InputError, match=r"pair\[0\]\.muscle\[0\]\.tone"):
        template_from_toml('[[pair]]\nbone = ["left_upper_arm", "left_lower_arm"]\n'
                           '[[pair.muscle]]\nname = "b"\ntone = 1.5\n', "bad.toml")


BILLION_LAUGHS = """<?xml version="1.0"?>
<!DOCTYPE lolz [
 <!ENTITY lol "lol">
 <!ENTITY lol2 "&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;">
 <!ENTITY lol3 "&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;">
]>
<musculoskeletalTemplate name="&lol3;"/>
"""
EXTERNAL = """<?xml version="1.0"?>
<!DOCTYPE t [<!ENTITY secret SYSTEM "file:///etc/passwd">]>
<musculoskeletalTemplate name="&secret;"/>
"""
MALFORMED = """<musculoskeletalTemplate name="x"><boneMusclePair><bone>"""


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.parametrize("text,expect", [(BILLION_LAUGHS, "refused"), (EXTERNAL, "refused"),
                                         (MALFORMED, "not well-formed XML")])
def test_cli_refuses_hostile_or_malformed_xml_templates(capsys, tmp_path, text, expect):
    figure = asset("characters/RiggedFigure.glb")
    xml = tmp_path / "evil.xml"
    xml.write_text(text)
    out_toml = tmp_path / "out" / "muscles.toml"
    code, out, err = run(capsys, "fit", figure, "--template", xml, "--out", out_toml, "--no-render")
    assert code == 2 and out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("jiggle: error: ") and str(xml) in lines[0] and expect in lines[0]
    assert "root:" not in err and not out_toml.exists()


def test_cli_refuses_bad_options(capsys, tmp_path):
    for argv, what in ((["--smoothing", "3"], "--smoothing"), (["--smoothing", "x"], "--smoothing"),
                       (["--iterations", "-1"], "--iterations"), (["--volume", "more"], "--volume")):
        with pytest.raises(SystemExit) as e:
            main(["fit", "--out", str(tmp_path / "m.toml"), "--no-render", *argv])
        err = capsys.readouterr().err
        assert e.value.code == 2 and what in err and err.strip().splitlines()[-1].startswith("jiggle: error: ")
    code, _, err = run(capsys, "fit", tmp_path / "missing.glb", "--out", tmp_path / "m.toml", "--no-render")
    assert code == 2 and "missing.glb" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "m.toml").exists()


# ------------------------------------------------------------------------------- the command
@pytest.mark.slow
def test_cli_fit_writes_musculature_facts_and_picture(capsys, tmp_path, fits):
    cesium = asset("characters/CesiumMan.glb")
    out_toml, png = tmp_path / "fit" / "muscles.toml", tmp_path / "pics" / "fit.png"
    code, out, err = run(capsys, "fit", cesium, "--out", out_toml, "--png", png)
    assert code == 0, err
    assert "fitted 28 muscles (5 fat)" in out and "jiggle: warning" not in err
    assert "fit quality: 28 ok, 0 warned, 0 refused" in out
    doc = tomllib.loads(out_toml.read_text())
    muscles = doc["muscle"]
    _, mus, _ = fits("CesiumMan")
    assert len(muscles) == 28 and [m["name"] for m in muscles] == list(mus.names)
    assert doc["template"] == "human" and doc["cvs_per_muscle"] == 40
    for i, m in enumerate(muscles):
        cvs = np.array(m["section_cvs"])
        assert cvs.shape == (40, 3)
        # the same fit as in-process, rounded to micrometres
        np.testing.assert_allclose(cvs, mus.rig.rest_cvs[40 * i:40 * i + 40], atol=1e-6)
        assert m["kind"] == ("fat" if m["name"] in FAT else "muscle") and len(m["joints"]) == 4
        assert m["volume_m3"] > 0 and 0 <= m["fit_rms_m"] < FIT_RMS_MAX
    facts = json.loads((tmp_path / "fit" / "muscles.json").read_text())
    assert facts["muscles"] == 28 and facts["fat"] == 5 and facts["skipped"] == []
    assert [m["name"] for m in facts["per_muscle"]] == list(mus.names)
    assert facts["quality"]["ok"] == 28 and all(m["status"] == "ok" for m in facts["per_muscle"])
    # the render smoke test: without working GL, VTK crashes or draws nothing
    import imageio.v3 as iio
    img = iio.imread(png)
    # 450-pixel panels: segmentation, front, side, back, the painted maps (the jiggle map, the shell regions)
    # and whatever else fit draws (the bone capsules)
    assert img.shape[0] == 800 and img.shape[1] % 450 == 0 and img.shape[1] >= 2700 and png.stat().st_size > 20_000
    # the maps' starting point beside the TOML, to paint in Blender and read back
    assert {p.name for p in out_toml.parent.iterdir()} >= {"CesiumMan.painted.glb", "CesiumMan.jiggle_map.npz"}
    assert len(np.unique(img.reshape(-1, img.shape[-1]), axis=0)) > 200
    assert not list(png.parent.glob(".*")) and not list(out_toml.parent.glob(".*"))  # no temporary files


@pytest.mark.slow
def test_cli_fit_default_generated_body_without_picture(capsys, tmp_path):
    out_toml = tmp_path / "muscles.toml"
    code, out, err = run(capsys, "fit", "--no-render", "--out", out_toml)
    assert code == 0, err
    assert "fitted 28 muscles (5 fat)" in out
    assert sorted(p.name for p in tmp_path.iterdir()) == ["jumping_jacks_body.jiggle_map.npz",
                                                          "jumping_jacks_body.painted.glb", "muscles.json",
                                                          "muscles.toml"]
    assert len(tomllib.loads(out_toml.read_text())["muscle"]) == 28
