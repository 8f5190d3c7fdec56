"""Shell deformers (Pratscher et al. 2005, "Outside-in anatomy based character rigging", 4.2, 4.3).

One deformer per muscle. In the muscle's local space (its ellipsoid E maps the unit sphere at the
origin to the muscle, p_l = E^-1 p, column vectors, metres in world) there are three shells: the
sticky shell of radius r_s = 1 + delta + (1 - s) d toward which points are pulled, the hard shell
1 + h d inside which the pull is full, and the drop-off shell 1 + d beyond which nothing moves
(d in local units: multiples of the muscle's radius in that direction; delta(u) is the star-shaped
offset of the real muscle surface from the ellipsoid along the local direction u, 0 without a star
table). The radius compared with the shells is rho = |p_l| - delta(u), measured from the muscle
surface.

Reading of the paper's basic deformation
----------------------------------------
The paper prints p'_l = w w_i beta(r) ||s - p_l|| p_l / ||p_l||, which taken literally is not a
deformation (it maps every point to a length, and points with beta = 0 to the origin). We read it
as what the text and Figure 7 describe: move p_l radially by w w_i beta |s - p_l| toward s, where
s = r_s u is the projection of p_l onto the sticky shell along u = p_l / |p_l|:

    p'_l = p_l + w w_i beta(rho) (r_s - r) u,        r = |p_l|.

With w = w_i = 1, points inside the hard shell land on the sticky shell (s = 1: the muscle surface;
s = 0: the drop-off shell), and the pull fades smoothly to 0 at the drop-off shell.
:func:`basic_local` is this absolute form; it is used for the Figure 7 behaviours only.

Why the skin gets RELATIVE displacements
----------------------------------------
The artist's skin at the bind pose must come out unchanged (to 1e-6 m): the shells add motion
driven by the muscles, they must not resculpt the character. The absolute deformer applied at rest
pulls every skin vertex inside the hard shell onto the sticky shell, i.e. it replaces the artist's
skin near each muscle by the muscle's offset surface. So each pair (vertex, muscle) contributes the
difference between the deformation through the muscle's CURRENT ellipsoid E_cur and through its
REST ellipsoid carried rigidly by its bone, E_ref. With q(p_l) = p_l + beta(rho) (r_s - r) u (the
unweighted projection, :func:`project`) and k = w w_i:

    basic:      D = k [E_cur q(E_cur^-1 p) - E_ref q(E_ref^-1 p)]
    stretch:    p_l = E_ref^-1 p, a = alpha(rho)^l,  D = k a (E_cur - E_ref) (q(p_l), 1)
    trajectory: p_l = E_ref^-1 p, a = alpha(rho)^l,  D = k [c(a) - c(0) + a (L_cur - L_ref) q(p_l)]

(L: the upper-left 3x3 block of E; c: the muscle's trajectory curve, c(0) the centre of E_ref and
c(1) the centre of E_cur, sampled at TRAJECTORY_SAMPLES parameters and interpolated piecewise
linearly; a = 0 wherever alpha = 0, whatever l, so nothing beyond the drop-off shell ever moves).
Each pair's D (before the weights k) is then held below LIMIT_REACH x the muscle's drop-off distance
along the point's direction, reach = LIMIT_REACH d |L_ref u| (u = E_ref^-1 p / |E_ref^-1 p|; d |L_ref u|
is the world gap between the muscle's surface and its drop-off shell through the point), by a smooth
limit (:func:`limit`: unchanged up to reach / 2, saturating toward reach). Why: the relative
displacement carries the skin by the muscle's own change relative to its bone, which near a tendon
end or in a crease can be far larger than the layer of flesh the deformer owns (a pectoral whose
insertion swings with the arm moves its centre 9 cm relative to the chest). The paper's absolute
deformer never moves a point farther than its drop-off distance; half of it is what keeps the skin
from folding where the pull fades: D falls to 0 across the drop-off band of width ~d |L_ref u| with
the fall-off's steepest slope, 8 / (3 sqrt 3) ~ 1.54 per band width, so its gradient stays below
0.8 with |D| < half the band (a gradient of 1 folds the skin). Measured on the generated body over
the CMU dance clip 05_02 (issue 18): the whole drop-off distance as the limit folded 31 edges per
frame on average where LBS folds 8; half of it, 13. Limiting the part across the muscle and the part
along it separately folded more (22), as two limits let the sum grow past either.
At the bind pose E_cur == E_ref and every D is exactly 0. A vertex's pairs are applied in series in
ascending muscle order, each D evaluated at the already-displaced point; inactive muscles (NaN or
degenerate frames) are skipped.

Contents: the per-muscle table (:class:`ShellTable`, :func:`shell_table`, from each muscle's
:class:`ShellParams`, which its template carries: rig/muscle/shell_params.py), the per-frame state
(:class:`ShellFrames`), the float64 NumPy references (:func:`falloff`, :func:`beta`, :func:`alpha`,
:func:`star_lookup`, :func:`project`, :func:`basic_local`, :func:`shell_numpy`) and the bind-time
culling (:func:`cull_pairs`). The Warp kernel is :mod:`rig.skin.shell.kernels`, its launcher
:class:`rig.skin.shell.deformer.ShellDeformer`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from jiggle.rig.base.errors import InputError
from jiggle.rig.base.frozen import frozen_array
from jiggle.rig.muscle.shell_params import MODES, ShellParams

STAR_THETA = 17
"""Star table rows: polar angles theta_i = pi i / 16, i = 0..16, about the local +z axis."""
STAR_PHI = 32
"""Star table columns: azimuths phi_j = -pi + 2 pi j / 32, j = 0..31 (periodic)."""
TRAJECTORY_SAMPLES = 9
"""K: samples c(u_k), u_k = k / (K - 1), of a muscle's trajectory curve per frame."""
LIMIT_KNEE = 0.5
"""The drop-off limit leaves displacements up to this fraction of its reach unchanged."""
LIMIT_REACH = 0.5
"""The drop-off limit's reach: this fraction of the drop-off distance (see the module)."""

@dataclass(frozen=True)
class ShellFrames:
    """One frame's ellipsoids of all M muscles (the per-frame state of the shell deformer).

    E_ref : (M, 4, 4) float64, the rest ellipsoid carried rigidly by the muscle's bone
        (local unit sphere -> world, column vectors, metres).
    E_ref_inv : (M, 4, 4) float64, its inverse.
    E_cur : (M, 4, 4) float64, the ellipsoid fitted to the muscle's current CVs.
    E_cur_inv : (M, 4, 4) float64, its inverse.
    curve : (M, K, 3) float64, metres: trajectory samples c(u_k), u_k = k / (K - 1), with c(0) the
        centre of E_ref and c(1) the centre of E_cur.
    active : (M,) bool; False: the muscle is skipped this frame (it contributes nothing).

    Arrays are converted (not copied when already of the right dtype) and their shapes checked;
    a mismatch raises InputError naming the field.
    """

    E_ref: np.ndarray
    E_ref_inv: np.ndarray
    E_cur: np.ndarray
    E_cur_inv: np.ndarray
    curve: np.ndarray
    active: np.ndarray

    def __post_init__(self):
        M = None
        for k in ("E_ref", "E_ref_inv", "E_cur", "E_cur_inv"):
            a = np.asarray(getattr(self, k), dtype=np.float64)
            if a.ndim != 3 or a.shape[1:] != (4, 4):
                raise InputError(f"expected shape (M, 4, 4), got {a.shape}", field=k)
            if M is None:
                M = a.shape[0]
            elif a.shape[0] != M:
                raise InputError(f"expected {M} matrices (as E_ref), got {a.shape[0]}", field=k)
            object.__setattr__(self, k, a)
        curve = np.asarray(self.curve, dtype=np.float64)
        if curve.ndim != 3 or curve.shape[0] != M or curve.shape[2] != 3 or curve.shape[1] < 2:
            raise InputError(f"expected shape ({M}, K >= 2, 3), got {curve.shape}", field="curve")
        object.__setattr__(self, "curve", curve)
        active = np.asarray(self.active)
        if active.shape != (M,):
            raise InputError(f"expected shape ({M},), got {active.shape}", field="active")
        object.__setattr__(self, "active", active.astype(bool))

    @property
    def num_muscles(self) -> int:
        return self.E_ref.shape[0]


# ---------------------------------------------------------------------------------------------
# per-muscle table


@dataclass(frozen=True)
class ShellTable:
    """The deformer parameters of all M muscles as flat read-only arrays (built once at bind).

    sticky, hard, drop_off, weight, slippage : (M,) float64 (see :class:`ShellParams`).
    mode : (M,) int32, index into MODES (0 basic, 1 stretch, 2 trajectory).
    star_index : (M,) int32, the muscle's row of `star`, -1 when it has no star table.
    star : (S, STAR_THETA, STAR_PHI) float32, local radial offsets delta of the muscle surface from
        the unit sphere (S may be 0).
    """

    sticky: np.ndarray
    hard: np.ndarray
    drop_off: np.ndarray
    weight: np.ndarray
    slippage: np.ndarray
    mode: np.ndarray
    star_index: np.ndarray
    star: np.ndarray

    @property
    def num_muscles(self) -> int:
        return self.sticky.shape[0]


def _check_star(star, star_index, M: int) -> tuple[np.ndarray, np.ndarray]:
    """Validated (S, STAR_THETA, STAR_PHI) tables and (M,) indices in [-1, S) (see shell_table)."""
    if star is None:
        star = np.zeros((0, STAR_THETA, STAR_PHI), np.float32)
    star = np.asarray(star)
    if star.ndim != 3 or star.shape[1:] != (STAR_THETA, STAR_PHI) or not np.issubdtype(star.dtype, np.number):
        raise InputError(f"expected a (S, {STAR_THETA}, {STAR_PHI}) float array, got shape {star.shape}",
                         field="star")
    if not np.all(np.isfinite(star)):
        raise InputError("star offsets contain NaN or inf", field="star")
    S = star.shape[0]
    if star_index is None:
        if S not in (0, M):
            raise InputError(f"{S} star tables for {M} muscles: give star_index", field="star_index")
        star_index = np.arange(M) if S else np.full(M, -1)
    star_index = np.asarray(star_index)
    if star_index.shape != (M,) or not np.issubdtype(star_index.dtype, np.integer):
        raise InputError(f"expected ({M},) integers (one per muscle), got shape {star_index.shape} "
                         f"dtype {star_index.dtype}", field="star_index")
    if M and (star_index.min() < -1 or star_index.max() >= S):
        raise InputError(f"expected indices in [-1, {S}) for {S} star tables, got "
                         f"[{star_index.min()}, {star_index.max()}]", field="star_index")
    return star, star_index


def shell_table(params: Sequence[ShellParams], star=None, star_index=None) -> ShellTable:
    """Flatten one ShellParams per muscle into a :class:`ShellTable`.

    Parameters
    ----------
    params : M ShellParams (already range-checked by their constructor).
    star : optional (S, STAR_THETA, STAR_PHI) float, finite, local offsets delta (see
        :func:`star_lookup`).
    star_index : optional (M,) int in [-1, S): muscle m uses star[star_index[m]], -1: none. When
        star is given without star_index, S must equal M and muscle m uses table m.

    Raises InputError naming `params`, `star` or `star_index` for a mismatch.
    """
    params = list(params)
    for i, p in enumerate(params):
        if not isinstance(p, ShellParams):
            raise InputError(f"expected ShellParams, got {type(p).__name__}", field=f"params[{i}]")
    M = len(params)
    star, star_index = _check_star(star, star_index, M)

    def col(k):
        return frozen_array([getattr(p, k) for p in params], np.float64)

    return ShellTable(sticky=col("sticky"), hard=col("hard"), drop_off=col("drop_off"),
                      weight=col("weight"), slippage=col("slippage"),
                      mode=frozen_array([MODES.index(p.mode) for p in params], np.int32),
                      star_index=frozen_array(star_index, np.int32),
                      star=frozen_array(star, np.float32))


# ---------------------------------------------------------------------------------------------
# NumPy references (float64, vectorised; the kernel in rig.skin.shell.kernels is measured against them)

_TINY_R = 1e-9
"""Below this local radius a point has no direction: it gets no projection term."""


def falloff(x) -> np.ndarray:
    """f(x) = (1 - x^2)^2 on [0, 1], 1 for x < 0, 0 for x > 1; C1 at both ends."""
    x = np.clip(np.asarray(x, np.float64), 0.0, 1.0)
    return (1.0 - x * x) ** 2


def beta(rho, hard, drop_off) -> np.ndarray:
    """The shell attenuation: 1 inside the hard shell (rho <= 1 + h d), 0 beyond the drop-off shell
    (rho >= 1 + d), f((rho - (1 + h d)) / ((1 - h) d)) between. Arguments broadcast; h = 1 has no
    transition region (and no division by 0)."""
    rho, h, d = np.broadcast_arrays(*(np.asarray(a, np.float64) for a in (rho, hard, drop_off)))
    inner = 1.0 + h * d
    den = (1.0 - h) * d
    with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
        x = (rho - inner) / np.where(den > 0.0, den, 1.0)
    return np.where(rho <= inner, 1.0, np.where(rho >= 1.0 + d, 0.0, falloff(x)))


def alpha(rho, drop_off) -> np.ndarray:
    """The stretch fall-off: 1 inside the muscle (rho <= 1), 0 beyond the drop-off shell, f((rho - 1)
    / d) between. Arguments broadcast."""
    rho, d = np.broadcast_arrays(np.asarray(rho, np.float64), np.asarray(drop_off, np.float64))
    return np.where(rho <= 1.0, 1.0, np.where(rho >= 1.0 + d, 0.0, falloff((rho - 1.0) / d)))


def star_lookup(tables, index, u) -> np.ndarray:
    """Star offsets delta(u): bilinear in (theta, phi) of the muscle's table, 0 where index < 0.

    Parameters
    ----------
    tables : (S, STAR_THETA, STAR_PHI) float; row i at theta_i = pi i / 16 (polar angle from local
        +z), column j at phi_j = -pi + 2 pi j / 32 (azimuth atan2(u_y, u_x)); phi wraps (column 32 is
        column 0).
    index : (n,) int, the table of each point, -1: none.
    u : (n, 3) float, unit local directions. theta is computed as atan2(|u_xy|, u_z), equal to
        acos(u_z) for unit u and accurate near the poles in float32 too.

    Returns
    -------
    (n,) float64, local units.
    """
    tables = np.asarray(tables)
    index = np.asarray(index)
    u = np.asarray(u, np.float64)
    out = np.zeros(index.shape[0])
    has = index >= 0
    if not np.any(has):
        return out
    u = u[has]
    theta = np.arctan2(np.hypot(u[:, 0], u[:, 1]), u[:, 2])
    phi = np.arctan2(u[:, 1], u[:, 0])
    ti = theta * ((STAR_THETA - 1) / math.pi)
    i0 = np.clip(np.floor(ti).astype(np.int64), 0, STAR_THETA - 2)
    ft = np.clip(ti - i0, 0.0, 1.0)
    pj = (phi + math.pi) * (STAR_PHI / (2.0 * math.pi))
    j0f = np.floor(pj)
    fp = np.clip(pj - j0f, 0.0, 1.0)
    j0 = np.mod(j0f.astype(np.int64), STAR_PHI)
    j1 = np.mod(j0 + 1, STAR_PHI)
    t = np.asarray(tables, np.float64)[index[has]]  # (h, NT, NP)
    rows = np.arange(t.shape[0])
    a = (1.0 - fp) * t[rows, i0, j0] + fp * t[rows, i0, j1]
    b = (1.0 - fp) * t[rows, i0 + 1, j0] + fp * t[rows, i0 + 1, j1]
    out[has] = (1.0 - ft) * a + ft * b
    return out


def _directions(p_l: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(r (n,), u (n, 3)): local radius and unit direction; u = 0 where r < _TINY_R."""
    r = np.linalg.norm(p_l, axis=-1)
    ok = r >= _TINY_R
    u = p_l / np.where(ok, r, 1.0)[:, None] * ok[:, None]
    return r, u


def project(p_l, s, h, d, delta=0.0) -> np.ndarray:
    """q(p_l) = p_l + beta(rho) (r_s - r) u: the UNWEIGHTED pull toward the sticky shell.

    Parameters
    ----------
    p_l : (n, 3) float, local points (unit sphere = the ellipsoid).
    s, h, d : sticky, hard, drop_off; scalars or (n,).
    delta : star offsets delta(u) of the points' directions, scalar or (n,) (0: the ellipsoid).

    Returns
    -------
    (n, 3) float64, local. Points with r < 1e-9 have no direction and are returned unchanged.
    """
    p_l = np.asarray(p_l, np.float64)
    r, u = _directions(p_l)
    delta = np.asarray(delta, np.float64)
    rho = r - delta
    r_s = 1.0 + delta + (1.0 - np.asarray(s, np.float64)) * d
    return p_l + (beta(rho, h, d) * (r_s - r))[:, None] * u


def basic_local(p_l, params: ShellParams, wi=1.0, star=None) -> np.ndarray:
    """The paper's absolute basic deformation in local space (see the module docstring):
    p'_l = p_l + w w_i beta(rho) (r_s - r) u.

    Parameters
    ----------
    p_l : (n, 3) float, local points.
    params : the muscle's ShellParams (sticky, hard, drop_off, weight; mode and slippage unused).
    wi : painted weight(s) in [0, 1], scalar or (n,).
    star : optional (STAR_THETA, STAR_PHI) float star table of the muscle.

    Returns
    -------
    (n, 3) float64, local.
    """
    p_l = np.asarray(p_l, np.float64)
    delta = 0.0
    if star is not None:
        _, u = _directions(p_l)
        delta = star_lookup(np.asarray(star)[None], np.zeros(p_l.shape[0], np.int64), u)
    q = project(p_l, params.sticky, params.hard, params.drop_off, delta)
    k = params.weight * np.asarray(wi, np.float64)
    return p_l + np.reshape(k, (-1, 1)) * (q - p_l)


def _apply(E: np.ndarray, x: np.ndarray) -> np.ndarray:
    """(n, 4, 4) affine matrices applied to (n, 3) points: E (x, 1)."""
    return np.einsum("nij,nj->ni", E[:, :3, :3], x) + E[:, :3, 3]


def _local(table: ShellTable, m: np.ndarray, E_inv: np.ndarray, p: np.ndarray):
    """Local point, its unweighted projection q and its star-corrected radius rho, for muscles m."""
    p_l = _apply(E_inv, p)
    r, u = _directions(p_l)
    delta = star_lookup(table.star, table.star_index[m], u)
    q = project(p_l, table.sticky[m], table.hard[m], table.drop_off[m], delta)
    return q, r - delta


def _curve_at(curve: np.ndarray, a: np.ndarray) -> np.ndarray:
    """Piecewise-linear c(a) of (n, K, 3) samples at u_k = k / (K - 1), a in [0, 1] -> (n, 3)."""
    K = curve.shape[1]
    x = np.clip(a, 0.0, 1.0) * (K - 1)
    i = np.minimum(np.floor(x).astype(np.int64), K - 2)
    f = (x - i)[:, None]
    rows = np.arange(curve.shape[0])
    c0, c1 = curve[rows, i], curve[rows, i + 1]
    return c0 + f * (c1 - c0)


def pair_displacement(p, muscle, wi, table: ShellTable, frames: ShellFrames) -> np.ndarray:
    """D of n (point, muscle) pairs (module docstring), all modes; inactive muscles give 0.

    Parameters
    ----------
    p : (n, 3) float, world points, metres.
    muscle : (n,) int, the pairs' muscles.
    wi : (n,) float, painted weights.

    Returns
    -------
    (n, 3) float64, metres.
    """
    p = np.asarray(p, np.float64)
    muscle = np.asarray(muscle, np.int64)
    wi = np.asarray(wi, np.float64)
    D = np.zeros_like(p)
    on = frames.active[muscle]
    p, m, k = p[on], muscle[on], table.weight[muscle[on]] * wi[on]
    E_ref, E_cur = frames.E_ref[m], frames.E_cur[m]
    mode = table.mode[m]
    q_ref, rho = _local(table, m, frames.E_ref_inv[m], p)
    d_on = np.zeros_like(p)

    b = mode == MODES.index("basic")
    if np.any(b):
        q_cur, _ = _local(table, m[b], frames.E_cur_inv[m[b]], p[b])
        d_on[b] = _apply(E_cur[b], q_cur) - _apply(E_ref[b], q_ref[b])

    al = alpha(rho, table.drop_off[m])
    # 0 ** 0 would be 1: nothing beyond the drop-off shell may move, whatever the slippage
    a = np.where(al > 0.0, al ** table.slippage[m], 0.0)
    st = mode == MODES.index("stretch")
    if np.any(st):
        d_on[st] = a[st, None] * _apply(E_cur[st] - E_ref[st], q_ref[st])
    tr = mode == MODES.index("trajectory")
    if np.any(tr):
        dL = E_cur[tr, :3, :3] - E_ref[tr, :3, :3]
        curve = frames.curve[m[tr]]
        d_on[tr] = (_curve_at(curve, a[tr]) - curve[:, 0]
                    + a[tr, None] * np.einsum("nij,nj->ni", dL, q_ref[tr]))
    p_l = _apply(frames.E_ref_inv[m], p)
    r = np.linalg.norm(p_l, axis=1, keepdims=True)
    u = np.where(r >= _TINY_R, p_l / np.maximum(r, _TINY_R), 0.0)
    reach = LIMIT_REACH * table.drop_off[m] * np.linalg.norm(np.einsum("nij,nj->ni", E_ref[:, :3, :3], u), axis=1)
    D[on] = k[:, None] * limit(d_on, reach)
    return D


def limit(D: np.ndarray, reach: np.ndarray) -> np.ndarray:
    """The drop-off limit: displacements D (n, 3) shortened so |D| < reach (n,), smoothly.

    |D| is kept below reach / 2 and saturates toward reach above it:
    |D'| = reach s(|D| / reach), s(x) = x for x <= 1/2, 1/2 + tanh(2 x - 1) / 2 beyond (C1 at 1/2).
    reach <= 0 (a point at the muscle's centre, no direction) gives D' = 0.
    """
    D = np.asarray(D, np.float64)
    reach = np.asarray(reach, np.float64)
    n = np.linalg.norm(D, axis=-1)
    x = n / np.where(reach > 0.0, reach, 1.0)
    s = np.where(x <= LIMIT_KNEE, x, LIMIT_KNEE + (1.0 - LIMIT_KNEE) * np.tanh((x - LIMIT_KNEE) / (1.0 - LIMIT_KNEE)))
    scale = np.where((reach > 0.0) & (n > 0.0), reach * s / np.where(n > 0.0, n, 1.0), 0.0)
    scale = np.where((reach > 0.0) & (n == 0.0), 1.0, scale)
    return D * scale[..., None]


def shell_numpy(points, pair_offsets, pair_muscle, pair_weight, table: ShellTable,
                frames: ShellFrames) -> np.ndarray:
    """The shells of all pairs applied in series (reference for the kernel).

    Parameters
    ----------
    points : (V, 3) float, skinned positions, metres.
    pair_offsets : (V + 1,) int, CSR: vertex v owns pairs pair_offsets[v]:pair_offsets[v + 1].
    pair_muscle : (P,) int, each pair's muscle (ascending within a vertex: the series order).
    pair_weight : (P,) float, painted weights w_i in [0, 1].

    Returns
    -------
    (V, 3) float64, metres: p <- p + D(p) for each pair of the vertex in order.
    """
    p = np.array(points, np.float64)
    off = np.asarray(pair_offsets, np.int64)
    muscle = np.asarray(pair_muscle, np.int64)
    wi = np.asarray(pair_weight, np.float64)
    count = np.diff(off)
    for slot in range(int(count.max()) if count.size else 0):
        v = np.nonzero(count > slot)[0]
        i = off[v] + slot
        p[v] += pair_displacement(p[v], muscle[i], wi[i], table, frames)
    return p


# ---------------------------------------------------------------------------------------------
# bind time


def pair_envelope(rest_vertices, E_rest, drop_off, margin: float, pair_offsets, pair_muscle, star=None,
                  star_index=None) -> np.ndarray:
    """(P,) float64 weight of each culled pair in [0, 1] that falls to 0 at the culling boundary:
    1 while the vertex's bind radius rho (as in :func:`cull_pairs`) is within the drop-off shell,
    falloff((rho - (1 + d)) / ((1 + d) margin)) in the margin beyond it.

    Why: culling decides at bind which vertices a shell may move; a vertex culled at bind that the
    motion brings into the drop-off band stays put while its neighbour moves, a step in the skin
    along the culling line (issue 18). Multiplied into the pair's weight, this envelope takes every
    pair's pull smoothly to 0 where the culled set ends. margin 0: 1 for every pair."""
    p = np.asarray(rest_vertices, np.float64)
    E_rest = np.asarray(E_rest, np.float64)
    drop_off = np.asarray(drop_off, np.float64)
    M = E_rest.shape[0]
    if star is None and star_index is None:
        star = np.zeros((0, STAR_THETA, STAR_PHI))
    star, star_index = _check_star(star, star_index, M)
    vertex = np.repeat(np.arange(len(p)), np.diff(np.asarray(pair_offsets)))
    m = np.asarray(pair_muscle, np.int64)
    if margin <= 0.0 or len(m) == 0:
        return np.ones(len(m))
    E_inv = np.linalg.inv(E_rest)[m]
    p_l = np.einsum("nij,nj->ni", E_inv[:, :3, :3], p[vertex]) + E_inv[:, :3, 3]
    r, u = _directions(p_l)
    rho = r - star_lookup(star, star_index[m], u)
    inner = 1.0 + drop_off[m]
    return falloff((rho - inner) / (inner * margin))


def cull_pairs(rest_vertices, E_rest, drop_off, margin: float = 0.25, star=None, star_index=None
               ) -> tuple[np.ndarray, np.ndarray]:
    """The (vertex, muscle) pairs a shell can move, as CSR sorted by vertex then muscle.

    A pair is kept when the vertex's star-corrected local radius under the muscle's rest ellipsoid,
    rho = |E_rest^-1 p| - delta(u), is < (1 + d) (1 + margin): the margin keeps vertices that the
    muscle reaches once it bulges or slides.

    Parameters
    ----------
    rest_vertices : (V, 3) float, the skin at bind, metres.
    E_rest : (M, 4, 4) float, rest ellipsoids (local unit sphere -> world).
    drop_off : (M,) float, d > 0, local units.
    margin : >= 0, relative.
    star, star_index : optional star tables (S, STAR_THETA, STAR_PHI) and (M,) indices (-1: none),
        as for :func:`shell_table` (star without star_index: S == M, muscle m uses table m).

    Returns
    -------
    pair_offsets : (V + 1,) int32. pair_muscle : (P,) int32.
    """
    p = np.asarray(rest_vertices, np.float64)
    E_rest = np.asarray(E_rest, np.float64)
    drop_off = np.asarray(drop_off, np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise InputError(f"expected shape (V, 3), got {p.shape}", field="rest_vertices")
    if E_rest.ndim != 3 or E_rest.shape[1:] != (4, 4):
        raise InputError(f"expected shape (M, 4, 4), got {E_rest.shape}", field="E_rest")
    M, V = E_rest.shape[0], p.shape[0]
    if drop_off.shape != (M,):
        raise InputError(f"expected shape ({M},), got {drop_off.shape}", field="drop_off")
    if not (math.isfinite(margin) and margin >= 0.0):
        raise InputError(f"expected a finite value >= 0, got {margin}", field="margin")
    if star is None and star_index is None:
        star = np.zeros((0, STAR_THETA, STAR_PHI))
    star, star_index = _check_star(star, star_index, M)
    E_inv = np.linalg.inv(E_rest)
    keep = np.zeros((V, M), bool)
    for m in range(M):
        p_l = p @ E_inv[m, :3, :3].T + E_inv[m, :3, 3]
        r, u = _directions(p_l)
        delta = star_lookup(star, np.full(V, star_index[m]), u)
        keep[:, m] = r - delta < (1.0 + drop_off[m]) * (1.0 + margin)
    v, m = np.nonzero(keep)  # row-major: sorted by vertex, then muscle
    offsets = np.zeros(V + 1, np.int64)
    np.cumsum(np.bincount(v, minlength=V), out=offsets[1:])
    return offsets.astype(np.int32), m.astype(np.int32)
