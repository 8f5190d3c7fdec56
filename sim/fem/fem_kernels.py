"""Warp kernels of the FEM reference: the attached vertices driven to their goal, the rest shape set to the goal.

The soft-body solve itself is Newton's (SolverVBD); what jiggle adds per step is (1) the attached (mass 0,
kinematic) vertices put at their goal at the step's end after VBD's forward step has recorded where they
were at its start (so VBD's damping and velocity see them move), and (2) every tet's rest shape (Dm^-1) set to
the goal shape at the step's end, so the body's stress-free shape is the goal (the static shape), as the
particles' springs are at rest on their goals; and in the hero mode (sim/fem/tissue.py) (3) the free vertices
kept out of the bone capsules and above the floor after the step.
"""
from __future__ import annotations

import warp as wp


@wp.kernel
def place_attached(
    # model
    indices: wp.array[wp.int32],
    # control
    goal: wp.array[wp.vec3],
    # out
    q_out: wp.array[wp.vec3],
    reference_out: wp.array[wp.vec3],
):
    """q_out[j] = reference_out[j] = goal[j], j = indices[i]: attached vertex j at its goal (goal: (N,) every
    vertex's goal at the step's end, metres)."""
    i = wp.tid()
    j = indices[i]
    q_out[j] = goal[j]
    reference_out[j] = goal[j]


@wp.kernel
def goal_rest_poses(
    # model
    tets: wp.array2d[wp.int32],
    # control
    goal: wp.array[wp.vec3],
    # out
    poses_out: wp.array[wp.mat33],
):
    """poses_out[t] = Dm^-1 of tet t in the goal shape: Dm = [x1 - x0, x2 - x0, x3 - x0] of goal (N,) metres."""
    t = wp.tid()
    x0 = goal[tets[t, 0]]
    Dm = wp.matrix_from_cols(goal[tets[t, 1]] - x0, goal[tets[t, 2]] - x0, goal[tets[t, 3]] - x0)
    poses_out[t] = wp.inverse(Dm)


@wp.kernel
def goal_drag_kernel(
    # model
    indices: wp.array[wp.int32],
    rate: wp.array[float],
    h: float,
    # control
    goal_velocity: wp.array[wp.vec3],
    # state
    qd: wp.array[wp.vec3],
):
    """The Rayleigh damping's mass-proportional part over a step of h seconds, exactly: vertex j = indices[i]'s
    velocity relative to its goal's decays by exp(-rate[j] h) (rate: (N,) 1/s, alpha of its part)."""
    i = wp.tid()
    j = indices[i]
    gv = goal_velocity[j]
    qd[j] = gv + (qd[j] - gv) * wp.exp(-rate[j] * h)


def goal_drag(indices, rate, h, goal_velocity, qd, device) -> None:
    """Launch goal_drag_kernel over the free vertices (skipped when there are none)."""
    if indices.shape[0] == 0:
        return
    wp.launch(goal_drag_kernel, dim=indices.shape[0], inputs=[indices, rate, float(h), goal_velocity], outputs=[qd],
              device=device)


def place(indices, goal, q, reference, device) -> None:
    """Launch place_attached over the attached vertices (skipped when there are none)."""
    if indices.shape[0] == 0:
        return
    wp.launch(place_attached, dim=indices.shape[0], inputs=[indices, goal], outputs=[q, reference], device=device)


def rest_poses(tets, goal, poses, device) -> None:
    """Launch goal_rest_poses over all tets (skipped when there are none)."""
    if tets.shape[0] == 0:
        return
    wp.launch(goal_rest_poses, dim=tets.shape[0], inputs=[tets, goal], outputs=[poses], device=device)


@wp.func
def _segment_foot(x: wp.vec3, a: wp.vec3, b: wp.vec3) -> wp.vec3:
    ab = b - a
    t = wp.clamp(wp.dot(x - a, ab) / wp.max(wp.dot(ab, ab), 1.0e-20), 0.0, 1.0)
    return a + t * ab


@wp.kernel
def keep_out_kernel(
    # model
    free_idx: wp.array[wp.int32],
    vertex_part: wp.array[wp.int32],
    pair_offsets: wp.array[wp.int32],
    pair_capsule: wp.array[wp.int32],
    radius: wp.array[wp.float32],
    # control
    ends: wp.array[wp.vec3],
    num_capsules: wp.int32,
    floor: wp.float32,
    has_floor: wp.int32,
    goal: wp.array[wp.vec3],
    # state (in and out)
    q: wp.array[wp.vec3],
    qd: wp.array[wp.vec3],
):
    """Free vertex i = free_idx[tid] of part m = vertex_part[i] kept out of the capsules m collides with
    (pair_capsule[pair_offsets[m]:pair_offsets[m + 1]], ends (2C,) metres, radius (C,)) and above the floor, as far as
    its goal is: its distance from a capsule's axis at least min(radius, the goal's distance), its z at least
    min(floor, the goal's z); moved out along the surface normal, its velocity into the surface removed."""
    i = free_idx[wp.tid()]
    x = q[i]
    v = qd[i]
    g = goal[i]
    if num_capsules > 0:
        m = vertex_part[i]
        for k in range(pair_offsets[m], pair_offsets[m + 1]):
            c = pair_capsule[k]
            a = ends[2 * c]
            b = ends[2 * c + 1]
            p = _segment_foot(x, a, b)
            d = x - p
            dist = wp.length(d)
            allowed = wp.min(radius[c], wp.length(g - _segment_foot(g, a, b)))
            if dist < allowed and dist > 1.0e-9:
                n = d / dist
                x = p + n * allowed
                vn = wp.dot(v, n)
                if vn < 0.0:
                    v = v - vn * n
    if has_floor != 0:
        zmin = wp.min(floor, g[2])
        if x[2] < zmin:
            x = wp.vec3(x[0], x[1], zmin)
            if v[2] < 0.0:
                v = wp.vec3(v[0], v[1], 0.0)
    q[i] = x
    qd[i] = v


def keep_out(free_idx, vertex_part, pair_offsets, pair_capsule, ends, radius, num_capsules, floor, goal, q, qd,
             device) -> None:
    """Launch keep_out_kernel over the free vertices (floor None: no floor; num_capsules 0: no capsules)."""
    if free_idx.shape[0] == 0:
        return
    wp.launch(keep_out_kernel, dim=free_idx.shape[0],
              inputs=[free_idx, vertex_part, pair_offsets, pair_capsule, radius, ends, int(num_capsules),
                      float(0.0 if floor is None else floor), int(floor is not None), goal],
              outputs=[q, qd], device=device)


COMPRESSED = wp.constant(0.5)
"""det F below which stiffen_kernel also stiffens a tet as 1 / J^2."""


@wp.kernel
def stiffen_kernel(
    # model
    tets: wp.array2d[wp.int32],
    poses: wp.array[wp.mat33],
    base: wp.array2d[float],
    stiffening: float,
    cap: float,
    # state
    q: wp.array[wp.vec3],
    # out
    materials_out: wp.array2d[float],
):
    """materials_out[t] = base[t] (k_mu, k_lambda, k_damp) scaled for tet t's distortion at q: the moduli by
    s = min(exp(stiffening (I1bar - 3)), cap), I1bar = J^(-2/3) tr(F^T F) (F = Ds Dm^-1, Dm^-1 = poses[t], the goal
    shape's), times (COMPRESSED / J)^2 below J = COMPRESSED, and the damping by s too: Rayleigh's beta K on the
    stiffened K, so a tet struck hard is damped in proportion (scaled by sqrt(s), keeping its damping ratio, one of
    CesiumMan's tets turned inside out on CMU 09_11 once the Rayleigh band had lowered beta)."""
    t = wp.tid()
    x0 = q[tets[t, 0]]
    Ds = wp.matrix_from_cols(q[tets[t, 1]] - x0, q[tets[t, 2]] - x0, q[tets[t, 3]] - x0)
    F = Ds * poses[t]
    J = wp.determinant(F)
    ic = wp.trace(wp.transpose(F) * F)
    i1 = ic * wp.pow(wp.max(wp.abs(J), 1.0e-6), -2.0 / 3.0)
    s = wp.exp(stiffening * wp.max(i1 - 3.0, 0.0))
    if J < COMPRESSED:
        # squeezed toward a flat tet: stiffer as 1 / J^2 (a barrier the lagged update reaches before J = 0)
        s = s * (COMPRESSED / wp.max(J, 1.0e-3)) * (COMPRESSED / wp.max(J, 1.0e-3))
    s = wp.min(s, cap)
    if J <= 0.0:
        s = cap
    materials_out[t, 0] = base[t, 0] * s
    materials_out[t, 1] = base[t, 1] * s
    materials_out[t, 2] = base[t, 2] * s


def stiffen(tets, poses, base, stiffening, cap, q, materials, device) -> None:
    """Launch stiffen_kernel over all tets (skipped when there are none or stiffening is 0)."""
    if tets.shape[0] == 0 or stiffening <= 0.0:
        return
    wp.launch(stiffen_kernel, dim=tets.shape[0], inputs=[tets, poses, base, float(stiffening), float(cap), q],
              outputs=[materials], device=device)


@wp.kernel
def tet_determinants_kernel(
    # model
    tets: wp.array2d[wp.int32],
    poses: wp.array[wp.mat33],
    # state
    q: wp.array[wp.vec3],
    # out
    det_out: wp.array[float],
):
    """det_out[t] = det F of tet t at q against its rest shape (F = Ds Dm^-1, Dm^-1 = poses[t]): its volume over
    the rest shape's (< 0: inside out)."""
    t = wp.tid()
    x0 = q[tets[t, 0]]
    Ds = wp.matrix_from_cols(q[tets[t, 1]] - x0, q[tets[t, 2]] - x0, q[tets[t, 3]] - x0)
    det_out[t] = wp.determinant(Ds * poses[t])


def tet_determinants(tets, poses, q, det, device) -> None:
    """Launch tet_determinants_kernel over all tets (skipped when there are none)."""
    if tets.shape[0] == 0:
        return
    wp.launch(tet_determinants_kernel, dim=tets.shape[0], inputs=[tets, poses, q], outputs=[det], device=device)
