"""Smoothing of a per-vertex field over a mesh's surface: how the skin spreads what the muscles do.

The skin over a muscle or a fat pad is an elastic sheet: it does not follow the pad's outline with a
step, it spreads the pull over a few centimetres. The shells' displacement fades out across their
drop-off band, which on a thin pad (belly fat, love handles, glutes) is narrow: at the default
strength the jiggle stretched edges there by more than their own length on every run and jump clip,
and the pectorals' static shells creased the chest (issue 18). `SurfaceSmoothing` diffuses the
deformers' displacement of the skin from the smooth skin beneath (rig.skin.muscle_skin: the static
and the jiggling skin alike; the RBF skin's jiggle, final - static) over the surface before it is
added back:

    skin' = smooth + S^n (skin - smooth),    S = (1 - step) I + step A

A: the mean over a vertex's edge neighbours; n steps spread a value over a reach of about
e sqrt(n step) (e the mean edge length), and n is chosen from a reach in metres (`steps_for_reach`),
so a coarse and a fine mesh of one body smooth alike. Averages keep a uniform offset (a rigid swing of
the whole skin) exactly, and a smooth one nearly; only the offsets' steps and spikes are spread.

Only the vertices the jiggle can move (`active`: those with deformer pairs) and the n rings around them
are computed; the rest stay 0. A field that starts on the active vertices alone (the deformers'
displacement) reaches one more ring per step: `spread_front` computes step k on the rings within k only
(the rows ordered by ring), ~15% fewer products on the generated body, with the same sums. One sparse
product per step for all frames at once (SciPy, float32, the frames side by side as columns, 16 frames
at a time so they stay in the cache through the steps):
on this 2-core machine ~0.06 ms per step and frame for 13k active vertices, several times faster
than a Warp gather kernel on the CPU.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from jiggle.rig.base.errors import InputError
from jiggle.rig.character.mesh_graph import mesh_neighbours

try:        # SciPy's CSR x dense kernel (what F @ y runs), into a result we keep: y += F x
    from scipy.sparse._sparsetools import csr_matvecs as _matvecs
except ImportError:         # a SciPy without it: F @ y, a new array per step
    _matvecs = None

JIGGLE_REACH = 0.015
"""How far the skin spreads the muscles' displacement, as a fraction of the character's size (2.7 cm
on a 1.8 m body, 7 steps on the generated body): measured on it over the shared clips
(benchmarks/bench_quality.py), 0.013 left a torn edge on 09_11 and a gradient p99.9 of 0.52 on 02_04,
0.015 one torn edge in the 688 frames of 01_01 and a p99.9 of 0.46 at worst; each step costs ~0.06 ms a
frame and skin."""
STEP = 0.9
"""Each step moves a value 9/10 of the way to its neighbours' mean. The operator's eigenvalues are
1 - step (1 - lambda) for the neighbour mean's lambda in [-1, 1]: in [-0.8, 1] on any mesh, so
nothing grows and a pattern that flips sign from vertex to vertex still dies out (on the generated
body lambda >= -0.49 and on CesiumMan >= -0.67: within [-0.5, 1]). A larger step spreads a value
farther per step: 7 steps where 1/2 took 13 for the same reach."""
MAX_STEPS = 60
BLOCK = 48
"""Columns (16 frames x xyz) smoothed together: ~1 MB per 20k rows, kept in the cache over the steps."""


_POOL = None


def pool():
    """Two worker threads shared by every smoothing (made on first use)."""
    global _POOL
    if _POOL is None:
        from concurrent.futures import ThreadPoolExecutor
        _POOL = ThreadPoolExecutor(max_workers=2, thread_name_prefix="jiggle-smooth")
    return _POOL


def steps_for_reach(vertices: np.ndarray, faces: np.ndarray, reach: float, step: float = STEP) -> int:
    """Smoothing steps that spread a value over `reach` metres: (reach / e)^2 / step, e the mean edge
    length, at most MAX_STEPS."""
    faces = np.asarray(faces, dtype=np.int64)
    if reach <= 0 or len(faces) == 0:
        return 0
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    mean_edge = float(np.linalg.norm(vertices[e[:, 0]] - vertices[e[:, 1]], axis=1).mean())
    return int(min(MAX_STEPS, round((reach / mean_edge) ** 2 / step))) if mean_edge > 0 else 0


class SurfaceSmoothing:
    """n steps of S over a mesh, restricted to the vertices within n rings of `active` (see the module).

    faces : (F, 3). num_vertices : V. steps : n >= 0 (0: the identity). active : (V,) bool or None (all).
    """

    def __init__(self, faces: np.ndarray, num_vertices: int, steps: int, active: np.ndarray | None = None,
                 step: float = STEP):
        if isinstance(steps, bool) or int(steps) != steps or steps < 0:
            raise InputError(f"expected a whole number >= 0, got {steps!r}", field="steps")
        if not 0.0 < step <= 1.0:
            raise InputError(f"expected a number in (0, 1], got {step}", field="step")
        self.steps, self.num_vertices = int(steps), int(num_vertices)
        A = mesh_neighbours(faces, num_vertices)
        reach = np.ones(num_vertices, bool) if active is None else np.asarray(active, bool).copy()
        if reach.shape != (num_vertices,):
            raise InputError(f"expected ({num_vertices},) bools, got {reach.shape}", field="active")
        for _ in range(self.steps):                     # the n rings the values spread into
            if reach.all():
                break
            reach |= (A @ reach.astype(np.float32)) > 0
        self.rows = np.nonzero(reach)[0]
        deg = np.asarray(A.sum(axis=1)).ravel()
        mean = sp.diags(np.where(deg > 0, 1.0 / np.maximum(deg, 1.0), 0.0).astype(np.float32)) @ A
        # a vertex on no edge keeps its value: its row of `mean` is itself
        lone = deg == 0
        mean = mean + sp.diags(lone.astype(np.float32))
        S = (1.0 - step) * sp.identity(num_vertices, np.float32, format="csr") + step * mean
        self.matrix = S.tocsr()[self.rows][:, self.rows].astype(np.float32).tocsr()
        self._fronts(A, active)

    def _fronts(self, A, active) -> None:
        """The rows by ring (`order`, `ring_ends`) and each step's operator on its front (`front`).

        order : (R,) the computed rows' vertices, ring by ring from `active` (ring 0; ascending within
        a ring). ring_ends : (n + 1,) rows within k rings are order[:ring_ends[k]].
        front : n CSR matrices, step k's rows within k rings and columns within k - 1 (in `order`):
        a field zero beyond ring 0 stays zero beyond ring k after k steps, so the other entries only
        ever add exact zeros. Each row keeps `matrix`'s entries in their stored order, so the sums run
        in the same order and :meth:`spread_front` equals :meth:`smooth_rows` bit for bit.
        """
        R, n = len(self.rows), self.steps
        ring = np.full(self.num_vertices, n + 1, np.int64)
        if active is None:
            ring[:] = 0
        else:
            reach = np.asarray(active, bool).copy()
            ring[reach] = 0
            for k in range(1, n + 1):
                reach |= (A @ reach.astype(np.float32)) > 0
                ring[reach & (ring > n)] = k
        rr = ring[self.rows]
        order = np.lexsort((self.rows, rr))                      # row-space indices, by ring then vertex
        self.order = self.rows[order]
        self.ring_ends = np.searchsorted(rr[order], np.arange(n + 1), side="right")
        new = np.empty(R, np.int64)
        new[order] = np.arange(R)                                 # row-space index -> position in order
        M = self.matrix
        lengths = np.diff(M.indptr)[order]
        starts = np.repeat(M.indptr[:-1][order], lengths)
        entry = starts + np.arange(lengths.sum()) - np.repeat(np.cumsum(lengths) - lengths, lengths)
        row = np.repeat(np.arange(R), lengths)                    # each entry's row, in order
        col, val = new[M.indices[entry]], M.data[entry].astype(np.float32)
        self.front = []
        for k in range(1, n + 1):
            rows_k, cols_k = int(self.ring_ends[k]), int(self.ring_ends[k - 1])
            keep = (row < rows_k) & (col < cols_k)
            indptr = np.zeros(rows_k + 1, np.int64)
            np.cumsum(np.bincount(row[keep], minlength=rows_k), out=indptr[1:])
            self.front.append(sp.csr_matrix((val[keep], col[keep].astype(np.int32), indptr.astype(np.int32)),
                                            shape=(rows_k, cols_k)))

    def __call__(self, field: np.ndarray) -> np.ndarray:
        """The smoothed field: (V, 3) or (T, V, 3) float32 (values outside the computed rows kept as given)."""
        f = np.asarray(field, dtype=np.float32)
        if f.shape[-2:] != (self.num_vertices, 3) or f.ndim not in (2, 3):
            raise InputError(f"expected (V, 3) or (T, V, 3) with V = {self.num_vertices}, got {f.shape}", field="field")
        if self.steps == 0 or len(self.rows) == 0:
            return f.copy()
        batch = f.reshape(-1, self.num_vertices, 3)
        T = len(batch)
        x = self.smooth_rows(batch[:, self.rows].transpose(1, 0, 2).reshape(len(self.rows), 3 * T))
        out = batch.copy()
        out[:, self.rows] = x.reshape(len(self.rows), T, 3).transpose(1, 0, 2)
        return out.reshape(f.shape)

    def spread_front(self, x: np.ndarray, out: np.ndarray | None = None, work: np.ndarray | None = None
                     ) -> np.ndarray:
        """The steps on a field that is zero beyond ring 0: x (ring_ends[0], C) float32, ring 0's rows
        (the active vertices, ascending) -> (R, C) float32, the rows in `order`, into `out` when given.
        Equal to :meth:`smooth_rows` of the field (zeros elsewhere) with its rows put in `order`; step
        k computes only the rows within k rings (`front`), from those within k - 1. The columns are
        taken a block at a time (BLOCK: they stay in the cache through the steps); one thread.

        work : (2, R * BLOCK) float32 (:meth:`workspace`), or None: the steps' products go into it
        (and the last straight into a C-contiguous `out` of at most BLOCK columns) instead of a new
        array per step; what the bake wants, where every array over 128 kB is a fresh mapping whose
        pages fault in (sim/bake/baker.py). The sums are the same either way (SciPy's own kernel)."""
        x = np.asarray(x, dtype=np.float32)
        n0, R = int(self.ring_ends[0]), len(self.rows)
        if x.ndim != 2 or x.shape[0] != n0:
            raise InputError(f"expected ({n0}, C) rows of ring 0, got {x.shape}", field="x")
        out = np.empty((R, x.shape[1]), np.float32) if out is None else out
        if work is not None and _matvecs is not None:
            if work.dtype != np.float32 or work.shape != (2, R * BLOCK) or not work.flags.c_contiguous:
                raise InputError(f"expected (2, {R * BLOCK}) float32, got {work.shape} {work.dtype}", field="work")
            direct = len(self.front) > 0 and out.flags.c_contiguous and out.shape[1] <= BLOCK
            for a in range(0, x.shape[1], BLOCK):
                C = min(BLOCK, x.shape[1] - a)
                y = work[0, :n0 * C].reshape(n0, C)
                np.copyto(y, x[:, a:a + C])
                for k, F in enumerate(self.front):
                    last = k == len(self.front) - 1
                    z = out if last and direct else work[(k + 1) % 2, :F.shape[0] * C].reshape(F.shape[0], C)
                    z.fill(0.0)         # SciPy's product adds into its (zeroed) result: F @ y's sums exactly
                    _matvecs(F.shape[0], F.shape[1], C, F.indptr, F.indices, F.data, y.reshape(-1), z.reshape(-1))
                    y = z
                if not direct:
                    out[:, a:a + C] = y
            return out
        for a in range(0, x.shape[1], BLOCK):
            y = np.ascontiguousarray(x[:, a:a + BLOCK])
            for F in self.front:
                y = F @ y
            out[:, a:a + BLOCK] = y
        return out

    def spread_device(self, smooth, moved):
        """The spread on a Warp device, for a GPU (where the CPU's blocks and SciPy would mean copying the
        displacements to the host and the skins back): smooth (T, V) wp.vec3, the smooth skin, metres;
        moved (n0, T) wp.vec3, ring 0's displacements (the active vertices, ascending: :meth:`spread_front`'s
        x) -> a new (T, V) wp.vec3 array on the device, smooth + the spread displacement on the computed
        rows, smooth elsewhere. One launch per step over its front (rows within k rings) and one to add;
        the same sums as spread_front (float32, each row's entries in stored order), to float32 rounding
        (a GPU may fuse the product and the sum)."""
        import warp as wp

        from jiggle.rig.skin import smoothing_kernels as k
        device = smooth.device
        T = smooth.shape[0]
        out = wp.clone(smooth)
        if self.steps == 0 or len(self.rows) == 0 or T == 0:
            return out
        fronts, order = self._device_fronts(device)
        y = moved
        for (indptr, indices, data), F in zip(fronts, self.front):
            z = wp.empty((F.shape[0], T), dtype=wp.vec3, device=device)
            wp.launch(k.front_step, dim=(F.shape[0], T), inputs=[indptr, indices, data, y], outputs=[z], device=device)
            y = z
        wp.launch(k.add_spread, dim=(len(self.order), T), inputs=[smooth, order, y], outputs=[out], device=device)
        return out

    def _device_fronts(self, device):
        """Each step's front (indptr, indices, data) and `order` as Warp arrays on `device`, made once."""
        import warp as wp
        key = str(device)
        cached = getattr(self, "_on_device", {})
        if key not in cached:
            fronts = [tuple(wp.array(a, dtype=t, device=device) for a, t in
                            ((F.indptr.astype(np.int32), wp.int32), (F.indices.astype(np.int32), wp.int32),
                             (F.data.astype(np.float32), wp.float32))) for F in self.front]
            cached[key] = (fronts, wp.array(self.order.astype(np.int32), dtype=wp.int32, device=device))
            self._on_device = cached
        return cached[key]

    def workspace(self) -> np.ndarray:
        """(2, R * BLOCK) float32, uninitialised: the products of :meth:`spread_front` (`work`)."""
        return np.empty((2, len(self.rows) * BLOCK), np.float32)

    def smooth_rows(self, x: np.ndarray, copy: bool = True, threads: bool = True) -> np.ndarray:
        """The steps on the computed rows alone: x (R, C) float32, R = len(rows), any C columns (e.g.
        frames x xyz side by side) -> (R, C) float32, a new array (copy False: x itself when it is a
        C-contiguous float32 array, smoothed in place). threads: share the column blocks between two
        threads."""
        x = np.array(x, dtype=np.float32, order="C", copy=True if copy else None)
        if x.shape[0] != len(self.rows):
            raise InputError(f"expected {len(self.rows)} rows, got {x.shape[0]}", field="x")
        def block(a: int) -> None:
            y = np.ascontiguousarray(x[:, a:a + BLOCK])
            for _ in range(self.steps):
                y = self.matrix @ y
            x[:, a:a + BLOCK] = y
        # a few frames' columns at a time stay in the cache through all the steps; the blocks are
        # independent, so two threads share them (SciPy's product runs without the GIL, ~1.3x here)
        starts = range(0, x.shape[1], BLOCK)
        if threads and len(starts) > 1:
            list(pool().map(block, starts))
        else:
            for a in starts:
                block(a)
        return x
