"""The bake: a scene or a request in; caches on disk out.

`scene` reads scene TOML; `setup.prepare` builds everything that stays fixed while a clip plays
(motion, character, muscles, skin, jiggle parameters, output times) into a `BakeSetup`; `baker`
runs the chunked loop (drive -> static CVs -> simulate -> blend -> skin, a chunk of frames at a
time, resumable) and `caches` writes USD, npz and pc2. Imports sim.jiggle, sim.drive and rig.*."""
