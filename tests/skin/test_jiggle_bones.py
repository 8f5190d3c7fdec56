"""Jiggle bones (rig/skin/jiggle_bones.py): the decomposition recovers bones that made a motion, keeps the
character's own weights where nothing moves, stays inside the influence budget, and spreads the budget by motion."""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from jiggle.rig.skin import jiggle_bones as jb


def two_bone_arm(T=24, seed=0):
    """A bar of vertices on two joints (an upper arm and a forearm turning at the elbow), and a 'muscle' motion
    made by two hidden bones under joint 0: a bulge swinging on the upper arm's front (rigid, as a bone makes)."""
    rng = np.random.default_rng(seed)
    x = rng.uniform(0, 2, 600)
    rest = np.c_[x, rng.uniform(-.1, .1, 600), rng.uniform(-.1, .1, 600)]
    w1 = np.clip((x - 0.8) / 0.4, 0, 1)                                   # forearm share, a soft elbow
    joints = np.where((w1 > 0.5)[:, None], [[1, 0]], [[0, 1]]).astype(np.int32)
    weights = np.where((w1 > 0.5)[:, None], np.c_[w1, 1 - w1], np.c_[1 - w1, w1]).astype(np.float32)
    ang = np.linspace(0, 1.2, T)
    S = np.tile(np.eye(4), (T, 2, 1, 1))
    S[:, 1, :3, :3] = Rotation.from_rotvec(np.c_[0 * ang, 0 * ang, ang]).as_matrix()
    S[:, 1, :3, 3] = np.c_[1 - np.cos(ang), -np.sin(ang), 0 * ang] * 1.0   # turning about (1, 0, 0)
    lbs = jb._lbs(joints.astype(np.int64), weights.astype(np.float64), S, rest)
    # the hidden bones: two rigid wobbles of the upper arm's middle, in its rest frame
    hid = np.zeros((T, 2, 4, 4))
    for k, (amp, f) in enumerate(((0.03, 2.0), (0.02, 3.0))):
        a = amp * np.sin(2 * np.pi * f * np.arange(T) / T)
        hid[:, k] = np.eye(4)
        hid[:, k, :3, :3] = Rotation.from_rotvec(np.c_[a, 0 * a, 0 * a]).as_matrix()
        hid[:, k, :3, 3] = np.c_[0 * a, a, 0.5 * a]
    share = np.zeros((600, 3))
    mid = (x > 0.2) & (x < 0.7)
    share[:, 0] = 1.0
    share[mid, 0], share[mid, 1], share[mid, 2] = 0.2, 0.5 + 0.3 * (rest[mid, 1] > 0), 0.3 - 0.3 * (rest[mid, 1] > 0)
    made = np.einsum("tkab,nb->tkna", hid[..., :3, :3], rest) + hid[:, :, None, :3, 3]        # (T, 2, n, 3)
    in_host = share[:, 0, None] * rest + np.einsum("nk,tkna->tna", share[:, 1:], made)       # host rest frame
    host_w = np.where(joints[:, 0] == 0, weights[:, 0], 0.0)
    final = lbs + host_w[None, :, None] * (in_host - rest)                 # joint 0 never moves: its frame is world
    return rest, joints, weights, S, lbs, final, mid


def test_the_decomposition_finds_the_bones_that_made_the_motion():
    """Two hidden bones under joint 0 move the upper arm's middle: with a budget of 2 the fit puts them back
    (error under 2% of the motion), hung under joint 0, and vertices that did not move keep their weights."""
    rest, joints, weights, S, lbs, final, mid = two_bone_arm()
    bones = jb.fit(rest, joints, weights, S, final, np.zeros(len(rest), int), ["biceps"], budget=2,
                   iterations=30)
    assert bones.names == ("biceps_jiggle_0", "biceps_jiggle_1") and list(bones.hosts) == [0, 0]
    played = jb.play(bones, S, rest)
    disp = np.linalg.norm(final - lbs, axis=2)
    err = np.linalg.norm(played - final, axis=2)
    assert disp.max() > 0.01
    assert err.sum() < 0.02 * disp.sum() and err.max() < 0.1 * disp.max()
    still = disp.max(axis=0) < 1e-9
    assert still.any() and np.allclose(bones.weights[still, :2], weights[still], atol=1e-6)
    assert np.array_equal(bones.joints[still, :2], joints[still])


def test_influences_stay_in_budget_and_weights_sum_to_one():
    rest, joints, weights, S, lbs, final, mid = two_bone_arm(seed=1)
    for budget in (1, 3):
        for k in (2, 3, 4):                      # 4: more slots than a vertex has candidates
            bones = jb.fit(rest, joints, weights, S, final, np.zeros(len(rest), int), ["m"], budget=budget,
                           max_influences=k)
            assert bones.joints.shape == (len(rest), k) and len(bones.names) == budget
            assert np.allclose(bones.weights.sum(axis=1), 1, atol=1e-5) and (bones.weights >= 0).all()
            assert bones.joints.max() < 2 + budget


def test_the_budget_goes_where_the_motion_is():
    assert list(jb._spread(np.array([10.0, 1.0, 0.0]), 2)) == [1, 1, 0]
    assert list(jb._spread(np.array([10.0, 1.0, 0.0]), 6)) == [5, 1, 0]
    assert jb._spread(np.array([3.0, 3.0, 3.0]), 2).sum() == 2
    assert jb._spread(np.zeros(3), 5).sum() == 0


def test_nearest_muscle_labels_points_by_control_points():
    cvs = np.array([[0, 0, 0], [0.1, 0, 0], [1, 0, 0]], float)
    lab = jb.nearest_muscle(np.array([[0.05, 0.01, 0], [0.9, 0, 0]]), cvs, np.array([0, 2, 3]))
    assert list(lab) == [0, 1]


def random_group(T=12, n=160, K1=14, seed=3):
    """A group's solve inputs: rest points, shares on the simplex, rigid bones (the host, bone 0, the identity),
    and the targets they make plus noise."""
    rng = np.random.default_rng(seed)
    p = rng.normal(size=(n, 3)) * 0.1
    R = Rotation.from_rotvec(rng.normal(size=(T * K1, 3)) * 0.3).as_matrix().reshape(T, K1, 3, 3)
    t = rng.normal(size=(T, K1, 3)) * 0.02
    R[:, 0], t[:, 0] = np.eye(3), 0.0
    u = rng.dirichlet(np.full(K1, 0.3), size=n)
    target = np.einsum("nk,tkab,nb->tna", u, R, p) + np.einsum("nk,tka->tna", u, t)
    return p, u, R, t, target + rng.normal(size=target.shape) * 1e-3, rng.uniform(0.2, 1.0, n), rng


def test_the_share_kernel_is_the_numpy_solve():
    """More bones than candidates (14 > 8), mixed influence limits: the kernel's shares are the NumPy
    reference's, on the simplex, within the limit, and only on a vertex's candidate bones."""
    p, u, R, t, target, omega, rng = random_group()
    u0 = np.zeros_like(u)
    u0[np.arange(len(u)), rng.integers(0, u.shape[1], len(u))] = 1.0
    limit = rng.integers(1, 5, len(u))
    got = jb._shares(p, target, R, t, omega, u0, limit)
    ref = jb._shares_numpy(p, target, R, t, omega, u0, limit)
    assert u.shape[1] > jb.CANDIDATES
    assert np.abs(got - ref).max() < 1e-12
    assert np.allclose(got.sum(axis=1), 1) and (got >= 0).all()
    assert ((got > 0).sum(axis=1) <= limit).all() and (got > 0).sum(axis=1).max() > 1


def test_the_sweep_kernel_is_the_numpy_sweep_and_finds_the_bones():
    p, u, R, t, target, omega, _ = random_group(seed=4)
    R1, t1 = np.broadcast_to(np.eye(3), R.shape).copy(), np.zeros_like(t)
    R2, t2 = R1.copy(), t1.copy()
    jb._sweep(p, target, u, R1, t1, omega)
    jb._sweep_numpy(p, target, u, R2, t2, omega)
    assert np.abs(R1 - R2).max() < 1e-10 and np.abs(t1 - t2).max() < 1e-10
    assert np.allclose(np.einsum("tkab,tkcb->tkac", R1, R1), np.eye(3), atol=1e-9)     # rotations
    assert np.allclose(np.linalg.det(R1), 1.0)
    for _ in range(40):                                       # known shares: the sweeps converge on the bones
        jb._sweep(p, target, u, R1, t1, omega)
    made = np.einsum("nk,tkab,nb->tna", u, R1, p) + np.einsum("nk,tka->tna", u, t1)
    assert np.sqrt(((made - target) ** 2).sum(axis=2).mean()) < 2e-3


def test_the_skinning_and_lever_kernels_are_numpy():
    rest, joints, weights, S, lbs, final, mid = two_bone_arm(seed=2)
    j, w = joints.astype(np.int64), weights.astype(np.float64)
    assert np.abs(jb._lbs(j, w, S, rest) - jb._lbs_numpy(j, w, S, rest)).max() < 1e-12
    # pruning: the elbow's weak second influences that never move their vertex 5 mm go to the first joint
    kept_j, kept_w = jb._pruned(j, w, S, rest, 5e-3)
    moved = np.linalg.norm(jb._moved(S, j[:, 1], rest) - jb._moved(S, j[:, 0], rest), axis=2).max(axis=0)
    drop = (w[:, 1] > 0) & (moved * w[:, 1] < 5e-3)
    assert drop.any() and (~drop & (w[:, 1] > 0)).any()
    assert np.allclose(kept_w[drop, 0], 1.0) and (kept_w[~drop, 1] == w[~drop, 1]).all()
