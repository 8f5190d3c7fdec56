"""Jiggle bones: what the muscles add to plain skinning (skin_final - skin_lbs, the static bulges and the jiggle
together), refitted as a few extra bones with skin weights, so any engine's ordinary linear blend skinning plays it.

The fit is smooth skinning decomposition with rigid bones (Le & Deng, "Smooth Skinning Decomposition with Rigid
Bones", 2012: the algorithm of EA's Dem Bones), with the character's own bones and weights locked:

- Vertices are grouped by their host: the joint the muscle nearest them rides when they have its weight, else
  their strongest joint. A group's jiggle bones hang under its host, named `<muscle>_jiggle_<k>` after the muscle
  most of their skin belongs to. The bone budget is spread over the groups by how much their vertices move (the
  square root of the sum over frames and vertices of |final - lbs|).
- A vertex hands its host's weight w_h over to the group's bones and the host itself, in shares u (u >= 0,
  sum 1); its other influences stay as they are. Then its skin is the LBS skin plus
  w_h * sum_k u_k (S_k - S_h) p, so in the host's rest frame the group's bones C_k = S_h^-1 S_k (the host
  itself C_0 = I) fit the targets p + S_h^-1 (final - lbs) / w_h by ordinary skinning decomposition, each
  vertex's error weighted by w_h^2 (its share of the world error).
- Initial bones: k-means of the vertices' displacement paths; then Dem Bones' alternation: each bone's rigid
  transform per frame by weighted Procrustes (Kabsch) against what the other bones leave (Gauss-Seidel over the
  bones, a frame per thread), and each vertex's shares by a least-squares fit on the simplex (projected
  gradient, a vertex per thread) over the CANDIDATES bones that fit it best alone (Dem Bones' nearest bones),
  cut to the influences the vertex has free (the budget, 4 per vertex by default, less its other joints).
- Those two solves, the smooth skin and the pruning's levers are Warp kernels in float64
  (rig/skin/jiggle_bones_kernels.py, checked against the NumPy references `_*_numpy` here); the groups are
  independent and run on a thread per core.

Shapes: T frames, V vertices, J character joints, K jiggle bones.
"""
from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class JiggleBones:
    """A fit.

    names : (K,) bone names, `<muscle>_jiggle_<k>`.
    hosts : (K,) int32 the character joint each bone hangs under.
    skin : (T, K, 4, 4) float64 the bones' skinning matrices per frame (world <- rest skin, rigid when the
        host's is), the jiggle bone's bind being its host's.
    joints : (V, n) int32 each vertex's influences, strongest first: < J a character joint, J + k bone k;
        padded with 0 where the weight is 0.
    weights : (V, n) float32 their weights, rows summing to 1.
    """

    names: tuple
    hosts: np.ndarray
    skin: np.ndarray
    joints: np.ndarray
    weights: np.ndarray


def nearest_muscle(points: np.ndarray, muscle_points: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """(V,) int32 index of the muscle whose control points (N, 3), muscle m's rows offsets[m]:offsets[m + 1],
    lie nearest each point (V, 3)."""
    from scipy.spatial import cKDTree
    owner = np.repeat(np.arange(len(offsets) - 1), np.diff(offsets))
    return owner[cKDTree(muscle_points).query(points)[1]].astype(np.int32)


def play(bones: JiggleBones, skin_mats: np.ndarray, rest: np.ndarray) -> np.ndarray:
    """(T, V, 3) float32 the skin an engine plays: LBS of the rest skin (V, 3) by the character's skinning
    matrices (T, J, 4, 4) and the bones', with the fit's influences."""
    mats = np.concatenate([skin_mats, bones.skin], axis=1)            # (T, J + K, 4, 4)
    out = np.zeros((len(mats), len(rest), 3))
    p = np.c_[rest, np.ones(len(rest))]
    for c in range(bones.joints.shape[1]):
        w = bones.weights[:, c].astype(np.float64)
        m = mats[:, bones.joints[:, c]]                               # (T, V, 4, 4)
        out += w[None, :, None] * np.einsum("tvab,vb->tva", m[..., :3, :], p)
    return out.astype(np.float32)


def fit(rest: np.ndarray, joints: np.ndarray, weights: np.ndarray, skin_mats: np.ndarray, final: np.ndarray,
        muscle: np.ndarray, muscle_names, budget: int, max_influences: int = 4, muscle_joint=None,
        iterations: int = 4, min_motion_m: float = 5e-5, prune_m: float = 5e-4, seed: int = 0) -> JiggleBones:
    """Fit jiggle bones (see the module).

    rest : (V, 3) rest skin. joints, weights : (V, k) the character's influences (strongest first).
    skin_mats : (T, J, 4, 4) the character's skinning matrices per frame (`Character.skin_matrices`).
    final : (T, V, 3) the skin to reproduce (the bake's skin_final); the smooth skin is the LBS of the above.
    muscle : (V,) int the muscle each vertex belongs to (`nearest_muscle`), -1 none; muscle_names : (M,).
    muscle_joint : (M,) the joint each muscle rides (None: none known): a vertex hands over that joint's weight
        when it has it (>= 0.2), so its bones move with the muscle; else its strongest joint's.
    budget : jiggle bones in all. max_influences : per vertex, the character's and the bones' together.
    min_motion_m : vertices that never move more than this from the LBS skin are left alone.
    prune_m : a weak influence that never moves its vertex more than this (metres, against the strongest joint
        over the clip) goes to the strongest joint, freeing its slot for the jiggle bones; what it moved joins the
        fitted motion (the reported error includes it).
    """
    rest = np.asarray(rest, np.float64)
    V, J, T = len(rest), skin_mats.shape[1], len(skin_mats)
    joints = np.asarray(joints, np.int64)
    weights = np.asarray(weights, np.float64)
    if weights.shape[1] > max_influences:
        raise ValueError(f"the character has {weights.shape[1]} influences per vertex, the budget {max_influences}")
    joints, weights = _pruned(joints, weights, skin_mats, rest, prune_m)
    d = _lbs(joints, weights, skin_mats, rest)                         # the smooth skin of the kept influences,
    np.subtract(final, d, out=d)                                       # and what the muscles add to it (T, V, 3)
    far = np.sqrt(np.einsum("tva,tva->tv", d, d))                      # (T, V) metres
    moving = far.max(axis=0) > min_motion_m
    if muscle_joint is not None:                                       # the muscle's joint first, where it is one
        mj = np.where(muscle >= 0, np.asarray(muscle_joint)[np.maximum(muscle, 0)], -1)
        col = np.argmax((joints == mj[:, None]) & (weights >= 0.2), axis=1)
        swap = np.arange(V)
        for a in (joints, weights):
            first = a[swap, 0].copy()
            a[swap, 0] = a[swap, col]
            a[swap, col] = first
    host = joints[:, 0].astype(np.int64)
    w_host = weights[:, 0].astype(np.float64)
    free = max_influences - (weights[:, 1:] > 0).sum(axis=1)           # slots for the host's share
    use = moving & (free >= 1) & (w_host > 0.2)
    keys = sorted({int(h) for h in host[use]})
    travel = far.sum(axis=0)
    motion = np.array([travel[use & (host == h)].sum() for h in keys])
    # bones in proportion to the square root of the motion: a group's error falls slower than its bones grow, and
    # spending in proportion starved the demo's shoulders (8 bones to the thighs' 34, p99 3.2 mm there)
    counts = _spread(np.sqrt(motion), budget)
    groups = [(h, K, np.flatnonzero(use & (host == h))) for h, K in zip(keys, counts) if K > 0]

    def one(group):                                                    # a group's own generator: the same fit
        h, K, ids = group                                              # whichever thread runs it
        return _fit_group(rest[ids], d[:, ids], w_host[ids], skin_mats[:, h], free[ids], K, iterations,
                          np.random.default_rng([seed, h]))

    from concurrent.futures import ThreadPoolExecutor

    from threadpoolctl import threadpool_limits
    # a thread per core, each with a one-thread BLAS: a group's GEMMs are small, and BLAS threads on top of ours
    # cost more than they give (2.5x slower on two cores)
    with threadpool_limits(limits=1, user_api="blas"), \
            ThreadPoolExecutor(max_workers=min(len(groups), os.cpu_count() or 1) or 1) as pool:
        # groups are independent and their kernels and GEMMs release the GIL; the largest start first
        order = sorted(range(len(groups)), key=lambda g: -len(groups[g][2]) * groups[g][1])
        fits = dict(zip(order, pool.map(one, [groups[g] for g in order])))
    names, hosts, skins = [], [], []
    share_cols = {}                                                    # host -> (vertex ids, shares, first bone)
    per_muscle: dict[str, int] = {}
    for g, (h, K, ids) in enumerate(groups):
        C, u = fits[g]
        base = len(names)
        for k in range(C.shape[1]):                                    # named for the muscle most of its skin is
            mine = muscle[ids][u[:, k + 1] > 0.5]
            mine = mine[mine >= 0]
            label = str(muscle_names[np.bincount(mine).argmax()]) if len(mine) else f"joint{h}"
            names.append(f"{label}_jiggle_{per_muscle.get(label, 0)}")
            per_muscle[label] = per_muscle.get(label, 0) + 1
            hosts.append(h)
        skins.append(skin_mats[:, h][:, None] @ C)                     # (T, K, 4, 4)
        share_cols[h] = (ids, u, base)
    skin = np.concatenate(skins, axis=1) if skins else np.zeros((T, 0, 4, 4))
    out_j = np.zeros((V, max_influences), np.int64)
    out_w = np.zeros((V, max_influences))
    k0 = min(weights.shape[1], max_influences)
    out_j[:, :k0], out_w[:, :k0] = joints[:, :k0], weights[:, :k0]
    for ids, u, base in share_cols.values():
        # each vertex's candidates: its other joints, the host's share kept, the bones' shares; the strongest kept
        K = u.shape[1] - 1
        cj = np.concatenate([joints[ids, 1:], host[ids, None], np.broadcast_to(J + base + np.arange(K), (len(ids), K))],
                            axis=1)
        cw = np.concatenate([weights[ids, 1:], w_host[ids, None] * u], axis=1)
        cw = np.where(cw > 1e-6, cw, 0.0)
        top = np.argsort(-cw, axis=1, kind="stable")[:, :max_influences]
        tw = np.take_along_axis(cw, top, 1)
        m = top.shape[1]                                               # fewer candidates than slots: zeros after
        out_j[ids], out_w[ids] = 0, 0.0
        out_j[ids, :m] = np.where(tw > 0, np.take_along_axis(cj, top, 1), 0)
        out_w[ids, :m] = tw / tw.sum(axis=1, keepdims=True)
    return JiggleBones(tuple(names), np.array(hosts, np.int32), skin, out_j.astype(np.int32),
                       out_w.astype(np.float32))


def _pruned(joints, weights, skin_mats, rest, tol: float):
    """(joints, weights) with the influences whose weight times their joint's motion against the strongest joint
    stays under `tol` metres over every frame given to the strongest joint (see `fit`)."""
    j, w = joints.copy(), weights.copy()
    if tol <= 0:
        return j, w
    import warp as wp
    from jiggle.rig.skin import jiggle_bones_kernels as kern
    mats = skin_mats[np.unique(np.linspace(0, len(skin_mats) - 1, 48).astype(int))]   # a joint's motion is smooth:
    T, J = mats.shape[:2]                                              # 48 frames show its largest
    lever = np.zeros(j.shape)
    wp.launch(kern.lever, dim=j.shape, device="cpu", inputs=[
        _cpu(_f64(rest), wp.vec3d), _cpu(j.astype(np.int32)), _cpu(_f64(mats).reshape(T, J, 16), wp.mat44d),
        _cpu(lever, copy=False)])
    wp.synchronize_device("cpu")
    for c in range(1, j.shape[1]):
        drop = np.flatnonzero((w[:, c] > 0) & (lever[:, c] * w[:, c] < tol))
        w[drop, 0] += w[drop, c]
        w[drop, c], j[drop, c] = 0.0, 0
    order = np.argsort(-w, axis=1, kind="stable")                      # strongest first again
    return np.take_along_axis(j, order, 1), np.take_along_axis(w, order, 1)


def _moved(skin_mats, joint, rest):
    """(T, V, 3) each rest point (V, 3) moved by its joint's skinning matrices (T, J, 4, 4)."""
    out = np.empty((len(skin_mats), len(rest), 3))
    for j in np.unique(joint):                                         # a GEMM per joint, not a (T, V, 4, 4) gather
        ids = np.flatnonzero(joint == j)
        out[:, ids] = _path(rest[ids], skin_mats[:, j, :3, :3], skin_mats[:, j, :3, 3])
    return out


def _lbs(joints, weights, skin_mats, rest):
    """(T, V, 3) float64 LBS of rest (V, 3) by skin_mats (T, J, 4, 4) and the influences (V, k): the Warp kernel
    `smooth_skin`, in float64 (the bake's own skin_lbs is float32)."""
    import warp as wp
    from jiggle.rig.skin import jiggle_bones_kernels as kern
    T, J = skin_mats.shape[:2]
    out = np.empty((T, len(rest), 3))
    rest_w, joints_w, weights_w = _cpu(_f64(rest), wp.vec3d), _cpu(np.asarray(joints, np.int32)), _cpu(_f64(weights))

    def frames(a, b):                                                  # a launch per core, on its own frames
        wp.launch(kern.smooth_skin, dim=(b - a, len(rest)), device="cpu", inputs=[
            rest_w, joints_w, weights_w, _cpu(_f64(skin_mats[a:b]).reshape(b - a, J, 16), wp.mat44d),
            _cpu(out[a:b], wp.vec3d, copy=False)])

    from concurrent.futures import ThreadPoolExecutor
    cuts = np.linspace(0, T, min(T, os.cpu_count() or 1) + 1).astype(int)
    with ThreadPoolExecutor(max_workers=len(cuts) - 1 or 1) as pool:
        list(pool.map(frames, cuts[:-1], cuts[1:]))
    wp.synchronize_device("cpu")
    return out


def _lbs_numpy(joints, weights, skin_mats, rest):
    """`_lbs` in NumPy (the reference the kernel is tested against)."""
    out = np.zeros((len(skin_mats), len(rest), 3))
    for c in range(joints.shape[1]):
        live = weights[:, c] > 0
        out[:, live] += weights[None, live, c, None] * _moved(skin_mats, joints[live, c], rest[live])
    return out


SAMPLE_FRAMES = 32
"""Frames the shares are fitted on (half evenly spaced, half where the group moves most)."""
SAMPLE_VERTICES = 1500
"""Vertices per group the shares and bones alternate on (the rest get their shares from the result)."""
FINAL_SWEEPS = 2
"""Passes over every frame's bone transforms once the shares are fixed."""


def _spread(motion: np.ndarray, budget: int) -> np.ndarray:
    """Bones per group: each moving group one (the most moving first) before any gets a second, the rest in
    proportion to their motion, largest remainders first."""
    motion = np.asarray(motion, np.float64)
    out = np.zeros(len(motion), np.int64)
    live = np.flatnonzero(motion > 0)
    if len(live) == 0 or budget <= 0:
        return out
    first = live[np.argsort(-motion[live])][:budget]
    out[first] = 1
    left = budget - len(first)
    if left > 0:
        want = np.maximum(motion / motion.sum() * budget - out, 0)
        extra = np.floor(want / want.sum() * left).astype(np.int64) if want.sum() > 0 else np.zeros_like(out)
        out += extra
        rest = left - int(extra.sum())
        order = live[np.argsort(-(want - extra)[live])]
        out[order[:rest]] += 1
    return out


def _fit_group(p, d, w_host, host_mats, free, K, iterations, rng):
    """One group's bones: (C (T, K, 4, 4) rigid transforms in the host's rest frame, shares (n, K + 1): the
    host's own first)."""
    T, n = d.shape[:2]
    inv = np.linalg.inv(host_mats)                                     # (T, 4, 4)
    target = p[None] + (d @ np.swapaxes(inv[:, :3, :3], 1, 2)) / w_host[None, :, None]       # (T, n, 3)
    omega = w_host ** 2
    K = min(K, n)
    # initial bones: k-means of the displacement paths (a few frames suffice), one bone per cluster
    frames = np.linspace(0, T - 1, min(T, 48)).astype(int)
    feats = (target[frames] - p[None]).transpose(1, 0, 2).reshape(n, -1)
    if K > 1:
        from scipy.cluster.vq import kmeans2
        _, label = kmeans2(feats, K, minit="++", seed=rng)
    else:
        label = np.zeros(n, np.int64)
    u = np.zeros((n, K + 1))
    u[np.arange(n), label + 1] = 1.0
    limit = np.minimum(free, K + 1)
    # shares and bones alternate on a sample of the frames (shares do not change with time): evenly spaced,
    # and the frames where the group moves most; then every frame's bones, the shares fixed
    sample = np.unique(np.r_[np.linspace(0, T - 1, min(T, SAMPLE_FRAMES // 2)).astype(int),
                             np.argsort(-np.abs(target - p[None]).sum(axis=(1, 2)))[:SAMPLE_FRAMES // 2]])
    R = np.broadcast_to(np.eye(3), (len(sample), K + 1, 3, 3)).copy()
    t = np.zeros((len(sample), K + 1, 3))
    # and on a sample of the vertices (every bone's cluster represented), then every vertex's shares once
    fit = _vertex_sample(label, SAMPLE_VERTICES, rng)
    tf = target[sample][:, fit]
    for it in range(iterations):
        _sweep(p[fit], tf, u[fit], R, t, omega[fit])
        u[fit] = _shares(p[fit], tf, R, t, omega[fit], u[fit], limit[fit])
    if len(fit) < n:
        u = _shares(p, target[sample], R, t, omega, u, limit)
    R = np.broadcast_to(np.eye(3), (T, K + 1, 3, 3)).copy()
    t = np.zeros((T, K + 1, 3))
    for _ in range(FINAL_SWEEPS):
        _sweep(p, target, u, R, t, omega)
    C = np.zeros((T, K, 4, 4))
    C[:, :, :3, :3], C[:, :, :3, 3], C[:, :, 3, 3] = R[:, 1:], t[:, 1:], 1.0
    return C, u


def _vertex_sample(label: np.ndarray, most: int, rng) -> np.ndarray:
    """Indices of at most `most` vertices, drawn from each initial cluster in proportion (at least a few each)."""
    n = len(label)
    if n <= most:
        return np.arange(n)
    out = []
    for k in np.unique(label):
        ids = np.flatnonzero(label == k)
        take = min(len(ids), max(8, int(round(most * len(ids) / n))))
        out.append(rng.choice(ids, take, replace=False))
    return np.sort(np.concatenate(out))


def _sweep(p, target, u, R, t, omega) -> None:
    """Every bone's transforms once, in place (R (T, K1, 3, 3), t (T, K1, 3)), each against the blend the others
    make (Gauss-Seidel), for p (n, 3), target (T, n, 3), shares u (n, K1), error weights omega (n,): the Warp
    kernel `sweep`, a frame per thread."""
    import warp as wp
    from jiggle.rig.skin import jiggle_bones_kernels as kern
    T, n = target.shape[:2]
    K1 = u.shape[1]
    members = [np.flatnonzero(u[:, k] > 0) for k in range(K1)]        # the bone's own vertices: nobody else sees it
    offsets = np.r_[0, np.cumsum([len(m) for m in members])].astype(np.int32)
    flat = np.concatenate(members)
    share = u[flat, np.repeat(np.arange(K1), np.diff(offsets))]
    w = omega[flat] * share ** 2                                       # Procrustes weights, the same every frame
    mass = np.add.reduceat(w, offsets[:-1]) if len(flat) else np.zeros(K1)
    mass[np.diff(offsets) == 0] = 0.0
    centre = np.zeros((K1, 3))
    for k in np.flatnonzero(mass > 0):
        centre[k] = w[offsets[k]:offsets[k + 1]] @ p[members[k]] / mass[k]
    Rw = _f64(R).reshape(T, K1, 9)
    tw = _f64(t)
    wp.launch(kern.sweep, dim=T, device="cpu", inputs=[
        _cpu(_f64(p), wp.vec3d), _cpu(_f64(target), wp.vec3d, copy=False), _cpu(_f64(omega)), _cpu(offsets),
        _cpu(flat.astype(np.int32)), _cpu(_f64(share)), _cpu(_f64(mass)), _cpu(centre, wp.vec3d),
        _cpu(Rw, wp.mat33d, copy=False), _cpu(tw, wp.vec3d, copy=False), wp.empty((T, n), wp.vec3d, device="cpu")])
    wp.synchronize_device("cpu")
    R[...] = Rw.reshape(R.shape)
    t[...] = tw


def _cpu(a: np.ndarray, dtype=None, copy: bool = True):
    """A NumPy array as a Warp array on the CPU; copy=False: a view the kernel writes through. The fit names its
    device on every array and launch rather than through wp.ScopedDevice, whose default device is process-wide
    while the groups run on threads."""
    import warp as wp
    return wp.array(a, copy=copy, device="cpu", **({} if dtype is None else {"dtype": dtype}))


def _f64(a) -> np.ndarray:
    """a as a C-contiguous float64 array (a view when it already is one, so a kernel writes through it)."""
    return np.ascontiguousarray(a, dtype=np.float64)


def _sweep_numpy(p, target, u, R, t, omega) -> None:
    """`_sweep` in NumPy, a bone at a time over every frame (the reference the kernel is tested against)."""
    Y = _blend(p, u, R, t)                                             # the blend, kept up to date bone by bone
    for k in range(1, R.shape[1]):
        ids = np.flatnonzero(u[:, k] > 0)                              # the bone's own vertices: nobody else sees it
        if len(ids) == 0:
            continue
        uk = u[ids, k][None, :, None]
        others = Y[:, ids] - uk * _path(p[ids], R[:, k], t[:, k])
        R[:, k], t[:, k] = _procrustes(p[ids], target[:, ids], others, u[ids, k], omega[ids], R[:, k], t[:, k])
        Y[:, ids] = others + uk * _path(p[ids], R[:, k], t[:, k])


def _path(p, R, t):
    """(T, n, 3) R p + t of one bone over the frames (R (T, 3, 3), t (T, 3))."""
    T = len(R)
    rp = (p @ np.transpose(R, (2, 0, 1)).reshape(3, 3 * T)).reshape(len(p), T, 3)    # one GEMM for every frame
    return np.transpose(rp, (1, 0, 2)) + t[:, None]


def _blend(p, u, R, t):
    """(T, n, 3) sum_k u_k (R_k p + t_k)."""
    out = np.zeros((len(R), len(p), 3))
    for k in range(R.shape[1]):
        ids = np.flatnonzero(u[:, k] > 0)
        if len(ids):
            out[:, ids] += u[None, ids, k, None] * _path(p[ids], R[:, k], t[:, k])
    return out


def _procrustes(p, target, others, uk, omega, Rk, tk):
    """A bone's rigid transform per frame (T, 3, 3), (T, 3) minimising the weighted error (weights omega u_k^2)
    the other bones leave, `others` (T, n, 3) their blend."""
    w = omega * uk ** 2
    if w.sum() < 1e-12:
        return Rk, tk
    wr = (omega * uk)[None, :, None] * (target - others)              # w * r, r = (target - others) / u_k
    W = w.sum()
    pc = (w[:, None] * p).sum(0) / W
    rc = wr.sum(1) / W                                                 # (T, 3)
    H = np.einsum("na,tnb->tab", p - pc, wr, optimize=True)            # sum w (p - pc)(r - rc)^T: sum w (p - pc) = 0
    U, _, Vt = np.linalg.svd(H)
    D = np.ones((len(H), 3))
    D[:, 2] = np.sign(np.linalg.det(np.swapaxes(Vt, 1, 2) @ np.swapaxes(U, 1, 2)))
    Rk = np.swapaxes(Vt, 1, 2) @ (D[:, :, None] * np.swapaxes(U, 1, 2))
    tk = rc - np.einsum("tab,b->ta", Rk, pc)
    return Rk, tk


def _frame_sums(p, target, R, t):
    """The shares' least squares without forming every bone's path: frame sums RtR (K1, K1, 3, 3) = sum_t R_k^T R_l,
    Rtt (K1, K1, 3) = sum_t R_k^T t_l, tt (K1, K1) = sum_t t_k . t_l, and the linear term c (n, K1) =
    sum_t (R_k p + t_k) . target."""
    T, K1 = R.shape[:2]
    A = R.transpose(1, 3, 0, 2).reshape(3 * K1, 3 * T)                 # rows (k, a), columns (t, b): R_tk[b, a]
    B = t.transpose(0, 2, 1).reshape(3 * T, K1)                        # rows (t, b), columns l: t_tl[b]
    RtR = (A @ A.T).reshape(K1, 3, K1, 3).transpose(0, 2, 1, 3)         # each a GEMM
    Rtt = (A @ B).reshape(K1, 3, K1).transpose(0, 2, 1)
    tt = B.T @ B
    flat = target.transpose(0, 2, 1).reshape(3 * T, -1)                # (T*3, n)
    Rt = (A @ flat).reshape(K1, 3, -1)                                 # sum_t R_k^T target
    c = np.einsum("kan,na->nk", Rt, p) + (B.T @ flat).T
    return RtR, Rtt, tt, c


CANDIDATES = 8
"""Bones a vertex's shares are solved over: those that fit it best alone (Dem Bones' nearest bones)."""


def _shares(p, target, R, t, omega, u0, limit, steps: int = 20):
    """Each vertex's shares (n, K1) on the simplex minimising sum_t |sum_k u_k (R_k p + t_k) - target|^2 over the
    CANDIDATES bones that fit it best alone, at most limit[i] of them nonzero (the strongest kept, then refitted),
    warm-started from u0: the Warp kernel `shares`, a vertex per thread."""
    import warp as wp
    from jiggle.rig.skin import jiggle_bones_kernels as kern
    RtR, Rtt, tt, c = _frame_sums(p, target, R, t)
    n, K1 = u0.shape
    u = _f64(u0).copy()
    C = min(CANDIDATES, K1)
    scratch = [wp.empty(shape, dtype, device="cpu") for shape, dtype in (
        ((n, C), wp.int32), ((n, C), wp.float64), ((n, C, C), wp.float64), ((n, C), wp.float64),
        ((n, C), wp.float64), ((n, C), wp.int32), ((n, C), wp.float64))]         # pick, score, G, cc, uc, mask, g
    wp.launch(kern.shares, dim=n, device="cpu", inputs=[
        _cpu(_f64(p), wp.vec3d), _cpu(_f64(RtR).reshape(K1, K1, 9), wp.mat33d), _cpu(_f64(Rtt), wp.vec3d),
        _cpu(_f64(tt)), _cpu(_f64(c)), _cpu(np.asarray(limit, np.int32)), steps, _cpu(u, copy=False), *scratch])
    wp.synchronize_device("cpu")
    return u


def _shares_numpy(p, target, R, t, omega, u0, limit, steps: int = 20):
    """`_shares` in NumPy, batched over the vertices (the reference the kernel is tested against)."""
    RtR, Rtt, tt, c = _frame_sums(p, target, R, t)
    G = np.einsum("na,klab,nb->nkl", p, RtR, p) + np.einsum("na,kla->nkl", p, Rtt) \
        + np.einsum("na,lka->nkl", p, Rtt) + tt[None]
    K1 = G.shape[1]
    cand = _best(2 * c - np.einsum("nkk->nk", G), np.ones_like(u0, bool), np.full(len(u0), CANDIDATES))
    G = G * (cand[:, :, None] & cand[:, None, :])
    u = _simplex_lsq(G, c, u0, cand, steps)                          # warm-started from the last shares
    keep = _best(u, cand, limit)
    return _simplex_lsq(G, c, u * keep, keep, steps)


def _best(score, mask, count):
    """(n, K1) bool: mask less the entries not among each row's count[i] largest scores of the masked (ties: the
    first)."""
    s = np.where(mask, score, -np.inf)
    order = np.argsort(-s, axis=1, kind="stable")
    rank = np.empty_like(order)
    np.put_along_axis(rank, order, np.arange(s.shape[1])[None].repeat(len(s), 0), 1)
    return mask & (rank < np.asarray(count)[:, None])


def _simplex_lsq(G, c, u, mask, steps):
    """min u^T G u - 2 c^T u on {u >= 0, sum u = 1, u = 0 off mask}, by projected gradient (batched)."""
    L = np.linalg.norm(G, axis=(1, 2))[:, None] + 1e-12                # >= the largest eigenvalue
    u = _project(u, mask)
    for _ in range(steps):
        g = np.matmul(G, u[:, :, None])[:, :, 0] - c
        u = _project(u - g / L, mask)
    return u


def _project(x, mask):
    """Euclidean projection of each row of x onto the simplex restricted to mask (batched sort algorithm)."""
    x = np.where(mask, x, -1e30)
    s = -np.sort(-x, axis=1)
    cs = np.cumsum(np.where(s > -1e29, s, 0), axis=1) - 1
    idx = np.arange(1, x.shape[1] + 1)[None]
    ok = (s - cs / idx > 0) & (s > -1e29)
    r = ok.sum(axis=1).clip(min=1)
    theta = cs[np.arange(len(x)), r - 1] / r
    return np.where(mask, np.maximum(x - theta[:, None], 0), 0.0)
