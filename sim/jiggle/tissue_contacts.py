"""Contact between muscles of different body parts: particle against particle, between the solver's steps.

An option on top of the capsule and floor contacts (sim/jiggle/colliders.py): the particles of a muscle
also collide with the particles of the muscles fitted to other bones. :class:`TissueContactModel` (frozen,
built once at bind by :func:`tissue_contact_model`) holds per particle:

- a radius (metres): half the distance to the nearest of its two neighbours on its ring of CVs at bind,
  so the spheres of a ring touch and cover the loft's surface around it, capped at RADIUS_MAX (a fat
  ring's spheres would otherwise reach across half the muscle and, as the hash grid's cell is twice the
  largest radius, make every query see many more neighbours);
- its muscle, and its bind position X;

and an (M, M) mask of the muscles that may touch: those fitted to DIFFERENT bones
(``MuscleSpec.bone``, the joint whose frame carries the muscle's middle; rig.joints[:, 8]). Muscles of one
bone (the quadriceps and the hamstrings on the thigh) never interact: they share a body part whose
static shape already packs them, and their jiggle is one limb's tissue moving together.

The contact distance of a pair (i, j) is ``D_ij = min(r_i + r_j, SHARE |X_i - X_j|)``: two particles
farther apart at bind than (r_i + r_j) / SHARE touch at the sum of their radii; a pair that lies closer
at bind (adjacent muscles meeting at a joint, a pad resting on a neighbour) may come to SHARE of its bind
distance before it is pushed. A bound at the bind distance itself would push such a pair apart at rest
(the muscles overlap there by design) and the rest shape would drift; SHARE = 1/2 leaves room for the
gravity sag and the poses that press such neighbours together without letting one pass through the
other. D_ij is computed in the kernel from the bind positions (no (N, N) table).

The contact is a Jacobi projection with friction after every step (sim/jiggle/tissue_contact_kernels.py
says how), the same kind of constraint as the capsules' and the reach: the goal flow is exact at any
step, and a penalty stiff enough to hold two muscles apart in a landing would need its own, much smaller
step limit. A cross-muscle contact cannot live inside the solver's one-launch run (a thread per muscle
looping over the steps), so :func:`integrate_tissue` runs the solver one step per launch, each followed
by the contact pass on all particles; with contacts off the run is the one-launch run, unchanged.

Hit ids extend the colliders': a capsule c in 0..C-1, C the floor, C + 1 + m the particles of muscle m
(:meth:`TissueContactModel.hit_names`).

Cost (benchmarks/bench_tissue_contacts.py, 2-core CPU): per step one launch of the solver's run kernel
over that step (with colliders, ParticleSolver.step_plan: the stretch's step arrays go to the device once,
a step costs a launch; the kernel then forms the offsets and closes the kick every step, work the one-launch
run does once), two small broad-phase launches (a thread per muscle), the hash grid's build when some muscle
is near another it may touch, and the contact kernel. On the demo (28 muscles, no tissue contact) the option
makes the simulate stage ~2.7x slower; on 40 pads pressing on each other every frame ~12x, most of it the
contact kernel (every particle in contact, every step).
"""
from __future__ import annotations

import math
import weakref
from dataclasses import dataclass

import numpy as np
import warp as wp

from jiggle.rig.base.errors import InputError
from jiggle.rig.base.frozen import frozen_array
from jiggle.sim.jiggle import tissue_contact_kernels as kernels
from jiggle.sim.jiggle.colliders import FRICTION
from jiggle.sim.jiggle.params import CVS, RING
from jiggle.sim.jiggle.solver import recorded_launch

SHARE = 0.5
"""A pair of particles closer than r_i + r_j at bind touches at this fraction of its bind distance."""
RADIUS_MAX = 0.025
"""metres: the largest particle radius (a ring of 8 CVs of radius R has spheres of 0.38 R: R <= 6.5 cm)."""
NO_HIT = kernels.NO_HIT
BONE_SLOT = 8
"""rig.muscle.model.MuscleRig.joints' slot of the joint `MuscleSpec.bone` (the middle offset's)."""


@dataclass(frozen=True, eq=False)
class TissueContactModel:
    """The particles' spheres and which muscles touch (read-only arrays; `wp_*` their device copies).

    radius : (N,) metres. muscle : (N,) int64, each particle's muscle (group of the particle model).
    rest : (N, 3) metres, bind positions. mask : (M, M) bool, symmetric: muscles a and b may touch.
    bone : (M,) int64, each muscle's body part (fitted bone). muscle_names : (M,).
    friction : Coulomb coefficient >= 0. share : SHARE (see the module).
    """

    radius: np.ndarray
    muscle: np.ndarray
    rest: np.ndarray
    mask: np.ndarray
    bone: np.ndarray
    muscle_names: tuple
    friction: float
    share: float
    device: str
    wp_radius: wp.array
    wp_muscle: wp.array
    wp_rest: wp.array
    wp_mask: wp.array

    @property
    def num_particles(self) -> int:
        return len(self.radius)

    @property
    def num_muscles(self) -> int:
        return len(self.mask)

    @property
    def muscle_offsets(self) -> np.ndarray:
        """(M + 1,) int64: muscle m's particles are muscle_offsets[m]:muscle_offsets[m + 1]."""
        return np.searchsorted(self.muscle, np.arange(self.num_muscles + 1)).astype(np.int64)

    @property
    def any_pairs(self) -> bool:
        """Whether any two muscles may touch (if not, a run with the option is the run without it)."""
        return bool(self.mask.any()) and self.query_radius > 0

    @property
    def query_radius(self) -> float:
        """metres: the hash grid's cell and query radius, twice the largest radius (>= any r_i + r_j)."""
        return 2.0 * float(self.radius.max()) if len(self.radius) else 0.0

    def hit_names(self, collider_names=None) -> tuple:
        """Names by hit id: collider_names (the ColliderModel's `names`: its capsules then "floor"; None:
        ("floor",), no capsules) followed by the muscles (hit C + 1 + m: the particles of muscle m)."""
        base = ("floor",) if collider_names is None else tuple(collider_names)
        return base + tuple(self.muscle_names)

    @classmethod
    def build(cls, rest: np.ndarray, group_offsets: np.ndarray, bone, *, radius: np.ndarray | None = None,
              muscle_names=None, friction: float = FRICTION, share: float = SHARE,
              device: str = "cpu") -> "TissueContactModel":
        """A model from bind positions rest (N, 3) metres, muscles group_offsets (M + 1,) and each muscle's
        bone (M,) int. radius : (N,) metres, None for the ring rule (every muscle 5 rings of 8 CVs)."""
        if not (isinstance(friction, (int, float)) and math.isfinite(friction) and friction >= 0):
            raise InputError(f"tissue friction must be a number >= 0, got {friction!r}", field="friction")
        if not (isinstance(share, (int, float)) and 0 < share <= 1):
            raise InputError(f"the contact share must be in (0, 1], got {share!r}", field="share")
        rest = np.asarray(rest, dtype=np.float64).reshape(-1, 3)
        offsets = np.asarray(group_offsets, dtype=np.int64)
        bone = np.asarray(bone, dtype=np.int64).reshape(-1)
        M, N = len(offsets) - 1, len(rest)
        if len(bone) != M or offsets[-1] != N:
            raise InputError(f"expected a bone for each of {M} muscles over {N} particles, got {len(bone)} "
                             f"bones and {offsets[-1]} particles", field="tissue")
        if radius is None:
            if np.any(np.diff(offsets) != CVS):
                raise InputError(f"the ring radius rule needs muscles of {CVS} CVs", field="tissue")
            radius = ring_radii(rest)
        radius = np.asarray(radius, dtype=np.float64).reshape(-1)
        if len(radius) != N or not np.all(np.isfinite(radius) & (radius >= 0)):
            raise InputError(f"expected {N} finite radii >= 0", field="tissue")
        muscle = np.repeat(np.arange(M), np.diff(offsets))
        mask = bone[:, None] != bone[None, :]

        def dev(a, dtype):
            return wp.array(np.ascontiguousarray(a), dtype=dtype, device=device)
        return cls(radius=frozen_array(radius), muscle=frozen_array(muscle, np.int64), rest=frozen_array(rest),
                   mask=frozen_array(mask, bool), bone=frozen_array(bone, np.int64),
                   muscle_names=tuple(muscle_names or (f"group {m}" for m in range(M))), friction=float(friction),
                   share=float(share), device=str(device),
                   wp_radius=dev(radius.astype(np.float32), wp.float32),
                   wp_muscle=dev(muscle.astype(np.int32), wp.int32), wp_rest=dev(rest.astype(np.float32), wp.vec3),
                   wp_mask=dev(mask.reshape(-1).astype(np.int32) if M else np.zeros(1, np.int32), wp.int32))


def ring_radii(rest: np.ndarray, cap: float = RADIUS_MAX) -> np.ndarray:
    """(N,) metres: per CV of muscles of 5 rings of 8 (rest (N, 3), bind positions) half the distance to
    the nearer of its two ring neighbours, at most `cap`."""
    rings = np.asarray(rest, dtype=np.float64).reshape(-1, RING, 3)
    gap = np.linalg.norm(rings - np.roll(rings, -1, axis=1), axis=2)           # CV r to r + 1
    near = np.minimum(gap, np.roll(gap, 1, axis=1))                            # and r - 1 to r
    return np.minimum(0.5 * near, cap).reshape(-1)


def tissue_contact_model(rig, particle_model, *, friction: float = FRICTION, share: float = SHARE,
                         device: str | None = None) -> TissueContactModel:
    """The tissue contacts of `rig`'s muscles (rig.muscle.model.MuscleRig) as particle_model (its
    ParticleModel, one group per muscle) has them: ring radii, bones from rig.joints, bind positions
    from the particle model."""
    if len(particle_model.group_offsets) != rig.M + 1:
        raise InputError(f"the particle model has {len(particle_model.group_offsets) - 1} groups, the rig "
                         f"{rig.M} muscles", field="tissue")
    bone = np.asarray(rig.joints)[:, BONE_SLOT]
    return TissueContactModel.build(particle_model.rest, particle_model.group_offsets, bone,
                                    muscle_names=rig.names, friction=friction, share=share,
                                    device=device or particle_model.device)


# ------------------------------------------------------------------------------ stepping with contacts
class TissuePass:
    """The contact pass of one TissueContactModel on the device (sim/jiggle/tissue_contact_kernels.py): its
    scratch (the muscles' boxes, the hash grid, the frame's records) and its launches, recorded once.
    integrate_tissue keeps one per solver; :meth:`run` is the pass of one step."""

    def __init__(self, tissue: TissueContactModel):
        dev, N, M = tissue.device, tissue.num_particles, tissue.num_muscles
        self.tissue = tissue
        self.none = _none(N)
        self.caps = wp.array(self.none, dtype=wp.vec3, device=dev)
        """(N,) the step's capsule / floor records (the solver's), "none" without colliders."""
        self.acc = wp.array(self.none, dtype=wp.vec3, device=dev)
        """(N,) the frame's records so far."""
        self.offsets = wp.array(np.asarray(tissue.muscle_offsets, np.int32), dtype=wp.int32, device=dev)
        self.boxes = [wp.zeros(M, dtype=wp.vec3, device=dev) for _ in range(4)]
        self.near = wp.zeros(M, dtype=wp.int32, device=dev)
        self.grid = wp.HashGrid(64, 64, 64, device=dev)
        self.launches = 0
        self._recorded: dict = {}

    def run(self, inv_mass: wp.array, x: wp.array, v: wp.array, fresh: bool, hit_base: float, x_out: wp.array,
            v_out: wp.array) -> None:
        """The pass on the step's end (x, v) into (x_out, v_out), its records merged with self.caps into
        self.acc (started afresh when `fresh`). The hash grid is built only when some muscle is near another
        it may touch (the M flags read back: a copy on the CPU, a sync on a GPU)."""
        boxes, near, contact = self._launches(inv_mass, x, v, fresh, hit_base, x_out, v_out, self.caps)
        for kernel, dim, args in (boxes, near):
            self._launch(kernel, dim, args)
        if self.near.numpy().any():
            self.grid.build(x, self.tissue.query_radius)
        self._launch(*contact)

    def _launches(self, inv_mass, x, v, fresh: bool, hit_base: float, x_out, v_out, caps) -> tuple:
        """The pass's three launches as (kernel, dim, args): the muscles' boxes, their near boxes, the contact."""
        tm = self.tissue
        lo, hi, near_lo, near_hi = self.boxes
        R = tm.query_radius
        return ((kernels.muscle_boxes, tm.num_muscles, [self.offsets, x, lo, hi]),
                (kernels.near_boxes, tm.num_muscles, [tm.wp_mask, tm.num_muscles, R, lo, hi, near_lo, near_hi,
                                                      self.near]),
                (kernels.tissue_contact, tm.num_particles, [
                    self.grid.id, R, inv_mass, tm.wp_radius, tm.wp_muscle, self.offsets, tm.wp_rest, tm.wp_mask,
                    tm.num_muscles, tm.share, tm.friction, float(hit_base), x, v, near_lo, near_hi, caps, int(fresh),
                    x_out, v_out, self.acc]))

    def pass_ops(self, inv_mass, x, v, fresh: bool, hit_base: float, x_out, v_out, caps, any_near) -> list:
        """:meth:`run` as the chunk graph's operations (sim/jiggle/graph.py), with nothing read back: the M near
        flags reduced on the device into any_near (1,) int32 and the hash grid built under
        ("if", any_near, [("grid", ...)]) (a conditional node in a CUDA graph); caps : the step's capsule
        records (self.caps, or a step plan's)."""
        from jiggle.sim.jiggle.graph_kernels import any_flag
        boxes, near, contact = self._launches(inv_mass, x, v, fresh, hit_base, x_out, v_out, caps)
        tm = self.tissue
        return [("launch", *boxes), ("launch", *near), ("launch", any_flag, 1, [self.near, tm.num_muscles, any_near]),
                ("if", any_near, [("grid", self.grid, x, tm.query_radius)]), ("launch", *contact)]

    def _launch(self, kernel, dim: int, args: list) -> None:
        """Launch `kernel`, recorded once; only changed arguments packed again (sim.jiggle.solver.recorded_launch)."""
        recorded_launch(self._recorded, kernel, dim, args, self.tissue.device)
        self.launches += 1


class _Scratch:
    """What integrate_tissue keeps per solver: the solver's step output (a ParticleState) and the pass."""

    def __init__(self, solver, tissue: TissueContactModel):
        self.tissue = tissue
        self.step = solver.model.state()
        self.pass_ = TissuePass(tissue)
        self.caps_clean = True


_SCRATCH: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def _scratch(solver, tissue: TissueContactModel) -> _Scratch:
    sc = _SCRATCH.get(solver)
    if sc is None or sc.tissue is not tissue:
        sc = _SCRATCH[solver] = _Scratch(solver, tissue)
    return sc


def _check(model, tissue: TissueContactModel) -> None:
    if tissue.num_particles != model.num_particles or tissue.num_muscles != len(model.group_offsets) - 1:
        raise InputError(f"the tissue contacts are for {tissue.num_particles} particles in {tissue.num_muscles} "
                         f"muscles, the model has {model.num_particles} in {len(model.group_offsets) - 1}",
                         field="tissue")
    if tissue.device != str(model.device):
        raise InputError(f"the tissue contacts are on {tissue.device}, the model on {model.device}", field="tissue")


def integrate_tissue(solver, state_in, state_out, control, grid: np.ndarray, record=None, colliders=None,
                     tissue: TissueContactModel | None = None) -> np.ndarray | None:
    """``solver.integrate`` (ParticleSolver or KeyedSolver) with tissue contacts: one step per launch, each
    followed by the contact pass (sim/jiggle/tissue_contact_kernels.py) on the hash grid of the step's end.

    grid : (K + 1,) step times, seconds; record : None or the recorded steps (R,) (indices 1..K,
    increasing). Returns the positions (R, N, 3) float32 metres after the recorded steps (None when record
    is None), and leaves in solver.contact_records the (R, N, 3) float32 records (depth m before
    correction, impulse N s, hit id) of the steps since the previous recorded one, capsule / floor and
    tissue merged (largest depth, summed impulse, the deepest's hit; tissue hits are C + 1 + muscle).

    Each step is ``solver.integrate`` over that one step (the steps' closing and opening spring kicks are
    then not merged: K calls of ``solver.step``), so a run going on from a stored state at any step
    repeats an unbroken one bit for bit. tissue None, or without a pair of muscles that may touch: exactly
    ``solver.integrate``.
    """
    m = solver.model
    grid = np.asarray(grid, dtype=np.float64)
    K = len(grid) - 1
    ks = np.zeros(0, np.int64) if record is None else np.asarray(record, dtype=np.int64).reshape(-1)
    if len(ks) and (ks.min() < 1 or ks.max() > K or np.any(np.diff(ks) <= 0)):
        raise InputError(f"recorded steps must be increasing indices in 1..{K}, got {ks.tolist()}", field="record")
    if tissue is not None:
        _check(m, tissue)
    if tissue is None or not tissue.any_pairs or m.num_particles == 0 or K < 1:
        out = solver.integrate(state_in, state_out, control, grid, record=record, colliders=colliders)
        if colliders is None and tissue is not None:
            solver.contact_records = np.repeat(_none(m.num_particles)[None], len(ks), axis=0)
        return out
    sc = _scratch(solver, tissue)
    tp = sc.pass_
    R, N = len(ks), m.num_particles
    frames = np.empty((R, N, 3), np.float32)
    records = np.empty((R, N, 3), np.float32)
    recorded = np.zeros(K + 1, bool)
    recorded[ks] = True
    hit_base = float((colliders.model.num_capsules if colliders is not None else 0) + 1)
    if colliders is None and not sc.caps_clean:
        tp.caps.assign(tp.none)
    sc.caps_clean = colliders is None
    src, fresh, r = state_in, True, 0
    launches = tp.launches
    # with colliders the stretch's step arrays go to the device once and each step is one launch of the run
    # kernel over views of them (equal to solver.integrate over the step bit for bit, without its host work)
    plan = solver.step_plan(control, grid, colliders) if colliders is not None else None
    none_caps = tp.caps
    if plan is not None and plan.kernel is not None:
        tp.caps = plan.record               # the step's capsule / floor records, read by the pass on the device
    try:
        for k in range(K):
            # the step into the scratch state, then its contacts from there into state_out (the next step's start)
            if plan is not None:
                plan.step(k, src, sc.step)
            else:
                solver.integrate(src, sc.step, control, grid[k:k + 2], record=None, colliders=None)
            tp.run(m.wp_inv_mass, sc.step.x, sc.step.v, fresh, hit_base, state_out.x, state_out.v)
            fresh = False
            if recorded[k + 1]:
                frames[r] = state_out.x.numpy()
                records[r] = tp.acc.numpy()
                r += 1
                fresh = True
            src = state_out
    finally:
        tp.caps = none_caps
    solver.launches += tp.launches - launches
    solver.contact_records = records
    return None if record is None else frames


def _none(n: int) -> np.ndarray:
    out = np.zeros((n, 3), np.float32)
    out[:, 2] = NO_HIT
    return out


def tissue_contact_pass(tissue: TissueContactModel, inv_mass: np.ndarray, x: np.ndarray, v: np.ndarray,
                        hit_base: int = 1, caps: np.ndarray | None = None, acc: np.ndarray | None = None):
    """One contact pass on the device from NumPy arrays (the kernels' test against
    :func:`tissue_contact_numpy`, same arguments): (x, v, record) (N, 3) float32."""
    tp = TissuePass(tissue)

    def dev(a, dtype=wp.vec3):
        return wp.array(np.ascontiguousarray(a, dtype=np.float32), dtype=dtype, device=tissue.device)
    if caps is not None:
        tp.caps.assign(np.asarray(caps, np.float32))
    if acc is not None:
        tp.acc.assign(np.asarray(acc, np.float32))
    x_out, v_out = dev(np.zeros((len(x), 3))), dev(np.zeros((len(x), 3)))
    tp.run(dev(inv_mass, float), dev(x), dev(v), acc is None, float(hit_base), x_out, v_out)
    return x_out.numpy(), v_out.numpy(), tp.acc.numpy()


# ------------------------------------------------------------------------------ NumPy reference
def tissue_contact_numpy(tissue: TissueContactModel, inv_mass: np.ndarray, x: np.ndarray, v: np.ndarray,
                         hit_base: int, caps: np.ndarray | None = None, acc: np.ndarray | None = None):
    """The reference of the tissue_contact kernel in float64, every pair tested (no hash grid):
    (x, v) (N, 3) after the pass from x, v (N, 3); the record (N, 3) (depth, impulse, hit) merged from acc
    (None: a fresh frame), the step's capsule records caps (None: none) and this pass."""
    x = np.asarray(x, dtype=np.float64)
    v = np.asarray(v, dtype=np.float64)
    N = len(x)
    w = np.asarray(inv_mass, dtype=np.float64)
    r, mus, X = tissue.radius, tissue.muscle, tissue.rest
    rec = _none(N).astype(np.float64) if acc is None else np.array(acc, dtype=np.float64)

    def merge(rc, depth, impulse, hit):
        return np.array([depth, rc[1] + impulse, hit]) if depth > rc[0] else np.array([rc[0], rc[1] + impulse, rc[2]])
    x_out, v_out = x.copy(), v.copy()
    for i in range(N):
        if caps is not None and caps[i, 2] != NO_HIT:
            rec[i] = merge(rec[i], *caps[i])
        dx, dv, n, deepest, hit = np.zeros(3), np.zeros(3), 0, 0.0, NO_HIT
        for j in range(N):
            if j == i or not tissue.mask[mus[i], mus[j]]:
                continue
            d = x[i] - x[j]
            dist = np.linalg.norm(d)
            D = min(r[i] + r[j], tissue.share * np.linalg.norm(X[i] - X[j]))
            if dist >= D:
                continue
            nrm = d / dist if dist > 1e-9 else (X[i] - X[j]) / np.linalg.norm(X[i] - X[j])
            p = D - dist
            if p > deepest:
                deepest, hit = p, hit_base + mus[j]
            if w[i] + w[j] > 0:
                k = w[i] / (w[i] + w[j])
                dx += k * p * nrm
                vr = v[i] - v[j]
                vn = vr @ nrm
                if vn < 0:
                    vt = vr - vn * nrm
                    st = np.linalg.norm(vt)
                    keep = max(0.0, st + tissue.friction * vn) / st if st > 0 else 0.0
                    dv += k * ((keep - 1.0) * vt - vn * nrm)
                n += 1
        if n:
            x_out[i] += dx / n
            v_out[i] += dv / n
            rec[i] = merge(rec[i], deepest, np.linalg.norm(dv / n) / w[i] if w[i] > 0 else 0.0, hit)
        elif hit != NO_HIT:
            rec[i] = merge(rec[i], deepest, 0.0, hit)
    return x_out, v_out, rec
