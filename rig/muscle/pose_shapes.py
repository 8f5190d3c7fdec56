"""Pose-based muscle shapes (Pratscher et al. 2005, section 4.1, "Pose-Based Deformation").

When an artist sculpted the character in several poses, the template is fitted to each sculpted pose
and the muscles' shapes are interpolated over the joint angles of the poses, instead of (or before)
the procedural volume-preserving rule:

    for each sculpted pose k: fit the musculature to the pose's skin and skeleton, and keep every
        muscle's section CVs in the frame of its bone a:  local_k = inverse(W_k[a]) @ cvs_k
    at run time, for joint angles q: local(q) = interpolate(q_k -> local_k), then cvs = W(t)[a] @ local(q)

With one parameter (a single-DOF joint such as an elbow), shapes are interpolated linearly between the
neighbouring sculpted poses (clamped beyond the first and last), as the paper does. With several
parameters, scipy's RBFInterpolator (thin-plate spline with a linear polynomial part) interpolates
exactly through the sculpted poses. Keeping the CVs in the bone's frame makes the result follow the
skeleton; only the change of shape is interpolated.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np

from jiggle.rig.base.errors import InputError
from jiggle.rig.base.frozen import frozen_array


@dataclass(frozen=True, eq=False)
class SculptedPose:
    """One sculpted pose of the character's mesh.

    vertices : (V, 3) metres, the character's skin (same topology) as sculpted in this pose.
    world : (J, 4, 4) rigid bone world transforms of the pose, in the character's joint order.
    angles : (D,) the pose's interpolation parameters (e.g. an elbow angle in degrees).
    """

    vertices: np.ndarray
    world: np.ndarray
    angles: np.ndarray

    def __post_init__(self):
        object.__setattr__(self, "vertices", frozen_array(self.vertices))
        object.__setattr__(self, "world", frozen_array(self.world))
        object.__setattr__(self, "angles", frozen_array(np.atleast_1d(np.asarray(self.angles, float))))


@dataclass(frozen=True, eq=False)
class PoseShapes:
    """Muscle shapes of the sculpted poses, ready to interpolate.

    names : muscle names (those fitted in every pose).
    bones : (M,) int joint index a of each muscle.
    angles : (K, D) the poses' parameters.
    local : (K, M, C, 3) each pose's section CVs in its muscles' bone frames, metres.
    """

    names: tuple[str, ...]
    bones: np.ndarray
    angles: np.ndarray
    local: np.ndarray

    def __post_init__(self):
        object.__setattr__(self, "bones", frozen_array(self.bones, np.int64))  # indexes `world` in cvs()
        for k in ("angles", "local"):
            object.__setattr__(self, k, frozen_array(getattr(self, k)))

    @cached_property
    def _rbf(self):
        """The interpolant over several parameters, solved once (not per evaluated frame)."""
        from scipy.interpolate import RBFInterpolator
        return RBFInterpolator(self.angles, self.local.reshape(len(self.angles), -1), kernel="thin_plate_spline",
                               degree=1)

    def local_cvs(self, angles) -> np.ndarray:
        """(M, C, 3) CVs in the bones' frames for parameters `angles` (D,)."""
        q = np.atleast_1d(np.asarray(angles, float))
        K, D = self.angles.shape
        if q.shape != (D,) or not np.all(np.isfinite(q)):
            raise InputError(f"expected {D} finite pose parameter(s), got {q.tolist()}", field="angles")
        flat = self.local.reshape(K, -1)
        if D == 1:
            order = np.argsort(self.angles[:, 0])
            x, y = self.angles[order, 0], flat[order]
            i = int(np.clip(np.searchsorted(x, q[0]), 1, K - 1))
            w = float(np.clip((q[0] - x[i - 1]) / (x[i] - x[i - 1]), 0.0, 1.0))
            out = (1.0 - w) * y[i - 1] + w * y[i]
        else:
            out = self._rbf(q[None])[0]
        return out.reshape(self.local.shape[1:])

    def cvs(self, world: np.ndarray, angles) -> np.ndarray:
        """(M, C, 3) world CVs: the interpolated shape carried by the bones' transforms `world` (J, 4, 4)."""
        local = self.local_cvs(angles)
        W = np.asarray(world, float)[self.bones]
        return np.einsum("mij,mcj->mci", W[:, :3, :3], local) + W[:, None, :3, 3]


def fit_pose_shapes(character, poses: list[SculptedPose], template="human", options=None,
                    roles: dict | None = None, front: np.ndarray | None = None) -> PoseShapes:
    """Fit `template` to every sculpted pose of `character` (rig.muscle.fit) and collect the muscles'
    section CVs in their bones' frames. Muscles missing from some pose are left out."""
    from jiggle.rig.character.character import bind_clip
    from jiggle.rig.character.normals import vertex_normals
    from jiggle.rig.muscle.fit import FitOptions, fit_musculature
    if len(poses) < 2:
        raise InputError(f"pose-based shapes need at least two sculpted poses, got {len(poses)}", field="poses")
    D = len(poses[0].angles)
    if any(len(p.angles) != D for p in poses):
        raise InputError("every sculpted pose needs the same number of parameters", field="poses")
    if len({tuple(p.angles) for p in poses}) != len(poses):
        raise InputError("two sculpted poses have the same parameters", field="poses")
    fits = []
    for k, p in enumerate(poses):
        if p.vertices.shape != character.vertices.shape or p.world.shape != character.bind_world.shape:
            raise InputError(f"sculpted pose {k} does not match the character: vertices {p.vertices.shape} and "
                             f"bones {p.world.shape}, expected {character.vertices.shape} and "
                             f"{character.bind_world.shape}", field=f"poses[{k}]")
        skel = bind_clip(character.joint_names, character.parents, p.world, name=character.name)
        posed = replace(character, vertices=p.vertices, normals=vertex_normals(p.vertices, character.faces),
                        bind_world=p.world, bind_matrices=p.world, skeleton=skel)
        fits.append(fit_musculature(posed, template, options or FitOptions(), roles=roles, front=front))
    names = [n for n in fits[0].names if all(n in f.names for f in fits[1:])]
    if not names:
        raise InputError("no muscle was fitted in every sculpted pose", field="poses")
    bones = np.array([fits[0].muscle(n).bone for n in names])
    local = []
    for p, f in zip(poses, fits):
        rig = f.rig
        idx = [f.names.index(n) for n in names]
        cvs = np.stack([rig.rest_cvs[rig.cv_offsets[i]:rig.cv_offsets[i + 1]] for i in idx])
        W = p.world[bones]
        inv_r = np.transpose(W[:, :3, :3], (0, 2, 1))
        local.append(np.einsum("mij,mcj->mci", inv_r, cvs - W[:, None, :3, 3]))
    return PoseShapes(names=tuple(names), bones=bones, angles=np.stack([p.angles for p in poses]),
                      local=np.stack(local))


# ---------------------------------------------------------------------------------- scaled sections
SECTIONS = 5
MAX_SCALE = 10.0
"""Largest section scale a pose shape may key (and 1 / MAX_SCALE the smallest)."""


@dataclass(frozen=True)
class SectionShape:
    """One muscle's sections scaled by keys on one joint's bend, as an artist shapes a muscle by pose
    ("the biceps bulges 25% at 90 degrees of elbow flexion") without sculpting a mesh.

    muscle : the muscle's name. joint : the joint whose bend drives it (a name of the character's joints).
    angles : (K,) degrees of that joint's rotation away from its rest pose, increasing, K >= 1.
    scales : (K, 5) factors on the size of each section (origin rim, bulge, middle, bulge, insertion rim)
    about its centre on the action curve at each key; linear between keys, held beyond the first and last.
    path, line : where the shape was given (a scene file and the line of its table), for errors.
    """

    muscle: str
    joint: str
    angles: tuple
    scales: tuple
    path: str | None = None
    line: int | None = None


@dataclass(frozen=True, eq=False)
class SectionShapes:
    """Section shapes bound to a rig and a skeleton, applied by MuscleRig.static after the volume rule
    (a pose shape is the artist's word: it changes the volume on purpose).

    muscles : (P,) int64 each shape's muscle (an index of the rig). joints, parents : (P,) int64 the
    driving joint and its parent (-1: the root, whose rotation is measured in the world).
    rest : (P, 3, 3) the driving joint's rest rotation relative to its parent.
    angles : (P, K) degrees, keys padded by repeating the last; scales : (P, K, 5).
    station_basis : (P, 5, 5) the muscle's action-curve weights at its sections (section centres).
    """

    shapes: tuple
    muscles: np.ndarray
    joints: np.ndarray
    parents: np.ndarray
    rest: np.ndarray
    angles: np.ndarray
    scales: np.ndarray
    station_basis: np.ndarray

    def __post_init__(self):
        for k in ("muscles", "joints", "parents"):
            object.__setattr__(self, k, frozen_array(getattr(self, k), np.int64))
        for k in ("rest", "angles", "scales", "station_basis"):
            object.__setattr__(self, k, frozen_array(getattr(self, k)))

    def bend(self, world: np.ndarray) -> np.ndarray:
        """(T, P) degrees: each shape's joint rotated away from its rest pose, for rigid joint world
        transforms (T, J, 4, 4)."""
        R = np.asarray(world, float)[:, :, :3, :3]
        Rj = R[:, self.joints]                                                   # (T, P, 3, 3)
        Rp = np.where((self.parents >= 0)[None, :, None, None], R[:, np.maximum(self.parents, 0)], np.eye(3))
        local = np.einsum("tpji,tpjk->tpik", Rp, Rj)                            # parent^T joint
        delta = np.einsum("pji,tpjk->tpik", self.rest, local)                   # rest^T local
        cos = (np.trace(delta, axis1=2, axis2=3) - 1.0) / 2.0
        return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))

    def factors(self, world: np.ndarray) -> np.ndarray:
        """(T, P, 5) section scales at the joints' bends (linear between keys, held beyond them)."""
        a = self.bend(world)                                                     # (T, P)
        out = np.empty(a.shape + (SECTIONS,))
        for p in range(len(self.muscles)):                  # a few shapes per rig; every frame at once
            for s in range(SECTIONS):
                out[:, p, s] = np.interp(a[:, p], self.angles[p], self.scales[p, :, s])
        return out

    def apply(self, cvs: np.ndarray, curve: np.ndarray, world: np.ndarray, cv_offsets: np.ndarray) -> np.ndarray:
        """cvs (T, N, 3) with each shaped muscle's sections scaled about their centres (a copy).
        curve : (T, M, 5, 3) the action-curve CVs of the same frames; world : (T, J, 4, 4)."""
        f = self.factors(world)
        out = np.array(cvs, dtype=np.float64)
        T = len(out)
        for p, m in enumerate(self.muscles):
            a, b = cv_offsets[m], cv_offsets[m + 1]
            centre = np.einsum("kj,tjx->tkx", self.station_basis[p], curve[:, m])      # (T, 5, 3)
            x = out[:, a:b].reshape(T, SECTIONS, -1, 3)
            out[:, a:b] = (centre[:, :, None] + f[:, p, :, None, None] * (x - centre[:, :, None])).reshape(T, -1, 3)
        return out


def bind_section_shapes(shapes, rig, joint_names, parents, bind_world) -> SectionShapes | None:
    """SectionShapes of `shapes` (SectionShape, ...) on `rig` (rig.muscle.model.MuscleRig) and the
    character's skeleton (joint_names (J,), parents (J,), rigid bind_world (J, 4, 4)); None when there
    are none. A shape's muscle may be a glob ("biceps_*", "*_fat"): one shape per muscle it matches.
    InputError naming the shape's file and line for an unknown muscle or joint, an empty glob, keys out of order
    or scales outside [1 / MAX_SCALE, MAX_SCALE]."""
    from fnmatch import fnmatchcase
    if not shapes:
        return None
    names = list(rig.names)
    joints = list(joint_names)
    bound, rows = [], []
    for sh in shapes:
        at = (sh.path, sh.line)
        hits = [i for i, n in enumerate(names) if fnmatchcase(n, sh.muscle)]
        if not hits:
            close = _close(sh.muscle, names)
            raise InputError(f"pose shape for {sh.muscle!r}: no such muscle{close}", *at, field="pose_shapes.muscle")
        if sh.joint not in joints:
            raise InputError(f"pose shape for {sh.muscle!r}: no joint {sh.joint!r} in the character"
                             f"{_close(sh.joint, joints)}", *at, field="pose_shapes.joint")
        ang = np.asarray(sh.angles, float).reshape(-1)
        sc = np.asarray(sh.scales, float)
        if len(ang) < 1 or not np.isfinite(ang).all() or np.any(np.diff(ang) <= 0) or ang.min() < 0 or ang.max() > 180:
            raise InputError(f"pose shape for {sh.muscle!r}: angles must increase within [0, 180] degrees, "
                             f"got {ang.tolist()}", *at, field="pose_shapes.angles")
        if sc.ndim == 1 and len(sc) == len(ang):
            sc = np.repeat(sc[:, None], SECTIONS, axis=1)            # one factor for all five sections
        if sc.shape != (len(ang), SECTIONS):
            raise InputError(f"pose shape for {sh.muscle!r}: scales must give one number or {SECTIONS} numbers "
                             f"per angle ({len(ang)} angles), got shape {sc.shape}", *at, field="pose_shapes.scales")
        if not (np.isfinite(sc).all() and sc.min() >= 1.0 / MAX_SCALE and sc.max() <= MAX_SCALE):
            raise InputError(f"pose shape for {sh.muscle!r}: scales must be in [{1 / MAX_SCALE:g}, {MAX_SCALE:g}]"
                             f", got {sc.tolist()}", *at, field="pose_shapes.scales")
        j = joints.index(sh.joint)
        for m in hits:
            bound.append(replace(sh, muscle=names[m]))
            rows.append((m, j, int(parents[j]), ang, sc))
    K = max(len(r[3]) for r in rows)
    pad = lambda a: np.concatenate([a, np.repeat(a[-1:], K - len(a), axis=0)])  # noqa: E731
    W = np.asarray(bind_world, float)[:, :3, :3]
    rest = np.stack([W[p].T @ W[j] if p >= 0 else W[j] for _, j, p, _, _ in rows])
    return SectionShapes(tuple(bound), np.array([r[0] for r in rows]), np.array([r[1] for r in rows]),
                         np.array([r[2] for r in rows]), rest, np.stack([pad(r[3]) for r in rows]),
                         np.stack([pad(r[4]) for r in rows]), np.stack([rig.station_basis[r[0]] for r in rows]))


def _close(name: str, names: list[str]) -> str:
    import difflib
    near = difflib.get_close_matches(name, names, n=3)
    return f" (did you mean {', '.join(map(repr, near))}?)" if near else f" ({len(names)} known, e.g. " + \
        ", ".join(map(repr, names[:4])) + ")"
