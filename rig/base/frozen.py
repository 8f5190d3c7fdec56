"""Read-only arrays for data that is built once and never changed while a clip plays."""
from __future__ import annotations

import numpy as np


def frozen_array(a, dtype=np.float64) -> np.ndarray:
    """A read-only copy of `a` as `dtype` (writes raise ValueError)."""
    a = np.array(a, dtype=dtype, copy=True)
    a.setflags(write=False)
    return a
