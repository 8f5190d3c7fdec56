"""The particle solver: ``step(state_in, state_out, control, t, dt)`` and ``integrate`` over many steps.

A step of length h from time t (it must lie inside one knot interval of the goal track):

1. half kick of the neighbour springs (on the offsets) at t;
2. exact flow of every particle's goal spring, damping, friction, gravity and the goal's own motion
   over h (sim/jiggle/goal_flow.py): exact for any h, so the goal springs are never the reason to take
   small steps, however stiff (goal weights near 1) or however long the frame; a particle past half its
   reach, where the tissue law stiffens the goal spring (sim/jiggle/tissue_law.py), takes this part in
   2^j substeps of its own, each the stiffening's half kicks around the exact flow over h / 2^j;
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
opening one and takes a whole run of steps in one launch, a thread per group of particles that no spring
leaves (a muscle) looping over the steps; :meth:`ParticleSolver.integrate_steps` does the same arithmetic
with one launch per step.
"""
from __future__ import annotations

import math
import os

import numpy as np
import warp as wp

from jiggle.rig.base.errors import InputError
from jiggle.sim.jiggle import particle_kernels as kernels
from jiggle.sim.jiggle import tissue_law
from jiggle.sim.jiggle.goal_track import GoalControl, GoalTrack, hermite
from jiggle.sim.jiggle.particles import ParticleModel, ParticleState

NO_FLOOR = -1.0e30
"""metres: the floor height of colliders without a floor (no float32 position is below it)."""
GRAPHS_ENV = "JIGGLE_GRAPHS"
"""Environment variable: "0" turns the chunk graph (sim/jiggle/graph.py) off: a CUDA solver takes the plain path."""
STEP_OMEGA = 0.5
"""Largest omega h (and gamma h) of the neighbour springs in one step; stability ends at 2."""


def _check_steps(track: GoalTrack, grid: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(seg, s0, H), each (K,): knot interval j (int64), s0 = t - times[j] and its length H (float64
    seconds) of each step [grid[k], grid[k + 1]], which must lie inside one knot interval."""
    grid = np.asarray(grid, dtype=np.float64)
    t, dt = grid[:-1], np.diff(grid)
    bad = ~(np.isfinite(dt) & (dt > 0))
    if bad.any():
        raise InputError(f"the time step must be a finite number > 0 s, got {float(dt[bad][0])!r}", field="dt")
    if not np.isfinite(t).all():
        raise InputError(f"the step's time must be finite, got {float(t[~np.isfinite(t)][0])!r}", field="t")
    j = track.intervals(t + 0.5 * dt)
    t0, t1 = track.times[j], track.times[j + 1]
    eps = 1e-9 * np.maximum(1.0, np.abs(t1))
    out = (t < t0 - eps) | (t + dt > t1 + eps)
    if out.any():
        k = int(np.flatnonzero(out)[0])
        raise InputError(f"the step [{t[k]:.6f}, {t[k] + dt[k]:.6f}] s must lie inside one knot interval of the goal "
                         f"track ([{t0[k]:.6f}, {t1[k]:.6f}] s)", field="dt")
    return j, t - t0, t1 - t0


def thread_groups(model: ParticleModel) -> np.ndarray:
    """(G + 1,) int64 particle offsets of the groups a one-launch run steps apart: the model's groups (the
    muscles), merged wherever a spring joins two of them (a group's particles then only ever read each
    other); a model whose springs cross every boundary is one group."""
    n = model.num_particles
    b = np.asarray(model.group_offsets, dtype=np.int64)
    b = np.unique(np.concatenate([[0, n], b[(b > 0) & (b < n)]]))
    if model.num_springs:
        span = np.zeros(n + 1, np.int64)          # cumsum: springs (i < j) with i < b <= j, across boundary b
        np.add.at(span, model.springs.min(axis=1) + 1, 1)
        np.add.at(span, model.springs.max(axis=1) + 1, -1)
        b = b[np.cumsum(span)[b] == 0]
    return b


class FreshArrays:
    """Where a run's per-call device arrays come from on the plain path: new ones each call. The chunk graph
    (sim/jiggle/graph.py: GraphArrays) gives the same calls buffers that keep their place from chunk to chunk."""

    def __init__(self, device):
        self.device = device

    def upload(self, a, dtype, pad: bool = False) -> wp.array:
        """A device copy of the host array `a` (pad: the graph's may be longer, zero-filled, for a list whose
        length varies from chunk to chunk and that the kernels index through offsets)."""
        return wp.array(np.ascontiguousarray(a), dtype=dtype, device=self.device)

    def empty(self, shape, dtype) -> wp.array:
        return wp.empty(shape, dtype=dtype, device=self.device)

    def zeros(self, shape, dtype) -> wp.array:
        return wp.zeros(shape, dtype=dtype, device=self.device)


class RunPlan:
    """A run of steps prepared on the device, not launched (ParticleSolver.run_plan): its kernel, K steps,
    each step's recorded frame (K,) int32 (-1: none), the kernel's arguments, and its outputs on the device:
    frames (max(R, 1), N) vec3 and, with colliders, records (max(R, 1), N) vec3; R recorded steps."""

    __slots__ = ("kernel", "K", "frame", "args", "frames", "records", "R")

    def __init__(self, kernel, K, frame, args, frames, records, R):
        self.kernel, self.K, self.frame, self.args = kernel, K, frame, args
        self.frames, self.records, self.R = frames, records, R


class ParticleSolver:
    """Steps a ParticleModel; owns only scratch buffers and the exact-flow coefficients per step length."""

    def __init__(self, model: ParticleModel):
        self.model = model
        self._flows: dict[float, tuple[np.ndarray, wp.array]] = {}
        n, dev = model.num_particles, model.device
        self._y = [wp.zeros(n, dtype=wp.vec3, device=dev) for _ in range(2)]
        self._u = [wp.zeros(n, dtype=wp.vec3, device=dev) for _ in range(2)]
        self._cubics = wp.zeros(n, dtype=kernels.cubic, device=dev)
        # the run kernel's packed model: (1 / mass, drag, reach) per particle, the springs as Edge records
        self._params = wp.array(np.stack([a.numpy() for a in (model.wp_inv_mass, model.wp_drag, model.wp_reach)],
                                         axis=1), dtype=wp.vec3, device=dev)
        edges = np.zeros(len(model.adj_index), dtype=kernels.Edge.numpy_dtype())
        for name, a in (("j", model.wp_adj_index), ("k", model.wp_adj_k), ("c", model.wp_adj_c)):
            edges[name] = a.numpy()
        self._edges = wp.array(edges, dtype=kernels.Edge, device=dev)
        self._recorded: dict[str, tuple] = {}
        self._contact_scratch: dict = {}
        self._fixed = None
        self.contact_records = np.zeros((0, model.num_particles, 3), np.float32)
        """(R, N, 3) float32: the contact records of the recorded steps of the last :meth:`integrate` with
        colliders."""
        self._tables: dict[tuple, wp.array] = {}
        groups = thread_groups(model)
        self.num_groups = len(groups) - 1
        """threads of a one-launch run (:meth:`integrate`): groups of particles no spring leaves."""
        self._groups = wp.array(groups.astype(np.int32), dtype=wp.int32, device=dev)
        self.stops = wp.zeros(n, dtype=wp.int32, device=dev)
        """(N,) int32 on the device: each particle's hard stops since it was made or zeroed (sim/jiggle/tissue_law.py:
        substeps that end near the reach with the outward speed more than halved from a fast start; the tissue law
        makes none)."""
        self.stepwise = not wp.get_device(dev).is_cpu
        """Runs launch a step at a time, a thread per particle (sim/jiggle/step_kernels.py): on a GPU, where a
        thread per group (the one-launch run) leaves it nearly idle; equal to the one-launch run (bit for bit
        on the CPU, where the one-launch run is the faster)."""
        self._extras = None
        self.launches = 0
        """kernel launches so far: every one (glue, the runs of :meth:`integrate`, the steps of
        :meth:`integrate_steps`)."""
        self._gravity = wp.vec3(*model.gravity_vector.astype(np.float32))
        omega, gamma = model.spring_rate_bound()
        self.max_step = min(STEP_OMEGA / omega if omega > 0 else math.inf,
                            STEP_OMEGA / gamma if gamma > 0 else math.inf)
        """seconds: the longest step the spring kicks take (inf without springs)."""
        self.graph = None
        """None, or the sim.jiggle.graph.ChunkGraph that steps a chunk of sim.jiggle.simulate.run as one device
        program (captured once per chunk shape as a CUDA graph and replayed); sim.jiggle.simulate.run makes it on
        its first chunk where :attr:`use_graph`."""
        self.use_graph = type(self) is ParticleSolver and not wp.get_device(dev).is_cpu and \
            os.environ.get(GRAPHS_ENV, "1") != "0"
        """Whether runs make and use the chunk graph: a plain solver on a CUDA device unless JIGGLE_GRAPHS=0; on the
        CPU the launches as they are (the keyed solver: always)."""

    def flow(self, h: float) -> tuple[np.ndarray, tuple[wp.array, wp.array]]:
        """Tissue rows (N, tissue_law.ROW) float64 for step h (sim.jiggle.tissue_law.rows: the exact goal flow over
        h, kappa, the flows over h / 2^j), and their float32 device copies as the kernels read them: the flows
        over h (N,) and the levels (1, LEVELS + 1, N) (sim.jiggle.tissue_law.split)."""
        key = round(float(h), 12)
        if key not in self._flows:
            if len(self._flows) > 64:          # uneven steps (odd frame rates): keep the cache small
                self._flows.clear()
            c = tissue_law.rows(self.model.goal_k, self.model.goal_c + self.model.drag, key)
            lin, lev = tissue_law.split(c)
            dev = self.model.device
            self._flows[key] = (c, (wp.array(lin, dtype=kernels.flow_row, device=dev),
                                    wp.array(lev[None], dtype=kernels.flow_row, device=dev)))
        return self._flows[key]

    def step(self, state_in: ParticleState, state_out: ParticleState, control: GoalControl, t: float,
             dt: float) -> None:
        """Advance state_in at time t by dt seconds into state_out (two different states)."""
        self.integrate(state_in, state_out, control, np.array([t, t + dt]))

    def _flow_table(self, dts: np.ndarray) -> tuple[list, np.ndarray]:
        """The tissue rows of the distinct step lengths among dts (K,) seconds on the device, [flows (F, N),
        levels (F, LEVELS + 1, N)] of flow rows (float32, as :meth:`flow` gives them), and each step's index
        f in them (K,) int32."""
        uniq, inverse = np.unique(dts, return_inverse=True)
        keys = [round(float(h), 12) for h in uniq]                 # flow()'s key: lengths equal to 1e-12 s share it
        index = {k: f for f, k in enumerate(dict.fromkeys(keys))}
        table_key = tuple(index)
        table = self._tables.get(table_key)
        if table is None:
            if len(self._tables) > 16:
                self._tables.clear()
            lin, lev = tissue_law.split(np.stack([self.flow(k)[0] for k in table_key]))      # (F, N, ..)
            dev = self.model.device
            table = self._tables[table_key] = [
                wp.array(lin, dtype=kernels.flow_row, device=dev),
                wp.array(lev, dtype=kernels.flow_row, device=dev)]
        return table, np.array([index[k] for k in keys], dtype=np.int32)[inverse.reshape(-1)]

    def _run_steps(self, control: GoalControl, grid: np.ndarray, record, arrays=None):
        """What a run of the steps `grid` (K + 1,) needs on the host: (ks, seg, s0, H, dts, h_kick, frame,
        frames, dev_array); or its result when there is nothing to step (None, or zero frames (R, N, 3)).
        InputError for recorded steps that are not increasing indices in 1..K. arrays : where the device
        arrays come from (FreshArrays: new ones; the chunk graph's keep their place)."""
        m, dev = self.model, self.model.device
        arrays = arrays or FreshArrays(dev)
        grid = np.asarray(grid, dtype=np.float64)
        ks = np.zeros(0, np.int64) if record is None else np.asarray(record, dtype=np.int64).reshape(-1)
        K = len(grid) - 1
        if len(ks) and (ks.min() < 1 or ks.max() > K or np.any(np.diff(ks) <= 0)):
            raise InputError(f"recorded steps must be increasing indices in 1..{K}, got {ks.tolist()}", field="record")
        if m.num_particles == 0 or K < 1:
            return None if record is None else np.zeros((len(ks), m.num_particles, 3), np.float32)
        seg, s0, H = _check_steps(control.track, grid)
        dts = np.diff(grid)
        # the kick before step k: its own opening half, plus the previous step's closing half
        h_kick = 0.5 * dts
        h_kick[1:] += 0.5 * dts[:-1]
        frame = np.full(K, -1, np.int32)
        frame[ks - 1] = np.arange(len(ks), dtype=np.int32)
        frames = arrays.empty((max(len(ks), 1), m.num_particles), wp.vec3)
        return ks, seg, s0, H, dts, h_kick, frame, frames, arrays.upload

    def integrate(self, state_in: ParticleState, state_out: ParticleState, control: GoalControl,
                  grid: np.ndarray, record=None, colliders=None) -> np.ndarray | None:
        """Advance state_in from grid[0] through the steps between the times grid (K + 1,) into state_out,
        in one launch; returns the positions (R, N, 3) float32 metres after the steps `record` (R,)
        (indices 1..K of grid, increasing), read back once, or None when record is None.

        Like K calls of :meth:`step`, but each step's closing half kick is merged with the next step's
        opening one into one kick at the same positions (equal to K steps without spring damping; with
        it the merged kick sees the velocity before both halves, a difference of the order of the
        damping error). Equal bit for bit to :meth:`integrate_steps` (one launch per step). The NumPy
        reference is :func:`integrate_numpy`.

        colliders : None, or sim.jiggle.colliders.Colliders on the goal track's knots: the particles then
            collide with its capsules and floor after every step (sim/jiggle/contact_kernels.py; the
            NumPy reference is :func:`sim.jiggle.colliders.integrate_contact_numpy`), and
            :attr:`contact_records` holds each recorded step's (R, N, 3) float32 contact records (depth m,
            impulse N s, hit id; see sim.jiggle.colliders.muscle_contacts). Where nothing touches, the
            positions are those of a run without colliders bit for bit.
        """
        plan = self.run_plan(state_in, state_out, control, grid, record, colliders)
        if not isinstance(plan, RunPlan):
            return plan
        self._run_or_step(plan.kernel, plan.K, plan.frame, plan.args)
        if plan.records is not None:
            self.contact_records = plan.records.numpy()[:plan.R]
        if record is None:
            return None
        return plan.frames.numpy()[:plan.R] if plan.R else np.zeros((0, self.model.num_particles, 3), np.float32)

    def run_plan(self, state_in: ParticleState, state_out: ParticleState, control: GoalControl, grid: np.ndarray,
                 record=None, colliders=None, arrays=None):
        """The run :meth:`integrate` launches, prepared on the device and not launched (a :class:`RunPlan`; its
        launches are :meth:`launch_list`), or integrate's result where there is nothing to step. arrays : where
        its device arrays come from (None: new ones; sim.jiggle.graph.GraphArrays: the chunk graph's buffers)."""
        m = self.model
        run = self._run_steps(control, grid, record, arrays)
        if isinstance(run, np.ndarray) or run is None:
            return run
        ks, seg, s0, H, dts, h_kick, frame, frames, dev_array = run
        table, flow_index = self._flow_table(dts)
        Y, U = self._y, self._u
        if colliders is not None:
            kernel, args, records = self._integrate_contact(
                state_in, state_out, control, colliders, seg, s0, H, dts, h_kick, table,
                dev_array(flow_index, wp.int32), frame, frames, ks, dev_array, plan=True, arrays=arrays, records=True)
            return RunPlan(kernel, len(seg), frame, args, frames, records, len(ks))
        args = [
            self._params, *table, m.wp_adj_offsets, self._edges, self._gravity, self._groups,
            control.pos, control.vel_start, control.vel_end,
            dev_array(seg.astype(np.int32), wp.int32), dev_array(H.astype(np.float32), float),
            dev_array(s0.astype(np.float32), float), dev_array(dts.astype(np.float32), float),
            dev_array(h_kick.astype(np.float32), float), dev_array(flow_index, wp.int32), dev_array(frame, wp.int32),
            float(s0[-1] + dts[-1]), float(0.5 * dts[-1]), state_in.x, state_in.v, Y[0], U[0], Y[1], U[1],
            self._cubics, frames, state_out.x, state_out.v, self.stops]
        return RunPlan(kernels.integrate_run, len(seg), frame, args, frames, None, len(ks))

    def hard_stops(self) -> np.ndarray:
        """(N,) int64: each particle's hard stops counted in :attr:`stops`."""
        return self.stops.numpy().astype(np.int64)

    def _contact_flows(self, control: GoalControl, seg: np.ndarray, dts: np.ndarray, dev_array):
        """(flows, step_flow, kernel) of a run with contacts: the kernel's flow arguments, each step's index into
        them on the device, the run kernel (the keyed solver gives its own, sim/jiggle/keyed_solver.py)."""
        from jiggle.sim.jiggle import contact_kernels as ck
        table, flow_index = self._flow_table(dts)
        return table, dev_array(flow_index, wp.int32), ck.integrate_run_contact

    def step_plan(self, control: GoalControl, grid: np.ndarray, colliders) -> "StepPlan":
        """The steps grid (K + 1,) of a cut-free stretch with `colliders` prepared once on the device (the same
        arrays :meth:`integrate` would upload), to be launched one step at a time (:class:`StepPlan`): what a
        pass between steps needs (sim/jiggle/tissue_contacts.py) without the host work of K calls of
        :meth:`integrate`. A step equals :meth:`integrate` over that one step bit for bit."""
        return StepPlan(self, control, grid, colliders)

    def _integrate_contact(self, state_in, state_out, control, colliders, seg, s0, H, dts, h_kick, flows,
                           step_flow, frame, frames, ks, dev_array, kernel=None, plan: bool = False, arrays=None,
                           records: bool = False):
        """:meth:`integrate` with contacts (the integrate_run_contact kernel, the broad phase from
        sim.jiggle.colliders.Colliders.active). flows : the kernel's flow arguments after the packed
        model ([flows, levels], or the keyed rows, levels and reaches); step_flow : each step's device index into them
        (K,), or the keyed row bases (K, G); kernel : None for integrate_run_contact, or the keyed one
        (sim/jiggle/keyed_kernels.py). plan : return (kernel, args, record) without launching (StepPlan; with
        `records`, the frames' records array in place of the step's record: ParticleSolver.run_plan). arrays :
        None, or the chunk graph's buffers (sim.jiggle.graph.GraphArrays): the broad phase's lists and the
        capsules' ends in them (padded: their length varies from chunk to chunk), not in the solver's cache."""
        from jiggle.sim.jiggle import contact_kernels as ck
        m, dev, cm = self.model, self.model.device, colliders.model
        if colliders.control.track.num_knots != control.track.num_knots or \
                np.any(colliders.control.track.times != control.track.times):
            raise InputError("the colliders' track must have the goal track's knots", field="colliders")
        if len(cm.pair_offsets) != len(m.group_offsets):
            raise InputError(f"the colliders are for {len(cm.pair_offsets) - 1} muscles, the model has "
                             f"{len(m.group_offsets) - 1}", field="colliders")
        key = (id(colliders), id(control.track))
        if arrays is not None:
            offsets, ids = colliders.active(m, control.track)
            act_offsets = arrays.upload(offsets, wp.int32)
            act_ids = arrays.upload(ids if len(ids) else np.zeros(1, np.int32), wp.int32, pad=True)
            A = act_ids.shape[0]
            ends = [arrays.zeros(A, wp.vec3) for _ in range(4)]
        elif self._contact_scratch.get("key") != key:
            offsets, ids = colliders.active(m, control.track)
            A = max(len(ids), 1)
            self._contact_scratch = {
                "key": key, "hold": (colliders, control.track),
                "active": (dev_array(offsets, wp.int32), dev_array(ids if len(ids) else np.zeros(1, np.int32), wp.int32)),
                "ends": [wp.zeros(A, dtype=wp.vec3, device=dev) for _ in range(4)]}
        if arrays is None:
            sc = self._contact_scratch
            act_offsets, act_ids = sc["active"]
            ends = sc["ends"]
        record, dirty, group_muscles, muscle_offsets = self._fixed_contact_scratch()
        ea, eb, eva, evb = ends
        none = np.zeros((max(len(ks), 1), m.num_particles, 3), np.float32)
        none[..., 2] = ck.NO_HIT
        records_out = (arrays or FreshArrays(dev)).upload(none, wp.vec3)
        cc = colliders.control
        floor = cm.floor if cm.floor is not None else NO_FLOOR
        Y, U = self._y, self._u
        args = [
            self._params, *flows, m.wp_adj_offsets, self._edges, self._gravity, self._groups, group_muscles,
            self.stops, muscle_offsets, cm.wp_radius, float(floor), float(cm.friction), int(cm.num_capsules),
            int(len(m.group_offsets) - 1), act_offsets, act_ids,
            control.pos, control.vel_start, control.vel_end, cc.pos, cc.vel_start, cc.vel_end,
            dev_array(seg.astype(np.int32), wp.int32), dev_array(H.astype(np.float32), float),
            dev_array(s0.astype(np.float32), float), dev_array(dts.astype(np.float32), float),
            dev_array(h_kick.astype(np.float32), float), step_flow, dev_array(frame, wp.int32),
            float(s0[-1] + dts[-1]), float(0.5 * dts[-1]), *_xv(state_in), Y[0], U[0], Y[1], U[1],
            self._cubics, ea, eb, eva, evb, record, dirty, frames, records_out, *_xv(state_out)]
        if plan:
            return kernel or ck.integrate_run_contact, args, records_out if records else record
        self._run_or_step(kernel or ck.integrate_run_contact, len(seg), frame, args)
        self.contact_records = records_out.numpy()[:len(ks)]
        return frames.numpy()[:len(ks)] if len(ks) else np.zeros((0, m.num_particles, 3), np.float32)

    def _fixed_contact_scratch(self) -> tuple:
        """The contact runs' scratch that does not depend on the run (made once per solver): each particle's record
        (N,) vec3, each muscle's dirty flag (M,) int32, each thread group's first muscle (G + 1,) int32 and the
        muscles' particle offsets (M + 1,) int32."""
        if self._fixed is None:
            m, dev = self.model, self.model.device
            groups = self._groups.numpy()
            self._fixed = (wp.zeros(m.num_particles, dtype=wp.vec3, device=dev),
                           wp.zeros(len(m.group_offsets) - 1, dtype=wp.int32, device=dev),
                           wp.array(np.searchsorted(m.group_offsets, groups).astype(np.int32), dtype=wp.int32,
                                    device=dev),
                           wp.array(m.group_offsets.astype(np.int32), dtype=wp.int32, device=dev))
        return self._fixed

    def integrate_steps(self, state_in: ParticleState, state_out: ParticleState, control: GoalControl,
                        grid: np.ndarray, on_step=None) -> None:
        """:meth:`integrate` with one launch per step (plus one to form the offsets and one to close):
        the reference the one-launch run equals bit for bit, and the way to see every step on the device.
        on_step(k, x) is called after step k (1..K) with the positions at grid[k] (a device array, valid
        until the next step)."""
        m = self.model
        grid = np.asarray(grid, dtype=np.float64)
        if m.num_particles == 0 or len(grid) < 2:
            return
        seg_k, s0_k, H_k = _check_steps(control.track, grid)
        steps = list(zip(seg_k.tolist(), s0_k.tolist(), H_k.tolist()))
        dts = np.diff(grid)
        Y, (U, U_pre) = list(self._y), self._u
        dim = (m.num_particles + kernels.BLOCK_SIZE - 1) // kernels.BLOCK_SIZE
        seg, s0, H = steps[0]
        self._run(kernels.offsets, dim, [control.pos, control.vel_start, control.vel_end, seg, float(H), float(s0),
                                         state_in.x, state_in.v, Y[0], U])
        h_kick = 0.5 * dts[0]
        for k, ((seg, s0, H), h) in enumerate(zip(steps, dts)):
            _, (flow, levels) = self.flow(h)
            # offsets (Y[0], U) at s0 -> (Y[1], U_pre) at s0 + h; U is free again after this launch
            self._run(kernels.kick_drift, dim, [m.wp_inv_mass, m.wp_drag, m.wp_reach, flow, levels, m.wp_adj_offsets,
                                                m.wp_adj_index, m.wp_adj_k, m.wp_adj_c, self._gravity, control.pos,
                                                control.vel_start, control.vel_end, seg, float(H), float(s0),
                                                float(h), float(h_kick), Y[0], U, state_out.x, Y[1], U_pre,
                                                self.stops])
            Y.reverse()
            U, U_pre = U_pre, U
            if on_step is not None:
                on_step(k + 1, state_out.x)
            h_kick = 0.5 * h + (0.5 * dts[k + 1] if k + 1 < len(dts) else 0.0)
        seg, s0, H = steps[-1]
        self._run(kernels.kick, dim, [m.wp_inv_mass, m.wp_adj_offsets, m.wp_adj_index, m.wp_adj_k, m.wp_adj_c,
                                      control.pos, control.vel_start, control.vel_end, seg, float(H),
                                      float(s0 + dts[-1]), float(0.5 * dts[-1]), Y[0], U, state_out.v])

    def _run_or_step(self, kernel, K: int, frame: np.ndarray, args: list) -> None:
        """A one-launch run over `args` (K steps; frame (K,) each step's recorded frame or -1): in one launch, or
        a launch per step where :attr:`stepwise` (the plain and contact runs; the keyed solver's own kernels
        always run in one)."""
        from jiggle.sim.jiggle import contact_kernels as ck
        if self.stepwise and kernel in (kernels.integrate_run, ck.integrate_run_contact):
            self._run_stepwise(kernel, K, args, frame)
        else:
            self._run(kernel, self.num_groups, args)

    def launch_list(self, kernel, K: int, frame: np.ndarray, args: list) -> list:
        """The launches of a one-launch run (`kernel` over `args`, K steps; frame (K,) each step's recorded frame or
        -1), in order, as (kernel, dim, args): the one launch, a thread per group; or where :attr:`stepwise` (the plain
        and contact runs) a launch per step, a thread per particle (and per muscle for the contacts):
        sim/jiggle/step_kernels.py, the GPU's way, each step kernel with its step index first. What
        :meth:`_run_or_step` launches and what the chunk graph (sim/jiggle/graph.py) captures: one list."""
        from jiggle.sim.jiggle import contact_kernels as ck
        from jiggle.sim.jiggle import step_kernels as sk
        if not (self.stepwise and kernel in (kernels.integrate_run, ck.integrate_run_contact)):
            return [(kernel, self.num_groups, args)]
        m = self.model
        N, M = m.num_particles, len(m.group_offsets) - 1
        if kernel is kernels.integrate_run:
            opening, steps, closing = [(sk.run_open, N)], [(sk.run_one, N)], (sk.run_close, N)
        else:
            opening = [(sk.contact_open, N), (sk.contact_clear, M)]
            steps = [(sk.contact_one, N), (sk.contact_gather, M), (sk.contact_each, N)]
            closing = (sk.contact_close, N)
        extra = self._contact_extras() if kernel is ck.integrate_run_contact else []
        wide = {sk.contact_gather.key, sk.contact_each.key, sk.contact_flush.key}

        def op(kern, n: int, k: int) -> tuple:
            return kern, n, [k, *args, *(extra if kern.key in wide else [])]
        out = [op(kern, n, 0) for kern, n in opening if n > 0]
        recorded_steps = np.asarray(frame) >= 0
        for k in range(K):
            out += [op(kern, n, k) for kern, n in steps if n > 0]
            if extra and N > 0 and recorded_steps[k]:
                out.append(op(sk.contact_flush, N, k))
        if N > 0:
            out.append(op(closing[0], N, 0))
        return out

    def _run_stepwise(self, kernel, K: int, args: list, frame: np.ndarray) -> None:
        """A one-launch run (kernels.integrate_run or contact_kernels.integrate_run_contact over `args`) as a
        launch per step (:meth:`launch_list`), a thread per particle (and per muscle for the contacts):
        sim/jiggle/step_kernels.py, the GPU's way (:attr:`stepwise`). Each kernel is recorded once per run and
        only its step index set between launches."""
        recorded = {}
        ops = self.launch_list(kernel, K, frame, args)
        for kern, n, a in ops:
            launch = recorded.get(kern.key)
            if launch is None:
                launch = recorded[kern.key] = wp.launch(kern, dim=n, inputs=a, device=self.model.device,
                                                        record_cmd=True)
            else:
                launch.set_param_at_index(0, a[0])
            launch.launch()
        self.launches += len(ops)

    def _contact_extras(self) -> list:
        """The per-particle contact kernels' own arrays: per muscle the shared union box and floor, per particle
        its muscle (made once per solver)."""
        if self._extras is None:
            m, dev = self.model, self.model.device
            M = len(m.group_offsets) - 1
            owner = np.repeat(np.arange(M, dtype=np.int32), np.diff(np.asarray(m.group_offsets)))
            self._extras = [wp.zeros(max(M, 1), dtype=wp.vec3, device=dev), wp.zeros(max(M, 1), dtype=wp.vec3, device=dev),
                            wp.zeros(max(M, 1), dtype=float, device=dev),
                            wp.array(owner if len(owner) else np.zeros(1, np.int32), dtype=wp.int32, device=dev)]
        return self._extras

    def _run(self, kernel, dim: int, args: list) -> None:
        """Launch `kernel` over `dim` threads with `args` (inputs then outputs). The launch is recorded
        once and only the arguments that changed since the last call are packed again (packing all
        of them costs more than the kernel on a small model)."""
        recorded_launch(self._recorded, kernel, dim, args, self.model.device)
        self.launches += 1

    def glue(self, state: ParticleState, control: GoalControl, t: float) -> None:
        """Put every particle on its goal at time t, moving with it (a reset at a cut or a start)."""
        m = self.model
        if m.num_particles == 0:
            return
        self.launches += 1
        kernel, dim, args = self.glue_launch(state, control, t)
        wp.launch(kernel, dim=dim, device=m.device, inputs=args)

    def glue_launch(self, state: ParticleState, control: GoalControl, t: float) -> tuple:
        """:meth:`glue`'s launch as (kernel, dim, args), not launched (the chunk graph's, sim/jiggle/graph.py)."""
        track = control.track
        j = track.interval(t)
        return kernels.glue, self.model.num_particles, [
            control.pos, control.vel_start, control.vel_end, j, float(track.times[j + 1] - track.times[j]),
            float(t - track.times[j]), state.x, state.v]


def recorded_launch(recorded: dict, kernel, dim: int, args: list, device) -> None:
    """Launch `kernel` over `dim` threads with `args` (inputs then outputs), recorded in `recorded` (by
    kernel) the first time; later only the arguments that changed since the last call are packed again
    (packing all of them costs more than the kernel on a small model)."""
    rec = recorded.get(kernel.key)
    if rec is None:
        launch = wp.launch(kernel, dim=dim, inputs=args, device=device, record_cmd=True)
        recorded[kernel.key] = rec = (launch, list(args))
    else:
        launch, last = rec
        for i, a in enumerate(args):
            if a is not last[i] and not (type(a) in (int, float) and a == last[i]):
                launch.set_param_at_index(i, a)
                last[i] = a
    rec[0].launch()


def _xv(state) -> tuple:
    """(x, v) of a ParticleState; (None, None) while a StepPlan is built (each step sets its states)."""
    return (None, None) if state is None else (state.x, state.v)


class StepPlan:
    """A cut-free stretch of steps with colliders, prepared once (ParticleSolver.step_plan): the run kernel's
    arguments for all K steps on the device; :meth:`step` launches step k alone, its arrays views of those.

    A launch over one step opens with its own half kick and closes with its own (the steps' kicks are not
    merged, as K calls of ParticleSolver.step), and equals ParticleSolver.integrate over [grid[k],
    grid[k + 1]] bit for bit. After a step, :attr:`record` (N,) vec3 holds each particle's capsule / floor
    contact of that step (depth m, impulse N s, hit id; -1 none) on the device."""

    # indices of the per-step arguments in the contact kernels' argument lists, counted from the end
    _STEPS = 26                      # step_seg .. step_frame (7), s_end, h_end, x, v, then 15 scratch and outputs
    _X_IN, _V_IN = -17, -16
    _X_OUT, _V_OUT = -2, -1

    def __init__(self, solver: ParticleSolver, control: GoalControl, grid: np.ndarray, colliders, arrays=None):
        self.solver = solver
        grid = np.asarray(grid, dtype=np.float64)
        self.K = len(grid) - 1
        run = solver._run_steps(control, grid, None, arrays)
        if run is None:
            self.kernel = None
            return
        ks, seg, s0, H, dts, h_kick, frame, frames, dev_array = run
        flows, step_flow, kernel = solver._contact_flows(control, seg, dts, dev_array)
        # one step a launch: each opens with its own half kick; no frames written (state_out holds the positions)
        opening = (0.5 * dts).astype(np.float32)
        self.kernel, self.args, self.record = solver._integrate_contact(
            None, None, control, colliders, seg, s0, H, dts, opening, flows, step_flow,
            np.full(len(dts), -1, np.int32), frames, ks, dev_array, kernel=kernel, plan=True, arrays=arrays)
        first = len(self.args) - self._STEPS
        self._first = first
        full = self.args[first:first + 7]                            # seg, H, s0, h, kick, flow, frame (K, ...)
        # the launch reads one-step arrays, filled per step: on the CPU through their NumPy views (a wp.array
        # view per step and argument costs ~25 us of Python), elsewhere by a device copy of the step's row
        self._full = full
        self._one = [(arrays.empty if arrays is not None else
                      lambda shape, dtype, d=a.device: wp.empty(shape, dtype=dtype, device=d))((1,) + tuple(a.shape[1:]),
                                                                                               a.dtype) for a in full]
        # the chunk graph's plan (arrays given) copies on the device everywhere: its steps are replayed launches
        self._cpu = arrays is None and all(a.device.is_cpu for a in full)
        if self._cpu:
            self._host = [a.numpy() for a in full]
            self._views = [o.numpy() for o in self._one]
        for i, o in enumerate(self._one):
            self.args[first + i] = o
        self._ends = [(float(a + h), float(0.5 * h)) for a, h in zip(s0, dts)]

    def step(self, k: int, state_in, state_out) -> None:
        """Step k (0..K - 1) from state_in into state_out (two different ParticleStates), one launch."""
        if self.kernel is None:
            return
        if self._cpu:
            for view, host in zip(self._views, self._host):
                view[0] = host[k]
        else:
            for one, a in zip(self._one, self._full):
                row = one.size
                wp.copy(one, a, src_offset=k * row, count=row)
        self.solver._run(self.kernel, self.solver.num_groups, self._step_args(k, state_in, state_out))

    def _step_args(self, k: int, state_in, state_out) -> list:
        args = self.args
        f = self._first
        args[f + 7], args[f + 8] = self._ends[k]
        args[self._X_IN], args[self._V_IN] = state_in.x, state_in.v
        args[self._X_OUT], args[self._V_OUT] = state_out.x, state_out.v
        return args

    def step_ops(self, k: int, state_in, state_out) -> list:
        """Step k as the chunk graph's operations (sim/jiggle/graph.py), not run: the copies of its row of each
        step array on the device, then its launch: [("copy", dst, src, dst_offset, src_offset, count), ...,
        ("launch", kernel, dim, args)]. Equal to :meth:`step` (a plan made with the graph's arrays)."""
        if self.kernel is None:
            return []
        ops = [("copy", one, a, 0, k * one.size, one.size) for one, a in zip(self._one, self._full)]
        return ops + [("launch", self.kernel, self.solver.num_groups, list(self._step_args(k, state_in, state_out)))]


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


def integrate_numpy(model: ParticleModel, flow, track: GoalTrack, x: np.ndarray, v: np.ndarray,
                    grid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The NumPy reference of ParticleSolver.integrate in float64 (merged kicks between steps):
    (x, v) (N, 3) at grid[-1] from x, v at grid[0]. flow(h) -> (N, tissue_law.ROW) tissue flow rows
    (ParticleSolver.flow(h)[0]); the goal part of each step is sim.jiggle.tissue_law.step_numpy."""
    grid = np.asarray(grid, dtype=np.float64)
    dts = np.diff(grid)
    steps = list(zip(*(a.tolist() for a in _check_steps(track, grid))))
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
        y, u, _ = tissue_law.step_numpy(flow(h), y, u, b0, b1, b2, h, np.asarray(model.reach, dtype=np.float64))
        h_kick = 0.5 * h + (0.5 * dts[k + 1] if k + 1 < len(dts) else 0.0)
    j, s0, _ = steps[-1]
    g1, gv1, _, _ = goal(j, s0 + dts[-1])
    u = kick_numpy(model, y, u, 0.5 * dts[-1])
    return g1 + y, gv1 + u


def step_numpy(model: ParticleModel, flow: np.ndarray, track: GoalTrack, x: np.ndarray, v: np.ndarray,
               t: float, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """The NumPy reference of ParticleSolver.step in float64: (x, v) (N, 3) at t + dt.
    flow : (N, tissue_law.ROW) tissue flow rows for dt."""
    return integrate_numpy(model, lambda h: flow, track, x, v, np.array([t, t + dt]))
