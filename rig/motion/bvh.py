"""BVH (Biovision hierarchy) reader.

Supports any hierarchy (several ROOTs too), any channel order and count per joint (0-6 channels,
position channels on any joint), End Sites, and the MOTION block.

Readings where the format is loose, stated once here:
- Rotation channels compose in the order listed, as intrinsic rotations: "Zrotation Yrotation
  Xrotation" is R = Rz @ Ry @ Rx acting on column vectors.
- Position channels give the joint's whole local translation and replace its OFFSET (MotionBuilder
  and the CMU conversion write them that way); an axis without a channel keeps the OFFSET value.
  The local transform is translate(position) then rotate.
- Axes: files are Y-up unless `up="z"`; Y-up is turned into jiggle's Z-up by a +90 degree rotation
  about X: (x, y, z) -> (x, -z, y).
- Units: `scale` is metres per file unit. By default the CMU conversion (recognised by its joint
  names LHipJoint/RHipJoint/LowerBack) gets 0.056444 m; otherwise the unit is guessed from the
  rest-pose height (>= 400 units: millimetres, >= 20: centimetres, else metres) and recorded in
  ``clip.meta["units"]``. Pass `scale` for anything else.
- Frame rate: 1 / Frame Time, snapped to a whole number when within 1e-4 of one (files print
  0.0083333 for 120 fps).
- Physical ranges, refused with the line: a Frame Time <= 0, non-finite or outside [1e-6, 3600] s; an
  OFFSET (or a position channel value) over 1 km once scaled to metres.
- T-pose: the CMU conversion prepends a T-pose frame. With ``tpose="auto"`` (default) the first frame
  is dropped when it looks added: all its rotation values are whole degrees, and the mean change
  over rotation channels from it to the second frame is over 2 degrees and over 5 times the 95th
  percentile of that mean change between frames in the next second of motion. ``"skip"`` always drops frame 1, ``"keep"`` never does.
  ``clip.meta["tpose"]`` says what happened.
"""
from __future__ import annotations

import os

import numpy as np

from jiggle.rig.base.errors import InputError, require_file
from jiggle.rig.motion import quat
from jiggle.rig.motion.clip import Clip

CMU_UNIT = 0.056444  # metres per CMU BVH unit (1/0.45 inch)
MAX_OFFSET = 1000.0  # metres: a longer OFFSET (or position channel) is a broken file or a wrong unit
MIN_FRAME_TIME, MAX_FRAME_TIME = 1e-6, 3600.0  # seconds: a million fps to one frame an hour
_ROT = {"xrotation": "X", "yrotation": "Y", "zrotation": "Z"}
_POS = {"xposition": 0, "yposition": 1, "zposition": 2}
Y_TO_Z_UP = quat.from_axis_angle(np.array([1.0, 0.0, 0.0]), np.pi / 2)  # (x,y,z) -> (x,-z,y)


class _Joint:
    __slots__ = ("name", "parent", "offset", "channels", "line", "offset_line")

    def __init__(self, name, parent, line):
        self.name, self.parent, self.line = name, parent, line
        self.offset, self.offset_line = None, line
        self.channels: list[str] = []


def _number(tok: str, path: str, line: int, what: str) -> float:
    try:
        v = float(tok)
    except ValueError:
        raise InputError(f"expected a number for {what}, found {tok!r}", path, line) from None
    if not np.isfinite(v):
        raise InputError(f"{what} is {tok}, expected a finite number", path, line)
    return v


def _parse_hierarchy(lines: list[str], path: str) -> tuple[list[_Joint], list[tuple[int, np.ndarray, int]], int]:
    """Parse HIERARCHY up to MOTION. Returns joints, end sites (joint index, offset, OFFSET line) and
    the 0-based index of the MOTION line."""
    joints: list[_Joint] = []
    ends: list[tuple[int, np.ndarray, int]] = []
    stack: list[object] = []  # _Joint index, or ("end", parent, [offset]) for End Sites
    pending = None  # a node opened by ROOT/JOINT/End Site, waiting for "{"
    seen_hierarchy = False
    i = 0
    n = len(lines)
    while i < n:
        ln = i + 1
        toks = lines[i].split()
        i += 1
        if not toks:
            continue
        key = toks[0].upper()
        if not seen_hierarchy:
            if key != "HIERARCHY":
                raise InputError(f"expected 'HIERARCHY' at the start of a BVH file, found {toks[0]!r}", path, ln)
            seen_hierarchy = True
            continue
        if key == "MOTION":
            if stack or pending is not None:
                raise InputError("MOTION reached before every '{' of the hierarchy was closed", path, ln)
            if not joints:
                raise InputError("the hierarchy defines no joint (expected ROOT name { ... })", path, ln)
            return joints, ends, i - 1
        if pending is not None:
            if toks != ["{"]:
                raise InputError(f"expected '{{' after {pending[0]}, found {lines[i - 1].strip()!r}", path, ln)
            stack.append(pending[1])
            pending = None
            continue
        if key in ("ROOT", "JOINT"):
            if len(toks) < 2:
                raise InputError(f"{toks[0]} needs a name", path, ln)
            if key == "ROOT" and stack:
                raise InputError("ROOT inside another joint (expected JOINT)", path, ln)
            if key == "JOINT" and (not stack or not isinstance(stack[-1], int)):
                raise InputError("JOINT outside a ROOT or JOINT block", path, ln)
            name = " ".join(toks[1:])
            if any(j.name == name for j in joints):
                raise InputError(f"joint name {name!r} appears twice", path, ln)
            parent = stack[-1] if stack else -1
            joints.append(_Joint(name, parent, ln))
            pending = (f"{toks[0]} {name}", len(joints) - 1)
        elif key == "END":
            if len(toks) < 2 or toks[1].upper() != "SITE" or not stack or not isinstance(stack[-1], int):
                raise InputError("expected 'End Site' inside a joint block", path, ln)
            pending = ("End Site", ["end", stack[-1], None, ln])
        elif key == "OFFSET":
            if not stack:
                raise InputError("OFFSET outside a joint block", path, ln)
            if len(toks) != 4:
                raise InputError(f"OFFSET needs 3 numbers, found {len(toks) - 1}", path, ln)
            off = np.array([_number(t, path, ln, "OFFSET") for t in toks[1:]])
            top = stack[-1]
            if isinstance(top, int):
                joints[top].offset, joints[top].offset_line = off, ln
            else:
                top[2], top[3] = off, ln
        elif key == "CHANNELS":
            top = stack[-1] if stack else None
            if not isinstance(top, int):
                raise InputError("CHANNELS outside a joint block", path, ln)
            if len(toks) < 2:
                raise InputError("CHANNELS needs a count", path, ln)
            try:
                count = int(toks[1])
            except ValueError:
                raise InputError(f"CHANNELS count must be an integer, found {toks[1]!r}", path, ln) from None
            names = [t.lower() for t in toks[2:]]
            if count != len(names):
                raise InputError(f"CHANNELS says {count} but lists {len(names)} channel names", path, ln)
            if count > 6:
                raise InputError(f"a joint has at most 6 channels, found {count}", path, ln)
            for t in names:
                if t not in _ROT and t not in _POS:
                    raise InputError(f"unknown channel {t!r}; expected X/Y/Z position or rotation", path, ln)
            if len(set(names)) != len(names):
                raise InputError("a channel is listed twice", path, ln)
            joints[top].channels = names
        elif key == "}":
            if not stack:
                raise InputError("'}' without a matching '{'", path, ln)
            top = stack.pop()
            if isinstance(top, int):
                if joints[top].offset is None:
                    raise InputError(f"joint {joints[top].name!r} has no OFFSET", path, joints[top].line)
            else:
                if top[2] is None:
                    raise InputError("End Site has no OFFSET", path, ln)
                ends.append((top[1], top[2], top[3]))
        elif key == "{":
            raise InputError("'{' without ROOT, JOINT or End Site before it", path, ln)
        else:
            raise InputError(f"unexpected {toks[0]!r} in the hierarchy", path, ln)
    raise InputError("file ends before its MOTION block (truncated?)", path, n)


def _parse_motion(lines: list[str], start: int, n_channels: int,
                  path: str) -> tuple[np.ndarray, float, list[int]]:
    """Parse 'Frames:', 'Frame Time:' and the frame lines. Returns (F, C) values, frame time and the
    1-based line of each frame."""
    def header(idx: int, label: str) -> tuple[str, int]:
        while idx < len(lines) and not lines[idx].strip():
            idx += 1
        if idx >= len(lines):
            raise InputError(f"file ends before '{label}' (truncated?)", path, len(lines))
        text = lines[idx].strip()
        if not text.lower().replace(" ", "").startswith(label.lower().replace(" ", "")):
            raise InputError(f"expected '{label} ...', found {text!r}", path, idx + 1)
        return text.split(":", 1)[1].strip(), idx

    val, i = header(start + 1, "Frames:")
    try:
        frames = int(val)
    except ValueError:
        raise InputError(f"'Frames:' needs a whole number, found {val!r}", path, i + 1) from None
    if frames <= 0:
        raise InputError(f"the file has {frames} frames; a clip needs at least one", path, i + 1)
    val, i = header(i + 1, "Frame Time:")
    dt = _number(val, path, i + 1, "Frame Time")
    if dt <= 0:
        raise InputError(f"Frame Time must be > 0 seconds, found {val}", path, i + 1)
    if dt < MIN_FRAME_TIME or dt > MAX_FRAME_TIME:
        raise InputError(f"{val} s is outside the physical range [{MIN_FRAME_TIME:g}, {MAX_FRAME_TIME:g}] "
                         f"seconds (expected e.g. 0.0083333 for 120 fps)", path, i + 1, "Frame Time")
    body = [(k + 1, ln) for k, ln in enumerate(lines[i + 1:], start=i + 1) if ln.strip()]
    if len(body) < frames:
        last = body[-1][0] if body else i + 1
        raise InputError(f"expected {frames} frame lines, found {len(body)} (truncated?)", path, last)
    if len(body) > frames:
        raise InputError(f"'Frames:' says {frames} but more frame lines follow", path, body[frames][0])
    counts = [len(ln.split()) for _, ln in body]
    for (ln_no, _), c in zip(body, counts):
        if c != n_channels:
            raise InputError(f"expected {n_channels} values (one per channel), found {c}", path, ln_no)
    try:
        data = np.array(" ".join(ln for _, ln in body).split(), dtype=np.float64).reshape(frames, n_channels)
    except ValueError:
        data = None
    if data is None or not np.all(np.isfinite(data)):
        for ln_no, ln in body:
            for tok in ln.split():
                _number(tok, path, ln_no, "a channel value")
    return data, dt, [k for k, _ in body]


def _check_offsets(joints: list[_Joint], ends, data: np.ndarray, frame_lines: list[int], scale: float,
                   path: str) -> None:
    """InputError at the line of the first OFFSET (or frame line of a position channel) longer than
    MAX_OFFSET metres once scaled."""
    for j in joints:
        if not np.linalg.norm(j.offset) * scale <= MAX_OFFSET:
            raise InputError(f"OFFSET of joint {j.name!r} is {np.linalg.norm(j.offset) * scale:.4g} m long; "
                             f"expected at most {MAX_OFFSET:g} m (a wrong unit or a broken number?)",
                             path, j.offset_line, "OFFSET")
    for _, off, ln in ends:
        if not np.linalg.norm(off) * scale <= MAX_OFFSET:
            raise InputError(f"End Site OFFSET is {np.linalg.norm(off) * scale:.4g} m long; expected at most "
                             f"{MAX_OFFSET:g} m (a wrong unit or a broken number?)", path, ln, "OFFSET")
    col = 0
    for j in joints:
        for c in j.channels:
            if c in _POS:
                with np.errstate(over="ignore", invalid="ignore"):
                    bad = np.flatnonzero(~(np.abs(data[:, col]) * scale <= MAX_OFFSET))
                if bad.size:
                    raise InputError(f"{c} of joint {j.name!r} is {data[bad[0], col]:g} units "
                                     f"({abs(data[bad[0], col]) * scale:.4g} m); expected at most {MAX_OFFSET:g} m",
                                     path, frame_lines[bad[0]], c)
            col += 1


def _detect_tpose(rot_deg: np.ndarray, dt: float) -> bool:
    """rot_deg: (F, R) rotation channel values in degrees. True when frame 0 looks like an added T-pose."""
    if rot_deg.shape[0] < 3 or rot_deg.shape[1] == 0:
        return False
    f0 = rot_deg[0]
    if np.max(np.abs(f0 - np.round(f0))) > 1e-6:
        return False
    # Means over channels, so one channel wrapping through 180 degrees does not decide.
    jump = np.mean(np.abs(rot_deg[1] - f0))
    nxt = rot_deg[1:2 + max(3, int(round(1.0 / dt)))]
    typical = np.percentile(np.mean(np.abs(np.diff(nxt, axis=0)), axis=1), 95)
    return bool(jump > 2.0 and jump > 5.0 * typical)


def _snap_fps(dt: float) -> float:
    """1/dt, snapped to a whole number when the file printed dt with few digits (0.0083333 -> 120)."""
    fps = 1.0 / dt
    return float(round(fps)) if round(fps) > 0 and abs(fps - round(fps)) < 1e-4 * fps else fps


def read_bvh(path: str | os.PathLike, scale: float | None = None, up: str = "y",
             tpose: str = "auto") -> Clip:
    """Read a BVH file into a :class:`Clip` (Z-up, metres). See the module docstring for the readings.

    Parameters
    ----------
    path : the .bvh file.
    scale : metres per file unit, or None to recognise CMU / guess from height.
    up : "y" (default, as most BVH) or "z", the file's up axis.
    tpose : "auto", "skip" or "keep" for the first frame (see module docstring).
    """
    p = require_file(path, "BVH file")
    if up.lower() not in ("y", "z"):
        raise InputError(f"up must be 'y' or 'z', got {up!r}", field="up")
    if tpose not in ("auto", "skip", "keep"):
        raise InputError(f"tpose must be 'auto', 'skip' or 'keep', got {tpose!r}", field="tpose")
    if scale is not None and (not np.isfinite(scale) or scale <= 0):
        raise InputError(f"scale must be a positive number of metres per unit, got {scale}", field="scale")
    try:
        with open(p, "r", encoding="utf-8", errors="strict") as fh:
            text = fh.read()
    except UnicodeDecodeError as e:
        raise InputError(f"not a text file (byte {e.start} is not UTF-8); expected a BVH text file", p) from None
    lines = text.splitlines()
    joints, ends, motion_at = _parse_hierarchy(lines, p)
    n_channels = sum(len(j.channels) for j in joints)
    data, dt, frame_lines = _parse_motion(lines, motion_at, n_channels, p)

    J, F = len(joints), data.shape[0]
    offsets = np.array([j.offset for j in joints])
    translations = np.broadcast_to(offsets, (F, J, 3)).copy()
    rotations = quat.identity((F, J))
    rot_cols = []
    by_order: dict[str, list[tuple[int, list[int]]]] = {}
    col = 0
    for ji, j in enumerate(joints):
        order, cols = "", []
        for c in j.channels:
            if c in _POS:
                translations[:, ji, _POS[c]] = data[:, col]
            else:
                order += _ROT[c]
                cols.append(col)
            col += 1
        rot_cols += cols
        if order:
            by_order.setdefault(order, []).append((ji, cols))
    for order, members in by_order.items():
        idx = [m[0] for m in members]
        angles = data[:, [c for m in members for c in m[1]]].reshape(F, len(idx), len(order))
        rotations[:, idx] = quat.from_euler(angles, order, degrees=True)

    skipped = False
    if tpose == "skip" or (tpose == "auto" and _detect_tpose(data[:, rot_cols], dt)):
        if F < 2:
            raise InputError("cannot skip the T-pose frame of a one-frame clip", p, field="tpose")
        rotations, translations, skipped = rotations[1:], translations[1:], True
    names = [j.name for j in joints]

    units = None
    if scale is None:
        if {"LHipJoint", "RHipJoint", "LowerBack"} <= set(names):
            scale, units = CMU_UNIT, f"CMU units ({CMU_UNIT} m)"
        else:
            from jiggle.rig.motion.clip import Clip as _C  # rest height in file units, before scaling
            tmp = _C(names, [j.parent for j in joints], offsets, quat.identity((J,)),
                     quat.identity((1, J)), offsets[None], 1.0)
            _, pos = tmp.rest_world()
            ax = 1 if up.lower() == "y" else 2
            h = float(np.ptp(pos[:, ax])) if J > 1 else 0.0
            scale, units = ((0.001, "millimetres") if h >= 400 else (0.01, "centimetres") if h >= 20
                            else (1.0, "metres"))
            units += f" (guessed from a rest height of {h:.4g} units)"
    else:
        units = f"{scale} m per unit (given)"

    _check_offsets(joints, ends, data, frame_lines, scale, p)
    end_parents = np.array([e[0] for e in ends], dtype=np.int32)
    end_offsets = np.array([e[1] for e in ends]).reshape(-1, 3)
    if up.lower() == "y":
        A = quat.to_matrix(Y_TO_Z_UP)
        offsets, translations, end_offsets = offsets @ A.T, translations @ A.T, end_offsets @ A.T
        rotations = quat.mul(quat.mul(Y_TO_Z_UP, rotations), quat.conj(Y_TO_Z_UP))
    meta = {"format": "BVH", "units": units, "metres_per_unit": scale, "up": up.lower(),
            "channels": n_channels, "frames_in_file": F,
            "tpose": ("detected and skipped" if skipped and tpose == "auto" else
                      "skipped (tpose='skip')" if skipped else
                      "kept (tpose='keep')" if tpose == "keep" else "none detected")}
    return Clip(joint_names=names, parents=[j.parent for j in joints], offsets=offsets * scale,
                rest_rotations=quat.identity((J,)), rotations=rotations, translations=translations * scale,
                fps=_snap_fps(dt), end_parents=end_parents, end_offsets=end_offsets * scale,
                name=os.path.splitext(os.path.basename(p))[0], source=p, meta=meta)
