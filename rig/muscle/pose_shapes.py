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

from rig.base.errors import InputError
from rig.base.frozen import frozen_array


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
    from rig.character.character import bind_clip
    from rig.character.normals import vertex_normals
    from rig.muscle.fit import FitOptions, fit_musculature
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
