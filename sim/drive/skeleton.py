"""MuJoCo drives the skeleton: an MJCF model built from any clip, and its world transforms per step.

The model has a body per clip joint (a free joint on each root, a ball joint elsewhere, three slide
joints before the ball where a non-root translation is animated) and capsule geoms along the bones
with a tissue density, so that masses are plausible for the physics drive.

Bone thickness follows the bone's role, found from the joint tree alone (no joint names), see
:func:`rig.motion.bone_roles.bone_roles`: limbs get a radius proportional to their length; the trunk (spine from the root
up to the chest, where arms and neck branch off, and the pelvis bones from the root to the hips), the
neck and the head get fixed radii. With the defaults a CMU skeleton weighs about 60 kg; with
every bone a limb it weighed 38 kg, its trunk being pencil-thin. Per step the clip is
sampled at the step's time (interpolated, never held), turned into qpos, and `mj_kinematics` gives
the world transform of every bone.
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from xml.sax.saxutils import quoteattr

import mujoco
import numpy as np

from jiggle.rig.motion import quat
from jiggle.rig.motion.bone_roles import bone_roles
from jiggle.rig.motion.clip import Clip


@dataclass(frozen=True)
class BodyShape:
    """How bones become capsules.

    radius_ratio : limb capsule radius per metre of bone length.
    min_radius, max_radius : clamp of that radius, metres.
    trunk_radius : radius of the spine and pelvis capsules, metres.
    neck_radius : radius of the neck capsules (chest to head), metres.
    head_radius : radius of the head capsule (the last bone of the neck chain), metres.
    density : kg/m^3 (about that of soft tissue).
    """

    radius_ratio: float = 0.22
    min_radius: float = 0.02
    max_radius: float = 0.065
    trunk_radius: float = 0.12
    neck_radius: float = 0.05
    head_radius: float = 0.09
    density: float = 1000.0


def _fmt(v) -> str:
    # 17 significant digits: the text round-trips float64 exactly, so MuJoCo FK matches Clip.world
    return " ".join(f"{x:.17g}" for x in np.ravel(v))


def mjcf_names(clip: Clip) -> list[str]:
    """Body names used in the MJCF for each clip joint: the joint name with characters outside
    [A-Za-z0-9_.-] replaced, made unique."""
    out, seen = [], set()
    for n in clip.joint_names:
        s = re.sub(r"[^A-Za-z0-9_.\-]", "_", n) or "joint"
        base, k = s, 1
        while s in seen:
            k += 1
            s = f"{base}_{k}"
        seen.add(s)
        out.append(s)
    return out


def build_mjcf(clip: Clip, shape: BodyShape = BodyShape(), floor_height: float | None = None,
               timestep: float = 0.002) -> str:
    """MJCF text for the clip's skeleton (its rest pose at qpos0).

    floor_height : z of a floor plane in metres, or None for no floor.
    Geoms collide only with the floor (contype 1, conaffinity 0; the floor the reverse).
    """
    names = mjcf_names(clip)
    moving = clip.animated_translation
    kids = [clip.children(j) for j in range(clip.num_joints)]
    ends = [[o for e, o in zip(clip.end_parents, clip.end_offsets) if e == j] for j in range(clip.num_joints)]

    roles = bone_roles(clip)
    bone = clip.bone_translations  # body positions: where the clip keeps each joint
    fixed = {"trunk": shape.trunk_radius, "neck": shape.neck_radius, "head": shape.head_radius}

    def geoms(j: int) -> list[str]:
        g = []
        tips = [bone[c] for c in kids[j]] + ends[j]
        for k, tip in enumerate(tips):
            length = float(np.linalg.norm(tip))
            if length < 1e-4:
                continue
            r = fixed.get(roles[j][k])
            if r is None:
                r = float(np.clip(shape.radius_ratio * length, shape.min_radius, shape.max_radius))
            # Pull the capsule ends in by the radius so that the rounded caps end at the joints.
            inset = min(r, 0.45 * length) / length
            a, b = tip * inset, tip * (1.0 - inset)
            g.append(f'<geom name={quoteattr(f"{names[j]}_bone{k}")} type="capsule" size="{r:.6g}" '
                     f'fromto="{_fmt(a)} {_fmt(b)}"/>')
        if not g:
            g.append(f'<geom name={quoteattr(f"{names[j]}_node")} type="sphere" size="{shape.min_radius:.6g}"/>')
        return g

    def body(j: int, depth: int) -> list[str]:
        pad = "  " * depth
        lines = [f'{pad}<body name={quoteattr(names[j])} pos="{_fmt(bone[j])}" '
                 f'quat="{_fmt(clip.rest_rotations[j])}">']
        if clip.parents[j] < 0:
            lines.append(f'{pad}  <freejoint name={quoteattr(names[j] + "_free")}/>')
        else:
            if moving[j]:
                for a, axis in zip("xyz", np.eye(3)):
                    lines.append(f'{pad}  <joint name={quoteattr(f"{names[j]}_t{a}")} type="slide" '
                                 f'axis="{_fmt(axis)}"/>')
            lines.append(f'{pad}  <joint name={quoteattr(names[j] + "_ball")} type="ball"/>')
        lines += [f"{pad}  {g}" for g in geoms(j)]
        for c in kids[j]:
            lines += body(c, depth + 1)
        lines.append(f"{pad}</body>")
        return lines

    world = []
    if floor_height is not None:
        world.append(f'<geom name="floor" type="plane" size="0 0 0.05" pos="0 0 {floor_height:.9g}" '
                     f'contype="0" conaffinity="1" rgba="0.8 0.8 0.8 1"/>')
    for j in range(clip.num_joints):
        if clip.parents[j] < 0:
            world += body(j, 1)
    model_name = re.sub(r"[^A-Za-z0-9_.\-]", "_", clip.name or "clip")
    return "\n".join([
        f'<mujoco model={quoteattr(model_name)}>',
        '  <compiler angle="radian" inertiafromgeom="true"/>',
        f'  <option timestep="{timestep:.9g}" gravity="0 0 -9.81"/>',
        f'  <default><geom density="{shape.density:.6g}" contype="1" conaffinity="0" '
        f'rgba="0.7 0.5 0.4 1"/></default>',
        '  <worldbody>',
        *["    " + w for w in world],
        '  </worldbody>',
        '</mujoco>',
    ])


class Skeleton:
    """A clip's skeleton as a MuJoCo model, posed by `mj_kinematics`.

    Parameters
    ----------
    clip : the motion; its rest pose is the model's qpos0.
    shape : capsule sizes and density.
    floor_height : z of a floor plane (metres) or None.

    Attributes
    ----------
    model, data : mujoco.MjModel / MjData.
    body_ids : (J,) int, MuJoCo body of each clip joint.
    """

    def __init__(self, clip: Clip, shape: BodyShape = BodyShape(), floor_height: float | None = None,
                 timestep: float = 0.002):
        self.clip = clip
        self.xml = build_mjcf(clip, shape, floor_height, timestep)
        self.model = mujoco.MjModel.from_xml_string(self.xml)
        self.data = mujoco.MjData(self.model)
        names = mjcf_names(clip)
        self.body_ids = np.array([mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, n) for n in names])
        self._bone = clip.bone_translations
        self._layout = []  # (joint index, kind, qpos address)
        for j, n in enumerate(names):
            if clip.parents[j] < 0:
                self._layout.append((j, "free", self._qadr(n + "_free")))
                continue
            if clip.animated_translation[j]:
                self._layout.append((j, "slide", self._qadr(n + "_tx")))
            self._layout.append((j, "ball", self._qadr(n + "_ball")))

    def _qadr(self, joint_name: str) -> int:
        jid = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_JOINT, joint_name)
        return int(self.model.jnt_qposadr[jid])

    @property
    def total_mass(self) -> float:
        """kg."""
        return float(np.sum(self.model.body_mass))

    def qpos(self, rotations: np.ndarray, translations: np.ndarray) -> np.ndarray:
        """(N, nq) qpos for local rotations (N, J, 4) and translations (N, J, 3) of the clip."""
        clip = self.clip
        q = np.zeros((rotations.shape[0], self.model.nq))
        for j, kind, a in self._layout:
            if kind == "free":
                q[:, a:a + 3] = translations[:, j]
                q[:, a + 3:a + 7] = rotations[:, j]
            elif kind == "ball":
                # The body's rest rotation is its `quat`; the ball joint carries the rest.
                q[:, a:a + 4] = quat.mul(quat.conj(clip.rest_rotations[j]), rotations[:, j])
            else:  # slide axes live in the body frame, rotated by the rest rotation
                q[:, a:a + 3] = quat.rotate(quat.conj(clip.rest_rotations[j]),
                                            translations[:, j] - self._bone[j])
        return q

    def qpos_at(self, times: np.ndarray) -> np.ndarray:
        """(N, nq) qpos at times (seconds from the clip's start), the clip interpolated."""
        return self.qpos(*self.clip.sample(times))

    def kinematics(self, qpos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World rotations (N, J, 4) w,x,y,z and positions (N, J, 3) metres for qpos (N, nq)."""
        return body_poses(self.model, self.data, qpos, self.body_ids)

    def world(self, times: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """World rotations (N, J, 4) and positions (N, J, 3) at `times` seconds (default: every
        frame of the clip), through MuJoCo."""
        if times is None:
            q = self.qpos(self.clip.rotations, self.clip.translations)
        else:
            q = self.qpos_at(times)
        return self.kinematics(q)


def body_poses(model: mujoco.MjModel, data: mujoco.MjData, qpos: np.ndarray, bodies: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray]:
    """World rotations (N, B, 4) w,x,y,z and positions (N, B, 3) metres of `bodies` (B,) for each
    row of qpos (N, nq), by mj_kinematics (overwrites `data`)."""
    n = qpos.shape[0]
    rot = np.empty((n, len(bodies), 4))
    pos = np.empty((n, len(bodies), 3))
    for i in range(n):
        data.qpos[:] = qpos[i]
        mujoco.mj_kinematics(model, data)
        rot[i] = data.xquat[bodies]
        pos[i] = data.xpos[bodies]
    return rot, pos


def capsule_geoms(model: mujoco.MjModel, body_ids: np.ndarray) -> dict:
    """The capsule (and sphere) geoms of a MuJoCo model on the bodies `body_ids` (J,) (body of each clip
    joint), in each body's own frame, as collision capsules: {"joint": (C,) int, the clip joint whose body
    carries it; "local": (C, 2, 3) metres, the ends of its segment in the body frame (a sphere's two ends
    coincide); "radius": (C,) metres; "names": the geoms' names}. The world transform MuJoCo gives a body
    is its joint's (Skeleton.world), so world @ local puts a geom where the model has it in any pose.
    Other geom types (boxes, meshes, the floor plane) are left out."""
    joint_of = {int(b): j for j, b in enumerate(np.asarray(body_ids))}
    joint, local, radius, names = [], [], [], []
    for g in range(model.ngeom):
        kind = int(model.geom_type[g])
        if kind not in (int(mujoco.mjtGeom.mjGEOM_CAPSULE), int(mujoco.mjtGeom.mjGEOM_SPHERE)):
            continue
        j = joint_of.get(int(model.geom_bodyid[g]))
        if j is None:
            continue
        R = np.empty(9)
        mujoco.mju_quat2Mat(R, model.geom_quat[g])
        axis = R.reshape(3, 3)[:, 2]
        half = float(model.geom_size[g, 1]) if kind == int(mujoco.mjtGeom.mjGEOM_CAPSULE) else 0.0
        c = np.asarray(model.geom_pos[g], dtype=np.float64)
        joint.append(j)
        local.append([c - half * axis, c + half * axis])
        radius.append(float(model.geom_size[g, 0]))
        names.append(mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, g) or f"geom{g}")
    return {"joint": np.array(joint, np.int64), "local": np.array(local, np.float64).reshape(-1, 2, 3),
            "radius": np.array(radius, np.float64), "names": tuple(names)}


def model_capsules(clip: Clip, character):
    """(capsules, G, kept): the collision capsules of --colliders model, the capsule geoms of the MuJoCo model
    that drives `clip`'s skeleton (:func:`build_mjcf`'s: the kinematic and the physics drive build the same
    geoms) kept inside `character`'s skin, then its bone capsules (named "bone:...") where a joint has none
    (rig.character.capsules.model_capsules); G the model's capsule geoms, kept how many of them the capsules
    hold (their first `kept`). The clip's joints must be the character's (a clip retargeted onto it, or its
    own skeleton)."""
    from dataclasses import replace

    from jiggle.rig.base.errors import InputError
    from jiggle.rig.character.capsules import bone_capsules
    from jiggle.rig.character.capsules import model_capsules as kept_inside
    sk = Skeleton(clip)
    if len(sk.body_ids) != character.num_joints:
        raise InputError(f"the MuJoCo model has {len(sk.body_ids)} bodies for the clip's joints, the character "
                         f"{character.num_joints} joints; use --colliders bone", field="--colliders")
    g = capsule_geoms(sk.model, sk.body_ids)
    bone = bone_capsules(character)
    bone = replace(bone, names=tuple(f"bone:{n}" for n in bone.names))
    caps, kept = kept_inside(character, g["joint"], g["local"], g["radius"], g["names"], fallback=bone)
    return caps, len(g["names"]), kept
