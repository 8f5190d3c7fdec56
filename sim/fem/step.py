"""One goal-driven solid's time step, shared by the reference (sim.fem.solve.simulate_part) and the hero mode
(sim.fem.tissue.FemTissue): Newton's SolverVBD with jiggle's per-step additions, and a step that would leave a tet
near inside out redone in halves.

A step ending at time t, h seconds long (the order both solvers have always used):
1. every vertex's goal at t (the attached vertices are put there inside VBD's forward step, after it has recorded
   their start: _goal_vbd; sim/fem/solve.py says why);
2. with rest "goal", every tet's rest shape set to its goal shape at t (fem_kernels.rest_poses);
3. every tet's moduli stiffened for its distortion at the step's start (fem_kernels.stiffen, lagged a step);
4. VBD's step (its own iterations, damping, backward Euler);
5. the Rayleigh damping's mass-proportional part on the free vertices (fem_kernels.goal_drag);
6. contacts, when given (the hero mode's capsules and floor: fem_kernels.keep_out).

Then the step is checked: the smallest det F over the tets against their rest shape (the goal's, rest "goal") at its
end. Below DET_FLOOR the state is put back as it was before the step and the step is taken again as two half steps,
each checked the same way, down to a step 2^-MAX_SPLITS of the original. Why this is (nearly always) enough: VBD runs
a fixed count of local (per-vertex) Newton iterations on backward Euler's incremental potential, and the lagged strain
stiffening and the stable Neo-Hookean's volume term only resist a collapse they see coming within the step; on a hard
landing the goal (the bone-attached core) moves several millimetres in a 0.5 ms step, and the free flesh beside it,
held back by its inertia, is squeezed past J = 0 before an iteration can push back. A shorter step moves the goal less
per solve and lets the stiffening (updated every step) catch up, so the solve stays on the barrier's side of the
potential.

Where even the shortest step ends below the floor (a sliver of a folded part's mesh, a 0.5 mm edge against 10 mm ones,
whose free corner the flesh around it pushes through: CesiumMan's right pectoral on CMU 05_02's leaps), the step ends
with a line search toward the goal: the free vertices of the tets below the floor are drawn back along their offset
from their goal, as little as does it (DRAW_BACK), until every tet they touch is at the floor or above (on the goal a
tet is its own rest shape, det F 1), the set growing to the next ring of tets while one stays below, and after
LOCAL_RINGS rings to the whole mesh of the part (det F is continuous in the draw-back, and 1 on the goal). So no kept
step ends below the floor (rest "goal"). bake.json and the reference's tables report the smallest det F, the steps
redone and the steps line-searched with the vertices moved; an output frame with an inverted tet is never written
silently (sim.bake.baker._warn_inverted).

A run with no redone step is exactly the run without the check (the check only reads the state)."""
from __future__ import annotations

import numpy as np

DET_FLOOR = 0.25
"""The smallest det F (a tet's volume over its goal shape's) a step may end with before it is redone in halves: a
quarter of its volume. Well above 0, so a step heading toward inversion is caught while the next one could still
turn it; well below what the tissue reaches in motion (the shared clips' smallest, with redone steps: ~0.5)."""
MAX_SPLITS = 5
"""How many times a step is halved at most (a 0.5 ms hero step down to ~16 us)."""
LOCAL_RINGS = 6
"""How many rings of tets the line search grows its set of vertices by before it takes the whole mesh."""
DRAW_BACK = (0.9, 0.75, 0.5, 0.25, 0.1, 0.0)
"""The line search's tries: the share s of the vertices' offset from their goal kept, the largest first (the least
change that restores the floor)."""


class GoalSolid:
    """A goal-driven solid's state and its checked steps (see the module).

    model : a finalized Newton model of tet meshes (the attached vertices with mass 0). attached : (N,) bool.
    tets : (T, 4) int32 the model's tets. alpha : (N,) 1/s, each vertex's goal-relative drag (0: none).
    iterations : VBD's per step. stiffening : b of the strain stiffening (0: none). cap : its largest factor.
    rest_goal : the tets' rest shape follows the goal (else the model's bind shape). after : callable(t, goal_end,
    q, qd) run after each step (contacts), None: none. floor : DET_FLOOR (None: no check, no redo).
    Counters: steps (steps kept), redone (steps put back and taken again in halves), searched (shortest steps
    ended by the line search), searched_vertices (the vertices it moved, summed), whole (searches that drew a whole
    part back) and smallest_draw (the smallest share of its offset such a part kept), min_det (the smallest det F of
    any kept step's end, inf before the first), and per tet the smallest det F of a kept step (tet_min_det (T,)).
    """

    def __init__(self, model, attached: np.ndarray, tets: np.ndarray, alpha: np.ndarray, *, iterations: int,
                 stiffening: float, cap: float, rest_goal: bool = True, after=None, floor: float | None = DET_FLOOR,
                 max_splits: int = MAX_SPLITS, device: str = "cpu"):
        import warp as wp

        from jiggle.sim.fem import fem_kernels
        self.k, self.device, self.model = fem_kernels, device, model
        N, T = len(attached), len(tets)
        self.solver = _goal_vbd()(model=model, iterations=int(iterations), particle_enable_self_contact=False,
                                  particle_enable_tile_solve=False)
        self.s0, self.s1 = model.state(), model.state()
        self.control = model.control()
        self.solver.attached_idx = wp.array(np.flatnonzero(attached).astype(np.int32), dtype=wp.int32, device=device)
        self.solver.goal_end = wp.zeros(max(N, 1), dtype=wp.vec3, device=device)
        self.tets = wp.array(np.asarray(tets, np.int32).reshape(-1, 4), dtype=wp.int32, device=device)
        self.base = wp.clone(model.tet_materials)
        self.stiffening, self.cap, self.rest_goal, self.after = float(stiffening), float(cap), bool(rest_goal), after
        self.free_idx = wp.array(np.flatnonzero(~np.asarray(attached, bool)).astype(np.int32), dtype=wp.int32,
                                 device=device)
        alpha = np.asarray(alpha, np.float32).reshape(-1)
        self.drag = bool((alpha > 0.0).any())
        self.rate = wp.array(alpha if len(alpha) else np.zeros(1, np.float32), dtype=float, device=device)
        self.goal_velocity = wp.zeros(max(N, 1), dtype=wp.vec3, device=device)
        self.floor, self.max_splits = floor, int(max_splits)
        self.det = wp.zeros(max(T, 1), dtype=float, device=device)
        self.q_save = wp.zeros(max(N, 1), dtype=wp.vec3, device=device)
        self.qd_save = wp.zeros(max(N, 1), dtype=wp.vec3, device=device)
        self.tet_min_det = np.full(T, np.inf, np.float32)
        self._free = ~np.asarray(attached, bool)
        self._component = _components(len(attached), np.asarray(tets).reshape(-1, 4))
        self.steps, self.redone, self.min_det = 0, 0, float("inf")
        self.searched, self.searched_vertices, self.whole, self.smallest_draw = 0, 0, 0, 1.0

    # ------------------------------------------------------------------------------------------------ state
    def set_state(self, x: np.ndarray, v: np.ndarray) -> None:
        """Positions and velocities (N, 3) metres, m/s."""
        self.s0.particle_q.assign(np.asarray(x, np.float32))
        self.s0.particle_qd.assign(np.asarray(v, np.float32))

    def state(self) -> tuple[np.ndarray, np.ndarray]:
        """(x, v) (N, 3) float32, a copy."""
        return self.s0.particle_q.numpy().copy(), self.s0.particle_qd.numpy().copy()

    def rest_on(self, goal: np.ndarray) -> None:
        """The tets' rest shape set to goal (N, 3) metres (a run's start, rest "goal")."""
        self.solver.goal_end.assign(np.asarray(goal, np.float32))
        self.k.rest_poses(self.tets, self.solver.goal_end, self.model.tet_poses, self.device)

    # ------------------------------------------------------------------------------------------------ steps
    def advance(self, curve, t: float, h: float, depth: int = 0) -> None:
        """The step of h seconds ending at time t (seconds) on the goal curve `curve` (t -> (goal, velocity)
        (N, 3)), checked and redone in halves below the floor (see the module)."""
        import warp as wp
        check = self.floor is not None and self.det.shape[0] > 0 and len(self.tet_min_det) > 0
        if check:
            wp.copy(self.q_save, self.s0.particle_q)
            wp.copy(self.qd_save, self.s0.particle_qd)
        self._step(curve, t, h)
        if not check:
            self.steps += 1
            return
        self.k.tet_determinants(self.tets, self.model.tet_poses, self.s0.particle_q, self.det, self.device)
        det = self.det.numpy()
        low = float(det.min())
        if low < self.floor and depth < self.max_splits:
            wp.copy(self.s0.particle_q, self.q_save)
            wp.copy(self.s0.particle_qd, self.qd_save)
            self.redone += 1
            self.advance(curve, t - 0.5 * h, 0.5 * h, depth + 1)
            self.advance(curve, t, 0.5 * h, depth + 1)
            return
        if low < self.floor:                 # the shortest step still ends below: a line search toward the goal
            det = self._line_search(curve(t)[1], det)
            low = float(det.min())
        self.steps += 1
        self.min_det = min(self.min_det, low)
        np.minimum(self.tet_min_det, det, out=self.tet_min_det)

    def _step(self, curve, t: float, h: float) -> None:
        g, gv = curve(t)
        self.solver.goal_end.assign(g.astype(np.float32))
        if self.rest_goal:
            self.k.rest_poses(self.tets, self.solver.goal_end, self.model.tet_poses, self.device)
        self.k.stiffen(self.tets, self.model.tet_poses, self.base, self.stiffening, self.cap, self.s0.particle_q,
                       self.model.tet_materials, self.device)
        self.s0.clear_forces()
        self.solver.step(self.s0, self.s1, self.control, None, h)
        self.s0, self.s1 = self.s1, self.s0
        if self.drag:
            self.goal_velocity.assign(gv.astype(np.float32))
            self.k.goal_drag(self.free_idx, self.rate, h, self.goal_velocity, self.s0.particle_qd, self.device)
        if self.after is not None:
            self.after(t, self.solver.goal_end, self.s0.particle_q, self.s0.particle_qd)

    def _line_search(self, goal_velocity: np.ndarray, det: np.ndarray) -> np.ndarray:
        """Every tet back at the floor or above by drawing vertices back along their offset from the goal (x = g +
        s (x - g), v = gv + s (v - gv), s from DRAW_BACK, the largest that does, 0: on the goal). First the free
        vertices of the tets below the floor, their set growing by a ring of tets while one stays below (LOCAL_RINGS
        times); then, where that is not enough, every free vertex of the meshes those tets belong to. Returns every
        tet's det F after (goal_velocity (N, 3) m/s; det (T,) before). Why it ends: on the goal a tet is its own rest
        shape (det F 1, rest "goal"), and det F is continuous in s."""
        tets = self.tets.numpy()
        poses = self.model.tet_poses.numpy()
        x, v = self.s0.particle_q.numpy().copy(), self.s0.particle_qd.numpy().copy()
        g = self.solver.goal_end.numpy()
        gv = np.asarray(goal_velocity, np.float32)
        verts = np.zeros(len(x), bool)
        bad = det < self.floor
        for ring in range(LOCAL_RINGS + 1):
            whole = ring == LOCAL_RINGS
            if whole:                                    # the meshes (connected parts) of the tets still below
                verts |= np.isin(self._component, np.unique(self._component[tets[bad, 0]]))
                self.whole += 1
            else:
                verts[tets[bad].reshape(-1)] = True
            verts &= self._free
            near = verts[tets].any(axis=1)               # the tets the moved vertices touch
            x0, v0 = x[verts].copy(), v[verts].copy()
            for s in DRAW_BACK:
                x[verts] = g[verts] + s * (x0 - g[verts])
                v[verts] = gv[verts] + s * (v0 - gv[verts])
                det[near] = _determinants(x, tets[near], poses[near])
                if (det[near] >= self.floor).all():
                    break
            if whole:
                self.smallest_draw = min(self.smallest_draw, s)
            bad = near & (det < self.floor)
            if not bad.any():
                break
        self.s0.particle_q.assign(x)
        self.s0.particle_qd.assign(v)
        self.searched += 1
        self.searched_vertices += int(verts.sum())
        return det

    def to_json(self) -> dict:
        """The check's record: floor, the most splits, the steps kept and redone, the smallest det F."""
        return {"det_floor": self.floor, "max_splits": self.max_splits, "steps": self.steps,
                "steps_redone": self.redone, "steps_line_searched": self.searched,
                "line_searched_vertices": self.searched_vertices, "whole_meshes_drawn_back": self.whole,
                "smallest_draw_back": self.smallest_draw,
                "step_min_det": None if not np.isfinite(self.min_det) else round(float(self.min_det), 6)}


def _goal_vbd():
    """SolverVBD whose particle initialisation ends by placing the attached vertices at their goal (sim/fem/solve.py
    says why after VBD has recorded their start)."""
    import newton

    from jiggle.sim.fem import fem_kernels

    class _GoalVBD(newton.solvers.SolverVBD):
        goal_end = None          # wp.array (N,) vec3: every vertex's goal at the step's end
        attached_idx = None      # wp.array (A,) int32

        def _initialize_particles(self, state_in, state_out, contacts, dt):
            super()._initialize_particles(state_in, state_out, contacts, dt)
            fem_kernels.place(self.attached_idx, self.goal_end, state_in.particle_q,
                              self.pos_prev_collision_detection, self.device)

    return _GoalVBD


def _components(n: int, tets: np.ndarray) -> np.ndarray:
    """(n,) int: the connected mesh (a part) of each of n vertices, over tets (T, 4)."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components
    if not len(tets):
        return np.arange(n)
    i = np.repeat(tets[:, :1], 3, axis=1).reshape(-1)
    j = tets[:, 1:].reshape(-1)
    return connected_components(sp.coo_matrix((np.ones(len(i)), (i, j)), shape=(n, n)), directed=False)[1]


def _determinants(x: np.ndarray, tets: np.ndarray, poses: np.ndarray) -> np.ndarray:
    """(T,) det F of tets (T, 4) at x (N, 3) against their rest shapes' inverse poses (T, 3, 3)."""
    p = np.asarray(x, np.float64)[tets]
    Ds = np.stack([p[:, 1] - p[:, 0], p[:, 2] - p[:, 0], p[:, 3] - p[:, 0]], axis=-1)
    return np.linalg.det(Ds @ np.asarray(poses, np.float64))


__all__ = ["GoalSolid", "DET_FLOOR", "MAX_SPLITS", "LOCAL_RINGS", "DRAW_BACK"]
