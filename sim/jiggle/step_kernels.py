"""A GPU's way through a run of particle steps: a thread per particle and a launch per step.

The one-launch runs (sim/jiggle/particle_kernels.py: integrate_run, sim/jiggle/contact_kernels.py:
integrate_run_contact) step each group of particles that no spring leaves in one thread, all K steps in
a loop: on a CPU that is the fastest way (no launch per step, a group's particles in the cache), on a GPU
it leaves a few dozen threads for a whole body (28 muscles) and a thread runs far slower than a CPU core.
Here each step is a launch over the particles (and, with contacts, one over the muscles), so a GPU runs
thousands of threads and the launches keep the steps in order; the contacts after a step run a muscle per
thread for what its particles' tests share, then a particle per thread. The kernels take the one-launch kernel's
arguments as they are, after the step index k, and do per particle (per muscle) exactly what its loops do
for that particle (muscle) at step k: the same float32 operations in the same order, so a run launched
this way equals the one-launch run bit for bit on the CPU (tests/jiggle/test_chunk_solver.py), and to
float32 rounding on a GPU (whose compiler may fuse a product and a sum).
"""
from __future__ import annotations

import warp as wp

from jiggle.sim.jiggle.contact_kernels import NO_HIT, contact_ends, contact_particle
from jiggle.sim.jiggle.particle_kernels import Edge, close_velocity, cubic, flow_row, open_offsets, run_step, set_cubic

wp.set_module_options({"enable_backward": False})


@wp.func
def new_cubic(pos: wp.array2d(dtype=wp.vec3), vel_start: wp.array2d(dtype=wp.vec3), vel_end: wp.array2d(dtype=wp.vec3),
              step_seg: wp.array(dtype=wp.int32), step_H: wp.array(dtype=float), k: int, i: int,
              cubics: wp.array(dtype=cubic)):
    """Particle i's goal cubic on step k's knot interval, when step k starts a new one (as the run's loop)."""
    seg = int(step_seg[k])
    if k == 0 or seg != int(step_seg[wp.max(k - 1, 0)]):
        set_cubic(i, pos, vel_start, vel_end, seg, step_H[k], cubics)


# ------------------------------------------------------------------------------------- plain runs
@wp.kernel
def run_open(
    k: int,
    params: wp.array(dtype=wp.vec3), flows: wp.array2d(dtype=flow_row), levels: wp.array3d(dtype=flow_row),
    adj_offsets: wp.array(dtype=wp.int32), edges: wp.array(dtype=Edge), gravity: wp.vec3,
    group_offsets: wp.array(dtype=wp.int32),
    pos: wp.array2d(dtype=wp.vec3), vel_start: wp.array2d(dtype=wp.vec3), vel_end: wp.array2d(dtype=wp.vec3),
    step_seg: wp.array(dtype=wp.int32), step_H: wp.array(dtype=float), step_s0: wp.array(dtype=float),
    step_h: wp.array(dtype=float), step_kick: wp.array(dtype=float), step_flow: wp.array(dtype=wp.int32),
    step_frame: wp.array(dtype=wp.int32), s_end: float, h_end: float,
    x: wp.array(dtype=wp.vec3), v: wp.array(dtype=wp.vec3),
    y_a: wp.array(dtype=wp.vec3), u_a: wp.array(dtype=wp.vec3), y_b: wp.array(dtype=wp.vec3),
    u_b: wp.array(dtype=wp.vec3), cubics: wp.array(dtype=cubic),
    frames_out: wp.array2d(dtype=wp.vec3), x_out: wp.array(dtype=wp.vec3), v_out: wp.array(dtype=wp.vec3),
    stops_out: wp.array(dtype=wp.int32),
):
    """integrate_run's opening: particle i's offsets from its goal at the first step's start."""
    i = wp.tid()
    open_offsets(i, pos, vel_start, vel_end, int(step_seg[0]), step_H[0], step_s0[0], x, v, y_a, u_a)


@wp.kernel
def run_one(
    k: int,
    params: wp.array(dtype=wp.vec3), flows: wp.array2d(dtype=flow_row), levels: wp.array3d(dtype=flow_row),
    adj_offsets: wp.array(dtype=wp.int32), edges: wp.array(dtype=Edge), gravity: wp.vec3,
    group_offsets: wp.array(dtype=wp.int32),
    pos: wp.array2d(dtype=wp.vec3), vel_start: wp.array2d(dtype=wp.vec3), vel_end: wp.array2d(dtype=wp.vec3),
    step_seg: wp.array(dtype=wp.int32), step_H: wp.array(dtype=float), step_s0: wp.array(dtype=float),
    step_h: wp.array(dtype=float), step_kick: wp.array(dtype=float), step_flow: wp.array(dtype=wp.int32),
    step_frame: wp.array(dtype=wp.int32), s_end: float, h_end: float,
    x: wp.array(dtype=wp.vec3), v: wp.array(dtype=wp.vec3),
    y_a: wp.array(dtype=wp.vec3), u_a: wp.array(dtype=wp.vec3), y_b: wp.array(dtype=wp.vec3),
    u_b: wp.array(dtype=wp.vec3), cubics: wp.array(dtype=cubic),
    frames_out: wp.array2d(dtype=wp.vec3), x_out: wp.array(dtype=wp.vec3), v_out: wp.array(dtype=wp.vec3),
    stops_out: wp.array(dtype=wp.int32),
):
    """integrate_run's step k for particle i (the offsets from buffer a to b on even steps, b to a on odd)."""
    i = wp.tid()
    new_cubic(pos, vel_start, vel_end, step_seg, step_H, k, i, cubics)
    last = k == step_seg.shape[0] - 1
    if k % 2 == 0:
        run_step(i, i + 1, params, flows, levels, int(step_flow[k]), adj_offsets, edges, gravity, cubics, step_s0[k],
                 step_h[k], step_kick[k], y_a, u_a, int(step_frame[k]), last, frames_out, x_out, y_b, u_b, stops_out)
    else:
        run_step(i, i + 1, params, flows, levels, int(step_flow[k]), adj_offsets, edges, gravity, cubics, step_s0[k],
                 step_h[k], step_kick[k], y_b, u_b, int(step_frame[k]), last, frames_out, x_out, y_a, u_a, stops_out)


@wp.kernel
def run_close(
    k: int,
    params: wp.array(dtype=wp.vec3), flows: wp.array2d(dtype=flow_row), levels: wp.array3d(dtype=flow_row),
    adj_offsets: wp.array(dtype=wp.int32), edges: wp.array(dtype=Edge), gravity: wp.vec3,
    group_offsets: wp.array(dtype=wp.int32),
    pos: wp.array2d(dtype=wp.vec3), vel_start: wp.array2d(dtype=wp.vec3), vel_end: wp.array2d(dtype=wp.vec3),
    step_seg: wp.array(dtype=wp.int32), step_H: wp.array(dtype=float), step_s0: wp.array(dtype=float),
    step_h: wp.array(dtype=float), step_kick: wp.array(dtype=float), step_flow: wp.array(dtype=wp.int32),
    step_frame: wp.array(dtype=wp.int32), s_end: float, h_end: float,
    x: wp.array(dtype=wp.vec3), v: wp.array(dtype=wp.vec3),
    y_a: wp.array(dtype=wp.vec3), u_a: wp.array(dtype=wp.vec3), y_b: wp.array(dtype=wp.vec3),
    u_b: wp.array(dtype=wp.vec3), cubics: wp.array(dtype=cubic),
    frames_out: wp.array2d(dtype=wp.vec3), x_out: wp.array(dtype=wp.vec3), v_out: wp.array(dtype=wp.vec3),
    stops_out: wp.array(dtype=wp.int32),
):
    """integrate_run's closing half kick: particle i's velocity at the run's end."""
    i = wp.tid()
    K = step_seg.shape[0]
    close_velocity(i, K, params, adj_offsets, edges, pos, vel_start, vel_end, int(step_seg[K - 1]), step_H[K - 1],
                   s_end, h_end, y_a, u_a, y_b, u_b, v_out)


# ------------------------------------------------------------------------------------- with contacts
# each kernel takes integrate_run_contact's arguments (sim/jiggle/contact_kernels.py) after k
@wp.kernel
def contact_open(
    k: int,
    params: wp.array(dtype=wp.vec3), flows: wp.array2d(dtype=flow_row), levels: wp.array3d(dtype=flow_row),
    adj_offsets: wp.array(dtype=wp.int32), edges: wp.array(dtype=Edge), gravity: wp.vec3,
    group_offsets: wp.array(dtype=wp.int32), group_muscles: wp.array(dtype=wp.int32),
    stops_out: wp.array(dtype=wp.int32),
    muscle_offsets: wp.array(dtype=wp.int32), cap_radius: wp.array(dtype=float),
    floor: float, friction: float, num_capsules: int, num_muscles: int,
    active_offsets: wp.array(dtype=wp.int32), active_id: wp.array(dtype=wp.int32),
    pos: wp.array2d(dtype=wp.vec3), vel_start: wp.array2d(dtype=wp.vec3), vel_end: wp.array2d(dtype=wp.vec3),
    cap_pos: wp.array2d(dtype=wp.vec3), cap_vs: wp.array2d(dtype=wp.vec3), cap_ve: wp.array2d(dtype=wp.vec3),
    step_seg: wp.array(dtype=wp.int32), step_H: wp.array(dtype=float), step_s0: wp.array(dtype=float),
    step_h: wp.array(dtype=float), step_kick: wp.array(dtype=float), step_flow: wp.array(dtype=wp.int32),
    step_frame: wp.array(dtype=wp.int32),
    s_end: float, h_end: float,
    x: wp.array(dtype=wp.vec3), v: wp.array(dtype=wp.vec3),
    y_a: wp.array(dtype=wp.vec3), u_a: wp.array(dtype=wp.vec3), y_b: wp.array(dtype=wp.vec3),
    u_b: wp.array(dtype=wp.vec3), cubics: wp.array(dtype=cubic),
    ends_a: wp.array(dtype=wp.vec3), ends_b: wp.array(dtype=wp.vec3), ends_va: wp.array(dtype=wp.vec3),
    ends_vb: wp.array(dtype=wp.vec3), record: wp.array(dtype=wp.vec3), dirty: wp.array(dtype=wp.int32),
    frames_out: wp.array2d(dtype=wp.vec3), contacts_out: wp.array2d(dtype=wp.vec3), x_out: wp.array(dtype=wp.vec3),
    v_out: wp.array(dtype=wp.vec3),
):
    """integrate_run_contact's opening for particle i: offsets and an empty contact record."""
    i = wp.tid()
    open_offsets(i, pos, vel_start, vel_end, int(step_seg[0]), step_H[0], step_s0[0], x, v, y_a, u_a)
    record[i] = wp.vec3(0.0, 0.0, NO_HIT)


@wp.kernel
def contact_clear(
    k: int,
    params: wp.array(dtype=wp.vec3), flows: wp.array2d(dtype=flow_row), levels: wp.array3d(dtype=flow_row),
    adj_offsets: wp.array(dtype=wp.int32), edges: wp.array(dtype=Edge), gravity: wp.vec3,
    group_offsets: wp.array(dtype=wp.int32), group_muscles: wp.array(dtype=wp.int32),
    stops_out: wp.array(dtype=wp.int32),
    muscle_offsets: wp.array(dtype=wp.int32), cap_radius: wp.array(dtype=float),
    floor: float, friction: float, num_capsules: int, num_muscles: int,
    active_offsets: wp.array(dtype=wp.int32), active_id: wp.array(dtype=wp.int32),
    pos: wp.array2d(dtype=wp.vec3), vel_start: wp.array2d(dtype=wp.vec3), vel_end: wp.array2d(dtype=wp.vec3),
    cap_pos: wp.array2d(dtype=wp.vec3), cap_vs: wp.array2d(dtype=wp.vec3), cap_ve: wp.array2d(dtype=wp.vec3),
    step_seg: wp.array(dtype=wp.int32), step_H: wp.array(dtype=float), step_s0: wp.array(dtype=float),
    step_h: wp.array(dtype=float), step_kick: wp.array(dtype=float), step_flow: wp.array(dtype=wp.int32),
    step_frame: wp.array(dtype=wp.int32),
    s_end: float, h_end: float,
    x: wp.array(dtype=wp.vec3), v: wp.array(dtype=wp.vec3),
    y_a: wp.array(dtype=wp.vec3), u_a: wp.array(dtype=wp.vec3), y_b: wp.array(dtype=wp.vec3),
    u_b: wp.array(dtype=wp.vec3), cubics: wp.array(dtype=cubic),
    ends_a: wp.array(dtype=wp.vec3), ends_b: wp.array(dtype=wp.vec3), ends_va: wp.array(dtype=wp.vec3),
    ends_vb: wp.array(dtype=wp.vec3), record: wp.array(dtype=wp.vec3), dirty: wp.array(dtype=wp.int32),
    frames_out: wp.array2d(dtype=wp.vec3), contacts_out: wp.array2d(dtype=wp.vec3), x_out: wp.array(dtype=wp.vec3),
    v_out: wp.array(dtype=wp.vec3),
):
    """integrate_run_contact's opening for muscle m: no records yet."""
    dirty[wp.tid()] = 0


@wp.kernel
def contact_one(
    k: int,
    params: wp.array(dtype=wp.vec3), flows: wp.array2d(dtype=flow_row), levels: wp.array3d(dtype=flow_row),
    adj_offsets: wp.array(dtype=wp.int32), edges: wp.array(dtype=Edge), gravity: wp.vec3,
    group_offsets: wp.array(dtype=wp.int32), group_muscles: wp.array(dtype=wp.int32),
    stops_out: wp.array(dtype=wp.int32),
    muscle_offsets: wp.array(dtype=wp.int32), cap_radius: wp.array(dtype=float),
    floor: float, friction: float, num_capsules: int, num_muscles: int,
    active_offsets: wp.array(dtype=wp.int32), active_id: wp.array(dtype=wp.int32),
    pos: wp.array2d(dtype=wp.vec3), vel_start: wp.array2d(dtype=wp.vec3), vel_end: wp.array2d(dtype=wp.vec3),
    cap_pos: wp.array2d(dtype=wp.vec3), cap_vs: wp.array2d(dtype=wp.vec3), cap_ve: wp.array2d(dtype=wp.vec3),
    step_seg: wp.array(dtype=wp.int32), step_H: wp.array(dtype=float), step_s0: wp.array(dtype=float),
    step_h: wp.array(dtype=float), step_kick: wp.array(dtype=float), step_flow: wp.array(dtype=wp.int32),
    step_frame: wp.array(dtype=wp.int32),
    s_end: float, h_end: float,
    x: wp.array(dtype=wp.vec3), v: wp.array(dtype=wp.vec3),
    y_a: wp.array(dtype=wp.vec3), u_a: wp.array(dtype=wp.vec3), y_b: wp.array(dtype=wp.vec3),
    u_b: wp.array(dtype=wp.vec3), cubics: wp.array(dtype=cubic),
    ends_a: wp.array(dtype=wp.vec3), ends_b: wp.array(dtype=wp.vec3), ends_va: wp.array(dtype=wp.vec3),
    ends_vb: wp.array(dtype=wp.vec3), record: wp.array(dtype=wp.vec3), dirty: wp.array(dtype=wp.int32),
    frames_out: wp.array2d(dtype=wp.vec3), contacts_out: wp.array2d(dtype=wp.vec3), x_out: wp.array(dtype=wp.vec3),
    v_out: wp.array(dtype=wp.vec3),
):
    """integrate_run_contact's step k for particle i, before the contacts."""
    i = wp.tid()
    new_cubic(pos, vel_start, vel_end, step_seg, step_H, k, i, cubics)
    last = k == step_seg.shape[0] - 1
    frame = int(step_frame[k])
    if k % 2 == 0:
        run_step(i, i + 1, params, flows, levels, int(step_flow[k]), adj_offsets, edges, gravity, cubics, step_s0[k],
                 step_h[k], step_kick[k], y_a, u_a, frame, last, frames_out, x_out, y_b, u_b, stops_out)
    else:
        run_step(i, i + 1, params, flows, levels, int(step_flow[k]), adj_offsets, edges, gravity, cubics, step_s0[k],
                 step_h[k], step_kick[k], y_b, u_b, frame, last, frames_out, x_out, y_a, u_a, stops_out)


@wp.kernel
def contact_gather(
    k: int,
    params: wp.array(dtype=wp.vec3), flows: wp.array2d(dtype=flow_row), levels: wp.array3d(dtype=flow_row),
    adj_offsets: wp.array(dtype=wp.int32), edges: wp.array(dtype=Edge), gravity: wp.vec3,
    group_offsets: wp.array(dtype=wp.int32), group_muscles: wp.array(dtype=wp.int32),
    stops_out: wp.array(dtype=wp.int32),
    muscle_offsets: wp.array(dtype=wp.int32), cap_radius: wp.array(dtype=float),
    floor: float, friction: float, num_capsules: int, num_muscles: int,
    active_offsets: wp.array(dtype=wp.int32), active_id: wp.array(dtype=wp.int32),
    pos: wp.array2d(dtype=wp.vec3), vel_start: wp.array2d(dtype=wp.vec3), vel_end: wp.array2d(dtype=wp.vec3),
    cap_pos: wp.array2d(dtype=wp.vec3), cap_vs: wp.array2d(dtype=wp.vec3), cap_ve: wp.array2d(dtype=wp.vec3),
    step_seg: wp.array(dtype=wp.int32), step_H: wp.array(dtype=float), step_s0: wp.array(dtype=float),
    step_h: wp.array(dtype=float), step_kick: wp.array(dtype=float), step_flow: wp.array(dtype=wp.int32),
    step_frame: wp.array(dtype=wp.int32),
    s_end: float, h_end: float,
    x: wp.array(dtype=wp.vec3), v: wp.array(dtype=wp.vec3),
    y_a: wp.array(dtype=wp.vec3), u_a: wp.array(dtype=wp.vec3), y_b: wp.array(dtype=wp.vec3),
    u_b: wp.array(dtype=wp.vec3), cubics: wp.array(dtype=cubic),
    ends_a: wp.array(dtype=wp.vec3), ends_b: wp.array(dtype=wp.vec3), ends_va: wp.array(dtype=wp.vec3),
    ends_vb: wp.array(dtype=wp.vec3), record: wp.array(dtype=wp.vec3), dirty: wp.array(dtype=wp.int32),
    frames_out: wp.array2d(dtype=wp.vec3), contacts_out: wp.array2d(dtype=wp.vec3), x_out: wp.array(dtype=wp.vec3),
    v_out: wp.array(dtype=wp.vec3),
    u_lo: wp.array(dtype=wp.vec3), u_hi: wp.array(dtype=wp.vec3), u_floor: wp.array(dtype=float),
    particle_muscle: wp.array(dtype=wp.int32),
):
    """The contact pass after step k, first for muscle m: what its particles' tests share (contact_ends: the
    listed capsules' ends and boxes, their union, the floor), into u_lo, u_hi, u_floor; and the flag of the
    records written with the step before cleared (contact_pass clears it right after writing them)."""
    m = wp.tid()
    if k > 0 and int(step_frame[k - 1]) >= 0:
        dirty[m] = 0
    seg = int(step_seg[k])
    e0 = int(active_offsets[seg * num_muscles + m])
    e1 = int(active_offsets[seg * num_muscles + m + 1])
    if e1 > e0:
        ulo, uhi, floor_live = contact_ends(e0, e1, num_capsules, floor, cap_radius, active_id, cap_pos, cap_vs,
                                            cap_ve, seg, step_H[k], step_s0[k] + step_h[k], ends_a, ends_b, ends_va,
                                            ends_vb)
        u_lo[m] = ulo
        u_hi[m] = uhi
        u_floor[m] = floor_live


@wp.kernel
def contact_each(
    k: int,
    params: wp.array(dtype=wp.vec3), flows: wp.array2d(dtype=flow_row), levels: wp.array3d(dtype=flow_row),
    adj_offsets: wp.array(dtype=wp.int32), edges: wp.array(dtype=Edge), gravity: wp.vec3,
    group_offsets: wp.array(dtype=wp.int32), group_muscles: wp.array(dtype=wp.int32),
    stops_out: wp.array(dtype=wp.int32),
    muscle_offsets: wp.array(dtype=wp.int32), cap_radius: wp.array(dtype=float),
    floor: float, friction: float, num_capsules: int, num_muscles: int,
    active_offsets: wp.array(dtype=wp.int32), active_id: wp.array(dtype=wp.int32),
    pos: wp.array2d(dtype=wp.vec3), vel_start: wp.array2d(dtype=wp.vec3), vel_end: wp.array2d(dtype=wp.vec3),
    cap_pos: wp.array2d(dtype=wp.vec3), cap_vs: wp.array2d(dtype=wp.vec3), cap_ve: wp.array2d(dtype=wp.vec3),
    step_seg: wp.array(dtype=wp.int32), step_H: wp.array(dtype=float), step_s0: wp.array(dtype=float),
    step_h: wp.array(dtype=float), step_kick: wp.array(dtype=float), step_flow: wp.array(dtype=wp.int32),
    step_frame: wp.array(dtype=wp.int32),
    s_end: float, h_end: float,
    x: wp.array(dtype=wp.vec3), v: wp.array(dtype=wp.vec3),
    y_a: wp.array(dtype=wp.vec3), u_a: wp.array(dtype=wp.vec3), y_b: wp.array(dtype=wp.vec3),
    u_b: wp.array(dtype=wp.vec3), cubics: wp.array(dtype=cubic),
    ends_a: wp.array(dtype=wp.vec3), ends_b: wp.array(dtype=wp.vec3), ends_va: wp.array(dtype=wp.vec3),
    ends_vb: wp.array(dtype=wp.vec3), record: wp.array(dtype=wp.vec3), dirty: wp.array(dtype=wp.int32),
    frames_out: wp.array2d(dtype=wp.vec3), contacts_out: wp.array2d(dtype=wp.vec3), x_out: wp.array(dtype=wp.vec3),
    v_out: wp.array(dtype=wp.vec3),
    u_lo: wp.array(dtype=wp.vec3), u_hi: wp.array(dtype=wp.vec3), u_floor: wp.array(dtype=float),
    particle_muscle: wp.array(dtype=wp.int32),
):
    """The contact pass after step k for particle i (contact_particle, with its muscle's shared part from
    contact_gather)."""
    i = wp.tid()
    m = int(particle_muscle[i])
    seg = int(step_seg[k])
    e0 = int(active_offsets[seg * num_muscles + m])
    e1 = int(active_offsets[seg * num_muscles + m + 1])
    if e1 > e0:
        last = k == step_seg.shape[0] - 1
        frame = int(step_frame[k])
        s1 = step_s0[k] + step_h[k]
        if k % 2 == 0:
            contact_particle(i, m, e0, e1, u_lo[m], u_hi[m], u_floor[m], params, cap_radius, floor, friction,
                             num_capsules, active_id, cubics, cap_pos, cap_vs, cap_ve, seg, step_H[k], s1, ends_a,
                             ends_b, ends_va, ends_vb, record, dirty, y_b, u_b, frame, last, frames_out, x_out)
        else:
            contact_particle(i, m, e0, e1, u_lo[m], u_hi[m], u_floor[m], params, cap_radius, floor, friction,
                             num_capsules, active_id, cubics, cap_pos, cap_vs, cap_ve, seg, step_H[k], s1, ends_a,
                             ends_b, ends_va, ends_vb, record, dirty, y_a, u_a, frame, last, frames_out, x_out)


@wp.kernel
def contact_flush(
    k: int,
    params: wp.array(dtype=wp.vec3), flows: wp.array2d(dtype=flow_row), levels: wp.array3d(dtype=flow_row),
    adj_offsets: wp.array(dtype=wp.int32), edges: wp.array(dtype=Edge), gravity: wp.vec3,
    group_offsets: wp.array(dtype=wp.int32), group_muscles: wp.array(dtype=wp.int32),
    stops_out: wp.array(dtype=wp.int32),
    muscle_offsets: wp.array(dtype=wp.int32), cap_radius: wp.array(dtype=float),
    floor: float, friction: float, num_capsules: int, num_muscles: int,
    active_offsets: wp.array(dtype=wp.int32), active_id: wp.array(dtype=wp.int32),
    pos: wp.array2d(dtype=wp.vec3), vel_start: wp.array2d(dtype=wp.vec3), vel_end: wp.array2d(dtype=wp.vec3),
    cap_pos: wp.array2d(dtype=wp.vec3), cap_vs: wp.array2d(dtype=wp.vec3), cap_ve: wp.array2d(dtype=wp.vec3),
    step_seg: wp.array(dtype=wp.int32), step_H: wp.array(dtype=float), step_s0: wp.array(dtype=float),
    step_h: wp.array(dtype=float), step_kick: wp.array(dtype=float), step_flow: wp.array(dtype=wp.int32),
    step_frame: wp.array(dtype=wp.int32),
    s_end: float, h_end: float,
    x: wp.array(dtype=wp.vec3), v: wp.array(dtype=wp.vec3),
    y_a: wp.array(dtype=wp.vec3), u_a: wp.array(dtype=wp.vec3), y_b: wp.array(dtype=wp.vec3),
    u_b: wp.array(dtype=wp.vec3), cubics: wp.array(dtype=cubic),
    ends_a: wp.array(dtype=wp.vec3), ends_b: wp.array(dtype=wp.vec3), ends_va: wp.array(dtype=wp.vec3),
    ends_vb: wp.array(dtype=wp.vec3), record: wp.array(dtype=wp.vec3), dirty: wp.array(dtype=wp.int32),
    frames_out: wp.array2d(dtype=wp.vec3), contacts_out: wp.array2d(dtype=wp.vec3), x_out: wp.array(dtype=wp.vec3),
    v_out: wp.array(dtype=wp.vec3),
    u_lo: wp.array(dtype=wp.vec3), u_hi: wp.array(dtype=wp.vec3), u_floor: wp.array(dtype=float),
    particle_muscle: wp.array(dtype=wp.int32),
):
    """After a recorded step k's contacts, particle i's record written with the frame and started afresh, where its
    muscle touched something (launched for recorded steps only)."""
    i = wp.tid()
    m = int(particle_muscle[i])
    if dirty[m] != 0:
        contacts_out[int(step_frame[k]), i] = record[i]
        record[i] = wp.vec3(0.0, 0.0, NO_HIT)


@wp.kernel
def contact_close(
    k: int,
    params: wp.array(dtype=wp.vec3), flows: wp.array2d(dtype=flow_row), levels: wp.array3d(dtype=flow_row),
    adj_offsets: wp.array(dtype=wp.int32), edges: wp.array(dtype=Edge), gravity: wp.vec3,
    group_offsets: wp.array(dtype=wp.int32), group_muscles: wp.array(dtype=wp.int32),
    stops_out: wp.array(dtype=wp.int32),
    muscle_offsets: wp.array(dtype=wp.int32), cap_radius: wp.array(dtype=float),
    floor: float, friction: float, num_capsules: int, num_muscles: int,
    active_offsets: wp.array(dtype=wp.int32), active_id: wp.array(dtype=wp.int32),
    pos: wp.array2d(dtype=wp.vec3), vel_start: wp.array2d(dtype=wp.vec3), vel_end: wp.array2d(dtype=wp.vec3),
    cap_pos: wp.array2d(dtype=wp.vec3), cap_vs: wp.array2d(dtype=wp.vec3), cap_ve: wp.array2d(dtype=wp.vec3),
    step_seg: wp.array(dtype=wp.int32), step_H: wp.array(dtype=float), step_s0: wp.array(dtype=float),
    step_h: wp.array(dtype=float), step_kick: wp.array(dtype=float), step_flow: wp.array(dtype=wp.int32),
    step_frame: wp.array(dtype=wp.int32),
    s_end: float, h_end: float,
    x: wp.array(dtype=wp.vec3), v: wp.array(dtype=wp.vec3),
    y_a: wp.array(dtype=wp.vec3), u_a: wp.array(dtype=wp.vec3), y_b: wp.array(dtype=wp.vec3),
    u_b: wp.array(dtype=wp.vec3), cubics: wp.array(dtype=cubic),
    ends_a: wp.array(dtype=wp.vec3), ends_b: wp.array(dtype=wp.vec3), ends_va: wp.array(dtype=wp.vec3),
    ends_vb: wp.array(dtype=wp.vec3), record: wp.array(dtype=wp.vec3), dirty: wp.array(dtype=wp.int32),
    frames_out: wp.array2d(dtype=wp.vec3), contacts_out: wp.array2d(dtype=wp.vec3), x_out: wp.array(dtype=wp.vec3),
    v_out: wp.array(dtype=wp.vec3),
):
    """integrate_run_contact's closing half kick for particle i."""
    i = wp.tid()
    K = step_seg.shape[0]
    close_velocity(i, K, params, adj_offsets, edges, pos, vel_start, vel_end, int(step_seg[K - 1]), step_H[K - 1],
                   s_end, h_end, y_a, u_a, y_b, u_b, v_out)
