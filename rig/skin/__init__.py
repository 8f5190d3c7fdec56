"""Skin: joint transforms and muscle CVs per frame in; the deformed skin out.

`skinning` (LBS / DQS, kernels in `skinning_kernels`) poses the rest skin; then every muscle's shell
deformer (`shell/`: maths, per-frame frames, Warp kernels, launcher, painted weights), or influence
objects (`influence`), or the anatomy's RBF (`rbf_skin`) adds what the muscles do beyond their bones.
`muscle_skin.MuscleSkin` is the one front door (bind once, `pose` / `pose_batch` per frame) and
`muscle_skin.skin_frames` the pipeline's skin stage; the skin spreads what the muscles do over its
surface (`surface_smoothing`), `delta_mush` cleans the smooth skin on request, and `quality` measures
folds and tears per frame. Every kernel reads a vertex's weighted influences the same way
(`gather_kernels`); batched launches keep their buffers in a `scratch.Scratch`. Imports every rig
stage below it."""
