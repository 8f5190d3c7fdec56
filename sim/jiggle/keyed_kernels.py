"""The one-launch run of the particle solver with keyed goal springs (sim/jiggle/keyed.py): the arithmetic of
sim/jiggle/particle_kernels.py's integrate_run, but each step reads its goal-flow coefficients and reach from
rows chosen per (step, thread group) instead of one table row per step and the model's reach. Unkeyed runs
never launch it (they stay on integrate_run, bit for bit and as fast as before). integrate_run_contact_keyed is
the same for contact_kernels.integrate_run_contact (collisions).

Row of particle i at step k: ``rows[row_index[step_base[k, g] + i]]`` (g its thread group), with its reach
``row_reach[step_base[k, g] + i]``: an unkeyed group points at the plain table (one block of N entries per
step length), a keyed one at its block for the step's (knot interval, step length); the index leads each entry to
its row, one row per distinct (stiffness, damping, step length) (a stiffness keyed by activation repeats across a
section's particles and across intervals). The NumPy reference is
sim.jiggle.keyed_solver.integrate_keyed_numpy.
"""
from __future__ import annotations

import warp as wp

from jiggle.sim.jiggle.contact_kernels import NO_HIT, contact_pass
from jiggle.sim.jiggle.particle_kernels import (
    Edge,
    close_velocity,
    cubic,
    edge_kick,
    flow_row,
    open_offsets,
    set_cubic,
    tissue_near,
    tissue_substeps,
)

wp.set_module_options({"enable_backward": False})

NONE_HIT = wp.constant(NO_HIT)
"""contact_kernels.NO_HIT as a kernel constant."""


@wp.func
def run_step_keyed(
    lo: int, hi: int,
    # model: per particle (1 / mass, drag, reach: unused, the rows carry it)
    params: wp.array(dtype=wp.vec3), rows: wp.array(dtype=flow_row), levels: wp.array3d(dtype=flow_row),
    row_reach: wp.array(dtype=float), row_index: wp.array(dtype=wp.int32), base: int,
    adj_offsets: wp.array(dtype=wp.int32), edges: wp.array(dtype=Edge), gravity: wp.vec3,
    # goals: the cubics of the step's knot interval
    cubics: wp.array(dtype=cubic), s0: float, h: float, h_kick: float,
    # offsets in (at s0)
    y: wp.array(dtype=wp.vec3), u: wp.array(dtype=wp.vec3),
    # out
    frame: int, last: bool,
    frames_out: wp.array2d(dtype=wp.vec3), x_out: wp.array(dtype=wp.vec3),
    y_out: wp.array(dtype=wp.vec3), u_out: wp.array(dtype=wp.vec3), stops_out: wp.array(dtype=wp.int32),
):
    """particle_kernels.run_step with the flow row and tissue levels of particle i at rows[r], levels[0, :, r] (r =
    row_index[base + i]) and its reach at row_reach[base + i]."""
    for i in range(lo, hi):
        cu = cubics[i]
        pa = wp.vec3(cu[0], cu[1], cu[2])
        va = wp.vec3(cu[3], cu[4], cu[5])
        c2 = wp.vec3(cu[6], cu[7], cu[8])
        c3 = wp.vec3(cu[9], cu[10], cu[11])
        g_vel = va + s0 * (2.0 * c2 + 3.0 * s0 * c3)
        g_acc = 2.0 * c2 + 6.0 * s0 * c3
        g_jerk = 6.0 * c3
        pr = params[i]
        y0 = y[i]
        u0 = edge_kick(i, h_kick, pr[0], adj_offsets, edges, y, u)
        mu = pr[1]
        b0 = gravity - g_acc - mu * g_vel
        b1 = -g_jerk - mu * g_acc
        b2 = (-0.5 * mu) * g_jerk
        r = int(row_index[base + i])
        fl = rows[r]
        y1 = fl[0] * y0 + fl[1] * u0 + fl[4] * b0 + fl[5] * b1 + fl[6] * b2
        u1 = fl[2] * y0 + fl[3] * u0 + fl[7] * b0 + fl[8] * b1 + fl[9] * b2
        stops = int(0)
        reach = row_reach[base + i]
        if tissue_near(y0, u0, y1, u1, h, reach):
            y1, u1, stops = tissue_substeps(y0, u0, y1, u1, fl, levels, 0, r, b0, b1, b2, h, reach)
        if stops > 0:
            stops_out[i] = stops_out[i] + stops
        if frame >= 0 or last:
            s1 = s0 + h
            x1 = pa + s1 * (va + s1 * (c2 + s1 * c3)) + y1
            if frame >= 0:
                frames_out[frame, i] = x1
            if last:
                x_out[i] = x1
        y_out[i] = y1
        u_out[i] = u1


@wp.kernel
def integrate_run_keyed(
    # model
    params: wp.array(dtype=wp.vec3), rows: wp.array(dtype=flow_row), levels: wp.array3d(dtype=flow_row),
    row_reach: wp.array(dtype=float), row_index: wp.array(dtype=wp.int32),
    adj_offsets: wp.array(dtype=wp.int32), edges: wp.array(dtype=Edge), gravity: wp.vec3,
    group_offsets: wp.array(dtype=wp.int32), stops_out: wp.array(dtype=wp.int32),
    # goals
    pos: wp.array2d(dtype=wp.vec3), vel_start: wp.array2d(dtype=wp.vec3), vel_end: wp.array2d(dtype=wp.vec3),
    # steps (K,): knot interval, its length H, start s0 in it, length h, kick before it, frame (-1: none);
    # (K, G): the row base of each thread group
    step_seg: wp.array(dtype=wp.int32), step_H: wp.array(dtype=float), step_s0: wp.array(dtype=float),
    step_h: wp.array(dtype=float), step_kick: wp.array(dtype=float), step_base: wp.array2d(dtype=wp.int32),
    step_frame: wp.array(dtype=wp.int32),
    # the closing half kick: at s_end of interval step_seg[K - 1], over h_end
    s_end: float, h_end: float,
    # state in
    x: wp.array(dtype=wp.vec3), v: wp.array(dtype=wp.vec3),
    # scratch
    y_a: wp.array(dtype=wp.vec3), u_a: wp.array(dtype=wp.vec3), y_b: wp.array(dtype=wp.vec3),
    u_b: wp.array(dtype=wp.vec3), cubics: wp.array(dtype=cubic),
    # out
    frames_out: wp.array2d(dtype=wp.vec3), x_out: wp.array(dtype=wp.vec3), v_out: wp.array(dtype=wp.vec3),
):
    """particle_kernels.integrate_run with per (step, thread group) rows (see the module)."""
    g = wp.tid()
    lo = int(group_offsets[g])
    hi = int(group_offsets[g + 1])
    K = step_seg.shape[0]
    seg0 = int(step_seg[0])
    for i in range(lo, hi):
        open_offsets(i, pos, vel_start, vel_end, seg0, step_H[0], step_s0[0], x, v, y_a, u_a)
    for k in range(K):
        seg = int(step_seg[k])
        if k == 0 or seg != int(step_seg[wp.max(k - 1, 0)]):
            for i in range(lo, hi):
                set_cubic(i, pos, vel_start, vel_end, seg, step_H[k], cubics)
        last = k == K - 1
        base = int(step_base[k, g])
        if k % 2 == 0:
            run_step_keyed(lo, hi, params, rows, levels, row_reach, row_index, base, adj_offsets, edges, gravity, cubics, step_s0[k],
                           step_h[k], step_kick[k], y_a, u_a, int(step_frame[k]), last, frames_out, x_out, y_b, u_b, stops_out)
        else:
            run_step_keyed(lo, hi, params, rows, levels, row_reach, row_index, base, adj_offsets, edges, gravity, cubics, step_s0[k],
                           step_h[k], step_kick[k], y_b, u_b, int(step_frame[k]), last, frames_out, x_out, y_a, u_a, stops_out)
    for i in range(lo, hi):
        close_velocity(i, K, params, adj_offsets, edges, pos, vel_start, vel_end, int(step_seg[K - 1]), step_H[K - 1],
                       s_end, h_end, y_a, u_a, y_b, u_b, v_out)


@wp.kernel
def integrate_run_contact_keyed(
    # model
    params: wp.array(dtype=wp.vec3), rows: wp.array(dtype=flow_row), levels: wp.array3d(dtype=flow_row),
    row_reach: wp.array(dtype=float), row_index: wp.array(dtype=wp.int32),
    adj_offsets: wp.array(dtype=wp.int32), edges: wp.array(dtype=Edge), gravity: wp.vec3,
    group_offsets: wp.array(dtype=wp.int32), group_muscles: wp.array(dtype=wp.int32),
    stops_out: wp.array(dtype=wp.int32),
    # colliders
    muscle_offsets: wp.array(dtype=wp.int32), cap_radius: wp.array(dtype=float),
    floor: float, friction: float, num_capsules: int, num_muscles: int,
    active_offsets: wp.array(dtype=wp.int32), active_id: wp.array(dtype=wp.int32),
    # goals: the particles', the capsule ends' (same knots)
    pos: wp.array2d(dtype=wp.vec3), vel_start: wp.array2d(dtype=wp.vec3), vel_end: wp.array2d(dtype=wp.vec3),
    cap_pos: wp.array2d(dtype=wp.vec3), cap_vs: wp.array2d(dtype=wp.vec3), cap_ve: wp.array2d(dtype=wp.vec3),
    # steps (K,) as integrate_run_keyed, (K, G) row bases
    step_seg: wp.array(dtype=wp.int32), step_H: wp.array(dtype=float), step_s0: wp.array(dtype=float),
    step_h: wp.array(dtype=float), step_kick: wp.array(dtype=float), step_base: wp.array2d(dtype=wp.int32),
    step_frame: wp.array(dtype=wp.int32),
    s_end: float, h_end: float,
    # state in
    x: wp.array(dtype=wp.vec3), v: wp.array(dtype=wp.vec3),
    # scratch
    y_a: wp.array(dtype=wp.vec3), u_a: wp.array(dtype=wp.vec3), y_b: wp.array(dtype=wp.vec3),
    u_b: wp.array(dtype=wp.vec3), cubics: wp.array(dtype=cubic),
    ends_a: wp.array(dtype=wp.vec3), ends_b: wp.array(dtype=wp.vec3), ends_va: wp.array(dtype=wp.vec3),
    ends_vb: wp.array(dtype=wp.vec3), record: wp.array(dtype=wp.vec3), dirty: wp.array(dtype=wp.int32),
    # out
    frames_out: wp.array2d(dtype=wp.vec3), contacts_out: wp.array2d(dtype=wp.vec3), x_out: wp.array(dtype=wp.vec3),
    v_out: wp.array(dtype=wp.vec3),
):
    """contact_kernels.integrate_run_contact with per (step, thread group) rows (see the module)."""
    g = wp.tid()
    lo = int(group_offsets[g])
    hi = int(group_offsets[g + 1])
    m0 = int(group_muscles[g])
    m1 = int(group_muscles[g + 1])
    K = step_seg.shape[0]
    seg0 = int(step_seg[0])
    for i in range(lo, hi):
        open_offsets(i, pos, vel_start, vel_end, seg0, step_H[0], step_s0[0], x, v, y_a, u_a)
        record[i] = wp.vec3(0.0, 0.0, NONE_HIT)
    for m in range(m0, m1):
        dirty[m] = 0
    for k in range(K):
        seg = int(step_seg[k])
        if k == 0 or seg != int(step_seg[wp.max(k - 1, 0)]):
            for i in range(lo, hi):
                set_cubic(i, pos, vel_start, vel_end, seg, step_H[k], cubics)
        last = k == K - 1
        s1 = step_s0[k] + step_h[k]
        frame = int(step_frame[k])
        base = int(step_base[k, g])
        if k % 2 == 0:
            run_step_keyed(lo, hi, params, rows, levels, row_reach, row_index, base, adj_offsets, edges, gravity, cubics, step_s0[k],
                           step_h[k], step_kick[k], y_a, u_a, frame, last, frames_out, x_out, y_b, u_b, stops_out)
            contact_pass(m0, m1, params, muscle_offsets, cap_radius, floor, friction, num_capsules, num_muscles,
                         active_offsets, active_id, cubics, cap_pos, cap_vs, cap_ve, seg, step_H[k], s1, ends_a,
                         ends_b, ends_va, ends_vb, record, dirty, y_b, u_b, frame, last, frames_out, x_out,
                         contacts_out)
        else:
            run_step_keyed(lo, hi, params, rows, levels, row_reach, row_index, base, adj_offsets, edges, gravity, cubics, step_s0[k],
                           step_h[k], step_kick[k], y_b, u_b, frame, last, frames_out, x_out, y_a, u_a, stops_out)
            contact_pass(m0, m1, params, muscle_offsets, cap_radius, floor, friction, num_capsules, num_muscles,
                         active_offsets, active_id, cubics, cap_pos, cap_vs, cap_ve, seg, step_H[k], s1, ends_a,
                         ends_b, ends_va, ends_vb, record, dirty, y_a, u_a, frame, last, frames_out, x_out,
                         contacts_out)
    for i in range(lo, hi):
        close_velocity(i, K, params, adj_offsets, edges, pos, vel_start, vel_end, int(step_seg[K - 1]), step_H[K - 1],
                       s_end, h_end, y_a, u_a, y_b, u_b, v_out)
