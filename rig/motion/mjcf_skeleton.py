"""The skeleton of a MuJoCo model (MJCF) as a one-frame Clip: bodies at qpos0 are the rest pose.

Each body but the world body becomes a joint named after the body (unnamed ones `body<id>`),
parents first as MuJoCo orders them. Leaf bodies get an end site at the tip of their geoms (the
capsule or cylinder end farthest from the body's origin, else the geom's centre), so that hands,
feet and the head have a length to give a generated body or automatic weights.
"""
from __future__ import annotations

import os

import numpy as np

from jiggle.rig.base.errors import InputError, require_file
from jiggle.rig.motion import quat
from jiggle.rig.motion.clip import Clip, local_from_world


def read_mjcf_skeleton(path: str | os.PathLike) -> Clip:
    """Bodies of the MJCF at qpos0 as a one-frame Clip (Z-up metres, as MuJoCo models are)."""
    import mujoco
    p = require_file(path, "MJCF model")
    try:
        m = mujoco.MjModel.from_xml_path(p)
    except ValueError as e:  # MuJoCo's parse and compile errors
        raise InputError(f"MuJoCo cannot load the model: {e}".strip(), p) from None
    if m.nbody < 2:
        raise InputError("the model has no body besides the world", p, field="worldbody")
    d = mujoco.MjData(m)
    mujoco.mj_kinematics(m, d)
    ids = np.arange(1, m.nbody)
    names = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, int(b)) or f"body{b}" for b in ids]
    parents = np.array([b - 1 if b > 0 else -1 for b in m.body_parentid[ids]], dtype=np.int32)
    wr, wp = d.xquat[ids].copy(), d.xpos[ids].copy()
    rot, tra = local_from_world(parents, wr, wp)
    has_child = np.zeros(len(ids), bool)
    has_child[parents[parents >= 0]] = True
    end_parents, end_offsets = [], []
    for j in np.nonzero(~has_child)[0]:
        tip = _geom_tip(m, d, int(ids[j]))
        if tip is not None:
            end_parents.append(j)
            end_offsets.append(quat.rotate(quat.conj(wr[j]), tip - wp[j]))
    return Clip(joint_names=tuple(names), parents=parents, offsets=tra, rest_rotations=rot,
                rotations=rot[None], translations=tra[None], fps=30.0,
                end_parents=np.array(end_parents, dtype=np.int32),
                end_offsets=np.array(end_offsets, dtype=np.float64).reshape(-1, 3),
                name=os.path.splitext(os.path.basename(p))[0], source=p, meta={"format": "MJCF qpos0"})


def _geom_tip(m, d, body: int) -> np.ndarray | None:
    """World point of the body's geoms farthest from its origin: capsule/cylinder ends, else centres."""
    import mujoco
    geoms = np.nonzero(m.geom_bodyid == body)[0]
    if len(geoms) == 0:
        return None
    pts = []
    for g in geoms:
        c = d.geom_xpos[g]
        if m.geom_type[g] in (mujoco.mjtGeom.mjGEOM_CAPSULE, mujoco.mjtGeom.mjGEOM_CYLINDER):
            axis = d.geom_xmat[g].reshape(3, 3)[:, 2] * m.geom_size[g, 1]
            pts += [c + axis, c - axis]
        else:
            pts.append(c)
    pts = np.array(pts)
    far = pts[np.argmax(np.linalg.norm(pts - d.xpos[body], axis=1))]
    return far if np.linalg.norm(far - d.xpos[body]) > 1e-6 else None
