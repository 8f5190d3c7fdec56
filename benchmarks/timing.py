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
