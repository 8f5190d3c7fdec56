"""One module per `jiggle` subcommand, each with `add_parser(sub)` (its options, shared groups from
sim/app/args.py) and `run(args) -> int`: inspect, play, demo, bake, batch, compare, export, view, morph,
body, fit, deform, simulate (in the order `jiggle --help` lists them, COMMANDS)."""
from jiggle.sim.app.commands import (bake, batch, body, compare, deform, demo, export, fit, inspect, morph, play, simulate,
                              view)

COMMANDS = (inspect, play, demo, bake, batch, compare, export, view, morph, body, fit, deform, simulate)
