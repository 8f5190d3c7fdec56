"""Warp kernels of one particle step: the offsets from the goals, a half kick of the neighbour springs
with the exact goal flow, and the closing half kick (sim/jiggle/solver.py launches them; the NumPy reference is
:func:`sim.jiggle.solver.step_numpy`; the math is in sim/jiggle/goal_flow.py and sim/jiggle/particles.py);
and :func:`integrate_run`, all of them over a whole cut-free run of steps in one launch, a thread per
group of particles that no spring leaves, equal to them bit for bit.

All muscles' particles are one flat array; a particle's springs are its CSR row. Goals come from the
device goal track (sim/jiggle/goal_track.py): knot interval ``seg`` of length ``H``, at ``s`` seconds into
it, on the cubic Hermite curve. Float32 throughout; offsets from the goal are formed first, so the
precision of a jiggle does not depend on how far from the origin the character is.
"""
from __future__ import annotations

import warp as wp

from jiggle.sim.jiggle import tissue_law

# forward only: these kernels are never differentiated (no adjoint code to compile)
wp.set_module_options({"enable_backward": False})

flow_row = wp.types.vector(length=10, dtype=float)
"""A particle's exact-flow coefficients for one step length (sim/jiggle/goal_flow.py: COEFFS). The tissue law's
levels are rows too (sim/jiggle/tissue_law.py: split): per step length and particle LEVELS + 1 of them, level
0 holding kappa in its first float, level j the exact flow over h / 2^j."""
TISSUE_ONSET = wp.constant(tissue_law.ONSET)
TISSUE_GAIN = wp.constant(tissue_law.GAIN)
TISSUE_SLOPE = wp.constant(tissue_law.SLOPE)
TISSUE_SAFE = wp.constant(tissue_law.SAFE)
TISSUE_NEAR = wp.constant(tissue_law.NEAR)
TISSUE_FAST = wp.constant(tissue_law.FAST)
TISSUE_LEVELS = wp.constant(tissue_law.LEVELS)
assert tissue_law.LEVELS == 6, "tissue_substeps counts the six level thresholds one by one"
TISSUE_STABLE = wp.constant(tissue_law.STABLE)

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
def tissue_accel(y: wp.vec3, kap: float, reach: float):
    """The tissue law's stiffening acceleration -kappa phi(|y| / reach) y (sim/jiggle/tissue_law.py)."""
    r2 = wp.dot(y, y)
    on = TISSUE_ONSET * reach
    if r2 <= on * on:                               # the linear range: nothing (no square root)
        return wp.vec3(0.0)
    rho = wp.sqrt(r2) / reach
    if rho > 1.0:                                   # past the reach: the force grows on in a straight line
        return (-kap * (TISSUE_GAIN + TISSUE_SLOPE * (rho - 1.0)) / rho) * y
    t = (rho - TISSUE_ONSET) / (1.0 - TISSUE_ONSET)
    return (-kap * TISSUE_GAIN * t * t * t) * y


@wp.func
def hard_stop(y0: wp.vec3, u0: wp.vec3, y1: wp.vec3, u1: wp.vec3, reach: float, h: float):
    """1 for a substep that ends near the limit with the outward offset speed fallen by more than half
    and not turned back, from a fast start (sim.jiggle.tissue_law.hard_stop_numpy), else 0."""
    near = TISSUE_NEAR * reach
    if wp.dot(y1, y1) < near * near:
        return int(0)
    n0 = wp.length(y0)
    n1 = wp.length(y1)
    if n0 <= 0.0:
        return int(0)
    v0 = wp.dot(u0, y0) / n0
    v1 = wp.dot(u1, y1) / n1
    # a wall leaves the outward speed at 0 (to round-off): one that turned back by more than 1% of it was not stopped
    if v0 * h > TISSUE_FAST * reach and v1 >= -0.01 * v0 and v1 < 0.5 * v0:
        return int(1)
    return int(0)


@wp.func
def tissue_near(y0: wp.vec3, u0: wp.vec3, y1: wp.vec3, u1: wp.vec3, h: float, reach: float):
    """Whether a step (y0, u0) -> (y1, u1) of the linear flow over h may pass the tissue law's onset (then
    :func:`tissue_substeps` takes it again): the larger end plus a quarter step at the larger end speed, over
    SAFE x ONSET x reach (sim.jiggle.tissue_law.bound). Small, so the step kernels keep it inline and the
    linear steps cost what they cost before the law."""
    a = wp.max(wp.dot(y0, y0), wp.dot(y1, y1))
    q = 0.25 * h
    v = q * q * wp.max(wp.dot(u0, u0), wp.dot(u1, u1))
    lim = TISSUE_SAFE * TISSUE_ONSET * reach
    if a + v <= 0.5 * lim * lim:                    # (sqrt(a) + sqrt(v))^2 <= 2 (a + v): surely below
        return False
    return wp.sqrt(a) + wp.sqrt(v) > lim


@wp.func
def tissue_substeps(y0: wp.vec3, u0: wp.vec3, y1: wp.vec3, u1: wp.vec3, fl: flow_row,
                    levels: wp.array3d(dtype=flow_row), f: int, i: int, b0: wp.vec3, b1: wp.vec3, b2: wp.vec3,
                    h: float, reach: float):
    """The goal part of a step of h under the tissue law (sim/jiggle/tissue_law.py) for a particle that may
    pass the onset (:func:`tissue_near`): (y, u, hard stops) from offsets (y0, u0) under the forcing
    b0 + b1 tau + b2 tau^2, given the step's linear flow fl and its result (y1, u1): 2^j substeps of a half
    kick of the stiffening, the exact flow levels[f, j, i] over h / 2^j, a half kick (level 0 holds kappa, k
    and the energy thresholds of the levels)."""
    stops = int(0)
    l0 = levels[f, 0, i]
    kap = l0[0]
    if kap <= 0.0:
        return y1, u1, stops
    # the level from the particle's energy per unit mass and reach^2 (sim.jiggle.tissue_law.thresholds): a free
    # swing keeps it, so one swing keeps one level
    rho = wp.length(y0) / reach
    tt = wp.max(rho - TISSUE_ONSET, 0.0) / (1.0 - TISSUE_ONSET)
    past = wp.max(rho - 1.0, 0.0)
    tt = wp.min(tt, 1.0)
    pot = TISSUE_GAIN * (1.0 - TISSUE_ONSET) * (TISSUE_ONSET * tt * tt * tt * tt / 4.0 +
                                                (1.0 - TISSUE_ONSET) * tt * tt * tt * tt * tt / 5.0) + \
        TISSUE_GAIN * past + 0.5 * TISSUE_SLOPE * past * past
    e = 0.5 * wp.dot(u0, u0) / (reach * reach) + 0.5 * l0[1] * rho * rho + kap * pot
    # thresholds passed (LEVELS = 6 of them, l0[2:8]), without a loop or a dynamic index
    j = (wp.where(l0[2] <= e, 1, 0) + wp.where(l0[3] <= e, 1, 0) + wp.where(l0[4] <= e, 1, 0) +
         wp.where(l0[5] <= e, 1, 0) + wp.where(l0[6] <= e, 1, 0) + wp.where(l0[7] <= e, 1, 0))
    if j == 0:                                      # one substep: the linear flow of the kicked velocity is
        uk = (0.5 * h) * tissue_accel(y0, kap, reach)   # the step's linear flow plus the flow of the kick
        yn = y1 + fl[1] * uk
        un = u1 + fl[3] * uk
        un = un + (0.5 * h) * tissue_accel(yn, kap, reach)
        stops += hard_stop(y0, u0, yn, un, reach, h)
        return yn, un, stops
    sub = levels[f, j, i]
    n = int(1)
    for _ in range(j):
        n = 2 * n                                   # 2^j
    hs = h / float(n)
    # a particle whose stiffening outruns even the finest level (a goal weight near 1 driven far past its reach)
    # stiffens only as much as the substeps resolve: never unstable
    if j == TISSUE_LEVELS:
        kap = wp.min(kap, TISSUE_STABLE * TISSUE_STABLE / (hs * hs * TISSUE_SLOPE))
    y = y0
    u = u0
    for q in range(n):
        tau = hs * float(q)
        c0 = b0 + tau * (b1 + tau * b2)
        c1 = b1 + (2.0 * tau) * b2
        uk = u + (0.5 * hs) * tissue_accel(y, kap, reach)
        yn = sub[0] * y + sub[1] * uk + sub[4] * c0 + sub[5] * c1 + sub[6] * b2
        un = sub[2] * y + sub[3] * uk + sub[7] * c0 + sub[8] * c1 + sub[9] * b2
        un = un + (0.5 * hs) * tissue_accel(yn, kap, reach)
        stops += hard_stop(y, u, yn, un, reach, hs)
        y = yn
        u = un
    return y, u, stops


@wp.kernel
def kick_drift(
    # model
    inv_mass: wp.array(dtype=float), drag: wp.array(dtype=float), reach: wp.array(dtype=float),
    flow: wp.array(dtype=flow_row), levels: wp.array3d(dtype=flow_row),
    adj_offsets: wp.array(dtype=wp.int32), adj_index: wp.array(dtype=wp.int32),
    adj_k: wp.array(dtype=float), adj_c: wp.array(dtype=float), gravity: wp.vec3,
    # goals
    pos: wp.array2d(dtype=wp.vec3), vel_start: wp.array2d(dtype=wp.vec3), vel_end: wp.array2d(dtype=wp.vec3),
    seg: int, H: float, s0: float, h: float, h_kick: float,
    # offsets in (at s0)
    y: wp.array(dtype=wp.vec3), u: wp.array(dtype=wp.vec3),
    # out
    x_out: wp.array(dtype=wp.vec3), y_out: wp.array(dtype=wp.vec3), u_out: wp.array(dtype=wp.vec3),
    stops_out: wp.array(dtype=wp.int32),
):
    """Kick of the springs over h_kick at s0 (h/2 opening a step; the previous step's closing half kick
    plus this one's opening half between two steps), then the goal part over h under the tissue law
    (tissue_near, tissue_substeps): x_out and the offsets at s0 + h (u_out before any closing kick); each particle's hard
    stops added to stops_out."""
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
        fl = flow[i]
        y1 = fl[0] * y0 + fl[1] * u0 + fl[4] * b0 + fl[5] * b1 + fl[6] * b2
        u1 = fl[2] * y0 + fl[3] * u0 + fl[7] * b0 + fl[8] * b1 + fl[9] * b2
        stops = int(0)
        if tissue_near(y0, u0, y1, u1, h, reach[i]):
            y1, u1, stops = tissue_substeps(y0, u0, y1, u1, fl, levels, 0, i, b0, b1, b2, h, reach[i])
        if stops > 0:
            stops_out[i] = stops_out[i] + stops
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


# ------------------------------------------------------------------------------ a whole run, one launch
# The run's data is packed so that each particle and each of its springs is one load (the CPU pays
# for every index's address arithmetic, as much as for the float operations themselves).
cubic = wp.types.vector(length=12, dtype=float)
"""A particle's goal on one knot interval: pa, va, c2, c3 (g(s) = pa + va s + c2 s^2 + c3 s^3)."""


@wp.struct
class Edge:
    """One end of a spring in a particle's CSR row: the other particle j, stiffness k (N/m), damping c (N s/m)."""
    j: wp.int32
    k: float
    c: float


@wp.func
def edge_kick(i: int, h: float, inv_mass: float, adj_offsets: wp.array(dtype=wp.int32), edges: wp.array(dtype=Edge),
              y: wp.array(dtype=wp.vec3), u: wp.array(dtype=wp.vec3)):
    """:func:`spring_kick` with the springs as Edge records and the particle's 1 / mass given."""
    y_i = y[i]
    f = wp.vec3(0.0)
    c = float(0.0)
    for e in range(adj_offsets[i], adj_offsets[i + 1]):
        ed = edges[e]
        f += ed.k * (y[ed.j] - y_i) + ed.c * u[ed.j]
        c += ed.c
    d = 0.5 * h * inv_mass * c
    return (u[i] * (1.0 - d) + (h * inv_mass) * f) / (1.0 + d)


@wp.func
def open_offsets(i: int, pos: wp.array2d(dtype=wp.vec3), vel_start: wp.array2d(dtype=wp.vec3),
                 vel_end: wp.array2d(dtype=wp.vec3), seg0: int, H0: float, s0: float, x: wp.array(dtype=wp.vec3),
                 v: wp.array(dtype=wp.vec3), y: wp.array(dtype=wp.vec3), u: wp.array(dtype=wp.vec3)):
    """A run's opening for particle i: its offsets y, u from its goal at the first step's start."""
    pa, pb, va, vb = segment(pos, vel_start, vel_end, seg0, i)
    y[i] = x[i] - goal_pos(pa, pb, va, vb, H0, s0)
    u[i] = v[i] - goal_vel(pa, pb, va, vb, H0, s0)


@wp.func
def set_cubic(i: int, pos: wp.array2d(dtype=wp.vec3), vel_start: wp.array2d(dtype=wp.vec3),
              vel_end: wp.array2d(dtype=wp.vec3), seg: int, H: float, cubics: wp.array(dtype=cubic)):
    """Particle i's goal cubic on knot interval seg (of length H), for all the steps in it."""
    pa, pb, va, vb = segment(pos, vel_start, vel_end, seg, i)
    c2, c3 = hermite(pa, pb, va, vb, H)
    cubics[i] = cubic(pa[0], pa[1], pa[2], va[0], va[1], va[2], c2[0], c2[1], c2[2], c3[0], c3[1], c3[2])


@wp.func
def close_velocity(i: int, K: int, params: wp.array(dtype=wp.vec3), adj_offsets: wp.array(dtype=wp.int32),
                   edges: wp.array(dtype=Edge), pos: wp.array2d(dtype=wp.vec3), vel_start: wp.array2d(dtype=wp.vec3),
                   vel_end: wp.array2d(dtype=wp.vec3), seg1: int, H1: float, s_end: float, h_end: float,
                   y_a: wp.array(dtype=wp.vec3), u_a: wp.array(dtype=wp.vec3), y_b: wp.array(dtype=wp.vec3),
                   u_b: wp.array(dtype=wp.vec3), v_out: wp.array(dtype=wp.vec3)):
    """A run of K steps' closing half kick for particle i: its velocity at the end (the offsets in buffer b after
    an odd count of steps, a after an even one)."""
    g_vel = goal_vel(pos[seg1, i], pos[seg1 + 1, i], vel_start[seg1, i], vel_end[seg1, i], H1, s_end)
    inv_m = params[i][0]
    if K % 2 == 1:
        v_out[i] = g_vel + edge_kick(i, h_end, inv_m, adj_offsets, edges, y_b, u_b)
    else:
        v_out[i] = g_vel + edge_kick(i, h_end, inv_m, adj_offsets, edges, y_a, u_a)


@wp.func
def run_step(
    lo: int, hi: int,
    # model: per particle (1 / mass, drag, reach)
    params: wp.array(dtype=wp.vec3), flows: wp.array2d(dtype=flow_row), levels: wp.array3d(dtype=flow_row), f: int,
    adj_offsets: wp.array(dtype=wp.int32), edges: wp.array(dtype=Edge), gravity: wp.vec3,
    # goals: the cubics of the step's knot interval
    cubics: wp.array(dtype=cubic), s0: float, h: float, h_kick: float,
    # offsets in (at s0)
    y: wp.array(dtype=wp.vec3), u: wp.array(dtype=wp.vec3),
    # out: frame `frame` of frames_out (none when < 0), x_out when `last`
    frame: int, last: bool,
    frames_out: wp.array2d(dtype=wp.vec3), x_out: wp.array(dtype=wp.vec3),
    y_out: wp.array(dtype=wp.vec3), u_out: wp.array(dtype=wp.vec3), stops_out: wp.array(dtype=wp.int32),
):
    """:func:`kick_drift` on the particles lo:hi with flow coefficients flows[f]: the same float32
    operations in the same order (the one-launch run equals the per-step launches bit for bit)."""
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
        fl = flows[f, i]
        y1 = fl[0] * y0 + fl[1] * u0 + fl[4] * b0 + fl[5] * b1 + fl[6] * b2
        u1 = fl[2] * y0 + fl[3] * u0 + fl[7] * b0 + fl[8] * b1 + fl[9] * b2
        stops = int(0)
        if tissue_near(y0, u0, y1, u1, h, pr[2]):
            y1, u1, stops = tissue_substeps(y0, u0, y1, u1, fl, levels, f, i, b0, b1, b2, h, pr[2])
        if stops > 0:
            stops_out[i] = stops_out[i] + stops
        if frame >= 0 or last:                      # positions only where someone reads them
            s1 = s0 + h
            x1 = pa + s1 * (va + s1 * (c2 + s1 * c3)) + y1
            if frame >= 0:
                frames_out[frame, i] = x1
            if last:
                x_out[i] = x1
        y_out[i] = y1
        u_out[i] = u1


@wp.kernel
def integrate_run(
    # model
    params: wp.array(dtype=wp.vec3), flows: wp.array2d(dtype=flow_row), levels: wp.array3d(dtype=flow_row),
    adj_offsets: wp.array(dtype=wp.int32), edges: wp.array(dtype=Edge), gravity: wp.vec3,
    group_offsets: wp.array(dtype=wp.int32),
    # goals
    pos: wp.array2d(dtype=wp.vec3), vel_start: wp.array2d(dtype=wp.vec3), vel_end: wp.array2d(dtype=wp.vec3),
    # steps (K,): knot interval, its length H, start s0 in it, length h, kick before it, flows index, frame (-1: none)
    step_seg: wp.array(dtype=wp.int32), step_H: wp.array(dtype=float), step_s0: wp.array(dtype=float),
    step_h: wp.array(dtype=float), step_kick: wp.array(dtype=float), step_flow: wp.array(dtype=wp.int32),
    step_frame: wp.array(dtype=wp.int32),
    # the closing half kick: at s_end of interval step_seg[K - 1], over h_end
    s_end: float, h_end: float,
    # state in
    x: wp.array(dtype=wp.vec3), v: wp.array(dtype=wp.vec3),
    # scratch: offsets, double-buffered; the goals' cubics on the current knot interval
    y_a: wp.array(dtype=wp.vec3), u_a: wp.array(dtype=wp.vec3), y_b: wp.array(dtype=wp.vec3),
    u_b: wp.array(dtype=wp.vec3), cubics: wp.array(dtype=cubic),
    # out
    frames_out: wp.array2d(dtype=wp.vec3), x_out: wp.array(dtype=wp.vec3), v_out: wp.array(dtype=wp.vec3),
    stops_out: wp.array(dtype=wp.int32),
):
    """All K steps of a cut-free run (:func:`offsets`, K x :func:`kick_drift`, :func:`kick`) for the
    particles of group tid (no spring leaves a group, so a group steps alone): each step reads only the
    previous step's buffers, so the result does not depend on the order of the threads. Writes the
    positions after step k to frames_out[step_frame[k]] and the state at the end to x_out, v_out."""
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
            # a new knot interval: the cubics once for all its steps
            for i in range(lo, hi):
                set_cubic(i, pos, vel_start, vel_end, seg, step_H[k], cubics)
        last = k == K - 1
        if k % 2 == 0:
            run_step(lo, hi, params, flows, levels, int(step_flow[k]), adj_offsets, edges, gravity, cubics, step_s0[k],
                     step_h[k], step_kick[k], y_a, u_a, int(step_frame[k]), last, frames_out, x_out, y_b, u_b, stops_out)
        else:
            run_step(lo, hi, params, flows, levels, int(step_flow[k]), adj_offsets, edges, gravity, cubics, step_s0[k],
                     step_h[k], step_kick[k], y_b, u_b, int(step_frame[k]), last, frames_out, x_out, y_a, u_a, stops_out)
    for i in range(lo, hi):
        close_velocity(i, K, params, adj_offsets, edges, pos, vel_start, vel_end, int(step_seg[K - 1]), step_H[K - 1],
                       s_end, h_end, y_a, u_a, y_b, u_b, v_out)
