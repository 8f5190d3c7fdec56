"""Launcher of the shell deformers (kernel :func:`rig.skin.shell.kernels.shells`, math in :mod:`rig.skin.shell.shells`).

The per-muscle table and the culled (vertex, muscle) pairs are uploaded once; each frame uploads only
the M ellipsoids, curves and active flags (float32) and runs one launch over the vertices, taking the
skinned points as a device array and returning the wrapper's device buffer.

Batched (`launch_batch`, kernel :func:`rig.skin.shell.kernels.shells_batch`): a chunk of T frames and S
sets of muscle states (e.g. static and blended CVs) in one upload and one launch over the vertices
that have pairs (on the CPU a thread runs its vertex through every frame and set; on a GPU a thread
per frame and vertex); the reference ellipsoids ride the bones and are shared by the sets
(:class:`ShellBatch`). `launch_displace` runs the same launch but returns only the paired vertices'
displacements from the smooth skin, (S, P, T), the layout the skin's spread smooths
(rig.skin.muscle_skin.MuscleSkin.pose_batch): nothing is copied for the other vertices. In either, a
pair's reference part is computed once for all sets that share its point (kernels.shell_sets).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from jiggle.rig.base.errors import InputError
from jiggle.rig.skin.scratch import Scratch
from jiggle.rig.skin.shell import kernels
from jiggle.rig.skin.shell.shells import ShellFrames, ShellTable


@dataclass(frozen=True)
class ShellModel:
    """The deformers on the device; built once, never changed.

    pair_offsets : (V + 1,) int32 CSR offsets. pair_muscle : (P,) int32. pair_weight : (P,) float32.
    sticky, hard, drop_off, weight, slippage : (M,) float32. mode, star_index : (M,) int32.
    star : (max(S, 1), 17, 32) float32 (one zero table stands in when S == 0).
    star_max : (max(S, 1),) float32, each table's largest offset (the kernel's early-out bound).
    paired : (num_paired,) int32, ascending, the vertices owning at least one pair (the batched
        launch deforms only these and copies the others).
    arrays : the same arrays as the kernels' ShellArrays struct (what every launch passes).
    """

    pair_offsets: wp.array
    pair_muscle: wp.array
    pair_weight: wp.array
    sticky: wp.array
    hard: wp.array
    drop_off: wp.array
    weight: wp.array
    slippage: wp.array
    mode: wp.array
    star_index: wp.array
    star: wp.array
    star_max: wp.array
    paired: wp.array
    num_vertices: int
    num_pairs: int
    num_muscles: int
    num_paired: int
    arrays: kernels.ShellArrays


@dataclass(frozen=True)
class ShellBatch:
    """The ellipsoids of S sets of muscle states over T frames (the batched launch's state).

    E_ref, E_ref_inv : (T, M, 4, 4) float64, the rest ellipsoids carried by the bones and their
        inverses, shared by every set (local unit sphere -> world, metres).
    E_cur, E_cur_inv : (S, T, M, 4, 4) float64, the ellipsoids fitted to each set's CVs.
    curve : (S, T, M, K, 3) float64, metres, trajectory samples (as :class:`rig.skin.shell.shells.ShellFrames`).
    active : (S, T, M) bool; False: the muscle is skipped in that set and frame.

    Set s at frame t is ``ShellFrames(E_ref[t], E_ref_inv[t], E_cur[s, t], E_cur_inv[s, t],
    curve[s, t], active[s, t])``. Shapes are checked (InputError naming the field); arrays are
    converted, not copied when already float64 / bool.
    """

    E_ref: np.ndarray
    E_ref_inv: np.ndarray
    E_cur: np.ndarray
    E_cur_inv: np.ndarray
    curve: np.ndarray
    active: np.ndarray

    def __post_init__(self):
        ref = np.asarray(self.E_ref, dtype=np.float64)
        if ref.ndim != 4 or ref.shape[2:] != (4, 4):
            raise InputError(f"expected shape (T, M, 4, 4), got {ref.shape}", field="E_ref")
        T, M = ref.shape[:2]
        cur = np.asarray(self.E_cur, dtype=np.float64)
        if cur.ndim != 5 or cur.shape[1:] != (T, M, 4, 4):
            raise InputError(f"expected shape (S, {T}, {M}, 4, 4), got {cur.shape}", field="E_cur")
        S = cur.shape[0]
        want = {"E_ref": (T, M, 4, 4), "E_ref_inv": (T, M, 4, 4), "E_cur": (S, T, M, 4, 4),
                "E_cur_inv": (S, T, M, 4, 4)}
        for k, shape in want.items():
            a = np.asarray(getattr(self, k), dtype=np.float64)
            if a.shape != shape:
                raise InputError(f"expected shape {shape}, got {a.shape}", field=k)
            object.__setattr__(self, k, a)
        curve = np.asarray(self.curve, dtype=np.float64)
        if curve.ndim != 5 or curve.shape[:3] != (S, T, M) or curve.shape[4] != 3 or curve.shape[3] < 2:
            raise InputError(f"expected shape ({S}, {T}, {M}, K >= 2, 3), got {curve.shape}", field="curve")
        object.__setattr__(self, "curve", curve)
        active = np.asarray(self.active)
        if active.shape != (S, T, M):
            raise InputError(f"expected shape ({S}, {T}, {M}), got {active.shape}", field="active")
        object.__setattr__(self, "active", active.astype(bool, copy=False))

    @property
    def num_sets(self) -> int:
        return self.E_cur.shape[0]

    @property
    def num_frames(self) -> int:
        return self.E_ref.shape[0]

    @property
    def num_muscles(self) -> int:
        return self.E_ref.shape[1]


def check_pairs(pair_offsets, pair_muscle, pair_weight, num_muscles: int
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Validated CSR pairs: offsets (V + 1,) int32, muscle (P,) int32, weight (P,) float32.

    Raises InputError naming the array: wrong shapes or dtypes, offsets not starting at 0, not
    non-decreasing or not ending at P, muscles out of [0, M) or not strictly ascending within a
    vertex (the series order), weights outside [0, 1] or NaN.
    """
    off = np.asarray(pair_offsets)
    mus = np.asarray(pair_muscle)
    wts = np.asarray(pair_weight)
    if off.ndim != 1 or off.shape[0] < 1 or not np.issubdtype(off.dtype, np.integer):
        raise InputError(f"expected (V + 1,) integers, got shape {off.shape} dtype {off.dtype}",
                         field="pair_offsets")
    if mus.ndim != 1 or not np.issubdtype(mus.dtype, np.integer):
        raise InputError(f"expected (P,) integers, got shape {mus.shape} dtype {mus.dtype}",
                         field="pair_muscle")
    P = mus.shape[0]
    if wts.shape != (P,) or not np.issubdtype(wts.dtype, np.number):
        raise InputError(f"expected ({P},) floats (one per pair), got shape {wts.shape} dtype {wts.dtype}",
                         field="pair_weight")
    if off[0] != 0 or off[-1] != P or np.any(np.diff(off) < 0):
        raise InputError(f"expected non-decreasing offsets from 0 to P = {P}, got {off[0]} .. {off[-1]}",
                         field="pair_offsets")
    if P and (mus.min() < 0 or mus.max() >= num_muscles):
        raise InputError(f"expected muscle indices in [0, {num_muscles}), got [{mus.min()}, {mus.max()}]",
                         field="pair_muscle")
    # within a vertex the muscles must ascend: a step that does not ascend must start a vertex
    starts = np.zeros(P, bool)
    starts[off[:-1][off[:-1] < P]] = True
    if P > 1 and np.any((np.diff(mus) <= 0) & ~starts[1:]):
        raise InputError("expected strictly ascending muscles within each vertex", field="pair_muscle")
    w = wts.astype(np.float64)
    if not np.all((w >= 0.0) & (w <= 1.0)):
        raise InputError("expected painted weights in [0, 1] (no NaN)", field="pair_weight")
    return off.astype(np.int32), mus.astype(np.int32), w.astype(np.float32)


def _struct(struct, fields: dict):
    """`struct` (a Warp struct instance) with its fields set from `fields`."""
    for k, v in fields.items():
        setattr(struct, k, v)
    return struct


def _state(E_ref, E_ref_inv, dE, E_cur_inv, centre, curve, active) -> kernels.ShellState:
    """The kernels' per-launch state struct over device arrays (no copy)."""
    return _struct(kernels.ShellState(), dict(E_ref=E_ref, E_ref_inv=E_ref_inv, dE=dE, E_cur_inv=E_cur_inv,
                                              centre=centre, curve=curve, active=active))


class ShellDeformer:
    """All muscles' shell deformers on one skin, in series, with Warp.

    Parameters
    ----------
    table : the M muscles' parameters and star tables (:func:`rig.skin.shell.shells.shell_table`).
    pair_offsets : (V + 1,) int, CSR over the skin's V vertices (:func:`rig.skin.shell.shells.cull_pairs`).
    pair_muscle : (P,) int, strictly ascending within each vertex.
    pair_weight : (P,) float in [0, 1], the painted weights w_i.
    device : Warp device for the model, the buffers and every launch.

    `thread_per_frame` (default: True on a GPU, False on the CPU) chooses the batched launch's threads:
    one per frame and paired vertex, or one per paired vertex running through the frames.
    """

    def __init__(self, table: ShellTable, pair_offsets, pair_muscle, pair_weight, device="cpu"):
        if not isinstance(table, ShellTable):
            raise InputError(f"expected a ShellTable, got {type(table).__name__}", field="table")
        M = table.num_muscles
        off, mus, wts = check_pairs(pair_offsets, pair_muscle, pair_weight, M)
        self.device = wp.get_device(device)
        star = table.star if table.star.shape[0] else np.zeros((1,) + table.star.shape[1:], np.float32)
        paired = np.nonzero(np.diff(off) > 0)[0]

        def f32(a):
            return wp.array(np.asarray(a, np.float32), dtype=wp.float32, device=self.device)

        def i32(a):
            return wp.array(np.asarray(a, np.int32), dtype=wp.int32, device=self.device)

        arrays = dict(
            pair_offsets=i32(off), pair_muscle=i32(mus), pair_weight=f32(wts),
            sticky=f32(table.sticky), hard=f32(table.hard), drop_off=f32(table.drop_off),
            weight=f32(table.weight), slippage=f32(table.slippage), mode=i32(table.mode),
            star_index=i32(table.star_index),
            star=wp.array(np.asarray(star, np.float32), dtype=wp.float32, device=self.device),
            star_max=f32(np.max(star, axis=(1, 2))))
        self.model = ShellModel(
            **arrays, paired=i32(paired), num_vertices=int(off.shape[0] - 1), num_pairs=int(mus.shape[0]),
            num_muscles=int(M), num_paired=len(paired), arrays=_struct(kernels.ShellArrays(), arrays))
        V = self.model.num_vertices
        self._points_out = wp.empty(V, dtype=wp.vec3, device=self.device)
        self._E = [wp.empty(M, dtype=wp.mat44, device=self.device) for _ in range(4)]
        self._centre = wp.empty(M, dtype=wp.vec3, device=self.device)
        self._active = wp.empty(M, dtype=wp.int32, device=self.device)
        self._curve = None
        self._scratch = Scratch(self.device)      # the batched launch's buffers, sized (S, T, ...)
        # batched launches: a thread per frame and vertex (GPU) or per vertex, running through the frames
        # (CPU: Warp's CPU launch divides the index of every thread of a multi-dimensional launch)
        self.thread_per_frame = not self.device.is_cpu
        self.launches = 0
        """Warp launches made so far (every launch method adds its own)."""

    @property
    def num_vertices(self) -> int:
        return self.model.num_vertices

    def deform(self, points, frames: ShellFrames) -> np.ndarray:
        """points : (V, 3) float, metres -> (V, 3) float32, metres, a new array."""
        p = np.asarray(points)
        if p.shape != (self.num_vertices, 3):
            raise InputError(f"expected shape ({self.num_vertices}, 3), got {p.shape}", field="points")
        pts = wp.array(p.astype(np.float32), dtype=wp.vec3, device=self.device)
        out = self.launch(pts, frames).numpy()
        # on the CPU .numpy() is a view of the buffer the next call overwrites
        return out.copy() if self.device.is_cpu else out

    def launch(self, points: wp.array, frames: ShellFrames) -> wp.array:
        """Deform on the device; returns the wrapper's (V,) wp.vec3 buffer, valid until the next call.

        points : (V,) wp.vec3 on this deformer's device, metres (e.g. :meth:`rig.skin.skinning.Skinner.launch`).
        frames : this frame's ellipsoids of the M muscles; active muscles must be finite.
        """
        model = self.model
        if not isinstance(points, wp.array) or points.dtype != wp.vec3 or points.shape != (model.num_vertices,):
            shape = getattr(points, "shape", None)
            raise InputError(f"expected a ({model.num_vertices},) wp.vec3 array, got {type(points).__name__} "
                             f"shape {shape}", field="points")
        self._upload(frames)
        if model.num_vertices == 0:
            return self._points_out
        if model.num_pairs == 0:
            wp.copy(self._points_out, points)
            return self._points_out
        state = _state(*self._E, self._centre, self._curve, self._active)
        wp.launch(kernels.shells, dim=model.num_vertices, device=self.device,
                  inputs=[model.arrays, state, points], outputs=[self._points_out])
        self.launches += 1
        return self._points_out

    def deform_batch(self, points, batch: ShellBatch) -> np.ndarray:
        """points : (T, V, 3) float, metres -> (S, T, V, 3) float32, metres, a new array."""
        p = np.asarray(points)
        if p.ndim != 3 or p.shape[1:] != (self.num_vertices, 3):
            raise InputError(f"expected shape (T, {self.num_vertices}, 3), got {p.shape}", field="points")
        pts = wp.array(p.astype(np.float32), dtype=wp.vec3, device=self.device)
        out = self.launch_batch(pts, batch).numpy()
        return out.copy() if self.device.is_cpu else out

    def launch_batch(self, points: wp.array, batch: ShellBatch) -> wp.array:
        """Deform T frames for S sets on the device in one launch over the vertices that have pairs
        (the others are copied); returns the wrapper's (S, T, V) wp.vec3 buffer, valid until the next
        batched call.

        points : (T, V) wp.vec3 on this deformer's device, metres, shared by the sets (e.g.
            :meth:`rig.skin.skinning.Skinner.launch_batch`).
        batch : the T frames' ellipsoids for the S sets; active muscles must be finite.
        Row [s, t] equals :meth:`launch` of points[t] with set s's frame t (the same per-vertex code).
        """
        model = self.model
        S, T, V = self._check_batch(points, batch)
        M = batch.num_muscles
        out = self._scratch("points_out", (S, T, V), wp.vec3)
        if S * T * V == 0:
            return out
        # every set starts from the smooth skin; the kernel then rewrites the paired vertices only
        for s in range(S):
            wp.copy(out, points, dest_offset=s * T * V, count=T * V)
        if model.num_paired == 0:
            return out
        state = self._upload_batch(batch)
        stride = T if self.thread_per_frame else 1
        wp.launch(kernels.shells_batch, dim=(stride, model.num_paired), device=self.device,
                  inputs=[model.arrays, model.paired, M, stride, _state(*state), points], outputs=[out])
        self.launches += 1
        return out

    def launch_displace(self, points: wp.array, batch: ShellBatch, out: wp.array | None = None) -> wp.array:
        """The displacements of the paired vertices only, (S, P, T) wp.vec3, metres, the wrapper's
        buffer valid until the next call (or `out`): [s, i, t] = :meth:`launch_batch`'s
        [s, t, paired[i]] minus points[t, paired[i]] (float32), P = `model.num_paired`, `model.paired`
        ascending. Every other vertex is left where the smooth skin puts it; one launch, nothing
        copied for them.

        points, batch : as :meth:`launch_batch`.
        out : a (S, P, T) wp.vec3 array on this device to write into instead (e.g. on the CPU a NumPy
            array the caller keeps, wrapped without a copy), or None.
        """
        model = self.model
        S, T, V = self._check_batch(points, batch)
        shape = (S, model.num_paired, T)
        if out is None:
            out = self._scratch("moved_out", shape, wp.vec3)
        elif (not isinstance(out, wp.array) or out.dtype != wp.vec3 or out.shape != shape
              or out.device != self.device):
            raise InputError(f"expected a {shape} wp.vec3 array on {self.device}", field="out")
        if S * T * model.num_paired == 0:
            return out
        state = self._upload_batch(batch)
        stride = T if self.thread_per_frame else 1
        wp.launch(kernels.shells_displace, dim=(stride, model.num_paired), device=self.device,
                  inputs=[model.arrays, model.paired, batch.num_muscles, stride, _state(*state), points],
                  outputs=[out])
        self.launches += 1
        return out

    def _check_batch(self, points, batch) -> tuple[int, int, int]:
        """(S, T, V) of a batched launch's points (T, V) and batch, checked (InputError naming them)."""
        model = self.model
        if not isinstance(batch, ShellBatch):
            raise InputError(f"expected a ShellBatch, got {type(batch).__name__}", field="batch")
        S, T, M = batch.num_sets, batch.num_frames, batch.num_muscles
        V = model.num_vertices
        if (not isinstance(points, wp.array) or points.dtype != wp.vec3 or points.shape != (T, V)
                or points.device != self.device):
            desc = (f"{points.dtype.__name__} {points.shape} on {points.device}" if isinstance(points, wp.array)
                    else type(points).__name__)
            raise InputError(f"expected a ({T}, {V}) wp.vec3 array on {self.device}, got {desc}", field="points")
        if M != model.num_muscles:
            raise InputError(f"expected frames of {model.num_muscles} muscles, got {M}", field="batch")
        return S, T, V

    def _upload_batch(self, batch: ShellBatch) -> list:
        """Check the active muscles' state is finite and upload the batch once: E_ref, E_ref_inv,
        centre (T * M,), dE = E_cur - E_ref in float64 and E_cur_inv (S * T * M,), curve
        (S * T * M, K), active (S * T * M,)."""
        S, T, M = batch.num_sets, batch.num_frames, batch.num_muscles
        on = batch.active
        ref_needed = on.any(axis=0)                                 # (T, M): some set reads E_ref there
        for name, E, mask in (("E_ref", batch.E_ref, ref_needed), ("E_ref_inv", batch.E_ref_inv, ref_needed),
                              ("E_cur", batch.E_cur, on), ("E_cur_inv", batch.E_cur_inv, on)):
            if not np.isfinite(E[mask]).all():
                raise InputError("NaN or inf in an active muscle's matrix (mark it inactive)", field=name)
        if not np.isfinite(batch.curve[on]).all():
            raise InputError("NaN or inf in an active muscle's curve (mark it inactive)", field="curve")
        # the kernel reads E_cur - E_ref, formed here in float64: exactly 0 for a muscle at rest
        dE = np.where(on[..., None, None], batch.E_cur - batch.E_ref, 0.0)
        K = batch.curve.shape[3]
        state = [self._scratch("E_ref", (T * M,), wp.mat44), self._scratch("E_ref_inv", (T * M,), wp.mat44),
                 self._scratch("dE", (S * T * M,), wp.mat44), self._scratch("E_cur_inv", (S * T * M,), wp.mat44),
                 self._scratch("centre", (T * M,), wp.vec3), self._scratch("curve", (S * T * M, K), wp.vec3),
                 self._scratch("active", (S * T * M,), wp.int32)]
        host = (batch.E_ref, batch.E_ref_inv, dE, batch.E_cur_inv, batch.E_ref[..., :3, 3], batch.curve, on)
        for buf, a in zip(state[:-1], host[:-1]):
            buf.assign(a.astype(np.float32).reshape(buf.shape + ((4, 4) if buf.dtype == wp.mat44 else (3,))))
        state[-1].assign(on.astype(np.int32).ravel())
        return state

    def _upload(self, frames: ShellFrames) -> None:
        if not isinstance(frames, ShellFrames):
            raise InputError(f"expected ShellFrames, got {type(frames).__name__}", field="frames")
        M = self.model.num_muscles
        if frames.num_muscles != M:
            raise InputError(f"expected frames of {M} muscles, got {frames.num_muscles}", field="frames")
        on = frames.active
        mats = (frames.E_ref, frames.E_ref_inv, frames.E_cur, frames.E_cur_inv)
        for name, E in zip(("E_ref", "E_ref_inv", "E_cur", "E_cur_inv"), mats):
            if not np.all(np.isfinite(E[on])):
                raise InputError("NaN or inf in an active muscle's matrix (mark it inactive)", field=name)
        if not np.all(np.isfinite(frames.curve[on])):
            raise InputError("NaN or inf in an active muscle's curve (mark it inactive)", field="curve")
        # the kernel reads E_cur - E_ref, formed here in float64: exactly 0 for a muscle at rest
        dE = np.where(on[:, None, None], frames.E_cur - frames.E_ref, 0.0)
        for buf, E in zip(self._E, (frames.E_ref, frames.E_ref_inv, dE, frames.E_cur_inv)):
            buf.assign(E.astype(np.float32))
        self._centre.assign(frames.E_ref[:, :3, 3].astype(np.float32))
        K = frames.curve.shape[1]
        if self._curve is None or self._curve.shape != (M, K):
            self._curve = wp.empty((M, K), dtype=wp.vec3, device=self.device)
        self._curve.assign(frames.curve.astype(np.float32))
        self._active.assign(on.astype(np.int32))
