"""The per-vertex influence gather shared by every skin kernel (LBS, DQS, shells, influence objects).

A skin vertex is moved by a few sources, each with a weight: joints with their skin weights (LBS,
DQS: a fixed k per vertex, vertex ``v`` owning entries ``v*k .. v*k + k - 1``) or muscles with their
painted pair weights (shells, influence objects: CSR pairs, vertex ``v`` owning entries
``offsets[v] .. offsets[v + 1] - 1``). Both layouts are flat arrays of sources and weights read
entry by entry; :func:`fixed_span` and :func:`csr_span` give a vertex's entries, :func:`entry` the
(source, weight) of one. What each kernel does with an influence (blend a matrix, a dual
quaternion, apply a shell, add an attachment's move) stays in that kernel: a Warp function cannot
take another as an argument.
"""
from __future__ import annotations

import warp as wp


@wp.func
def fixed_span(k: int, v: int):
    """Entries [first, end) of vertex v when every vertex has k (the top-k skin weights)."""
    return v * k, v * k + k


@wp.func
def csr_span(offsets: wp.array(dtype=wp.int32), v: int):
    """Entries [first, end) of vertex v in CSR arrays with offsets (V + 1,) (the (vertex, muscle) pairs)."""
    return offsets[v], offsets[v + 1]


@wp.func
def entry(sources: wp.array(dtype=wp.int32), weights: wp.array(dtype=wp.float32), e: int):
    """(source, weight) of entry e: a joint and its skin weight, or a muscle and its pair weight."""
    return sources[e], weights[e]
