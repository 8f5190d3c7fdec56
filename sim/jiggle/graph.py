"""A chunk's particle stepping as one device program: captured once per chunk shape as a CUDA graph, then replayed.

On a GPU the particle stage of a chunk is ~1,500 small launches (a launch per step and stage, sim/jiggle/
step_kernels.py) and the host's cost of issuing them, not the GPU's work, sets its time. :class:`ChunkGraph` does
:func:`sim.jiggle.simulate.run`'s stepping of a chunk in three phases:

1. prepare, on the host (no device reads): the step grid, the flow tables, the broad phase, the (re)starts'
   offsets (sim.jiggle.simulate.restart: from the track alone) are uploaded into the graph's own buffers
   (:class:`GraphArrays`: a buffer per call, in call order, that keeps its place while its shape does), the
   chunk's goal and capsule tracks and its start state copied in; and the chunk's device work is written down as
   a list of operations (launches, device copies, the hash grid's build under a device condition);
2. run the operations: on a CUDA device the first chunk whose operations have a given signature (every kernel,
   dim, scalar argument and buffer address: its "shape") is captured with ``wp.ScopedCapture`` and every later
   chunk of that shape replays it with ``wp.capture_launch``; elsewhere (the CPU) they are launched directly
   (``capture=True`` captures on the CPU too: Warp records a CPU graph and replays it in C++);
3. read back, once: the output frames, the contact records, the end state.

Nothing in phase 2 waits on the host: the decisions the plain path made on the host between launches are made
on the device or once per chunk:

- the tissue law's substep levels were always chosen on the device (sim/jiggle/tissue_law.py);
- the plain path read each stretch's frames and records back after its launch: here they stay on the device until
  phase 3;
- a (re)start read the glued state back to add the quasi-static offset on the host: here the offset (a function of
  the track) is uploaded in phase 1 and added on the device in float64 (graph_kernels.restart_offsets);
- the tissue contacts read the M near flags back every step to decide whether to build the hash grid: here the
  flags are reduced on the device (graph_kernels.any_flag) and the build is a conditional node
  (``wp.capture_if``; where the driver has no conditional nodes the grid is built every step: the contact kernel
  queries it only for particles in a near box, so the result is the same);
- the capsule contacts' broad phase (Colliders.active) was and is host work from the tracks, once per chunk; its
  list is padded to a power of two so that its length does not change the chunk's shape.

The counts read once per chunk stay where they were: the hard stops (ParticleSolver.hard_stops, the bake's).

Equal, bit for bit on the CPU, to the plain path: the same kernels on the same arguments in the same order (both walk
one step sequence, sim/jiggle/step_sequence.py; ParticleSolver.launch_list, StepPlan.step_ops, TissuePass.pass_ops
give the plain path's launches and these operations from one list). tests/jiggle/test_graph.py runs both, with contacts and the tissue law, over chunks, and
checks that the operations read nothing back and that two chunks of one shape give one signature (one capture).
The keyed solver (sim/jiggle/keyed_solver.py) runs the plain path.
"""
from __future__ import annotations

import warnings
from collections import OrderedDict

import numpy as np
import warp as wp

from jiggle.sim.jiggle import graph_kernels
from jiggle.sim.jiggle.goal_track import GoalControl
from jiggle.sim.jiggle.step_sequence import step_sequence

MAX_GRAPHS = 8
"""Captured graphs kept per solver (the chunks of a bake have two or three shapes: the first, the others, the last)."""


class GraphArrays:
    """The graph's per-chunk device buffers, one per call in call order since :meth:`begin`: a call gets the buffer
    of its place when its shape and dtype are the same as last chunk's (its contents replaced), a new one when not;
    so two chunks of one shape use the same buffers and a graph captured on one replays for the other. The same
    calls as sim.jiggle.solver.FreshArrays."""

    def __init__(self, device):
        self.device = device
        self._slots: list[wp.array] = []
        self._i = 0

    def begin(self) -> None:
        self._i = 0

    def _slot(self, shape: tuple, dtype) -> wp.array:
        dtype = {float: wp.float32, int: wp.int32, bool: wp.bool}.get(dtype, dtype)   # as wp.array names them
        i, self._i = self._i, self._i + 1
        if i < len(self._slots):
            a = self._slots[i]
            if a.shape == shape and a.dtype == dtype:
                return a
        a = wp.empty(shape, dtype=dtype, device=self.device)
        if i < len(self._slots):
            self._slots[i] = a
        else:
            self._slots.append(a)
        return a

    def upload(self, a, dtype, pad: bool = False) -> wp.array:
        """The host array `a` in this place's buffer (pad: its first axis to the next power of two, zeros after)."""
        a = np.ascontiguousarray(a)
        dtype = {float: wp.float32, int: wp.int32, bool: wp.bool}.get(dtype, dtype)
        inner = len(getattr(dtype, "_shape_", ()))
        shape = a.shape[:a.ndim - inner] if inner else a.shape
        if pad:
            cap = 1 << max(int(shape[0]) - 1, 0).bit_length()
            if cap != shape[0]:
                a = np.concatenate([a, np.zeros((cap - shape[0],) + a.shape[1:], a.dtype)])
            shape = (cap,) + tuple(shape[1:])
        out = self._slot(tuple(int(n) for n in shape), dtype)
        out.assign(a)
        return out

    def empty(self, shape, dtype) -> wp.array:
        shape = (int(shape),) if np.isscalar(shape) else tuple(int(n) for n in shape)
        return self._slot(shape, dtype)

    def zeros(self, shape, dtype) -> wp.array:
        out = self.empty(shape, dtype)
        out.zero_()
        return out

    def copy_in(self, a: wp.array) -> wp.array:
        """A device array's contents in this place's buffer (a device copy)."""
        out = self._slot(tuple(a.shape), a.dtype)
        wp.copy(out, a)
        return out


def _sig(a):
    """An operation argument's part of the chunk's signature: what a captured graph holds of it."""
    if isinstance(a, wp.array):
        return ("a", a.ptr, a.shape, a.dtype.__name__ if hasattr(a.dtype, "__name__") else str(a.dtype))
    if isinstance(a, wp.HashGrid):
        return ("grid", a.id)
    if isinstance(a, (float, np.floating)):
        return ("f", float(np.float32(a)))
    if isinstance(a, (bool, int, np.integer)):
        return ("i", int(a))
    if isinstance(a, list):
        return tuple(signature(a))
    return ("v", tuple(np.asarray(a, dtype=np.float64).reshape(-1).tolist()))


def signature(ops: list) -> list:
    """The operations' signature: equal for two chunks exactly when one's captured graph replays the other."""
    out = []
    for op in ops:
        if op[0] == "launch":
            out.append(("launch", op[1].key, int(op[2]), tuple(_sig(a) for a in op[3])))
        else:
            out.append((op[0],) + tuple(_sig(a) for a in op[1:]))
    return out


class ChunkGraph:
    """Steps the chunks of one ParticleSolver as device programs (the module docstring).

    capture : None (default): capture and replay graphs on a CUDA device, launch directly on the CPU; True: capture
        on any device (a CPU graph on the CPU, as the tests do); False: launch directly.

    Counters: :attr:`captures` graphs captured, :attr:`replays` chunks that replayed one, :attr:`direct` chunks
    launched directly; :attr:`last_ops` the last chunk's operations.
    """

    def __init__(self, solver, capture: bool | None = None, max_graphs: int = MAX_GRAPHS):
        self.solver = solver
        m = solver.model
        self.device = wp.get_device(m.device)
        self.capture = (not self.device.is_cpu) if capture is None else bool(capture)
        self.conditional = self.device.is_cpu or wp.is_conditional_graph_supported()
        self.max_graphs = max_graphs
        self.arrays = GraphArrays(m.device)
        self.graphs: OrderedDict = OrderedDict()
        self.captures = self.replays = self.direct = 0
        self.last_ops: list = []
        self.states = (m.state(), m.state())
        self._glued = wp.array(np.asarray(m.glued, np.int32), dtype=wp.int32, device=m.device)
        self._any = wp.zeros(1, dtype=wp.int32, device=m.device)
        self._reserved = set()

    @staticmethod
    def supports(solver) -> bool:
        """Whether the graph steps this solver's runs: a plain ParticleSolver (the keyed one runs the plain path)."""
        from jiggle.sim.jiggle.solver import ParticleSolver
        return type(solver) is ParticleSolver and solver.model.num_particles > 0

    # ------------------------------------------------------------------------------------------ phase 1
    def prepare(self, track, control, grid: np.ndarray, out_times: np.ndarray, wanted: np.ndarray, is_out: np.ndarray,
                start, colliders=None, tissue=None, offsets=None):
        """The chunk's operations and where its outputs land: (ops, outputs, end_state). start : ("given", (x, v))
        float32 arrays, ("rest",) the bind pose at rest (a preroll), or ("restart", t0); outputs : (device array,
        rows (R,) of it, output frames (R,), kind "x" or "records"); end_state : the ParticleState holding the end.
        offsets(t) -> (y, vel) (N, 3) float64: a (re)start's quasi-static offsets and the goals' velocities at t
        (sim.jiggle.simulate.start_offsets)."""
        self._offsets = offsets
        from jiggle.sim.jiggle.colliders import Colliders
        s, m, A = self.solver, self.solver.model, self.arrays
        A.begin()
        ctrl = GoalControl(track, A.copy_in(control.pos), A.copy_in(control.vel_start), A.copy_in(control.vel_end))
        cols = None
        if colliders is not None:
            cc = colliders.control
            cols = Colliders(colliders.model, GoalControl(cc.track, A.copy_in(cc.pos), A.copy_in(cc.vel_start),
                                                          A.copy_in(cc.vel_end)))
        state, nxt = self.states
        ops, outputs = [], []
        N = m.num_particles
        for kind, g, e, ks in step_sequence(track, grid, is_out):   # the plain path (simulate.run) walks it too
            if kind == "stretch":
                if tissue is None or not tissue.any_pairs:
                    plan = s.run_plan(state, nxt, ctrl, grid[g:e + 1], record=ks, colliders=cols, arrays=A)
                    ops += [("launch", *op) for op in s.launch_list(plan.kernel, plan.K, plan.frame, plan.args)]
                    if len(ks):
                        outputs.append((plan.frames, np.arange(len(ks)), wanted[g + ks], "x"))
                        if plan.records is not None:
                            outputs.append((plan.records, np.arange(len(ks)), wanted[g + ks], "records"))
                else:
                    frames, recs = self._tissue_ops(ops, state, nxt, ctrl, grid[g:e + 1], ks, cols, tissue)
                    if len(ks):
                        outputs.append((frames, np.arange(len(ks)), wanted[g + ks], "x"))
                        outputs.append((recs, np.arange(len(ks)), wanted[g + ks], "records"))
                state, nxt = nxt, state
                continue
            if kind == "glue":
                ops.append(("launch", *s.glue_launch(state, ctrl, grid[e])))
            elif kind == "restart":                    # the cut's far side: a fresh start there
                ops += self._restart_ops(state, ctrl, grid[e])
            elif start[0] == "given":                  # the start
                state.assign(*start[1])
            elif start[0] == "rest":
                state.assign(m.rest, np.zeros_like(m.rest))
            else:
                ops += self._restart_ops(state, ctrl, start[1])
            if len(ks):                                # the state at grid[e] is an output frame
                row = A.empty((1, N), wp.vec3)
                ops.append(("copy", row, state.x, 0, 0, N))
                outputs.append((row, np.zeros(1, np.int64), wanted[e:e + 1], "x"))
        if not self.conditional:                       # no conditional nodes: the grid built every step
            ops = [o for op in ops for o in (op[2] if op[0] == "if" else [op])]
        return ops, outputs, state

    def _restart_ops(self, state, ctrl, t: float) -> list:
        """sim.jiggle.simulate.restart on the device: the glue launch, then the offsets (from the track, uploaded)."""
        m = self.solver.model
        y, vel = self._offsets(t)
        A = self.arrays
        return [("launch", *self.solver.glue_launch(state, ctrl, t)),
                ("launch", graph_kernels.restart_offsets, m.num_particles,
                 [self._glued, A.upload(np.asarray(y, np.float64), wp.vec3d),
                  A.upload(np.asarray(vel, np.float64), wp.vec3d), state.x, state.v])]

    def _tissue_ops(self, ops: list, state_in, state_out, ctrl, grid: np.ndarray, ks: np.ndarray, cols, tissue):
        """sim.jiggle.tissue_contacts.integrate_tissue's steps as operations appended to ops: each step (a step plan's
        row copies and launch, or the plain run over the step), its contact pass (TissuePass.pass_ops), the recorded
        steps' positions and records copied into (max(R, 1), N) device arrays, returned."""
        from jiggle.sim.jiggle.solver import StepPlan
        from jiggle.sim.jiggle.tissue_contacts import _check, _scratch
        s, m, A = self.solver, self.solver.model, self.arrays
        _check(m, tissue)
        N, K = m.num_particles, len(grid) - 1
        sc = _scratch(s, tissue)
        tp = sc.pass_
        if tp.grid.id not in self._reserved:               # the grid's buffers made before any capture
            tp.grid.reserve(N)
            self._reserved.add(tp.grid.id)
        recorded = np.zeros(K + 1, bool)
        recorded[ks] = True
        hit_base = float((cols.model.num_capsules if cols is not None else 0) + 1)
        if cols is None and not sc.caps_clean:
            tp.caps.assign(tp.none)
        sc.caps_clean = cols is None
        plan = StepPlan(s, ctrl, grid, cols, arrays=A) if cols is not None else None
        caps = plan.record if plan is not None and plan.kernel is not None else tp.caps
        frames = A.empty((max(len(ks), 1), N), wp.vec3)
        recs = A.empty((max(len(ks), 1), N), wp.vec3)
        src, fresh, r = state_in, True, 0
        for k in range(K):
            if plan is not None:
                ops += plan.step_ops(k, src, sc.step)
            else:
                p = s.run_plan(src, sc.step, ctrl, grid[k:k + 2], record=None, colliders=None, arrays=A)
                ops += [("launch", *op) for op in s.launch_list(p.kernel, p.K, p.frame, p.args)]
            ops += tp.pass_ops(m.wp_inv_mass, sc.step.x, sc.step.v, fresh, hit_base, state_out.x, state_out.v, caps,
                               self._any)
            fresh = False
            if recorded[k + 1]:
                ops.append(("copy", frames, state_out.x, r * N, 0, N))
                ops.append(("copy", recs, tp.acc, r * N, 0, N))
                r += 1
                fresh = True
            src = state_out
        return frames, recs

    # ------------------------------------------------------------------------------------------ phase 2
    def execute(self, ops: list) -> None:
        """Issue the operations on the device, in order (what a capture records)."""
        dev = self.device
        for op in ops:
            kind = op[0]
            if kind == "launch":
                wp.launch(op[1], dim=op[2], inputs=op[3], device=dev)
            elif kind == "copy":
                wp.copy(op[1], op[2], dest_offset=op[3], src_offset=op[4], count=op[5])
            elif kind == "grid":
                op[1].build(op[2], op[3])
            elif kind == "if":
                wp.capture_if(op[1], on_true=lambda body=op[2]: self.execute(body))
            else:
                raise ValueError(f"unknown graph operation {kind!r}")

    def launch(self, ops: list) -> None:
        """Run the chunk's operations: replay the graph captured for their signature, or capture it (capture on),
        or launch them directly."""
        self.last_ops = ops
        self.solver.launches += sum(1 for op in ops if op[0] == "launch")
        if not self.capture:
            self.execute(ops)
            self.direct += 1
            return
        key = tuple(signature(ops))
        graph = self.graphs.get(key)
        if graph is None:
            try:
                with wp.ScopedCapture(device=self.device) as cap:
                    self.execute(ops)
            except Exception as e:  # noqa: BLE001 - a capture that fails leaves the plain launches, which are right
                warnings.warn(f"the chunk graph could not be captured ({type(e).__name__}: {e}); launching directly",
                              RuntimeWarning, stacklevel=2)
                self.capture = False
                self.execute(ops)
                self.direct += 1
                return
            graph = self.graphs[key] = cap.graph
            self.captures += 1
            while len(self.graphs) > self.max_graphs:
                self.graphs.popitem(last=False)
        else:
            self.graphs.move_to_end(key)
            self.replays += 1
        wp.capture_launch(graph)

    # ------------------------------------------------------------------------------------------ all three
    def run(self, track, control, grid, out_times, wanted, is_out, start, colliders=None, tissue=None, offsets=None):
        """A chunk's stepping (sim.jiggle.simulate.run's loop): (positions (T, N, 3) float32 at out_times,
        contact records (T, N, 3) float32 (zeros and -1 where none), end state (x, v) (N, 3) float32)."""
        ops, outputs, end = self.prepare(track, control, np.asarray(grid, np.float64), out_times, wanted, is_out,
                                         start, colliders, tissue, offsets)
        self.launch(ops)
        # phase 3: read back once (the first read waits for the chunk; the rest are copies)
        T, N = len(out_times), self.solver.model.num_particles
        frames = np.zeros((T, N, 3), np.float32)
        records = np.zeros((T, N, 3), np.float32)
        records[..., 2] = -1.0
        for array, rows, at, kind in outputs:
            (frames if kind == "x" else records)[at] = array.numpy()[rows]
        return frames, records, (end.x.numpy().copy(), end.v.numpy().copy())
