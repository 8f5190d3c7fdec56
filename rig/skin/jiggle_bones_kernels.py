"""Warp kernels for the jiggle bones fit (rig.skin.jiggle_bones): the shares on the simplex, the bones' rigid
transforms (Gauss-Seidel sweeps of weighted Procrustes), and the smooth skin, in float64 like the NumPy around them.

The launch wrappers are `jiggle_bones.shares`, `jiggle_bones.sweep` and `jiggle_bones.smooth_skin`; the NumPy
references they are tested against are `jiggle_bones._shares_numpy`, `_sweep_numpy` and `_lbs_numpy`.
Shapes: T frames, n a group's vertices, K1 its bones with the host first (bone 0, the identity, never moved).
"""
from __future__ import annotations

import warp as wp

F0 = wp.constant(wp.float64(0.0))
F1 = wp.constant(wp.float64(1.0))


@wp.func
def project_row(x: wp.array2d(dtype=wp.float64), mask: wp.array2d(dtype=wp.int32), i: int):
    """Row i of x projected (in place) onto the simplex restricted to mask[i], by Michelot's algorithm: the
    threshold theta = (sum of the active entries - 1) / their count, entries at or under it dropped, until none
    is (a few passes of K1, no sort)."""
    K1 = x.shape[1]
    theta = wp.float64(0.0)
    lo = wp.float64(-1.0e300)                                  # entries <= lo are out
    changed = int(1)
    while changed != 0:
        run = wp.float64(0.0)
        m = int(0)
        for k in range(K1):
            if mask[i, k] != 0:
                if x[i, k] > lo:
                    run += x[i, k]
                    m += 1
        theta = (run - F1) / wp.float64(m)
        changed = int(0)
        for k in range(K1):
            if mask[i, k] != 0:
                if x[i, k] > lo and x[i, k] <= theta:
                    changed = 1
        lo = theta
    for k in range(K1):
        if mask[i, k] != 0:
            x[i, k] = wp.max(x[i, k] - theta, F0)
        else:
            x[i, k] = F0


@wp.func
def descend(G: wp.array3d(dtype=wp.float64), c: wp.array2d(dtype=wp.float64), u: wp.array2d(dtype=wp.float64),
            mask: wp.array2d(dtype=wp.int32), g: wp.array2d(dtype=wp.float64), i: int, L: wp.float64, steps: int):
    """Projected gradient on row i: min u^T G u - 2 c^T u on the masked simplex, `steps` steps of 1 / L."""
    K1 = u.shape[1]
    project_row(u, mask, i)
    for _ in range(steps):
        for k in range(K1):
            g[i, k] = -c[i, k]
        for l in range(K1):                                    # G u over u's nonzeros: after a projection, few
            ul = u[i, l]
            if ul != F0:
                for k in range(K1):
                    if mask[i, k] != 0:
                        g[i, k] += G[i, k, l] * ul
        for k in range(K1):
            u[i, k] = u[i, k] - g[i, k] / L
        project_row(u, mask, i)


@wp.func
def gram(pi: wp.vec3d, RtR: wp.array2d(dtype=wp.mat33d), Rtt: wp.array2d(dtype=wp.vec3d),
         tt: wp.array2d(dtype=wp.float64), k: int, l: int):
    """sum_t (R_k p + t_k) . (R_l p + t_l) from the frame sums."""
    return wp.dot(pi, RtR[k, l] * pi) + wp.dot(pi, Rtt[k, l]) + wp.dot(pi, Rtt[l, k]) + tt[k, l]


@wp.func
def keep_best(score: wp.array2d(dtype=wp.float64), mask: wp.array2d(dtype=wp.int32), i: int, count: int):
    """mask[i, k] = 0 unless score[i, k] is among the `count` largest of the masked (ties: the first)."""
    K1 = score.shape[1]
    for k in range(K1):
        if mask[i, k] != 0:
            rank = int(0)
            for l in range(K1):
                if mask[i, l] != 0:
                    if score[i, l] > score[i, k] or (score[i, l] == score[i, k] and l < k):
                        rank += 1
            if rank >= count:
                mask[i, k] = 2                                 # out, once every rank is known
    for k in range(K1):
        if mask[i, k] == 2:
            mask[i, k] = 0


@wp.kernel
def shares(p: wp.array(dtype=wp.vec3d), RtR: wp.array2d(dtype=wp.mat33d), Rtt: wp.array2d(dtype=wp.vec3d),
           tt: wp.array2d(dtype=wp.float64), c: wp.array2d(dtype=wp.float64), limit: wp.array(dtype=wp.int32),
           steps: int, u: wp.array2d(dtype=wp.float64), pick: wp.array2d(dtype=wp.int32),
           score: wp.array2d(dtype=wp.float64), G: wp.array3d(dtype=wp.float64), cc: wp.array2d(dtype=wp.float64),
           uc: wp.array2d(dtype=wp.float64), mask: wp.array2d(dtype=wp.int32), g: wp.array2d(dtype=wp.float64)):
    """Vertex i's shares u[i] (K1,), warm-started. The C = pick.shape[1] bones that fit the vertex best alone
    (Dem Bones' nearest bones) are solved on the simplex, then their limit[i] largest shares only; the Gram
    G[i, a, b] = sum_t (R_k p + t_k) . (R_l p + t_l) of candidates a, b (bones k, l) comes from the frame sums
    RtR[k, l] = sum_t R_k^T R_l, Rtt[k, l] = sum_t R_k^T t_l, tt[k, l] = sum_t t_k . t_l. pick, score (n, C),
    G (n, C, C), cc, uc, mask, g (n, C) are per-vertex scratch, the candidates in bone order."""
    i = wp.tid()
    K1 = u.shape[1]
    C = wp.min(pick.shape[1], K1)
    pi = p[i]
    m = int(0)
    for k in range(K1):                                        # alone, bone k leaves |target|^2 + G_kk - 2 c_k:
        e = wp.float64(2.0) * c[i, k] - gram(pi, RtR, Rtt, tt, k, k)    # the C best, kept sorted (ties: the first)
        if m < C or e > score[i, m - 1]:
            j = int(wp.min(m, C - 1))
            while j > 0:
                if score[i, j - 1] >= e:
                    break
                score[i, j] = score[i, j - 1]
                pick[i, j] = pick[i, j - 1]
                j -= 1
            score[i, j] = e
            pick[i, j] = k
            m = wp.min(m + 1, C)
    for a in range(1, C):                                      # into bone order
        k = pick[i, a]
        j = int(a)
        while j > 0:
            if pick[i, j - 1] <= k:
                break
            pick[i, j] = pick[i, j - 1]
            j -= 1
        pick[i, j] = k
    norm2 = wp.float64(0.0)
    for a in range(C):
        k = pick[i, a]
        cc[i, a] = c[i, k]
        uc[i, a] = u[i, k]
        mask[i, a] = 1
        for b in range(C):
            v = gram(pi, RtR, Rtt, tt, k, pick[i, b])
            G[i, a, b] = v
            norm2 += v * v
    L = wp.sqrt(norm2) + wp.float64(1e-12)                     # >= the largest eigenvalue
    descend(G, cc, uc, mask, g, i, L, steps)
    keep_best(uc, mask, i, limit[i])
    descend(G, cc, uc, mask, g, i, L, steps)
    for k in range(K1):
        u[i, k] = F0
    for a in range(C):
        u[i, pick[i, a]] = uc[i, a]


@wp.kernel
def sweep(p: wp.array(dtype=wp.vec3d), target: wp.array2d(dtype=wp.vec3d), omega: wp.array(dtype=wp.float64),
          offsets: wp.array(dtype=wp.int32), members: wp.array(dtype=wp.int32), share: wp.array(dtype=wp.float64),
          mass: wp.array(dtype=wp.float64), centre: wp.array(dtype=wp.vec3d), R: wp.array2d(dtype=wp.mat33d),
          tr: wp.array2d(dtype=wp.vec3d), Y: wp.array2d(dtype=wp.vec3d)):
    """Frame t's bones once, in place (R, tr (T, K1)): bone k's vertices members[offsets[k]:offsets[k + 1]] with
    their shares `share` (same rows); each bone k >= 1 the weighted Procrustes fit (weights omega u_k^2, their sum
    mass[k], the weighted mean of its rest points centre[k]) of what the others' blend leaves of target (T, n);
    bone 0, the host, stays. Y (T, n) scratch: the blend, kept up to date bone by bone."""
    t = wp.tid()
    for i in range(p.shape[0]):
        Y[t, i] = wp.vec3d()
    for k in range(R.shape[1]):
        Rk = R[t, k]
        tk = tr[t, k]
        for e in range(offsets[k], offsets[k + 1]):
            i = members[e]
            Y[t, i] = Y[t, i] + share[e] * (Rk * p[i] + tk)
    for k in range(1, R.shape[1]):
        W = mass[k]
        if W < wp.float64(1e-12):
            continue
        pc = centre[k]
        Rk = R[t, k]
        tk = tr[t, k]
        H = wp.mat33d()
        rw = wp.vec3d()
        for e in range(offsets[k], offsets[k + 1]):
            i = members[e]
            uk = share[e]
            wr = (omega[i] * uk) * (target[t, i] - (Y[t, i] - uk * (Rk * p[i] + tk)))
            rw += wr
            H += wp.outer(p[i] - pc, wr)
        U = wp.mat33d()
        sigma = wp.vec3d()
        V = wp.mat33d()
        wp.svd3(H, U, sigma, V)                                # rotations, sigma sorted, the last signed: V U^T is
        Rn = V * wp.transpose(U)                               # the best rotation, reflections excluded
        tn = rw / W - Rn * pc
        for e in range(offsets[k], offsets[k + 1]):
            i = members[e]
            Y[t, i] = Y[t, i] + share[e] * ((Rn * p[i] + tn) - (Rk * p[i] + tk))
        R[t, k] = Rn
        tr[t, k] = tn


@wp.kernel
def smooth_skin(rest: wp.array(dtype=wp.vec3d), joints: wp.array2d(dtype=wp.int32),
                weights: wp.array2d(dtype=wp.float64), mats: wp.array2d(dtype=wp.mat44d),
                out: wp.array2d(dtype=wp.vec3d)):
    """out[t, v] (metres): LBS of rest[v] by frame t's skinning matrices mats[t] (J,) and v's influences."""
    t, v = wp.tid()
    acc = wp.vec3d()
    for c in range(joints.shape[1]):
        w = weights[v, c]
        if w != F0:
            acc += w * wp.transform_point(mats[t, joints[v, c]], rest[v])
    out[t, v] = acc


@wp.kernel
def lever(rest: wp.array(dtype=wp.vec3d), joints: wp.array2d(dtype=wp.int32), mats: wp.array2d(dtype=wp.mat44d),
          out: wp.array2d(dtype=wp.float64)):
    """out[v, c] (metres): how far vertex v's joint c ever moves it from where its first joint does, over the
    frames of mats (T, J): max_t |M_t[joints[v, c]] p - M_t[joints[v, 0]] p|."""
    v, c = wp.tid()
    far = wp.float64(0.0)
    for t in range(mats.shape[0]):
        gap = wp.transform_point(mats[t, joints[v, c]], rest[v]) - wp.transform_point(mats[t, joints[v, 0]], rest[v])
        far = wp.max(far, wp.length(gap))
    out[v, c] = far
