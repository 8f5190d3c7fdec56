"""MuJoCo drives the skeleton: mj_kinematics world positions against an independent NumPy FK."""
import bvh_reference as ref
import numpy as np
import pytest
from bvh_reference import write_odd_bvh
from conftest import CMU_BVH, asset

from jiggle.rig.motion import quat
from jiggle.rig.motion.bvh import CMU_UNIT, read_bvh
from jiggle.rig.motion.clip import transforms
from jiggle.sim.drive.skeleton import Skeleton


@pytest.mark.slow
@pytest.mark.parametrize("name", CMU_BVH)
def test_mujoco_world_positions_equal_independent_fk_on_every_frame(name):
    path = asset(f"mocap/cmu_bvh/{name}.bvh")
    clip = read_bvh(path)
    joints, _, frames, _ = ref.parse(path.read_text())
    want = ref.to_zup_metres(ref.world_positions(joints, frames[1:]), CMU_UNIT)  # frame 1 is the T-pose
    rot, pos = Skeleton(clip).world()
    assert pos.shape == want.shape
    err = np.abs(pos - want).max()
    print(f"{name}: {clip.num_frames} frames, max |MuJoCo - reference| = {err:.2e} m")
    assert err < 1e-5
    # the world rotations carry the bones: each child sits at parent + R_parent * offset
    child = np.array([j for j in range(clip.num_joints) if clip.parents[j] >= 0])
    par = clip.parents[child]
    np.testing.assert_allclose(pos[:, child], pos[:, par] + quat.rotate(rot[:, par], clip.offsets[child]), atol=1e-9)


def test_animated_non_root_translation_uses_slide_joints(tmp_path):
    clip = read_bvh(write_odd_bvh(tmp_path / "odd.bvh"), scale=0.01, tpose="keep")
    sk = Skeleton(clip)
    kinds = set(int(t) for t in sk.model.jnt_type)
    assert kinds == {0, 1, 2}  # free, ball, slide
    _, pos = sk.world()
    _, want = clip.world()
    np.testing.assert_allclose(pos, want, atol=1e-9)


def test_substeps_interpolate_the_clip_not_hold_frames():
    clip = read_bvh(asset("mocap/cmu_bvh/09_11.bvh"))
    sk = Skeleton(clip)
    t = (np.arange(40) + 0.5) / clip.fps  # half-way between frames, as substeps land
    _, mid = sk.world(t)
    _, frames = sk.world()
    # not held: the mid-step pose differs from both neighbours where the body moves
    moving = np.linalg.norm(frames[1:41] - frames[:40], axis=-1).max() > 1e-3
    assert moving and np.abs(mid - frames[:40]).max() > 1e-3
    # interpolated: equals FK of the slerped/lerped local transforms (NumPy path)
    rot, tra = clip.sample(t)
    _, want = clip.world(rot, tra)
    np.testing.assert_allclose(mid, want, atol=1e-9)
    # and lies close to the mean of its neighbouring frames (smooth motion, 120 fps)
    assert np.abs(mid - 0.5 * (frames[:40] + frames[1:41])).max() < 5e-3


def test_body_mass_is_plausible_for_an_adult():
    sk = Skeleton(read_bvh(asset("mocap/cmu_bvh/02_03.bvh")))
    assert 55.0 < sk.total_mass < 85.0


def test_transforms_are_rigid():
    clip = read_bvh(asset("mocap/cmu_bvh/02_03.bvh"))
    rot, pos = Skeleton(clip).world(np.array([0.3]))
    m = transforms(rot, pos)
    r = m[..., :3, :3]
    np.testing.assert_allclose(r @ np.swapaxes(r, -1, -2), np.broadcast_to(np.eye(3), r.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(r), 1.0, atol=1e-12)
    np.testing.assert_allclose(m[..., :3, 3], pos)


@pytest.mark.parametrize("name", ["CesiumMan", "RiggedFigure"])
def test_exporter_noise_in_translation_keys_makes_no_slide_joints(name):
    from jiggle.rig.motion.gltf_anim import read_gltf_animation
    clip = read_gltf_animation(asset(f"characters/{name}.glb"))
    sk = Skeleton(clip)
    # glTF keys every joint's translation; sub-micrometre wobble is noise: only the root moves
    assert clip.animated_translation.sum() == 1
    assert sk.model.nq == 7 + 4 * (clip.num_joints - 1)
    _, pos = sk.world()
    _, want = clip.world()
    assert np.abs(pos - want).max() < 1e-6  # the noise itself, at most half a micrometre here
