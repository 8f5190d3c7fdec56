"""`python -m jiggle ARGS`: the same as `jiggle ARGS` (same options, output and exit codes)."""
import sys

from jiggle.sim.app.cli import main

if __name__ == "__main__":
    sys.exit(main())
