"""Acclaim ASF/AMC reader (the format CMU publishes its motion capture in).

An ``.asf`` file holds the skeleton (units, root, bones, hierarchy); an ``.amc`` file holds the motion
for one skeleton (one block per frame: the frame number, then one line per bone with its dof values).

Readings where the format is loose, stated once here:

- Units: ``:units length L`` means a file unit is 1/L inches, so metres per unit = 0.0254 / L (CMU's
  0.45 gives 0.056444 m). ``angle deg|rad`` is the unit of the ASF's angles (``axis``, root
  ``orientation``, rotational ``limits``); the AMC's angles follow its own ``:DEGREES``/``:RADIANS``
  (degrees when absent). ``mass`` is ignored. Physical range: a file unit, the root position or a
  bone length over 1 km (MAX_OFFSET) is refused at its line.
- A bone's ``axis ax ay az ORDER`` gives the three angles about x, y and z, applied in ``ORDER``
  (first letter first) as rotations of column vectors: ``XYZ`` is C = Rz(az) Ry(ay) Rx(ax).
- A bone's AMC rotation values are listed in its ``dof`` order, but always compose as
  M = Rz Ry Rx (rx applied first); dofs the bone lacks are zero. Its local rotation in jiggle is
  L = C M C^-1 in a joint frame that is world-aligned at rest (so ``rest_rotations`` are identity).
- The root's ``order`` (e.g. ``TX TY TZ RX RY RZ``) gives both the column order of its AMC values and
  the order its rotations apply (first listed first); its ``orientation`` angles apply in its
  ``axis`` order and give C for the root, as for a bone. Its translation is the AMC tx/ty/tz (an
  axis without a value keeps the ASF ``position``).
- Bone translations: ``tx ty tz`` dofs move the bone's start in its axis frame C (file units);
  ``l`` lengthens the bone along its direction (its children follow; end sites keep the rest
  length, since a Clip's end offsets are fixed).
- Clip layout: a joint named ``root`` for the root, then one joint per bone in hierarchy order
  (depth first, children in the order the hierarchy lists them), each located at the START of its
  bone. A child of ``root`` sits at the root; a child of bone b sits at b's tip
  (direction * length, in b's rest frame). Leaf bones get an end site at their tip.
- Every AMC frame must list every bone that has dofs, once (what ``:FULLY-SPECIFIED`` declares; a
  file without the keyword is read the same way); frame numbers must count up by one.
- Axes: ASF/AMC are Y-up; like ``rig.motion.bvh`` the data are turned into jiggle's Z-up by a +90 degree
  rotation about X, (x, y, z) -> (x, -z, y).
"""
from __future__ import annotations

import glob
import numbers
import os
from dataclasses import dataclass

import numpy as np

from jiggle.rig.base.errors import InputError, require_file
from jiggle.rig.base.frozen import frozen_array
from jiggle.rig.motion import quat
from jiggle.rig.motion.bvh import Y_TO_Z_UP
from jiggle.rig.motion.clip import Clip

INCH = 0.0254  # metres
MAX_OFFSET = 1000.0  # metres: a longer root position or bone (or a larger file unit) is refused
CMU_FPS = 120.0  # CMU captured at 120 frames per second; AMC files do not store a rate
_DOFS = ("rx", "ry", "rz", "tx", "ty", "tz", "l")
_AXES = "XYZ"


# ---------------------------------------------------------------------------------------- types
@dataclass(frozen=True, eq=False)
class AsfRoot:
    """The ``:root`` section.

    order : AMC column order of the root's values, e.g. ("tx", "ty", "tz", "rx", "ry", "rz").
    axis : order in which ``orientation`` angles apply, e.g. "XYZ" (first letter first).
    position : (3,) float64, file units, Y-up, rest position of the root.
    orientation : (3,) float64, radians, rotation angles about x, y, z of the root's axis frame.
    """

    order: tuple[str, ...]
    axis: str
    position: np.ndarray
    orientation: np.ndarray


@dataclass(frozen=True, eq=False)
class AsfBone:
    """One ``begin ... end`` block of ``:bonedata``.

    id : the file's id (or -1 when absent).
    name : bone name.
    direction : (3,) float64, unit vector, Y-up, direction from the bone's start to its tip at rest.
    length : file units (>= 0).
    axis : (3,) float64, radians, angles about x, y, z of the bone's axis frame C.
    axis_order : order those angles apply, e.g. "XYZ" (first letter first).
    dof : dof names in AMC column order, a subset of rx ry rz tx ty tz l.
    limits : one (low, high) per dof, radians for rotations and file units for translations
        (may be +-inf); empty when the file gives none.
    line : 1-based line of the block's ``begin``.
    """

    id: int
    name: str
    direction: np.ndarray
    length: float
    axis: np.ndarray
    axis_order: str
    dof: tuple[str, ...]
    limits: tuple[tuple[float, float], ...]
    line: int


@dataclass(frozen=True, eq=False)
class AsfSkeleton:
    """A parsed ASF skeleton.

    name : the ``:name`` (or the file stem).
    path : the file read.
    metres_per_unit : 0.0254 / (``:units length``).
    angle_unit : "deg" or "rad", the unit the ASF's own angles were written in.
    root : the root section.
    bones : bones in clip order (depth first over the hierarchy, parents before children).
    parents : parent of each bone, an index into `bones`, or -1 for a child of the root.
    """

    name: str
    path: str
    metres_per_unit: float
    angle_unit: str
    root: AsfRoot
    bones: tuple[AsfBone, ...]
    parents: tuple[int, ...]

    @property
    def bone_names(self) -> tuple[str, ...]:
        return tuple(b.name for b in self.bones)

    def bone(self, name: str) -> AsfBone:
        for b in self.bones:
            if b.name == name:
                return b
        raise InputError(f"the skeleton has no bone {name!r}", self.path, field="bone")

    # ------------------------------------------------------------------ clip layout (Y-up, file units)
    def _layout(self):
        """Joint names, parents, rest offsets (J, 3) in file units Y-up, axis frames C (J, 4),
        end sites (joint, offset) in file units Y-up."""
        B = len(self.bones)
        names = ["root"] + [b.name for b in self.bones]
        parents = [-1] + [p + 1 for p in self.parents]  # joint 0 is the root
        offsets = np.zeros((B + 1, 3))
        offsets[0] = self.root.position
        tips = np.array([b.direction * b.length for b in self.bones]).reshape(B, 3)
        for i, p in enumerate(self.parents):
            offsets[i + 1] = 0.0 if p < 0 else tips[p]
        axes = np.empty((B + 1, 4))
        axes[0] = _euler(self.root.orientation, self.root.axis)
        for i, b in enumerate(self.bones):
            axes[i + 1] = _euler(b.axis, b.axis_order)
        has_child = np.zeros(B, bool)
        has_child[[p for p in self.parents if p >= 0]] = True
        ends = [(i + 1, tips[i]) for i in range(B) if not has_child[i]]
        return names, parents, offsets, axes, ends

    def rest_clip(self) -> Clip:
        """A one-frame :class:`Clip` of the rest pose (every dof zero), Z-up, metres."""
        names, parents, offsets, _, ends = self._layout()
        J = len(names)
        return _make_clip(self, names, parents, offsets, quat.identity((1, J)), offsets[None].copy(),
                          ends, CMU_FPS, os.path.splitext(os.path.basename(self.path))[0], self.path,
                          {"format": "ASF", "frames_in_file": 0})


def _euler(angles_xyz: np.ndarray, order: str) -> np.ndarray:
    """Quaternion(s) (..., 4) for angles (..., 3) about x, y, z in radians, applied in `order`
    (first letter first, e.g. "XYZ" -> Rz Ry Rx)."""
    a = np.asarray(angles_xyz, float)
    idx = [_AXES.index(c) for c in order]
    # quat.from_euler(..., "ZYX") is Rz @ Ry @ Rx: reverse the application order.
    return quat.from_euler(a[..., idx[::-1]], order[::-1], degrees=False)


def _rzryrx(ang: np.ndarray) -> np.ndarray:
    """Quaternions (..., 4) of M = Rz(az) Ry(ay) Rx(ax) for angles (..., 3) = (ax, ay, az) in
    radians. The product of the three half-angle quaternions written out: ~10x faster than
    SciPy's from_euler on the 80k rotations of a long AMC."""
    h = 0.5 * np.asarray(ang, float)
    cx, cy, cz = np.moveaxis(np.cos(h), -1, 0)
    sx, sy, sz = np.moveaxis(np.sin(h), -1, 0)
    return np.stack([cz * cy * cx + sz * sy * sx,
                     cz * cy * sx - sz * sy * cx,
                     cz * sy * cx + sz * cy * sx,
                     sz * cy * cx - cz * sy * sx], axis=-1)


def _make_clip(asf: AsfSkeleton, names, parents, offsets, rotations, translations, ends, fps,
               name, source, meta) -> Clip:
    """Scale to metres and turn Y-up into Z-up, as rig.motion.bvh does."""
    s = asf.metres_per_unit
    A = quat.to_matrix(Y_TO_Z_UP)
    end_parents = np.array([e[0] for e in ends], dtype=np.int32)
    end_offsets = np.array([e[1] for e in ends]).reshape(-1, 3)
    rotations = quat.mul(quat.mul(Y_TO_Z_UP, rotations), quat.conj(Y_TO_Z_UP))
    meta = {**meta, "units": f"{s:.6g} m per unit (ASF length {INCH / s:.6g})", "metres_per_unit": s,
            "up": "y", "skeleton": asf.path}
    with np.errstate(over="ignore", invalid="ignore"):  # huge values become inf; Clip rejects them
        return Clip(joint_names=names, parents=parents, offsets=(offsets @ A.T) * s,
                    rest_rotations=quat.identity((len(names),)), rotations=rotations,
                    translations=(translations @ A.T) * s, fps=fps, end_parents=end_parents,
                    end_offsets=(end_offsets @ A.T) * s, name=name, source=source, meta=meta)


# ---------------------------------------------------------------------------------------- ASF
def _read_text(path: str, what: str) -> list[str]:
    try:
        with open(path, "r", encoding="utf-8", errors="strict") as fh:
            return fh.read().splitlines()
    except UnicodeDecodeError as e:
        raise InputError(f"not a text file (byte {e.start} is not UTF-8); expected an {what} text file",
                         path) from None
    except OSError as e:
        raise InputError(f"cannot read the {what}: {e.strerror}", path) from None


def _num(tok: str, path: str, line: int, what: str, allow_inf: bool = False) -> float:
    try:
        v = float(tok)
    except ValueError:
        raise InputError(f"expected a number, found {tok!r}", path, line, what) from None
    if np.isnan(v) or (not allow_inf and not np.isfinite(v)):
        raise InputError(f"{tok} is not a finite number", path, line, what)
    return v


def _nums(toks: list[str], n: int, path: str, line: int, what: str) -> np.ndarray:
    if len(toks) != n:
        raise InputError(f"expected {n} numbers, found {len(toks)}", path, line, what)
    return np.array([_num(t, path, line, what) for t in toks])


def _order(tok: str, path: str, line: int, what: str) -> str:
    o = tok.upper()
    if len(o) != 3 or sorted(o) != ["X", "Y", "Z"]:
        raise InputError(f"expected a rotation order such as XYZ, found {tok!r}", path, line, what)
    return o


def read_asf(path: str | os.PathLike) -> AsfSkeleton:
    """Read an Acclaim skeleton file. See the module docstring for the readings."""
    p = require_file(path, "ASF skeleton file")
    lines = _read_text(p, "ASF")
    sections, section_line = _asf_sections(lines, p)
    length_unit, angle_unit = _parse_units(sections.get("units", []), p)
    to_rad = np.pi / 180.0 if angle_unit == "deg" else 1.0
    root = _parse_root(sections["root"], p, to_rad, length_unit, section_line["root"])
    bones = _parse_bones(sections["bonedata"], p, to_rad, INCH / length_unit)
    by_name = {b.name: k for k, b in enumerate(bones)}
    if "root" in by_name:
        raise InputError("a bone is named 'root', the name of the root", p, bones[by_name["root"]].line,
                         "name")
    children, child_line = _parse_hierarchy(sections["hierarchy"], p, by_name)
    order_out, parents = _depth_first(children, by_name, bones, child_line, p)
    name = " ".join(sections["name"][0][1]) if sections.get("name") else ""
    return AsfSkeleton(name=name or os.path.splitext(os.path.basename(p))[0], path=p,
                       metres_per_unit=INCH / length_unit, angle_unit=angle_unit, root=root,
                       bones=tuple(bones[k] for k in order_out), parents=tuple(parents))


def _asf_sections(lines: list[str], p: str) -> tuple[dict[str, list[tuple[int, list[str]]]], dict[str, int]]:
    """The file's ``:section`` blocks: {section: [(1-based line, tokens), ...]} without comments, and
    the line each section starts on. InputError when a section repeats or a required one is absent."""
    sections: dict[str, list[tuple[int, list[str]]]] = {}
    section_line: dict[str, int] = {}
    current = None
    for i, raw in enumerate(lines):
        text = raw.split("#", 1)[0]
        toks = text.split()
        if not toks:
            continue
        if toks[0].startswith(":"):
            current = toks[0][1:].lower()
            if current in sections and current != "documentation":
                raise InputError(f"section :{current} appears twice", p, i + 1)
            sections.setdefault(current, [])
            section_line.setdefault(current, i + 1)
            if len(toks) > 1:  # ":name VICON", ":version 1.10": the value on the same line
                sections[current].append((i + 1, toks[1:]))
            continue
        if current is None:
            raise InputError(f"expected a section such as ':units' before {toks[0]!r}", p, i + 1)
        sections[current].append((i + 1, toks))
    for need in ("root", "bonedata", "hierarchy"):
        if need not in sections:
            raise InputError(f"the file has no :{need} section; expected an Acclaim ASF skeleton", p,
                             len(lines) or None)
    return sections, section_line


def _parse_units(rows: list[tuple[int, list[str]]], p: str) -> tuple[float, str]:
    """The ``:units`` section: (file units per inch, "deg" or "rad"); defaults 1.0 and "deg"."""
    length_unit, angle_unit = 1.0, "deg"
    for ln, toks in rows:
        key = toks[0].lower()
        if key not in ("length", "angle", "mass"):
            continue
        if len(toks) != 2:
            raise InputError(f"expected ':units {key} <value>'", p, ln, f"units {key}")
        if key == "length":
            length_unit = _num(toks[1], p, ln, "units length")
            if length_unit <= 0:
                raise InputError(f"length must be > 0 (file units per inch), found {toks[1]}", p, ln,
                                 "units length")
            if not INCH / length_unit <= MAX_OFFSET:
                raise InputError(f"length {toks[1]} makes a file unit {INCH / length_unit:.4g} m; expected at most "
                                 f"{MAX_OFFSET:g} m", p, ln, "units length")
        elif key == "angle":
            angle_unit = toks[1].lower()
            if angle_unit not in ("deg", "rad"):
                raise InputError(f"unknown angle unit {toks[1]!r}; expected 'deg' or 'rad'", p, ln,
                                 "units angle")
    return length_unit, angle_unit


def _parse_root(rows: list[tuple[int, list[str]]], p: str, to_rad: float, length_unit: float,
                section_line: int) -> AsfRoot:
    """The ``:root`` section; `to_rad` converts the ASF's angles to radians, `length_unit` is file
    units per inch and `section_line` the section's 1-based line (for a missing ``order``)."""
    order, axis, position, orientation = None, "XYZ", np.zeros(3), np.zeros(3)
    for ln, toks in rows:
        key = toks[0].lower()
        if key == "order":
            order = tuple(t.lower() for t in toks[1:])
            bad = [t for t in order if t not in ("tx", "ty", "tz", "rx", "ry", "rz")]
            if bad or len(set(order)) != len(order):
                raise InputError(f"root order must list distinct TX TY TZ RX RY RZ, found "
                                 f"{' '.join(toks[1:])!r}", p, ln, "root order")
        elif key == "axis":
            if len(toks) != 2:
                raise InputError("expected 'axis' and an order such as XYZ", p, ln, "root axis")
            axis = _order(toks[1], p, ln, "root axis")
        elif key == "position":
            position = _nums(toks[1:], 3, p, ln, "root position")
            _check_length(float(np.linalg.norm(position)) * INCH / length_unit, p, ln, "root position")
        elif key == "orientation":
            orientation = _nums(toks[1:], 3, p, ln, "root orientation") * to_rad
        else:
            raise InputError(f"unknown root field {toks[0]!r}; expected order, axis, position or "
                             f"orientation", p, ln, "root")
    if order is None:
        raise InputError("the :root section has no 'order'", p, section_line, "root order")
    return AsfRoot(order, axis, frozen_array(position), frozen_array(orientation))


def _parse_hierarchy(rows: list[tuple[int, list[str]]], p: str, by_name: dict[str, int]
                     ) -> tuple[dict[str, list[str]], dict[str, int]]:
    """The ``:hierarchy`` section: {parent name: [child names in file order]} and the 1-based line
    naming each child. InputError for an unknown bone or a bone given two parents."""
    children: dict[str, list[str]] = {}
    child_line: dict[str, int] = {}
    opened = False
    for ln, toks in rows:
        key = toks[0].lower()
        if key == "begin" and len(toks) == 1:
            opened = True
            continue
        if key == "end" and len(toks) == 1:
            opened = False
            continue
        if not opened:
            raise InputError(f"expected 'begin' before {toks[0]!r}", p, ln, "hierarchy")
        parent = toks[0]
        if parent != "root" and parent not in by_name:
            raise InputError(f"unknown bone {parent!r} (not in :bonedata)", p, ln, "hierarchy")
        for c in toks[1:]:
            if c not in by_name:
                raise InputError(f"unknown bone {c!r} (not in :bonedata)", p, ln, "hierarchy")
            if c in child_line:
                raise InputError(f"bone {c!r} already has a parent (line {child_line[c]})", p, ln,
                                 "hierarchy")
            child_line[c] = ln
            children.setdefault(parent, []).append(c)
    return children, child_line


def _depth_first(children: dict[str, list[str]], by_name: dict[str, int], bones: list[AsfBone],
                 child_line: dict[str, int], p: str) -> tuple[list[int], list[int]]:
    """Clip order of the bones (indices into `bones`, depth first from the root, children in file
    order) and each one's parent as a position in that order (-1: a child of the root). InputError
    when a bone is not reached from the root."""
    order_out: list[int] = []
    parents: list[int] = []
    stack = [(c, -1) for c in reversed(children.get("root", []))]
    while stack:
        name, par = stack.pop()
        k = len(order_out)
        order_out.append(by_name[name])
        parents.append(par)
        stack += [(c, k) for c in reversed(children.get(name, []))]
    if len(order_out) != len(bones):
        lost = [b for b in bones if b.name not in {bones[k].name for k in order_out}]
        b = lost[0]
        at = child_line.get(b.name, b.line)
        raise InputError(f"bone {b.name!r} is not connected to the root in :hierarchy (a loop or a "
                         f"missing parent)", p, at, "hierarchy")
    return order_out, parents


def _check_length(metres: float, p: str, ln: int, what: str) -> None:
    """InputError at line `ln` when a length is beyond MAX_OFFSET metres (or not finite)."""
    if not metres <= MAX_OFFSET:
        raise InputError(f"{what} is {metres:.4g} m; expected at most {MAX_OFFSET:g} m (a wrong :units length or a "
                         f"broken number?)", p, ln, what)


def _parse_bones(rows: list[tuple[int, list[str]]], p: str, to_rad: float,
                 metres_per_unit: float = INCH) -> list[AsfBone]:
    bones: list[AsfBone] = []
    cur: dict | None = None
    pending_limits = 0  # limits still expected on the following lines
    for ln, toks in rows:
        key = toks[0].lower()
        if pending_limits and toks[0].startswith("("):
            _limits(cur, toks, p, ln, to_rad)
            pending_limits = len(cur["dof"]) - len(cur["limits"])
            continue
        if key == "begin" and len(toks) == 1:
            if cur is not None:
                raise InputError("'begin' inside a bone block (missing 'end')", p, ln, "bonedata")
            cur = {"line": ln, "id": -1, "name": None, "direction": None, "length": None,
                   "axis": np.zeros(3), "axis_order": "XYZ", "dof": (), "limits": []}
            continue
        if cur is None:
            raise InputError(f"expected 'begin' before {toks[0]!r}", p, ln, "bonedata")
        if pending_limits:
            raise InputError(f"expected {pending_limits} more limits '(low high)'", p, ln, "limits")
        if key == "end" and len(toks) == 1:
            bones.append(_finish_bone(cur, p, ln, bones))
            cur = None
        elif key == "id":
            if len(toks) != 2:
                raise InputError("expected 'id <number>'", p, ln, "id")
            try:
                cur["id"] = int(toks[1])
            except ValueError:
                raise InputError(f"expected a whole number, found {toks[1]!r}", p, ln, "id") from None
        elif key == "name":
            if len(toks) != 2:
                raise InputError("expected 'name <bone name>' (one word)", p, ln, "name")
            cur["name"] = toks[1]
        elif key == "direction":
            d = _nums(toks[1:], 3, p, ln, "direction")
            n = float(np.linalg.norm(d))
            cur["direction"] = (d / n if n > 0 else d, ln)
        elif key == "length":
            v = _nums(toks[1:], 1, p, ln, "length")[0]
            if v < 0:
                raise InputError(f"a bone length must be >= 0, found {toks[1]}", p, ln, "length")
            _check_length(float(v) * metres_per_unit, p, ln, "length")
            cur["length"] = v
        elif key == "axis":
            if len(toks) != 5:
                raise InputError("expected 'axis <x> <y> <z> <order>'", p, ln, "axis")
            cur["axis"] = _nums(toks[1:4], 3, p, ln, "axis") * to_rad
            cur["axis_order"] = _order(toks[4], p, ln, "axis")
        elif key == "dof":
            dof = tuple(t.lower() for t in toks[1:])
            bad = [t for t in dof if t not in _DOFS]
            if bad or len(set(dof)) != len(dof):
                raise InputError(f"dof must list distinct names among {' '.join(_DOFS)}, found "
                                 f"{' '.join(toks[1:])!r}", p, ln, "dof")
            cur["dof"] = dof
        elif key == "limits":
            if not cur["dof"]:
                raise InputError("limits before dof", p, ln, "limits")
            if len(toks) > 1:
                _limits(cur, toks[1:], p, ln, to_rad)
            pending_limits = len(cur["dof"]) - len(cur["limits"])
        elif key in ("bodymass", "cofmass"):
            continue  # dynamics hints, not used
        else:
            raise InputError(f"unknown bone field {toks[0]!r}", p, ln, "bonedata")
    if cur is not None:
        raise InputError("the last bone block has no 'end' (truncated?)", p, cur["line"], "bonedata")
    if pending_limits:
        raise InputError("file ends inside a limits list (truncated?)", p, rows[-1][0], "limits")
    return bones


def _limits(cur: dict, toks: list[str], p: str, ln: int, to_rad: float) -> None:
    """Parse one or more '(low high)' groups from a line's tokens into cur['limits']."""
    text = " ".join(toks).replace("(", " ( ").replace(")", " ) ").split()
    k = 0
    while k < len(text):
        if text[k] != "(" or k + 3 >= len(text) or text[k + 3] != ")":
            raise InputError(f"expected '(low high)', found {' '.join(toks)!r}", p, ln, "limits")
        if len(cur["limits"]) >= len(cur["dof"]):
            raise InputError(f"more limits than the {len(cur['dof'])} dofs", p, ln, "limits")
        lo = _num(text[k + 1], p, ln, "limits", allow_inf=True)
        hi = _num(text[k + 2], p, ln, "limits", allow_inf=True)
        dof = cur["dof"][len(cur["limits"])]
        f = to_rad if dof.startswith("r") else 1.0
        cur["limits"].append((lo * f, hi * f))
        k += 4


def _finish_bone(cur: dict, p: str, ln: int, bones: list[AsfBone]) -> AsfBone:
    for k in ("name", "direction", "length"):
        if cur[k] is None:
            raise InputError(f"bone block has no '{k}'", p, cur["line"], k)
    if any(b.name == cur["name"] for b in bones):
        raise InputError(f"bone name {cur['name']!r} appears twice", p, cur["line"], "name")
    d, dline = cur["direction"]
    if cur["length"] > 0 and not np.any(d):
        raise InputError("direction is the zero vector", p, dline, "direction")
    if cur["limits"] and len(cur["limits"]) != len(cur["dof"]):
        raise InputError(f"{len(cur['limits'])} limits for {len(cur['dof'])} dofs", p, ln, "limits")
    return AsfBone(id=cur["id"], name=cur["name"], direction=frozen_array(d), length=float(cur["length"]),
                   axis=frozen_array(cur["axis"]), axis_order=cur["axis_order"], dof=cur["dof"],
                   limits=tuple(cur["limits"]), line=cur["line"])


# ---------------------------------------------------------------------------------------- AMC
def find_asf(amc_path: str | os.PathLike) -> str:
    """The one ``.asf`` file in the folder of `amc_path`; InputError when there are none or several."""
    p = require_file(amc_path, "AMC motion file")
    folder = os.path.dirname(os.path.abspath(p))
    found = sorted(f for f in glob.glob(os.path.join(glob.escape(folder), "*"))
                   if f.lower().endswith(".asf") and os.path.isfile(f))
    if len(found) == 1:
        return found[0]
    what = "no .asf file" if not found else f"{len(found)} .asf files ({', '.join(map(os.path.basename, found))})"
    raise InputError(f"{what} beside the AMC; pass the skeleton explicitly (skeleton=path/to/file.asf)",
                     p, field="skeleton")


def read_amc(path: str | os.PathLike, asf: AsfSkeleton | str | os.PathLike,
             fps: float = CMU_FPS) -> Clip:
    """Read an AMC motion for the skeleton `asf` into a :class:`Clip` (Z-up, metres).

    Parameters
    ----------
    path : the .amc file.
    asf : an :class:`AsfSkeleton` or the path of its .asf file.
    fps : frames per second (AMC files do not store it; CMU captured at 120).

    Returns a Clip whose joints are ``root`` and the ASF bones (see the module docstring); fps as
    given; ``meta`` records the units and the skeleton file.
    """
    p = require_file(path, "AMC motion file")
    if not isinstance(asf, AsfSkeleton):
        asf = read_asf(asf)
    if not isinstance(fps, numbers.Real) or isinstance(fps, bool) or not np.isfinite(fps) or fps <= 0:
        raise InputError(f"fps must be a positive number, got {fps!r}", field="fps")
    lines = _read_text(p, "AMC")
    degrees, start = _amc_header(lines)
    table = _amc_table(lines, start, asf, p)
    to_rad = np.pi / 180.0 if degrees else 1.0
    names, parents, offsets, axes, ends = asf._layout()
    with np.errstate(over="ignore", invalid="ignore"):  # huge values -> inf; the Clip rejects them
        rotations, translations = _amc_motion(asf, table, to_rad, parents, offsets, axes)
        far = ~(np.abs(translations) * asf.metres_per_unit <= MAX_OFFSET).all(axis=2)
    if far.any():
        f, j = np.argwhere(far)[0]
        dist = np.linalg.norm(translations[f, j]) * asf.metres_per_unit
        raise InputError(f"frame {f + 1} places {names[j]!r} {dist:.4g} m from its parent (the origin for the "
                         f"root); expected at most {MAX_OFFSET:g} m (a broken number or a wrong :units length?)",
                         p, table.frame_lines[f], names[j])
    meta = {"format": "ASF/AMC", "frames_in_file": table.frames, "angles": "degrees" if degrees else "radians",
            "fps": f"{fps:g} (given)" if fps != CMU_FPS else f"{CMU_FPS:g} (CMU default)"}
    return _make_clip(asf, names, parents, offsets, rotations, translations, ends, fps,
                      os.path.splitext(os.path.basename(p))[0], p, meta)


def _amc_header(lines: list[str]) -> tuple[bool, int]:
    """(angles in degrees, index of the first line after the header): comments (#) and keywords (:)
    before the first frame number; ``:RADIANS``/``:DEGREES`` set the unit (degrees when absent)."""
    degrees = True
    start = len(lines)
    for i, raw in enumerate(lines):
        s = raw.strip()
        if not s or s.startswith("#"):
            continue
        if s.startswith(":"):
            key = s.split()[0].upper()
            if key == ":RADIANS":
                degrees = False
            elif key == ":DEGREES":
                degrees = True
            continue  # :FULLY-SPECIFIED and other flags
        start = i
        break
    return degrees, start


@dataclass(frozen=True, eq=False)
class _AmcTable:
    """An AMC's value lines, gathered per name, checked for layout but not yet parsed as numbers.

    rows : {name: [the values text of each frame]} for the root and each bone with dofs.
    ncols : {name: number of values per frame} for the root and every bone (0 for no dofs).
    frame_lines : 1-based line of each frame number.
    lines, start, path : the file's lines, the index of its first frame line, and its path.
    """

    rows: dict[str, list[str]]
    ncols: dict[str, int]
    frame_lines: list[int]
    lines: list[str]
    start: int
    path: str

    @property
    def frames(self) -> int:
        return len(self.frame_lines)

    def values(self, name: str) -> np.ndarray:
        """(F, ncols) float64 in file units, checked finite."""
        try:
            v = np.array(" ".join(self.rows[name]).split(), dtype=np.float64)
        except ValueError:
            v = None
        if v is None or not np.all(np.isfinite(v)):
            # Rare path: find the offending line again (not tracked per line on the fast path).
            for ln in range(self.start, len(self.lines)):
                parts = self.lines[ln].split()
                if parts and parts[0] == name:
                    for tok in parts[1:]:
                        _num(tok, self.path, ln + 1, name)
        return v.reshape(self.frames, self.ncols[name])


def _amc_table(lines: list[str], start: int, asf: AsfSkeleton, p: str) -> _AmcTable:
    """Gather the frames from line index `start` on: frame numbers count up by one and every frame
    lists each bone with dofs once, with as many values as its dofs (the root: its ``order``)."""
    ncols = {"root": len(asf.root.order)}
    ncols.update({b.name: len(b.dof) for b in asf.bones})
    rows: dict[str, list[str]] = {n: [] for n, c in ncols.items() if c > 0}
    frame_lines: list[int] = []
    seen: set[str] = set()
    expect = set(rows)
    prev_frame = None
    for i in range(start, len(lines)):
        parts = lines[i].split(None, 1)
        if not parts or parts[0].startswith("#"):
            continue
        head, rest = parts[0], (parts[1] if len(parts) > 1 else "")
        if head.isascii() and head.isdigit() and not rest.strip():
            n = int(head)
            if prev_frame is not None:
                if seen != expect:
                    _missing(expect - seen, p, frame_lines[-1], prev_frame)
                if n != prev_frame + 1:
                    raise InputError(f"frame number {n} follows frame {prev_frame}; expected "
                                     f"{prev_frame + 1}", p, i + 1, "frame")
            prev_frame = n
            frame_lines.append(i + 1)
            seen = set()
            continue
        if prev_frame is None:
            raise InputError(f"expected a frame number before {head!r}", p, i + 1, "frame")
        _check_bone_line(head, rest, ncols, seen, prev_frame, asf, p, i + 1)
        seen.add(head)
        if ncols[head]:
            rows[head].append(rest)
    if prev_frame is None:
        raise InputError("the file has no frames; a clip needs at least one", p, len(lines) or None, "frame")
    if seen != expect:
        _missing(expect - seen, p, frame_lines[-1], prev_frame, last=True)
    return _AmcTable(rows, ncols, frame_lines, lines, start, p)


def _check_bone_line(name: str, rest: str, ncols: dict[str, int], seen: set[str], frame: int,
                     asf: AsfSkeleton, p: str, line: int) -> None:
    """InputError when the line `name rest...` of frame `frame` names no bone of the skeleton, a bone
    already listed in the frame, or holds a wrong number of values."""
    if name not in ncols:
        raise InputError(f"bone {name!r} is not in the skeleton {os.path.basename(asf.path)}",
                         p, line, name)
    if name in seen:
        raise InputError(f"bone {name!r} appears twice in frame {frame}", p, line, name)
    vals = rest.split()
    if len(vals) != ncols[name]:
        want = " ".join(asf.root.order) if name == "root" else " ".join(asf.bone(name).dof)
        raise InputError(f"expected {ncols[name]} values ({want or 'no dofs'}), found {len(vals)}",
                         p, line, name)


def _amc_motion(asf: AsfSkeleton, table: _AmcTable, to_rad: float, parents: list[int],
                offsets: np.ndarray, axes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Local rotations (F, J, 4) and translations (F, J, 3) (file units, Y-up) of the clip's joints
    (``root``, then the bones) from the AMC values; `offsets` (J, 3) and axis frames `axes` (J, 4)
    as ``AsfSkeleton._layout`` gives them."""
    F, J = table.frames, len(parents)
    rotations = quat.identity((F, J))
    translations = np.broadcast_to(offsets, (F, J, 3)).copy()
    # Root: translation replaces position per axis; rotations apply in the order listed.
    if "root" in table.rows:
        v = table.values("root")
        rot_cols, rot_order = [], ""
        for c, d in enumerate(asf.root.order):
            if d[0] == "t":
                translations[:, 0, "xyz".index(d[1])] = v[:, c]
            else:
                rot_cols.append(c)
                rot_order += d[1].upper()
        if rot_order:
            m = quat.from_euler(v[:, rot_cols[::-1]] * to_rad, rot_order[::-1], degrees=False)
            rotations[:, 0] = quat.mul(quat.mul(axes[0], m), quat.conj(axes[0]))
    ang = np.zeros((F, J, 3))  # rx, ry, rz of every bone, radians (zero where no dof)
    rotating = []
    for k, b in enumerate(asf.bones):
        if not b.dof:
            continue
        j = k + 1
        v = table.values(b.name)
        for c, d in enumerate(b.dof):
            if d[0] == "r":
                ang[:, j, "xyz".index(d[1])] = v[:, c] * to_rad
            elif d[0] == "t":  # a move of the bone's start, in its axis frame C
                e = np.zeros(3)
                e["xyz".index(d[1])] = 1.0
                translations[:, j] += v[:, c, None] * quat.rotate(axes[j], e)
            else:  # "l": the bone grows along its direction; its children move with the tip
                for ch in range(J):
                    if parents[ch] == j:
                        translations[:, ch] += v[:, c, None] * b.direction
        if any(d[0] == "r" for d in b.dof):
            rotating.append(j)
    if rotating:  # all bones in one call: M = Rz Ry Rx, then L = C M C^-1
        m = _rzryrx(ang[:, rotating])
        c = axes[rotating]
        rotations[:, rotating] = quat.mul(quat.mul(c, m), quat.conj(c))
    return rotations, translations


def _missing(names: set[str], p: str, line: int, frame: int, last: bool = False) -> None:
    lst = ", ".join(sorted(names))
    hint = " (truncated?)" if last else ""
    raise InputError(f"frame {frame} lacks bone(s) {lst}{hint}", p, line, "frame")
