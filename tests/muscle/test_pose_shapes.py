"""Pose-based muscle shapes (rig.muscle.pose_shapes, Pratscher et al. 2005 section 4.1).

A synthetic arm: a tube of skin (radius 4 cm) around the joints shoulder > elbow > wrist, with the
roles of a left arm and front -y, and a one-pair template (biceps in front, triceps behind the upper
arm). Sculpted poses are the rest tube and the same tube with the front of the upper arm pushed out
(a bulge); the muscles fitted to each are interpolated over the poses' parameters.
"""
import numpy as np
import pytest

from jiggle.rig.base.errors import InputError
from jiggle.rig.character.character import Character, bind_clip
from jiggle.rig.character.normals import vertex_normals
from jiggle.rig.muscle import loft
from jiggle.rig.muscle.fit import fit_musculature
from jiggle.rig.muscle.pose_shapes import PoseShapes, SculptedPose, fit_pose_shapes
from jiggle.rig.muscle.template import template_from_toml

TEMPLATE = template_from_toml("""
name = "arm"
[[pair]]
bone = ["left_upper_arm", "left_lower_arm"]
partition = 0.0
[[pair.muscle]]
name = "left_biceps"
pair_id = 0
type = "upper"
span = [0.15, 0.95]
[[pair.muscle]]
name = "left_triceps"
pair_id = 0
type = "lower"
span = [0.15, 0.95]
""")
ROLES = {"left_upper_arm": 0, "left_lower_arm": 1, "left_hand": 2}
FRONT = np.array([0.0, -1.0, 0.0])
JOINTS = np.array([[0.0, 0.0, 1.2], [0.30, 0.0, 1.2], [0.55, 0.0, 1.2]])
RADIUS = 0.04


def arm_character() -> Character:
    import trimesh
    tube = trimesh.creation.cylinder(radius=RADIUS, segment=[[-0.02, 0.0, 1.2], [0.6, 0.0, 1.2]], sections=32)
    v, f = trimesh.remesh.subdivide_to_size(tube.vertices, tube.faces, 0.012)
    v, f = np.asarray(v), np.asarray(f)
    names, parents = ("shoulder", "elbow", "wrist"), np.array([-1, 0, 1])
    bind = np.tile(np.eye(4), (3, 1, 1))
    bind[:, :3, 3] = JOINTS
    dominant = np.where(v[:, 0] < JOINTS[1, 0], 0, 1)[:, None]
    return Character(vertices=v, faces=f, normals=vertex_normals(v, f), uvs=None, joint_names=names, parents=parents,
                     bind_world=bind, bind_matrices=bind, joints=dominant, weights=np.ones((len(v), 1), np.float32),
                     skeleton=bind_clip(names, parents, bind), name="arm")


def bulged(vertices: np.ndarray, amount: float) -> np.ndarray:
    """The front (-y) of the upper arm pushed out by up to `amount` metres, smoothly."""
    v = np.array(vertices, float)
    s = np.clip((v[:, 0] - 0.05) / 0.23, 0.0, 1.0)
    front = np.clip(-v[:, 1] / RADIUS, 0.0, 1.0)
    v[:, 1] -= amount * np.sin(np.pi * s) ** 2 * front ** 2
    return v


def rigid(angle_deg: float, axis, shift) -> np.ndarray:
    """(4, 4) rotation by angle about `axis` through the shoulder, then a shift."""
    from scipy.spatial.transform import Rotation
    G = np.eye(4)
    G[:3, :3] = Rotation.from_rotvec(np.radians(angle_deg) * np.asarray(axis, float)).as_matrix()
    G[:3, 3] = JOINTS[0] - G[:3, :3] @ JOINTS[0] + np.asarray(shift, float)
    return G


def volumes(local: np.ndarray) -> np.ndarray:
    """Lofted volume (m^3) of CVs (..., M, 40, 3) (a rigid invariant, so local CVs do)."""
    return loft.volume(np.asarray(local).reshape(local.shape[:-2] + (5, 8, 3)))


def fit(character, poses):
    return fit_pose_shapes(character, poses, TEMPLATE, roles=ROLES, front=FRONT)


@pytest.fixture(scope="module")
def arm():
    return arm_character()


@pytest.fixture(scope="module")
def elbow(arm):
    """Two sculpted poses: the rest tube at 0 degrees, the bulged one at 90."""
    W = arm.bind_world
    return fit(arm, [SculptedPose(arm.vertices, W, 0.0), SculptedPose(bulged(arm.vertices, 0.02), W, [90.0])])


def test_shapes_hold_every_muscle_in_its_bone_frame(elbow):
    assert elbow.names == ("left_biceps", "left_triceps")
    assert elbow.bones.tolist() == [0, 0] and elbow.bones.dtype.kind == "i"
    assert elbow.angles.shape == (2, 1) and elbow.angles[:, 0].tolist() == [0.0, 90.0]
    assert elbow.local.shape == (2, 2, 40, 3) and np.all(np.isfinite(elbow.local))
    assert not elbow.local.flags.writeable


def test_one_parameter_is_linear_between_the_poses_and_clamped_beyond(elbow):
    a, b = elbow.local
    np.testing.assert_array_equal(elbow.local_cvs(0.0), a)
    np.testing.assert_array_equal(elbow.local_cvs([90.0]), b)
    np.testing.assert_allclose(elbow.local_cvs(45.0), 0.5 * (a + b), rtol=0, atol=1e-12)
    np.testing.assert_allclose(elbow.local_cvs(22.5), 0.75 * a + 0.25 * b, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(elbow.local_cvs(-30.0), a)
    np.testing.assert_array_equal(elbow.local_cvs(200.0), b)


def test_the_sculpted_bulge_grows_the_biceps_only(elbow):
    v = volumes(elbow.local)                                    # (2 poses, 2 muscles)
    mid = volumes(elbow.local_cvs(45.0))
    print(f"\nbiceps volume: rest {v[0, 0] * 1e6:.1f} cm^3, 45 deg {mid[0] * 1e6:.1f}, bulged {v[1, 0] * 1e6:.1f}")
    assert v[1, 0] > 1.2 * v[0, 0]
    assert v[0, 0] < mid[0] < v[1, 0]
    # the bulge is in front: the biceps' CVs moved toward -y (its bone frame is the world's here)
    assert elbow.local[1, 0, :, 1].mean() < elbow.local[0, 0, :, 1].mean() - 0.003
    # the triceps, behind the partition plane, does not see the front's sculpt
    np.testing.assert_allclose(elbow.local[1, 1], elbow.local[0, 1], atol=1e-9)
    assert mid[1] == pytest.approx(v[0, 1], rel=1e-9)


def test_world_cvs_ride_the_bone(arm, elbow):
    W = arm.bind_world
    # at a sculpted pose and its skeleton, the CVs are that pose's fitted rest CVs
    mus = fit_musculature(arm, TEMPLATE, roles=ROLES, front=FRONT)
    np.testing.assert_allclose(elbow.cvs(W, 0.0).reshape(-1, 3), mus.rig.rest_cvs, atol=1e-12)
    # a rigid motion of the skeleton moves them rigidly
    G = rigid(70.0, [0.3, 0.5, 0.8] / np.linalg.norm([0.3, 0.5, 0.8]), [0.2, -0.1, 0.4])
    for q in (0.0, 45.0, 90.0):
        here = elbow.cvs(W, q)
        moved = elbow.cvs(G @ W, q)
        np.testing.assert_allclose(moved, here @ G[:3, :3].T + G[:3, 3], atol=1e-12)
    # only the muscles' bone (the shoulder joint) carries them: the elbow's transform does not matter
    W2 = W.copy()
    W2[1] = rigid(50.0, [0, 0, 1], [0, 0, 0]) @ W[1]
    np.testing.assert_array_equal(elbow.cvs(W2, 30.0), elbow.cvs(W, 30.0))
    W3 = W.copy()
    W3[0] = rigid(50.0, [0, 0, 1], [0, 0, 0]) @ W[0]
    assert np.abs(elbow.cvs(W3, 30.0) - elbow.cvs(W, 30.0)).max() > 0.05


def test_a_rigidly_moved_sculpt_has_the_same_local_shape(arm):
    """A pose that is the rest skin and skeleton moved rigidly (arm swung 60 degrees about the front
    axis and shifted) gives the same shape in the bone frame: only the change of shape is interpolated."""
    G = rigid(60.0, [0, 1, 0], [0.1, 0.2, -0.05])
    v = arm.vertices @ G[:3, :3].T + G[:3, 3]
    shapes = fit(arm, [SculptedPose(arm.vertices, arm.bind_world, 0.0), SculptedPose(v, G @ arm.bind_world, 30.0)])
    np.testing.assert_allclose(shapes.local[1], shapes.local[0], atol=1e-6)
    assert np.abs(shapes.cvs(G @ arm.bind_world, 30.0) - shapes.cvs(arm.bind_world, 0.0)).max() > 0.05


def test_two_parameters_interpolate_through_every_pose(arm):
    W = arm.bind_world
    sculpts = [(0.0, (0.0, 0.0)), (0.02, (90.0, 0.0)), (0.01, (0.0, 90.0)), (0.03, (90.0, 90.0))]
    shapes = fit(arm, [SculptedPose(bulged(arm.vertices, a), W, q) for a, q in sculpts])
    assert shapes.angles.shape == (4, 2)
    for k, (_, q) in enumerate(sculpts):
        np.testing.assert_allclose(shapes.local_cvs(q), shapes.local[k], rtol=0, atol=1e-9)
    v = volumes(shapes.local)[:, 0]
    assert np.all(np.diff(v[[0, 2, 1, 3]]) > 0)              # the bigger the bulge, the bigger the biceps
    mid = volumes(shapes.local_cvs([45.0, 45.0]))[0]
    assert v.min() < mid < v.max()
    with pytest.raises(InputError, match="2 finite pose parameter"):
        shapes.local_cvs(45.0)


def test_interpolation_rules_on_given_shapes():
    """Without fitting: one parameter, poses out of order, piecewise linear; two parameters, the thin
    plate spline with a linear part reproduces shapes that are linear in the parameters everywhere."""
    rng = np.random.default_rng(1)
    local = rng.normal(size=(3, 2, 40, 3))
    one = PoseShapes(names=("a", "b"), bones=np.array([0, 1]), angles=np.array([[90.0], [0.0], [30.0]]), local=local)
    np.testing.assert_allclose(one.local_cvs(15.0), 0.5 * (local[1] + local[2]), atol=1e-12)
    np.testing.assert_allclose(one.local_cvs(60.0), 0.5 * (local[2] + local[0]), atol=1e-12)
    np.testing.assert_allclose(one.local_cvs(0.0), local[1], atol=1e-12)
    np.testing.assert_allclose(one.local_cvs(100.0), local[0], atol=1e-12)
    q = np.array([[0.0, 0.0], [90.0, 0.0], [0.0, 90.0], [90.0, 90.0], [40.0, 20.0]])
    base, d1, d2 = rng.normal(size=(3, 2, 40, 3))
    linear = base + q[:, 0, None, None, None] / 90.0 * d1 + q[:, 1, None, None, None] / 90.0 * d2
    two = PoseShapes(names=("a", "b"), bones=np.array([0, 1]), angles=q, local=linear)
    np.testing.assert_allclose(two.local_cvs([45.0, 60.0]), base + 0.5 * d1 + (2 / 3) * d2, atol=1e-9)


def test_bad_input_is_refused(arm, elbow):
    W, v = arm.bind_world, arm.vertices
    with pytest.raises(InputError, match="at least two"):
        fit(arm, [SculptedPose(v, W, 0.0)])
    with pytest.raises(InputError, match="same parameters"):
        fit(arm, [SculptedPose(v, W, 10.0), SculptedPose(bulged(v, 0.02), W, 10.0)])
    with pytest.raises(InputError, match="same number of parameters"):
        fit(arm, [SculptedPose(v, W, 0.0), SculptedPose(v, W, [90.0, 0.0])])
    with pytest.raises(InputError, match="does not match the character"):
        fit(arm, [SculptedPose(v[:-3], W, 0.0), SculptedPose(v, W, 90.0)])
    with pytest.raises(InputError, match="does not match the character"):
        fit(arm, [SculptedPose(v, W[:2], 0.0), SculptedPose(v, W, 90.0)])
    for q in (np.nan, np.inf, [10.0, 20.0]):
        with pytest.raises(InputError, match="1 finite pose parameter"):
            elbow.local_cvs(q)
        with pytest.raises(InputError):
            elbow.cvs(W, q)


# ---------------------------------------------------------------------------------- scaled sections
def bent(arm, deg: float) -> np.ndarray:
    """(J, 4, 4) the arm's bind pose with the elbow (and the wrist it carries) flexed by `deg` about z."""
    W = arm.bind_world.copy()
    R = np.eye(4)
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    R[:2, :2] = [[c, -s], [s, c]]
    G = np.eye(4)
    G[:3, 3] = JOINTS[1]
    G = G @ R
    G[:3, 3] -= G[:3, :3] @ JOINTS[1]
    W[1:] = G @ W[1:]
    return W


def section_radii(rig, shape, m: int) -> np.ndarray:
    """(T, 5) mean distance (m) of muscle m's section CVs from their centres on the action curve."""
    from jiggle.rig.muscle.pose_shapes import SECTIONS
    cvs = shape.cvs if shape.cvs.ndim == 3 else shape.cvs[None]
    curve = shape.curve if shape.curve.ndim == 4 else shape.curve[None]
    a, b = rig.cv_offsets[m], rig.cv_offsets[m + 1]
    centre = np.einsum("kj,tjx->tkx", rig.station_basis[m], curve[:, m])
    x = cvs[:, a:b].reshape(len(cvs), SECTIONS, -1, 3)
    return np.linalg.norm(x - centre[:, :, None], axis=-1).mean(axis=-1)


@pytest.fixture(scope="module")
def arm_rig(arm):
    return fit_musculature(arm, TEMPLATE, roles=ROLES, front=FRONT).rig


def test_scaled_sections_take_their_keyed_size_at_the_keyed_bend(arm, arm_rig):
    """The biceps keyed 1 at 0 degrees and (1, 1.2, 1.4, 1.2, 1) at 90 degrees of elbow flexion: bent 90
    degrees its sections are those factors times the unshaped ones (about the same centres), bent 45
    degrees halfway, bent 120 held at the 90-degree key; the triceps and the bind pose are untouched."""
    from dataclasses import replace

    from jiggle.rig.muscle.pose_shapes import SectionShape, bind_section_shapes
    keyed = [1.0, 1.2, 1.4, 1.2, 1.0]
    shapes = bind_section_shapes([SectionShape("left_bic*", "elbow", (0.0, 90.0), ((1.0,) * 5, tuple(keyed)))],
                                 arm_rig, arm.joint_names, arm.parents, arm.bind_world)
    shaped = replace(arm_rig, pose_shapes=shapes)
    world = np.stack([bent(arm, d) for d in (0.0, 45.0, 90.0, 120.0)])
    np.testing.assert_allclose(shapes.bend(world)[:, 0], [0.0, 45.0, 90.0, 120.0], atol=1e-9)
    for device in ("cpu", None):
        plain, new = arm_rig.static(world, device=device), shaped.static(world, device=device)
        ratio = section_radii(shaped, new, 0) / section_radii(arm_rig, plain, 0)
        np.testing.assert_allclose(ratio[0], 1.0, atol=1e-12)
        np.testing.assert_allclose(ratio[1], 1.0 + 0.5 * (np.array(keyed) - 1.0), atol=1e-12)
        np.testing.assert_allclose(ratio[2], keyed, atol=1e-12)
        np.testing.assert_allclose(ratio[3], keyed, atol=1e-12)
        np.testing.assert_array_equal(new.curve, plain.curve)                 # the action curve is not shaped
        tri = slice(arm_rig.cv_offsets[1], arm_rig.cv_offsets[2])
        np.testing.assert_array_equal(new.cvs[:, tri], plain.cvs[:, tri])
        np.testing.assert_array_equal(new.cvs[0], plain.cvs[0])
    # one frame (J, 4, 4) as well as a batch
    np.testing.assert_allclose(shaped.static(world[2]).cvs, shaped.static(world).cvs[2], atol=1e-12)
    assert volumes(shaped.static(world[2]).cvs[None, :40][:, None])[0, 0] > \
        1.3 * volumes(arm_rig.static(world[2]).cvs[None, :40][:, None])[0, 0]


@pytest.mark.parametrize("shape, match", [
    (dict(muscle="quads*"), "no such muscle"),
    (dict(muscle="left_bicep"), "did you mean 'left_biceps'"),
    (dict(joint="knee"), "no joint 'knee'"),
    (dict(angles=(90.0, 0.0)), "angles must increase"),
    (dict(angles=(0.0, 200.0)), "angles must increase"),
    (dict(scales=((1.0, 1.0), (1.0, 1.0))), "one number or 5 numbers"),
    (dict(scales=(1.0, 0.0)), r"scales must be in \[0.1, 10\]"),
    (dict(scales=(1.0, float("nan"))), "scales must be in"),
])
def test_bad_section_shapes_name_where_they_were_given(arm, arm_rig, shape, match):
    from jiggle.rig.muscle.pose_shapes import SectionShape, bind_section_shapes
    given = dict(muscle="left_biceps", joint="elbow", angles=(0.0, 90.0), scales=(1.0, 1.3), path="s.toml", line=7)
    with pytest.raises(InputError, match=match) as e:
        bind_section_shapes([SectionShape(**{**given, **shape})], arm_rig, arm.joint_names, arm.parents,
                            arm.bind_world)
    assert str(e.value).startswith("s.toml:7: pose_shapes.")
