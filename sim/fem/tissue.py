"""The FEM hero mode (`jiggle bake --tissue fem`): every simulated muscle part a Neo-Hookean solid of its material.

What the particles do per part (a mass-spring particle on each of its 40 CVs pulled to its goal), this does with
the part's volume: each part's tet mesh (sim.fem.tet_mesh.part_mesh; a part whose loft folds into itself, the
structured mesh of its loft coordinates) in one Newton model, simulated by Newton's SolverVBD exactly as the
volumetric reference does (sim.fem.solve: the tets' rest shape follows the part's goal shape, the bone-attached
core rides its goal, Rayleigh damping at the material's ratio across its low modes: sim/fem/modes.py), and the
part's 40 CVs embedded in its tets (barycentric, sim.fem.tet_mesh.TetMesh.cv_bary): the dynamic CVs the bake
blends, skins, caches and compares are the embedded ones, so nothing downstream knows which solver ran.

Material: each part's own (sim.jiggle.materials.material_of: the material its goal springs stand for, --material's
when given), in real units at the character's real size. The simulation runs in the rig's metres, `real_scale`
real metres each (rig.character.real_size), so the moduli are divided by real_scale^2: a part real_scale times
bigger at the same shear speed rings real_scale times slower, the same as a shear speed real_scale times lower.

Time: between two output frames, n = ceil(frame step / DT_MAX) equal steps; the state at every output frame is a
step's state, and what a chunk does depends only on the state it starts from and its frames' goals, so a resumed
bake repeats an unbroken one bit for bit. A cut of the goal track (a teleport) puts every vertex back on its goal
at the frame after it.

Contacts: after every step the free vertices are kept out of the bone capsules their part collides with (the
particles' pairs, sim.jiggle.colliders) and above the floor, as far as their goal is (a goal already inside a
capsule allows that depth), their velocity into the surface removed (fem_kernels.keep_out).

Checks: every step's end against a det F floor, a step below it redone in halves and, where the shortest still is,
ended by a line search toward the goal (sim.fem.step, shared with the reference); per output frame the smallest det F
over all tets against the goal shape (> 0: none inverted), each part's, and how many tets are inverted.
"""
from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass

import numpy as np

from jiggle.rig.muscle.material import Material
from jiggle.sim.fem.solve import ITERATIONS, STIFFENING, STIFFENING_CAP, GoalCurve
from jiggle.sim.fem.step import DET_FLOOR, GoalSolid
from jiggle.sim.fem.tet_mesh import TetMesh, structured_part_mesh

DT_MAX = 1.0 / 2000.0
"""seconds: the longest step (half the reference's sim.fem.solve.DT; VBD's numerical damping, taken off the requested
damping, ~0.75 omega dt). The strain stiffening is applied lagged by a step: at 1 ms the pectorals and a biceps of
CesiumMan still turned a few tets inside out late in CMU 09_11 (20 VBD iterations did not help, 0.5 ms did)."""
HERO_MESH = {"rows": 7, "cols": 12, "layers": (0.5, 1.0), "core": 0.0}
"""The hero mode's mesh of a part: the structured mesh of its loft coordinates (sim.fem.tet_mesh.structured_part_mesh):
7 rows across the sections x 12 around them, the axis, a ring half way out and the surface; the axis and the two end
rows ride the bone. 648 tets, 175 vertices a part. Why this mesh:
- speed: Warp's CPU kernels run on one thread, a step costs ~2.5 us a tet, so a 28-part body steps in ~45 ms;
- robustness: every vertex's goal is an exact loft point (no inversion of coordinates, no TetGen failure on a
  loft that folds) and the mesh has no slivers for the goal shape to flatten (TetGen's coarse meshes of CesiumMan's
  parts, ~400 tets each, inverted tets by the hundred on CMU 09_11 and ran at 105 ms a step);
- it rings as the materials' rule says: a lofted ellipsoid's fundamental is 1.07x the rule's (the reference's
  2k-tet TetGen meshes: 0.98x); attaching a ring at the CORE too (as part_mesh's Steiner vertices are) made it
  1.8-2.9x stiffer at this size, the one element left across the layer shearing stiffly."""


@dataclass(frozen=True, eq=False)
class FemPart:
    """One simulated part: muscle index, its mesh, its material in real units and as simulated (moduli over
    real_scale^2), its sway's frequency (Hz, its mesh's modes: sim.fem.modes), the Rayleigh damping's band (f1, f2)
    Hz, tet damping k_damp (Pa s) and goal-relative drag alpha (1/s), and where its vertices start in the model
    (offset)."""

    muscle: int
    name: str
    mesh: TetMesh
    material: Material
    simulated: Material
    frequency_hz: float
    k_damp: float
    offset: int
    alpha: float = 0.0
    band_hz: tuple = ()


class FemTissue:
    """The hero mode's solid: the parts' meshes in one Newton model, stepped between output frames (see the module).

    parts : [FemPart] (fem_parts). cv_offsets : (M + 1,) the rig's CV offsets per muscle. pairs : (offsets (M + 1,),
    capsules (P,)) the capsules each muscle collides with (sim.jiggle.colliders.ColliderModel's CSR list), None: none;
    capsule_radius : (C,) metres; floor : metres (world z), None: none. dt_max : seconds, the longest step.
    iterations : VBD's per step. stiffening : b of the strain stiffening (sim.fem.solve.STIFFENING; 0: none).
    After construction: cv_index (P x 40,) the rig's CV rows the parts' embedded CVs replace; steps and seconds, the
    solver's steps run so far and the wall seconds they took.
    """

    def __init__(self, parts: list, cv_offsets: np.ndarray, *, pairs=None, capsule_radius=None, floor=None,
                 device: str = "cpu", dt_max: float = DT_MAX, iterations: int = ITERATIONS,
                 stiffening: float = STIFFENING, floor_det: float | None = DET_FLOOR):
        import newton
        import scipy.sparse as sp
        import warp as wp

        from jiggle.sim.fem import fem_kernels
        self.parts, self.device, self.dt_max, self.iterations = list(parts), device, float(dt_max), int(iterations)
        self._kernels = fem_kernels
        N = sum(len(p.mesh.points) for p in self.parts)
        self.num_vertices = N
        self.cv_index = np.concatenate([np.arange(cv_offsets[p.muscle], cv_offsets[p.muscle + 1]) for p in self.parts]) \
            if self.parts else np.zeros(0, np.int64)
        # goal map (N, rig CVs) and embedding (parts' CVs, N), block-sparse
        ncv = int(cv_offsets[-1])
        rows, cols, vals, erows, ecols, evals = [], [], [], [], [], []
        for k, p in enumerate(self.parts):
            g = p.mesh.goal_map
            r, c = np.nonzero(g)
            rows.append(r + p.offset)
            cols.append(c + cv_offsets[p.muscle])
            vals.append(g[r, c])
            tv = p.mesh.tets[p.mesh.cv_tet] + p.offset                      # (40, 4)
            erows.append(np.repeat(np.arange(40) + 40 * k, 4))
            ecols.append(tv.reshape(-1))
            evals.append(p.mesh.cv_bary.reshape(-1))
        cat = (lambda a, dt: np.concatenate(a).astype(dt)) if self.parts else (lambda a, dt: np.zeros(0, dt))
        self.goal_map = sp.csr_matrix((cat(vals, np.float64), (cat(rows, np.int64), cat(cols, np.int64))),
                                      shape=(N, ncv))
        self.embed = sp.csr_matrix((cat(evals, np.float64), (cat(erows, np.int64), cat(ecols, np.int64))),
                                   shape=(40 * len(self.parts), N))
        self.tets = np.concatenate([p.mesh.tets + p.offset for p in self.parts]).astype(np.int32) if self.parts \
            else np.zeros((0, 4), np.int32)
        self.attached = np.concatenate([p.mesh.attached for p in self.parts]) if self.parts else np.zeros(0, bool)
        self.vertex_part = np.concatenate([np.full(len(p.mesh.points), p.muscle, np.int32) for p in self.parts]) \
            if self.parts else np.zeros(0, np.int32)

        builder = newton.ModelBuilder(gravity=(0.0, 0.0, 0.0))
        with warnings.catch_warnings():
            # a part with tets left out across a fold of its loft has a surface Newton calls non-manifold (the
            # surface it lists is only for contacts, which this model does not use)
            warnings.filterwarnings("ignore", message=".*non-manifold.*")
            self._add_parts(builder)
        for i in np.flatnonzero(self.attached):     # kinematic: VBD leaves mass-0 vertices where the state has them
            builder.particle_mass[int(i)] = 0.0
        builder.color()
        self.model = builder.finalize(device=device)
        self.stiffening = float(stiffening)
        # contacts: the free vertices against their part's capsules and the floor
        self.wp_vertex_part = wp.array(self.vertex_part, dtype=wp.int32, device=device)
        self.contacts = pairs is not None or floor is not None
        offs, caps = pairs if pairs is not None else (np.zeros(int(self.vertex_part.max(initial=0)) + 2, np.int32),
                                                      np.zeros(0, np.int32))
        self.num_capsules = 0 if capsule_radius is None else len(capsule_radius)
        self.wp_pair_offsets = wp.array(np.asarray(offs, np.int32), dtype=wp.int32, device=device)
        self.wp_pair_capsule = wp.array(np.asarray(caps, np.int32) if len(caps) else np.zeros(1, np.int32),
                                        dtype=wp.int32, device=device)
        self.wp_radius = wp.array(np.asarray(capsule_radius if self.num_capsules else [0.0], np.float32),
                                  dtype=wp.float32, device=device)
        self.wp_ends = wp.zeros(max(2 * self.num_capsules, 2), dtype=wp.vec3, device=device)
        self.floor = floor
        self._ends = None                    # (knots, (K, 2C, 3)) of the run under way: the capsules' ends
        # the Rayleigh damping's mass-proportional part: each vertex's part's alpha, on its velocity from its goal's
        alpha = np.concatenate([np.full(len(p.mesh.points), p.alpha) for p in self.parts]) if self.parts \
            else np.zeros(0)
        self.solid = GoalSolid(self.model, self.attached, self.tets, alpha, iterations=self.iterations,
                               stiffening=self.stiffening, cap=STIFFENING_CAP,
                               after=self._keep_out if self.contacts else None, floor=floor_det, device=device)
        self.free_idx = self.solid.free_idx
        self.tet_part = np.concatenate([np.full(len(p.mesh.tets), k, np.int32) for k, p in enumerate(self.parts)]) \
            if self.parts else np.zeros(0, np.int32)
        self.seconds = 0.0

    def _add_parts(self, builder) -> None:
        import warp as wp
        for p in self.parts:
            m = p.simulated
            builder.add_soft_mesh(pos=wp.vec3(0.0, 0.0, 0.0), rot=wp.quat_identity(), scale=1.0,
                                  vel=wp.vec3(0.0, 0.0, 0.0), vertices=[wp.vec3(*x) for x in p.mesh.points],
                                  indices=p.mesh.tets.reshape(-1).tolist(), density=m.density, k_mu=m.shear_pa,
                                  k_lambda=m.lame_pa, k_damp=p.k_damp)

    @property
    def num_tets(self) -> int:
        return len(self.tets)

    def goals(self, static_cvs: np.ndarray) -> np.ndarray:
        """(K, N, 3) metres: every vertex's goal for the rig's static CVs (K, rig CVs, 3) (the parts' goal maps)."""
        cvs = np.asarray(static_cvs, np.float64)
        K = len(cvs)
        flat = np.ascontiguousarray(cvs.transpose(1, 0, 2)).reshape(cvs.shape[1], K * 3)
        return np.asarray(self.goal_map @ flat).reshape(self.num_vertices, K, 3).transpose(1, 0, 2)

    def run(self, knots: np.ndarray, static_cvs: np.ndarray, times: np.ndarray, start=None, cuts=None,
            capsule_ends=None) -> tuple[np.ndarray, tuple, dict]:
        """Simulate over output times (T,) seconds, the goals from the rig's static CVs (K, rig CVs, 3) at knots (K,).

        start : (x, v) (N, 3) float32 the state at times[0] (None: on the goal, moving with it). cuts : (K - 1,) bool,
        the goal track's cuts. capsule_ends : (K, 2C, 3) metres the capsules' ends at the knots (None: no capsules).
        Returns the parts' embedded CVs (T, P x 40, 3) float64 (rows cv_index of the rig's), the state at times[-1]
        ((x, v) float32) and per frame {"min_det" (T,), "inverted" (T,) int, "part_min_det" (T, P) each part's}.
        A step that would leave a tet below the det F floor is redone in halves (sim.fem.step)."""
        import warp as wp
        knots = np.asarray(knots, np.float64)
        times = np.asarray(times, np.float64)
        curve = GoalCurve(knots, self.goals(static_cvs))
        T, N = len(times), self.num_vertices
        if start is None:
            g0, v0 = curve(times[0])
            x = g0.astype(np.float32)
            v = v0.astype(np.float32)
        else:
            x, v = (np.asarray(a, np.float32).reshape(N, 3) for a in start)
        frames = np.empty((T, N, 3), np.float32)
        frames[0] = x
        solid = self.solid
        solid.set_state(x, v)
        k_cut = np.flatnonzero(np.asarray(cuts, bool)) if cuts is not None else np.zeros(0, np.int64)
        cut_at = knots[k_cut + 1] if len(k_cut) else np.zeros(0)
        ends = None if capsule_ends is None or not self.num_capsules else np.asarray(capsule_ends, np.float64)
        self._ends = None if ends is None else (knots, ends)
        clock = time.perf_counter()
        for i in range(T - 1):
            t0, t1 = times[i], times[i + 1]
            n = max(1, int(math.ceil((t1 - t0) / self.dt_max - 1e-9)))
            h = (t1 - t0) / n
            for j in range(1, n + 1):
                solid.advance(curve, t0 + (t1 - t0) * j / n, h)
            if len(cut_at) and ((cut_at > t0) & (cut_at <= t1 + 1e-12)).any():   # a teleport: back on the goal
                g1, gv1 = curve(t1)
                solid.set_state(g1, gv1)
            frames[i + 1] = solid.s0.particle_q.numpy()
        wp.synchronize_device(self.device)
        self.seconds += time.perf_counter() - clock
        end = solid.state()
        cvs = np.asarray(self.embed @ np.ascontiguousarray(frames.transpose(1, 0, 2)).reshape(N, T * 3),
                         np.float64).reshape(-1, T, 3).transpose(1, 0, 2)
        goal = np.stack([curve(t)[0] for t in times])
        det = self.determinants(frames, goal)
        part_min = np.stack([det[:, self.tet_part == k].min(axis=1) for k in range(len(self.parts))], axis=1) \
            if self.parts else np.zeros((T, 0))
        return cvs, end, {"min_det": det.min(axis=1, initial=np.inf), "inverted": (det <= 0.0).sum(axis=1),
                          "part_min_det": part_min}

    @property
    def steps(self) -> int:
        """The solver's steps kept so far (sim.fem.step.GoalSolid)."""
        return self.solid.steps

    def _keep_out(self, t: float, goal, q, qd) -> None:
        """The contacts after a step ending at t seconds: the free vertices out of their part's capsules (their ends
        at t, linear between the run's knots) and above the floor, as far as their goal is (fem_kernels.keep_out)."""
        if self._ends is not None:
            self.wp_ends.assign(_at(*self._ends, t).astype(np.float32))
        self._kernels.keep_out(self.free_idx, self.wp_vertex_part, self.wp_pair_offsets, self.wp_pair_capsule,
                               self.wp_ends, self.wp_radius, self.num_capsules if self._ends is not None else 0,
                               self.floor, goal, q, qd, self.device)

    def determinants(self, x: np.ndarray, goal: np.ndarray) -> np.ndarray:
        """(T, tets) det F of every tet for vertex positions x (T, N, 3) against the goal shapes goal (T, N, 3)."""
        def edges(p):
            q = np.asarray(p, np.float64)[:, self.tets]                              # (T, tets, 4, 3)
            return np.stack([q[:, :, 1] - q[:, :, 0], q[:, :, 2] - q[:, :, 0], q[:, :, 3] - q[:, :, 0]], axis=-1)
        return np.linalg.det(edges(x)) / np.linalg.det(edges(goal))

    def to_json(self, real_scale: float) -> dict:
        """bake.json's "fem": the parts, their meshes and materials, the solver."""
        return {"solver": "Newton SolverVBD, stable Neo-Hookean tets (sim/fem/tissue.py)",
                "stiffening": {"b": self.stiffening, "cap": STIFFENING_CAP,
                               "law": "moduli x exp(b (I1bar - 3)) per tet at its distortion from the goal shape"},
                "iterations": self.iterations, "dt_max_s": self.dt_max, "steps": self.steps,
                "step_check": {**self.solid.to_json(),
                               "rule": "a step ending with a tet's det F below det_floor is put back and taken again "
                                       "as two half steps, down to 2^-max_splits of it; where the shortest still ends "
                                       "below, the vertices of the tets below are drawn back toward their goal until "
                                       "none is (sim/fem/step.py)"},
                "seconds": round(self.seconds, 3), "ms_per_step": round(1e3 * self.seconds / max(self.steps, 1), 3),
                "vertices": self.num_vertices, "tets": self.num_tets, "attached": int(self.attached.sum()),
                "real_scale": real_scale,
                "moduli_rule": "the simulation runs in the rig's metres, real_scale real metres each: E / real_scale^2",
                "contacts": "free vertices kept out of their part's capsules and above the floor, as far as their "
                            "goal is, after every step" if self.contacts else None,
                "parts": {p.name: {"tets": int(len(p.mesh.tets)), "vertices": int(len(p.mesh.points)),
                                   "mesher": p.mesh.mesher, "material": p.material.to_json(),
                                   "frequency_hz": round(p.frequency_hz, 4), "k_damp_pa_s": round(p.k_damp, 6),
                                   "alpha_per_s": round(p.alpha, 6),
                                   "damping_band_hz": [round(f, 4) for f in p.band_hz]}
                          for p in self.parts}}


def _at(knots: np.ndarray, values: np.ndarray, t: float) -> np.ndarray:
    """values (K, ...) at time t, linear between the knots (held outside)."""
    if t <= knots[0]:
        return values[0]
    if t >= knots[-1]:
        return values[-1]
    j = int(np.searchsorted(knots, t, side="right")) - 1
    s = (t - knots[j]) / (knots[j + 1] - knots[j])
    return (1.0 - s) * values[j] + s * values[j + 1]


def fem_parts(rest_cvs: np.ndarray, cv_offsets: np.ndarray, names, materials: dict, real_scale: float, *,
              dt: float = DT_MAX, mesh=None, log=lambda s: None) -> list:
    """[FemPart] of the muscles in `materials` ({muscle index: Material in real units}): each one's mesh from its
    rest CVs (rest_cvs (rig CVs, 3) metres as simulated), its material with moduli over real_scale^2, and Rayleigh
    damping at its material's ratio across its mesh's low modes (sim.fem.modes: the lowest and the sway), VBD's own
    taken off. mesh : structured_part_mesh's keywords (None: HERO_MESH)."""
    from jiggle.sim.fem.modes import band, modes, rayleigh
    from jiggle.sim.fem.solve import NUMERICAL_DAMPING
    parts, offset = [], 0
    t = time.perf_counter()
    for m in sorted(materials):
        cvs = np.asarray(rest_cvs[cv_offsets[m]:cv_offsets[m + 1]], np.float64)
        tm = structured_part_mesh(cvs, **(HERO_MESH if mesh is None else mesh))
        mat = materials[m]
        s2 = float(real_scale) ** 2
        sim = Material(youngs_pa=mat.youngs_pa / s2, poisson=mat.poisson, density=mat.density,
                       damping_ratio=mat.damping_ratio, name=mat.name)
        found = modes(tm, sim)
        f1, f2 = band(found)
        alpha, k_damp = rayleigh(mat.damping_ratio, f1, f2, sim.shear_pa, dt, NUMERICAL_DAMPING)
        parts.append(FemPart(muscle=int(m), name=str(names[m]), mesh=tm, material=mat, simulated=sim,
                             frequency_hz=found.sway_hz, k_damp=k_damp, offset=offset, alpha=alpha, band_hz=(f1, f2)))
        offset += len(tm.points)
    log(f"fem: {len(parts)} parts, {offset} vertices, {sum(len(p.mesh.tets) for p in parts)} tets "
        f"({time.perf_counter() - t:.1f} s)")
    return parts


__all__ = ["FemTissue", "FemPart", "fem_parts", "DT_MAX", "HERO_MESH"]
