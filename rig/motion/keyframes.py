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

Physical ranges, refused with the file, line and field: fps in (0, 10000]; cycles in [1, 100000]; an
offset or root position over 1 km; a clip over 200,000 frames (fps x key span x cycles).
"""
from __future__ import annotations

import os

import numpy as np
from scipy.interpolate import CubicSpline

from jiggle.rig.base.errors import InputError
from jiggle.rig.base.tomlfile import read_toml
from jiggle.rig.motion import quat
from jiggle.rig.motion.clip import Clip

MAX_OFFSET = 1000.0     # metres: a longer joint offset or root position is refused
MAX_FPS = 10000.0       # frames per second
MAX_FRAMES = 200_000   # frames in the clip (fps x duration x cycles): 55 min at 60 fps
MAX_CYCLES = 100_000


class _Where:
    """Best-effort 1-based lines of keys in the file (tomllib gives none), for error messages:
    `line(key)` at the top, `line(key, "keys", k)` inside the k-th [[keys]] table (or its [keys.rotate])."""

    def __init__(self, path: str):
        try:
            with open(path, encoding="utf-8") as fh:
                self.text = fh.read().splitlines()
        except (OSError, UnicodeDecodeError):
            self.text = []

    def line(self, key: str, array: str | None = None, k: int = 0) -> int | None:
        seen, inside = -1, array is None
        for i, s in enumerate(self.text, 1):
            t = s.strip()
            if t.startswith("["):
                name = t.strip("[] \t").split("#")[0].strip().rstrip("]").strip()
                if t.startswith("[[") and name == array:
                    seen += 1
                    inside = seen == k
                    if inside and key == "":
                        return i
                elif array is None or not (inside and name.startswith(f"{array}.")):
                    inside = False
                continue
            if inside and t.split("=")[0].strip().strip('"\'') == key and "=" in t:
                return i
        return None


def _vec3(v, path: str, field: str, line: int | None = None, limit: float | None = None) -> np.ndarray:
    if isinstance(v, bool) or (isinstance(v, list) and any(isinstance(x, bool) for x in v)):
        raise InputError(f"expected 3 numbers, found {v!r}", path, line, field)
    try:
        a = np.array(v, dtype=float)
    except (TypeError, ValueError, OverflowError):
        raise InputError(f"expected 3 numbers, found {v!r}", path, line, field) from None
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise InputError(f"expected 3 finite numbers, found {v!r}", path, line, field)
    if limit is not None and not np.linalg.norm(a) <= limit:
        raise InputError(f"{np.linalg.norm(a):.4g} m long; expected at most {limit:g} m (metres, Z-up)", path, line,
                         field)
    return a


def _number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def read_keyframes(path: str | os.PathLike) -> Clip:
    """Read a keyframed TOML clip (see module docstring) into a :class:`Clip`."""
    p, doc = read_toml(path, "keyframe file")
    where = _Where(p)
    fps, order, loop, cycles = _parse_settings(doc, p, where)
    names, parents, offsets = _parse_joints(doc, p, where)
    end_parents, end_offsets = _parse_ends(doc, p, where, names)
    times, angles, root = _parse_keys(doc, p, where, names, offsets)
    frames = (times[-1] - times[0]) * cycles * fps
    if not frames <= MAX_FRAMES:
        raise InputError(f"the keys span {times[-1] - times[0]:.6g} s; at {fps:g} fps and {cycles} cycles that is "
                         f"{frames:.4g} frames, over the {MAX_FRAMES:,} a clip may have", p,
                         where.line("time", "keys", len(times) - 1), f"keys[{len(times) - 1}].time")
    times = np.array(times) - times[0]
    if loop and not (np.allclose(angles[0], angles[-1]) and np.allclose(root[0], root[-1])):
        raise InputError("a looping cycle must end on the pose it starts with", p, field="keys")
    rotations, translations = _sample(times, angles, root, offsets, fps, order, loop, cycles)
    J = len(names)
    return Clip(joint_names=names, parents=parents, offsets=np.array(offsets),
                rest_rotations=quat.identity((J,)), rotations=rotations, translations=translations,
                fps=float(fps), end_parents=np.array(end_parents, dtype=np.int32),
                end_offsets=np.array(end_offsets).reshape(-1, 3),
                name=str(doc.get("name", os.path.splitext(os.path.basename(p))[0])), source=p,
                meta={"format": "keyframes (TOML)", "keys": len(times), "cycles": cycles, "loop": loop})


def _parse_settings(doc: dict, p: str, where: _Where) -> tuple[float, str, bool, int]:
    """The top-level settings: (fps, euler order such as "XYZ", loop, cycles), checked."""
    fps = doc.get("fps", 60)
    if not _number(fps) or not np.isfinite(fps) or fps <= 0 or fps > MAX_FPS:
        raise InputError(f"expected a positive number of frames per second (at most {MAX_FPS:g}), found {fps!r}", p,
                         where.line("fps"), "fps")
    euler = doc.get("euler", "XYZ")
    order = euler.upper() if isinstance(euler, str) else ""
    if sorted(order) != ["X", "Y", "Z"]:
        raise InputError(f"expected a permutation of XYZ, found {euler!r}", p, where.line("euler"), "euler")
    loop = doc.get("loop", False)
    if not isinstance(loop, bool):
        raise InputError(f"expected true or false, found {loop!r}", p, where.line("loop"), "loop")
    cycles = doc.get("cycles", 1)
    if not isinstance(cycles, int) or isinstance(cycles, bool) or not 1 <= cycles <= MAX_CYCLES:
        raise InputError(f"expected a whole number in [1, {MAX_CYCLES}], found {cycles!r}", p, where.line("cycles"),
                         "cycles")
    return fps, order, loop, cycles


def _parse_joints(doc: dict, p: str, where: _Where) -> tuple[list[str], list[int], list[np.ndarray]]:
    """The ``[[joints]]``: names, parent indices (-1 for the root) and offsets, each (3,) metres."""
    joints = doc.get("joints")
    if not isinstance(joints, list) or not joints:
        raise InputError("expected a list of [[joints]] tables", p, where.line("joints"), "joints")
    names, parents, offsets = [], [], []
    for k, j in enumerate(joints):
        if not isinstance(j, dict) or not isinstance(j.get("name"), str):
            raise InputError("each joint needs a name", p, where.line("", "joints", k), f"joints[{k}]")
        if j["name"] in names:
            raise InputError(f"joint name {j['name']!r} appears twice", p, where.line("name", "joints", k),
                             f"joints[{k}].name")
        par = j.get("parent", "")
        if not isinstance(par, str) or (par and par not in names):
            raise InputError(f"parent {par!r} is not a joint listed before it", p, where.line("parent", "joints", k),
                             f"joints[{k}].parent")
        names.append(j["name"])
        parents.append(names.index(par) if par else -1)
        offsets.append(_vec3(j.get("offset", [0, 0, 0]), p, f"joints[{k}].offset", where.line("offset", "joints", k),
                             MAX_OFFSET))
    return names, parents, offsets


def _parse_ends(doc: dict, p: str, where: _Where, names: list[str]) -> tuple[list[int], list[np.ndarray]]:
    """The ``[[ends]]``: parent joint indices and offsets, each (3,) metres."""
    ends = doc.get("ends", [])
    if not isinstance(ends, list):
        raise InputError("expected a list of [[ends]] tables", p, where.line("ends"), "ends")
    end_parents, end_offsets = [], []
    for k, e in enumerate(ends):
        if not isinstance(e, dict) or not isinstance(e.get("parent"), str) or e.get("parent") not in names:
            got = e.get("parent") if isinstance(e, dict) else e
            raise InputError(f"parent {got!r} is not a joint", p, where.line("parent", "ends", k), f"ends[{k}].parent")
        end_parents.append(names.index(e["parent"]))
        end_offsets.append(_vec3(e.get("offset"), p, f"ends[{k}].offset", where.line("offset", "ends", k),
                                 MAX_OFFSET))
    return end_parents, end_offsets


def _parse_keys(doc: dict, p: str, where: _Where, names: list[str], offsets: list[np.ndarray]
                ) -> tuple[list[float], np.ndarray, np.ndarray]:
    """The ``[[keys]]``: times (K,) seconds, increasing; joint angles (K, J, 3) degrees (zero where
    a key omits a joint); root positions (K, 3) metres (the root's offset where a key omits it)."""
    keys = doc.get("keys")
    if not isinstance(keys, list) or len(keys) < 2:
        raise InputError("expected at least two [[keys]]", p, where.line("keys"), "keys")
    times = []
    angles = np.zeros((len(keys), len(names), 3))
    root = np.zeros((len(keys), 3))
    for k, key in enumerate(keys):
        if not isinstance(key, dict):
            raise InputError(f"expected a [[keys]] table, found {key!r}", p, where.line("keys"), f"keys[{k}]")
        t = key.get("time")
        if not _number(t) or not np.isfinite(t):
            raise InputError(f"expected a time in seconds, found {t!r}", p, where.line("time", "keys", k),
                             f"keys[{k}].time")
        if times and t <= times[-1]:
            raise InputError(f"key times must increase ({t} after {times[-1]})", p, where.line("time", "keys", k),
                             f"keys[{k}].time")
        times.append(float(t))
        root[k] = (_vec3(key["root"], p, f"keys[{k}].root", where.line("root", "keys", k), MAX_OFFSET)
                   if "root" in key else offsets[0])
        rotate = key.get("rotate", {})
        if not isinstance(rotate, dict):
            raise InputError(f"expected a table of joint = [x, y, z] degrees, found {rotate!r}", p,
                             where.line("rotate", "keys", k), f"keys[{k}].rotate")
        for jn, a in rotate.items():
            if jn not in names:
                raise InputError(f"no joint named {jn!r}", p, where.line(jn, "keys", k), f"keys[{k}].rotate.{jn}")
            angles[k, names.index(jn)] = _vec3(a, p, f"keys[{k}].rotate.{jn}", where.line(jn, "keys", k))
    return times, angles, root


def _sample(times: np.ndarray, angles: np.ndarray, root: np.ndarray, offsets: list[np.ndarray], fps: float,
            order: str, loop: bool, cycles: int) -> tuple[np.ndarray, np.ndarray]:
    """Spline the keys (times (K,) seconds from 0, angles (K, J, 3) degrees, root (K, 3) metres)
    at `fps` over `cycles` plays: local rotations (n, J, 4) and translations (n, J, 3) metres."""
    bc = "periodic" if loop else "natural"
    period = times[-1]
    n = int(np.floor(period * cycles * fps + 1e-9)) + 1
    t = np.arange(n) / fps
    local_t = np.mod(t, period) if loop else np.minimum(t, period)
    if loop and cycles > 0:
        local_t[-1] = period if abs(t[-1] - period * cycles) < 1e-9 else local_t[-1]
    J = angles.shape[1]
    ang = CubicSpline(times, angles.reshape(len(times), -1), bc_type=bc)(local_t).reshape(n, J, 3)
    rpos = CubicSpline(times, root, bc_type=bc)(local_t)
    rotations = quat.from_euler(ang[..., [("XYZ".index(c)) for c in order]], order, degrees=True)
    translations = np.broadcast_to(np.array(offsets), (n, J, 3)).copy()
    translations[:, 0] = rpos
    return rotations, translations
