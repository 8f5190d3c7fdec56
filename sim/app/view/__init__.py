"""`jiggle view OUT_DIR`: a bake played in the browser, and re-simulated as its sliders move.

Takes a bake folder (bake.npz, bake.json; metrics.json when `jiggle compare` ran) and gives a local web
page (viser: its scene, GUI and websocket; no file of the folder is served over HTTP):

    bake.npz --playback.Playback (frames, heat bands, muscle surfaces, amplitudes)--> page.ViewerPage
    bake.json --tuning.Tuner (the setup rebuilt once: fitted rig, static shapes, goal tracks cached)
        sliders -> Tuning -> Tuner.run (particles, blend, skin only) -> Playback.replace_motion
        "save scene" -> scene_file.tuned_scene -> a scene TOML `jiggle bake` reproduces exactly
"""
