"""Retarget a clip onto a character's skeleton by humanoid roles.

A :class:`JointMap` (TOML) names, for canonical roles, the joint that plays it in one skeleton. The
file has a ``[joints]`` table; each value is a joint name or a list of alternatives (the first the
skeleton has is used), and an optional top-level ``name``::

    name = "cmu"
    [joints]
    hips = ["Hips", "root"]
    left_upper_leg = ["LeftUpLeg", "lfemur"]

Roles: hips, spine, chest, neck, head and, on each side (``left_``/``right_``), shoulder, upper_arm,
lower_arm, hand, upper_leg, lower_leg, foot, toe. Required: hips, spine, head and the arm and leg
roles except shoulder and toe. Built-in presets live in ``rig/motion/presets/<name>.toml`` (``cmu``,
``cesiumman``).

The method (:func:`retarget`):

1. Facing: each skeleton's rest facing is ``left x up`` (left = left minus right upper leg and upper
   arm, horizontal). ``Y`` turns the character's facing about +Z onto the clip's.
2. Rest alignment per mapped role r with clip joint c and character joint k: ``A_r = between(Y d_k,
   d_c) Y``, where d is the rest bone direction (world) from the role's joint to the next role along
   its chain (hips > spine > chest > neck > head, shoulder > upper_arm > lower_arm > hand, upper_leg >
   lower_leg > foot > toe) that is at least 1 cm away in both rests; roles with no such next role
   (head, hand, toe here) use ``A_r = Y``. The clip's rest is its offsets/rest rotations (the CMU
   T-pose); the character's is its bind pose.
3. Each frame: the clip joint's world delta ``D = Q_c(t) conj(Q_c,rest)`` is applied to the aligned
   character rest: ``Q_k(t) = D A_r Q_k,bind``. So the character's bone points where the clip's bone
   points (exactly, when both bones end at the direct child of the role's joint). Unmapped character
   joints keep their bind-local rotation relative to their parent (an unmapped root: ``Y Q_bind``).
4. Root path: scaled by ``s`` = character hip height / clip hip height (hips above the lowest foot or
   toe joint, each in its own rest). Horizontally the hips start at the character's bind position and
   move by ``s`` times the clip's hip displacement; vertically they follow ``s`` times the clip's hip
   height, corrected so the feet stay on the character's floor (``floor``, default z = 0, where glTF
   characters stand). A foot's *clearance* is its lowest foot/toe joint above that joint's rest
   height over the floor (0: as low as when standing in the rest pose); the clip's floor is taken
   where its clearance is lowest over the clip. ``contact="per_frame"`` (default) shifts the hips each
   frame so that the character's clearance equals ``s`` times the clip's for the clip's lower foot (a
   soft minimum over the two feet, 2 cm wide, keeps the shift continuous); leg proportions that differ
   from the clip's then change the hip height a little instead of pushing a planted foot through the
   floor or lifting it off. ``contact="constant"`` uses one shift for the whole clip, putting the
   lowest clearance over the clip at 0. The character's root carries the path (when the hips are
   not the root, the root moves so that the hips land on it).

The result is a Clip on the character's skeleton: its joint names and parents, offsets = bind-local
translations, rest rotations = bind-local rotations, animated translation on the root only.
"""
from __future__ import annotations

import importlib.resources
import os
import tomllib
from dataclasses import dataclass, field

import numpy as np

from jiggle.rig.base.errors import InputError
from jiggle.rig.motion import quat
from jiggle.rig.motion.clip import Clip
from jiggle.rig.motion.gltf_skeleton import CharacterSkeleton

SIDES = ("left", "right")
LIMB_ROLES = ("shoulder", "upper_arm", "lower_arm", "hand", "upper_leg", "lower_leg", "foot", "toe")
ROLES = ("hips", "spine", "chest", "neck", "head") + tuple(f"{s}_{r}" for s in SIDES for r in LIMB_ROLES)
REQUIRED = ("hips", "spine", "head") + tuple(f"{s}_{r}" for s in SIDES for r in (
    "upper_arm", "lower_arm", "hand", "upper_leg", "lower_leg", "foot"))
_CHAINS = [("hips", "spine", "chest", "neck", "head")] + [
    tuple(f"{s}_{r}" for r in chain) for s in SIDES
    for chain in (("shoulder", "upper_arm", "lower_arm", "hand"), ("upper_leg", "lower_leg", "foot", "toe"))]
MIN_BONE = 0.01  # metres: shorter role-to-role segments give no usable direction


def presets() -> list[str]:
    """Names of the built-in joint maps."""
    folder = importlib.resources.files("jiggle.rig.motion") / "presets"
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml"))


@dataclass(frozen=True)
class JointMap:
    """Roles -> candidate joint names (first present wins).

    roles : {role: (name, ...)}.
    source : the TOML file it came from (for error messages).
    name : the map's label.
    """

    roles: dict[str, tuple[str, ...]]
    source: str = ""
    name: str = ""
    meta: dict = field(default_factory=dict)

    @classmethod
    def load(cls, path_or_preset: str | os.PathLike) -> "JointMap":
        """Read a TOML joint map from a path, or a built-in preset by name ("cmu", "cesiumman")."""
        s = os.fspath(path_or_preset)
        if os.path.isfile(s):
            path = s
            with open(s, "rb") as fh:
                raw = fh.read()
        elif s.endswith(".toml") or os.sep in s or "/" in s:
            raise InputError("joint map file not found", s)
        else:
            res = importlib.resources.files("jiggle.rig.motion") / "presets" / f"{s}.toml"
            if not res.is_file():
                raise InputError(f"no joint map preset named {s!r}; presets are {', '.join(presets())}, or give "
                                 f"a path to a .toml file", field="joint map")
            path = str(res)
            raw = res.read_bytes()
        try:
            data = tomllib.loads(raw.decode("utf-8"))
        except (UnicodeDecodeError, tomllib.TOMLDecodeError) as e:
            raise InputError(f"not valid TOML: {e}", path) from None
        joints = data.get("joints")
        if not isinstance(joints, dict):
            raise InputError("expected a [joints] table mapping roles to joint names", path, field="joints")
        roles: dict[str, tuple[str, ...]] = {}
        for k, v in joints.items():
            if k not in ROLES:
                raise InputError(f"unknown role {k!r}; roles are {', '.join(ROLES)}", path, field=f"joints.{k}")
            names = (v,) if isinstance(v, str) else tuple(v) if isinstance(v, list) else None
            if not names or not all(isinstance(n, str) and n for n in names):
                raise InputError("expected a joint name or a non-empty list of joint names", path,
                                 field=f"joints.{k}")
            roles[k] = names
        missing = [r for r in REQUIRED if r not in roles]
        if missing:
            raise InputError(f"required role(s) missing: {', '.join(missing)}", path, field=f"joints.{missing[0]}")
        name = data.get("name", os.path.splitext(os.path.basename(path))[0])
        return cls(roles=roles, source=path, name=str(name))

    def resolve(self, joint_names: tuple[str, ...] | list[str], skeleton: str = "") -> dict[str, int]:
        """{role: joint index} in a skeleton with these joint names. Raises InputError naming the TOML
        file and key when no alternative of a role is in the skeleton or two roles share a joint."""
        index = {n: i for i, n in enumerate(joint_names)}
        out: dict[str, int] = {}
        for role, names in self.roles.items():
            hit = next((index[n] for n in names if n in index), None)
            if hit is None:
                which = " or ".join(repr(n) for n in names)
                raise InputError(f"joint {which} is not in the skeleton{' ' + skeleton if skeleton else ''} "
                                 f"(its joints: {', '.join(joint_names)})", self.source or None, field=f"joints.{role}")
            out[role] = hit
        seen: dict[int, str] = {}
        for role, j in out.items():
            if j in seen:
                raise InputError(f"joint {joint_names[j]!r} is mapped to both {seen[j]!r} and {role!r}",
                                 self.source or None, field=f"joints.{role}")
            seen[j] = role
        return out


def _facing(pos: np.ndarray, m: dict[str, int]) -> np.ndarray:
    """(3,) unit horizontal forward direction of a rest pose (J, 3) from its mapped left/right joints."""
    lat = np.zeros(3)
    for a in ("upper_leg", "upper_arm"):
        if f"left_{a}" in m and f"right_{a}" in m:
            lat += pos[m[f"left_{a}"]] - pos[m[f"right_{a}"]]
    lat[2] = 0.0
    if np.linalg.norm(lat) < 1e-6:
        raise InputError("cannot tell left from right: the left and right legs and arms coincide in the rest pose")
    fwd = np.cross(lat, [0.0, 0.0, 1.0])
    return fwd / np.linalg.norm(fwd)


def _yaw_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Rotation about +Z taking horizontal direction a onto b (both (3,), unit)."""
    ang = np.arctan2(a[0] * b[1] - a[1] * b[0], a[0] * b[0] + a[1] * b[1])
    return quat.from_axis_angle(np.array([0.0, 0.0, 1.0]), ang)


def _next_role(role: str, used: set[str], pc: np.ndarray, pk: np.ndarray, mc: dict, mk: dict) -> str | None:
    for chain in _CHAINS:
        if role in chain:
            for nxt in chain[chain.index(role) + 1:]:
                if nxt in used and (np.linalg.norm(pc[mc[nxt]] - pc[mc[role]]) >= MIN_BONE
                                    and np.linalg.norm(pk[mk[nxt]] - pk[mk[role]]) >= MIN_BONE):
                    return nxt
    return None


def bone_pairs(roles: set[str]) -> list[tuple[str, str]]:
    """(role, next role) for the limb bones among `roles`: upper/lower arm and leg, and foot to toe."""
    out = []
    for s in SIDES:
        for a, b in (("upper_arm", "lower_arm"), ("lower_arm", "hand"), ("upper_leg", "lower_leg"),
                     ("lower_leg", "foot"), ("foot", "toe")):
            if f"{s}_{a}" in roles and f"{s}_{b}" in roles:
                out.append((f"{s}_{a}", f"{s}_{b}"))
    return out


@dataclass(frozen=True, eq=False)
class _Matched:
    """The clip and the character matched by role, with the poses retargeting compares (world,
    Z-up, metres; Jc clip joints, J character joints, T frames).

    mc, mk : {role: joint index} in the clip and in the character.
    used : the roles both maps resolve.
    cr_r, cr_p : (Jc, 4) rotations and (Jc, 3) positions of the clip's rest pose.
    cw_r, cw_p : (T, Jc, 4) rotations and (T, Jc, 3) positions of the clip's frames.
    kb_r, kb_p : (J, 4) rotations and (J, 3) positions of the character's bind pose.
    """

    mc: dict[str, int]
    mk: dict[str, int]
    used: set[str]
    cr_r: np.ndarray
    cr_p: np.ndarray
    cw_r: np.ndarray
    cw_p: np.ndarray
    kb_r: np.ndarray
    kb_p: np.ndarray


def _match(clip: Clip, clip_map: JointMap, character: CharacterSkeleton, character_map: JointMap) -> _Matched:
    """Resolve both joint maps and take the clip's rest and frames and the character's bind pose."""
    mc = clip_map.resolve(clip.joint_names, f"of clip {clip.name!r}")
    mk = character_map.resolve(character.joint_names, f"of character {character.name!r}")
    cr_r, cr_p = clip.rest_world()
    cw_r, cw_p = clip.world()
    kb_r = quat.from_matrix(character.bind_world[:, :3, :3])
    return _Matched(mc, mk, set(mc) & set(mk), cr_r, cr_p, cw_r, cw_p, kb_r, character.bind_positions)


def retarget(clip: Clip, clip_map: JointMap, character: CharacterSkeleton, character_map: JointMap, *,
             scale: float | None = None, floor: float = 0.0, contact: str = "per_frame") -> Clip:
    """The clip's motion on the character's skeleton (see the module docstring for the method).

    Parameters
    ----------
    clip : the motion (any reader's Clip, Z-up metres).
    clip_map, character_map : joint maps for the two skeletons.
    character : the target skeleton and its bind pose.
    scale : root path scale; None for character hip height / clip hip height.
    floor : z of the character's floor, metres.
    contact : "per_frame" (default) or "constant", how the hips' height is corrected so the feet
        stay on the floor (module docstring, step 4).

    Returns a Clip with the character's joints (T frames at the clip's fps); ``meta`` records the
    scale, the roles used, the yaw alignment and the vertical offset.
    """
    if contact not in ("per_frame", "constant"):
        raise InputError(f"contact must be 'per_frame' or 'constant', got {contact!r}", field="contact")
    if not np.isfinite(floor):
        raise InputError(f"floor must be a finite height in metres, got {floor}", field="floor")
    m = _match(clip, clip_map, character, character_map)
    T, J = clip.num_frames, character.num_joints

    yaw = _yaw_between(_facing(m.kb_p, m.mk), _facing(m.cr_p, m.mc))
    align = _rest_alignment(m, yaw)
    by_joint = {m.mk[r]: r for r in m.used}
    local = _local_rotations(m, character, by_joint, align, yaw, T)

    # Root path.
    feet = [r for s in SIDES for r in (f"{s}_foot", f"{s}_toe") if r in m.used]
    h_c, h_k = _hip_height(m.cr_p, m.mc, feet), _hip_height(m.kb_p, m.mk, feet)
    scale = _path_scale(scale, h_c, h_k, clip)
    translations, hip_root, pos = _place_hips(m, character, local, clip.fps, scale, T)
    lift = _floor_lift(m, pos, feet, scale, floor, contact, T)
    translations[:, hip_root, 2] += lift

    roots = np.nonzero(character.parents < 0)[0]
    meta = {"format": "retargeted", "from": clip.name, "from_format": clip.meta.get("format", ""),
            "character": character.name, "clip_map": clip_map.name, "character_map": character_map.name,
            "roles": sorted(m.used), "scale": scale, "clip_hip_height_m": h_c, "character_hip_height_m": h_k,
            "yaw_deg": float(np.degrees(2 * np.arctan2(yaw[3], yaw[0]))), "contact": contact,
            "vertical_correction_m": [float(lift.min()), float(lift.max())],
            "floor_m": floor, "unmapped_joints": [character.joint_names[k] for k in range(J) if k not in by_joint],
            "extra_roots": [character.joint_names[r] for r in roots if r != hip_root]}
    return Clip(joint_names=character.joint_names, parents=character.parents, offsets=character.bind_translations,
                rest_rotations=character.bind_rotations, rotations=local, translations=translations, fps=clip.fps,
                name=f"{clip.name} on {character.name}", source=clip.source, meta=meta)


def _rest_alignment(m: _Matched, yaw: np.ndarray) -> dict[str, np.ndarray]:
    """{role: A_r (4,)}, the rotation taking the character's rest bone of each used role onto the
    clip's after the facing turn `yaw` (module docstring, step 2)."""
    align: dict[str, np.ndarray] = {}
    for role in m.used:
        nxt = _next_role(role, m.used, m.cr_p, m.kb_p, m.mc, m.mk)
        if nxt is None:
            align[role] = yaw
            continue
        d_c = m.cr_p[m.mc[nxt]] - m.cr_p[m.mc[role]]
        d_k = quat.rotate(yaw, m.kb_p[m.mk[nxt]] - m.kb_p[m.mk[role]])
        align[role] = quat.mul(quat.between(d_k, d_c), yaw)
    return align


def _local_rotations(m: _Matched, character: CharacterSkeleton, by_joint: dict[int, str],
                     align: dict[str, np.ndarray], yaw: np.ndarray, T: int) -> np.ndarray:
    """(T, J, 4) local rotations of the character's joints (module docstring, step 3): mapped joints
    follow their clip joint's world delta, unmapped ones keep their bind-local rotation."""
    J = character.num_joints
    # World rotation targets, parents first.
    world = np.empty((T, J, 4))
    for k in range(J):
        p = character.parents[k]
        if k in by_joint:
            r = by_joint[k]
            c = m.mc[r]
            delta = quat.mul(m.cw_r[:, c], quat.conj(m.cr_r[c]))
            world[:, k] = quat.mul(delta, quat.mul(align[r], m.kb_r[k]))
        elif p < 0:
            world[:, k] = quat.mul(yaw, m.kb_r[k])
        else:
            world[:, k] = quat.mul(world[:, p], character.bind_rotations[k])
    local = np.empty_like(world)
    for k in range(J):
        p = character.parents[k]
        local[:, k] = world[:, k] if p < 0 else quat.mul(quat.conj(world[:, p]), world[:, k])
    return local


def _hip_height(pos: np.ndarray, m: dict[str, int], feet: list[str]) -> float:
    """Metres from the lowest of the `feet` roles' joints up to the hips in a pose `pos` (J, 3)."""
    return float(pos[m["hips"], 2] - min(pos[m[r], 2] for r in feet))


def _path_scale(scale: float | None, h_c: float, h_k: float, clip: Clip) -> float:
    """The root path scale: `scale` checked, or the hip heights' ratio `h_k / h_c` when None."""
    if scale is None:
        if h_c <= MIN_BONE:
            raise InputError(f"the clip's hips are {h_c:.3g} m above its feet in the rest pose; cannot scale "
                             f"the root path (pass scale=)", clip.source or None, field="scale")
        scale = h_k / h_c
    elif not np.isfinite(scale) or scale <= 0:
        raise InputError(f"scale must be a positive number, got {scale}", field="scale")
    return scale


def _place_hips(m: _Matched, character: CharacterSkeleton, local: np.ndarray, fps: float, scale: float,
                T: int) -> tuple[np.ndarray, int, np.ndarray]:
    """Move the root joint above the hips so the hips follow the clip's, scaled (module docstring,
    step 4, before the floor correction). Returns translations (T, J, 3), that root's index and
    the joint world positions (T, J, 3) it gives."""
    J = character.num_joints
    hips_c, hips_k = m.mc["hips"], m.mk["hips"]
    target = np.empty((T, 3))
    target[:, :2] = m.kb_p[hips_k, :2] + scale * (m.cw_p[:, hips_c, :2] - m.cw_p[0, hips_c, :2])
    target[:, 2] = scale * m.cw_p[:, hips_c, 2]

    translations = np.broadcast_to(character.bind_translations, (T, J, 3)).copy()
    hip_root = int(hips_k)
    while character.parents[hip_root] >= 0:
        hip_root = int(character.parents[hip_root])
    probe = Clip(character.joint_names, character.parents, character.bind_translations, character.bind_rotations,
                 local, translations, fps)
    _, pos = probe.world()
    translations[:, hip_root] += target - pos[:, hips_k]
    _, pos = probe.world(local, translations)
    return translations, hip_root, pos


def _clearance(p: np.ndarray, m: dict[str, int], rest_p: np.ndarray, base: float, used: set[str]) -> np.ndarray:
    """(T, 2) per frame and foot (left, right): the lowest of its foot/toe joints in `p` (T, J, 3)
    above that joint's rest height in `rest_p` (J, 3) less `base`, metres."""
    return np.stack([np.min(p[:, [m[r] for r in (f"{s}_foot", f"{s}_toe") if r in used], 2]
                            - (rest_p[[m[r] for r in (f"{s}_foot", f"{s}_toe") if r in used], 2] - base),
                            axis=1) for s in SIDES], axis=1)


def _floor_lift(m: _Matched, pos: np.ndarray, feet: list[str], scale: float, floor: float, contact: str,
                T: int) -> np.ndarray:
    """(T,) metres to raise the hips by so the character's feet stay on its floor, given its joint
    positions `pos` (T, J, 3) before the correction (module docstring, step 4)."""
    # Feet on the character's floor. Clearance of a foot: its lowest foot/toe joint above that joint's
    # rest height (0 = as low as standing in the rest pose); the clip's floor is where its clearance
    # is lowest over the clip.
    c_clip = _clearance(m.cw_p, m.mc, m.cr_p, min(m.cr_p[m.mc[r], 2] for r in feet), m.used)
    c_clip -= c_clip.min()
    c_char = _clearance(pos, m.mk, m.kb_p, floor, m.used) - floor
    if contact == "per_frame":
        # The lower foot of the clip sets the height: the character's clearance follows the clip's,
        # scaled, with a soft minimum over the feet (2 cm) so the correction stays continuous.
        w = np.exp(-(c_clip - c_clip.min(axis=1, keepdims=True)) / 0.02)
        w /= w.sum(axis=1, keepdims=True)
        return np.sum(w * (scale * c_clip - c_char), axis=1)
    return np.full(T, -float(c_char.min()))


def foot_clearance(clip: Clip, character: CharacterSkeleton, character_map: JointMap, floor: float = 0.0
                   ) -> np.ndarray:
    """(T, 2) metres: per frame and foot (left, right), the lowest of the foot's mapped foot/toe joints
    above its own bind-pose height over `floor` (0 = as low as when the character stands in bind)."""
    mk = character_map.resolve(character.joint_names)
    _, pos = clip.world()
    out = np.empty((clip.num_frames, 2))
    for i, s in enumerate(SIDES):
        ks = [mk[r] for r in (f"{s}_foot", f"{s}_toe") if r in mk]
        out[:, i] = np.min(pos[:, ks, 2] - (character.bind_positions[ks, 2] - floor), axis=1)
    return out


def same_skeleton(clip: Clip, character: CharacterSkeleton) -> np.ndarray | None:
    """(J,) index into the clip's joints of each of the character's joints when the clip moves the
    character's own skeleton (every joint there by name, with the same parent), else None."""
    index = {n: i for i, n in enumerate(clip.joint_names)}
    if not all(n in index for n in character.joint_names):
        return None
    idx = np.array([index[n] for n in character.joint_names], np.int64)
    for j, p in enumerate(character.parents):
        cp = clip.parents[idx[j]]
        if (p < 0) != (cp < 0) or (p >= 0 and clip.joint_names[cp] != character.joint_names[p]):
            return None
    return idx


def identity(clip: Clip, idx: np.ndarray, parents: np.ndarray, scale: float = 1.0) -> Clip:
    """The clip on the character's own skeleton: its joints `idx` (J,) in the character's order with
    the character's `parents`, lengths times `scale` (the character's metres per file unit, a clip of
    its own rig being in the same unit); nothing else moves (no retargeting)."""
    from dataclasses import replace
    return replace(clip, joint_names=[clip.joint_names[i] for i in idx], parents=parents,
                   offsets=clip.offsets[idx] * scale, rest_rotations=clip.rest_rotations[idx],
                   rotations=clip.rotations[:, idx], translations=clip.translations[:, idx] * scale,
                   end_parents=np.zeros(0, np.int32), end_offsets=np.zeros((0, 3)),
                   meta={**clip.meta, "retarget": "identity (the character's own skeleton)"})


def scaled_skeleton(character: CharacterSkeleton, scale: float) -> CharacterSkeleton:
    """The skeleton with every length times `scale` (metres per file unit; rotations kept)."""
    if scale == 1.0:
        return character
    from dataclasses import replace
    bind = np.array(character.bind_world)
    bind[:, :3, 3] *= scale
    return replace(character, bind_world=bind, bind_translations=character.bind_translations * scale,
                   rest_translations=character.rest_translations * scale)
