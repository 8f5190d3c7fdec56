"""The particle solver: ``step(state_in, state_out, control, t, dt)`` and ``integrate`` over many steps.

A step of length h from time t (it must lie inside one knot interval of the goal track):

1. half kick of the neighbour springs (on the offsets) at t;
2. exact flow of every particle's goal spring, damping, friction, gravity and the goal's own motion
   over h (sim/jiggle/goal_flow.py): exact for any h, so the goal springs are never the reason to take
   small steps, however stiff (goal weights near 1) or however long the frame; then each offset is
   held within its particle's reach (an inelastic stop: projected onto the sphere, the outward offset
   velocity dropped);
3. half kick of the springs at t + h.

This is the splitting of the impulse (r-RESPA) family with an exact inner flow: symmetric and, for
undamped springs, second order in h and the velocity Verlet method when there are no goals (momentum
conserved to round-off, energy bounded). In a kick the stiffness and the neighbours' velocities are
explicit and each particle's own velocity in its dampers is trapezoidal,
``u' = (u (1 - d) + h/m (F_k + sum c_ij u_j)) / (1 + d)``, ``d = h sum c_ij / (2 m)``: a particle's own
damping never overshoots, and the error left is first order in the damping between neighbours
(measured: 1.1% of the peak jiggle at h = 1/120 s on the simple arm, against 1.4% fully explicit).
The explicit kicks are stable for omega h < 2 with omega the springs' fastest frequency;
:meth:`ParticleSolver.max_step` keeps omega h and the damping rate times h <= 0.5, and sim/jiggle/secondary.py
splits steps to it. :meth:`ParticleSolver.integrate` merges each closing half kick with the next
opening one (one launch per step).
"""
from __future__ import annotations

import math

import numpy as np
import warp as wp

from rig.base.errors import InputError
from sim.jiggle import particle_kernels as kernels
from sim.jiggle.goal_flow import flow_numpy, goal_flow
from sim.jiggle.goal_track import GoalControl, GoalTrack, hermite
from sim.jiggle.particles import ParticleModel, ParticleState

STEP_OMEGA = 0.5
"""Largest omega h (and gamma h) of the neighbour springs in one step; stability ends at 2."""


def _check_step(track: GoalTrack, t: float, dt: float) -> tuple[int, float, float]:
    """(interval j, s0 = t - times[j], H) for a step [t, t + dt] inside one knot interval."""
    if not (isinstance(dt, (int, float, np.floating)) and math.isfinite(dt) and dt > 0):
        raise InputError(f"the time step must be a finite number > 0 s, got {dt!r}", field="dt")
    if not math.isfinite(t):
        raise InputError(f"the step's time must be finite, got {t!r}", field="t")
    j = track.interval(t + 0.5 * dt)
    t0, t1 = track.times[j], track.times[j + 1]
    H = t1 - t0
    eps = 1e-9 * max(1.0, abs(t1))
    if t < t0 - eps or t + dt > t1 + eps:
        raise InputError(f"the step [{t:.6f}, {t + dt:.6f}] s must lie inside one knot interval of the goal track "
                         f"([{t0:.6f}, {t1:.6f}] s)", field="dt")
    return j, t - t0, H


class ParticleSolver:
    """Steps a ParticleModel; owns only scratch buffers and the exact-flow coefficients per step length."""

    def __init__(self, model: ParticleModel):
        self.model = model
        self._flows: dict[float, tuple[np.ndarray, wp.array]] = {}
        n, dev = model.num_particles, model.device
        self._y = [wp.zeros(n, dtype=wp.vec3, device=dev) for _ in range(2)]
        self._u = [wp.zeros(n, dtype=wp.vec3, device=dev) for _ in range(2)]
        self._recorded: dict[str, tuple] = {}
        self._gravity = wp.vec3(*model.gravity_vector.astype(np.float32))
        omega, gamma = model.spring_rate_bound()
        self.max_step = min(STEP_OMEGA / omega if omega > 0 else math.inf,
                            STEP_OMEGA / gamma if gamma > 0 else math.inf)
        """seconds: the longest step the spring kicks take (inf without springs)."""

    def flow(self, h: float) -> tuple[np.ndarray, wp.array]:
        """Exact goal-flow coefficients (N, 10) for step h: float64 NumPy and float32 device copies."""
        key = round(float(h), 12)
        if key not in self._flows:
            if len(self._flows) > 64:          # uneven steps (odd frame rates): keep the cache small
                self._flows.clear()
            c = goal_flow(self.model.goal_k, self.model.goal_c + self.model.drag, key)
            self._flows[key] = (c, wp.array(c.astype(np.float32), dtype=float, device=self.model.device))
        return self._flows[key]

    def step(self, state_in: ParticleState, state_out: ParticleState, control: GoalControl, t: float,
             dt: float) -> None:
        """Advance state_in at time t by dt seconds into state_out (two different states)."""
        self.integrate(state_in, state_out, control, np.array([t, t + dt]))

    def integrate(self, state_in: ParticleState, state_out: ParticleState, control: GoalControl,
                  grid: np.ndarray, on_step=None) -> None:
        """Advance state_in from grid[0] through the steps between the times grid (K + 1,) into state_out.

        Like K calls of :meth:`step`, but each step's closing half kick is merged with the next step's
        opening one into one kick at the same positions (equal to K steps without spring damping; with
        it the merged kick sees the velocity before both halves, a difference of the order of the
        damping error): one launch per step, plus one to form the offsets and one to close. The NumPy
        reference is :func:`integrate_numpy`. on_step(k, x) is called after step k (1..K) with the
        positions at grid[k] (a device array, valid until the next step).
        """
        m = self.model
        grid = np.asarray(grid, dtype=np.float64)
        if m.num_particles == 0 or len(grid) < 2:
            return
        track = control.track
        steps = [_check_step(track, float(a), float(b - a)) for a, b in zip(grid[:-1], grid[1:])]
        dts = np.diff(grid)
        Y, (U, U_pre) = list(self._y), self._u
        seg, s0, H = steps[0]
        self._run(kernels.offsets, [control.pos, control.vel_start, control.vel_end, seg, float(H), float(s0),
                                    state_in.x, state_in.v, Y[0], U])
        h_kick = 0.5 * dts[0]
        for k, ((seg, s0, H), h) in enumerate(zip(steps, dts)):
            _, flow = self.flow(h)
            # offsets (Y[0], U) at s0 -> (Y[1], U_pre) at s0 + h; U is free again after this launch
            self._run(kernels.kick_drift, [m.wp_inv_mass, m.wp_drag, m.wp_reach, flow, m.wp_adj_offsets,
                                           m.wp_adj_index,
                                           m.wp_adj_k, m.wp_adj_c, self._gravity, control.pos, control.vel_start,
                                           control.vel_end, seg, float(H), float(s0), float(h), float(h_kick),
                                           Y[0], U, state_out.x, Y[1], U_pre])
            Y.reverse()
            U, U_pre = U_pre, U
            if on_step is not None:
                on_step(k + 1, state_out.x)
            h_kick = 0.5 * h + (0.5 * dts[k + 1] if k + 1 < len(dts) else 0.0)
        seg, s0, H = steps[-1]
        self._run(kernels.kick, [m.wp_inv_mass, m.wp_adj_offsets, m.wp_adj_index, m.wp_adj_k, m.wp_adj_c,
                                 control.pos, control.vel_start, control.vel_end, seg, float(H), float(s0 + dts[-1]),
                                 float(0.5 * dts[-1]), Y[0], U, state_out.v])

    def _run(self, kernel, args: list) -> None:
        """Launch `kernel` over the particles with `args` (inputs then outputs). The launch is recorded
        once and only the arguments that changed since the last step are packed again (packing all
        of them costs more than the kernel on a small model)."""
        rec = self._recorded.get(kernel.key)
        if rec is None:
            blocks = (self.model.num_particles + kernels.BLOCK_SIZE - 1) // kernels.BLOCK_SIZE
            launch = wp.launch(kernel, dim=blocks, inputs=args, device=self.model.device, record_cmd=True)
            self._recorded[kernel.key] = rec = (launch, list(args))
        else:
            launch, last = rec
            for i, a in enumerate(args):
                if a is not last[i] and not (type(a) in (int, float) and a == last[i]):
                    launch.set_param_at_index(i, a)
                    last[i] = a
        rec[0].launch()

    def glue(self, state: ParticleState, control: GoalControl, t: float) -> None:
        """Put every particle on its goal at time t, moving with it (a reset at a cut or a start)."""
        m = self.model
        if m.num_particles == 0:
            return
        track = control.track
        j = track.interval(t)
        wp.launch(kernels.glue, dim=m.num_particles, device=m.device,
                  inputs=[control.pos, control.vel_start, control.vel_end, j, float(track.times[j + 1] - track.times[j]),
                          float(t - track.times[j])],
                  outputs=[state.x, state.v])


# ---------------------------------------------------------------------------------- NumPy reference
def spring_force_numpy(model: ParticleModel, y: np.ndarray, u: np.ndarray) -> np.ndarray:
    """(N, 3) newtons: sum over each particle's springs of k (y_j - y_i) + c (u_j - u_i)."""
    f = np.zeros_like(y)
    if model.num_springs:
        i, j = model.springs[:, 0], model.springs[:, 1]
        fij = model.spring_k[:, None] * (y[j] - y[i]) + model.spring_c[:, None] * (u[j] - u[i])
        np.add.at(f, i, fij)
        np.add.at(f, j, -fij)
    return f


def kick_numpy(model: ParticleModel, y: np.ndarray, u: np.ndarray, h: float) -> np.ndarray:
    """(N, 3) offset velocities after a spring kick over h (the kernels' spring_kick):
    u' = (u (1 - d) + h / m (F + c_sum u)) / (1 + d), d = h c_sum / (2 m), F the spring force."""
    inv_m = np.where(model.glued, 0.0, 1.0 / model.mass)
    csum = np.bincount(model.springs.reshape(-1), weights=np.repeat(model.spring_c, 2),
                       minlength=model.num_particles) if model.num_springs else np.zeros(model.num_particles)
    d = (0.5 * h * inv_m * csum)[:, None]
    f = spring_force_numpy(model, y, u) + csum[:, None] * u          # the explicit part: F without -c_sum u_i
    return (u * (1.0 - d) + h * inv_m[:, None] * f) / (1.0 + d)


def within_reach_numpy(reach: np.ndarray, y: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The kernels' within_reach: offsets y (N, 3) beyond reach (N,) projected onto it, their outward
    offset velocity u dropped."""
    n = np.linalg.norm(y, axis=1)
    over = n > reach
    if not over.any():
        return y, u
    d = y[over] / n[over, None]
    out = np.maximum(np.sum(u[over] * d, axis=1), 0.0)
    y, u = y.copy(), u.copy()
    y[over] = d * reach[over, None]
    u[over] -= out[:, None] * d
    return y, u


def integrate_numpy(model: ParticleModel, flow, track: GoalTrack, x: np.ndarray, v: np.ndarray,
                    grid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The NumPy reference of ParticleSolver.integrate in float64 (merged kicks between steps):
    (x, v) (N, 3) at grid[-1] from x, v at grid[0]. flow(h) -> (N, 10) goal_flow coefficients."""
    grid = np.asarray(grid, dtype=np.float64)
    dts = np.diff(grid)
    steps = [_check_step(track, float(a), float(b - a)) for a, b in zip(grid[:-1], grid[1:])]
    mu = model.drag[:, None]

    def goal(j, s):
        return hermite(track.pos[j], track.pos[j + 1], track.vel_start[j], track.vel_end[j],
                       track.times[j + 1] - track.times[j], s)

    j, s0, _ = steps[0]
    g, gv, _, _ = goal(j, s0)
    y, u = x - g, v - gv
    h_kick = 0.5 * dts[0]
    for k, ((j, s0, _), h) in enumerate(zip(steps, dts)):
        _, gv, gacc, gjerk = goal(j, s0)
        u = kick_numpy(model, y, u, h_kick)
        b0 = model.gravity_vector - gacc - mu * gv
        b1 = -gjerk - mu * gacc
        b2 = -0.5 * mu * gjerk
        y, u = within_reach_numpy(model.reach, *flow_numpy(flow(h), y, u, b0, b1, b2))
        h_kick = 0.5 * h + (0.5 * dts[k + 1] if k + 1 < len(dts) else 0.0)
    j, s0, _ = steps[-1]
    g1, gv1, _, _ = goal(j, s0 + dts[-1])
    u = kick_numpy(model, y, u, 0.5 * dts[-1])
    return g1 + y, gv1 + u


def step_numpy(model: ParticleModel, flow: np.ndarray, track: GoalTrack, x: np.ndarray, v: np.ndarray,
               t: float, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """The NumPy reference of ParticleSolver.step in float64: (x, v) (N, 3) at t + dt.
    flow : (N, 10) goal_flow coefficients for dt."""
    return integrate_numpy(model, lambda h: flow, track, x, v, np.array([t, t + dt]))
