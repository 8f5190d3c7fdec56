"""Body plans from the rest pose's geometry, quadruped roles, and the checks that refuse a role map the
skeleton's shape contradicts (rig/motion/body_plan.py)."""
from __future__ import annotations

import dataclasses
import glob
import os
import warnings

import numpy as np
import pytest

from jiggle.rig.base.errors import InputError
from jiggle.rig.motion.body_plan import (
    QUADRUPED_REQUIRED,
    check_roles,
    detect_body_plan,
    quadruped_roles,
)
from jiggle.rig.motion.clip import Clip
from jiggle.rig.motion.role_map import resolve_roles

ASSETS = os.path.join(os.path.dirname(__file__), "..", "..", "..", "shared", "assets")

# A dog facing -Y (left at +X), Z-up metres: joint, parent, world position at rest.
DOG = [
    ("pelvis", "", (0.0, 0.2, 0.55)),
    ("spine1", "pelvis", (0.0, 0.0, 0.56)),
    ("chest", "spine1", (0.0, -0.25, 0.57)),
    ("neck", "chest", (0.0, -0.35, 0.68)),
    ("head", "neck", (0.0, -0.45, 0.78)),
    ("tail1", "pelvis", (0.0, 0.3, 0.55)),
    ("tail2", "tail1", (0.0, 0.45, 0.5)),
    ("tail3", "tail2", (0.0, 0.6, 0.42)),
] + [row for s, x in (("l", 0.1), ("r", -0.1)) for row in (
    (f"{s}_scapula", "chest", (x * 0.6, -0.22, 0.62)),
    (f"{s}_shoulder", f"{s}_scapula", (x, -0.3, 0.48)),
    (f"{s}_elbow", f"{s}_shoulder", (x, -0.27, 0.3)),
    (f"{s}_carpus", f"{s}_elbow", (x, -0.28, 0.1)),
    (f"{s}_fpaw", f"{s}_carpus", (x, -0.3, 0.03)),
    (f"{s}_hip", "pelvis", (x, 0.22, 0.5)),
    (f"{s}_stifle", f"{s}_hip", (x, 0.15, 0.3)),
    (f"{s}_hock", f"{s}_stifle", (x, 0.25, 0.13)),
    (f"{s}_hpaw", f"{s}_hock", (x, 0.22, 0.03)),
)]
DOG_ENDS = [("head", (0.0, -0.62, 0.72)), ("tail3", (0.0, 0.75, 0.35))] + [
    (f"{s}_{p}", (x, y, 0.0)) for s, x in (("l", 0.1), ("r", -0.1)) for p, y in (("fpaw", -0.34), ("hpaw", 0.18))]


def skeleton(rows, ends, name="dog") -> Clip:
    """A one-frame Clip with world-aligned joint frames (as BVH) from world rest positions."""
    names = [r[0] for r in rows]
    parents = np.array([names.index(p) if p else -1 for _, p, _ in rows], np.int32)
    world = np.array([r[2] for r in rows], float)
    offsets = np.array([world[j] - (world[p] if p >= 0 else 0.0) for j, p in enumerate(parents)])
    rot = np.tile([1.0, 0.0, 0.0, 0.0], (len(rows), 1))
    ep = np.array([names.index(n) for n, _ in ends], np.int32)
    eo = np.array([np.asarray(w) - world[names.index(n)] for n, w in ends]).reshape(-1, 3)
    return Clip(joint_names=names, parents=parents, offsets=offsets, rest_rotations=rot, rotations=rot[None],
                translations=offsets[None], fps=30.0, end_parents=ep, end_offsets=eo, name=name)


def named(clip, roles):
    return {r: clip.joint_names[j] for r, j in roles.items()}


def test_a_dog_is_a_quadruped_with_its_roles():
    dog = skeleton(DOG, DOG_ENDS)
    plan = detect_body_plan(dog)
    assert plan.kind == "quadruped" and plan.ground_limbs == 4 and plan.tail and plan.spine_deg < 10, plan
    assert plan.template == "quadruped"
    roles = named(dog, quadruped_roles(dog))
    assert roles == {
        "hips": "pelvis", "spine": "spine1", "chest": "chest", "neck": "neck", "head": "head", "tail": "tail1",
        "left_front_shoulder": "l_scapula", "left_front_upper_leg": "l_shoulder", "left_front_lower_leg": "l_elbow",
        "left_front_foot": "l_carpus", "left_front_toe": "l_fpaw",
        "left_hind_upper_leg": "l_hip", "left_hind_lower_leg": "l_stifle", "left_hind_foot": "l_hock",
        "left_hind_toe": "l_hpaw",
        "right_front_shoulder": "r_scapula", "right_front_upper_leg": "r_shoulder",
        "right_front_lower_leg": "r_elbow", "right_front_foot": "r_carpus", "right_front_toe": "r_fpaw",
        "right_hind_upper_leg": "r_hip", "right_hind_lower_leg": "r_stifle", "right_hind_foot": "r_hock",
        "right_hind_toe": "r_hpaw"}
    assert set(QUADRUPED_REQUIRED) <= set(roles)
    # resolve_roles takes the quadruped's path when no preset fits, and its result passes the checks
    assert named(dog, resolve_roles(dog)) == roles


def test_the_dog_turned_or_without_tail_keeps_its_roles():
    """Facing +X instead of -Y: left and right follow the body, not the world axes. No tail: no tail role."""
    turn = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # -Y -> +X
    rows = [(n, p, tuple(turn @ np.array(w))) for n, p, w in DOG]
    ends = [(n, tuple(turn @ np.array(w))) for n, w in DOG_ENDS]
    dog = skeleton(rows, ends)
    assert named(dog, quadruped_roles(dog)) == named(skeleton(DOG, DOG_ENDS), quadruped_roles(skeleton(DOG, DOG_ENDS)))
    bare = skeleton([r for r in DOG if not r[0].startswith("tail")], [e for e in DOG_ENDS if e[0] != "tail3"])
    plan = detect_body_plan(bare)
    assert plan.kind == "quadruped" and not plan.tail
    assert "tail" not in quadruped_roles(bare)


@pytest.mark.parametrize("case", ["six_legs", "lying_human", "snake"])
def test_other_body_plans_say_why(case):
    if case == "six_legs":
        rows = DOG + [("l_mid", "spine1", (0.1, 0.0, 0.4)), ("l_mpaw", "l_mid", (0.12, 0.0, 0.03)),
                      ("r_mid", "spine1", (-0.1, 0.0, 0.4)), ("r_mpaw", "r_mid", (-0.12, 0.0, 0.03))]
        clip = skeleton(rows, DOG_ENDS + [("l_mpaw", (0.12, 0.0, 0.0)), ("r_mpaw", (-0.12, 0.0, 0.0))])
        want = "6 limbs reach the ground"
    elif case == "lying_human":  # a biped lying on its back: two "legs" on the floor, a flat spine
        rows = [("hips", "", (0, 0, 0.1)), ("chest", "hips", (0, -0.5, 0.1)), ("head", "chest", (0, -0.8, 0.12)),
                ("l_hip", "hips", (0.1, 0, 0.1)), ("l_knee", "l_hip", (0.1, 0.45, 0.1)),
                ("l_ankle", "l_knee", (0.1, 0.9, 0.05)),
                ("r_hip", "hips", (-0.1, 0, 0.1)), ("r_knee", "r_hip", (-0.1, 0.45, 0.1)),
                ("r_ankle", "r_knee", (-0.1, 0.9, 0.05))]
        clip = skeleton(rows, [("head", (0, -1.0, 0.12)), ("l_ankle", (0.1, 1.0, 0.0)), ("r_ankle", (-0.1, 1.0, 0.0))])
        want = "spine 1 deg above the horizontal"
    else:
        rows = [(f"s{i}", f"s{i - 1}" if i else "", (0.0, 0.2 * i, 0.05)) for i in range(8)]
        clip = skeleton(rows, [("s7", (0.0, 1.6, 0.05))])
        want = "reach the ground"
    plan = detect_body_plan(clip)
    assert plan.kind == "other" and want in plan.reason, plan
    assert plan.template is None            # the fit's generic template, not a built-in one


def test_human_template_on_a_dog_is_refused_naming_roles():
    """The human role map on the dog (the tail as an arm, as name-blind mapping did) is refused: the
    arms do not mirror each other. Never applied."""
    dog = skeleton(DOG, DOG_ENDS)
    i = dog.joint_names.index
    bad = {"hips": i("pelvis"), "spine": i("spine1"), "head": i("head"),
           "left_upper_arm": i("tail1"), "left_lower_arm": i("tail2"), "left_hand": i("tail3"),
           "right_upper_arm": i("r_hip"), "right_lower_arm": i("r_stifle"), "right_hand": i("r_hock"),
           "left_upper_leg": i("l_shoulder"), "left_lower_leg": i("l_elbow"), "left_foot": i("l_carpus"),
           "right_upper_leg": i("r_shoulder"), "right_lower_leg": i("r_elbow"), "right_foot": i("r_carpus")}
    with pytest.raises(InputError, match=r"left_upper_arm \(tail1\) and right_upper_arm \(r_hip\) do not mirror"
                                         r".*Roles found: .*missing: .*left_shoulder"):
        check_roles(dog, bad)
    # a chain out of order is refused too
    good = quadruped_roles(dog)
    swapped = {**good, "left_front_foot": good["left_front_lower_leg"], "left_front_lower_leg": good["left_front_foot"],
               "right_front_foot": good["right_front_lower_leg"],
               "right_front_lower_leg": good["right_front_foot"]}
    with pytest.raises(InputError, match="is not below"):
        check_roles(dog, swapped)


def human_files():
    files = sorted(glob.glob(os.path.join(ASSETS, "mocap", "cmu_bvh", "*.bvh")))[:2]
    files += sorted(glob.glob(os.path.join(ASSETS, "mocap", "cmu_amc", "*.amc")))[:1]
    files += [os.path.join(ASSETS, "characters", n) for n in ("CesiumMan.glb", "RiggedFigure.glb")]
    files += [os.path.join(ASSETS, "mjcf", "humanoid_CMU.xml")]
    files = [f for f in files if os.path.isfile(f)]
    return files + [os.path.join(os.path.dirname(__file__), "..", "..", "scenes", "motions", "jumping_jacks.toml")]


@pytest.mark.parametrize("path", human_files(), ids=os.path.basename)
def test_humans_are_bipeds_and_their_maps_pass(path):
    from jiggle.rig.character.load import load_skeleton
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        clip = load_skeleton(path)
    plan = detect_body_plan(clip)
    assert plan.kind == "biped" and plan.spine_deg > 75, plan
    assert plan.template == "human"
    check_roles(clip, resolve_roles(clip))  # presets and automatic maps alike


# The dog grazing (head lowered below the back), its tail raised above the back, horns on its head and two pole
# targets (IK helpers, no skin) hung off the pelvis behind the tail: joint, parent, world position at rest.
GRAZING = {"neck": (0.0, -0.38, 0.45), "head": (0.0, -0.45, 0.3),
           "tail1": (0.0, 0.3, 0.6), "tail2": (0.0, 0.38, 0.75), "tail3": (0.0, 0.45, 0.9)}
COW = [(n, p, GRAZING.get(n, w)) for n, p, w in DOG] + [
    ("l_horn", "head", (0.06, -0.42, 0.4)), ("r_horn", "head", (-0.06, -0.42, 0.4)),
    ("pole_l", "pelvis", (0.1, 0.9, 0.3)), ("pole_r", "pelvis", (-0.1, 0.9, 0.3))]
COW_ENDS = [("head", (0.0, -0.6, 0.22)), ("tail3", (0.0, 0.5, 1.0))] + DOG_ENDS[2:] + [
    ("l_horn", (0.1, -0.4, 0.5)), ("r_horn", (-0.1, -0.4, 0.5))]
# skin weight per joint (summed over the vertices): the head and neck carry most, a tail little, poles none
COW_SKIN = {"head": 10.0, "neck": 4.0, "l_horn": 0.3, "r_horn": 0.3, "tail1": 0.6, "tail2": 0.4, "tail3": 0.3,
            "pole_l": 0.0, "pole_r": 0.0}


def test_the_skin_tells_the_head_end_of_a_grazing_horned_quadruped():
    """Issue 43: with the head lowered, the tail raised above it, horns and pole targets, the highest point is the
    tail's tip; the skin weight says the head end is the other one (it carries more skin beyond its girdle), the
    head is the head joint (the horns below it carry less than it does), and the tail is the chain from the hips,
    not a pole target. The weights come as a keyword or in clip.meta["joint_weight"] (as body_skeleton gives)."""
    cow = skeleton(COW, COW_ENDS, name="cow")
    weights = np.array([COW_SKIN.get(n, 2.0) for n in cow.joint_names])
    plan = detect_body_plan(cow, weights=weights)
    assert plan.kind == "quadruped" and plan.tail and "carrying more skin" in plan.reason, plan
    roles = named(cow, quadruped_roles(cow, weights=weights))
    dog = named(skeleton(DOG, DOG_ENDS), quadruped_roles(skeleton(DOG, DOG_ENDS)))
    assert roles == dog            # every role where the upright dog has it: head, tail, girdles, sides
    carried = dataclasses.replace(cow, meta={"joint_weight": weights})
    assert named(carried, quadruped_roles(carried)) == roles
    assert named(carried, resolve_roles(carried)) == roles


def test_pole_targets_are_no_tail():
    """Without weights (geometry only) a pole target hung off the pelvis behind the tail's tip is not the tail:
    a tail starts at the hips."""
    rows = DOG + [("pole_l", "pelvis", (0.1, 0.9, 0.3)), ("pole_r", "pelvis", (-0.1, 0.9, 0.3))]
    dog = skeleton(rows, DOG_ENDS)
    assert named(dog, quadruped_roles(dog))["tail"] == "tail1"
    bare = skeleton([r for r in rows if not r[0].startswith("tail")], [e for e in DOG_ENDS if e[0] != "tail3"])
    assert "tail" not in quadruped_roles(bare) and not detect_body_plan(bare).tail


ZOO = {"Cow": "a lowered head, horns, a tail above the head", "Horse": "head up, ears"}


@pytest.mark.parametrize("name", sorted(ZOO))
def test_zoo_quadrupeds_face_their_heads(name):
    """The shared Quaternius Cow and Horse (CC0; IK feet and pole targets, a seven-joint tail): the body's skeleton
    (rig.character.body_skeleton, with its skin weights) is a quadruped with its head at Head, its tail at Tail1
    and its legs on their own sides; the Cow's tail once turned it around (the head found as the highest point
    off the legs)."""
    path = os.path.join(ASSETS, "characters", "zoo", f"{name}.glb")
    if not os.path.isfile(path):
        pytest.skip(f"shared asset {path} is absent")
    from jiggle.rig.base.errors import JiggleWarning
    from jiggle.rig.character.body_skeleton import body_skeleton
    from jiggle.rig.character.gltf_character import read_gltf_character
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", JiggleWarning)
        character = read_gltf_character(path)
    body, order = body_skeleton(character)
    plan = detect_body_plan(body)
    assert plan.kind == "quadruped" and plan.tail, plan.reason
    names = character.joint_names
    roles = {r: names[order[j]] for r, j in resolve_roles(body).items()}
    expect = {"hips": "Back", "spine": "Torso", "chest": "Torso2", "neck": "Torso3", "head": "Head", "tail": "Tail1"}
    for s, c in (("left", "L"), ("right", "R")):
        expect.update({f"{s}_front_shoulder": f"FrontShoulder.{c}", f"{s}_front_upper_leg": f"FrontUpperLeg.{c}",
                       f"{s}_front_lower_leg": f"FrontLowerLeg.{c}", f"{s}_front_foot": f"IKFrontLeg.{c}",
                       f"{s}_front_toe": f"FF.{c}", f"{s}_hind_upper_leg": f"BackUpperLeg.{c}",
                       f"{s}_hind_lower_leg": f"BackLowerLeg.{c}", f"{s}_hind_foot": f"IKBackLeg.{c}",
                       f"{s}_hind_toe": f"FFB.{c}"})
    assert roles == expect
