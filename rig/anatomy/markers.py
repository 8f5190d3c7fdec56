"""Marker points of a humanoid character (Simmons et al. 2002, sections 2 and 3.1): named places on the
skin where a target's measurements are given, found on any humanoid from its joint roles alone.

A marker is defined by a bone axis, a place along it and a direction (:data:`HUMAN`; a set keeps
the markers whose roles the character has): the axis runs
from a role's joint to the next role's joint on its chain (rig.motion.retarget's chains; for a chain's last
joint, to the end of its bone segment). From the point at fraction `t` of the axis, a ray in the
direction, made perpendicular to the axis (except "along", which follows it, and "ahead", the body's
front as it is), meets the skin; the
marker is the skin vertex nearest that hit. Directions are in the body's frame (rig.motion.role_map.facing):
front, back, up, out (to the character's left on the left side, to its right on the right side).

Markers play three parts in a morph (rig.anatomy.morph):
- joint markers (t = 0, `locates` set) locate their joint in the target: the joint keeps its offset
  from the marker, turned and scaled with the marker's component;
- tip markers ("along", "ahead") give the direction and length of a chain's last bone (hand, foot, head);
- pairs across a bone (:data:`WIDTHS`) measure its thickness in one or both directions across it.

Marker files (TOML or JSON) give target positions, metres in jiggle's world (Z-up, the character's
frame as jiggle reads it), unless `unit` says otherwise::

    unit = "m"                      # optional: "m", "cm", "mm", "in", "ft", or metres per unit
    [markers]
    head_top = [0.0, -0.01, 1.51]
    left_elbow = [0.31, 0.05, 0.96]

Every marker of the canonical's set must be there and no other: a file with an unknown name, a
missing one, a position that is not three finite numbers or lies over 1 km from the origin, is an
InputError naming the file, the marker and (for TOML) its line.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass

import numpy as np

from jiggle.rig.base.errors import InputError, require_file
from jiggle.rig.base.frozen import frozen_array

FORMAT = "jiggle.markers/1"


@dataclass(frozen=True)
class MarkerSpec:
    """One marker of a set: `role`'s axis, fraction `t` along it, `direction` (front, back, up, out,
    along, ahead), and the joint role it locates (None: it does not locate a joint)."""

    name: str
    role: str
    t: float
    direction: str
    locates: str | None = None


def _human() -> tuple[MarkerSpec, ...]:
    m = [MarkerSpec("head_top", "head", 0.0, "along"),
         MarkerSpec("neck_back", "neck", 0.0, "back", "neck"),
         MarkerSpec("sacrum", "hips", 0.0, "back", "hips"),
         MarkerSpec("navel", "hips", 0.7, "front"),
         MarkerSpec("lower_back", "hips", 0.7, "back"),
         MarkerSpec("sternum", "spine", 0.6, "front"),
         MarkerSpec("upper_back", "spine", 0.6, "back")]
    for s in ("left", "right"):
        m += [MarkerSpec(f"{s}_waist", "hips", 0.7, "out"),
              MarkerSpec(f"{s}_chest", "spine", 0.6, "out"),
              MarkerSpec(f"{s}_shoulder", f"{s}_upper_arm", 0.0, "up", f"{s}_upper_arm"),
              MarkerSpec(f"{s}_upper_arm_front", f"{s}_upper_arm", 0.5, "front"),
              MarkerSpec(f"{s}_upper_arm_back", f"{s}_upper_arm", 0.5, "back"),
              MarkerSpec(f"{s}_elbow", f"{s}_lower_arm", 0.0, "back", f"{s}_lower_arm"),
              MarkerSpec(f"{s}_forearm_front", f"{s}_lower_arm", 0.5, "front"),
              MarkerSpec(f"{s}_forearm_back", f"{s}_lower_arm", 0.5, "back"),
              MarkerSpec(f"{s}_wrist", f"{s}_hand", 0.0, "up", f"{s}_hand"),
              MarkerSpec(f"{s}_hand_tip", f"{s}_hand", 0.0, "along"),
              MarkerSpec(f"{s}_hip", f"{s}_upper_leg", 0.0, "out", f"{s}_upper_leg"),
              MarkerSpec(f"{s}_thigh_front", f"{s}_upper_leg", 0.5, "front"),
              MarkerSpec(f"{s}_thigh_back", f"{s}_upper_leg", 0.5, "back"),
              MarkerSpec(f"{s}_knee", f"{s}_lower_leg", 0.0, "front", f"{s}_lower_leg"),
              MarkerSpec(f"{s}_calf_front", f"{s}_lower_leg", 0.5, "front"),
              MarkerSpec(f"{s}_calf_back", f"{s}_lower_leg", 0.5, "back"),
              MarkerSpec(f"{s}_ankle", f"{s}_foot", 0.0, "out", f"{s}_foot"),
              MarkerSpec(f"{s}_toe", f"{s}_toe", 0.0, "ahead")]
    return tuple(m)


HUMAN = _human()
"""The humanoid marker set (43 markers)."""

WIDTHS = (("waist", "left_waist", "right_waist", "hips", "side"),
          ("chest", "left_chest", "right_chest", "spine", "side"),
          ("belly_depth", "navel", "lower_back", "hips", "front"),
          ("chest_depth", "sternum", "upper_back", "spine", "front")) + tuple(
    (f"{s}_{part}", f"{s}_{part}_front", f"{s}_{part}_back", f"{s}_{role}", "both")
    for s in ("left", "right")
    for part, role in (("upper_arm", "upper_arm"), ("forearm", "lower_arm"), ("thigh", "upper_leg"),
                       ("calf", "lower_leg")))
"""Body dimensions: (name, marker a, marker b, role of the bone across which |a - b| is measured,
which scale it sets: "side" (across, left-right), "front" (front-back) or "both")."""

# the next role down each chain (rig.motion.retarget's chains): a role's axis runs to that role's joint
NEXT_ROLE = {"hips": "spine", "spine": "chest", "chest": "neck", "neck": "head"}
for _s in ("left", "right"):
    NEXT_ROLE.update({f"{_s}_shoulder": f"{_s}_upper_arm", f"{_s}_upper_arm": f"{_s}_lower_arm",
                      f"{_s}_lower_arm": f"{_s}_hand", f"{_s}_upper_leg": f"{_s}_lower_leg",
                      f"{_s}_lower_leg": f"{_s}_foot", f"{_s}_foot": f"{_s}_toe"})


@dataclass(frozen=True, eq=False)
class MarkerSet:
    """The markers of one skin. names (n,), specs (n,) MarkerSpec, vertex (n,) int64 skin vertex,
    positions (n, 3) float64 metres (the vertices' rest positions)."""

    names: tuple
    specs: tuple
    vertex: np.ndarray
    positions: np.ndarray

    def __post_init__(self):
        object.__setattr__(self, "vertex", frozen_array(self.vertex, np.int64))
        object.__setattr__(self, "positions", frozen_array(self.positions))

    def index(self, name: str) -> int:
        return self.names.index(name)


def role_axis(role: str, roles: dict, positions: np.ndarray, segments) -> tuple[np.ndarray, np.ndarray]:
    """(start, end) (3,) metres of `role`'s axis: its joint to the next role's joint on its chain, or
    to the end of the longest bone segment starting at the joint when the chain stops there."""
    j = roles[role]
    nxt = NEXT_ROLE.get(role)
    if nxt in roles and np.linalg.norm(positions[roles[nxt]] - positions[j]) > 1e-6:
        return positions[j], positions[roles[nxt]]
    own = np.nonzero(np.asarray(segments.parent) == j)[0]
    if not len(own):
        raise InputError(f"the joint of role {role!r} starts no bone segment: its axis is unknown", field="roles")
    s = own[np.argmax(segments.lengths[own])]
    return segments.start[s], segments.end[s]


def body_frame(positions: np.ndarray, roles: dict) -> dict:
    """{"front", "back", "up", "left", "right"} (3,) unit directions of the rest pose."""
    from jiggle.rig.motion.role_map import facing
    front, left = facing(positions, roles)
    up = np.array([0.0, 0.0, 1.0])
    return {"front": front, "back": -front, "up": up, "left": left, "right": -left}


def marker_rays(specs, roles: dict, positions: np.ndarray, segments) -> tuple[np.ndarray, np.ndarray]:
    """(origins (n, 3), directions (n, 3) unit) of every marker's ray."""
    frame = body_frame(positions, roles)
    missing = sorted({s.role for s in specs} - set(roles))
    if missing:  # callers pass usable_specs(); this guards direct use
        raise InputError(f"the character has no joint for the roles {', '.join(missing)} the markers need",
                         field="roles")
    o, d = np.zeros((len(specs), 3)), np.zeros((len(specs), 3))
    for i, s in enumerate(specs):
        a, b = role_axis(s.role, roles, positions, segments)
        axis = (b - a) / np.linalg.norm(b - a)
        o[i] = a + s.t * (b - a)
        if s.direction in ("along", "ahead"):
            d[i] = axis if s.direction == "along" else frame["front"]
            continue
        name = s.direction
        if name == "out":
            name = "left" if s.name.startswith("left") else "right"
        v = frame[name] - (frame[name] @ axis) * axis
        if np.linalg.norm(v) < 1e-3:
            raise InputError(f"marker {s.name!r}: its direction {s.direction!r} runs along its bone", field="markers")
        d[i] = v / np.linalg.norm(v)
    return o, d


def usable_specs(specs, roles: dict) -> tuple:
    """The specs whose roles the character has (a skeleton without toes has no toe markers)."""
    return tuple(s for s in specs if s.role in roles and (s.locates is None or s.locates in roles))


def find_markers(vertices, faces, roles: dict, positions: np.ndarray, segments, specs=HUMAN) -> MarkerSet:
    """The markers `specs` on a skin (vertices (V, 3) metres, faces (F, 3)) around joints at rest
    `positions` (J, 3) with `roles`; each the vertex of the hit triangle nearest its ray's first hit."""
    import trimesh
    specs = usable_specs(specs, roles)
    o, d = marker_rays(specs, roles, positions, segments)
    mesh = trimesh.Trimesh(np.asarray(vertices, np.float64), np.asarray(faces, np.int64), process=False)
    loc, ray, tri = mesh.ray.intersects_location(o, d, multiple_hits=False)
    hit = np.full((len(specs), 3), np.nan)
    face = np.full(len(specs), -1)
    hit[ray], face[ray] = loc, tri
    missed = [specs[i].name for i in range(len(specs)) if face[i] < 0]
    if missed:
        raise InputError(f"markers {', '.join(missed)}: their rays from the bones meet no skin", field="markers")
    corners = mesh.faces[face]                                                   # (n, 3)
    dist = np.linalg.norm(mesh.vertices[corners] - hit[:, None], axis=2)
    vertex = corners[np.arange(len(specs)), dist.argmin(axis=1)]
    return MarkerSet(tuple(s.name for s in specs), tuple(specs), vertex, mesh.vertices[vertex])


# ---------------------------------------------------------------------------------- files
MAX_DISTANCE = 1000.0   # metres: a marker farther from the origin is refused


def _line_of(path: str, name: str) -> int | None:
    """The line of `path` that sets `name`, for messages."""
    with open(path, encoding="utf-8") as fh:
        for i, line in enumerate(fh, 1):
            if line.split("=")[0].split(":")[0].strip().strip('"') == name:
                return i
    return None


def read_markers(path: str | os.PathLike, names) -> dict[str, np.ndarray]:
    """{name: (3,) float64 metres} from a marker file (TOML or JSON, see the module docstring), with
    exactly the marker names `names`."""
    from jiggle.rig.base.tomlfile import read_toml
    from jiggle.rig.character.character import unit_scale
    p = require_file(path, "markers file")
    if p.lower().endswith(".json"):
        try:
            with open(p, encoding="utf-8") as fh:
                doc = json.load(fh)
        except UnicodeDecodeError:
            raise InputError("not a UTF-8 text file; expected JSON markers", p) from None
        except json.JSONDecodeError as e:
            raise InputError(f"not valid JSON: {e}", p, line=e.lineno) from None
    else:
        p, doc = read_toml(p, "markers file")
    if not isinstance(doc, dict) or not isinstance(doc.get("markers"), dict):
        raise InputError("expected a [markers] table of name = [x, y, z]", p, field="markers")
    extra = sorted(set(doc) - {"markers", "unit", "format", "source"})
    if extra:
        raise InputError(f"unknown keys {', '.join(extra)}; expected markers, unit (and format, source)", p)
    scale = unit_scale(doc.get("unit", "m"), p)
    given = doc["markers"]
    names = list(names)
    unknown = [n for n in given if n not in names]
    if unknown:
        raise InputError(f"unknown marker {unknown[0]!r} ({len(unknown)} unknown); the canonical's markers are: "
                         f"{', '.join(names)}", p, line=_line_of(p, unknown[0]), field="markers")
    missing = [n for n in names if n not in given]
    if missing:
        raise InputError(f"missing markers: {', '.join(missing)} (every marker of the canonical is needed; "
                         f"`jiggle morph CANONICAL --write-markers FILE` writes the full set)", p, field="markers")
    out = {}
    for n in names:
        v = given[n]
        ok = isinstance(v, list) and len(v) == 3 and all(
            isinstance(x, (int, float)) and not isinstance(x, bool) for x in v)
        if not ok or not np.isfinite(np.asarray(v, np.float64)).all():
            raise InputError(f"marker {n!r}: expected three finite numbers [x, y, z], got {v!r}", p,
                             line=_line_of(p, n), field=f"markers.{n}")
        out[n] = np.asarray(v, np.float64) * float(scale)
        if not np.linalg.norm(out[n]) <= MAX_DISTANCE:
            raise InputError(f"marker {n!r} is {np.linalg.norm(out[n]):.4g} m from the origin; expected at most "
                             f"{MAX_DISTANCE:g} m (a wrong unit or a broken number?)", p, line=_line_of(p, n),
                             field=f"markers.{n}")
    return out


def write_markers(path: str | os.PathLike, names, positions: np.ndarray, source: str = "") -> str:
    """Write a marker file (TOML, metres, Z-up) atomically; returns the path."""
    from jiggle.rig.base.atomic import atomic_path
    positions = np.asarray(positions, np.float64)
    if not np.isfinite(positions).all():
        raise InputError("marker positions hold NaN or inf", str(path), field="markers")
    lines = [f'format = "{FORMAT}"', 'unit = "m"      # metres, jiggle\'s world: Z-up, as jiggle reads the character']
    if source:
        lines.append(f"source = {json.dumps(str(source))}")
    lines.append("")
    lines.append("[markers]")
    for n, p in zip(names, positions):
        lines.append(f"{n} = [{p[0]:.6f}, {p[1]:.6f}, {p[2]:.6f}]")
    with atomic_path(str(path)) as tmp:
        with open(tmp, "w") as fh:
            fh.write("\n".join(lines) + "\n")
    return str(path)
