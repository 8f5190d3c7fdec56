"""Shell deformers (Pratscher et al. 2005, 4.2-4.3), all in one place.

`shells`: the maths, the per-muscle table and the float64 NumPy references; `frames`: each muscle's
per-frame ellipsoids, star tables and trajectories (`MuscleFrames`); `kernels`: the Warp kernel;
`deformer`: its launcher (`ShellDeformer`, `ShellBatch`); `weights`: painted per-vertex weights."""
