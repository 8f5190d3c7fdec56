"""What runs over time, stage by stage: drive (MuJoCo moves the skeleton), jiggle (the particles and
the blend), bake (the chunked loop and its caches), app (the command line and what presents results)."""
