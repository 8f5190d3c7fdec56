"""Roles found from a skeleton's shape (rig.motion.role_map): the presets' answers on CesiumMan and CMU, all
roles with the right sides on other skeletons, mirrored and turned skeletons, facing, explicit maps."""
from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import pytest
from conftest import CMU_BVH, asset

from jiggle.rig.base.errors import InputError, JiggleWarning
from jiggle.rig.character.load import body_character, load_character, load_skeleton
from jiggle.rig.motion import quat
from jiggle.rig.motion.body_plan import check_roles
from jiggle.rig.motion.clip import Clip
from jiggle.rig.motion.mocap import load_clip
from jiggle.rig.motion.retarget import REQUIRED, ROLES, JointMap
from jiggle.rig.motion.role_map import auto_roles, facing, resolve_roles

DEMO = "scenes/motions/jumping_jacks.toml"
# the demo skeleton's joints by role (l_ is the character's left)
DEMO_ROLES = {"hips": "pelvis", "spine": "spine", "chest": "chest", "neck": "neck", "head": "head"}
for _s in ("left", "right"):
    DEMO_ROLES.update({f"{_s}_{r}": f"{_s[0]}_{n}" for r, n in (
        ("shoulder", "clavicle"), ("upper_arm", "upper_arm"), ("lower_arm", "forearm"), ("hand", "hand"),
        ("upper_leg", "thigh"), ("lower_leg", "shin"), ("foot", "foot"), ("toe", "toe"))})


def names(clip: Clip, roles: dict[str, int]) -> dict[str, str]:
    return {r: clip.joint_names[j] for r, j in roles.items()}


def preset_names(clip: Clip, preset: str) -> dict[str, str]:
    return names(clip, JointMap.load(preset).resolve(clip.joint_names))


def mirrored(clip: Clip) -> Clip:
    """One-frame rest clip reflected through the x = 0 plane: offsets x -> -x, and each rotation
    conjugated by the reflection ((w, x, y, z) -> (w, x, -y, -z)), so rest positions are x-negated."""
    flip = np.array([-1.0, 1.0, 1.0])
    rot = clip.rest_rotations * np.array([1.0, 1.0, -1.0, -1.0])
    off = clip.offsets * flip
    return dataclasses.replace(clip, offsets=off, rest_rotations=rot, rotations=rot[None],
                               translations=off[None], end_offsets=clip.end_offsets * flip)


def turned(clip: Clip, degrees: float) -> Clip:
    """One-frame rest clip turned about +Z (the root's rest rotation and offset)."""
    q = quat.from_axis_angle(np.array([0.0, 0.0, 1.0]), np.radians(degrees))
    rot, off = clip.rest_rotations.copy(), clip.offsets.copy()
    for r in np.nonzero(clip.parents < 0)[0]:
        rot[r] = quat.mul(q, rot[r])
        off[r] = quat.rotate(q, off[r])
    return dataclasses.replace(clip, offsets=off, rest_rotations=rot, rotations=rot[None], translations=off[None])


def swap_sides(d: dict[str, str]) -> dict[str, str]:
    other = {"left": "right", "right": "left"}
    return {(f"{other[k.split('_')[0]]}_{k.split('_', 1)[1]}" if k.split("_")[0] in other else k): v
            for k, v in d.items()}


@pytest.fixture(scope="module")
def cesium() -> Clip:
    return load_character(asset("characters/CesiumMan.glb")).skeleton


def test_cesiumman_matches_its_preset(cesium):
    assert names(cesium, auto_roles(cesium)) == preset_names(cesium, "cesiumman")
    # no collar bones in this rig: the shoulder roles are left out
    assert "left_shoulder" not in auto_roles(cesium)


@pytest.mark.parametrize("stem", CMU_BVH)
def test_cmu_bvh_matches_its_preset(stem):
    clip = load_clip(asset(f"mocap/cmu_bvh/{stem}.bvh"))
    # the preset names every role; its spine is LowerBack, at the Hips' place, and its hand LeftHand,
    # at LeftFingerBase's place: zero-length bones keep the first joint of the place
    assert names(clip, auto_roles(clip)) == preset_names(clip, "cmu")


@pytest.mark.parametrize("rel", ["mocap/cmu_amc/01_01.amc", "mjcf/humanoid_CMU.xml"])
def test_cmu_asf_and_mjcf_match_the_preset(rel):
    path = asset(rel)
    clip = load_skeleton(path) if rel.endswith(".xml") else load_clip(path)
    # ASF names (root, lclavicle, lhumerus, lwrist, ...); the clavicles start at lowerneck's place
    # but hang from thorax, the chest; lwrist is the hand though lhand/lfingers go further
    assert names(clip, auto_roles(clip)) == preset_names(clip, "cmu")


def test_rigged_figure_sides():
    clip = load_character(asset("characters/RiggedFigure.glb")).skeleton
    got = names(clip, auto_roles(clip))
    expect = {"hips": "torso_joint_1", "spine": "torso_joint_2", "chest": "torso_joint_3", "neck": "neck_joint_1",
              "head": "neck_joint_2"}
    for s, c in (("left", "L"), ("right", "R")):
        expect.update({f"{s}_upper_arm": f"arm_joint_{c}_1", f"{s}_lower_arm": f"arm_joint_{c}_2",
                       f"{s}_hand": f"arm_joint_{c}_3", f"{s}_upper_leg": f"leg_joint_{c}_1",
                       f"{s}_lower_leg": f"leg_joint_{c}_2", f"{s}_foot": f"leg_joint_{c}_3",
                       f"{s}_toe": f"leg_joint_{c}_5"})
    assert got == expect
    assert set(REQUIRED) <= set(got)
    # no preset fits its names: resolve_roles falls back to the shape
    assert resolve_roles(clip) == auto_roles(clip)


def test_demo_skeleton_and_generated_body():
    clip = load_clip(DEMO)
    assert names(clip, auto_roles(clip)) == DEMO_ROLES
    # the generated body's bind pose swings the arms out by 40 deg; the roles do not move
    bind = body_character(clip).skeleton
    assert names(bind, auto_roles(bind)) == DEMO_ROLES


def test_mirrored_skeletons_swap_sides(cesium):
    for clip, expect in ((load_clip(DEMO), DEMO_ROLES), (cesium, preset_names(cesium, "cesiumman"))):
        m = mirrored(clip)
        got = names(m, auto_roles(m))
        assert got == swap_sides(expect)
        _, pos = m.rest_world()
        front, left = facing(pos, auto_roles(m))
        # the toes still point to -Y, so the left is still +X, where the old right side went
        np.testing.assert_allclose(front, [0, -1, 0], atol=0.1)
        np.testing.assert_allclose(left, [1, 0, 0], atol=0.1)


@pytest.mark.parametrize("degrees", [90.0, 180.0, -135.0])
def test_turned_skeleton_keeps_its_roles(degrees):
    clip = load_clip(DEMO)
    t = turned(clip, degrees)
    roles = auto_roles(t)
    assert names(t, roles) == DEMO_ROLES
    _, pos = t.rest_world()
    front, left = facing(pos, roles)
    a = np.radians(degrees)
    np.testing.assert_allclose(front, [np.sin(a), -np.cos(a), 0.0], atol=1e-9)  # -Y turned
    np.testing.assert_allclose(left, [np.cos(a), np.sin(a), 0.0], atol=1e-9)  # +X turned


def test_facing_on_cesiumman(cesium):
    _, pos = cesium.rest_world()
    front, left = facing(pos, resolve_roles(cesium))
    np.testing.assert_allclose(left, [1, 0, 0], atol=0.02)
    np.testing.assert_allclose(front, [0, -1, 0], atol=0.02)
    assert abs(np.linalg.norm(front) - 1) < 1e-12 and front[2] == 0 and left[2] == 0
    # the arms stand in when the legs are not mapped
    arms = {r: j for r, j in resolve_roles(cesium).items() if "leg" not in r}
    np.testing.assert_allclose(facing(pos, arms)[1], [1, 0, 0], atol=0.02)
    with pytest.raises(InputError, match="upper_leg"):
        facing(pos, {"hips": 0})


def test_resolve_roles(cesium, tmp_path):
    # no map: the preset whose names fit, else the shape
    assert resolve_roles(cesium) == JointMap.load("cesiumman").resolve(cesium.joint_names)
    demo = load_clip(DEMO)
    assert resolve_roles(demo) == auto_roles(demo)
    # explicit maps: by name, path or JointMap
    assert resolve_roles(cesium, JointMap.load("cesiumman")) == resolve_roles(cesium, "cesiumman")
    with pytest.raises(InputError, match="no joint map preset named 'nope'"):
        resolve_roles(cesium, "nope")
    with pytest.raises(InputError) as e:
        resolve_roles(cesium, "cmu")  # names CMU joints CesiumMan does not have
    assert e.value.field == "joints.hips" and e.value.path.endswith("cmu.toml")
    bad = tmp_path / "bad.toml"
    text = "[joints]\n" + "".join(f'{r} = "{DEMO_ROLES[r]}"\n' for r in REQUIRED)
    bad.write_text(text.replace('left_hand = "l_hand"', 'left_hand = "l_paw"'))
    with pytest.raises(InputError) as e:
        resolve_roles(demo, bad)
    assert e.value.field == "joints.left_hand" and e.value.path == str(bad) and "l_paw" in str(e.value)
    good = tmp_path / "good.toml"
    good.write_text(text)
    assert names(demo, resolve_roles(demo, good)) == {r: DEMO_ROLES[r] for r in ROLES if r in REQUIRED}


def _tree(spec, ends=()) -> Clip:
    """One-frame clip from (name, parent name or None, world position) rows and (joint, world end)."""
    idx = {s[0]: i for i, s in enumerate(spec)}
    par = np.array([idx[s[1]] if s[1] else -1 for s in spec])
    w = np.array([s[2] for s in spec], float)
    off = w - np.where(par[:, None] >= 0, w[par], 0.0)
    rot = np.tile([1.0, 0.0, 0.0, 0.0], (len(spec), 1))
    return Clip([s[0] for s in spec], par, off, rot, rot[None], off[None], 30.0,
                end_parents=np.array([idx[e[0]] for e in ends], np.int32),
                end_offsets=np.array([np.subtract(e[1], w[idx[e[0]]]) for e in ends]).reshape(-1, 3))


def _rig(root=False, head_top=False, heel=False, toes=True, knees=0.0):
    """A Mixamo/UE-like rig: fingers past the wrist, optional floor root with IK feet, head-top marker,
    heels; the toes point to -Y and "L" is at +X (the character's left)."""
    s = [("root", None, (0, 0, 0))] if root else []
    s += [("Hips", "root" if root else None, (0, 0, 1.0)), ("Spine", "Hips", (0, 0, 1.1)),
          ("Spine1", "Spine", (0, 0, 1.25)), ("Spine2", "Spine1", (0, 0, 1.4)), ("Neck", "Spine2", (0, 0, 1.5)),
          ("Head", "Neck", (0, 0, 1.6))]
    if head_top:
        s.append(("HeadTop_End", "Head", (0, 0, 1.78)))
    for c, x in (("L", 1), ("R", -1)):
        s += [(f"Sh{c}", "Spine2", (0.05 * x, 0, 1.45)), (f"Arm{c}", f"Sh{c}", (0.18 * x, 0, 1.45)),
              (f"Fore{c}", f"Arm{c}", (0.46 * x, 0, 1.45)), (f"Hand{c}", f"Fore{c}", (0.71 * x, 0, 1.45)),
              (f"Mid{c}", f"Hand{c}", (0.8 * x, 0, 1.45)), (f"Mid2{c}", f"Mid{c}", (0.85 * x, 0, 1.45)),
              (f"Thumb{c}", f"Hand{c}", (0.75 * x, -0.05, 1.45)),
              (f"Up{c}", "Hips", (0.1 * x, 0, 0.95)), (f"Leg{c}", f"Up{c}", (0.1 * x, -knees, 0.5)),
              (f"Foot{c}", f"Leg{c}", (0.1 * x, 0, 0.08))]
        if toes:
            s += [(f"Toe{c}", f"Foot{c}", (0.1 * x, -0.12, 0.02)), (f"ToeEnd{c}", f"Toe{c}", (0.1 * x, -0.2, 0.02))]
        if heel:
            s.append((f"Heel{c}", f"Foot{c}", (0.1 * x, 0.06, 0.0)))
    if root:
        s += [("ik_foot_root", "root", (0, 0, 0)), ("ik_foot_l", "ik_foot_root", (0.1, 0, 0.08)),
              ("ik_foot_r", "ik_foot_root", (-0.1, 0, 0.08))]
    return _tree(s)


RIG = {"hips": "Hips", "spine": "Spine", "chest": "Spine2", "neck": "Neck", "head": "Head"}
for _s, _c in (("left", "L"), ("right", "R")):
    RIG.update({f"{_s}_{r}": f"{n}{_c}" for r, n in (
        ("shoulder", "Sh"), ("upper_arm", "Arm"), ("lower_arm", "Fore"), ("hand", "Hand"),
        ("upper_leg", "Up"), ("lower_leg", "Leg"), ("foot", "Foot"), ("toe", "Toe"))})


@pytest.mark.parametrize("kw", [{}, {"root": True}, {"head_top": True}, {"heel": True}],
                         ids=["plain", "floor-root-and-ik", "head-top-marker", "heels"])
def test_other_rig_layouts(kw):
    clip = _rig(**kw)
    assert names(clip, auto_roles(clip)) == RIG


def test_front_from_knees_then_default():
    no_toe = {k: v for k, v in RIG.items() if not k.endswith("toe")}
    # no toes: the knees, flexed 3 cm forward (-Y), tell the front
    clip = _rig(toes=False, knees=0.03)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert names(clip, auto_roles(clip)) == no_toe
    # knees bent the other way: the character faces +Y, so its left is at -X
    clip = _rig(toes=False, knees=-0.03)
    assert names(clip, auto_roles(clip)) == swap_sides(no_toe)
    # nothing to tell: assume glTF's front (-Y), with a warning
    clip = _rig(toes=False)
    with pytest.warns(JiggleWarning, match="assuming -Y"):
        assert names(clip, auto_roles(clip)) == no_toe


def test_no_spine_and_not_a_body():
    # hips branching straight into legs, arms and neck: no spine or chest joint to name
    s = [("Hips", None, (0, 0, 1.0)), ("Neck", "Hips", (0, 0, 1.5)), ("Head", "Neck", (0, 0, 1.6))]
    for c, x in (("L", 1), ("R", -1)):
        s += [(f"Arm{c}", "Hips", (0.18 * x, 0, 1.45)), (f"Fore{c}", f"Arm{c}", (0.46 * x, 0, 1.45)),
              (f"Hand{c}", f"Fore{c}", (0.71 * x, 0, 1.45)), (f"Up{c}", "Hips", (0.1 * x, 0, 0.95)),
              (f"Leg{c}", f"Up{c}", (0.1 * x, 0, 0.5)), (f"Foot{c}", f"Leg{c}", (0.1 * x, 0, 0.08)),
              (f"Toe{c}", f"Foot{c}", (0.1 * x, -0.12, 0.02))]
    clip = _tree(s)
    got = names(clip, auto_roles(clip))
    assert "spine" not in got and "chest" not in got
    assert got["hips"] == "Hips" and got["neck"] == "Neck" and got["head"] == "Head"
    assert got["left_upper_arm"] == "ArmL" and got["right_foot"] == "FootR" and got["left_toe"] == "ToeL"
    # a lone chain is no body
    with pytest.raises(InputError, match="give a joint map"):
        auto_roles(_tree([("a", None, (0, 0, 1)), ("b", "a", (0, 0, 0.5)), ("c", "b", (0, 0, 0))]))


@pytest.mark.parametrize("preset", ["mixamo", "humanik", "unreal", "rigify", "vroid"])
def test_naming_schemes_are_found_by_themselves(preset):
    """A CMU skeleton renamed into a naming scheme people meet (Mixamo, HumanIK, Unreal's mannequin, Rigify's
    .L/.R, VRoid's VRM humanoid; each name the scheme's first spelling, every other joint a name of no
    scheme): resolve_roles finds that scheme's built-in map by itself and the same joints as the CMU map."""
    clip = load_clip(asset("mocap/cmu_bvh/02_03.bvh"))
    cmu = JointMap.load("cmu").resolve(clip.joint_names)
    scheme = JointMap.load(preset)
    names = [f"extra_{i}" for i in range(clip.num_joints)]
    for role, j in cmu.items():
        if role in scheme.roles:
            names[j] = scheme.roles[role][0]
    renamed = dataclasses.replace(clip, joint_names=tuple(names))
    roles = resolve_roles(renamed)
    assert roles == {r: j for r, j in cmu.items() if r in scheme.roles}
    assert len(roles) >= len(REQUIRED)



def _turn(axis, degrees: float) -> np.ndarray:
    """(3, 3) rotation by `degrees` about the unit `axis`."""
    return quat.to_matrix(quat.from_axis_angle(np.asarray(axis, float), np.radians(degrees)))


def _mixamo(foot_forward=0.3, arm_raise=60.0, prefix="mixamorig:", swap=False) -> Clip:
    """A Mixamo-named skeleton (fingers, head-top and toe-end markers as Mixamo exports them), facing -Y with its
    left at +X; its bind pose has the left foot `foot_forward` metres forward (the leg swung about the hip) and
    the right arm raised `arm_raise` degrees (about the front axis, at the shoulder joint). swap: the Left and
    Right names exchanged (the left limbs named Right)."""
    s = [("Hips", None, (0, 0, 1.0)), ("Spine", "Hips", (0, 0, 1.1)), ("Spine1", "Spine", (0, 0, 1.25)),
         ("Spine2", "Spine1", (0, 0, 1.4)), ("Neck", "Spine2", (0, 0, 1.5)), ("Head", "Neck", (0, 0, 1.6)),
         ("HeadTop_End", "Head", (0, 0, 1.78))]
    for side, x in (("Left", 1), ("Right", -1)):
        s += [(f"{side}Shoulder", "Spine2", (0.05 * x, 0, 1.45)),
              (f"{side}Arm", f"{side}Shoulder", (0.18 * x, 0, 1.45)),
              (f"{side}ForeArm", f"{side}Arm", (0.46 * x, 0, 1.45)),
              (f"{side}Hand", f"{side}ForeArm", (0.71 * x, 0, 1.45)),
              (f"{side}HandMiddle1", f"{side}Hand", (0.8 * x, 0, 1.45)),
              (f"{side}HandMiddle2", f"{side}HandMiddle1", (0.85 * x, 0, 1.45)),
              (f"{side}UpLeg", "Hips", (0.1 * x, 0, 0.95)),
              (f"{side}Leg", f"{side}UpLeg", (0.1 * x, -0.02, 0.5)),
              (f"{side}Foot", f"{side}Leg", (0.1 * x, 0, 0.08)),
              (f"{side}ToeBase", f"{side}Foot", (0.1 * x, -0.12, 0.02)),
              (f"{side}Toe_End", f"{side}ToeBase", (0.1 * x, -0.2, 0.02))]
    pos = {n: np.array(w, float) for n, _, w in s}
    hip = pos["LeftUpLeg"]
    swing = _turn((1, 0, 0), -np.degrees(np.arcsin(foot_forward / np.linalg.norm(pos["LeftFoot"] - hip))))
    for n in ("LeftLeg", "LeftFoot", "LeftToeBase", "LeftToe_End"):
        pos[n] = hip + swing @ (pos[n] - hip)
    shoulder = pos["RightArm"]
    raise_ = _turn((0, 1, 0), arm_raise)                           # +Y axis turns -X (the right arm) up
    for n in ("RightForeArm", "RightHand", "RightHandMiddle1", "RightHandMiddle2"):
        pos[n] = shoulder + raise_ @ (pos[n] - shoulder)
    other = {"Left": "Right", "Right": "Left"}

    def name(n):
        side = next((k for k in other if n.startswith(k)), None)
        return prefix + (other[side] + n[len(side):] if swap and side else n)
    return _tree([(name(n), name(p) if p else None, tuple(pos[n])) for n, p, _ in s])


def _no_names(clip: Clip) -> Clip:
    return dataclasses.replace(clip, joint_names=tuple(f"joint{i}" for i in range(clip.num_joints)))


def test_names_come_first_on_an_asymmetric_bind_pose():
    """Issue 43: a Mixamo export whose bind pose is not mirror-symmetric (left foot 0.3 m forward, right arm raised
    60 deg) keeps the Mixamo preset's joints (its names say left and right; the chains are in order): it was
    dropped by the mirror test, and the shape's map, shifted one joint along each arm, then refused. An explicit
    map is not refused for the pose either. The same skeleton without names goes the shape's way, where the
    mirror test stays."""
    clip = _mixamo()
    _, pos = clip.rest_world()
    i = clip.joint_names.index
    assert pos[i("mixamorig:LeftFoot"), 1] - pos[i("mixamorig:RightFoot"), 1] == pytest.approx(-0.3)
    assert pos[i("mixamorig:RightHand"), 2] > pos[i("mixamorig:RightArm"), 2] + 0.4
    expect = preset_names(clip, "mixamo")
    assert expect["left_upper_arm"] == "mixamorig:LeftArm" and expect["left_shoulder"] == "mixamorig:LeftShoulder"
    assert names(clip, resolve_roles(clip)) == expect
    assert names(clip, resolve_roles(clip, "mixamo")) == expect
    # without names: the shape's way. The raised hand is the highest point, so no head can be found...
    bare = _no_names(clip)
    with pytest.raises(InputError, match="from the skeleton's shape"):
        resolve_roles(bare)
    # ...and with the arm down the shape finds the limbs, but the foot forward does not mirror: refused
    foot = _no_names(_mixamo(arm_raise=0.0))
    assert names(foot, auto_roles(foot))["left_foot"] == "joint" + str(i("mixamorig:LeftFoot"))
    with pytest.raises(InputError, match="left_foot .* and right_foot .* do not mirror"):
        resolve_roles(foot)
    # a symmetric bind pose without names: the shape's map, the preset's joints
    still = _no_names(_mixamo(foot_forward=0.0, arm_raise=0.0))
    assert resolve_roles(still) == auto_roles(still) == JointMap.load("mixamo").resolve(clip.joint_names)


def test_names_with_left_and_right_swapped_are_refused():
    """A name map whose left leg stands clearly on the character's right (the toes say where the front is) is
    refused, so the preset is passed over and the shape gives the sides; a map that is only asymmetric is not."""
    clip = _mixamo(foot_forward=0.0, arm_raise=0.0, swap=True)
    roles = JointMap.load("mixamo").resolve(clip.joint_names)
    with pytest.raises(InputError, match="left and right are swapped"):
        check_roles(clip, roles, mirror=False)
    got = names(clip, resolve_roles(clip))
    assert got["left_upper_leg"] == "mixamorig:RightUpLeg" and got["left_upper_arm"] == "mixamorig:RightArm"
    check_roles(_mixamo(), JointMap.load("mixamo").resolve(_mixamo().joint_names), mirror=False)
