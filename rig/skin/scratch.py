"""Device buffers of a batched launch, kept between calls and reallocated only when a shape changes.

The skinner and the shell deformer launch over T frames (and S sets) at a time; a bake calls them
once per chunk with the same T, so their outputs and uploads reuse one buffer per name.
"""
from __future__ import annotations

import warp as wp


class Scratch:
    """Named device arrays on one Warp device: ``scratch(name, shape, dtype)`` returns the buffer,
    allocating it (uninitialised) the first time and whenever the shape asked for changes."""

    def __init__(self, device):
        self.device = device
        self._buffers: dict[str, wp.array] = {}

    def __call__(self, name: str, shape: tuple, dtype) -> wp.array:
        buf = self._buffers.get(name)
        if buf is None or buf.shape != shape:
            buf = self._buffers[name] = wp.empty(shape, dtype=dtype, device=self.device)
        return buf
