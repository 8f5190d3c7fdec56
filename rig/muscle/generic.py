"""Tissue on any body: the generic template, built from the skin's segmentation by bone.

When no built-in body plan fits a skeleton (a blob of four joints, a winged or floating creature, a rig
whose roles cannot be read), the fit still has the first step of the outside-in method (Pratscher et al.
2005, section 3.1): the skin split into one region per bone segment. Each region is judged by its shape:

- volume: the region's triangles, their local radius about the bone (rig.muscle.fit_quality.local_radius),
  and their roundness (how evenly the skin's normals face every way around the bone: a membrane's do not);
- a part holds volume when it is neither flat (FLAT: wings, ears, fins, capes), nor thin (its radius under
  THIN of the body's largest part: tails, antennae, fingers), nor small (under SMALL of the skin's area);
- parts holding volume get one tissue mass fitted to their whole region: fat on the body's soft core (at
  least CORE of the bulkiest part's volume, skin area x radius: a blob's body, a belly, a head as big as the
  body), muscle on the others (limbs, a neck); the core's stacked bones along a straight, unbranched chain are one mass (a blob's
  body and head joints), so no seam runs through it;
- sizes come from the skin: a fat layer FAT_DEPTH_RADII and the thinnest muscle THICKNESS_RADII of the part's
  radius, so the template has no length in metres and gives the same shapes at any scale;
- frequencies come from the part's size relative to the body (a smaller part is stiffer: f ~ radius^-1/2,
  clamped to the kind's range), the other jiggle values are the kind's defaults (rig.muscle.template).

Parts that hold no volume get no tissue: they follow their bones (plain skinning), so a wing does not flap
like fat. :func:`generic_parts` says for every part what it got and why; `jiggle inspect` and the bake's
report print it.
"""
from __future__ import annotations

import re
from dataclasses import dataclass, replace

import numpy as np

from jiggle.rig.muscle.template import BoneMusclePair, MuscleTemplate, Template, default_jiggle

GENERIC = "generic"
"""The template name that asks for this template (--template generic)."""
FLAT = 0.25
"""A region whose roundness about its bone is under this is flat (a wing, an ear; see _roundness)."""
THIN = 0.2
"""A region whose radius about its bone is under this share of the largest part's is thin (a tail, a finger)."""
SMALL = 0.01
"""A region with under this share of the skin's area is too small to hold tissue."""
FEW = 12
"""A region with fewer skin vertices than this is not judged flat (its normals are too few to tell)."""
THIN_NAMES = ("wing", "ear", "fin", "tail", "cape", "hair", "feather", "antenna", "tentacle", "ponytail", "whisker",
              "cloth", "skirt", "horn")
"""Words in a joint's name that say its part is a membrane or an appendage, not tissue: a bone named so, and the
bones below it, get none whatever their shape (a wing's thick leading edge looks round)."""
CORE = 0.5
"""Parts holding at least this share of the bulkiest part's volume (skin area x radius about the bone) are the
body's soft core: they get fat (a blob's body, a big head, a belly)."""
STRAIGHT = np.cos(np.radians(35.0))
"""Consecutive bones of a soft core within 35 degrees of each other are one body (a blob's stacked joints)."""
FAT_DEPTH_RADII = 0.15
"""The fat layer's thickness, in the part's radius."""
THICKNESS_RADII = 0.05
"""A muscle's thinnest fitted radius, in the part's radius."""


@dataclass(frozen=True)
class Part:
    """One bone segment's skin region as the generic template judges it.

    segment : index into the segmentation's bone segments; label : its "parent>child" label.
    joint, child : the segment's start and end joints (child = joint for a leaf bone ending at its tip).
    segments : the segments the part's tissue covers: its own, then those merged into it (a fat core and the
        tissue after it along a straight unbranched chain are one body: a blob's stacked joints jiggle as one
        mass, without seams); () for a part without tissue.
    area : metres^2 of skin; radius : metres, its local radius about the bone; roundness : its roundness about
        the bone (0 a membrane .. 1 round, see _roundness).
    kind : "fat", "muscle" or None (no tissue); reason : one phrase saying why.
    """

    segment: int
    label: str
    joint: int
    child: int
    area: float
    radius: float
    roundness: float
    kind: str | None
    reason: str
    segments: tuple[int, ...] = ()

    def to_json(self) -> dict:
        return {"part": self.label, "tissue": self.kind or "none", "why": self.reason,
                "radius_m": round(self.radius, 5), "roundness": round(self.roundness, 3),
                "segments": len(self.segments)}


def generic_parts(vertices: np.ndarray, faces: np.ndarray, face_region: np.ndarray, segments, normals: np.ndarray,
                  vertex_region: np.ndarray) -> list[Part]:
    """Judge every bone segment's region (see the module docstring).

    vertices (V, 3) metres and faces (F, 3) of the skin fitted to; face_region (F,) the segment of each
    triangle; segments : rig.muscle.segmentation.BoneSegments; normals (V, 3) the file's unit vertex normals
    (outward whatever the triangles' winding) and vertex_region (V,) the segment of each vertex, for the
    first V vertices of the skin (the character's own).
    """
    from jiggle.rig.muscle.fit_quality import local_radius
    V = np.asarray(vertices, np.float64)
    F = np.asarray(faces, np.int64)
    tri = V[F]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    total = max(float(area.sum()), 1e-30)
    rows = []
    for s in range(len(segments)):
        mine = np.flatnonzero((face_region == s) & (area > 0))
        a = float(area[mine].sum())
        if len(mine) < 3:
            rows.append((s, a, 0.0, 0.0))
            continue
        r = local_radius(V, F[mine], segments.start[s], segments.end[s])
        rows.append((s, a, r, _roundness(np.asarray(normals)[vertex_region == s],
                                          segments.end[s] - segments.start[s])))
    round_ = [(a, r) for s, a, r, f in rows if a >= SMALL * total and f >= FLAT and not _thin_name(
        segments.labels[s].split(">")[0])]
    biggest = max((r for a, r in round_), default=0.0)
    bulk = max((a * r for a, r in round_), default=0.0)     # ~ the volume the skin holds (area x radius)
    parts = []
    names = segments.labels
    for s, a, r, solid in rows:
        named = _thin_name(names[s].split(">")[0])
        if named:
            kind, why = None, f"named a {named}: an appendage follows its bones"
        elif a < SMALL * total:
            kind, why = None, f"small ({100 * a / total:.1f}% of the skin)"
        elif solid < FLAT:
            kind, why = None, f"flat (roundness {solid:.2f}): a wing, fin or ear follows its bones"
        elif r < THIN * biggest:
            kind, why = None, f"thin (radius {r / biggest:.2f} of the body's): a tail or finger follows its bones"
        elif a * r >= CORE * bulk:
            kind, why = "fat", f"the body's soft core ({a * r / bulk:.2f} of the bulkiest part's volume)"
        else:
            kind, why = "muscle", f"holds volume ({a * r / bulk:.2f} of the bulkiest part's, radius " \
                                  f"{r / biggest:.2f} of the largest)"
        child = int(segments.child[s])
        parts.append(Part(segment=s, label=segments.labels[s], joint=int(segments.parent[s]),
                          child=child if child >= 0 else int(segments.parent[s]), area=a, radius=r,
                          roundness=solid, kind=kind, reason=why, segments=(s,)))
    return _merge_chains(parts, segments)


def _thin_name(joint: str) -> str | None:
    """The word of THIN_NAMES a joint's name holds ("Wing1.L" -> "wing", "LeftEar" -> "ear"), or None."""
    words = re.findall(r"[A-Z]?[a-z]+|[A-Z]+(?![a-z])", joint)
    return next((w.lower() for w in words if w.lower() in THIN_NAMES), None)


def _roundness(normals: np.ndarray, along: np.ndarray) -> float:
    """How round a region is about its bone: the skin normals (n, 3) made perpendicular to the bone `along` (3,),
    their second moment's two eigenvalues across it, the smaller over the larger. A ring around a limb or a
    blob's skin faces every way (~1); a membrane's two sides face one way and its opposite (~0: a wing, a fin,
    an ear, a cape). The sign of a normal does not count, so neither does a triangle's winding, and the
    overlapping shells of a low-poly game model do not either."""
    n = np.asarray(normals, np.float64)
    if len(n) < FEW:
        return 1.0              # a few normals cannot tell a membrane; a part this coarse is not one
    a = np.asarray(along, np.float64)
    a = a / max(np.linalg.norm(a), 1e-300)
    p = n - np.outer(n @ a, a)
    w = np.linalg.eigvalsh(p.T @ p)           # ascending; w[0] ~ 0 along the bone
    return float(w[1] / w[2]) if w[2] > 0 else 0.0


def _merge_chains(parts: list[Part], segments) -> list[Part]:
    """A fat part and the tissue parts after it along an unbranched, straight chain (within STRAIGHT) merged into
    the run's first part: it covers them all and ends where the run ends; the others keep their judgement but no
    tissue ("merged")."""
    starts: dict[int, list[int]] = {}
    for p in parts:
        starts.setdefault(p.joint, []).append(p.segment)
    out = {p.segment: p for p in parts}
    absorbed: set[int] = set()
    for p in parts:
        if p.kind != "fat" or p.segment in absorbed:
            continue
        run, last = [p.segment], p
        # the next segment of the run: the only bone leaving this one's end joint, holding tissue
        while last.child != last.joint and len(starts.get(last.child, [])) == 1:
            nxt = out[starts[last.child][0]]
            if nxt.kind is None or nxt.segment in absorbed or nxt.segment in run:
                break
            a = segments.end[last.segment] - segments.start[last.segment]
            b = segments.end[nxt.segment] - segments.start[nxt.segment]
            if a @ b < STRAIGHT * np.linalg.norm(a) * np.linalg.norm(b):
                break       # the chain bends there: a joint the tissue must bend at, not one mass
            run.append(nxt.segment)
            last = nxt
        if len(run) == 1:
            continue
        absorbed.update(run[1:])
        label = f"{p.label.split('>')[0]}>{last.label.split('>')[1]}"
        out[p.segment] = replace(p, label=label, child=last.child, segments=tuple(run),
                                 area=sum(out[s].area for s in run),
                                 radius=max(out[s].radius for s in run),
                                 reason=p.reason + f"; one mass over {len(run)} bones of an unbranched chain")
        for s in run[1:]:
            out[s] = replace(out[s], kind=None, reason=f"merged into {label}", segments=())
    return [out[p.segment] for p in parts]


def generic_front(character) -> np.ndarray:
    """(3,) the front of a body without roles to read it from: -Y, the front of glTF (+Z, Y-up) and of Blender
    once turned Z-up; a single-region muscle does not depend on it beyond its loft's seam."""
    return np.array([0.0, -1.0, 0.0])


def _muscle_name(label: str, kind: str, taken: set[str]) -> str:
    """A muscle name (letters, digits, _) from a segment label: "Body>Head" fat -> "body_fat"."""
    joint = label.split(">")[0]
    base = re.sub(r"[^A-Za-z0-9]+", "_", joint).strip("_").lower() or "part"
    if not base[0].isalpha():
        base = "j_" + base
    name, k = f"{base}_{kind}", 2
    while name in taken:
        name, k = f"{base}_{kind}_{k}", k + 1
    taken.add(name)
    return name


def generic_template(parts: list[Part]) -> tuple[Template, dict[str, int]]:
    """(template, segments): a Template with one pair per part that holds volume, whose one muscle takes the
    whole region, and {muscle name: segment index}. Labels are joint names (a leaf's child label is
    "<joint>>end"), read by rig.muscle.fit through the segments, not through roles."""
    pairs, where, taken = [], {}, set()
    for p in parts:
        if p.kind is None:
            continue
        # its kind's material at the character's real size (then held under the limit on its cycles, sim.bake.setup)
        jiggle = default_jiggle(p.kind)
        name = _muscle_name(p.label, p.kind, taken)
        m = MuscleTemplate(name=name, kind=p.kind, type="single",
                           depth=FAT_DEPTH_RADII * p.radius if p.kind == "fat" else 0.0,
                           thickness_min=THICKNESS_RADII * p.radius, jiggle=jiggle)
        parent, child = p.label.split(">")
        pairs.append(BoneMusclePair(parent=parent, child=child if child != "end" else f"{parent}>end", muscles=(m,)))
        where[name] = p.segment
    return Template(name="generic", pairs=tuple(pairs)), where
