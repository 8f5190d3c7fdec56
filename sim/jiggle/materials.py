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

its density to the material's and its damping ratio to the one that makes the part ring with the material's ratio:
the particles' own ring-down damping is more than their goal springs' damping_ratio (each CV's damper is 2 zeta
omega_i m_i at its own omega_i, the stiff tendon CVs' too, and the neighbour springs have dampers of their own), by
PARTICLE_DAMPING's (A, B) of the part's kind (realized = A + B damping_ratio, fitted to the ring-downs of the
calibration parts: benchmarks/fem_reference.py, "Particle damping"), so

    damping_ratio = max((zeta - A) / B, 0).

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


PARTICLE_DAMPING = {"fat": (0.180, 0.925), "muscle": (0.072, 1.040)}
"""(A, B) per part kind: a part's particles ring down with zeta = A + B damping_ratio (benchmarks/results/
fem_reference.md, "Particle damping": 8 ring-downs of CesiumMan's fat parts, rms 0.040; 28 of its muscles and of
lofted ellipsoids, rms 0.044). A fat part's lower tendon-to-belly goal weights leave more of its mode on the stiff
ends' dampers. Other kinds take the muscle's."""


def particle_damping(zeta: float, kind: str | None = None) -> float:
    """The goal springs' damping_ratio with which a part of `kind` rings down with damping ratio `zeta`
    (PARTICLE_DAMPING inverted; 0 where zeta is below what the particles damp on their own)."""
    A, B = PARTICLE_DAMPING.get(kind or "muscle", PARTICLE_DAMPING["muscle"])
    return max((float(zeta) - A) / B, 0.0)


def ring_damping(damping_ratio: float, kind: str | None = None) -> float:
    """The damping ratio a part of `kind` with goal springs of `damping_ratio` rings down with (PARTICLE_DAMPING)."""
    A, B = PARTICLE_DAMPING.get(kind or "muscle", PARTICLE_DAMPING["muscle"])
    return A + B * float(damping_ratio)


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
                  kind: str | None = None):
    """`jiggle` (sim.jiggle.params.MuscleJiggle) with its goal springs, damping ratio and density from `material`
    for a part of `kind` ("fat", "muscle": its template's, which sets how much its particles damp on their own),
    mean radius `radius_m` and rest length `length_m` (metres, real size)."""
    f = fem_frequency(material, radius_m, length_m) / ring_factor(jiggle)
    return replace(jiggle, frequency_hz=float(f), damping_ratio=particle_damping(material.damping_ratio, kind),
                   density=float(material.density))


def material_of(jiggle, kind: str, radius_m: float, length_m: float | None = None) -> Material:
    """The Material a part of `kind` whose goal springs are `jiggle` stands for: E from its frequency_hz (its
    reference value for a keyed one) by the module's rule inverted (radius_m, length_m as fem_frequency), nu of its
    kind's material, its density, and the damping ratio it rings down with (ring_damping)."""
    ref = jiggle.reference() if jiggle.keyed else jiggle
    base = material_for(kind)
    f_fem = float(ref.frequency_hz) * ring_factor(ref)
    shear_speed = f_fem * max(float(radius_m), 1e-9) / shape_constant(radius_m, length_m)
    mu = float(ref.density) * shear_speed ** 2
    return Material(youngs_pa=2.0 * (1.0 + base.poisson) * mu, poisson=base.poisson, density=float(ref.density),
                    damping_ratio=ring_damping(ref.damping_ratio, kind),
                    name=base.name if _same(ref, base, radius_m, length_m, kind) else "custom")


def _same(jiggle, base: Material, radius_m: float, length_m: float | None = None, kind: str | None = None) -> bool:
    """Whether `jiggle` is what `base` gives (its frequency within 0.1%, its damping and density equal)."""
    f = fem_frequency(base, radius_m, length_m) / ring_factor(jiggle)
    return (abs(float(jiggle.frequency_hz) / f - 1.0) < 1e-3 and abs(float(jiggle.damping_ratio) -
            particle_damping(base.damping_ratio, kind)) < 1e-9 and abs(float(jiggle.density) - base.density) < 1e-9)


__all__ = ["FEM_C", "FEM_C_SLENDER", "FEM_A", "PARTICLE_DAMPING", "particle_damping", "ring_damping", "shape_constant", "belly_goal", "ring_factor", "fem_frequency",
           "with_material", "material_of"]
