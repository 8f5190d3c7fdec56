"""Keyframed motion written by hand in TOML: the project's own clips (the built-in demo's motion).

File layout (all lengths metres, world Z-up, the figure facing -Y with its left side at +X, as the
CMU clips are after import)::

    name = "jumping_jacks"
    fps = 60              # output frame rate of the clip
    euler = "XYZ"         # intrinsic order of the key angles (R = Rx @ Ry @ Rz), degrees
    loop = true           # keys describe one cycle; the last key must equal the first
    cycles = 3            # how many times the cycle plays

    [[joints]]            # parents first; parent = "" for the root
    name = "pelvis"
    parent = ""
    offset = [0.0, 0.0, 0.95]
    ...
    [[ends]]              # bone tips without a joint (head top, finger tips, toe tips)
    parent = "head"
    offset = [0.0, 0.0, 0.2]

    [[keys]]
    time = 0.0            # seconds
    root = [0.0, 0.0, 0.95]            # optional; root world position
    [keys.rotate]         # local rotation of joints at this key (omitted: zero)
    l_upper_arm = [0.0, -10.0, 0.0]

Joint frames are world-aligned at rest, as in BVH. Angles and the root path are interpolated with
cubic splines (periodic when `loop`), so the motion is smooth in velocity and acceleration, which
matters for the jiggle downstream.
"""
from __future__ import annotations

import os

import numpy as np
from scipy.interpolate import CubicSpline

from rig.base.errors import InputError
from rig.base.tomlfile import read_toml
from rig.motion import quat
from rig.motion.clip import Clip


def _vec3(v, path: str, field: str) -> np.ndarray:
    try:
        a = np.array(v, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"expected 3 numbers, found {v!r}", path, field=field) from None
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise InputError(f"expected 3 finite numbers, found {v!r}", path, field=field)
    return a


def read_keyframes(path: str | os.PathLike) -> Clip:
    """Read a keyframed TOML clip (see module docstring) into a :class:`Clip`."""
    p, doc = read_toml(path, "keyframe file")

    fps = doc.get("fps", 60)
    if not isinstance(fps, (int, float)) or not np.isfinite(fps) or fps <= 0:
        raise InputError(f"expected a positive number, found {fps!r}", p, field="fps")
    order = str(doc.get("euler", "XYZ")).upper()
    if sorted(order) != ["X", "Y", "Z"]:
        raise InputError(f"expected a permutation of XYZ, found {order!r}", p, field="euler")
    loop = bool(doc.get("loop", False))
    cycles = doc.get("cycles", 1)
    if not isinstance(cycles, int) or cycles < 1:
        raise InputError(f"expected a whole number >= 1, found {cycles!r}", p, field="cycles")

    joints = doc.get("joints")
    if not isinstance(joints, list) or not joints:
        raise InputError("expected a list of [[joints]] tables", p, field="joints")
    names, parents, offsets = [], [], []
    for k, j in enumerate(joints):
        if not isinstance(j, dict) or not isinstance(j.get("name"), str):
            raise InputError("each joint needs a name", p, field=f"joints[{k}]")
        par = j.get("parent", "")
        if par and par not in names:
            raise InputError(f"parent {par!r} is not a joint listed before it", p, field=f"joints[{k}].parent")
        names.append(j["name"])
        parents.append(names.index(par) if par else -1)
        offsets.append(_vec3(j.get("offset", [0, 0, 0]), p, f"joints[{k}].offset"))
    ends = doc.get("ends", [])
    end_parents, end_offsets = [], []
    for k, e in enumerate(ends):
        if e.get("parent") not in names:
            raise InputError(f"parent {e.get('parent')!r} is not a joint", p, field=f"ends[{k}].parent")
        end_parents.append(names.index(e["parent"]))
        end_offsets.append(_vec3(e.get("offset"), p, f"ends[{k}].offset"))

    keys = doc.get("keys")
    if not isinstance(keys, list) or len(keys) < 2:
        raise InputError("expected at least two [[keys]]", p, field="keys")
    times = []
    angles = np.zeros((len(keys), len(names), 3))
    root = np.zeros((len(keys), 3))
    for k, key in enumerate(keys):
        t = key.get("time")
        if not isinstance(t, (int, float)) or not np.isfinite(t):
            raise InputError(f"expected a time in seconds, found {t!r}", p, field=f"keys[{k}].time")
        if times and t <= times[-1]:
            raise InputError(f"key times must increase ({t} after {times[-1]})", p, field=f"keys[{k}].time")
        times.append(float(t))
        root[k] = _vec3(key["root"], p, f"keys[{k}].root") if "root" in key else offsets[0]
        for jn, a in key.get("rotate", {}).items():
            if jn not in names:
                raise InputError(f"no joint named {jn!r}", p, field=f"keys[{k}].rotate.{jn}")
            angles[k, names.index(jn)] = _vec3(a, p, f"keys[{k}].rotate.{jn}")
    times = np.array(times) - times[0]
    if loop and not (np.allclose(angles[0], angles[-1]) and np.allclose(root[0], root[-1])):
        raise InputError("a looping cycle must end on the pose it starts with", p, field="keys")
    bc = "periodic" if loop else "natural"
    period = times[-1]
    n = int(np.floor(period * cycles * fps + 1e-9)) + 1
    t = np.arange(n) / fps
    local_t = np.mod(t, period) if loop else np.minimum(t, period)
    if loop and cycles > 0:
        local_t[-1] = period if abs(t[-1] - period * cycles) < 1e-9 else local_t[-1]
    ang = CubicSpline(times, angles.reshape(len(times), -1), bc_type=bc)(local_t).reshape(n, len(names), 3)
    rpos = CubicSpline(times, root, bc_type=bc)(local_t)
    J = len(names)
    rotations = quat.from_euler(ang[..., [("XYZ".index(c)) for c in order]], order, degrees=True)
    translations = np.broadcast_to(np.array(offsets), (n, J, 3)).copy()
    translations[:, 0] = rpos
    return Clip(joint_names=names, parents=parents, offsets=np.array(offsets),
                rest_rotations=quat.identity((J,)), rotations=rotations, translations=translations,
                fps=float(fps), end_parents=np.array(end_parents, dtype=np.int32),
                end_offsets=np.array(end_offsets).reshape(-1, 3),
                name=str(doc.get("name", os.path.splitext(os.path.basename(p))[0])), source=p,
                meta={"format": "keyframes (TOML)", "keys": len(keys), "cycles": cycles, "loop": loop})
