"""Retargeting CMU mocap onto CesiumMan: bone directions, feet on the floor, MuJoCo agreement, maps."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from conftest import asset

from jiggle.rig.base.errors import InputError
from jiggle.rig.motion import quat
from jiggle.rig.motion.bvh import read_bvh
from jiggle.rig.motion.gltf_anim import read_gltf_animation
from jiggle.rig.motion.gltf_skeleton import read_gltf_skeleton
from jiggle.rig.motion.retarget import REQUIRED, JointMap, bone_pairs, foot_clearance, presets, retarget
from jiggle.sim.drive.skeleton import Skeleton

SIDES = ("left", "right")


@pytest.fixture(scope="module")
def run():
    clip = read_bvh(asset("mocap/cmu_bvh/02_03.bvh"))
    character = read_gltf_skeleton(asset("characters/CesiumMan.glb"))
    cmap, kmap = JointMap.load("cmu"), JointMap.load("cesiumman")
    return clip, character, cmap, kmap, retarget(clip, cmap, character, kmap)


def _angles(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    cos = np.sum(a * b, -1) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1))
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def test_limb_directions_follow_the_clip(run):
    clip, character, cmap, kmap, out = run
    mc, mk = cmap.resolve(clip.joint_names), kmap.resolve(character.joint_names)
    pairs = bone_pairs(set(mc) & set(mk))
    # Every limb the brief names (upper/lower arm and leg), both sides, plus foot -> toe.
    assert len(pairs) == 10
    _, cp = clip.world()
    _, kp = out.world()
    worst = {}
    for a, b in pairs:
        ang = _angles(kp[:, mk[b]] - kp[:, mk[a]], cp[:, mc[b]] - cp[:, mc[a]])
        worst[a] = float(ang.max())
    # Required: within 20 degrees on every frame. Each of these bones ends at the direct child of the
    # role's joint in both skeletons, so the method makes them parallel up to rounding (measured
    # max ~2e-6 degrees); 1e-3 degrees leaves room for rounding only.
    assert max(worst.values()) < 1e-3, worst
    # The torso follows too, though not exactly: clip joints between two roles (CMU Spine, Neck1)
    # bend that segment in ways a single character bone cannot (measured max ~6 and ~9 degrees).
    for a, b in (("hips", "chest"), ("neck", "head")):
        assert _angles(kp[:, mk[b]] - kp[:, mk[a]], cp[:, mc[b]] - cp[:, mc[a]]).max() < 15.0


def test_feet_stay_on_the_floor(run):
    clip, character, cmap, kmap, out = run
    fc = foot_clearance(out, character, kmap)  # (T, 2) metres above bind-pose height
    lowest, per_frame = float(fc.min()), fc.min(axis=1)
    # The clip's own clearance (lowest foot/toe joint above its T-pose height, floor at its minimum).
    mc = cmap.resolve(clip.joint_names)
    _, cp = clip.world()
    _, rest = clip.rest_world()
    feet = {s: [mc[f"{s}_foot"], mc[f"{s}_toe"]] for s in SIDES}
    base = rest[feet["left"] + feet["right"], 2].min()
    cc = np.stack([np.min(cp[:, feet[s], 2] - (rest[feet[s], 2] - base), axis=1) for s in SIDES], axis=1)
    cc -= cc.min()
    # Measured on 02_03 (a jog): lowest foot over the clip -5.2 mm (the 2 cm soft minimum lets the
    # feet dip a little while both are low), per-frame minimum between -5.2 mm and 79 mm.
    assert -0.01 < lowest < 0.005
    assert per_frame.max() < 0.12  # a jog has flight phases, but the hips never leave the feet far behind
    for i, s in enumerate(SIDES):
        toe = cp[:, mc[f"{s}_toe"], :2]
        speed = np.linalg.norm(np.gradient(toe, axis=0) * clip.fps, axis=1)
        planted = (cc[:, i] < 0.02) & (speed < 0.5)  # clip foot within 2 cm of its floor, toe not sliding
        assert planted.sum() >= 10, f"{s}: the jog plants each foot for several frames"
        # Planted in the clip -> within 2 cm of the character's floor (measured max 14 mm), and the
        # character's clearance is the clip's scaled by the hip-height ratio (measured within 0.1 mm).
        assert np.all(np.abs(fc[planted, i]) < 0.02), (s, fc[planted, i])
        np.testing.assert_allclose(fc[planted, i], out.meta["scale"] * cc[planted, i], atol=2e-3)
    # A constant shift instead leaves the planted feet up to ~5 cm off (leg proportions differ), which is
    # why per-frame contact is the default; its lowest clearance is exactly on the floor.
    const = retarget(clip, cmap, character, kmap, contact="constant")
    assert foot_clearance(const, character, kmap).min() == pytest.approx(0.0, abs=1e-9)


def test_output_is_a_clip_on_the_character(run):
    clip, character, cmap, kmap, out = run
    assert out.joint_names == character.joint_names
    np.testing.assert_array_equal(out.parents, character.parents)
    np.testing.assert_allclose(out.offsets, character.bind_translations)
    assert out.num_frames == clip.num_frames and out.fps == clip.fps
    # Only the root translates; every bone keeps the character's bind length.
    assert list(np.nonzero(out.animated_translation)[0]) == [0]
    # Root path scaled by the hip-height ratio (CesiumMan 0.66 m / CMU subject 2 0.92 m).
    s = out.meta["scale"]
    assert s == pytest.approx(0.713, abs=0.005)
    _, cp = clip.world()
    _, kp = out.world()
    np.testing.assert_allclose(kp[:, 0, :2] - kp[0, 0, :2], s * (cp[:, 0, :2] - cp[0, 0, :2]), atol=1e-12)


def test_mujoco_skeleton_matches_clip_world(run):
    *_, out = run
    sk = Skeleton(out)
    rot, pos = sk.world()
    wr, wp = out.world()
    err = np.abs(pos - wp).max()
    assert err < 1e-5, err  # measured 8e-10 m
    assert np.degrees(quat.angle(quat.mul(quat.conj(wr), rot))).max() < 1e-3


def test_character_onto_itself_reproduces_its_own_motion():
    path = asset("characters/CesiumMan.glb")
    walk = read_gltf_animation(path)
    character = read_gltf_skeleton(path)
    kmap = JointMap.load("cesiumman")
    out = retarget(walk, kmap, character, kmap)
    # All 19 joints are mapped and CesiumMan's rest pose is its bind pose, so every world rotation is
    # the walk's own (bind and rest differ by float32 rounding, ~2e-5 degrees).
    wr, wp = walk.world()
    kr, kp = out.world()
    assert np.degrees(quat.angle(quat.mul(quat.conj(wr), kr))).max() < 1e-3
    assert out.meta["scale"] == pytest.approx(1.0, abs=1e-5)
    np.testing.assert_allclose(kp[:, 0, :2] - kp[0, 0, :2], wp[:, 0, :2] - wp[0, 0, :2], atol=1e-6)


def test_the_characters_own_skeleton_needs_no_map():
    """A clip of the character's own skeleton (here its own animation) is taken as it is, with no map
    and no retargeting: the same joints, the same local motion; a clip of another skeleton
    still goes through the maps."""
    from jiggle.rig.motion.retarget import same_skeleton
    from jiggle.rig.motion.retarget_onto import retarget_onto
    path = asset("characters/CesiumMan.glb")
    walk = read_gltf_animation(path)
    said = []
    out = retarget_onto(walk, path, log=said.append)
    assert "no retargeting" in said[0] and out.meta["retarget"].startswith("identity")
    assert out.joint_names == read_gltf_skeleton(path).joint_names
    np.testing.assert_allclose(out.rotations, walk.rotations, atol=1e-12)       # renormalised: last bits
    np.testing.assert_array_equal(out.translations, walk.translations)
    run = read_bvh(asset("mocap/cmu_bvh/02_03.bvh"))
    assert same_skeleton(run, read_gltf_skeleton(path)) is None


def test_a_skeleton_no_preset_fits_is_mapped_by_its_shape():
    """RiggedFigure's joint names match no preset: its roles are found from its shape and the CMU run
    lands on it with the feet on its floor and the thighs following the clip's."""
    from jiggle.rig.motion.retarget_onto import joint_map_for, retarget_onto
    path = str(asset("characters/RiggedFigure.glb"))
    character = read_gltf_skeleton(path)
    said = []
    jm = joint_map_for(None, character.to_clip(), "--character-map", path)
    assert jm.name == "found from the shape" and {"hips", "left_upper_leg", "right_foot"} <= set(jm.roles)
    run = read_bvh(asset("mocap/cmu_bvh/02_03.bvh"))
    out = retarget_onto(run, path, log=said.append)
    assert "found from the shape" in said[0]
    _, pos = out.world()
    feet = [character.joint_names.index(jm.roles[f"{s}_foot"][0]) for s in ("left", "right")]
    low = pos[:, feet, 2].min(axis=1)  # the lower ankle per frame
    rest = character.bind_positions[feet, 2].min()
    assert np.abs(low - rest).min() < 0.02 and low.max() < rest + 0.3 * np.ptp(character.bind_positions[:, 2])


def test_turning_the_clip_turns_the_character(run):
    clip, character, cmap, kmap, out = run
    yaw = quat.from_axis_angle(np.array([0.0, 0.0, 1.0]), np.radians(90.0))
    rot = clip.rotations.copy()
    tra = clip.translations.copy()
    rot[:, 0] = quat.mul(yaw, rot[:, 0])
    tra[:, 0] = quat.rotate(yaw, tra[:, 0])
    turned = retarget(dataclasses.replace(clip, rotations=rot, translations=tra), cmap, character, kmap)
    r0, p0 = out.world()
    r1, p1 = turned.world()
    np.testing.assert_allclose(quat.to_matrix(r1), quat.to_matrix(quat.mul(yaw, r0)), atol=1e-9)
    # Positions relative to the hips turn with it; the path starts at the character's bind spot.
    np.testing.assert_allclose(p1 - p1[:, :1], quat.rotate(yaw, p0 - p0[:, :1]), atol=1e-9)


def test_cmu_preset_covers_bvh_and_asf_names():
    from jiggle.rig.motion.acclaim import read_asf

    assert {"cmu", "cesiumman"} <= set(presets())
    cmap = JointMap.load("cmu")
    bvh = read_bvh(asset("mocap/cmu_bvh/02_03.bvh"))
    asf = read_asf(asset("mocap/cmu_amc/01.asf")).rest_clip()
    mb, ma = cmap.resolve(bvh.joint_names), cmap.resolve(asf.joint_names)
    assert set(mb) == set(ma) == set(cmap.roles)
    assert asf.joint_names[ma["left_upper_leg"]] == "lfemur" and bvh.joint_names[mb["left_upper_leg"]] == "LeftUpLeg"
    # The same roles sit at matching places: the left hand is the wrist, ~0.19 m past the elbow in both.
    for c, m in ((bvh, mb), (asf, ma)):
        _, p = c.rest_world()
        assert 0.15 < np.linalg.norm(p[m["left_hand"]] - p[m["left_lower_arm"]]) < 0.25


def test_bad_maps_name_the_file_and_key(tmp_path, run):
    clip, character, cmap, kmap, _ = run
    good = open(kmap.source).read()
    p = tmp_path / "typo.toml"
    p.write_text(good.replace('left_foot = "leg_joint_L_3"', 'left_foot = "leg_joint_L_33"'))
    with pytest.raises(InputError, match="'leg_joint_L_33' is not in the skeleton") as e:
        retarget(clip, cmap, character, JointMap.load(p))
    assert e.value.path == str(p) and e.value.field == "joints.left_foot"
    p.write_text(good.replace('left_hand = "Skeleton_arm_joint_L__2_"\n', ""))
    with pytest.raises(InputError, match="required role.*left_hand") as e:
        JointMap.load(p)
    assert e.value.path == str(p) and e.value.field == "joints.left_hand"
    p.write_text(good + 'left_tail = "x"\n')
    with pytest.raises(InputError, match="unknown role 'left_tail'") as e:
        JointMap.load(p)
    assert e.value.field == "joints.left_tail"
    p.write_text(good.replace('hips = "Skeleton_torso_joint_1"', "hips = 3"))
    with pytest.raises(InputError, match="joint name") as e:
        JointMap.load(p)
    assert e.value.field == "joints.hips"
    p.write_text("[joints\nhips = 'x'\n")
    with pytest.raises(InputError, match="not valid TOML") as e:
        JointMap.load(p)
    assert e.value.path == str(p)
    p.write_text(good.replace('spine = "Skeleton_torso_joint_2"', 'spine = "Skeleton_torso_joint_1"'))
    with pytest.raises(InputError, match="mapped to both 'hips' and 'spine'"):
        JointMap.load(p).resolve(character.joint_names)
    with pytest.raises(InputError, match="no joint map preset named 'mixamorig'.*cesiumman, cmu, humanik, mixamo"):
        JointMap.load("mixamorig")
    with pytest.raises(InputError, match="not found"):
        JointMap.load(tmp_path / "absent.toml")
    assert set(REQUIRED) <= set(cmap.roles)
