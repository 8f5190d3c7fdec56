"""The particle solver with keyed goal springs (sim/jiggle/keyed.py): ParticleSolver whose one-launch run reads
each step's goal flow and reach for its knot interval (sim/jiggle/keyed_kernels.py). A model with no keyed
muscle runs ParticleSolver's own integrate, so an unkeyed bake is unchanged bit for bit and in speed.

Cost: one 5x5 matrix exponential per distinct (stiffness, damping, step length) of the keyed particles over a
run (sim.jiggle.goal_flow.goal_flow_batch, vectorised), those rows uploaded once per run with an index from each
(knot interval, particle) to its row. With colliders the run is keyed_kernels.integrate_run_contact_keyed (the contacts of
sim/jiggle/contact_kernels.py after each step; the broad phase uses the model's reach, that of the largest
strength key, so it never misses a keyed muscle's reach).
"""
from __future__ import annotations

import numpy as np
import warp as wp

from jiggle.rig.base.errors import InputError
from jiggle.sim.jiggle import keyed_kernels
from jiggle.sim.jiggle import particle_kernels as kernels
from jiggle.sim.jiggle import tissue_law
from jiggle.sim.jiggle.goal_track import hermite
from jiggle.sim.jiggle.keyed import Schedule
from jiggle.sim.jiggle.solver import ParticleSolver, _check_steps, kick_numpy


class KeyedSolver(ParticleSolver):
    """ParticleSolver for a model whose muscles' goal springs may be keyed.

    model : the ParticleModel, built from the reference values (sim.jiggle.keyed.reference_values).
    jiggles : one MuscleJiggle per muscle of the model (numbers or sim.jiggle.keyed.Curve).
    """

    def __init__(self, model, jiggles):
        super().__init__(model)
        self.schedule = Schedule(model, jiggles, self._groups.numpy())
        self._plain_reach = np.minimum(np.asarray(model.reach, dtype=np.float64), np.finfo(np.float32).max)

    def model_at(self, t: float):
        """The model with the keyed goal springs at time t (for a start's or a restart's equilibrium)."""
        return self.schedule.model_at(t)

    def integrate(self, state_in, state_out, control, grid, record=None, colliders=None):
        """ParticleSolver.integrate with each step's goal springs those of its knot interval."""
        if self.schedule.empty:
            return super().integrate(state_in, state_out, control, grid, record=record, colliders=colliders)
        m = self.model
        run = self._run_steps(control, grid, record)
        if isinstance(run, np.ndarray) or run is None:
            return run
        ks, seg, s0, H, dts, h_kick, frame, frames, dev_array = run
        rows, levels, reach, base, index = self._rows(control.track.times, seg, dts)
        if colliders is not None:
            out = self._integrate_contact(state_in, state_out, control, colliders, seg, s0, H, dts, h_kick,
                                          [dev_array(rows, kernels.flow_row), dev_array(levels, kernels.flow_row),
                                           dev_array(reach, float), dev_array(index, wp.int32)],
                                          dev_array(base, wp.int32), frame, frames, ks, dev_array,
                                          kernel=keyed_kernels.integrate_run_contact_keyed)
            return None if record is None else out
        Y, U = self._y, self._u
        self._run(keyed_kernels.integrate_run_keyed, self.num_groups, [
            self._params, dev_array(rows, kernels.flow_row), dev_array(levels, kernels.flow_row),
            dev_array(reach, float), dev_array(index, wp.int32), m.wp_adj_offsets, self._edges,
            self._gravity, self._groups, self.stops, control.pos, control.vel_start, control.vel_end,
            dev_array(seg.astype(np.int32), wp.int32), dev_array(H.astype(np.float32), float),
            dev_array(s0.astype(np.float32), float), dev_array(dts.astype(np.float32), float),
            dev_array(h_kick.astype(np.float32), float), dev_array(base, wp.int32), dev_array(frame, wp.int32),
            float(s0[-1] + dts[-1]), float(0.5 * dts[-1]), state_in.x, state_in.v, Y[0], U[0], Y[1], U[1],
            self._cubics, frames, state_out.x, state_out.v])
        return None if record is None else frames.numpy()[:len(ks)]

    def _contact_flows(self, control, seg: np.ndarray, dts: np.ndarray, dev_array):
        """ParticleSolver._contact_flows with each step's goal springs those of its knot interval."""
        if self.schedule.empty:
            return super()._contact_flows(control, seg, dts, dev_array)
        rows, levels, reach, base, index = self._rows(control.track.times, seg, dts)
        return ([dev_array(rows, kernels.flow_row), dev_array(levels, kernels.flow_row), dev_array(reach, float),
                 dev_array(index, wp.int32)],
                dev_array(base, wp.int32),
                keyed_kernels.integrate_run_contact_keyed)

    def _rows(self, times: np.ndarray, seg: np.ndarray, dts: np.ndarray):
        """(rows (R, 10) float32, levels (1, tissue_law.LEVELS + 1, R, 10) float32, reach (E,) float32, base (K, G)
        int32, index (E,) int32) of a run (rows and levels: sim.jiggle.tissue_law.split of the tissue rows): the
        entries are the plain flow table's (one block of N per distinct step length, as ParticleSolver.integrate's)
        then the keyed blocks (one of P per distinct (knot interval, step length), sim.jiggle.keyed.Schedule.flows);
        entry e's row is rows[index[e]] (the plain table's N rows a step length, then one per distinct keyed
        triple) and its reach reach[e]; the entries of thread group g at step k start at base[k, g] (minus the
        group's first particle)."""
        m, sc = self.model, self.schedule
        N, G = m.num_particles, self.num_groups
        uniq, inverse = np.unique(np.round(dts, 12), return_inverse=True)
        plain = np.stack([self.flow(float(h))[0] for h in uniq])                           # (F, N, 10)
        coeffs, rows_of, kreach, block = sc.flows(times, seg, dts)                          # (U, ROW), (B, P)
        F, B, P = len(uniq), len(rows_of), len(sc.particles)
        rows, levels = tissue_law.split(np.concatenate([plain.reshape(F * N, -1), coeffs]))
        levels = levels[None]                                                             # (1, L + 1, R, 10)
        reach = np.concatenate([np.tile(self._plain_reach, F),
                                np.minimum(kreach, np.finfo(np.float32).max).reshape(-1)]).astype(np.float32)
        index = np.concatenate([np.arange(F * N), F * N + rows_of.reshape(-1)])
        base = np.repeat((inverse.reshape(-1) * N)[:, None], G, axis=1).astype(np.int64)   # (K, G)
        to = sc.thread_offsets
        for tg, start in zip(sc.keyed_threads, sc.thread_start):
            base[:, tg] = F * N + block * P + start - to[tg]
        if len(index) >= 2 ** 31:
            raise InputError("a keyed run needs more flow rows than a launch can index; use a smaller --chunk",
                             field="chunk")
        return rows, levels, reach, base.astype(np.int32), index.astype(np.int32)


def make_solver(model, jiggles) -> ParticleSolver:
    """The solver of a model built from `jiggles` (one MuscleJiggle per muscle): a KeyedSolver when any
    muscle's goal springs are keyed, else the plain ParticleSolver."""
    if any(getattr(j, "keyed", None) for j in jiggles):
        return KeyedSolver(model, jiggles)
    return ParticleSolver(model)


def integrate_keyed_numpy(model, schedule: Schedule, track, x: np.ndarray, v: np.ndarray,
                          grid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The NumPy reference of the keyed one-launch run (sim.jiggle.solver.integrate_numpy with each step's
    goal flow and reach those of its knot interval): (x, v) (N, 3) float64 at grid[-1] from x, v at grid[0]."""
    grid = np.asarray(grid, dtype=np.float64)
    dts = np.diff(grid)
    seg, s0s, _ = _check_steps(track, grid)
    coeffs, rows_of, reaches, block = schedule.flows(track.times, seg, dts)
    mu = model.drag[:, None]
    p = schedule.particles

    def goal(j, s):
        return hermite(track.pos[j], track.pos[j + 1], track.vel_start[j], track.vel_end[j],
                       track.times[j + 1] - track.times[j], s)

    g, gv, _, _ = goal(seg[0], s0s[0])
    y, u = x - g, v - gv
    h_kick = 0.5 * dts[0]
    for k in range(len(dts)):
        j, s0, h = int(seg[k]), float(s0s[k]), float(dts[k])
        _, gv, gacc, gjerk = goal(j, s0)
        u = kick_numpy(model, y, u, h_kick)
        fl = tissue_law.rows(model.goal_k, model.goal_c + model.drag, round(h, 12))
        fl[p] = coeffs[rows_of[block[k]]]
        reach = np.array(model.reach, dtype=np.float64)
        reach[p] = reaches[block[k]]
        b0 = model.gravity_vector - gacc - mu * gv
        b1 = -gjerk - mu * gacc
        b2 = -0.5 * mu * gjerk
        y, u, _ = tissue_law.step_numpy(fl, y, u, b0, b1, b2, h, reach)
        h_kick = 0.5 * h + (0.5 * dts[k + 1] if k + 1 < len(dts) else 0.0)
    g1, gv1, _, _ = goal(seg[-1], s0s[-1] + dts[-1])
    u = kick_numpy(model, y, u, 0.5 * dts[-1])
    return g1 + y, gv1 + u
