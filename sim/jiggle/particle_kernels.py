"""Warp kernels of one particle step: the offsets from the goals, a half kick of the neighbour springs
with the exact goal flow, and the closing half kick (sim/jiggle/solver.py launches them; the NumPy reference is
:func:`sim.jiggle.solver.step_numpy`; the math is in sim/jiggle/goal_flow.py and sim/jiggle/particles.py).

All muscles' particles are one flat array; a particle's springs are its CSR row. Goals come from the
device goal track (sim/jiggle/goal_track.py): knot interval ``seg`` of length ``H``, at ``s`` seconds into
it, on the cubic Hermite curve. Float32 throughout; offsets from the goal are formed first, so the
precision of a jiggle does not depend on how far from the origin the character is.
"""
from __future__ import annotations

import warp as wp

# forward only: these kernels are never differentiated (no adjoint code to compile)
wp.set_module_options({"enable_backward": False})

BLOCK_SIZE = 8
BLOCK = wp.constant(BLOCK_SIZE)
"""Particles per thread in the step kernels: Warp's CPU backend pays about 10 ns per thread, as much
as a short kernel's work, so each thread steps a block of consecutive particles (launch dim =
ceil(N / BLOCK_SIZE)); on a GPU the blocks still leave thousands of threads for real models."""


@wp.func
def hermite(pa: wp.vec3, pb: wp.vec3, va: wp.vec3, vb: wp.vec3, H: float):
    """c2, c3 of the cubic g(s) = pa + va s + c2 s^2 + c3 s^3 through pa (s = 0) and pb (s = H) with end
    velocities va, vb (sim/jiggle/goal_track.py: hermite)."""
    c2 = ((pb - pa) * (3.0 / H) - 2.0 * va - vb) / H
    c3 = ((pa - pb) * (2.0 / H) + va + vb) / (H * H)
    return c2, c3


@wp.func
def segment(pos: wp.array2d(dtype=wp.vec3), vel_start: wp.array2d(dtype=wp.vec3), vel_end: wp.array2d(dtype=wp.vec3),
            seg: int, i: int):
    """Particle i's goal on knot interval seg: end positions pa, pb and end velocities va, vb (the Hermite
    data of :func:`hermite`)."""
    return pos[seg, i], pos[seg + 1, i], vel_start[seg, i], vel_end[seg, i]


@wp.func
def goal_pos(pa: wp.vec3, pb: wp.vec3, va: wp.vec3, vb: wp.vec3, H: float, s: float):
    c2, c3 = hermite(pa, pb, va, vb, H)
    return pa + s * (va + s * (c2 + s * c3))


@wp.func
def goal_vel(pa: wp.vec3, pb: wp.vec3, va: wp.vec3, vb: wp.vec3, H: float, s: float):
    c2, c3 = hermite(pa, pb, va, vb, H)
    return va + s * (2.0 * c2 + 3.0 * s * c3)


@wp.func
def spring_kick(i: int, h: float, inv_mass: wp.array(dtype=float), adj_offsets: wp.array(dtype=wp.int32),
                adj_index: wp.array(dtype=wp.int32), adj_k: wp.array(dtype=float), adj_c: wp.array(dtype=float),
                y: wp.array(dtype=wp.vec3), u: wp.array(dtype=wp.vec3)):
    """Particle i's offset velocity after a kick of its springs over h: the stiffness and the
    neighbours' velocities explicit, its own velocity in the dampers trapezoidal (sim/jiggle/solver.py)."""
    y_i = y[i]
    f = wp.vec3(0.0)
    c = float(0.0)
    for e in range(adj_offsets[i], adj_offsets[i + 1]):
        j = adj_index[e]
        f += adj_k[e] * (y[j] - y_i) + adj_c[e] * u[j]
        c += adj_c[e]
    d = 0.5 * h * inv_mass[i] * c
    return (u[i] * (1.0 - d) + (h * inv_mass[i]) * f) / (1.0 + d)


@wp.kernel
def offsets(
    # goals
    pos: wp.array2d(dtype=wp.vec3), vel_start: wp.array2d(dtype=wp.vec3), vel_end: wp.array2d(dtype=wp.vec3),
    seg: int, H: float, s: float,
    # state in
    x: wp.array(dtype=wp.vec3), v: wp.array(dtype=wp.vec3),
    # out
    y_out: wp.array(dtype=wp.vec3), u_out: wp.array(dtype=wp.vec3),
):
    """Offsets from the goals at s: y = x - g, u = v - g'."""
    t = wp.tid()
    for i in range(t * BLOCK, wp.min(t * BLOCK + BLOCK, x.shape[0])):
        pa, pb, va, vb = segment(pos, vel_start, vel_end, seg, i)
        y_out[i] = x[i] - goal_pos(pa, pb, va, vb, H, s)
        u_out[i] = v[i] - goal_vel(pa, pb, va, vb, H, s)


@wp.func
def within_reach(y: wp.vec3, u: wp.vec3, reach: float):
    """(y, u) held inside the particle's reach: an offset beyond it is projected onto the sphere of
    radius reach and loses its outward offset velocity (an inelastic stop; sim/jiggle/particles.py)."""
    n = wp.length(y)
    if n <= reach:
        return y, u
    d = y / n
    out = wp.dot(u, d)
    if out > 0.0:
        u = u - out * d
    return d * reach, u


@wp.kernel
def kick_drift(
    # model
    inv_mass: wp.array(dtype=float), drag: wp.array(dtype=float), reach: wp.array(dtype=float),
    flow: wp.array2d(dtype=float),
    adj_offsets: wp.array(dtype=wp.int32), adj_index: wp.array(dtype=wp.int32),
    adj_k: wp.array(dtype=float), adj_c: wp.array(dtype=float), gravity: wp.vec3,
    # goals
    pos: wp.array2d(dtype=wp.vec3), vel_start: wp.array2d(dtype=wp.vec3), vel_end: wp.array2d(dtype=wp.vec3),
    seg: int, H: float, s0: float, h: float, h_kick: float,
    # offsets in (at s0)
    y: wp.array(dtype=wp.vec3), u: wp.array(dtype=wp.vec3),
    # out
    x_out: wp.array(dtype=wp.vec3), y_out: wp.array(dtype=wp.vec3), u_out: wp.array(dtype=wp.vec3),
):
    """Kick of the springs over h_kick at s0 (h/2 opening a step; the previous step's closing half kick
    plus this one's opening half between two steps), then the exact goal flow over h, held within each
    particle's reach: x_out and the offsets at s0 + h (u_out before any closing kick)."""
    t = wp.tid()
    for i in range(t * BLOCK, wp.min(t * BLOCK + BLOCK, y.shape[0])):
        pa, pb, va, vb = segment(pos, vel_start, vel_end, seg, i)
        c2, c3 = hermite(pa, pb, va, vb, H)
        g_vel = va + s0 * (2.0 * c2 + 3.0 * s0 * c3)
        g_acc = 2.0 * c2 + 6.0 * s0 * c3
        g_jerk = 6.0 * c3
        y0 = y[i]
        u0 = spring_kick(i, h_kick, inv_mass, adj_offsets, adj_index, adj_k, adj_c, y, u)
        # forcing of the offset ODE over tau in [0, h]: b0 + b1 tau + b2 tau^2 (sim/jiggle/goal_flow.py)
        mu = drag[i]
        b0 = gravity - g_acc - mu * g_vel
        b1 = -g_jerk - mu * g_acc
        b2 = (-0.5 * mu) * g_jerk
        y1 = flow[i, 0] * y0 + flow[i, 1] * u0 + flow[i, 4] * b0 + flow[i, 5] * b1 + flow[i, 6] * b2
        u1 = flow[i, 2] * y0 + flow[i, 3] * u0 + flow[i, 7] * b0 + flow[i, 8] * b1 + flow[i, 9] * b2
        y1, u1 = within_reach(y1, u1, reach[i])
        s1 = s0 + h
        x_out[i] = pa + s1 * (va + s1 * (c2 + s1 * c3)) + y1
        y_out[i] = y1
        u_out[i] = u1


@wp.kernel
def kick(
    # model
    inv_mass: wp.array(dtype=float), adj_offsets: wp.array(dtype=wp.int32), adj_index: wp.array(dtype=wp.int32),
    adj_k: wp.array(dtype=float), adj_c: wp.array(dtype=float),
    # goals
    pos: wp.array2d(dtype=wp.vec3), vel_start: wp.array2d(dtype=wp.vec3), vel_end: wp.array2d(dtype=wp.vec3),
    seg: int, H: float, s: float, h: float,
    # offsets in (at s)
    y: wp.array(dtype=wp.vec3), u: wp.array(dtype=wp.vec3),
    # out
    v_out: wp.array(dtype=wp.vec3),
):
    """Kick of the springs over h at s: v_out = g'(s) + the kicked offset velocity."""
    t = wp.tid()
    for i in range(t * BLOCK, wp.min(t * BLOCK + BLOCK, y.shape[0])):
        g_vel = goal_vel(pos[seg, i], pos[seg + 1, i], vel_start[seg, i], vel_end[seg, i], H, s)
        v_out[i] = g_vel + spring_kick(i, h, inv_mass, adj_offsets, adj_index, adj_k, adj_c, y, u)


@wp.kernel
def glue(
    # goals
    pos: wp.array2d(dtype=wp.vec3), vel_start: wp.array2d(dtype=wp.vec3), vel_end: wp.array2d(dtype=wp.vec3),
    seg: int, H: float, s: float,
    # out
    x_out: wp.array(dtype=wp.vec3), v_out: wp.array(dtype=wp.vec3),
):
    """Particles on their goals, moving with them, at s (a reset)."""
    i = wp.tid()
    pa, pb, va, vb = segment(pos, vel_start, vel_end, seg, i)
    x_out[i] = goal_pos(pa, pb, va, vb, H, s)
    v_out[i] = goal_vel(pa, pb, va, vb, H, s)
