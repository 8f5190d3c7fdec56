"""A run's step sequence, written once: what the particles do over the step grid, in order.

Both ways of stepping a run walk it: the plain loop of :func:`sim.jiggle.simulate.run` does each step at once (and
reads its frames back), the chunk graph (sim/jiggle/graph.py) writes each down as device operations. Which step comes
when is decided here alone; each way says only how it does a kind of step, so the two cannot disagree on the order.

The sequence over grid (G,) seconds:

- ``start`` at grid[0]: the particles take their start state (given, the bind pose at rest, or a (re)start);
- through a cut interval grid[g..g+1] (the goal track's ``cut``): ``glue`` to the goals at grid[g+1] while the next
  interval is cut too, else ``restart`` there (the cut's far side: a fresh start);
- ``stretch``: a cut-free run of intervals grid[g..e], stepped in one go (state in -> state out, then swapped).

Each step names the grid points it reaches whose times are output frames, so both ways record the same frames.
"""
from __future__ import annotations

from typing import Iterator, NamedTuple

import numpy as np


class Step(NamedTuple):
    """One step of the sequence.

    kind : "start", "glue", "restart" or "stretch".
    g, e : the grid indices it goes from and to (equal for "start"; e = g + 1 for "glue" and "restart").
    ks : (R,) int64, the points g + ks of the grid in (g, e] (for "start": g itself) that are output frames, in order.
    """
    kind: str
    g: int
    e: int
    ks: np.ndarray


def step_sequence(track, grid: np.ndarray, is_out: np.ndarray) -> Iterator[Step]:
    """The steps over grid (G,) seconds of the goal track `track` (sim.jiggle.goal_track.GoalTrack), in order;
    is_out (G,) bool: the grid points that are output times."""
    grid = np.asarray(grid, dtype=np.float64)
    yield Step("start", 0, 0, np.flatnonzero(is_out[:1]))
    cut = track.cut[track.intervals(0.5 * (grid[:-1] + grid[1:]))]
    cut_at = np.flatnonzero(cut)
    last = len(grid) - 1
    g = 0
    while g < last:
        if cut[g]:
            kind = "glue" if g + 1 < last and cut[g + 1] else "restart"
            yield Step(kind, g, g + 1, np.flatnonzero(is_out[g + 1:g + 2]) + 1)
            g += 1
            continue
        later = cut_at[cut_at > g]
        e = int(later[0]) if len(later) else last
        yield Step("stretch", g, e, np.flatnonzero(is_out[g + 1:e + 1]) + 1)
        g = e
