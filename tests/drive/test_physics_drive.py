"""Physics drive: MuJoCo follows a clip on a floor (sim/drive/physics_drive.py)."""
from __future__ import annotations

import json
import time

import numpy as np
import pytest
from conftest import CMU_BVH, asset

from jiggle.rig.base.errors import InputError
from jiggle.rig.motion import quat
from jiggle.rig.motion.bone_roles import bone_roles
from jiggle.rig.motion.bvh import read_bvh
from jiggle.rig.motion.clip import Clip
from jiggle.sim.drive.physics_drive import (
    GRAVITY,
    PhysicsDivergedError,
    PhysicsDrive,
    PhysicsResult,
    estimate_floor,
    find_feet,
)
from jiggle.sim.drive.skeleton import BodyShape, Skeleton

# A two-bone leg standing still: hip (root) -> knee -> ankle, a flat foot bone to a toe end site.
# The hip sits 8 cm ahead of the ankle so that the centre of mass (~5 cm ahead) lies between the
# foot capsule's heel and toe contacts (3.4 and 11.6 cm ahead): the leg stands without help.
HIP = np.array([0.0, 0.08, 0.9])
KNEE = np.array([0.0, -0.04, -0.45])
ANKLE = np.array([0.0, -0.04, -0.4])
TOE = np.array([0.0, 0.15, 0.0])


def standing_leg(seconds: float = 1.0, fps: float = 30.0) -> Clip:
    T = int(round(seconds * fps)) + 1
    offsets = np.array([HIP, KNEE, ANKLE])
    return Clip(joint_names=("hip", "knee", "ankle"), parents=np.array([-1, 0, 1]), offsets=offsets,
                rest_rotations=quat.identity((3,)), rotations=quat.identity((T, 3)),
                translations=np.broadcast_to(offsets, (T, 3, 3)), fps=fps,
                end_parents=np.array([2]), end_offsets=TOE[None], name="standing_leg")


def test_feet_and_floor_of_a_standing_leg():
    clip = standing_leg()
    assert find_feet(clip) == [2]
    r = BodyShape().radius_ratio * np.linalg.norm(TOE)
    r = float(np.clip(r, BodyShape().min_radius, BodyShape().max_radius))
    # a flat foot capsule: its lowest point is the ankle's height minus its radius
    ankle_z = (HIP + KNEE + ANKLE)[2]
    assert estimate_floor(clip) == pytest.approx(ankle_z - r, abs=1e-9)


def test_rest_stays_at_rest_and_the_floor_carries_the_weight():
    clip = standing_leg(seconds=1.0)
    drive = PhysicsDrive(clip)
    res = drive.run()
    weight = drive.total_mass * GRAVITY
    # Settling: a weld at impedance d gives way by (1 - d)/d * a0 / k under a load that would
    # accelerate it by a0 alone; for a joint here 1e-4 * ~5e3 rad/s^2 / (1 / 0.02^2 = 2.5e3 /s^2)
    # ~ 2e-4 rad, three joints over 0.85 m of leg ~ 0.5 mm (measured 0.55 mm, the hip leaning back).
    # The contact sinks by the same law, 1e-4 * a0 / (1 / 0.005^2) (measured 0.07 mm).
    assert np.max(res.joint_error) < 1e-3
    assert res.max_penetration < 2e-4
    # Rest stays at rest: settled after ~5 time constants of the root servo (5 * 55 ms), nothing
    # drifts over the remaining 0.75 s (measured 20 um) or moves.
    settled = np.searchsorted(res.times, 0.25)
    assert np.max(np.linalg.norm(res.positions[settled:] - res.positions[settled], axis=-1)) < 5e-5
    assert np.max(np.abs(drive.data.qvel)) < 1e-3
    # Statics: m g = F_floor + F_servo. The servo's share is m kp * sag, sag = the 0.09 mm the ankle
    # sank, over m g: 0.09 mm / (g tau^2 = 30 mm) = 0.3 %: the floor carries the weight within 1 %
    # at every frame of the last half second (measured 0.998).
    late = res.times >= 0.5
    total = res.foot_force[late].sum(axis=1)
    assert np.all(np.abs(total - weight) < 0.01 * weight), (total.min() / weight, total.max() / weight)
    assert np.all(np.abs(res.root_assist_force[late, 2]) < 0.01 * weight)
    assert np.all(res.foot_contact_count[late] >= 1)
    pts = res.foot_contact_points[-1, 0, :res.foot_contact_count[-1, 0]]
    assert np.allclose(pts[:, 2], res.floor_height, atol=1e-3)  # contact points lie on the floor


def test_step_api_matches_run():
    clip = standing_leg(seconds=0.2)
    drive = PhysicsDrive(clip)
    res = drive.run()
    drive.reset(0.0)
    substeps = sum(drive.advance(t) for t in clip.times)
    rot, pos = drive.pose()
    assert substeps == 20 * (clip.num_frames - 1)  # 1/30 s in equal steps of at most 1/600 s
    assert np.allclose(pos, res.positions[-1], atol=1e-12)
    assert np.allclose(rot, res.rotations[-1], atol=1e-12)
    force, assist, lowest = drive.take_interval()
    assert force.shape == (1,) and assist.shape == (3,) and lowest.shape == (1,)


def test_divergence_names_the_time():
    drive = PhysicsDrive(standing_leg(seconds=0.2))
    drive.model.opt.gravity[2] = -1e8  # no body survives this
    with pytest.raises(PhysicsDivergedError, match=r"diverged at t = 0\.00"):
        drive.run()


def test_bad_input_is_an_input_error():
    clip = standing_leg(seconds=0.2)
    with pytest.raises(InputError, match="no joint named"):
        PhysicsDrive(clip, feet=["heel"])
    with pytest.raises(InputError, match="floor height"):
        PhysicsDrive(clip, floor_height=float("nan"))
    with pytest.raises(InputError, match="timestep"):
        PhysicsDrive(clip, max_timestep=0.0)
    with pytest.raises(InputError, match="must not decrease"):
        PhysicsDrive(clip).run(times=[0.1, 0.0])


@pytest.mark.parametrize("name", CMU_BVH)
def test_cmu_bodies_weigh_like_adults(name):
    clip = read_bvh(asset(f"mocap/cmu_bvh/{name}.bvh"))
    skel = Skeleton(clip)
    assert 55.0 <= skel.total_mass <= 85.0
    assert any("trunk" in r for r in bone_roles(clip)) and any("head" in r for r in bone_roles(clip))
    _, pos = clip.world()
    assert np.max(np.abs(skel.world()[1] - pos)) < 1e-9


def test_run_09_11_tracks_stands_and_carries_the_body():
    clip = read_bvh(asset("mocap/cmu_bvh/09_11.bvh"))
    built = time.perf_counter()
    drive = PhysicsDrive(clip)
    built = time.perf_counter() - built
    res = drive.run()
    assert isinstance(res, PhysicsResult)
    N, J = clip.num_frames, clip.num_joints
    assert res.rotations.shape == (N, J, 4) and res.positions.shape == (N, J, 3)
    assert res.foot_joints == ("LeftFoot", "RightFoot")
    assert not res.positions.flags.writeable
    weight = res.weight
    total = res.foot_force.sum(axis=1)
    print(f"\n09_11: mass {res.total_mass:.1f} kg, floor {res.floor_height * 1000:.1f} mm, "
          f"RMS error {res.rms_error * 100:.2f} cm (max {res.joint_error.max() * 100:.1f} cm), "
          f"max penetration {res.max_penetration * 1000:.1f} mm, "
          f"mean foot force / weight {res.mean_foot_force_ratio:.3f}, "
          f"mean servo z force / weight {res.root_assist_force[:, 2].mean() / weight:.3f}, "
          f"simulated {res.wall_time:.2f} s (+{built:.2f} s build) for {clip.duration:.2f} s of clip")
    assert res.rms_error < 0.05
    assert res.max_penetration < 0.01  # from geom positions at every physics step
    # A run: each foot lands (force > 1.5 body weights at some frame of its stance), both feet are
    # off the floor together for a while (flight), and over the clip the feet carry the body:
    # measured 0.875, the root servo 0.14 of the weight, together 1.02.
    assert np.all(res.foot_force.max(axis=0) > 1.5 * weight)
    assert np.any(total == 0.0)
    assert 0.75 < res.mean_foot_force_ratio < 1.25
    summary = json.loads(json.dumps(res.summary()))  # plain values for summary.json
    assert summary["rms_joint_error_m"] == pytest.approx(res.rms_error, abs=1e-5)
    assert summary["mean_foot_force_over_weight"] == pytest.approx(res.mean_foot_force_ratio, abs=1e-4)
    # no force from a foot that stayed more than 2 cm above the floor over a whole interval
    assert np.all(res.foot_force[res.foot_lowest > 0.02] == 0.0)
    touching = res.foot_contact_count > 0
    assert np.all(np.isfinite(res.foot_contact_points[touching][:, 0]))
