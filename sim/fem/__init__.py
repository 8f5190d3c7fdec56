"""The volumetric finite-element reference of the tissue (issue 49, part 3): a peer of sim/jiggle.

In: one muscle part's rest CVs (rig.muscle.model.MuscleRig, 40 per part), a tissue Material
(rig.muscle.material: E, nu, rho, zeta) and the part's static CVs over time (rig.static(world).cvs at knots: the
goal shape the particles are driven by too).
Out: the part as a tetrahedral Neo-Hookean solid (tet_mesh) whose every vertex has loft coordinates (its goal is a
fixed linear map of the 40 CVs), simulated with Newton's VBD solver on the CPU (solve: core at its goal, rest shape
= the goal shape; Rayleigh damping at the material's ratio across its low modes, modes), its offsets from the goal
and what they measure: peak displacement, dominant frequency, damping ratio and log decrement (measure); the
ring-down experiments of the calibration (experiments) and the comparison
with the particles (benchmarks/fem_reference.py).

sim.fem imports rig.* only; comparisons with the particle model (sim.jiggle) live in the benchmark and tests.
"""
