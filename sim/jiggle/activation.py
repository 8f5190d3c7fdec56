"""Muscle activation from the motion's own loads: who carries a joint's torque, and how hard.

The joint torques of the clip (sim.drive.inverse.joint_torques: inverse dynamics with the ground) are shared among
the muscles that span each joint, by their moment arms and strengths, with the least effort: biomechanics' static
optimization (Crowninshield & Brand 1981, J Biomech 14:793: minimize the sum of squared activations subject to the
joint moments), solved each knot as one small bounded least-squares problem (scipy's lsq_linear):

    min  sum_j w^2 |sum_m R_mj F_m a_m - tau_j|^2  +  sum_m a_m^2,     0 <= a_m <= 1,

with a weight w large enough that the torques are met wherever the muscles can, and fat never activated.

- Moment arms (:func:`moment_arms`): each muscle's path, origin -> origin hinge -> insertion hinge -> insertion
  (rig.muscle.model: each point rides its joint), has length L; rotating joint j's subtree by d(theta) about a world
  axis a changes it by a . G_mj d(theta), G_mj = sum_k [point k below j] (P_k - p_j) x (u_(k-1) - u_k) (u_k the
  unit path segments), so the muscle's tension F gives the joint the torque R_mj F with R_mj = -G_mj (virtual work).
  They are taken at the bind pose, where the template's landmarks sit as in the anatomy, and carried in the joint's
  own frame (:func:`posed_arms`): a straight path from thigh to shin has no patella to wrap over and, in a deep
  crouch, would pass behind the knee and make the quadriceps a flexor; real knee-extensor moment arms stay 3-5 cm
  through the range (the patella's work), as a moment arm fixed in the joint's frame does.
- Strength (:func:`max_forces`): physiological cross-section (volume over fibre length; the fitted belly's rest
  length stands for the fibres) times a specific tension of SPECIFIC_TENSION (60 N/cm^2, the value of Rajagopal et
  al. 2016's full-body model, IEEE TBME 63:2068, within the 25-100 N/cm^2 measured). The fitted muscles are the
  visible shells of their regions, not the whole of their muscle: their volumes are scaled alike so that together
  they hold the body's skeletal muscle, MUSCLE_SHARE of its mass (ICRP 89: 29 of 73 kg).
- The leg's deep muscles (sim.jiggle.deep_muscles: iliopsoas, adductors, gluteus medius and minimus, tibialis
  anterior): on a human skeleton they share the hip's and ankle's torques with the fitted muscles (their paths
  and strengths are a musculoskeletal model's, scaled to the body), so that the glute is not asked to hold the
  pelvis level alone, nor the quadriceps to swing the leg forward; they are solved for, never simulated.
- Activation dynamics (:func:`activation_dynamics`): the excitation the optimization asks for is followed first
  order, rising with RISE_S (10 ms) and falling with FALL_S (40 ms) (Zajac 1989, Crit Rev Biomed Eng 17:359;
  Thelen 2003).

What activation does to the tissue (:func:`stiffened`): a working muscle's fibres are under tension, and a belly
under tension sways as a string does: its transverse wave speed is sqrt(sigma / rho), sigma = a SPECIFIC_TENSION
the fibres' stress (Martin et al. 2018, Nat Commun 9:1592, read a tendon's load from the same law), so its
fundamental sway is f_t = sqrt(sigma / rho) / (2 L) over its rest belly length L, added to its relaxed sway f_0 (its
material's, sim.jiggle.materials) as f = sqrt(f_0^2 + f_t^2): the goal springs' frequency is scaled by
sqrt(1 + (f_t / f_0)^2) at every frame (a keyed frequency; sim.jiggle.keyed). Muscle stiffness rising about
linearly with its force is what elastography measures (Bouillard, Nordez & Hug 2011; Ates et al. 2015, J
Electromyogr Kinesiol 25:703, over the whole range of contraction): sigma, and so f^2, is linear in the force.
Fat is never activated and keeps its springs.

Where a joint's torque is beyond what its muscles can give, their activations saturate at 1 (`saturated`). A joint
the clip never turns (a BVH's hip bone from the pelvis centre to the hip, CMU's LHipJoint: its local rotation stays
within RIGID_DEG) is the skeleton's, not a joint: its torque is the bone's to carry, and the muscles spanning it are
asked for none there (:func:`moving_joints`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from jiggle.rig.base.frozen import frozen_array

SPECIFIC_TENSION = 0.6e6
"""Pa: a muscle's largest force per physiological cross-section (see the module)."""
MUSCLE_SHARE = 0.40
"""Skeletal muscle over body mass (ICRP Publication 89, reference adult male: 29 kg of 73 kg)."""
MUSCLE_DENSITY = 1060.0
"""kg/m^3 (Mendez & Keys 1960)."""
RISE_S, FALL_S = 0.010, 0.040
"""seconds: activation's time constants, rising and falling (see the module)."""
TORQUE_WEIGHT = 1000.0
"""w of the optimization, per N m over the muscles' largest torque at the joint: torques met first, effort least."""
STIFFEN_STEP = math.log(1.02)
"""The stiffening's frequency factor is taken in steps of 2% (log-spaced): within 1% of the law, far inside the
material rule's own spread, and few distinct springs for the keyed solver to take the flow of."""
SPAN_KEEP = 0.2
"""A joint's torque is matched along the axes whose singular value of its muscles' torque matrix is at least this
share of the largest (see static_optimization)."""
RIGID_DEG = 1.0
"""degrees: a joint whose local rotation stays this near its mean over the clip is rigid (see the module)."""
PATH_SLOTS = (0, 2, 3, 1)
"""rig.muscle.model.MuscleRig.joints / local slots of a muscle's path: origin, o_hinge, i_hinge, insertion."""


@dataclass(frozen=True, eq=False)
class Activation:
    """Muscle activations over a clip (arrays read-only). times : (K,) seconds. activation : (K, M) in [0, 1],
    after activation dynamics. excitation : (K, M), the static optimization's. saturated : (K, J) bool, joints whose
    torque the muscles could not give (a muscle at 1 and torque left over). unmet : (K, J, 3) N m, the torque left
    over at the joints the muscles span. max_force : (M,) N. deep_names : the leg's deep muscles that shared the
    torques (sim.jiggle.deep_muscles; none without a human skeleton's legs), deep_activation (K, D) theirs."""

    times: np.ndarray
    activation: np.ndarray
    excitation: np.ndarray
    saturated: np.ndarray
    unmet: np.ndarray
    max_force: np.ndarray
    deep_names: tuple = ()
    deep_activation: np.ndarray | None = None

    def __post_init__(self):
        for k in ("times", "activation", "excitation", "saturated", "unmet", "max_force"):
            object.__setattr__(self, k, frozen_array(getattr(self, k)))
        if self.deep_activation is not None:
            object.__setattr__(self, "deep_activation", frozen_array(self.deep_activation))


def path_points(rig, world: np.ndarray) -> np.ndarray:
    """(K, M, 4, 3) metres: each muscle's path points (origin, o_hinge, i_hinge, insertion) for joint world
    transforms (K, J, 4, 4)."""
    world = np.asarray(world, np.float64)
    joints = np.asarray(rig.joints)[:, PATH_SLOTS]                       # (M, 4)
    local = np.asarray(rig.local)[:, PATH_SLOTS]                         # (M, 4, 4)
    W = world[:, joints]                                                 # (K, M, 4, 4, 4)
    return np.einsum("kmpij,mpj->kmpi", W, local)[..., :3]


def below(parents: np.ndarray) -> np.ndarray:
    """(J, J) bool: [j, i] when joint i is j or below it (parents come before children)."""
    parents = np.asarray(parents)
    J = len(parents)
    out = np.eye(J, dtype=bool)
    for i in range(J):
        p = parents[i]
        if p >= 0:
            out[:, i] |= out[:, p]
    return out


def moment_arms(rig, world: np.ndarray, parents: np.ndarray) -> np.ndarray:
    """(K, M, J, 3) metres: R_mj, the torque about joint j (world axes) per newton of muscle m's tension, for joint
    world transforms (K, J, 4, 4) and the skeleton's parents (J,) (see the module)."""
    return path_arms(path_points(rig, world), np.asarray(rig.joints)[:, PATH_SLOTS], parents, world)


def path_arms(P: np.ndarray, joints: np.ndarray, parents: np.ndarray, world: np.ndarray) -> np.ndarray:
    """(K, M, J, 3) metres: the moment arms (moment_arms) of paths of points P (K, M, n, 3) metres, point k of path
    m riding joint joints[m, k] ((M, n) int; a repeated last point adds nothing), for joint world transforms (K, J,
    4, 4) and the skeleton's parents (J,)."""
    seg = np.diff(P, axis=2)
    u = seg / np.maximum(np.linalg.norm(seg, axis=-1, keepdims=True), 1e-12)       # (K, M, n - 1, 3)
    zero = np.zeros_like(u[:, :, :1])
    du = np.concatenate([zero, u], axis=2) - np.concatenate([u, zero], axis=2)      # (K, M, n, 3): u_(k-1) - u_k
    under = below(parents)[:, np.asarray(joints)]                        # (J, M, n)
    p = np.asarray(world, np.float64)[:, :, :3, 3]                       # (K, J, 3)
    # G_mj = sum_k under[j, m, k] (P_k - p_j) x du_k = sum_k under (P_k x du_k) - p_j x sum_k under du_k
    a = np.einsum("jmp,tmpi->tmji", under, np.cross(P, du))
    b = np.einsum("jmp,tmpi->tmji", under, du)
    G = a - np.cross(p[:, None], b)
    return -G


def max_forces(rig, scale: float = 1.0, body_mass_kg: float | None = None) -> np.ndarray:
    """(M,) N: each muscle's largest force, SPECIFIC_TENSION x its rest volume over its rest belly length (the
    physiological cross-section), at real size (lengths x `scale`), the volumes scaled so the muscles hold
    MUSCLE_SHARE of `body_mass_kg` (None: as fitted); fat's 0."""
    muscle = np.asarray(rig.kinds) != "fat"
    volume = np.asarray(rig.rest_volume, np.float64) * scale ** 3
    if body_mass_kg is not None and volume[muscle].sum() > 0:
        volume = volume * (MUSCLE_SHARE * body_mass_kg / MUSCLE_DENSITY / volume[muscle].sum())
    area = volume / np.maximum(np.asarray(rig.rest_length, np.float64) * scale, 1e-9)
    return np.where(muscle, SPECIFIC_TENSION * area, 0.0)


def posed_arms(bind_arms: np.ndarray, bind_world: np.ndarray, world: np.ndarray) -> np.ndarray:
    """(K, M, J, 3): moment arms taken at the bind pose (M, J, 3), world axes, carried by each joint's rotation from
    its bind (J, 4, 4) to its pose (K, J, 4, 4)."""
    rb = np.asarray(bind_world, np.float64)[:, :3, :3]
    rk = np.asarray(world, np.float64)[:, :, :3, :3]
    local = np.einsum("jba,mjb->mja", rb, bind_arms)                    # into each joint's bind frame
    return np.einsum("kjab,mjb->kmja", rk, local)


def static_optimization(arms: np.ndarray, torques: np.ndarray, force: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(excitation (K, M), unmet (K, J, 3)): each knot's activations by the module's least-squares problem, for
    moment arms (K, M, J, 3) metres, joint torques (K, J, 3) N m and largest forces (M,) N; joints no muscle spans
    are left out."""
    from scipy.optimize import lsq_linear
    K, M, J, _ = arms.shape
    active = force > 0
    reach = np.abs(arms[:, active]).max(axis=(0, 1, 3)) if active.any() else np.zeros(J)     # (J,)
    spanned = np.flatnonzero(reach > 1e-4)
    exc = np.zeros((K, M))
    unmet = np.zeros((K, J, 3))
    if not len(spanned) or not active.any():
        return exc, unmet
    cols = np.flatnonzero(active)
    cap = np.abs(arms[:, cols][:, :, spanned] * force[cols, None, None]).sum(axis=1).max(axis=(0, 2))   # (S,) N m
    w = TORQUE_WEIGHT / np.maximum(cap, 1e-6)                            # per joint
    A_all = (arms[:, cols][:, :, spanned] * force[None, cols, None, None]).transpose(0, 2, 3, 1)  # (K, S, 3, C)
    # each joint's torque is asked of its muscles only along the axes they can turn it about (SPAN_KEEP): an axis
    # no muscle pulls well about (a forearm's twist for a biceps and triceps alone) is the ligaments' and the
    # unmodelled muscles', and matching it anyway buys a sliver of torque with a large co-contraction
    U, sv, _ = np.linalg.svd(A_all, full_matrices=False)                 # (K, S, 3, r), (K, S, r)
    keep = sv >= SPAN_KEEP * sv[..., :1]
    for k in range(K):
        rows, rhs = [], []
        for i in range(len(spanned)):
            basis = U[k, i][:, keep[k, i]]                               # (3, q)
            rows.append(w[i] * basis.T @ A_all[k, i])
            rhs.append(w[i] * basis.T @ torques[k, spanned[i]])
        Aw, bw = np.concatenate(rows), np.concatenate(rhs)
        res = lsq_linear(np.concatenate([Aw, np.eye(len(cols))]), np.concatenate([bw, np.zeros(len(cols))]),
                         bounds=(0.0, 1.0), method="bvls")
        exc[k, cols] = res.x
        unmet[k, spanned] = torques[k, spanned] - (A_all[k] @ res.x)
    return exc, unmet


def moving_joints(world: np.ndarray, parents: np.ndarray) -> np.ndarray:
    """(J,) bool: the joints whose local rotation (child in parent, from world transforms (K, J, 4, 4)) turns by
    more than RIGID_DEG from its first over the frames; roots count as moving."""
    world = np.asarray(world, np.float64)
    parents = np.asarray(parents)
    R = world[:, :, :3, :3]
    out = np.ones(len(parents), bool)
    for j, p in enumerate(parents):
        if p < 0:
            continue
        local = np.einsum("kba,kbc->kac", R[:, p], R[:, j])           # parent^T child
        rel = np.einsum("ba,kbc->kac", local[0], local)                 # from the first frame's
        cos = np.clip((np.trace(rel, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
        out[j] = np.degrees(np.arccos(cos)).max() > RIGID_DEG
    return out


def activation_dynamics(excitation: np.ndarray, times: np.ndarray, rise: float = RISE_S,
                        fall: float = FALL_S) -> np.ndarray:
    """(K, M): activations following `excitation` (K, M) at `times` (K,) seconds first order, with time constant
    `rise` where the excitation is above the activation and `fall` where below (exact per step for a held
    excitation); they start at the first excitation."""
    u = np.asarray(excitation, np.float64)
    t = np.asarray(times, np.float64)
    a = np.empty_like(u)
    a[0] = u[0]
    for k in range(1, len(t)):
        dt = t[k] - t[k - 1]
        tau = np.where(u[k] > a[k - 1], rise, fall)
        a[k] = u[k] + (a[k - 1] - u[k]) * np.exp(-dt / tau)
    return a


def activations(rig, world_at, loads, parents: np.ndarray, bind_world: np.ndarray, times: np.ndarray,
                scale: float = 1.0, load_times: np.ndarray | None = None, roles: dict | None = None) -> Activation:
    """The Activation of `rig`'s muscles at `times` (K,) seconds: the skeleton posed by `world_at` (times -> (K, J, 4,
    4), the bake's drive; its bind pose `bind_world` (J, 4, 4)), the joint torques of `loads`
    (sim.drive.inverse.Loads, whose mass_kg is the body's), the body at real size `scale` (lengths x scale; the
    loads are at real size already). load_times : (K,) the clip's seconds the loads are read at (None: `times`; a
    looped bake's times past the clip wrap to the cycle's own). roles : the skeleton's human roles (role -> joint):
    with both legs', the leg's deep muscles (sim.jiggle.deep_muscles) share the torques too."""
    from jiggle.sim.jiggle.deep_muscles import REFERENCE_MASS_KG, deep_paths
    times = np.asarray(times, np.float64)
    world = np.asarray(world_at(times), np.float64)
    bind = np.asarray(bind_world, np.float64)
    moving = moving_joints(world, parents)
    bind_arms = moment_arms(rig, bind[None], parents)[0] * scale
    force = max_forces(rig, scale, loads.mass_kg)
    deep = deep_paths(bind, roles or {})
    M = len(force)
    if deep is not None:
        names, points, joints, deep_force = deep
        bind_arms = np.concatenate([bind_arms, path_arms(points[None], joints, parents, bind[None])[0] * scale])
        force = np.concatenate([force, deep_force * loads.mass_kg / REFERENCE_MASS_KG])
    arms = posed_arms(bind_arms, bind, world) * moving[None, None, :, None]
    torques = loads.at(times if load_times is None else load_times) * moving[None, :, None]
    exc, unmet = static_optimization(arms, torques, force)
    exc = np.clip(exc, 0.0, 1.0)                                         # the bounded solver's round-off (-1e-22)
    act = np.clip(activation_dynamics(exc, times), 0.0, 1.0)
    top = exc >= 1.0 - 1e-6
    spans = np.abs(arms).max(axis=3) > 1e-4                              # (K, M, J)
    sat = np.einsum("km,kmj->kj", top.astype(float), spans.astype(float)) > 0
    sat &= np.linalg.norm(unmet, axis=2) > 0.05 * np.maximum(np.linalg.norm(torques, axis=2), 1e-9)
    if deep is None:
        return Activation(times, act, exc, sat, unmet, force)
    return Activation(times, act[:, :M], exc[:, :M], sat, unmet, force[:M], tuple(names), act[:, M:])


def tension_frequency(activation: np.ndarray, length_m: float, density: float) -> np.ndarray:
    """Hz: the sway of a belly of rest length `length_m` (metres) and `density` (kg/m^3) under its fibres' stress at
    `activation` (any shape, 0 to 1): sqrt(a SPECIFIC_TENSION / rho) / (2 L) (see the module)."""
    a = np.clip(np.asarray(activation, np.float64), 0.0, 1.0)
    return np.sqrt(a * SPECIFIC_TENSION / max(float(density), 1e-9)) / (2.0 * max(float(length_m), 1e-9))


def stiffened(jiggles, rig, activation: np.ndarray, times: np.ndarray, scale: float = 1.0) -> tuple[list, np.ndarray]:
    """(jiggles, factor): each muscle's goal springs keyed over `times` (T,) seconds by its activation (T, M): its
    frequency times sqrt(1 + (f_t / f_0)^2), f_t the tension's sway (tension_frequency at its rest belly length x
    `scale`, metres) and f_0 its relaxed sway (the material its springs stand for: sim.jiggle.materials); a keyed
    frequency keeps its keys' shape, scaled. factor : (T, M) the scale (1 for fat and for a muscle never active)."""
    from dataclasses import replace

    from jiggle.sim.jiggle.keyed import Curve
    from jiggle.sim.jiggle.materials import ring_factor
    times = np.asarray(times, np.float64)
    a = np.asarray(activation, np.float64)
    factor = np.ones_like(a)
    out = list(jiggles)
    for m, j in enumerate(jiggles):
        if rig.kinds[m] == "fat" or not a[:, m].max() > 0:
            continue
        L = float(rig.rest_length[m]) * scale
        ref = j.reference() if j.keyed else j
        # the relaxed sway its springs stand for (sim.jiggle.materials: the rule's f_fem, material_of's inverse)
        f0 = float(ref.frequency_hz) * ring_factor(ref)
        exact = np.sqrt(1.0 + (tension_frequency(a[:, m], L, float(ref.density)) / max(f0, 1e-9)) ** 2)
        # in STIFFEN_STEP steps: the keyed solver computes a goal flow once per distinct stiffness (sim.jiggle.goal_flow),
        # and a stiffness that differs on every knot interval made the frame loop 3.7x slower
        factor[:, m] = np.exp(np.round(np.log(exact) / STIFFEN_STEP) * STIFFEN_STEP)
        base = j.frequency_hz
        f = (base(times) if isinstance(base, Curve) else np.full(len(times), float(base))) * factor[:, m]
        # held between keys: the keyed solver reads a spring per knot interval at its middle, and a linear curve
        # there lands between two steps (a new stiffness on nearly every interval)
        out[m] = replace(j, frequency_hz=Curve(times, f, "step"))
    return out, factor


__all__ = ["Activation", "tension_frequency", "stiffened", "SPECIFIC_TENSION", "MUSCLE_SHARE", "RISE_S", "FALL_S", "path_points", "below", "moment_arms",
           "posed_arms", "path_arms", "max_forces", "moving_joints", "RIGID_DEG",
           "static_optimization", "activation_dynamics", "activations"]
