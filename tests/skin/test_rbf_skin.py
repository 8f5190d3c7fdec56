"""Anatomy-driven RBF skinning for animation (`skinning = "rbf"`, rig.skin.rbf_skin): the artist's skin at
bind, rigid motion reproduced exactly, one leg never moving the other, muscles carrying the skin,
batches equal to single frames, and a bake that uses it."""
from __future__ import annotations

import numpy as np
import pytest
from conftest import asset


@pytest.fixture(scope="module")
def skin():
    from jiggle.rig.character.load import load_character
    from jiggle.rig.muscle.fit import fit_musculature
    from jiggle.rig.skin.muscle_skin import MuscleSkin
    c = load_character(asset("characters/CesiumMan.glb"))
    mus = fit_musculature(c)
    return c, mus, MuscleSkin.from_musculature(mus, skinning="rbf")


def _turn(c, world, joint: str, axis, degrees: float) -> np.ndarray:
    """world (J, 4, 4) with `joint` and everything below it turned about the joint."""
    from jiggle.rig.motion.quat import from_axis_angle, to_matrix
    w = np.asarray(world, np.float64).copy()
    j = c.index(joint)
    below = [j]
    for k in range(j + 1, c.num_joints):
        if c.parents[k] in below:
            below.append(k)
    R = to_matrix(from_axis_angle(np.asarray(axis, np.float64), np.radians(degrees)))
    p = w[j, :3, 3].copy()
    for k in below:
        w[k, :3, :3] = R @ w[k, :3, :3]
        w[k, :3, 3] = R @ (w[k, :3, 3] - p) + p
    return w


@pytest.mark.slow
def test_bind_pose_is_the_artists_skin_and_topology_is_kept(skin):
    c, mus, sk = skin
    rbf = sk.deformer
    assert rbf.features.inserted == 0 and rbf.num_features > 150
    np.testing.assert_allclose(sk.pose(c.bind_world), c.vertices, atol=2e-6)


def test_rigid_motion_of_the_whole_body_is_exact(skin):
    c, mus, sk = skin
    from jiggle.rig.motion.quat import from_axis_angle, to_matrix
    M = np.eye(4)
    M[:3, :3] = to_matrix(from_axis_angle(np.array([0.3, 0.2, 1.0]) / np.linalg.norm([0.3, 0.2, 1.0]), 1.1))
    M[:3, 3] = [0.4, -1.2, 0.25]
    world = M @ np.asarray(c.bind_world)
    got = sk.pose(world)
    want = c.vertices @ M[:3, :3].T + M[:3, 3]
    np.testing.assert_allclose(got, want, atol=2e-5)


def test_one_leg_never_moves_the_other(skin):
    c, mus, sk = skin
    w = _turn(c, c.bind_world, "leg_joint_L_2", [1.0, 0.0, 0.0], 70.0)   # bend the left knee
    got = sk.pose(w)
    moved = np.linalg.norm(got - c.vertices, axis=1)
    z = sk.deformer.zones
    right = np.isin(z.vertex_zone, [z.index(n) for n in ("right_upper_leg", "right_lower_leg", "right_foot")])
    # the right leg's zones are not neighbours of the left shin: they do not see its features at all
    assert moved[right & (c.vertices[:, 2] < 0.5)].max() < 1e-6
    assert moved.max() > 0.15
    # the bent shin follows its bone: close to LBS there, away from the knee
    lbs = sk.lbs(w)
    shin = z.vertex_zone == z.index("left_lower_leg")
    low = shin & (c.vertices[:, 2] < 0.2)
    assert np.linalg.norm(got[low] - lbs[low], axis=1).mean() < 0.01


def test_muscles_carry_the_skin(skin):
    c, mus, sk = skin
    rig = mus.rig
    st = rig.static(c.bind_world)
    cvs = st.cvs.copy()
    m = rig.names.index("belly_fat")
    rows = slice(40 * m, 40 * m + 40)
    cvs[rows] += [0.0, -0.03, 0.0]                                       # the belly jiggles 3 cm forward
    got = sk.pose(c.bind_world, cvs, st.curve)
    d = got - c.vertices
    assert d[:, 1].min() < -0.02                                         # skin over the belly follows
    # and the pull fades with distance (the soliton kernel's e^(-r/s), s = 15 cm here; the zone's affine
    # part spreads a little of it further): under 15% of the push 40 cm away, under 3% on average
    r = np.linalg.norm(c.vertices - cvs[rows].mean(axis=0), axis=1)
    push = np.linalg.norm(d, axis=1)
    assert push[r > 0.4].max() < 0.15 * 0.03 and push[r > 0.4].mean() < 0.03 * 0.03
    assert push[r < 0.1].mean() > 5 * push[r > 0.4].mean()


def test_the_head_keeps_still_while_the_torso_jiggles(skin):
    """The pipeline's skin stage (skin_frames) on a jiggling belly and pectorals: the torso's skin shows
    the jiggle, the head's none (its zone holds no muscle: jiggle_mask 0), with no step at the neck
    (the mask blends across the zone boundary) and no edge torn by the jiggle."""
    from jiggle.rig.skin.muscle_skin import skin_frames
    from jiggle.rig.skin.quality import SkinQuality
    c, mus, sk = skin
    rig = mus.rig
    world = c.bind_world[None]
    st = rig.static(world)
    cvs = st.cvs.copy()
    for name in ("belly_fat", "left_pectoral", "right_pectoral"):
        m = rig.names.index(name)
        cvs[:, 40 * m:40 * m + 40] += [0.0, -0.03, 0.02]
    static, final = skin_frames(sk, world, (st.cvs, cvs), st.curve, np.arange(1))
    move = np.linalg.norm(final[0] - static[0], axis=1)
    zones = sk.deformer.zones
    head = zones.vertex_zone == list(zones.names).index("head")
    mask = sk.jiggle_mask
    assert mask[head].max() < 1.0 and (mask[head] == 0).mean() > 0.5 and mask[~head].max() == 1.0
    assert move[head & (mask == 0)].max() < 1e-4 and move[~head].max() > 0.01        # < 0.1 mm: the spread
    assert np.percentile(move[head], 99) < 1e-3
    assert SkinQuality(c.vertices, c.faces).jiggle(static, final)["torn_edges"][0] == 0


def test_batch_equals_single_frames(skin):
    c, mus, sk = skin
    world = np.stack([_turn(c, c.bind_world, "Skeleton_arm_joint_L__3_", [0, 0, 1.0], a) for a in (0, 30, 60)])
    st = mus.rig.static(world)
    batch = sk.pose_batch(world, [st.cvs, None], [st.curve, None])
    for t in range(3):
        one = sk.pose(world[t], st.cvs[t], st.curve[t])
        np.testing.assert_allclose(batch[0][t], one, atol=1e-6)
        np.testing.assert_allclose(batch[1][t], one, atol=1e-6)
    # smooth=True: the smooth skin (lbs_batch's) after the sets; launches: the RBF skinner's, one per
    # set, and the smooth skin's
    before = sk.launches
    *sets, smooth = sk.pose_batch(world, [st.cvs, None], [st.curve, None], smooth=True)
    assert len(sets) == 2 and sk.launches - before == 3
    np.testing.assert_array_equal(sets[0], batch[0])
    np.testing.assert_array_equal(smooth, sk.lbs_batch(world))


def test_nan_muscle_falls_back_to_its_rest_shape_with_a_warning(skin):
    from jiggle.rig.base.errors import JiggleWarning
    c, mus, sk = skin
    st = mus.rig.static(c.bind_world)
    cvs = st.cvs.copy()
    cvs[5] = np.nan
    with pytest.warns(JiggleWarning, match="left_biceps.*NaN"):
        got = sk.pose(c.bind_world, cvs, st.curve)
    assert np.isfinite(got).all()


@pytest.mark.slow
def test_bake_with_rbf_skinning(tmp_path):
    from jiggle.sim.app.cli import main
    clip = asset("mocap/cmu_bvh/02_03.bvh")
    character = asset("characters/CesiumMan.glb")
    out = tmp_path / "bake"
    assert main(["bake", "--clip", str(clip), "--character", str(character), "--skinning", "rbf",
                 "--frames", "12", "--formats", "npz", "--out", str(out)]) == 0
    data = np.load(out / "bake.npz")
    assert data["skin_final"].shape[1:] == (3273, 3) and np.isfinite(data["skin_final"]).all()
    assert np.abs(data["skin_final"] - data["skin_static"]).max() > 1e-4
