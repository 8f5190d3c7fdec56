"""From a tissue's material to its particles' goal springs, and back.

A part of the body (a muscle or fat, rig.muscle.model) made of a Material (rig/muscle/material.py: Young's modulus E,
Poisson's ratio nu, density rho, damping ratio zeta) and of mean rest radius r (metres, real size) wobbles, as
a finite-element solve of its volume says (sim/fem, benchmarks/fem_reference.py), at its fundamental frequency

    f_fem = FEM_C sqrt(mu / rho) / r,          mu = E / (2 (1 + nu)),

the shear wave's speed over the part's radius: a part twice as thick wobbles half as fast, a material four times
as stiff twice as fast. FEM_C is the volumetric reference's undamped ring-downs (sim/fem, driven by the parts' goal
shapes exactly as the particles are; benchmarks/results/fem_reference.md) of 5 lofted ellipsoids and 4 of CesiumMan's
fitted parts, fat and muscle: 0.168, spread 14% (0.128-0.220; muscle rings 2.0x faster than fat in every part, their
shear speeds' ratio). Where the part's rest length L is known (every bake), its slenderness is taken in too:

    f_fem = FEM_C_SLENDER (r / L)^FEM_A sqrt(mu / rho) / r,

which fits the same ring-downs within 10% (FEM_C_SLENDER 0.2583, FEM_A 0.203): a long part rings slower than a
short one of the same radius.

The particles ring at their goal springs' frequency: a particle of goal weight w at frequency_hz f rings at
f sqrt(w / (1 - w)) (sim/jiggle/params.py), and a part's visible wobble is its belly's (the sections between its
tendon ends, where the goal weights are lowest and the mass is). So the part's goal springs are set to

    frequency_hz = f_fem / sqrt(w_belly / (1 - w_belly)),

its density to the material's and its damping ratio to the one that makes the part ring down with the material's
ratio. The particles damp more than their goal springs' damping_ratio says: each CV's damper is 2 zeta omega_i m_i
at its own omega_i (the stiff tendon CVs' too), and the neighbour springs have dampers of their own, by an amount
that depends on the part's goal weights (a human fat pad's soft belly between stiff ends adds ~0.1; a part of even
goal weights, nothing). So the rule reads the part's own sway (:func:`sway_mode`: the damping ratio of the mode
that carries its mass, by the linearized particle model's eigenvalues) and sets damping_ratio so that
MODAL_GAIN x that ratio is the material's (:func:`particle_damping`). MODAL_GAIN is the ring-downs' (the solver's
particles, measured as the reference measures a solid: benchmarks/fem_reference.py, "Particle damping") over the
eigenvalues' (1.14, spread 8% over 36 ring-downs).

:func:`material_of` inverts the rule:
the Material a part's goal springs stand for (E from its frequency, nu and rho of its kind), which bake.json
records for every part, whichever set it.
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from jiggle.rig.muscle.material import Material, material_for

FEM_C = 0.168
"""f_fem r / sqrt(mu / rho): the volumetric reference's fundamental frequency of a lofted part over its shear speed
per radius (see the module; spread 14% over the shapes measured)."""
FEM_C_SLENDER, FEM_A = 0.2583, 0.203
"""The rule with the part's slenderness: f_fem = FEM_C_SLENDER (r / L)^FEM_A sqrt(mu / rho) / r, L its rest length
(rig.muscle.model.MuscleRig.rest_length): the same ring-downs fit within 10% (0.81-1.18 of it) where r alone spreads
14% (0.76-1.31). A long part rings slower than a short one of the same radius (a long quadriceps at 0.89 of the r
rule, a short, wide belly at 1.16): the rule the product uses wherever a part's length is known."""


MODAL_GAIN = 1.14
"""The particles' ring-down damping ratio (the logarithmic decrement of their centre-of-mass sway after a stop,
sim.fem.measure.decrement) over :func:`sway_mode`'s: benchmarks/results/fem_reference.md, "Particle damping" (the
calibration parts, fat and muscle, at half and all of each material's ratio: 1.137, spread 8%, 1.01-1.43)."""


def sway_mode(jiggle, rest_cvs: np.ndarray) -> tuple[float, float]:
    """(frequency Hz, damping ratio) of the particles' sway: the mode of a part's 40 particles (goal springs of
    `jiggle`, MuscleJiggle, at its reference values; its neighbour springs; its friction) that carries the most of
    its mass (the centre-of-mass wobble a ring-down reads), by the complex eigenvalues of the linearized model about
    the goal (offsets below the tissue law's onset; each axis alike). rest_cvs : (40, 3) metres, the part's rest
    CVs (its section masses and spring pairs). The frequency is the damped mode's |lambda| / 2 pi, the ratio
    -Re(lambda) / |lambda|; (0, 0) for a part with every particle glued."""
    from jiggle.sim.jiggle.particles import muscle_terms
    mj = jiggle.reference() if jiggle.keyed else jiggle
    # the particle model's own terms (sim.jiggle.particles.muscle_terms); the ratio is the same for any total mass
    m, k, c, ij, spring_k, spring_c = muscle_terms(rest_cvs, 1.0, mj)
    free = np.flatnonzero(np.isfinite(k))
    if not len(free):
        return 0.0, 0.0
    K = np.diag(m * np.where(np.isfinite(k), k, 0.0))
    C = np.diag(m * (c + float(mj.friction)))
    for A, v in ((K, spring_k), (C, spring_c)):
        np.add.at(A, (ij[:, 0], ij[:, 0]), v)
        np.add.at(A, (ij[:, 1], ij[:, 1]), v)
        np.add.at(A, (ij[:, 0], ij[:, 1]), -v)
        np.add.at(A, (ij[:, 1], ij[:, 0]), -v)
    n = len(free)
    inv_m = 1.0 / m[free]
    A = np.zeros((2 * n, 2 * n))
    A[:n, n:] = np.eye(n)
    A[n:, :n] = -inv_m[:, None] * K[np.ix_(free, free)]
    A[n:, n:] = -inv_m[:, None] * C[np.ix_(free, free)]
    lam, vec = np.linalg.eig(A)
    mf = m[free]
    phi = vec[:n]
    share = np.abs(mf @ phi) ** 2 / np.maximum((mf[:, None] * np.abs(phi) ** 2).sum(axis=0) * mf.sum(), 1e-300)
    share = np.where(lam.imag >= 0, share, -1.0)            # one of each conjugate pair (an overdamped mode: real)
    i = int(np.argmax(share))
    mag = float(abs(lam[i]))
    return mag / (2.0 * math.pi), float(-lam[i].real / max(mag, 1e-300))


def ring_damping(jiggle, rest_cvs: np.ndarray | None = None) -> float:
    """The damping ratio a part with goal springs `jiggle` and rest CVs (40, 3) rings down with: MODAL_GAIN x its
    sway_mode's; its damping_ratio where the CVs are not given."""
    if rest_cvs is None:
        ref = jiggle.reference() if jiggle.keyed else jiggle
        return float(ref.damping_ratio)
    return MODAL_GAIN * sway_mode(jiggle, rest_cvs)[1]


def particle_damping(zeta: float, jiggle, rest_cvs: np.ndarray | None = None) -> float:
    """The goal springs' damping_ratio with which the part (`jiggle` but for its damping ratio; rest CVs (40, 3))
    rings down with damping ratio `zeta` (ring_damping inverted; `zeta` itself without the CVs; 0 where the part
    damps that much with none)."""
    from scipy.optimize import brentq
    if rest_cvs is None:
        return float(zeta)

    def miss(d):
        return ring_damping(replace(jiggle, damping_ratio=float(d)), rest_cvs) - float(zeta)
    if miss(0.0) >= 0.0:
        return 0.0
    hi = max(2.0 * float(zeta), 0.1)
    while miss(hi) < 0.0 and hi < 64.0:
        hi *= 2.0
    if miss(hi) < 0.0:                  # past critical damping the sway no longer rings: as damped as it gets
        return hi
    return float(brentq(miss, 0.0, hi, xtol=1e-6))


def belly_goal(jiggle) -> float:
    """The goal weight of a part's belly: the mean of its middle three sections' (rows 8..31 of the 40 CVs), the
    smallest 1 - 1e-6 so a glued part has a finite factor."""
    g = np.asarray(jiggle.goal_weights(), np.float64)
    return float(np.clip(g[8:32].mean(), 1e-6, 1.0 - 1e-6))


def ring_factor(jiggle) -> float:
    """sqrt(w / (1 - w)) of the belly's goal weight w: the particles' ring frequency over frequency_hz."""
    w = belly_goal(jiggle)
    return math.sqrt(w / (1.0 - w))


def shape_constant(radius_m: float, length_m: float | None = None) -> float:
    """f_fem r / sqrt(mu / rho) of a part of mean radius radius_m and rest length length_m (metres; None: unknown):
    FEM_C_SLENDER (r / L)^FEM_A when the length is known, else FEM_C."""
    if length_m is None or not length_m > 0:
        return FEM_C
    return FEM_C_SLENDER * (max(float(radius_m), 1e-9) / float(length_m)) ** FEM_A


def fem_frequency(material: Material, radius_m: float, length_m: float | None = None) -> float:
    """Hz: a part of `material`, mean radius `radius_m` and rest length `length_m` (metres, real size; None: the
    radius alone) wobbles at this (the module's rule)."""
    return shape_constant(radius_m, length_m) * material.shear_speed / max(float(radius_m), 1e-9)


def with_material(jiggle, material: Material, radius_m: float, length_m: float | None = None,
                  rest_cvs: np.ndarray | None = None, only: tuple = ("frequency_hz", "damping_ratio", "density")):
    """`jiggle` (sim.jiggle.params.MuscleJiggle) with its goal springs, damping ratio and density from `material`
    for a part of mean radius `radius_m` and rest length `length_m` (metres, real size) and rest CVs (40, 3) (its
    shape: how much its particles damp on their own, particle_damping; None: the material's ratio as it is).
    only : the fields the material sets (the others stay as `jiggle` has them; a damping ratio is found for the
    frequency and density the part then has)."""
    out = jiggle
    if "frequency_hz" in only:
        out = replace(out, frequency_hz=float(fem_frequency(material, radius_m, length_m) / ring_factor(jiggle)))
    if "density" in only:
        out = replace(out, density=float(material.density))
    if "damping_ratio" in only:
        out = replace(out, damping_ratio=particle_damping(material.damping_ratio, out, rest_cvs))
    return out


def material_of(jiggle, kind: str, radius_m: float, length_m: float | None = None,
                rest_cvs: np.ndarray | None = None) -> Material:
    """The Material a part of `kind` whose goal springs are `jiggle` stands for: E from its frequency_hz (its
    reference value for a keyed one) by the module's rule inverted (radius_m, length_m as fem_frequency), nu of its
    kind's material, its density, and the damping ratio it rings down with (ring_damping, of its rest CVs (40, 3)
    when given)."""
    ref = jiggle.reference() if jiggle.keyed else jiggle
    base = material_for(kind)
    f_fem = float(ref.frequency_hz) * ring_factor(ref)
    shear_speed = f_fem * max(float(radius_m), 1e-9) / shape_constant(radius_m, length_m)
    mu = float(ref.density) * shear_speed ** 2
    zeta = ring_damping(ref, rest_cvs)
    return Material(youngs_pa=2.0 * (1.0 + base.poisson) * mu, poisson=base.poisson, density=float(ref.density),
                    damping_ratio=zeta, name=base.name if _same(ref, base, zeta, radius_m, length_m) else "custom")


def _same(jiggle, base: Material, zeta: float, radius_m: float, length_m: float | None = None) -> bool:
    """Whether `jiggle`, ringing down with `zeta`, is what `base` gives (its frequency and damping within 0.1%, its
    density equal)."""
    f = fem_frequency(base, radius_m, length_m) / ring_factor(jiggle)
    return (abs(float(jiggle.frequency_hz) / f - 1.0) < 1e-3 and abs(zeta - base.damping_ratio) <= 1e-3 *
            max(base.damping_ratio, 1e-3) and abs(float(jiggle.density) - base.density) < 1e-9)


def default_jiggles(rig, templates=None, scale: float = 1.0) -> list[MuscleJiggle]:
    """One MuscleJiggle per muscle of `rig` (rig.muscle.model.MuscleRig): from `templates` (a sequence
    of Jiggle, one per muscle, e.g. the fitted muscles' template entries). What a template leaves to its material
    (Jiggle.from_material: the goal springs, their damping, the density) comes from the material at the part's real
    size: its mean rest radius and rest length times `scale` (metres; rig.character.real_size.RealSize.scale), by
    sim.jiggle.materials.with_material. Without templates (a rig built in code, as the thesis's simple arm): the
    kind's default with its tuned springs (rig.muscle.template.TUNED_SPRINGS), as the thesis's demo has them."""
    from jiggle.rig.base.errors import InputError
    from jiggle.rig.muscle.material import parse_material
    from jiggle.rig.muscle.template import TUNED_SPRINGS, default_jiggle
    from jiggle.sim.jiggle.params import MAX_OFFSET_RADII, from_template
    if templates is None:
        templates = [replace(default_jiggle(k), **TUNED_SPRINGS.get(k, TUNED_SPRINGS["muscle"])) for k in rig.kinds]
    if len(templates) != rig.M:
        raise InputError(f"expected {rig.M} jiggle entries (one per muscle), got {len(templates)}", field="jiggle")
    radius = rig.mean_radii(rig.rest_cvs)
    out = []
    for m, (n, j, k) in enumerate(zip(rig.names, templates, rig.kinds)):
        need = j.from_material
        held = replace(j, **{f: TUNED_SPRINGS.get(k, TUNED_SPRINGS["muscle"])[f] for f in need})
        mj = replace(from_template(n, held), max_offset=MAX_OFFSET_RADII.get(k, MAX_OFFSET_RADII["muscle"]) * radius[m])
        if need:
            mj = with_material(mj, parse_material(j.material, where=f"{n}: jiggle.material"),
                               float(radius[m]) * scale, float(rig.rest_length[m]) * scale,
                               rig.rest_cvs[rig.cv_offsets[m]:rig.cv_offsets[m + 1]], only=need)
        out.append(mj)
    return out


__all__ = ["FEM_C", "FEM_C_SLENDER", "FEM_A", "MODAL_GAIN", "sway_mode", "particle_damping", "ring_damping", "shape_constant", "belly_goal", "ring_factor", "fem_frequency",
           "with_material", "material_of", "default_jiggles"]
