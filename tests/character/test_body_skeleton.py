"""The skeleton a character's body plan and roles are read from (rig/character/body_skeleton.py): helper bones
off a weightless root set aside, IK-placed feet hung under their legs, bone tips from the skin when the joints
alone give no body plan; and nothing changed for a skeleton that already reads as a body."""
from __future__ import annotations

import warnings
from types import SimpleNamespace

import numpy as np
import pytest
from conftest import asset

from jiggle.rig.base.errors import JiggleWarning
from jiggle.rig.character.body_skeleton import body_skeleton, original_parents
from jiggle.rig.motion import quat
from jiggle.rig.motion.body_plan import detect_body_plan, quadruped_roles
from jiggle.rig.motion.clip import Clip
from jiggle.rig.motion.role_map import resolve_roles


def test_ik_helper_bones_are_set_aside_to_read_the_body():
    """RobotExpressive (CC0): its feet and knee poles hang off a weightless root bone beside the body, as game
    rigs' IK targets do. Read as it is: one limb on the ground, no legs. The body's skeleton
    (rig.character.body_skeleton: weightless helpers set aside, the IK-placed feet hung under their lower legs)
    is a biped, with its own built-in map; CesiumMan's has no helpers and is read as it is."""
    from jiggle.rig.character.gltf_character import read_gltf_character
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", JiggleWarning)
        robot = read_gltf_character(asset("characters/RobotExpressive.glb"))
        man = read_gltf_character(asset("characters/CesiumMan.glb"))
    assert detect_body_plan(robot.skeleton).kind == "other"
    body, order = body_skeleton(robot)
    plan = detect_body_plan(body)
    assert plan.kind == "biped" and plan.ground_limbs == 2, plan.reason
    names = robot.joint_names
    parents = original_parents(body, order)
    for s in "LR":
        assert names[parents[names.index(f"Foot.{s}")]] == f"LowerLeg.{s}"     # the foot under its leg
        assert parents[names.index(f"PoleTarget.{s}")] == -1                    # the pole set aside
    roles = {r: names[order[j]] for r, j in resolve_roles(body).items()}
    assert roles["left_foot"] == "Foot.L" and roles["left_lower_leg"] == "LowerLeg.L"
    assert roles["left_upper_arm"] == "UpperArm.L" and roles["hips"] == "Body"
    same, identity = body_skeleton(man)
    assert same is man.skeleton and np.array_equal(identity, np.arange(man.num_joints))


def stick(names, parents, world) -> Clip:
    """A one-frame clip of joints at world positions (Z-up metres), every rotation the identity."""
    world = np.asarray(world, float)
    parents = np.asarray(parents)
    off = np.array([world[j] - (world[p] if p >= 0 else 0.0) for j, p in enumerate(parents)])
    rot = quat.identity((len(names),))
    return Clip(joint_names=names, parents=parents, offsets=off, rest_rotations=rot, rotations=rot[None],
                translations=off[None], fps=30.0, name="fox-like")


def test_paws_and_a_tail_from_the_skin_make_a_quadruped():
    """A fox-like rig (as the glTF Fox sample is built): hind legs that end at a toe joint on the ground, front legs
    named as arms that end at the wrist a fifth of the height up, a three-joint tail. The joints give two legs on
    the ground and a flat spine: no plan. With the bones' tips where the skin each last joint moves reaches (the
    paws down to the ground), it is a quadruped with a tail, and the quadruped roles find its legs."""
    names = ["hip", "spine", "chest", "neck", "head", "tail1", "tail2", "tail3",
             "l_upperarm", "l_forearm", "l_hand", "r_upperarm", "r_forearm", "r_hand",
             "l_leg1", "l_leg2", "l_foot1", "l_foot2", "r_leg1", "r_leg2", "r_foot1", "r_foot2"]
    P = {n: i for i, n in enumerate(names)}
    parents = [-1, 0, 1, 2, 3, 0, 5, 6, 2, 8, 9, 2, 11, 12, 0, 14, 15, 16, 0, 18, 19, 20]
    y0, y1 = 0.0, -0.45                               # hips at the back (y 0), chest at the front (y -0.45)
    world = [(0, y0, 0.55), (0, -0.2, 0.57), (0, y1, 0.58), (0, -0.55, 0.68), (0, -0.62, 0.78),
             (0, 0.12, 0.55), (0, 0.25, 0.50), (0, 0.37, 0.45),
             (0.07, y1, 0.50), (0.07, y1 + 0.02, 0.33), (0.07, y1, 0.16),
             (-0.07, y1, 0.50), (-0.07, y1 + 0.02, 0.33), (-0.07, y1, 0.16),
             (0.07, y0, 0.50), (0.07, 0.05, 0.32), (0.07, 0.0, 0.14), (0.07, -0.03, 0.02),
             (-0.07, y0, 0.50), (-0.07, 0.05, 0.32), (-0.07, 0.0, 0.14), (-0.07, -0.03, 0.02)]
    clip = stick(names, parents, world)
    assert detect_body_plan(clip).kind == "other"
    # the skin: a few vertices around each joint, the front paws' down to the ground in front of the wrist
    verts, owner = [], []
    rng = np.random.default_rng(0)
    for j, w in enumerate(world):
        for _ in range(6):
            verts.append(np.asarray(w) + rng.normal(0, 0.01, 3))
            owner.append(j)
    for hand in ("l_hand", "r_hand"):
        x, y, _ = world[P[hand]]
        verts += [(x, y - 0.06, 0.0), (x, y - 0.03, 0.05)]
        owner += [P[hand]] * 2
    verts += [(0, 0.5, 0.40)]                          # the tail's tip
    owner += [P["tail3"]]
    V = len(verts)
    character = SimpleNamespace(skeleton=clip, num_joints=len(names), vertices=np.array(verts),
                                joints=np.array(owner)[:, None], weights=np.ones((V, 1)))
    body, order = body_skeleton(character)
    plan = detect_body_plan(body)
    assert plan.kind == "quadruped" and plan.tail, plan.reason
    assert np.array_equal(order, np.arange(len(names)))          # the same joints: only bone tips were added
    roles = {r: names[j] for r, j in quadruped_roles(body).items()}
    assert roles["hips"] == "hip" and roles["chest"] == "chest" and roles["tail"] == "tail1"
    assert {roles["left_front_foot"], roles["right_front_foot"]} == {"l_hand", "r_hand"}
    assert {roles["left_hind_upper_leg"], roles["right_hind_upper_leg"]} == {"l_leg1", "r_leg1"}


@pytest.mark.slow
def test_robot_expressive_bakes_its_own_animation_with_no_flags(tmp_path):
    """`jiggle bake --character RobotExpressive.glb`: its body plan read from the body, the human template fitted,
    its own first animation baked (no --template, no map), every cache value finite."""
    import json

    from jiggle.sim.app.cli import main
    from jiggle.sim.bake.caches import read_npz
    out = tmp_path / "robot"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", JiggleWarning)
        assert main(["-q", "bake", "--character", str(asset("characters/RobotExpressive.glb")), "--out", str(out),
                     "--frames", "30", "--formats", "npz"]) == 0
    summary = json.loads((out / "bake.json").read_text())
    assert summary["params"]["template"] == "human" and summary["muscles"] >= 15
    d = read_npz(out / "bake.npz")
    assert np.isfinite(d.skin_final).all() and np.abs(d.skin_final - d.skin_static).max() > 1e-4


def test_ik_targets_of_a_game_quadruped_are_set_aside():
    """A game-asset quadruped (as an `AnimalArmature` is built): a weightless root holding the body and, beside it,
    IK targets for the four paws and pole targets, all without skin weight and the paw targets on the ground.
    Read as it is, six limbs reach the ground and they meet at the root; with the helpers set aside the body is
    a quadruped and its own paws carry the legs."""
    names = ["Root", "Body", "Spine", "Chest", "Neck", "Head",
             "FL1", "FL2", "FL3", "FR1", "FR2", "FR3", "HL1", "HL2", "HL3", "HR1", "HR2", "HR3",
             "IKFrontLeg.L", "IKFrontLeg.R", "IKBackLeg.L", "IKBackLeg.R", "PoleTarget.L", "PoleTarget.R"]
    parents = [-1, 0, 1, 2, 3, 4, 3, 6, 7, 3, 9, 10, 1, 12, 13, 1, 15, 16, 0, 0, 0, 0, 0, 0]
    world = [(0, 0, 0), (0, 0.0, 0.55), (0, -0.2, 0.57), (0, -0.45, 0.58), (0, -0.55, 0.7), (0, -0.62, 0.8),
             (0.08, -0.45, 0.5), (0.08, -0.45, 0.28), (0.08, -0.46, 0.02),
             (-0.08, -0.45, 0.5), (-0.08, -0.45, 0.28), (-0.08, -0.46, 0.02),
             (0.08, 0.0, 0.5), (0.08, 0.03, 0.28), (0.08, 0.0, 0.02),
             (-0.08, 0.0, 0.5), (-0.08, 0.03, 0.28), (-0.08, 0.0, 0.02),
             (0.08, -0.46, 0.0), (-0.08, -0.46, 0.0), (0.08, 0.0, 0.0), (-0.08, 0.0, 0.0),
             (0.08, -1.0, 0.3), (-0.08, -1.0, 0.3)]
    clip = stick(names, parents, world)
    assert detect_body_plan(clip).kind != "quadruped"
    weighted = range(1, 18)                                         # the body's joints carry the skin
    verts = np.array([world[j] for j in weighted for _ in range(3)]) + np.random.default_rng(1).normal(0, 0.005, (51, 3))
    owner = np.repeat(np.array(list(weighted)), 3)
    character = SimpleNamespace(skeleton=clip, num_joints=len(names), vertices=verts, joints=owner[:, None],
                                weights=np.ones((len(owner), 1)))
    body, order = body_skeleton(character)
    plan = detect_body_plan(body)
    assert plan.kind == "quadruped", plan.reason
    parents_back = original_parents(body, order)
    for helper in ("IKFrontLeg.L", "IKBackLeg.R", "PoleTarget.L"):
        assert parents_back[names.index(helper)] == -1
    roles = {r: names[order[j]] for r, j in quadruped_roles(body).items()}
    assert roles["hips"] == "Body" and roles["chest"] == "Chest"
    assert {roles["left_front_foot"], roles["right_front_foot"]} <= {"FL3", "FR3"}


@pytest.mark.slow
def test_a_clip_retargeted_onto_an_ik_rig_carries_its_feet():
    """A CMU walk retargeted onto RobotExpressive moves its legs; its feet hang off the root as IK targets, which
    the walk does not move. The bake hangs them under the lower legs (rig.character.body_skeleton.hang): in every
    frame each foot keeps its bind-pose place relative to its lower leg, and a foot goes where its leg goes."""
    from jiggle.sim.bake.setup import BakeRequest, prepare
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", JiggleWarning)
        setup = prepare(BakeRequest(clip=str(asset("mocap/cmu_bvh/02_03.bvh")),
                                    character=str(asset("characters/RobotExpressive.glb")), frames=40,
                                    formats=("npz",)), log=lambda s: None)
    names = setup.character.joint_names
    world = np.asarray(setup.world_at(setup.times))
    bind = setup.character.bind_world
    for s in "LR":
        leg, foot = names.index(f"LowerLeg.{s}"), names.index(f"Foot.{s}")
        rel = np.linalg.inv(bind[leg]) @ bind[foot]
        np.testing.assert_allclose(world[:, foot], world[:, leg] @ rel, atol=1e-6)
        assert np.ptp(world[:, foot, :3, 3], axis=0).max() > 0.1      # the feet walk
