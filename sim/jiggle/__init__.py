"""Jiggle: static muscle CVs over time in; dynamic CVs and the blend out.

A Model / State / Solver seam, as in Newton: `particles` builds the particle model once (a particle
on every CV, masses, goal and neighbour springs from `params`) and its two-buffer state;
`goal_track` / `goal_flow` carry the static CVs as moving goals; `solver.ParticleSolver` steps the
Warp kernels (`particle_kernels`); `keyed` holds the parameter curves and globs, and
`keyed_solver.KeyedSolver` (`keyed_kernels`) the goal springs of keyed muscles, per knot interval. The pipeline's stage functions are `simulate.goals` and
`simulate.simulate` (static CVs at goal knots -> dynamic CVs at output times, resumable) and
`blend.blend` (cvs = static + b (dynamic - static), weights from `blend.blend_weights`);
`secondary.jiggle_rig` runs static -> simulate -> blend over a whole clip (`jiggle simulate`).
Imports rig.*; not sim.drive, sim.bake or sim.app."""
