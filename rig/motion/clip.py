"""The one motion type: a joint tree with per-frame local transforms.

Every mocap reader (BVH, ASF/AMC, glTF) returns a :class:`Clip`. Its arrays are read-only: a clip is
loaded once and never changed while it plays; resampling and trimming return new clips.

Frames of reference: world is Z-up, metres. A joint's local transform maps its own frame into its
parent's: ``x_parent = translations[t, j] + rotate(rotations[t, j], x_joint)``. At rest (the pose the
file's hierarchy describes) the local translation is ``offsets[j]`` and the rotation
``rest_rotations[j]`` (identity for BVH and Acclaim, the node's own rotation for glTF).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from jiggle.rig.base.errors import InputError
from jiggle.rig.base.frozen import frozen_array
from jiggle.rig.motion import quat

TRANSLATION_NOISE = 1e-6  # metres: translation changes below this are exporter noise, not motion


def local_from_world(parents: np.ndarray, world_rot: np.ndarray, world_pos: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Local rotations (..., J, 4) w,x,y,z and translations (..., J, 3) of a joint tree from its world
    rotations (..., J, 4) and positions (..., J, 3) (any leading axes, e.g. frames); roots keep their world
    transform. Parents first."""
    world_rot = np.asarray(world_rot, dtype=np.float64)
    world_pos = np.asarray(world_pos, dtype=np.float64)
    rot = np.empty_like(world_rot)
    tra = np.empty_like(world_pos)
    for j, p in enumerate(parents):
        if p < 0:
            rot[..., j, :], tra[..., j, :] = world_rot[..., j, :], world_pos[..., j, :]
        else:
            inv = quat.conj(world_rot[..., p, :])
            rot[..., j, :] = quat.mul(inv, world_rot[..., j, :])
            tra[..., j, :] = quat.rotate(inv, world_pos[..., j, :] - world_pos[..., p, :])
    return quat.canonical(rot), tra


def transforms(rot: np.ndarray, pos: np.ndarray) -> np.ndarray:
    """(..., 4, 4) homogeneous matrices from world rotations (..., 4) and positions (..., 3)."""
    out = np.zeros(rot.shape[:-1] + (4, 4))
    out[..., :3, :3] = quat.to_matrix(rot)
    out[..., :3, 3] = pos
    out[..., 3, 3] = 1.0
    return out


def joint_index(joint_names: tuple[str, ...], name: str, source: str = "") -> int:
    """Index of joint `name`, or an InputError listing the joints (naming `source` when given)."""
    try:
        return joint_names.index(name)
    except ValueError:
        raise InputError(f"no joint named {name!r}; joints are {', '.join(joint_names)}",
                         source or None) from None


@dataclass(frozen=True, eq=False)
class Clip:
    """A skeletal motion.

    Attributes
    ----------
    joint_names : (J,) names as in the source file.
    parents : (J,) int32, parent index or -1; parents come before children.
    offsets : (J, 3) float64, metres, rest local translation of each joint in its parent's frame
        (world for a root).
    rest_rotations : (J, 4) float64, w,x,y,z, rest local rotation.
    rotations : (T, J, 4) float64, w,x,y,z, local rotation per frame, continuous in time.
    translations : (T, J, 3) float64, metres, local translation per frame (equal to ``offsets``
        for joints whose translation is not animated; the root's is its world position).
    fps : frames per second, > 0.
    end_parents : (E,) int32, joint carrying each end site (bone tip without a joint).
    end_offsets : (E, 3) float64, metres, end site in its joint's frame.
    name : a label, usually the file stem.
    source : path of the file it came from, or "" when built in code.
    meta : free-form facts from the reader (units, skipped T-pose, ...), for `jiggle inspect`.
    """

    joint_names: tuple[str, ...]
    parents: np.ndarray
    offsets: np.ndarray
    rest_rotations: np.ndarray
    rotations: np.ndarray
    translations: np.ndarray
    fps: float
    end_parents: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))
    end_offsets: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    name: str = ""
    source: str = ""
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        set_ = lambda k, v: object.__setattr__(self, k, v)  # noqa: E731 (frozen dataclass)
        set_("joint_names", tuple(str(n) for n in self.joint_names))
        set_("parents", frozen_array(self.parents, np.int32))
        set_("offsets", frozen_array(self.offsets))
        set_("rest_rotations", frozen_array(self.rest_rotations))
        set_("rotations", frozen_array(quat.make_continuous(quat.normalize(np.asarray(self.rotations, float)))))
        set_("translations", frozen_array(self.translations))
        set_("end_parents", frozen_array(self.end_parents, np.int32))
        set_("end_offsets", frozen_array(np.reshape(self.end_offsets, (-1, 3))))
        set_("fps", float(self.fps))
        set_("meta", dict(self.meta))
        J = len(self.joint_names)
        T = self.rotations.shape[0] if self.rotations.ndim == 3 else -1
        expect = {"parents": (J,), "offsets": (J, 3), "rest_rotations": (J, 4),
                  "rotations": (T, J, 4), "translations": (T, J, 3)}
        for k, shape in expect.items():
            if getattr(self, k).shape != shape:
                raise ValueError(f"Clip.{k} has shape {getattr(self, k).shape}, expected {shape}")
        if len(set(self.joint_names)) != J:
            raise InputError("joint names are not unique", self.source or None, field="joints")
        if np.any(self.parents >= np.arange(J)) or np.any(self.parents < -1):
            raise ValueError("Clip.parents must list parents before children (-1 for a root)")
        if J == 0 or T < 1:
            raise InputError(f"a clip needs at least one joint and one frame (got {J} joints, {T} frames)",
                             self.source or None)
        if not np.isfinite(self.fps) or self.fps <= 0:
            raise InputError(f"frame rate must be a positive number, got {self.fps}",
                             self.source or None, field="fps")
        for k in ("offsets", "rotations", "translations", "end_offsets"):
            if not np.all(np.isfinite(getattr(self, k))):
                raise InputError(f"{k} hold NaN or inf", self.source or None, field=k)

    def scaled(self, factor: float) -> "Clip":
        """The same clip with every length times `factor` (joint offsets, translations, end offsets; rotations
        kept): a clip in a file's units at real size (rig.character.real_size.RealSize.scale), for the physics."""
        if factor == 1.0:
            return self
        f = float(factor)
        return dataclasses.replace(self, offsets=self.offsets * f, translations=self.translations * f,
                       end_offsets=self.end_offsets * f)

    # ------------------------------------------------------------------ sizes and time
    @property
    def num_joints(self) -> int:
        return len(self.joint_names)

    @property
    def num_frames(self) -> int:
        return self.rotations.shape[0]

    @property
    def duration(self) -> float:
        """Seconds from the first to the last frame."""
        return (self.num_frames - 1) / self.fps

    @property
    def times(self) -> np.ndarray:
        """(T,) seconds of each frame from the clip's start."""
        return np.arange(self.num_frames) / self.fps

    @property
    def root_translation(self) -> np.ndarray:
        """(T, 3) metres, world position of the first root joint."""
        return self.translations[:, 0]

    def index(self, name: str) -> int:
        return joint_index(self.joint_names, name, self.source)

    def children(self, j: int) -> list[int]:
        return [int(c) for c in np.nonzero(self.parents == j)[0]]

    @property
    def animated_translation(self) -> np.ndarray:
        """(J,) bool, joints whose local translation changes over the clip (roots always).

        A change under a micrometre is float noise in exported keys (glTF exporters write every
        joint's translation channel), not motion.
        """
        moving = np.ptp(self.translations, axis=0).max(axis=1) > TRANSLATION_NOISE
        return moving | (self.parents < 0)

    @property
    def bone_translations(self) -> np.ndarray:
        """(J, 3) metres, the local translation a joint keeps over the clip (its mean over time) where
        it is not animated, else its rest offset. Files may key a constant translation that differs
        from the rest offset (CesiumMan: by up to 3 mm); the bones are where the motion puts them."""
        held = np.where(self.animated_translation[:, None], self.offsets, self.translations.mean(axis=0))
        held.setflags(write=False)
        return held

    # ------------------------------------------------------------------ sampling
    def sample(self, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Local transforms at arbitrary times (seconds from the start), interpolated.

        Rotations are slerped and translations lerped between the two neighbouring frames; times
        outside the clip clamp to its ends.

        Returns rotations (N, J, 4) and translations (N, J, 3).
        """
        t = np.clip(np.atleast_1d(np.asarray(times, dtype=float)) * self.fps, 0.0, self.num_frames - 1)
        i0 = np.minimum(np.floor(t).astype(np.int64), self.num_frames - 1)
        i1 = np.minimum(i0 + 1, self.num_frames - 1)
        a = t - i0
        rot = quat.slerp(self.rotations[i0], self.rotations[i1], np.broadcast_to(a[:, None], i0.shape + (self.num_joints,)))
        tra = self.translations[i0] + a[:, None, None] * (self.translations[i1] - self.translations[i0])
        return rot, tra

    def resample(self, fps: float) -> "Clip":
        """The same motion at another frame rate (slerp for rotations), same duration or just under."""
        if not np.isfinite(fps) or fps <= 0:
            raise InputError(f"fps must be a positive number, got {fps}", field="fps")
        n = int(np.floor(self.duration * fps + 1e-9)) + 1
        rot, tra = self.sample(np.arange(n) / fps)
        return dataclasses.replace(self, rotations=rot, translations=tra, fps=fps)

    def frames(self, start: int = 0, stop: int | None = None) -> "Clip":
        """Frames [start, stop) as a new clip (Python slice semantics, at least one frame)."""
        sl = slice(start, stop)
        idx = range(self.num_frames)[sl]
        if len(idx) == 0:
            raise InputError(f"frame range [{start}, {stop}) of a {self.num_frames}-frame clip is empty",
                             self.source or None, field="frames")
        return dataclasses.replace(self, rotations=self.rotations[sl], translations=self.translations[sl])

    def between(self, start: float = 0.0, end: float | None = None) -> "Clip":
        """The part between `start` and `end` seconds, sampled at the clip's fps from `start`."""
        end = self.duration if end is None else end
        if not (0.0 <= start <= end <= self.duration + 1e-9):
            raise InputError(f"time range [{start}, {end}] s is outside the clip's 0..{self.duration:.4g} s",
                             self.source or None, field="start/end")
        n = int(np.floor((end - start) * self.fps + 1e-9)) + 1
        rot, tra = self.sample(start + np.arange(n) / self.fps)
        return dataclasses.replace(self, rotations=rot, translations=tra)

    def with_speed(self, factor: float) -> "Clip":
        """Play `factor` times faster (2: half the duration) at the same fps."""
        if not np.isfinite(factor) or factor <= 0:
            raise InputError(f"speed factor must be a positive number, got {factor}", field="speed")
        fast = dataclasses.replace(self, fps=self.fps * factor)
        return fast.resample(self.fps)

    # ------------------------------------------------------------------ kinematics (NumPy)
    def world(self, rotations: np.ndarray | None = None, translations: np.ndarray | None = None
              ) -> tuple[np.ndarray, np.ndarray]:
        """World rotations (N, J, 4) and positions (N, J, 3) by forward kinematics in NumPy.

        Defaults to every frame of the clip. This is the plain reference; the per-step pipeline
        takes its bone transforms from MuJoCo (`sim.drive.skeleton`).
        """
        rot = self.rotations if rotations is None else rotations
        tra = self.translations if translations is None else translations
        wr = np.empty_like(rot)
        wp = np.empty_like(tra)
        for j, p in enumerate(self.parents):
            if p < 0:
                wr[:, j] = rot[:, j]
                wp[:, j] = tra[:, j]
            else:
                wr[:, j] = quat.mul(wr[:, p], rot[:, j])
                wp[:, j] = wp[:, p] + quat.rotate(wr[:, p], tra[:, j])
        return wr, wp

    def rest_world(self) -> tuple[np.ndarray, np.ndarray]:
        """World rotations (J, 4) and positions (J, 3) of the rest pose."""
        r, p = self.world(self.rest_rotations[None], self.offsets[None])
        return r[0], p[0]

    def end_world(self, world_rot: np.ndarray, world_pos: np.ndarray) -> np.ndarray:
        """(N, E, 3) world positions of the end sites for world joint transforms (N, J, ...)."""
        e = self.end_parents
        return world_pos[:, e] + quat.rotate(world_rot[:, e], self.end_offsets[None])
