"""The one timing helper the benchmarks share."""
from __future__ import annotations

import time


def best(fn, repeats: int = 3, warmup: bool = False):
    """(seconds, result): the fastest of `repeats` calls of `fn`, after one untimed call when
    `warmup` (compilation, caches and first allocations stay out of the figure)."""
    if warmup:
        fn()
    times, out = [], None
    for _ in range(repeats):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return min(times), out


def chunk_spans(times, knots, size: int = 64) -> list[tuple[int, int, int, int, int]]:
    """The bake's chunks of `size` output frames as sim/bake/baker.py runs them: (f0, f1, a, ka, kb) per chunk,
    its output frames f0:f1, the times it steps a:f1 (a chunk after the first goes on from the frame before
    it) and its goal knots ka:kb (MARGIN knots past its ends). times (T,), knots (S,) seconds."""
    import numpy as np

    from jiggle.sim.bake.baker import MARGIN
    from jiggle.sim.jiggle.simulate import TIME_EPS
    out = []
    for f0 in range(0, len(times), size):
        f1 = min(len(times), f0 + size)
        a = max(f0 - 1, 0)
        ka = max(0, int(np.searchsorted(knots, times[a] - TIME_EPS)) - MARGIN)
        kb = min(len(knots), int(np.searchsorted(knots, times[f1 - 1] + TIME_EPS, side="right")) + MARGIN)
        out.append((f0, f1, a, ka, kb))
    return out
