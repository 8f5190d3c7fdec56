"""The thesis muscle (Hoehne, sections 5.3 and 6.3) for every fitted muscle, vectorised over muscles.

A muscle is an action curve, 5 cross-sections of 8 CVs along it and the loft through them
(rig/muscle/loft.py). It is built once from a :class:`MuscleSpec` (a fitted, conformed muscle at bind, world
metres) and the bind transforms of the joints; per frame, :meth:`MuscleRig.static` takes the joints'
rigid world transforms and returns the static (goal) position of every section CV of every muscle
as one flat array, the positions the jiggle simulation starts from and is pulled toward.

Attachments
    The four attachment points (origin, origin hinge, insertion hinge, insertion) are stored in the
    local frame of the joint each rides (``inv(bind_world[b]) @ p``) and follow it per frame.
Tendons (Pratscher et al. 2005, "Procedural deformation": tendon length stays constant)
    The tendon runs origin -> o_hinge -> belly end e_o (and insertion -> i_hinge -> e_i). Its rest
    length T_o = |origin - o_hinge| + |o_hinge - ends[0]| is kept; the part between hinge and belly
    is ``l_o = T_o - |origin - o_hinge|`` (it may grow or shrink, or turn negative, so the belly
    absorbs every change of attachment distance). The belly end sits at ``e_o = o_hinge + l_o d_o``
    where d_o is the rest direction from the hinge to ends[0] expressed against
    ``u = unit(i_hinge - o_hinge)``: its component along u is kept and its perpendicular part rides
    the hinge's joint (re-orthogonalised to u). With the hinges at the belly ends (the default) the
    rest direction is undefined and d_o = u, d_i = -u: the ends slide along the hinge axis.
    A muscle cannot collapse: the belly's extent along u is kept >= MIN_BELLY (0.3) x its rest chord
    |ends[1] - ends[0]| by pushing both ends apart symmetrically along u.
Action curve (thesis 6.3)
    A clamped cubic B-spline (knots 0,0,0,0,.5,1,1,1,1) with 5 CVs: e_o, e_o + 0.125 c t_o,
    (e_o + e_i) / 2 + R_a middle_offset, e_i - 0.125 c t_i, e_i, where c = |e_i - e_o|, t_o is the rest
    belly direction carried by the o_hinge joint's rotation and t_i by the i_hinge joint's (a muscle
    whose hinges ride different joints bends), and R_a is the rotation of joint `bone`. Arc length
    by 8-point Gauss-Legendre quadrature on each of the two knot spans (the speed is smooth within a
    span), the same rule at rest and per frame.
Sections
    At curve parameters u_k = (0, 0.5 - b, 0.5, 0.5 + b, 1), b = bulge_position: frame T = unit
    tangent, U = R_a up made perpendicular to T (Gram-Schmidt; when up is within ~0.06 deg of T the
    side vector R_a unit(t_rest x up) is used instead), S = T x U. CV j of section k is
    ``c(u_k) + s_k (a_kj U + b_kj S)`` with the fitted 2D offsets (a, b) and the section scale
    s_k = attribute_k x s_volume, attribute = (rim, bulge, main, bulge, rim) scale.
    As in the thesis (one up object for the tangent constraints) a section turns fast about its
    tangent when that tangent passes near the up vector: possible only at the end of a muscle whose
    end tangent rides another joint than `bone` (flexed 90 deg toward the up vector).
Fit (at build)
    The 80 offsets (a, b) are the linear least-squares fit of the loft to the spec's surface points
    (the conformed shape), at attribute scale 1 (the attributes then scale the fitted shape; with the
    defaults 1 the rest loft reproduces the conformed muscle). Each point gets loft parameters (w, v):
    first from its projection on the rest chord (w) and its angle about the local frame (v), then,
    after each fit, the foot point on the fitted surface (nearest of a dense sampling, refined by a
    few Gauss-Newton steps); three fits. A small regulariser (weight FIT_SMOOTHING per point) penalises
    ``CV[j-1] + CV[j+1] - 2 cos(45 deg) CV[j]`` around each ring, which is zero for any ellipse
    centred on the curve and damps ripples and CVs the data do not reach; a tiny ridge (FIT_RIDGE)
    keeps the system regular. fit_rms / fit_max are the distances of the spec points to the fitted
    loft at attributes 1: the nearer of their foot point on the smooth surface and the end caps.
Volume (per frame; Li = rest arc length, Lc = current)
    "exact" (default): s = sqrt(Li / Lc) (exact for a straight muscle, whose volume goes with the
        section area times the length), then the lofted volume V is measured and s is corrected by
        sqrt(V_rest / V) (EXACT_ITERATIONS times, the factor clipped to [0.5, 2]). One correction
        holds the lofted volume to ~1e-5 even for a muscle folded 140 deg across the elbow (its
        volume is V2 s^2 plus small odd terms from the bend). At bind the correction is exactly 1,
        so the NumPy path static(bind_world, device=None) reproduces rest_cvs bit for bit (the Warp
        kernel, summing in another order, to ~1e-16 m).
    "sqrt": s = sqrt(Li / Lc).   "thesis": s = Li / Lc (thesis 6.3, S = Sc Li / Lc: sections' area
        goes with the square, so the volume drifts by Li / Lc).   "none": s = 1.
    Tone t in [0, 1] (Pratscher et al.) attenuates the change: s = 1 + t (s_rule - 1); t = 0 keeps the
    sections at their rest size (so below 1 no rule keeps the volume: that is the point of tone).
    The lofted volume is the enclosed volume of the loft's closed mesh (rig/muscle/loft.py: 17 x 16 grid
    plus centroid caps), the one `volumes` and `surface` use.
Output
    Flat CVs (N, 3), N = 40 M; muscle m owns rows cv_offsets[m]:cv_offsets[m + 1], section-major
    (section k, CV j at 8 k + j). The 5 action-curve CVs per muscle come separately (`curve`); the
    jiggle simulation moves the section CVs. By default (device "cpu") all frames and muscles of a
    call are one launch of a Warp kernel, one thread per (frame, muscle), in float64
    (rig/muscle/static_kernels.py); device=None runs the NumPy reference, which loops in Python only
    over chunks of STATIC_CHUNK frames: its arrays run components first and muscles last, so every
    step is one NumPy call over all muscles. The two agree to ~1e-14 m. On chunks of 256 frames of 28
    muscles the kernel is ~3x faster with the "exact" rule and ~5x with the others
    (benchmarks/bench_muscle_update.py).
"""
from __future__ import annotations

import weakref
from dataclasses import dataclass
from functools import lru_cache
from typing import ClassVar, NamedTuple

import numpy as np
from scipy.interpolate import BSpline
from scipy.spatial import cKDTree

from jiggle.rig.base.errors import InputError
from jiggle.rig.base.frozen import frozen_array
from jiggle.rig.muscle import loft

VOLUME_RULES = ("exact", "sqrt", "thesis", "none")
CURVE_KNOTS = frozen_array([0.0, 0.0, 0.0, 0.0, 0.5, 1.0, 1.0, 1.0, 1.0])
CURVE_TANGENT_FRACTION = 0.125   # CVs 1 and 3 sit 12.5% of the belly chord along the end tangents
MIN_BELLY = 0.3                  # the belly keeps at least this fraction of its rest chord
EXACT_ITERATIONS = 1             # measured-volume corrections after the sqrt start
FIT_ITERATIONS = 3               # least-squares fits (parameters re-projected between them)
FIT_SMOOTHING = 1e-3             # ring regulariser weight per surface point
FIT_RIDGE = 1e-9                 # ridge weight per surface point
STATIC_CHUNK = 4                 # frames evaluated together (bounds the temporary arrays)

# slots of the per-muscle local points / vectors, each riding one joint (pairs kept adjacent so the
# per-frame code treats the origin and insertion sides together)
_ORIGIN, _INSERTION, _O_HINGE, _I_HINGE, _Q_O, _Q_I, _T_O, _T_I, _MIDDLE, _UP, _SIDE = range(11)
_SLOTS = 11

_GL_X, _GL_W = np.polynomial.legendre.leggauss(8)
_ARC_U = np.concatenate([0.25 + 0.25 * _GL_X, 0.75 + 0.25 * _GL_X])     # two knot spans
_ARC_W = np.concatenate([0.25 * _GL_W, 0.25 * _GL_W])
_CURVE = BSpline(CURVE_KNOTS, np.eye(5), 3)
_ARC_SLOPE = _CURVE.derivative()(_ARC_U)                                 # (16, 5)


def curve_basis(u, derivative: int = 0) -> np.ndarray:
    """(n, 5) weights of the 5 action-curve CVs at curve parameters u (n,) in [0, 1]."""
    u = np.clip(np.asarray(u, dtype=np.float64).ravel(), 0.0, 1.0)
    return (_CURVE.derivative(derivative) if derivative else _CURVE)(u)


def station_parameters(bulge_position) -> np.ndarray:
    """(..., 5) curve parameters of the sections: 0, 0.5 - b, 0.5, 0.5 + b, 1."""
    b = np.asarray(bulge_position, dtype=np.float64)[..., None]
    return np.array([0.0, 0.5, 0.5, 0.5, 1.0]) + np.array([0.0, -1.0, 0.0, 1.0, 0.0]) * b


# ---------------------------------------------------------------------------------- spec
@dataclass(frozen=True, eq=False)
class MuscleSpec:
    """One fitted muscle at bind, world metres. Arrays are read-only.

    name, kind ("muscle", "fat", ...), group : labels carried to the rig.
    bone : joint a, whose rotation carries the up vector and the middle offset.
    bones : (4,) int joint indices the origin, o_hinge, i_hinge and insertion ride.
    points : (4, 3) origin, o_hinge, i_hinge, insertion at bind.
    ends : (2, 3) the belly's ends (the conformed muscle's major-axis ends) at bind.
    up : (3,) roughly perpendicular to the belly axis (made exactly so, and unit, at build).
    surface : (n, 3) points of the conformed muscle the loft reproduces (n >= 16).
    rim_scale, bulge_scale, main_scale : > 0, multiply the fitted end, bulge and middle sections.
    bulge_position : b in (0, 0.5), the bulge sections sit at curve parameters 0.5 -/+ b.
    tone : in [0, 1], how much of the volume rule's section scaling applies.
    middle_offset : (3,) metres, the middle curve CV's offset from the chord's midpoint, in the local
        frame of joint `bone` (the frame bind_world[bone] rotates, riding with it).
    """

    name: str
    kind: str
    group: str
    bone: int
    bones: np.ndarray
    points: np.ndarray
    ends: np.ndarray
    up: np.ndarray
    surface: np.ndarray
    rim_scale: float = 1.0
    bulge_scale: float = 1.0
    main_scale: float = 1.0
    bulge_position: float = 0.25
    tone: float = 1.0
    middle_offset: np.ndarray = (0.0, 0.0, 0.0)

    def __post_init__(self):
        set_ = lambda k, v: object.__setattr__(self, k, v)  # noqa: E731 (frozen dataclass)
        where = f"muscle {self.name!r}"
        shapes = {"bones": (4,), "points": (4, 3), "ends": (2, 3), "up": (3,), "middle_offset": (3,)}
        try:
            set_("bone", int(self.bone))
            set_("bones", frozen_array(np.asarray(self.bones).reshape(-1), np.int64))
            for k in ("points", "ends", "up", "surface", "middle_offset"):
                set_(k, frozen_array(getattr(self, k)))
            for k in ("rim_scale", "bulge_scale", "main_scale", "bulge_position", "tone"):
                set_(k, float(getattr(self, k)))
        except (TypeError, ValueError) as e:
            raise InputError(f"{where}: {e}", field="MuscleSpec") from None
        for k, shape in shapes.items():
            if getattr(self, k).shape != shape:
                raise InputError(f"{where}: {k} has shape {getattr(self, k).shape}, expected {shape}", field=k)
        if self.surface.ndim != 2 or self.surface.shape[1] != 3 or len(self.surface) < 16:
            raise InputError(f"{where}: surface must be (n, 3) with n >= 16 points, got {self.surface.shape}",
                             field="surface")
        for k in ("points", "ends", "up", "surface", "middle_offset", "rim_scale", "bulge_scale",
                  "main_scale", "bulge_position", "tone"):
            if not np.all(np.isfinite(getattr(self, k))):
                raise InputError(f"{where}: {k} holds NaN or inf", field=k)
        for k in ("rim_scale", "bulge_scale", "main_scale"):
            if getattr(self, k) <= 0:
                raise InputError(f"{where}: {k} must be > 0, got {getattr(self, k)}", field=k)
        if not 0.0 < self.bulge_position < 0.5:
            raise InputError(f"{where}: bulge_position must be in (0, 0.5), got {self.bulge_position}",
                             field="bulge_position")
        if not 0.0 <= self.tone <= 1.0:
            raise InputError(f"{where}: tone must be in [0, 1], got {self.tone}", field="tone")
        chord = self.ends[1] - self.ends[0]
        if np.linalg.norm(chord) < 1e-6:
            raise InputError(f"{where}: zero-length belly (ends {self.ends[0]} and {self.ends[1]} coincide)",
                             field="ends")
        if np.linalg.norm(self.points[2] - self.points[1]) < 1e-6:   # (origin, o_hinge, i_hinge, insertion)
            raise InputError(f"{where}: zero-length belly (o_hinge and i_hinge coincide)", field="points")
        t = chord / np.linalg.norm(chord)
        n = np.linalg.norm(self.up)
        if n < 1e-12 or np.linalg.norm(self.up - (self.up @ t) * t) < 0.1 * n:
            raise InputError(f"{where}: up {self.up} is zero or nearly parallel to the belly axis {t}",
                             field="up")


class StaticShape(NamedTuple):
    """Static muscle shape for one frame or a batch of T frames.

    cvs : (N, 3) or (T, N, 3) float64 metres, section CVs of all muscles (see MuscleRig.cv_offsets).
    curve : (M, 5, 3) or (T, M, 5, 3) float64 metres, the action-curve CVs.
    """

    cvs: np.ndarray
    curve: np.ndarray


# ---------------------------------------------------------------------------------- rig
@dataclass(frozen=True, eq=False)
class MuscleRig:
    """All muscles of a character, built once (`build_muscle_rig`); arrays are read-only.

    names, kinds, groups : (M,) labels.
    volume : the volume rule, one of VOLUME_RULES.
    num_joints : J, the joints `static` expects.
    cv_offsets : (M + 1,) int64, muscle m's CVs are rows cv_offsets[m]:cv_offsets[m + 1] (40 each).
    rest_cvs : (N, 3) float64 metres, the section CVs at bind (N = 40 M), equal to static(bind_world).
    rest_curve : (M, 5, 3) action-curve CVs at bind.
    rest_volume : (M,) cubic metres, lofted volume at bind.
    rest_length : (M,) metres, Li, the action curve's arc length at bind.
    fit_rms, fit_max : (M,) metres, distance of the spec's surface points to the fitted loft.
    sections : (M, 5, 8, 2) metres, fitted offsets (a, b) of each section CV along (U, S), attributes 1.
    section_scale : (M, 5) attribute scale of each section (rim, bulge, main, bulge, rim).
    tone : (M,) in [0, 1].
    bulge_position : (M,).
    joints : (M, 11) int64, the joint each local point / vector rides (slots: origin, insertion,
        o_hinge, i_hinge, q_o, q_i, t_o, t_i, middle offset, up, side).
    local : (M, 11, 4) homogeneous local coordinates (points w = 1, directions w = 0).
    tendon : (M, 2) metres, rest tendon lengths T_o, T_i.
    hinge_along : (M, 2) component along u of the rest hinge -> belly-end directions (1, -1 by default).
    rest_chord : (M,) metres, |ends[1] - ends[0]|.
    station_basis, station_slope : (M, 5, 5) curve weights (and d/du) at each section's parameter.
    pose_shapes : None, or rig.muscle.pose_shapes.SectionShapes: sections scaled by joint bends, applied
        after the volume rule (attach them with dataclasses.replace; rest_cvs stays the fitted shape).
    """

    CVS_PER_MUSCLE: ClassVar[int] = loft.SECTIONS * loft.RING

    names: tuple
    kinds: tuple
    groups: tuple
    volume: str
    num_joints: int
    cv_offsets: np.ndarray
    rest_cvs: np.ndarray
    rest_curve: np.ndarray
    rest_volume: np.ndarray
    rest_length: np.ndarray
    fit_rms: np.ndarray
    fit_max: np.ndarray
    sections: np.ndarray
    section_scale: np.ndarray
    tone: np.ndarray
    bulge_position: np.ndarray
    joints: np.ndarray
    local: np.ndarray
    tendon: np.ndarray
    hinge_along: np.ndarray
    rest_chord: np.ndarray
    station_basis: np.ndarray
    station_slope: np.ndarray
    pose_shapes: object = None

    def __post_init__(self):
        # the per-frame path works on components-first, muscles-last arrays (x, ..., T, M): every
        # elementwise step then runs over contiguous rows of all muscles at once
        set_ = lambda k, v: object.__setattr__(self, k, frozen_array(v))  # noqa: E731
        set_("_stations", np.concatenate([self.station_basis, self.station_slope], axis=1) @ _CURVE_FROM_Z)
        set_("_tendon", self.tendon.T[:, None])                                 # (2, 1, M)
        set_("_along", self.hinge_along.T[:, None])                             # (2, 1, M)
        set_("_cv_ab", self.sections.transpose(3, 1, 2, 0)[:, :, :, None, None])  # (2, 5, 8, 1, 1, M)
        set_("_scale", self.section_scale.T[:, None])                           # (5, 1, M)

    @property
    def M(self) -> int:
        """Number of muscles."""
        return len(self.names)

    @property
    def surface_faces(self) -> np.ndarray:
        """(F, 3) int32 triangles of one muscle's closed loft mesh (indices into `surface`'s P points)."""
        return loft.FACES

    # ------------------------------------------------------------------ per frame
    def static(self, world: np.ndarray, *, volume: str | None = None, device: str | None = "cpu") -> StaticShape:
        """Static shape of every muscle for joint world transforms `world` (J, 4, 4) or (T, J, 4, 4)
        (rigid, metres, in the character's joint order). `volume` overrides the rig's volume rule.
        `device`: the Warp device ("cpu", "cuda:0") that evaluates all frames in one launch
        (rig/muscle/static_kernels.py), or None for the NumPy reference; the two agree to ~1e-15 m.
        Returns StaticShape(cvs (N, 3) or (T, N, 3), curve (M, 5, 3) or (T, M, 5, 3)), float64."""
        rule = self.volume if volume is None else _check_rule(volume)
        world = np.asarray(world, dtype=np.float64)
        single = world.ndim == 3
        if world.ndim not in (3, 4) or world.shape[-3:] != (self.num_joints, 4, 4):
            raise InputError(f"world transforms must be ({self.num_joints}, 4, 4) or (T, {self.num_joints}, 4, 4), "
                             f"got {world.shape}", field="world")
        if not np.isfinite(world).all():
            raise InputError("world transforms hold NaN or inf", field="world")
        if single:
            world = world[None]
        if device is not None:
            cvs, curve = _static_on_device(self, world, rule, device)
        else:
            parts = [self._static(world[t0:t0 + STATIC_CHUNK], rule) for t0 in range(0, len(world), STATIC_CHUNK)]
            if len(parts) == 1:
                cvs, curve = parts[0]
            else:
                cvs = np.concatenate([c for c, _ in parts]) if parts else np.zeros((0, self.M, 5, 8, 3))
                curve = np.concatenate([q for _, q in parts]) if parts else np.zeros((0, self.M, 5, 3))
        cvs = cvs.reshape(len(world), self.M * self.CVS_PER_MUSCLE, 3)
        if self.pose_shapes is not None:
            cvs = self.pose_shapes.apply(cvs, curve, world, self.cv_offsets)
        return StaticShape(cvs[0], curve[0]) if single else StaticShape(cvs, curve)

    def _static(self, world: np.ndarray, rule: str):
        """CVs (T, M, 5, 8, 3) and curve (T, M, 5, 3) for world transforms (T, J, 4, 4)."""
        pose = _pose(self, world)
        offsets = _section_offsets(self, pose)
        ratio = self.rest_length / pose.length                                  # (T, M)
        if rule == "none":
            s = np.ones_like(ratio)
        elif rule == "thesis":
            s = ratio
        else:
            s = np.sqrt(ratio)
            if rule == "exact":
                for _ in range(EXACT_ITERATIONS):
                    V = _loft_volume(pose, offsets, self._scale * s)
                    s = s * np.sqrt(np.clip(self.rest_volume / np.maximum(V, 1e-300), 0.25, 4.0))
        s = 1.0 + self.tone * (s - 1.0)
        return _section_cvs(pose, offsets, self._scale * s), np.ascontiguousarray(pose.curve.transpose(2, 3, 1, 0))

    # ------------------------------------------------------------------ geometry of CVs
    def _muscle_cvs(self, cvs: np.ndarray) -> np.ndarray:
        cvs = np.asarray(cvs, dtype=np.float64)
        if cvs.ndim not in (2, 3) or cvs.shape[-2:] != (self.M * self.CVS_PER_MUSCLE, 3):
            raise InputError(f"cvs must be ({self.M * self.CVS_PER_MUSCLE}, 3) or (T, "
                             f"{self.M * self.CVS_PER_MUSCLE}, 3), got {cvs.shape}", field="cvs")
        return cvs.reshape(cvs.shape[:-2] + (self.M, loft.SECTIONS, loft.RING, 3))

    def surface(self, cvs: np.ndarray) -> np.ndarray:
        """Lofted surface points (M, P, 3) (or (T, M, P, 3)) of flat CVs (N, 3) (or (T, N, 3));
        P = rig.muscle.loft.POINTS, triangles `surface_faces`."""
        return loft.points(self._muscle_cvs(cvs))

    def mean_radii(self, cvs: np.ndarray) -> np.ndarray:
        """(M,) metres: each muscle's mean distance of its CVs from their section's centre."""
        X = self._muscle_cvs(np.asarray(cvs, dtype=np.float64))
        return np.linalg.norm(X - X.mean(axis=-2, keepdims=True), axis=-1).mean(axis=(-2, -1))

    def volumes(self, cvs: np.ndarray) -> np.ndarray:
        """(M,) (or (T, M)) cubic metres enclosed by each muscle's lofted mesh."""
        return loft.volume(self._muscle_cvs(cvs))


# ---------------------------------------------------------------------------------- on a Warp device
# the rig's constant arrays per device, uploaded on first use; keyed weakly by the rig (a rig holding
# device arrays itself could no longer be pickled to a worker process)
_ON_DEVICE: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _device_model(rig: MuscleRig, device) -> dict:
    """The kernel's model arrays of `rig` on `device` (a wp.Device), uploaded once."""
    import warp as wp
    per_rig = _ON_DEVICE.setdefault(rig, {})
    if device.alias not in per_rig:
        f64 = lambda a: wp.array(np.ascontiguousarray(a, np.float64), dtype=wp.float64, device=device)  # noqa: E731
        per_rig[device.alias] = dict(   # in the kernel's parameter order
            joints=wp.array(np.ascontiguousarray(rig.joints, np.int32), dtype=wp.int32, device=device),
            local=wp.array(np.ascontiguousarray(rig.local), dtype=wp.vec4d, device=device),
            tendon=wp.array(np.ascontiguousarray(rig.tendon), dtype=wp.vec2d, device=device),
            along=wp.array(np.ascontiguousarray(rig.hinge_along), dtype=wp.vec2d, device=device),
            rest_chord=f64(rig.rest_chord), stations=f64(rig._stations),
            sections=wp.array(np.ascontiguousarray(rig.sections), dtype=wp.vec2d, device=device),
            section_scale=f64(rig.section_scale), tone=f64(rig.tone), rest_length=f64(rig.rest_length),
            rest_volume=f64(rig.rest_volume), curve_from_z=f64(_CURVE_FROM_Z), arc_from_z=f64(_ARC_FROM_Z),
            arc_w=f64(_ARC_W), row_weights=f64(loft.ROW_WEIGHTS), col_weights=f64(loft.COL_WEIGHTS))
    return per_rig[device.alias]


def _static_on_device(rig: MuscleRig, world: np.ndarray, rule: str, device) -> tuple[np.ndarray, np.ndarray]:
    """CVs (T, N, 3) and curve (T, M, 5, 3) float64 for checked world transforms (T, J, 4, 4), all
    frames and muscles in one launch of rig.muscle.static_kernels.static_shape on the Warp `device`."""
    import warp as wp

    from jiggle.rig.muscle import static_kernels as kernels
    T, M = len(world), rig.M
    if T == 0 or M == 0:
        return np.zeros((T, M * rig.CVS_PER_MUSCLE, 3)), np.zeros((T, M, 5, 3))
    device = wp.get_device(device)
    model = _device_model(rig, device)
    w = wp.array(np.ascontiguousarray(world), dtype=wp.mat44d, device=device)     # (T, J)
    cvs = wp.empty((T, M * rig.CVS_PER_MUSCLE), dtype=wp.vec3d, device=device)
    curve = wp.empty((T, M * 5), dtype=wp.vec3d, device=device)
    code = {"none": kernels.RULE_NONE, "thesis": kernels.RULE_THESIS, "sqrt": kernels.RULE_SQRT,
            "exact": kernels.RULE_EXACT}[rule]
    wp.launch(kernels.static_shape, dim=(T, M), device=device,
              inputs=[*model.values(), MIN_BELLY, code, EXACT_ITERATIONS, w], outputs=[cvs, curve])
    # on the CPU .numpy() is a view of the fresh output buffers (kept alive by the views)
    return cvs.numpy().reshape(T, -1, 3), curve.numpy().reshape(T, M, 5, 3)


def _check_rule(volume: str) -> str:
    if volume not in VOLUME_RULES:
        raise InputError(f"unknown volume rule {volume!r}; expected one of {', '.join(VOLUME_RULES)}",
                         field="volume")
    return volume


# The curve CVs are a fixed linear map of Z = (e_o, e_i, c t_o, c t_i, middle offset):
# Q0 = e_o, Q1 = e_o + 0.125 c t_o, Q2 = (e_o + e_i) / 2 + offset, Q3 = e_i - 0.125 c t_i, Q4 = e_i.
_CURVE_FROM_Z = np.array([[1.0, 0.0, 0.0, 0.0, 0.0],
                          [1.0, 0.0, CURVE_TANGENT_FRACTION, 0.0, 0.0],
                          [0.5, 0.5, 0.0, 0.0, 1.0],
                          [0.0, 1.0, 0.0, -CURVE_TANGENT_FRACTION, 0.0],
                          [0.0, 1.0, 0.0, 0.0, 0.0]])
_ARC_FROM_Z = _ARC_SLOPE @ _CURVE_FROM_Z                                          # (16, 5)


class _Pose(NamedTuple):
    """One chunk of frames, components first and muscles last."""

    curve: np.ndarray    # (3, 5, T, M) action-curve CVs
    centre: np.ndarray   # (3, 5, T, M) section centres
    U: np.ndarray        # (3, 5, T, M) unit up of each section
    S: np.ndarray        # (3, 5, T, M) unit side of each section
    length: np.ndarray   # (T, M) arc length Lc


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return (a * b).sum(axis=0)


def _norm(a: np.ndarray) -> np.ndarray:
    return np.sqrt((a * a).sum(axis=0))


def _pose(rig, world: np.ndarray) -> _Pose:
    """Action curve and section frames for world transforms (T, J, 4, 4)."""
    T, M = len(world), len(rig.joints)
    X = world[:, rig.joints, :3]                                                 # (T, M, 11, 3, 4)
    q = np.einsum("tmnij,mnj->intm", X, rig.local)                               # (3, 11, T, M)
    attach, hinge = q[:, 0:2], q[:, 2:4]                                         # origin/insertion, hinges
    u = hinge[:, 1] - hinge[:, 0]
    u /= _norm(u)
    # tendons keep their rest length: what the origin (insertion) side gains, the belly gives
    length = rig._tendon - _norm(attach - hinge)                                 # (2, T, M)
    perp = q[:, 4:6] - _dot(q[:, 4:6], u[:, None]) * u[:, None]
    d = rig._along * u[:, None] + perp
    d /= np.maximum(_norm(d), 1e-12)
    ends = hinge + length * d                                                    # (3, 2, T, M) e_o, e_i
    # a muscle cannot collapse: keep the belly's extent along u above MIN_BELLY x its rest chord
    short = np.maximum(MIN_BELLY * rig.rest_chord - _dot(ends[:, 1] - ends[:, 0], u), 0.0)
    ends[:, 0] -= 0.5 * short * u
    ends[:, 1] += 0.5 * short * u
    chord = _norm(ends[:, 1] - ends[:, 0])
    Z = np.concatenate([ends, chord * q[:, 6:8], q[:, 8:9]], axis=1).reshape(3, 5, T * M)
    curve = (_CURVE_FROM_Z @ Z).reshape(3, 5, T, M)
    length = (_ARC_W @ _norm(_ARC_FROM_Z @ Z)).reshape(T, M)
    st = np.einsum("mkc,xctm->xktm", rig._stations, Z.reshape(3, 5, T, M))       # (3, 10, T, M)
    centre, tangent = st[:, :5], st[:, 5:]
    tangent = tangent / _norm(tangent)
    up, side = q[:, 9:10], q[:, 10:11]
    U = up - _dot(up, tangent) * tangent
    n = _norm(U)
    if np.any(n < 1e-3):   # up within ~0.06 deg of the tangent: use the side vector there
        W = side - _dot(side, tangent) * tangent
        U = np.where(n < 1e-3, W / _norm(W), U / np.maximum(n, 1e-300))
    else:
        U /= n
    t0, t1, t2 = tangent
    u0, u1, u2 = U
    S = np.stack([t1 * u2 - t2 * u1, t2 * u0 - t0 * u2, t0 * u1 - t1 * u0])
    return _Pose(curve, centre, U, S, length)


def _section_offsets(rig, pose: _Pose) -> np.ndarray:
    """(5, 8, 3, T, M) offsets a U + b S of every section CV from its centre, attributes 1."""
    U, S = pose.U.transpose(1, 0, 2, 3)[:, None], pose.S.transpose(1, 0, 2, 3)[:, None]   # (5, 1, 3, T, M)
    a, b = rig._cv_ab                                                            # (5, 8, 1, 1, M)
    off = U * a
    off += S * b
    return off


def _loft_volume(pose: _Pose, offsets: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """(T, M) volume of the loft of the CVs centre + scale offsets, scale (5, T, M) per section,
    measured about the middle section (rig.muscle.loft.volume's mesh)."""
    x = offsets * scale[:, None, None]
    x += (pose.centre - pose.centre[:, 2:3]).transpose(1, 0, 2, 3)[:, None]       # (5, 8, 3, T, M)
    return loft.grid_volume(loft.grid_of(x))


def _section_cvs(pose: _Pose, offsets: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """(T, M, 5, 8, 3) section CVs centre + scale offsets, scale (5, T, M) per section."""
    x = offsets * scale[:, None, None]
    x += pose.centre.transpose(1, 0, 2, 3)[:, None]
    return x.transpose(3, 4, 0, 1, 2)


# ---------------------------------------------------------------------------------- build
def build_muscle_rig(specs, bind_world: np.ndarray, volume: str = "exact") -> MuscleRig:
    """Build the thesis muscles of `specs` (sequence of MuscleSpec) on a skeleton whose joints have
    rigid bind transforms `bind_world` (J, 4, 4) metres. `volume`: one of VOLUME_RULES.

    Fits every muscle's sections to its spec's surface (see the module docstring) and records the
    fit errors; raises InputError for bad joints, transforms or rule."""
    _check_rule(volume)
    specs = list(specs)
    bind_world = np.asarray(bind_world, dtype=np.float64)
    if bind_world.ndim != 3 or bind_world.shape[1:] != (4, 4):
        raise InputError(f"bind_world must be (J, 4, 4), got {bind_world.shape}", field="bind_world")
    if not np.isfinite(bind_world).all():
        raise InputError("bind_world holds NaN or inf", field="bind_world")
    J, M = len(bind_world), len(specs)
    for s in specs:
        if not isinstance(s, MuscleSpec):
            raise InputError(f"expected MuscleSpec, got {type(s).__name__}", field="specs")
        bad = [int(b) for b in (s.bone, *s.bones) if not 0 <= b < J]
        if bad:
            raise InputError(f"muscle {s.name!r}: joint index {bad[0]} is outside 0..{J - 1}", field="bones")

    inv = np.linalg.inv(bind_world)
    joints = np.zeros((M, _SLOTS), np.int64)
    local = np.zeros((M, _SLOTS, 4))
    tendon, along, chord = np.zeros((M, 2)), np.zeros((M, 2)), np.zeros(M)
    for m, s in enumerate(specs):
        o, oh, ih, ins = s.points
        t_rest = (s.ends[1] - s.ends[0]) / np.linalg.norm(s.ends[1] - s.ends[0])
        u_rest = (ih - oh) / np.linalg.norm(ih - oh)
        up = s.up - (s.up @ t_rest) * t_rest
        up /= np.linalg.norm(up)
        side = np.cross(t_rest, up)
        tendon[m] = (np.linalg.norm(o - oh) + np.linalg.norm(oh - s.ends[0]),
                     np.linalg.norm(ins - ih) + np.linalg.norm(ih - s.ends[1]))
        chord[m] = np.linalg.norm(s.ends[1] - s.ends[0])
        perps = []
        for k, (hinge, end, default) in enumerate(((oh, s.ends[0], 1.0), (ih, s.ends[1], -1.0))):
            d = end - hinge
            n = np.linalg.norm(d)
            if n < 1e-9 * chord[m]:     # hinge at the belly end: the end slides along the hinge axis
                along[m, k], perp = default, np.zeros(3)
            else:
                along[m, k] = (d / n) @ u_rest
                perp = d / n - along[m, k] * u_rest
            perps.append(perp)
        a, (b_o, b_oh, b_ih, b_i) = s.bone, s.bones
        slots = {_ORIGIN: (b_o, o, 1), _INSERTION: (b_i, ins, 1), _O_HINGE: (b_oh, oh, 1),
                 _I_HINGE: (b_ih, ih, 1), _Q_O: (b_oh, perps[0], 0), _Q_I: (b_ih, perps[1], 0),
                 _T_O: (b_oh, t_rest, 0), _T_I: (b_ih, t_rest, 0), _MIDDLE: (a, None, 0),
                 _UP: (a, up, 0), _SIDE: (a, side, 0)}
        for k, (j, x, w) in slots.items():
            joints[m, k] = j
            if x is None:   # the middle offset is given in joint a's local frame already
                local[m, k, :3] = s.middle_offset
            else:
                local[m, k] = inv[j] @ np.append(x, w)

    bulge = np.array([s.bulge_position for s in specs], dtype=np.float64).reshape(M)
    stations = station_parameters(bulge)                                           # (M, 5)
    station_basis = curve_basis(stations.ravel()).reshape(M, 5, 5)
    station_slope = curve_basis(stations.ravel(), 1).reshape(M, 5, 5)
    section_scale = np.array([[s.rim_scale, s.bulge_scale, s.main_scale, s.bulge_scale, s.rim_scale]
                              for s in specs], dtype=np.float64).reshape(M, 5)
    tone = np.array([s.tone for s in specs], dtype=np.float64).reshape(M)
    fields = dict(
        names=tuple(s.name for s in specs), kinds=tuple(s.kind for s in specs),
        groups=tuple(s.group for s in specs), volume=volume, num_joints=J,
        cv_offsets=frozen_array(np.arange(M + 1) * MuscleRig.CVS_PER_MUSCLE, np.int64),
        section_scale=frozen_array(section_scale), tone=frozen_array(tone), bulge_position=frozen_array(bulge),
        joints=frozen_array(joints, np.int64), local=frozen_array(local), tendon=frozen_array(tendon),
        hinge_along=frozen_array(along), rest_chord=frozen_array(chord),
        station_basis=frozen_array(station_basis), station_slope=frozen_array(station_slope))
    empty = np.zeros(M)
    # the skeleton half of the rig gives the rest curve and section frames the fit needs
    sk = MuscleRig(**fields, rest_cvs=np.zeros((40 * M, 3)), rest_curve=np.zeros((M, 5, 3)), rest_volume=empty,
                   rest_length=empty, fit_rms=empty, fit_max=empty, sections=np.zeros((M, 5, 8, 2)))
    pose = _pose(sk, bind_world[None])
    centre, U, S = (np.moveaxis(x[:, :, 0], (0, 1), (2, 1)) for x in (pose.centre, pose.U, pose.S))  # (M, 5, 3)

    sections = np.zeros((M, 5, 8, 2))
    fit_rms, fit_max = np.zeros(M), np.zeros(M)
    for m, s in enumerate(specs):   # build time: one least-squares fit per muscle
        sections[m], fit_rms[m], fit_max[m] = fit_sections(s.surface, centre[m], U[m], S[m])
    fitted = MuscleRig(**fields, rest_cvs=np.zeros((40 * M, 3)), rest_curve=np.zeros((M, 5, 3)),
                       rest_volume=empty, rest_length=empty, fit_rms=empty, fit_max=empty, sections=sections)
    # the same computation as static(bind_world, device=None), so that it reproduces these bit for bit
    offsets = _section_offsets(fitted, pose)
    scale = fitted._scale * np.ones((1, M))
    rest_volume = _loft_volume(pose, offsets, scale)[0]
    rest_cvs = _section_cvs(pose, offsets, scale)[0].reshape(-1, 3)
    if np.any(rest_volume <= 0):
        m = int(np.argmin(rest_volume))
        raise InputError(f"muscle {specs[m].name!r}: the fitted loft encloses no volume "
                         f"({rest_volume[m]:.3g} m^3); check its surface and up vector", field="surface")
    return MuscleRig(**fields, rest_cvs=frozen_array(rest_cvs),
                     rest_curve=frozen_array(pose.curve[:, :, 0].transpose(2, 1, 0)),
                     rest_volume=frozen_array(rest_volume), rest_length=frozen_array(pose.length[0]),
                     fit_rms=frozen_array(fit_rms), fit_max=frozen_array(fit_max), sections=frozen_array(sections))


# ---------------------------------------------------------------------------------- fit
def _surface_at(X: np.ndarray, w: np.ndarray, v: np.ndarray):
    """Loft of 3D section CVs X (5, 8, 3) at parameters (w, v) (n,): points and their partial
    derivatives d/dw, d/dv, (n, 3) each."""
    ring = np.einsum("nj,kjx->nkx", loft.ring_weights(v), X)
    ring_v = np.einsum("nj,kjx->nkx", loft.ring_weights(v, 1), X)
    n0 = loft.section_weights(w)
    return (np.einsum("nk,nkx->nx", n0, ring), np.einsum("nk,nkx->nx", loft.section_weights(w, 1), ring),
            np.einsum("nk,nkx->nx", n0, ring_v))


@lru_cache(maxsize=1)
def _dense_grid():
    """Parameters (n,) w, v and weights (n, 40) of a dense sampling of the loft (33 x 64), where
    Gauss-Newton starts."""
    w, v = np.meshgrid(np.linspace(0.0, loft.SECTIONS - 1, 33), np.arange(8 * loft.RING) / 8.0, indexing="ij")
    w, v = w.ravel(), v.ravel()
    return w, v, loft.surface_weights(w, v).reshape(len(w), -1)


def _project(p: np.ndarray, X: np.ndarray, steps: int = 6):
    """Foot points of p (n, 3) on the smooth loft of X (5, 8, 3): parameters (w, v) and distance (n,).
    Nearest sample of a dense grid, then Gauss-Newton on |X(w, v) - p|^2 (kept when it improves)."""
    wd, vd, weights = _dense_grid()
    dist0, idx = cKDTree(weights @ X.reshape(-1, 3)).query(p)
    w, v = wd[idx], vd[idx]
    for _ in range(steps):
        x, xw, xv = _surface_at(X, w, v)
        r = p - x
        a, b, c = (xw * xw).sum(1), (xw * xv).sum(1), (xv * xv).sum(1)
        gw, gv = (xw * r).sum(1), (xv * r).sum(1)
        damp = 1e-9 * (a + c) + 1e-30
        det = (a + damp) * (c + damp) - b * b
        dw_ = np.clip(((c + damp) * gw - b * gv) / det, -0.5, 0.5)
        dv_ = np.clip(((a + damp) * gv - b * gw) / det, -1.0, 1.0)
        w, v = np.clip(w + dw_, 0.0, loft.SECTIONS - 1), np.mod(v + dv_, loft.RING)
    dist = np.linalg.norm(p - _surface_at(X, w, v)[0], axis=1)
    worse = dist > dist0
    return np.where(worse, wd[idx], w), np.where(worse, vd[idx], v), np.where(worse, dist0, dist)


def _ring_regulariser() -> np.ndarray:
    """(80, 80) rows CV[j-1] + CV[j+1] - 2 cos(45 deg) CV[j] for every section and component,
    unknowns ordered (section, CV, component) as MuscleRig.sections."""
    R = np.zeros((loft.RING, loft.RING))
    for j in range(loft.RING):
        R[j, (j - 1) % loft.RING] += 1.0
        R[j, (j + 1) % loft.RING] += 1.0
        R[j, j] -= 2.0 * np.cos(2.0 * np.pi / loft.RING)
    return np.kron(np.eye(loft.SECTIONS), np.kron(R, np.eye(2)))


def fit_sections(surface: np.ndarray, centres: np.ndarray, U: np.ndarray, S: np.ndarray
                 ) -> tuple[np.ndarray, float, float]:
    """Fit the section offsets of one muscle to surface points (n, 3), given its rest section
    centres, up and side vectors (5, 3) each. Returns (a, b) (5, 8, 2) metres, rms and max distance
    (metres) of the points to the fitted loft. See the module docstring."""
    p = np.asarray(surface, dtype=np.float64)
    n = len(p)
    e_o, axis = centres[0], centres[-1] - centres[0]
    c = np.linalg.norm(axis)
    t = axis / c
    # first parameters: w from the point's place along the rest chord (through the loft's centre
    # line, which is monotone along it), v from its angle about the nearby section frame
    wd = np.linspace(0.0, loft.SECTIONS - 1, 401)
    f = np.maximum.accumulate((loft.section_weights(wd) @ centres - e_o) @ t / c)
    w = np.interp(np.clip((p - e_o) @ t / c, 0.0, 1.0), f, wd)
    N = loft.section_weights(w)
    d = p - N @ centres
    v = np.mod(np.arctan2(np.einsum("ni,ni->n", d, N @ S), np.einsum("ni,ni->n", d, N @ U))
               * loft.RING / (2.0 * np.pi), loft.RING)
    reg = np.vstack([np.sqrt(FIT_SMOOTHING * n) * _ring_regulariser(), np.sqrt(FIT_RIDGE * n) * np.eye(80)])
    for _ in range(FIT_ITERATIONS):
        W = loft.surface_weights(w, v)                                              # (n, 5, 8)
        A = np.stack([W[:, None] * U.T[None, :, :, None], W[:, None] * S.T[None, :, :, None]], axis=-1)
        rhs = (p - W.sum(axis=2) @ centres).ravel()
        # normal equations of the regularised least squares: an 80 x 80 solve, well conditioned by the
        # ridge term, and ~10x cheaper than lstsq's SVD (which also suffers from BLAS threads
        # competing on a busy 2-core machine)
        M = A.reshape(3 * n, 80)
        sol = np.linalg.solve(M.T @ M + reg.T @ reg, M.T @ rhs)
        ab = sol.reshape(loft.SECTIONS, loft.RING, 2)
        X = centres[:, None] + ab[..., 0, None] * U[:, None] + ab[..., 1, None] * S[:, None]
        w, v, dist = _project(p, X)
    dist = np.minimum(dist, _cap_distance(p, X, U, S))
    return ab, float(np.sqrt(np.mean(dist ** 2))), float(dist.max())


def _cap_distance(p: np.ndarray, X: np.ndarray, U: np.ndarray, S: np.ndarray) -> np.ndarray:
    """(n,) distance of p (n, 3) to the two end caps of the loft of X (5, 8, 3) (inf where a point's
    foot on a cap's plane falls outside the cap). An end ring lies in its section's (U, S) plane; its
    cap is the fan from its centroid, taken as star-shaped about it."""
    out = np.full(len(p), np.inf)
    vd = np.arange(32 * loft.RING) / 32.0
    for k, w in ((0, 0.0), (loft.SECTIONS - 1, loft.SECTIONS - 1.0)):
        ring = _surface_at(X, np.full(len(vd), w), vd)[0]
        centre = ring.mean(axis=0)
        rel, d = ring - centre, p - centre
        phi_r = np.arctan2(rel @ S[k], rel @ U[k])
        order = np.argsort(phi_r)
        radius = np.interp(np.arctan2(d @ S[k], d @ U[k]), phi_r[order], np.hypot(rel @ U[k], rel @ S[k])[order],
                           period=2.0 * np.pi)
        inside = np.hypot(d @ U[k], d @ S[k]) <= radius
        out = np.where(inside, np.minimum(out, np.abs(d @ np.cross(U[k], S[k]))), out)
    return out
