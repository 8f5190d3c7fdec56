"""Zoned radial-basis-function interpolation of skin displacements (Simmons et al. 2002, section 4).

The skin's feature points p_i (rest) move to p'_i; their displacements u_i = p'_i - p_i are
interpolated to every skin vertex v by

    f(v) = L(v) + sum_i c_i phi(|v - p_i|)          (L affine, c_i in R^3)

with the side conditions sum_i c_i = 0 and sum_i c_i p_i^T = 0, i.e. the block system

    [[Phi, P], [P^T, 0]] [C; M^T] = [U; 0],   Phi_ij = phi(|p_i - p_j|), rows of P = (p_i, 1).

Kernels (s = scale, metres): soliton e^{-r/s} (the paper's choice), gaussian e^{-r^2 / 2 s^2},
multiquadric sqrt(1 + r^2/s^2), inverse_multiquadric (1 + r^2/s^2)^{-1/2}.

Geodesic zones (:class:`rig.anatomy.zones.Zones`, or any object with its fields ``names``, ``vertex_zone``,
``neighbours``, ``blend``): zone z has its own interpolant f_z built from the feature points whose zone
is a neighbour of z (itself included), so one leg never moves the other. Vertex v gets
``sum_z blend[v, z] f_z(v)`` (blend is a partition of unity). A vertex is independent of a feature
only when NONE of the zones it blends has that feature's zone as a neighbour: a thigh vertex that
blends in the torso's interpolant does feel the other leg, through the torso's feature set.

Cardinal weights. Solving ``A X = [K(v)^T; q(v)^T]`` with q(v) = (v, 1), K(v)_i = phi(|v - p_i|) gives
(A is symmetric) the row w(v) = X[:n]^T with f(v) = w(v) U for ANY data U. Its second block row reads
``P^T w(v) = q(v)``: sum_i w_i = 1 and sum_i w_i p_i = v, whatever K is, so affine data are
reproduced exactly, and the interpolated POSITION is

    v + f(v) = v + sum_i w_i (p'_i - p_i) = sum_i w_i p'_i.

Blending with a partition of unity keeps both identities, so a skin vertex is a fixed linear
combination of the current feature positions: :class:`ZoneRBF` stores that combination truncated to
the ``support`` largest weights per vertex (then corrected to reproduce affine maps exactly again) and
:class:`RBFSkinner` applies it each frame on a Warp device. :func:`interpolate` is the exact dense
evaluation for a single use (morphing).

Centres closer than ``merge`` are merged (values averaged): coincident centres make Phi singular.

- :func:`phi`, :data:`KERNELS`, :class:`RBFOptions`
- :func:`merge_centres`, :func:`solve_zone` (one block system)
- :func:`zone_interpolants` -> :class:`ZoneInterpolants` (per-zone coefficients; ``evaluate``,
  ``blended``), :func:`interpolate` (exact zoned morph of the skin)
- :func:`build_zone_rbf` -> :class:`ZoneRBF` (sparse cardinal weights; ``apply`` is the NumPy
  reference), :class:`RBFSkinner` (Warp launcher; kernel in :mod:`rig.anatomy.rbf_kernels`)
- :func:`boundary_report` (edges from :func:`weld_edges`): how smooth the result is across zone
  boundaries.

Each zone's block matrix is LU-factored once; its 2-norm condition number (Lanczos) is reported and
checked against ``max_condition``.
"""
from __future__ import annotations

import time
import warnings
from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.sparse
from scipy.sparse.csgraph import connected_components
from scipy.sparse.linalg import ArpackError, ArpackNoConvergence, LinearOperator, eigsh
from scipy.spatial import cKDTree
from scipy.spatial.distance import cdist

from jiggle.rig.base.errors import InputError
from jiggle.rig.base.frozen import frozen_array

KERNELS = ("soliton", "gaussian", "multiquadric", "inverse_multiquadric")
BLOCK = 8192            # vertices per block when building weights or evaluating (bounds memory)
_HINT = "use a larger merge distance, a smaller scale, or another kernel"
_EPS = np.finfo(np.float64).eps


# ----------------------------------------------------------------------------------------------
# kernels and options

def phi(r, kernel: str = "soliton", scale: float = 1.0) -> np.ndarray:
    """The radial basis function of distances `r` (any shape, metres), float64, same shape.

    kernel : one of :data:`KERNELS`; scale : s > 0, metres.
    """
    _check_kernel(kernel, "kernel")
    _check_positive(scale, "scale")
    r = np.asarray(r, dtype=np.float64)
    return _phi_sq(r * r, kernel, float(scale))


def _phi_sq(r2: np.ndarray, kernel: str, scale: float) -> np.ndarray:
    """phi of SQUARED distances, in place on `r2` (a float64 scratch array the caller owns)."""
    if kernel == "soliton":
        np.sqrt(r2, out=r2)
        r2 *= -1.0 / scale
        return np.exp(r2, out=r2)
    if kernel == "gaussian":
        r2 *= -0.5 / (scale * scale)
        return np.exp(r2, out=r2)
    r2 *= 1.0 / (scale * scale)
    r2 += 1.0
    np.sqrt(r2, out=r2)
    if kernel == "inverse_multiquadric":
        np.reciprocal(r2, out=r2)
    return r2


def _check_kernel(kernel, field: str) -> None:
    if not isinstance(kernel, str) or kernel not in KERNELS:
        raise InputError(f"expected one of {', '.join(KERNELS)}, got {kernel!r}", field=field)


def _check_positive(x, field: str, allow_zero: bool = False) -> float:
    ok = isinstance(x, (int, float, np.integer, np.floating)) and not isinstance(x, bool) and np.isfinite(x)
    if not ok or (x < 0 if allow_zero else x <= 0):
        want = "a finite number >= 0" if allow_zero else "a finite number > 0"
        raise InputError(f"expected {want}, got {x!r}", field=field)
    return float(x)


def _check_count(x, field: str, low: int) -> int:
    if isinstance(x, bool) or not isinstance(x, (int, np.integer)) or x < low:
        raise InputError(f"expected a whole number >= {low}, got {x!r}", field=field)
    return int(x)


@dataclass(frozen=True, kw_only=True)
class RBFOptions:
    """Settings of the zoned RBF (all keyword arguments; every one is validated).

    scale : s of the kernel, metres, > 0 (required; derive it from the body's size: the paper used
        1/6 to 5/6 of the horse's length).
    kernel : one of :data:`KERNELS`; "soliton" (e^{-r/s}, dies out with distance) by default.
    support : weights kept per vertex row of :class:`ZoneRBF` (the largest in magnitude); 0 keeps all
        (exact, but V x F memory).
    merge : metres; centres closer than this are merged and their values averaged; 0 disables.
    min_features : a zone whose set (itself and its neighbours) has fewer distinct centres is an error.
    max_condition : a zone system whose condition number estimate exceeds this is an error.
    """
    scale: float
    kernel: str = "soliton"
    support: int = 32
    merge: float = 1e-4
    min_features: int = 8
    max_condition: float = 1e12

    def __post_init__(self):
        _check_positive(self.scale, "scale")
        _check_kernel(self.kernel, "kernel")
        _check_count(self.support, "support", 0)
        _check_positive(self.merge, "merge", allow_zero=True)
        _check_count(self.min_features, "min_features", 4)
        _check_positive(self.max_condition, "max_condition")
        if self.max_condition < 1:
            raise InputError(f"expected a condition number >= 1, got {self.max_condition!r}", field="max_condition")


# ----------------------------------------------------------------------------------------------
# one zone

def merge_centres(points, tol: float):
    """Cluster points closer than `tol` (transitively: a chain of close pairs is one cluster).

    points : (n, 3) float, metres; tol : metres, >= 0 (0: no merging, every point its own centre).
    Returns (centres (m, 3) float64, the mean of each cluster; group (n,) int64, the cluster of each
    point, numbered in order of first appearance).
    """
    p = _points(points, "points")
    tol = _check_positive(tol, "tol", allow_zero=True)
    n = len(p)
    if tol == 0 or n < 2:
        return p.copy(), np.arange(n, dtype=np.int64)
    pairs = cKDTree(p).query_pairs(tol, output_type="ndarray")
    if len(pairs) == 0:
        return p.copy(), np.arange(n, dtype=np.int64)
    graph = scipy.sparse.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, labels = connected_components(graph, directed=False)
    _, first, group = np.unique(labels, return_index=True, return_inverse=True)
    order = np.argsort(np.argsort(first))       # renumber clusters by their first point
    group = order[group].astype(np.int64)
    m = len(first)
    count = np.bincount(group, minlength=m).astype(np.float64)
    centres = np.stack([np.bincount(group, weights=p[:, a], minlength=m) for a in range(3)], axis=1)
    return centres / count[:, None], group


def _points(x, field: str, n: int | None = None) -> np.ndarray:
    try:
        a = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"expected an (n, 3) array of numbers, got {type(x).__name__}", field=field) from None
    if a.ndim != 2 or a.shape[1] != 3 or (n is not None and len(a) != n):
        want = "(n, 3)" if n is None else f"({n}, 3)"
        raise InputError(f"expected a {want} array, got shape {a.shape}", field=field)
    bad = ~np.isfinite(a).all(axis=1)
    if bad.any():
        raise InputError(f"{int(bad.sum())} rows are not finite (first: row {int(np.argmax(bad))})", field=field)
    return a


def _sq_dist(x: np.ndarray, c: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """(len(x), len(c)) squared distances |x|^2 + |c|^2 - 2 x.c as one matrix product of augmented
    coordinates (x, 1, |x|^2) . (-2 c, |c|^2, 1). Coordinates are centred near 0 by the callers, so
    the cancellation error is ~1e-16 m^2; negative round-off is clamped."""
    xa = np.empty((len(x), 5))
    xa[:, :3] = x
    xa[:, 3] = 1.0
    xa[:, 4] = np.einsum("ij,ij->i", x, x)
    ca = np.empty((5, len(c)))
    ca[:3] = -2.0 * c.T
    ca[3] = np.einsum("ij,ij->i", c, c)
    ca[4] = 1.0
    d = np.matmul(xa, ca, out=out)
    return np.maximum(d, 0.0, out=d)


@dataclass(frozen=True, eq=False)
class _System:
    """One zone's factored block matrix (internal)."""
    centres: np.ndarray         # (n, 3) metres, relative to origin
    origin: np.ndarray          # (3,) centroid of the centres: coordinates are centred for conditioning
    lu: np.ndarray
    piv: np.ndarray
    condition: float

    def rows(self, x: np.ndarray, kernel: str, scale: float) -> np.ndarray:
        """(len(x), n + 4) = [K(x), x - origin, 1] for points x (absolute, metres)."""
        xc = x - self.origin
        out = np.empty((len(x), len(self.centres) + 4))
        n = len(self.centres)
        _phi_sq(_sq_dist(xc, self.centres, out=out[:, :n]), kernel, scale)
        out[:, n:n + 3] = xc
        out[:, n + 3] = 1.0
        return out


def _condition(A: np.ndarray, lu: np.ndarray, piv: np.ndarray) -> float:
    """The 2-norm condition number |lambda|_max / |lambda|_min of the symmetric block matrix A.

    Both extreme eigenvalues come from Lanczos (ARPACK, relative tolerance 1e-6): the largest of A,
    and the smallest as 1 / the largest of A^{-1} applied through the LU factors, O(n^2) a step and
    a few dozen steps, against O(n^3) for an SVD. Small matrices, or a Lanczos run that does not
    converge, get the SVD (np.linalg.cond). inf when a pivot is exactly 0.
    """
    m = len(A)
    if not np.isfinite(lu).all() or (np.diagonal(lu) == 0).any():
        return np.inf
    if m <= 64:
        return float(np.linalg.cond(A))
    v0 = 1.5 + np.cos(0.7 * np.arange(m))          # a fixed start: the same estimate every run
    inv = LinearOperator((m, m), matvec=lambda x: scipy.linalg.lu_solve((lu, piv), x, check_finite=False),
                         dtype=np.float64)
    try:
        big = eigsh(A, k=1, which="LM", v0=v0, tol=1e-6, return_eigenvectors=False)[0]
        small = eigsh(inv, k=1, which="LM", v0=v0, tol=1e-6, return_eigenvectors=False)[0]
        cond = abs(big) * abs(small)
    except (ArpackNoConvergence, ArpackError):
        cond = np.nan
    return float(cond) if np.isfinite(cond) else float(np.linalg.cond(A))


def _factor(centres: np.ndarray, options: RBFOptions, zone: str) -> _System:
    """Build and LU-factor the block matrix of `centres` (n, 3); raise InputError naming `zone` when it
    is singular or its condition number estimate exceeds options.max_condition."""
    n = len(centres)
    origin = centres.mean(axis=0) if n else np.zeros(3)
    c = centres - origin
    A = np.zeros((n + 4, n + 4))
    A[:n, :n] = _phi_sq(cdist(c, c, "sqeuclidean"), options.kernel, options.scale)
    A[:n, n:n + 3] = c
    A[:n, n + 3] = 1.0
    A[n:, :n] = A[:n, n:].T
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")     # an exactly singular pivot: reported below as infinite
        lu, piv = scipy.linalg.lu_factor(A, check_finite=False)
    cond = _condition(A, lu, piv)
    if cond > options.max_condition:
        what = (f"singular to working precision (condition number ~{cond:.3g})" if cond * _EPS >= 1
                else f"ill-conditioned (condition number ~{cond:.3g})")
        raise InputError(f"zone {zone}: the RBF system of its {n} centres is {what} > max_condition "
                         f"{options.max_condition:.3g}; {_HINT}", field="zones")
    return _System(c, origin, lu, piv, float(cond))


def solve_zone(centres, values, options: RBFOptions, zone: str = "(one zone)"):
    """Solve the block system of one zone.

    centres : (n, 3) float, metres (distinct: merge first); values : (n, d) or (n,) float, the data
    at the centres (displacements, metres). Returns (coeffs (n, d), affine (4, d), condition) with
    ``f(x) = sum_i coeffs[i] phi(|x - centres[i]|) + [x, 1] @ affine`` interpolating the values,
    sum_i coeffs[i] = 0 and centres^T coeffs = 0; condition: the 2-norm condition number of
    the block matrix. Raises InputError naming `zone` when the system is singular or too
    ill-conditioned.
    """
    if not isinstance(options, RBFOptions):
        raise InputError(f"expected RBFOptions, got {type(options).__name__}", field="options")
    c = _points(centres, "centres")
    u = np.asarray(values, dtype=np.float64)
    one = u.ndim == 1
    u = u[:, None] if one else u
    if u.ndim != 2 or len(u) != len(c):
        raise InputError(f"expected ({len(c)}, d) values, got shape {np.shape(values)}", field="values")
    if not np.isfinite(u).all():
        raise InputError("values are not finite", field="values")
    system = _factor(c, options, zone)
    coeffs, M = _coefficients(system, u, zone)
    # back from centred coordinates: [x - o, 1] M = x M[:3] + (M[3] - o M[:3])
    affine = M.copy()
    affine[3] -= system.origin @ M[:3]
    if one:
        return coeffs[:, 0], affine[:, 0], system.condition
    return coeffs, affine, system.condition


def _coefficients(system: _System, u: np.ndarray, zone: str):
    n = len(system.centres)
    rhs = np.zeros((n + 4, u.shape[1]))
    rhs[:n] = u
    x = scipy.linalg.lu_solve((system.lu, system.piv), rhs, check_finite=False)
    if not np.isfinite(x).all():
        raise InputError(f"zone {zone}: the RBF solve gave non-finite coefficients; {_HINT}", field="zones")
    return x[:n], x[n:]


# ----------------------------------------------------------------------------------------------
# zones

def _zone_fields(zones, V: int):
    """(names, vertex_zone (V,), neighbours (Z, Z) bool, blend csr (V, Z)) checked against the contract."""
    try:
        names = tuple(str(n) for n in zones.names)
        vz = np.asarray(zones.vertex_zone)
        nb = np.asarray(zones.neighbours)
        blend = zones.blend
    except AttributeError as e:
        raise InputError(f"expected a Zones object (names, vertex_zone, neighbours, blend): {e}",
                         field="zones") from None
    Z = len(names)
    if Z == 0:
        raise InputError("no zones", field="zones")
    if vz.shape != (V,) or not np.issubdtype(vz.dtype, np.integer) or (V and (vz.min() < 0 or vz.max() >= Z)):
        raise InputError(f"expected vertex_zone ({V},) ints in [0, {Z}), got {vz.dtype} {vz.shape}",
                         field="zones.vertex_zone")
    if nb.shape != (Z, Z) or nb.dtype != bool or not (nb == nb.T).all() or not nb.diagonal().all():
        raise InputError(f"expected neighbours a symmetric ({Z}, {Z}) bool matrix with a True diagonal",
                         field="zones.neighbours")
    blend = scipy.sparse.csr_matrix(blend, dtype=np.float64, copy=True)   # ours to tidy
    if blend.shape != (V, Z):
        raise InputError(f"expected blend of shape ({V}, {Z}), got {blend.shape}", field="zones.blend")
    blend.eliminate_zeros()
    if not np.isfinite(blend.data).all() or (blend.data < 0).any():
        raise InputError("blend weights must be finite and >= 0", field="zones.blend")
    sums = np.asarray(blend.sum(axis=1)).ravel()
    bad = np.abs(sums - 1.0) > 1e-6
    if bad.any():
        v = int(np.argmax(bad))
        raise InputError(f"blend rows must sum to 1 (a partition of unity); vertex {v} sums to {sums[v]:.6g}",
                         field="zones.blend")
    rows = np.repeat(np.arange(V), np.diff(blend.indptr))
    off = ~nb[vz[rows], blend.indices]
    if off.any():
        v, z = int(rows[off][0]), int(blend.indices[off][0])
        raise InputError(f"vertex {v} of zone {names[vz[v]]!r} has blend weight in zone {names[z]!r}, "
                         "which is not its neighbour", field="zones.blend")
    return names, vz.astype(np.int64), nb, blend


def _feature_zone(feature_zone, F: int, Z: int) -> np.ndarray:
    fz = np.asarray(feature_zone)
    if fz.shape != (F,) or not np.issubdtype(fz.dtype, np.integer) or (F and (fz.min() < 0 or fz.max() >= Z)):
        raise InputError(f"expected ({F},) ints in [0, {Z}), got {fz.dtype} {fz.shape}", field="feature_zone")
    return fz.astype(np.int64)


def _feature_vertex(feature_vertex, F: int, V: int):
    if feature_vertex is None:
        return None
    fv = np.asarray(feature_vertex)
    if fv.shape != (F,) or not np.issubdtype(fv.dtype, np.integer) or (F and (fv.min() < -1 or fv.max() >= V)):
        raise InputError(f"expected ({F},) skin vertex indices in [0, {V}) (or -1: not a vertex), "
                         f"got {fv.dtype} {fv.shape}", field="feature_vertex")
    return fv.astype(np.int64)


def _label(names, z: int) -> str:
    return f"{names[z]!r} ({z})"


@dataclass(frozen=True, eq=False)
class _ZoneSet:
    members: np.ndarray     # (m,) feature indices of the zone set
    group: np.ndarray       # (m,) centre of each member
    size: np.ndarray        # (n,) members per centre
    system: _System


def _zone_sets(features: np.ndarray, fz: np.ndarray, names, nb: np.ndarray, active: np.ndarray,
               options: RBFOptions):
    """(sets, counts): per zone its set's members merged into centres and the factored system (None
    for a zone no vertex blends in), and (Z,) distinct centres per zone set. Raises InputError for a
    set with fewer than min_features centres or a singular / ill-conditioned system."""
    sets = []
    own = np.bincount(fz, minlength=len(names))
    counts = np.zeros(len(names), np.int64)
    for z in range(len(names)):
        members = np.flatnonzero(nb[z][fz])
        centres, group = merge_centres(features[members], options.merge)
        counts[z] = len(centres)
        if len(centres) < options.min_features:
            raise InputError(
                f"zone {_label(names, z)} has {int(own[z])} feature points and its neighbours "
                f"{len(members) - int(own[z])}: {len(centres)} distinct centres < min_features "
                f"{options.min_features}; use a smaller feature spacing or a larger reach (more neighbours)",
                field="feature_zone")
        if not active[z]:
            sets.append(None)
            continue
        system = _factor(centres, options, _label(names, z))
        sets.append(_ZoneSet(members, group, np.bincount(group, minlength=len(centres)).astype(np.float64),
                             system))
    return sets, counts


def _merged_count(features: np.ndarray, tol: float) -> int:
    return len(features) - len(merge_centres(features, tol)[0]) if len(features) else 0


@dataclass(frozen=True, eq=False)
class ZoneInterpolants:
    """Every zone's interpolant of one set of feature values (see :func:`zone_interpolants`).

    names : (Z,) zone names; options : the RBFOptions used.
    centres : per zone (n_z, 3) metres (None for a zone no vertex blends in); coeffs : per zone
    (n_z, d); affine : per zone (4, d) (``f_z(x) = sum coeffs phi(|x - centres|) + [x, 1] @ affine``).
    condition : (Z,) 2-norm condition numbers of the block systems (NaN: zone not solved); zone_features : (Z,)
    distinct centres per zone set; merged : features merged away (over all features).
    """
    names: tuple
    options: RBFOptions
    centres: tuple
    coeffs: tuple
    affine: tuple
    condition: np.ndarray
    zone_features: np.ndarray
    merged: int

    def evaluate(self, z: int, points) -> np.ndarray:
        """f_z at points (n, 3) metres -> (n, d) float64 (the zone's own function, unblended)."""
        if self.centres[z] is None:
            raise InputError(f"zone {_label(self.names, z)} has no interpolant (no vertex blends in it)",
                             field="zone")
        x = _points(points, "points")
        c, a, o = self.centres[z], self.affine[z], self.centres[z].mean(axis=0)
        out = np.empty((len(x), a.shape[1]))
        for s in range(0, len(x), BLOCK):
            xb = x[s:s + BLOCK]
            K = _phi_sq(_sq_dist(xb - o, c - o), self.options.kernel, self.options.scale)
            out[s:s + BLOCK] = K @ self.coeffs[z] + xb @ a[:3] + a[3]
        return out

    def blended(self, points, blend) -> np.ndarray:
        """sum_z blend[v, z] f_z(points[v]): points (V, 3) metres, blend (V, Z) sparse -> (V, d)."""
        x = _points(points, "points")
        b = scipy.sparse.csc_matrix(blend)
        out = np.zeros((len(x), self.coeffs[_first(self.coeffs)].shape[1]))
        for z in range(len(self.names)):
            rows = b.indices[b.indptr[z]:b.indptr[z + 1]]
            if len(rows):
                out[rows] += b.data[b.indptr[z]:b.indptr[z + 1], None] * self.evaluate(z, x[rows])
        return out


def _first(items) -> int:
    return next(i for i, c in enumerate(items) if c is not None)


def zone_interpolants(vertices, features, values, feature_zone, zones, options: RBFOptions) -> ZoneInterpolants:
    """Solve every zone's interpolant of `values` at the features.

    vertices : (V, 3) rest skin, metres (only its count is checked against `zones`); features : (F, 3)
    rest feature points, metres; values : (F, d) data at the features (e.g. displacements, metres);
    feature_zone : (F,) int zone of each feature; zones : a Zones object over the V vertices.
    Merged features' values are averaged.
    """
    if not isinstance(options, RBFOptions):
        raise InputError(f"expected RBFOptions, got {type(options).__name__}", field="options")
    verts = _points(vertices, "vertices")
    feats = _points(features, "features")
    u = np.asarray(values, dtype=np.float64)
    if u.ndim != 2 or len(u) != len(feats) or not np.isfinite(u).all():
        raise InputError(f"expected ({len(feats)}, d) finite values, got shape {u.shape}", field="values")
    names, vz, nb, blend = _zone_fields(zones, len(verts))
    fz = _feature_zone(feature_zone, len(feats), len(names))
    active = np.diff(blend.tocsc().indptr) > 0
    sets, counts = _zone_sets(feats, fz, names, nb, active, options)
    centres, coeffs, affine = [], [], []
    cond = np.full(len(names), np.nan)
    for z, s in enumerate(sets):
        if s is None:
            centres.append(None), coeffs.append(None), affine.append(None)
            continue
        mean = np.stack([np.bincount(s.group, weights=u[s.members, a], minlength=len(s.size))
                         for a in range(u.shape[1])], axis=1) / s.size[:, None]
        c, M = _coefficients(s.system, mean, _label(names, z))
        a = M.copy()
        a[3] -= s.system.origin @ M[:3]
        centres.append(frozen_array(s.system.centres + s.system.origin))
        coeffs.append(frozen_array(c))
        affine.append(frozen_array(a))
        cond[z] = s.system.condition
    return ZoneInterpolants(names, options, tuple(centres), tuple(coeffs), tuple(affine), frozen_array(cond),
                            frozen_array(counts, np.int64), _merged_count(feats, options.merge))


def interpolate(vertices, features, displaced, feature_zone, zones, options: RBFOptions, feature_vertex=None):
    """The exact (dense) zoned RBF morph of a skin.

    vertices : (V, 3) rest skin, metres; features : (F, 3) rest feature points; displaced : (F, 3)
    their target positions; feature_zone : (F,) int; zones : Zones over the V vertices;
    feature_vertex : optional (F,) int skin vertex of each feature (-1: none): such vertices land
    exactly on their feature's target (the mean target when several features share a vertex).

    Returns (positions (V, 3) float64 metres, info) with info = {"condition": per-zone list (NaN for
    a zone no vertex blends in), "merged": features merged away, "zones": per-zone distinct centres,
    "seconds": {"solve", "evaluate"}} (JSON-ready).
    """
    t0 = time.perf_counter()
    verts = _points(vertices, "vertices")
    feats = _points(features, "features")
    moved = _points(displaced, "displaced", len(feats))
    fv = _feature_vertex(feature_vertex, len(feats), len(verts))
    interp = zone_interpolants(verts, feats, moved - feats, feature_zone, zones, options)
    t1 = time.perf_counter()
    positions = verts + interp.blended(verts, scipy.sparse.csr_matrix(zones.blend, dtype=np.float64))
    if fv is not None:
        on = fv >= 0
        count = np.bincount(fv[on], minlength=len(verts))
        hit = count > 0
        target = np.stack([np.bincount(fv[on], weights=moved[on, a], minlength=len(verts)) for a in range(3)], 1)
        positions[hit] = target[hit] / count[hit, None]
    t2 = time.perf_counter()
    info = {"condition": [float(c) for c in interp.condition], "merged": int(interp.merged),
            "zones": [int(c) for c in interp.zone_features],
            "seconds": {"solve": t1 - t0, "evaluate": t2 - t1}}
    return positions, info


# ----------------------------------------------------------------------------------------------
# precomputed sparse weights for animation

@dataclass(frozen=True, eq=False)
class ZoneRBF:
    """Sparse cardinal weights: skin vertex v = sum_j weight[v, j] * features[index[v, j]] (current
    feature positions, metres).

    index : (V, k) int32 feature indices, weight : (V, k) float64; per row sorted by |weight|
    descending (index[v, 0] the largest), rows with fewer non-zeros padded with index 0 / weight 0.
    Each row reproduces affine maps exactly: sum_j weight = 1, sum_j weight p_j = v at rest.
    condition : (Z,) float64 2-norm condition numbers of the block systems (NaN: zone not solved);
    zone_features : (Z,) int distinct centres per zone set; merged : features merged away;
    names : (Z,) zone names; num_features : F.
    """
    index: np.ndarray
    weight: np.ndarray
    condition: np.ndarray
    zone_features: np.ndarray
    merged: int
    names: tuple
    num_features: int

    @property
    def num_vertices(self) -> int:
        return len(self.index)

    @property
    def support(self) -> int:
        return self.index.shape[1]

    def apply(self, points) -> np.ndarray:
        """NumPy reference: points (F, 3) or (T, F, 3) metres -> (V, 3) or (T, V, 3) float64."""
        p = np.asarray(points, dtype=np.float64)
        F = self.num_features
        if p.shape[-2:] != (F, 3) or p.ndim not in (2, 3):
            raise InputError(f"expected ({F}, 3) or (T, {F}, 3) points, got shape {p.shape}", field="points")
        if p.ndim == 2:
            return np.einsum("vk,vkc->vc", self.weight, p[self.index])
        # frame by frame: a (T, V, k, 3) gather at once would be T x 67 MB for 87k vertices, k = 32
        return np.stack([np.einsum("vk,vkc->vc", self.weight, q[self.index]) for q in p]) if len(p) else \
            np.zeros((0, self.num_vertices, 3))


def build_zone_rbf(vertices, features, feature_zone, zones, options: RBFOptions, feature_vertex=None) -> ZoneRBF:
    """Precompute the per-vertex cardinal weights of the zoned interpolant.

    vertices : (V, 3) rest skin, metres; features : (F, 3) rest feature points, metres;
    feature_zone : (F,) int; zones : Zones over the V vertices; feature_vertex : optional (F,) int skin
    vertex of each feature (-1: none): that vertex gets the exact row (weight 1 on its feature; 1/c on
    each of c features sharing it).

    Per zone the block matrix is factored once; vertex blocks of :data:`BLOCK` rows then solve for
    their cardinal rows (all rows of a block at once), mix them with the blend weights, give each
    merged centre's weight to its member features (1/size each), keep the `support` largest |w| per
    row and add the minimum-norm correction that restores sum w = 1 and sum w p = v (four linear
    constraints per row, batched 4 x 4 solves).
    """
    if not isinstance(options, RBFOptions):
        raise InputError(f"expected RBFOptions, got {type(options).__name__}", field="options")
    verts = _points(vertices, "vertices")
    feats = _points(features, "features")
    V, F = len(verts), len(feats)
    names, vz, nb, blend = _zone_fields(zones, V)
    fz = _feature_zone(feature_zone, F, len(names))
    fv = _feature_vertex(feature_vertex, F, V)
    active = np.diff(blend.tocsc().indptr) > 0
    sets, counts = _zone_sets(feats, fz, names, nb, active, options)
    exact = np.zeros(V, bool)
    if fv is not None:
        exact[fv[fv >= 0]] = True
    # vertices grouped by the set of zones they blend (most: their own zone alone); a group's rows
    # are non-zero only on the union of its zones' feature sets
    patterns, of_vertex, values = _blend_patterns(blend)
    columns = [np.unique(np.concatenate([sets[z].members for z in pat if z >= 0])) for pat in patterns]
    k = options.support or max(len(c) for c in columns)
    if fv is not None:
        k = max(k, int(np.bincount(fv[fv >= 0]).max(initial=1)))
    index = np.zeros((V, k), np.int32)
    weight = np.zeros((V, k))
    order = np.argsort(of_vertex, kind="stable")
    starts = np.searchsorted(of_vertex[order], np.arange(len(patterns) + 1))
    for p, pat in enumerate(patterns):
        R = order[starts[p]:starts[p + 1]]
        R = R[~exact[R]]
        cols = columns[p]
        zs = [z for z in pat if z >= 0]
        local = [np.searchsorted(cols, sets[z].members) for z in zs]
        for s0 in range(0, len(R), BLOCK):
            rows = R[s0:s0 + BLOCK]
            W = np.zeros((len(rows), len(cols))) if len(zs) > 1 else None
            for j, z in enumerate(zs):
                s = sets[z]
                X = _cardinal(s.system, verts[rows], options)       # (rows, centres)
                X *= values[rows, j][:, None]
                if len(s.size) != len(s.members):                   # merged: 1 / size to each member
                    X = X[:, s.group] / s.size[s.group]
                if W is None:
                    W = X                   # one zone: its members are the columns, in order
                else:
                    W[:, local[j]] += X
            idx, w = _truncate(W, k, verts[rows], feats[cols])
            idx = cols[idx]
            idx[w == 0] = 0
            index[rows], weight[rows] = idx, w
    if not np.isfinite(weight).all():
        raise InputError(f"non-finite weights; {_HINT}", field="zones")
    if fv is not None:
        on = np.flatnonzero(fv >= 0)
        count = np.bincount(fv[on], minlength=V)
        slot = np.zeros(V, np.int64)
        for f in on:        # few features per vertex; a loop over features (once, at build)
            v = fv[f]
            index[v, slot[v]] = f
            weight[v, slot[v]] = 1.0 / count[v]
            slot[v] += 1
    cond = np.array([np.nan if s is None else s.system.condition for s in sets])
    return ZoneRBF(frozen_array(index, np.int32), frozen_array(weight), frozen_array(cond),
                   frozen_array(counts, np.int64), _merged_count(feats, options.merge), names, F)


def _cardinal(system: _System, x: np.ndarray, options: RBFOptions) -> np.ndarray:
    """(len(x), n) cardinal rows of the zone's interpolant at points x: f(x) = rows @ U for data U at
    its centres. A is symmetric, so row(x)^T = (A^{-1} [K(x); x; 1])[:n]: one LU solve with the
    points as right-hand sides (rows(x).T is already column-major, as LAPACK wants it)."""
    n = len(system.centres)
    X = scipy.linalg.lu_solve((system.lu, system.piv), system.rows(x, options.kernel, options.scale).T,
                              overwrite_b=True, check_finite=False)
    return X[:n].T


def _blend_patterns(blend: scipy.sparse.csr_matrix):
    """(patterns (P, m) int, zones of each distinct blend row padded with -1; of_vertex (V,) pattern
    of each vertex; values (V, m) its blend weights in the pattern's zone order)."""
    b = blend.copy()
    b.sort_indices()
    V = b.shape[0]
    per_row = np.diff(b.indptr)
    m = max(1, int(per_row.max(initial=0)))
    row = np.repeat(np.arange(V), per_row)
    col = np.arange(b.nnz) - b.indptr[row]
    zones = np.full((V, m), -1, np.int64)
    values = np.zeros((V, m))
    zones[row, col] = b.indices
    values[row, col] = b.data
    patterns, of_vertex = np.unique(zones, axis=0, return_inverse=True)
    return patterns, of_vertex.ravel(), values


def _truncate(W: np.ndarray, k: int, verts: np.ndarray, feats: np.ndarray):
    """Keep the k largest |W| per row, sorted by |w| descending, then restore affine reproduction on
    rows that lost non-zeros. W : (n, c) rows over features feats (c, 3); verts : (n, 3) their rest
    vertices. Returns (index (n, k) int64 into the c columns, weight (n, k)), padded with weight 0
    when k > c."""
    n, c = W.shape
    A = np.abs(W)
    if k < c:
        idx = np.argpartition(A, c - k, axis=1)[:, c - k:]
    else:
        idx = np.broadcast_to(np.arange(c), (n, c))
    order = np.argsort(-np.take_along_axis(A, idx, 1), axis=1, kind="stable")
    idx = np.take_along_axis(idx, order, 1)
    w = np.take_along_axis(W, idx, 1)
    if k < c:
        cut = np.count_nonzero(W, axis=1) > k
        if cut.any():
            w[cut] = _affine_correction(w[cut], feats[idx[cut]], verts[cut])
            again = np.argsort(-np.abs(w[cut]), axis=1, kind="stable")   # the change may reorder
            idx[cut] = np.take_along_axis(idx[cut], again, 1)
            w[cut] = np.take_along_axis(w[cut], again, 1)
    else:
        idx = np.pad(idx, ((0, 0), (0, k - c)))
        w = np.pad(w, ((0, 0), (0, k - c)))
    return idx, w


def _affine_correction(w: np.ndarray, p: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The minimum-norm change of w (n, k) so that sum_j w_j = 1 and sum_j w_j p_j = v (p (n, k, 3),
    v (n, 3)).

    With Q (k, 4) of rows ((p_j - v) / L, 1) (L: the row's RMS distance, so the columns are of one
    size) the constraints read Q^T w = (0, 0, 0, 1) = t, and the minimum-norm change is
    Q (Q^T Q)^{-1} (t - Q^T w) = Q1 R^{-T} (t - Q^T w) with Q = Q1 R (QR: no squared condition number
    where the kept features are nearly coplanar), repeated once to refine the round-off.
    """
    d = p - v[:, None, :]
    L = np.sqrt(np.einsum("nkc,nkc->n", d, d) / d.shape[1])
    L[L == 0] = 1.0
    Q = np.concatenate([d / L[:, None, None], np.ones(d.shape[:2] + (1,))], axis=2)   # (n, k, 4)
    Q1, R = np.linalg.qr(Q)
    RT = np.swapaxes(R, 1, 2)
    ok = np.abs(np.diagonal(R, axis1=1, axis2=2)).min(axis=1) > 1e-12 * np.abs(R).max(axis=(1, 2))
    for _ in range(2):
        r = -np.einsum("nki,nk->ni", Q, w)
        r[:, 3] += 1.0
        y = np.zeros_like(r)
        if ok.any():
            y[ok] = np.linalg.solve(RT[ok], r[ok, :, None])[..., 0]
        if not ok.all():    # exactly coplanar kept features: the least-squares (pseudo-inverse) change
            y[~ok] = np.einsum("nij,nj->ni", np.linalg.pinv(RT[~ok], rcond=1e-12), r[~ok])
        w = w + np.einsum("nki,ni->nk", Q1, y)
    return w


# ----------------------------------------------------------------------------------------------
# smoothness across zone boundaries

def weld_edges(vertices, faces, tol: float = 1e-7):
    """Unique undirected mesh edges after welding vertices closer than `tol` metres.

    Returns (edges (E, 2) int64 of representative vertex indices (the lowest index of each welded
    group), rep (V,) int64 representative of every vertex)."""
    verts = _points(vertices, "vertices")
    f = np.asarray(faces)
    if f.ndim != 2 or f.shape[1] != 3 or not np.issubdtype(f.dtype, np.integer) or \
            (f.size and (f.min() < 0 or f.max() >= len(verts))):
        raise InputError(f"expected (n, 3) int faces indexing {len(verts)} vertices", field="faces")
    _, group = merge_centres(verts, tol) if tol > 0 else (None, np.arange(len(verts)))
    first = np.full(group.max() + 1 if len(group) else 0, len(verts), np.int64)
    np.minimum.at(first, group, np.arange(len(verts)))
    rep = first[group]
    e = rep[f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)]
    e = np.sort(e[e[:, 0] != e[:, 1]], axis=1)
    return np.unique(e, axis=0), rep


def boundary_report(vertices, faces, displacement, zones, interpolants: ZoneInterpolants | None = None,
                    weld: float = 1e-7) -> dict:
    """Numbers that show how smooth a zoned displacement is across zone boundaries (JSON-ready).

    vertices : (V, 3) rest skin, metres; faces : (n, 3) int; displacement : (V, 3) the blended result
    minus the rest skin, metres; zones : Zones over V; interpolants : optional, the
    :class:`ZoneInterpolants` that made it (adds the raw jumps); weld : metres (meshes split at UV
    seams are welded by position first).

    Edges are sorted by the zones (vertex_zone) of their ends: "interior" (same zone), "boundary"
    (neighbouring zones: blending can hide the step there) and "apart" (zones that are not
    neighbours but touch on the mesh, like two thighs at the crotch: nothing blends them, so their
    step stays).
    "gradient": |d(a) - d(b)| / |a - b| per edge (dimensionless, metres of displacement change per
    metre): max, p99 (99th percentile) and mean for each kind of edge, and ratio_max / ratio_p99 =
    boundary / interior (~1: the boundaries are as smooth as the zones' insides).
    "raw_jump" (with interpolants): |f_A(x) - f_B(x)| in metres at both ends x of each boundary
    (and apart) edge, A and B the zones of its ends, before blending: what blending has to hide.
    """
    verts = _points(vertices, "vertices")
    d = _points(displacement, "displacement", len(verts))
    names, vz, nb, _ = _zone_fields(zones, len(verts))
    edges, _ = weld_edges(verts, faces, weld)
    a, b = edges[:, 0], edges[:, 1]
    length = np.linalg.norm(verts[a] - verts[b], axis=1)
    grad = np.linalg.norm(d[a] - d[b], axis=1) / np.maximum(length, 1e-12)
    cross = vz[a] != vz[b]

    def stats(x):
        if len(x) == 0:
            return {"max": 0.0, "p99": 0.0, "mean": 0.0}
        return {"max": float(x.max()), "p99": float(np.percentile(x, 99)), "mean": float(x.mean())}

    apart = cross & ~nb[vz[a], vz[b]]
    cross &= ~apart
    gb, gi = stats(grad[cross]), stats(grad[~cross & ~apart])
    out = {"boundary_edges": int(cross.sum()), "apart_edges": int(apart.sum()),
           "interior_edges": int((~cross & ~apart).sum()),
           "gradient": {"boundary": gb, "interior": gi, "apart": stats(grad[apart]),
                        "ratio_max": gb["max"] / gi["max"] if gi["max"] > 0 else float("nan"),
                        "ratio_p99": gb["p99"] / gi["p99"] if gi["p99"] > 0 else float("nan")}}
    if interpolants is not None:
        out["raw_jump"] = {"boundary": _raw_jumps(interpolants, verts, vz, a[cross], b[cross], stats),
                           "apart": _raw_jumps(interpolants, verts, vz, a[apart], b[apart], stats)}
    return out


def _raw_jumps(interpolants: ZoneInterpolants, verts, vz, ea, eb, stats) -> dict:
    """|f_A(x) - f_B(x)| at both ends x of edges (ea, eb) between zones A = vz[ea], B = vz[eb]."""
    jumps = []
    pairs = np.stack([vz[ea], vz[eb]], axis=1)
    for za, zb in np.unique(pairs, axis=0):
        if interpolants.centres[za] is None or interpolants.centres[zb] is None:
            continue
        sel = (pairs[:, 0] == za) & (pairs[:, 1] == zb)
        pts = verts[np.unique(np.concatenate([ea[sel], eb[sel]]))]
        jumps.append(np.linalg.norm(interpolants.evaluate(za, pts) - interpolants.evaluate(zb, pts), axis=1))
    return stats(np.concatenate(jumps) if jumps else np.zeros(0))


# ----------------------------------------------------------------------------------------------
# Warp launcher

class RBFSkinner:
    """Applies a :class:`ZoneRBF` on a Warp device (kernel :func:`rig.anatomy.rbf_kernels.rbf_gather`).

    The index and float32 weights are uploaded once; each call uploads the feature positions and
    reuses the output buffers (per frame count T).
    """

    def __init__(self, rbf: ZoneRBF, device="cpu"):
        import warp as wp
        if not isinstance(rbf, ZoneRBF):
            raise InputError(f"expected a ZoneRBF, got {type(rbf).__name__}", field="rbf")
        self.device = wp.get_device(device)
        self.num_vertices = rbf.num_vertices
        self.num_features = rbf.num_features
        d = self.device
        self._index = wp.array(np.ascontiguousarray(rbf.index, np.int32), dtype=wp.int32, device=d)
        self._weight = wp.array(np.ascontiguousarray(rbf.weight, np.float32), dtype=wp.float32, device=d)
        self._points = {}
        self._out = {}

    def _buffers(self, T: int):
        import warp as wp
        if T not in self._out:
            self._points[T] = wp.empty((T, self.num_features), dtype=wp.vec3, device=self.device)
            self._out[T] = wp.empty((T, self.num_vertices), dtype=wp.vec3, device=self.device)
        return self._points[T], self._out[T]

    def launch(self, points):
        """Device entry point: points (F,) or (T, F) wp.vec3 on this device, metres -> the wrapper's
        (V,) or (T, V) wp.vec3 buffer, valid until the next call with the same T."""
        import warp as wp

        from jiggle.rig.anatomy import rbf_kernels as kernels
        F = self.num_features
        ok = isinstance(points, wp.array) and points.dtype == wp.vec3 and points.device == self.device
        one = ok and points.shape == (F,)
        if not (one or (ok and points.ndim == 2 and points.shape[1] == F)):
            desc = (f"{points.dtype.__name__} {points.shape} on {points.device}" if isinstance(points, wp.array)
                    else type(points).__name__)
            raise InputError(f"expected a ({F},) or (T, {F}) wp.vec3 array on {self.device}, got {desc}",
                             field="points")
        p2 = points.reshape((1, F)) if one else points
        T = p2.shape[0]
        _, out = self._buffers(T)
        if T and self.num_vertices:
            wp.launch(kernels.rbf_gather, dim=(T, self.num_vertices), device=self.device,
                      inputs=[self._index, self._weight, p2], outputs=[out])
        return out.reshape((self.num_vertices,)) if one else out

    def apply(self, points) -> np.ndarray:
        """points (F, 3) float metres -> (V, 3) float32, a new array."""
        p = np.asarray(points)
        if p.shape != (self.num_features, 3):
            raise InputError(f"expected ({self.num_features}, 3) points, got shape {p.shape}", field="points")
        return self.apply_batch(p[None])[0]

    def apply_batch(self, points) -> np.ndarray:
        """points (T, F, 3) float metres -> (T, V, 3) float32, a new array (one launch)."""
        p = np.asarray(points)
        if p.ndim != 3 or p.shape[1:] != (self.num_features, 3) or not np.issubdtype(p.dtype, np.number):
            raise InputError(f"expected (T, {self.num_features}, 3) float points, got shape {p.shape}",
                             field="points")
        buf, _ = self._buffers(len(p))
        buf.assign(np.ascontiguousarray(p, np.float32))
        out = self.launch(buf).numpy()
        # on the CPU .numpy() is a view of the scratch buffer the next call overwrites
        return out.copy() if self.device.is_cpu else out
