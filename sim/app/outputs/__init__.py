"""What each command writes besides a bake, one module per command: inspect (a file's facts as text and JSON),
play (a clip on its skeleton as frames and a video), body, fit, deform, simulate and morph (their pictures,
meshes, TOML and JSON). Each takes the command's results and writes files into its output folder.
"""
