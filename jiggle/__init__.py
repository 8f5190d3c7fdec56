"""`python -m jiggle`: the `jiggle` command line (sim/app/cli.py) run as a module, for when the `jiggle`
script is not on the PATH. The library itself lives in the rig and sim packages."""
