"""The goals' path through time: static CVs at knots, a C1 cubic between them, cuts detected.

The solver needs the goal (and its velocity and acceleration) at any time inside a step. Goals are
sampled at knots whose spacing does not depend on the output frame rate (sim/jiggle/secondary.py picks them),
and between knots each goal follows the cubic Hermite curve through the two knots with velocities
from the three-point (quadratic) difference, one-sided at the ends. The acceleration is then linear
in each knot interval, which the exact goal-spring update takes whole.

A cut (a teleport: the motion jumps far beyond its velocity, as at a splice of two clips) must not
be interpolated: an interval whose largest CV move exceeds ``jump`` metres and ``ratio`` times the
largest move of each neighbouring interval is marked; velocities on either side are taken from that
side only, the goal moves linearly across it and the solver glues the particles to it (a reset).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from jiggle.rig.base.errors import InputError
from jiggle.rig.base.frozen import frozen_array


@dataclass(frozen=True, eq=False)
class GoalTrack:
    """Goal knots. times : (S,) seconds, increasing. pos : (S, N, 3) metres. vel_start, vel_end :
    (S - 1, N, 3) m/s, the goal velocity at the start and end of each knot interval. cut : (S - 1,)
    bool, intervals that are cuts."""

    times: np.ndarray
    pos: np.ndarray
    vel_start: np.ndarray
    vel_end: np.ndarray
    cut: np.ndarray

    @property
    def num_knots(self) -> int:
        return len(self.times)

    def interval(self, t: float) -> int:
        """Index j of the knot interval [times[j], times[j + 1]] holding time t (clamped)."""
        j = int(np.searchsorted(self.times, t, side="right")) - 1
        return min(max(j, 0), self.num_knots - 2)

    def intervals(self, t: np.ndarray) -> np.ndarray:
        """(K,) int64: :meth:`interval` of each time of t (K,) seconds."""
        j = np.searchsorted(self.times, np.asarray(t, dtype=np.float64), side="right") - 1
        return np.clip(j, 0, self.num_knots - 2)

    def sample(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Goal position, velocity and acceleration (N, 3) each at time t (inside the track)."""
        j = self.interval(t)
        return hermite(self.pos[j], self.pos[j + 1], self.vel_start[j], self.vel_end[j],
                       self.times[j + 1] - self.times[j], t - self.times[j])[:3]

    def to_device(self, device: str = "cpu") -> "GoalControl":
        def dev(a: np.ndarray) -> wp.array:
            # on the CPU the device array is the float32 copy itself (copy=False), not a second copy
            return wp.array(a.astype(np.float32), dtype=wp.vec3, device=device, copy=False)
        return GoalControl(self, dev(self.pos), dev(self.vel_start), dev(self.vel_end))


@dataclass(frozen=True, eq=False)
class GoalControl:
    """A GoalTrack on a device: pos (S, N), vel_start, vel_end (S - 1, N) wp.vec3 float32."""

    track: GoalTrack
    pos: wp.array
    vel_start: wp.array
    vel_end: wp.array


def hermite(pa, pb, va, vb, H: float, s):
    """The cubic through pa (at s = 0) and pb (at s = H) with end velocities va, vb, at s in [0, H]:
    (g, g', g'', g''') (arrays shaped like pa)."""
    c2 = (3.0 * (pb - pa) / H - 2.0 * va - vb) / H
    c3 = (2.0 * (pa - pb) / H + va + vb) / (H * H)
    g = pa + s * (va + s * (c2 + s * c3))
    return g, va + s * (2.0 * c2 + 3.0 * s * c3), 2.0 * c2 + 6.0 * s * c3, 6.0 * c3


def find_cuts(times: np.ndarray, pos: np.ndarray, ratio: float = 8.0, jump: float = 0.1) -> np.ndarray:
    """(S - 1,) bool: inner knot intervals whose largest move (over the N points of pos (S, N, 3))
    exceeds `jump` metres and `ratio` times the largest move of each neighbouring interval."""
    if len(times) < 2:
        return np.zeros(0, bool)
    step = np.diff(pos, axis=0)
    d = np.sqrt(np.einsum("snk,snk->sn", step, step).max(axis=1))          # (S - 1,)
    cut = np.zeros(len(d), bool)
    # the first and last intervals have one neighbour: a reversal of the motion there looks like a
    # jump, and a cut there would change nothing visible, so only inner intervals qualify
    if len(d) >= 3:
        inner = d[1:-1]
        cut[1:-1] = (inner > jump) & (inner > ratio * d[:-2]) & (inner > ratio * d[2:])
    return cut


def knot_velocities(times: np.ndarray, pos: np.ndarray, cut: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Velocities (vel_start, vel_end), each (S - 1, N, 3), of the C1 curve through the knots: the
    derivative of the quadratic through each knot and its neighbours (one-sided at the ends of the
    track and of each piece between cuts); cut intervals move linearly."""
    S = len(times)
    h = np.diff(times)[:, None, None]                                      # (S - 1, 1, 1)
    slope = np.diff(pos, axis=0)
    slope /= h                                                             # (S - 1, N, 3)
    vel = np.empty_like(pos)
    # a knot's left (right) interval exists and is not a cut
    has_l = np.concatenate([[False], ~cut])
    has_r = np.concatenate([~cut, [False]])
    both = has_l & has_r
    i = np.flatnonzero(both)
    if len(i) == S - 2:
        # no cut (the usual track): the same arithmetic on slices, written in place (a chunk's track is
        # a few MB per array, and every temporary costs as much as the sum)
        inner = vel[1:-1]
        np.multiply(h[1:], slope[:-1], out=inner)
        inner += h[:-1] * slope[1:]
        inner /= h[:-1] + h[1:]
    elif len(i):
        h0, h1 = h[i - 1], h[i]
        vel[i] = (h1 * slope[i - 1] + h0 * slope[i]) / (h0 + h1)
    # ends of a piece: the quadratic through the end knot and the next two inward; a = the interval
    # at the end, b = the one beyond it (v = s_a + (s_a - s_b) h_a / (h_a + h_b))
    for k, a, b in [(k, k, k + 1) for k in np.flatnonzero(has_r & ~has_l)] + \
                   [(k, k - 1, k - 2) for k in np.flatnonzero(has_l & ~has_r)]:
        if 0 <= b < S - 1 and not cut[b]:
            vel[k] = slope[a] + (slope[a] - slope[b]) * h[a] / (h[a] + h[b])
        else:
            vel[k] = slope[a]
    alone = ~has_l & ~has_r
    vel[alone] = 0.0
    if not cut.any():
        # views of one array (the ends of interval j and the starts of j + 1 are the same knots): no
        # copies of a chunk's worth of velocities
        return vel[:-1], vel[1:]
    vs, ve = vel[:-1].copy(), vel[1:].copy()
    vs[cut] = slope[cut]
    ve[cut] = slope[cut]
    return vs, ve


def build_track(times, pos, *, cuts=None, ratio: float = 8.0, jump: float = 0.1, names=None,
                offsets=None) -> GoalTrack:
    """A GoalTrack from goal knots: times (S,) seconds (S >= 2, increasing), pos (S, N, 3) metres.

    cuts : (S - 1,) bool marking cut intervals, or None to detect them (:func:`find_cuts`).
    names, offsets : the muscles' names and their particle offsets (M + 1,), to name the muscle and
    frame of a NaN goal in the error.
    """
    times = np.asarray(times, dtype=np.float64)
    pos = np.asarray(pos, dtype=np.float64)
    if times.ndim != 1 or len(times) < 2:
        raise InputError(f"a goal track needs at least 2 knot times, got {times.shape}", field="times")
    if pos.ndim != 3 or pos.shape[0] != len(times) or pos.shape[2] != 3:
        raise InputError(f"goals must be ({len(times)}, N, 3), got {pos.shape}", field="goals")
    if not np.isfinite(times).all() or np.any(np.diff(times) <= 0):
        raise InputError("knot times must be finite and strictly increasing", field="times")
    if not np.isfinite(pos).all():
        s, p = np.argwhere(~np.isfinite(pos).all(axis=2))[0]
        who = f"particle {p}"
        if names is not None and offsets is not None:
            m = int(np.searchsorted(offsets, p, side="right")) - 1
            who = f"muscle {names[m]!r} (CV {p - offsets[m]})"
        raise InputError(f"{who}: the goal (static CV) is NaN or inf at frame {s} (t = {times[s]:.4f} s)",
                         field="goals")
    cut = find_cuts(times, pos, ratio, jump) if cuts is None else np.asarray(cuts, bool).reshape(-1)
    if cut.shape != (len(times) - 1,):
        raise InputError(f"cuts must mark {len(times) - 1} intervals, got {cut.shape}", field="cuts")
    vs, ve = knot_velocities(times, pos, cut)
    vs.setflags(write=False)                    # made here, held by nobody else: frozen without a copy
    ve.setflags(write=False)
    return GoalTrack(frozen_array(times), frozen_array(pos), vs, ve, frozen_array(cut, bool))
