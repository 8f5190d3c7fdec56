"""Simulate one part's tet mesh as a Neo-Hookean solid with Newton's VBD solver, driven by its goal shape.

The drive is the particles' drive: the part's static CVs at knot times (rig.static(world).cvs, 40 rows per part)
give every tet vertex its goal through the mesh's loft coordinates (TetMesh.goal_map: goals = goal_map @ cvs),
and between knots each goal follows the C1 cubic Hermite curve through the knots with three-point velocities
(the same curve sim.jiggle.goal_track builds for the particles; written here as sim.fem may not import sim.jiggle).

Model: `newton.ModelBuilder.add_soft_mesh` with k_mu = the material's shear modulus mu (Pa), k_lambda = its Lame
lambda (Pa), density rho (kg/m^3) (lumped masses rho V / 4 per tet vertex); the attached vertices (TetMesh.attached:
the core and end caps) get mass 0, kinematic in VBD. Each step (fem_kernels):
- rest = "goal" (default): every tet's rest shape Dm^-1 is set to the goal shape at the step's end, so the
  body is stress-free exactly on its goal (the static shape bends with the action curve and bulges to keep its
  volume; the FEM follows it without stress, as the particles' goal springs are at rest on their goals); what
  moves it off the goal is inertia: the acceleration of the goal, as for the particles. rest = "bind" keeps the
  bind-pose rest shape (the body then also resists the static shape's change of shape).
- the attached vertices are put at their goal at the step's end after VBD's forward step has recorded their
  start (a SolverVBD subclass, `_GoalVBD`): VBD's velocity update and its damping then see them move. (Newton's
  forward step records a mass-0 vertex's start where the state holds it; setting them before the step, as the
  first version did, made the attached core look still to the damping, which then dragged the free vertices
  back on every moving drive.)

Damping: VBD's tet damping is viscous on the rate of C = F^T F, coefficient k_damp (Pa s): its force derives from
R = V k_damp / 2 sum_ij Cdot_ij^2 = 2 V k_damp sum_ij edot_ij^2 in small strain (C = I + 2 e), a viscous stress
4 k_damp edot against the shear's 2 mu e: stiffness-proportional (Rayleigh beta = 2 k_damp / mu), so a mode of
angular frequency omega rings with zeta = beta omega / 2 = k_damp omega / mu. `damping_coefficient` sets
k_damp = zeta mu / omega at one frequency (the calibration's ring-downs: benchmarks/results/fem_reference.md).
Higher modes are damped more (zeta_n = zeta omega_n / omega_1), lower ones less: a part's modes below its sway then
ring on, so the reference and the hero mode add a mass-proportional part, `alpha` (1/s), a drag on each free
vertex's velocity relative to its goal's, and take both from sim/fem/modes.py's Rayleigh band (the material's ratio
at the part's lowest mode and at its sway). VBD's backward Euler adds numerical damping.

Time: fixed steps of `dt` seconds from out_times[0]; output positions at out_times are linear between the
bracketing steps (frame-rate independent; only dt changes the simulation).

Checks, per output frame, in NumPy (the reference): min det F over tets relative to the goal shape (> 0: no tet
inverted) and the energy: kinetic relative to the goal's velocity (lumped masses, free vertices) + elastic against
the goal shape (the stable Neo-Hookean Newton uses: Smith et al. 2018, mu_NH = mu, lambda_NH = lambda + mu,
Psi = mu/2 (Ic - 3) + lambda_NH/2 (J - a)^2 - lambda_NH/2 (1 - a)^2, a = 1 + mu / lambda_NH, zero at rest).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from jiggle.rig.base.frozen import frozen_array
from jiggle.rig.muscle.material import Material
from jiggle.sim.fem.step import DET_FLOOR, MAX_SPLITS, GoalSolid
from jiggle.sim.fem.tet_mesh import TetMesh

DT = 1.0 / 1000.0
"""seconds: the default fixed step. A jiggle's fundamental is a few to tens of Hz; VBD is implicit, so the step
is set by accuracy (numerical damping ~ omega dt / 2 ~ 0.01 at 3 Hz) rather than by the nearly incompressible
material's pressure waves an explicit step would have to resolve."""
ITERATIONS = 10
"""VBD iterations per step (Newton's examples use 10)."""
STIFFENING = 3.0
"""b of the tissue's strain stiffening, the Fung exponential law (Fung 1993, Biomechanics: Mechanical Properties of
Living Tissues, ch. 7): each tet's moduli are mu exp(b (I1bar - 3)) at its distortion from the goal shape (I1bar - 3
~ the shear strain squared): x1.2 at 25% shear, x20 at 100%. Soft tissue stiffens steeply (adipose: Ogden alpha ~20
in Comley & Fleck 2010, Int. J. Impact Eng. 37; skeletal muscle: exponential fibre laws); a neo-Hookean solid of
the same small-strain modulus does not, and a soft part driven hard (a 1.4 Hz glute fat in a run) then shears its
tets inside out. It is the FEM's counterpart of the particles' tissue law (sim/jiggle/tissue_law.py), applied lagged
by one step (fem_kernels.stiffen); the reference (simulate_part) and the hero mode (sim/fem/tissue.py) both apply it."""
STIFFENING_CAP = 1000.0
"""The largest factor the stiffening multiplies a tet's moduli by (and an inverted tet's)."""


@dataclass(frozen=True, eq=False)
class FemRun:
    """A simulated part (arrays read-only).

    times : (F,) seconds. positions : (F, N, 3) float64 metres, every vertex. goals : (F, N, 3) metres, every
    vertex's goal (what the jiggle is measured against). min_det : (F,) the smallest det F (against the goal
    shape, rest "goal"; the bind shape, rest "bind") over all tets (> 0: none inverted). energy : (F,) joules,
    kinetic (relative to the goal's velocity) + elastic (see the module). steps : the solver's steps.
    ms_per_step : wall milliseconds per solver step (the loop alone). redone : steps redone in halves below the
    det F floor (sim.fem.step); searched : shortest steps ended by its line search (whole: of those, how many drew a
    whole part back). step_min_det : the smallest det F
    at any kept step's end (not only the output frames).
    """

    times: np.ndarray
    positions: np.ndarray
    goals: np.ndarray
    min_det: np.ndarray
    energy: np.ndarray
    steps: int
    ms_per_step: float = 0.0
    redone: int = 0
    step_min_det: float = float("inf")
    searched: int = 0
    whole: int = 0

    def __post_init__(self):
        for k in ("times", "positions", "goals", "min_det", "energy"):
            object.__setattr__(self, k, frozen_array(getattr(self, k)))


NUMERICAL_DAMPING = 0.75
"""VBD's own damping ratio per unit omega dt at ITERATIONS iterations: an undamped ring-down of a muscle ellipsoid
(17 Hz) rings with zeta 0.081 at dt 1 ms (2.5 periods fitted), ~half at 0.5 ms; more iterations do not lower it
(backward Euler's omega dt / 2 plus the unconverged iterations)."""


def damping_coefficient(material: Material, frequency_hz: float, dt: float | None = None) -> float:
    """k_damp (Pa s) of Newton's VBD tet damping for the material's damping ratio at a fundamental of
    `frequency_hz` (Hz): zeta mu / omega (see the module: stiffness-proportional, so exact at that frequency). With
    dt (seconds) the solver's numerical damping NUMERICAL_DAMPING omega dt is taken off the ratio first (not below
    0), so the part rings with the material's ratio in all (benchmarks/results/fem_reference.md: within ~10%)."""
    omega = 2.0 * math.pi * frequency_hz
    zeta = material.damping_ratio
    if dt is not None:
        zeta = max(zeta - NUMERICAL_DAMPING * omega * dt, 0.0)
    return zeta * material.shear_pa / omega


def carry_at(carry: np.ndarray, knots: np.ndarray, t: float) -> np.ndarray:
    """(4, 4) the rigid map at time t (seconds) between knots (K,) of carry (K, 4, 4): translation linear, rotation
    slerped; held before the first knot and after the last."""
    from scipy.spatial.transform import Rotation, Slerp
    if len(knots) == 1 or t <= knots[0]:
        return carry[0].copy()
    if t >= knots[-1]:
        return carry[-1].copy()
    i = int(np.searchsorted(knots, t, side="right")) - 1
    s = (t - knots[i]) / (knots[i + 1] - knots[i])
    out = np.eye(4)
    out[:3, 3] = (1 - s) * carry[i, :3, 3] + s * carry[i + 1, :3, 3]
    out[:3, :3] = Slerp([0.0, 1.0], Rotation.from_matrix(carry[i:i + 2, :3, :3]))([s]).as_matrix()[0]
    return out


def elastic_energy(mesh: TetMesh, x: np.ndarray, material: Material, rest: np.ndarray | None = None) -> np.ndarray:
    """(...) joules: the stable Neo-Hookean energy of vertex positions x (..., N, 3) against the rest shape rest
    (..., N, 3) (None: the mesh's points), zero at rest; volumes are the mesh's rest volumes (VBD's masses)."""
    Dm_inv = _rest_inverse(mesh, rest)
    F = _deformation(mesh, x, Dm_inv)
    mu, lam = material.shear_pa, material.lame_pa + material.shear_pa
    a = 1.0 + mu / lam
    Ic = np.einsum("...ij,...ij->...", F, F)
    J = np.linalg.det(F)
    psi = 0.5 * mu * (Ic - 3.0) + 0.5 * lam * (J - a) ** 2 - 0.5 * lam * (1.0 - a) ** 2
    return (psi * mesh.volumes).sum(axis=-1)


def determinants(mesh: TetMesh, x: np.ndarray, rest: np.ndarray | None = None) -> np.ndarray:
    """(..., T) det F of every tet for vertex positions x (..., N, 3) against rest (..., N, 3) (None: the mesh)."""
    return np.linalg.det(_deformation(mesh, x, _rest_inverse(mesh, rest)))


def lumped_masses(mesh: TetMesh, density: float) -> np.ndarray:
    """(N,) kg: rho V / 4 of each tet to each of its vertices (as add_soft_mesh lumps them)."""
    return np.bincount(mesh.tets.reshape(-1), weights=np.repeat(density * mesh.volumes / 4.0, 4),
                       minlength=len(mesh.points))


def _rest_inverse(mesh: TetMesh, rest: np.ndarray | None = None) -> np.ndarray:
    p = (mesh.points if rest is None else np.asarray(rest, dtype=np.float64))[..., mesh.tets, :]
    return np.linalg.inv(np.stack([p[..., 1, :] - p[..., 0, :], p[..., 2, :] - p[..., 0, :],
                                   p[..., 3, :] - p[..., 0, :]], axis=-1))


def _deformation(mesh: TetMesh, x: np.ndarray, Dm_inv: np.ndarray) -> np.ndarray:
    p = np.asarray(x, dtype=np.float64)[..., mesh.tets, :]                          # (..., T, 4, 3)
    Ds = np.stack([p[..., 1, :] - p[..., 0, :], p[..., 2, :] - p[..., 0, :], p[..., 3, :] - p[..., 0, :]], axis=-1)
    return Ds @ Dm_inv


class GoalCurve:
    """Goals (K, N, 3) metres at knots (K,) seconds as a C1 cubic Hermite curve: knot velocities from the quadratic
    through each knot and its neighbours (one-sided at the ends), as sim.jiggle.goal_track.knot_velocities without
    cuts; held before the first knot and after the last (velocity 0 there; on the end knots, their own velocity)."""

    def __init__(self, knots: np.ndarray, goals: np.ndarray):
        self.t = np.asarray(knots, dtype=np.float64).reshape(-1)
        self.x = np.asarray(goals, dtype=np.float64)
        K = len(self.t)
        if self.x.shape[0] != K:
            raise ValueError(f"goals must be ({K}, N, 3), got {self.x.shape}")
        self.v = np.zeros_like(self.x)
        if K >= 2:
            h = np.diff(self.t)[:, None, None]
            slope = np.diff(self.x, axis=0) / h
            if K == 2:
                self.v[:] = slope[0]
            else:
                self.v[1:-1] = (h[1:] * slope[:-1] + h[:-1] * slope[1:]) / (h[:-1] + h[1:])
                self.v[0] = slope[0] + (slope[0] - slope[1]) * h[0] / (h[0] + h[1])
                self.v[-1] = slope[-1] + (slope[-1] - slope[-2]) * h[-1] / (h[-1] + h[-2])

    def __call__(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Goal (N, 3) and its velocity (N, 3) at time t seconds."""
        if len(self.t) == 1 or t < self.t[0]:
            return self.x[0], np.zeros_like(self.x[0])
        if t > self.t[-1]:
            return self.x[-1], np.zeros_like(self.x[-1])
        j = min(int(np.searchsorted(self.t, t, side="right")) - 1, len(self.t) - 2)
        H, s = self.t[j + 1] - self.t[j], t - self.t[j]
        pa, pb, va, vb = self.x[j], self.x[j + 1], self.v[j], self.v[j + 1]
        c2 = (3.0 * (pb - pa) / H - 2.0 * va - vb) / H
        c3 = (2.0 * (pa - pb) / H + va + vb) / (H * H)
        return pa + s * (va + s * (c2 + s * c3)), va + s * (2.0 * c2 + 3.0 * s * c3)


def carried_goals(mesh: TetMesh, carry: np.ndarray) -> np.ndarray:
    """(K, N, 3) metres: the mesh's rest points carried rigidly by carry (K, 4, 4) (a rigid drive as goals)."""
    carry = np.asarray(carry, dtype=np.float64).reshape(-1, 4, 4)
    return np.einsum("kij,nj->kni", carry[:, :3, :3], mesh.points) + carry[:, None, :3, 3]


def simulate_part(mesh: TetMesh, material: Material, goals: np.ndarray, knots: np.ndarray, out_times: np.ndarray, *,
                  frequency_hz: float | None = None, k_damp: float | None = None, dt: float = DT,
                  iterations: int = ITERATIONS, rest: str = "goal", gravity: bool = False,
                  stiffening: float = STIFFENING, alpha: float = 0.0, floor: float | None = DET_FLOOR,
                  max_splits: int = MAX_SPLITS, device: str = "cpu") -> FemRun:
    """Simulate the part `mesh` of `material` driven by its vertices' goals (K, N, 3) metres at knot times knots (K,)
    seconds (mesh.goals(static_cvs) for a part's static CVs (K, 40, 3); carried_goals for a rigid drive) and sample
    it at out_times (F,) seconds (ascending).

    Damping: k_damp (Pa s) when given, else damping_coefficient(material, frequency_hz, dt) (the numerical damping
    taken off) when frequency_hz is given, else none. rest : "goal" (the tets' rest shape follows the goal) or "bind" (the mesh's points).
    gravity : along -Z, 9.81 m/s^2. stiffening : b of the tissue's strain stiffening (STIFFENING; 0: a plain
    Neo-Hookean solid). alpha : 1/s, the Rayleigh damping's mass-proportional part, on each free vertex's velocity
    relative to its goal's (sim/fem/modes.py; 0: none). floor : a step ending with a tet's det F below it is redone
    in halves, at most max_splits times, then line-searched toward the goal (sim.fem.step; None: no check). The body
    starts on its goal at out_times[0], moving with the goal's velocity.
    """
    import time

    import newton
    import warp as wp

    if rest not in ("goal", "bind"):
        raise ValueError(f"rest must be 'goal' or 'bind', got {rest!r}")
    knots = np.asarray(knots, dtype=np.float64).reshape(-1)
    goals = np.asarray(goals, dtype=np.float64).reshape(len(knots), len(mesh.points), 3)
    out_times = np.asarray(out_times, dtype=np.float64).reshape(-1)
    curve = GoalCurve(knots, goals)
    if k_damp is None:
        k_damp = 0.0 if frequency_hz is None else damping_coefficient(material, frequency_hz, dt)
    t0 = float(out_times[0])
    n_steps = int(math.ceil((out_times[-1] - t0) / dt - 1e-9))
    x0, v0 = curve(t0)

    builder = newton.ModelBuilder(gravity=(0.0, 0.0, -9.81 if gravity else 0.0))
    builder.add_soft_mesh(pos=wp.vec3(0.0, 0.0, 0.0), rot=wp.quat_identity(), scale=1.0, vel=wp.vec3(0.0, 0.0, 0.0),
                          vertices=[wp.vec3(*p) for p in mesh.points], indices=mesh.tets.reshape(-1).tolist(),
                          density=material.density, k_mu=material.shear_pa, k_lambda=material.lame_pa,
                          k_damp=k_damp)
    for i in np.flatnonzero(mesh.attached):         # kinematic: VBD leaves mass-0 vertices where the state has them
        builder.particle_mass[int(i)] = 0.0
    builder.color()
    solid = GoalSolid(builder.finalize(device=device), mesh.attached, mesh.tets,
                      np.full(len(mesh.points), float(alpha)), iterations=iterations, stiffening=stiffening,
                      cap=STIFFENING_CAP, rest_goal=rest == "goal", floor=floor, max_splits=max_splits,
                      device=device)
    solid.set_state(x0, v0)
    if rest == "goal":
        solid.rest_on(x0)

    step_times = t0 + dt * np.arange(n_steps + 1)
    frames = np.empty((len(out_times), len(mesh.points), 3))
    vels = np.empty_like(frames)
    prev_x, prev_v = x0, v0
    k = 0
    while k < len(out_times) and out_times[k] <= t0 + 1e-12:
        frames[k], vels[k] = x0, v0
        k += 1
    clock = time.perf_counter()
    for n in range(1, n_steps + 1):
        t = step_times[n]
        solid.advance(curve, t, dt)
        x, v = solid.s0.particle_q.numpy().astype(np.float64), solid.s0.particle_qd.numpy().astype(np.float64)
        while k < len(out_times) and out_times[k] <= t + 1e-12:
            s = min(1.0, 1.0 - (t - out_times[k]) / dt)                    # linear between the two steps
            frames[k], vels[k] = prev_x + s * (x - prev_x), prev_v + s * (v - prev_v)
            k += 1
        prev_x, prev_v = x, v
    ms = 1e3 * (time.perf_counter() - clock) / max(n_steps, 1)
    gx = np.stack([curve(t)[0] for t in out_times])
    gv = np.stack([curve(t)[1] for t in out_times])
    masses = lumped_masses(mesh, material.density)
    free = ~mesh.attached
    kinetic = 0.5 * (masses[free] * ((vels - gv)[:, free] ** 2).sum(-1)).sum(-1)
    ref = gx if rest == "goal" else None
    energy = kinetic + elastic_energy(mesh, frames, material, ref)
    min_det = determinants(mesh, frames, ref).min(axis=-1)
    return FemRun(times=out_times, positions=frames, goals=gx, min_det=min_det, energy=energy, steps=solid.steps,
                  ms_per_step=ms, redone=solid.redone, searched=solid.searched, whole=solid.whole,
                  step_min_det=solid.min_det if np.isfinite(solid.min_det) else float(min_det.min()))


__all__ = ["FemRun", "GoalCurve", "simulate_part", "STIFFENING", "STIFFENING_CAP", "carried_goals",
           "damping_coefficient", "carry_at", "elastic_energy", "determinants", "lumped_masses", "DT", "ITERATIONS", "NUMERICAL_DAMPING"]
