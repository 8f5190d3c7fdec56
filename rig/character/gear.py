"""Gear and hard surfaces: the parts of a character's skin that are not tissue.

Armour plates, helmets, pouches, weapons, a robot's metal shells: they ride the body under them
without stretching. :func:`find_rigid` tells them from flesh by the mesh, not by the weights alone (its
docstring gives the rule and the figures it was set from); :func:`parse_rigid` reads the user's override
(``--rigid``); rig.skin.muscle_skin.MuscleSkin keeps the shell deformers off them, so they follow plain
skinning (their bone, rigidly, for a shell bound to one joint) in the static and the jiggling skin alike.
"""
from __future__ import annotations

import os
import re
from dataclasses import dataclass, field

import numpy as np

from jiggle.rig.base.errors import InputError

RIGID_WEIGHT = 0.99
"""A vertex is bound rigidly when one joint carries at least this much of its weight."""
ALMOST_ALL = 0.98
"""A piece (welded connected component) is rigidly bound when this fraction of its vertices is."""
WELD = 1e-5
"""Vertices closer than this fraction of the character's largest extent are one (UV seams split them)."""
GEAR_WORDS = ("gear", "armor", "armour", "helmet", "weapon", "vest", "belt", "pouch", "sword", "shield",
              "holster", "backpack", "visor", "gun", "rifle", "pistol", "axe", "knife", "dagger", "spear")
"""Words in a part's (glTF node's) or its material's name that mark it as gear."""
METAL_WORDS = ("metal", "steel", "iron", "chrome", "bronze", "brass")
"""Words in a material's name that mark what it covers as gear, besides GEAR_WORDS."""
MAIN_BODY = 0.5
"""A part named like gear holding more than this fraction of the skin's vertices is the body, not gear."""

SHEET = 1.0
"""A piece is an open sheet (a plate) when (its boundary's length)^2 / its area exceeds this: a vest, a
visor, an ear made of one layer (a closed surface has 0; a blob with a small hole at its bottom about 0.1)."""
PLATE = 0.12
"""A closed piece is a thin plate when its thickness 2 V / A (V its volume, A its area: the thickness of a
slab, 2/3 of a ball's radius) is below this fraction of its width (its second principal extent); a ball
or a cube has 0.33, a cone 0.26, the shared zoo's bodies 0.09-0.31 and its rigid head pieces 0.17-0.36."""
SPIKE_LONG, SPIKE_TAPER, SPIKE_FILL = 1.5, 0.5, 0.35
"""A spike or shard: at least SPIKE_LONG times as long as wide, its end narrower than SPIKE_TAPER of its
other end, and filling at most SPIKE_FILL of its principal box (a cone 0.26, an ellipsoid 0.52)."""
SHELL_GAP, SHELL_VOLUME = 0.1, 0.5
"""A shell lying over other skin: the median distance of its vertices to the rest of the skin is below SHELL_GAP
of its length, and it holds less than SHELL_VOLUME of the volume of the piece it lies over (a vest on a torso, a
helmet on a head; not a head with small pieces on it, nor one plate beside another)."""
BODY_SHARE = 0.5
"""The body's own volume holds at least this share of the volume of the skin's closed pieces."""
BODY_FILL = 0.2
"""... and, riding one joint, fills at least this share of its principal box: rounded (a ball 0.52, the zoo's
bodies 0.25-0.53), and is no plate, sheet, spike or shell."""
JOINTED = 0.01
"""A rigidly bound piece is jointed when at least two joints each carry this share of its vertices: a body skinned
rigidly bone by bone (a stylised rig), whose shape, limbs and all, need not be bulky to be the body's volume."""

RULE_NAMED = "named like gear"
RULE_MATERIAL = "made of a material named like gear"
RULE_SHEET = "an open sheet (a plate)"
RULE_PLATE = "a thin plate"
RULE_SPIKE = "a spike or shard"
RULE_SHELL = "a shell lying over other skin"
RULE_PIECE = "a separate piece bound rigidly to one joint, not the body's own volume"
RULE_BODY = "the body's own volume (most of the skin's volume, the skeleton runs through it)"
RULES = (RULE_NAMED, RULE_MATERIAL, RULE_SHELL, RULE_SHEET, RULE_PLATE, RULE_SPIKE, RULE_BODY, RULE_PIECE)
"""Every rule find_rigid decides a piece by, in the order it asks them."""


@dataclass(frozen=True)
class RigidParts:
    """What of a character's skin is not tissue.

    mask : (V,) bool, the vertices that follow plain skinning (no shell deformer, no jiggle).
    pieces : number of welded connected components wholly in `mask`.
    parts : the parts (Character.meta["parts"] names) wholly rigid; `partly`: {part: fraction} of those
        only partly so.
    joints : the joints the rigid vertices ride (their largest weight), most vertices first.
    how : "auto" (detected), "none", or the --rigid value that set it.
    why : {rule: vertices} of the rigid ones, e.g. {"a thin plate": 6106} (RULES, or "as asked (--rigid ...)").
    soft : {rule: vertices} of rigidly bound vertices left soft, e.g. {RULE_BODY: 973}.
    decided : one dict per rigidly bound or named piece: {"piece", "part", "joint", "vertices", "rule",
        "hard"} (find_rigid), the rule that decided it.
    """

    mask: np.ndarray
    pieces: int = 0
    parts: tuple = ()
    partly: dict = field(default_factory=dict)
    joints: tuple = ()
    how: str = "auto"
    why: dict = field(default_factory=dict)
    soft: dict = field(default_factory=dict)
    decided: tuple = ()

    @property
    def count(self) -> int:
        return int(np.count_nonzero(self.mask))

    @property
    def any(self) -> bool:
        return bool(self.mask.any())

    @property
    def all(self) -> bool:
        """Every vertex is rigid: no skin is tissue."""
        return bool(len(self.mask)) and bool(self.mask.all())

    def by_rule(self) -> list:
        """`decided` grouped: [{"rule", "hard", "pieces", "vertices", "parts", "joints"}], hard first."""
        groups = {}
        for d in self.decided:
            g = groups.setdefault((d["rule"], d["hard"]), {"rule": d["rule"], "hard": d["hard"], "pieces": 0,
                                                           "vertices": 0, "parts": [], "joints": []})
            g["pieces"] += 1
            g["vertices"] += d["vertices"]
            for k, v in (("parts", d["part"]), ("joints", d["joint"])):
                if v is not None and v not in g[k]:
                    g[k].append(v)
        return sorted(groups.values(), key=lambda g: (not g["hard"], -g["vertices"]))

    def to_json(self) -> dict:
        """bake.json's / inspect's record (no per-vertex data)."""
        V = len(self.mask)
        out = {"how": self.how, "vertices": self.count, "of": V, "pieces": self.pieces, "parts": list(self.parts),
               "partly": {k: round(v, 3) for k, v in self.partly.items()}, "joints": list(self.joints),
               "why": dict(self.why)}
        if self.soft:
            out["soft"] = dict(self.soft)
        if self.decided:
            out["rules"] = [{**g, "parts": g["parts"][:12], "joints": g["joints"][:12]} for g in self.by_rule()]
        return out

    def describe(self) -> str:
        """One line for the bake's log."""
        flesh = "".join(f"; flesh though bound rigidly: {g['vertices']} vertices in {g['pieces']} piece(s) "
                        f"({', '.join(g['parts'][:4])}: {g['rule']})" for g in self.by_rule() if not g["hard"])
        if not self.any:
            return f"rigid parts ({self.how}): none; all the skin is tissue{flesh}"
        names = list(self.parts) + [f"{k} ({v:.0%})" for k, v in self.partly.items()]
        shown = ", ".join(names[:10]) + (f" and {len(names) - 10} more" if len(names) > 10 else "")
        rules = ", ".join(f"{k}: {v}" for k, v in self.why.items())
        return (f"rigid parts ({self.how}): {self.count} of {len(self.mask)} vertices in {self.pieces} piece(s) follow "
                f"their bones without jiggle: {shown} (on {', '.join(self.joints[:8])}"
                f"{' ...' if len(self.joints) > 8 else ''}; by rule: {rules}){flesh}; --rigid overrides")


def pieces(character) -> np.ndarray:
    """(V,) int64: the welded connected component of each vertex (positions closer than WELD x the
    largest extent are one vertex, so UV and normal seams do not split a piece)."""
    return _welded(character)[3]


def _welded(character):
    """(points (P, 3), faces (F, 3) on them, inverse (V,) vertex -> point, piece label (V,))."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    from jiggle.rig.character.bone_heat import WELD_TOLERANCE, weld
    v = np.asarray(character.vertices, np.float64)
    f = np.asarray(character.faces, np.int64)
    size = float(np.ptp(v, axis=0).max()) if len(v) else 0.0
    wv, wf, inverse = weld(v, f, max(WELD_TOLERANCE, WELD * size))
    P = int(inverse.max()) + 1 if len(inverse) else 0
    a = np.concatenate([wf[:, 0], wf[:, 1], wf[:, 2]])
    b = np.concatenate([wf[:, 1], wf[:, 2], wf[:, 0]])
    g = coo_matrix((np.ones(len(a)), (a, b)), shape=(P, P))
    _, label = connected_components(g, directed=False)
    return wv, wf, inverse, label[inverse].astype(np.int64)


def _rigid_vertices(character) -> tuple[np.ndarray, np.ndarray]:
    """(V,) bool bound rigidly (one weight >= RIGID_WEIGHT) and (V,) int64 the joint of each vertex's
    largest weight."""
    w = np.asarray(character.weights, np.float64)
    j = np.asarray(character.joints, np.int64)
    k = np.argmax(w, axis=1)
    rows = np.arange(len(w))
    return w[rows, k] >= RIGID_WEIGHT, j[rows, k]


def _gear_named(name: str, words=GEAR_WORDS) -> bool:
    words_in = re.split(r"[^a-z]+", name.lower())
    return any(w.startswith(g) for w in words_in if w for g in words)


def materials(character) -> list:
    """[[material name, first vertex, count]] of the character's parts: Character.meta["materials"] when it
    has them, else read from its glTF source (Character.source) through meta["primitives"] ([mesh,
    primitive, first, count], rig.character.gltf_character); [] when neither says."""
    given = character.meta.get("materials")
    if given is not None:
        return [list(m) for m in given]
    prims = character.meta.get("primitives") or []
    src = str(getattr(character, "source", "") or "")
    if not prims or not src.lower().endswith((".glb", ".gltf")) or not os.path.isfile(src):
        return []
    from jiggle.rig.motion.gltf_io import GltfDocument
    try:
        gltf = GltfDocument(src).gltf                # parsed and checked once, cached by the reader
        names = [str(m.name or "") for m in gltf.materials or []]
        out = []
        for mesh, prim, first, count in prims:
            mi = gltf.meshes[int(mesh)].primitives[int(prim)].material
            if mi is not None and 0 <= int(mi) < len(names) and names[int(mi)]:
                out.append([names[int(mi)], int(first), int(count)])
        return out
    except (InputError, OSError, ValueError, IndexError, TypeError):
        return []


def _winding(points: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """(P,) generalized winding number of points (P, 3) for triangles (F, 3) each corner: the signed solid
    angles summed over 4 pi (Van Oosterom-Strackee); about 1 inside a closed outward surface, 0 outside. In
    chunks of points holding about a million triangle corners each."""
    out = np.zeros(len(points))
    chunk = max(1, 1_000_000 // max(len(a), 1))
    for i in range(0, len(points), chunk):
        p = points[i:i + chunk, None]
        x, y, z = a[None] - p, b[None] - p, c[None] - p           # (chunk, F, 3) each
        lx, ly, lz = (np.linalg.norm(t, axis=2) for t in (x, y, z))
        det = np.einsum("pfi,pfi->pf", x, np.cross(y, z))
        den = (lx * ly * lz + np.einsum("pfi,pfi->pf", x, y) * lz + np.einsum("pfi,pfi->pf", y, z) * lx
               + np.einsum("pfi,pfi->pf", z, x) * ly)
        out[i:i + chunk] = np.arctan2(det, den).sum(axis=1) / (2.0 * np.pi)
    return out


NEAR_QUERY = 512
"""piece_shapes: a piece of at most this many samples finds its gap in one query of the whole skin's tree."""


def piece_shapes(character, welded=None, gaps=None) -> list:
    """The shape of every piece (welded connected component), what find_rigid reads: one dict per piece
    with "vertices" (count), "sheet" ((boundary length)^2 / area: 0 closed), "thickness" (2 V / A over its
    width), "long" (length over width), "taper" (the narrower end's radius over the wider's), "fill" (V
    over its principal box), "volume" (m^3, 0 for an open sheet), "length" (m) and "gap" (the median
    distance of its vertices to the rest of the skin over its length) and "over" (the piece nearest most of
    its vertices, -1 when alone; only for the pieces `gaps` lists, every piece when None). Principal axes from
    the area-weighted triangles."""
    from scipy.spatial import cKDTree
    wv, wf, inverse, label = welded if welded is not None else _welded(character)
    plabel = np.zeros(len(wv), np.int64)
    plabel[inverse] = label
    flab = plabel[wf[:, 0]] if len(wf) else np.zeros(0, np.int64)
    K = int(label.max()) + 1 if len(label) else 0
    a, b, c = wv[wf[:, 0]], wv[wf[:, 1]], wv[wf[:, 2]]
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    cen = (a + b + c) / 3.0
    out = []
    for k in range(K):
        sel = flab == k
        n = int(np.count_nonzero(label == k))
        ff, ar = wf[sel], area[sel]
        A = float(ar.sum())
        pts = wv[np.unique(ff)] if len(ff) else wv[inverse[label == k]]
        shape = {"vertices": n, "sheet": np.inf, "thickness": 0.0, "long": 1.0, "taper": 1.0, "fill": 0.0,
                 "volume": 0.0, "length": 0.0, "gap": np.inf, "over": -1}
        out.append(shape)
        if A <= 0.0 or len(pts) < 4:
            continue
        m = (ar[:, None] * cen[sel]).sum(0) / A
        vol = abs(float(np.einsum("ij,ij->i", a[sel] - m, np.cross(b[sel] - m, c[sel] - m)).sum()) / 6.0)
        e = np.sort(np.concatenate([ff[:, [0, 1]], ff[:, [1, 2]], ff[:, [2, 0]]]), axis=1)
        u, cnt = np.unique(e, axis=0, return_counts=True)
        rim = u[cnt == 1]
        B = float(np.linalg.norm(wv[rim[:, 0]] - wv[rim[:, 1]], axis=1).sum())
        X = cen[sel] - m
        _, axes = np.linalg.eigh((ar[:, None] * X).T @ X / A)
        axes = axes[:, ::-1]
        proj = (pts - m) @ axes
        L = np.maximum(np.ptp(proj, axis=0), 1e-12)
        # taper: the largest distance from the long axis in each end fifth of the length
        t = (proj[:, 0] - proj[:, 0].min()) / L[0]
        r = np.linalg.norm(proj[:, 1:], axis=1)
        ends = [r[t <= 0.2].max(initial=0.0), r[t >= 0.8].max(initial=0.0)]
        sheet = B * B / A
        shape.update(sheet=sheet, thickness=2.0 * vol / A / L[1], long=float(L[0] / L[1]),
                     taper=float(min(ends) / max(max(ends), 1e-12)), fill=float(vol / np.prod(L)),
                     volume=vol if sheet <= SHEET else 0.0, length=float(L[0]))
    # gap to the rest of the skin: vertices and triangle centres of the other pieces
    if K > 1:
        samples = np.concatenate([wv, cen])
        owner = np.concatenate([plabel, flab])
        tree = cKDTree(samples)
        for k in (range(K) if gaps is None else gaps):
            mine = np.nonzero(plabel == k)[0]
            if not len(mine) or out[k]["length"] <= 0.0 or not (owner != k).any():
                continue
            own = int(np.count_nonzero(owner == k))
            if own <= NEAR_QUERY:       # a small piece: its nearest samples past its own are another piece's
                d, near = tree.query(wv[mine], k=min(own + 8, len(samples)))
                other = owner[near] != k
                first = np.argmax(other, axis=1)
                d, near = d[np.arange(len(mine)), first], near[np.arange(len(mine)), first]
                found = other.any(axis=1)
                if not found.all():
                    continue
            else:                       # a large one: a tree of everything else
                rest = np.nonzero(owner != k)[0]
                d, near = cKDTree(samples[rest]).query(wv[mine])
                near = rest[near]
            out[k]["gap"] = float(np.median(d) / out[k]["length"])
            out[k]["over"] = int(np.bincount(owner[near], minlength=K).argmax())
    return out


def _bone_samples(character, per_bone: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """(S, 3) points along every bone (parent to child joint at bind) and (S,) the length each stands for."""
    p = np.asarray(character.bind_world, np.float64)[:, :3, 3]
    par = np.asarray(character.parents, np.int64)
    kids = np.nonzero(par >= 0)[0]
    if not len(kids):
        return np.zeros((0, 3)), np.zeros(0)
    s = (np.arange(per_bone) + 0.5) / per_bone
    a, b = p[par[kids]], p[kids]
    pts = a[:, None] + s[None, :, None] * (b - a)[:, None]
    w = np.repeat(np.linalg.norm(b - a, axis=1) / per_bone, per_bone)
    return pts.reshape(-1, 3), w


def _skeleton_inside(character, welded, ks) -> dict:
    """{piece: the bone length (m) inside it} for the closed pieces `ks`."""
    wv, wf, inverse, label = welded
    plabel = np.zeros(len(wv), np.int64)
    plabel[inverse] = label
    flab = plabel[wf[:, 0]]
    pts, w = _bone_samples(character)
    out = {}
    for k in ks:
        ff = wf[flab == k]
        if not len(pts) or not len(ff):
            out[k] = 0.0
            continue
        lo, hi = wv[np.unique(ff)].min(0), wv[np.unique(ff)].max(0)
        box = np.all((pts >= lo) & (pts <= hi), axis=1)             # outside its box: outside it
        inside = np.zeros(len(pts), bool)
        if box.any():
            inside[box] = np.abs(_winding(pts[box], wv[ff[:, 0]], wv[ff[:, 1]], wv[ff[:, 2]])) > 0.5
        out[k] = float(w[inside].sum())
    return out


def _shape_rule(s: dict) -> str | None:
    """The rule a rigidly bound piece's shape makes it hard by (RULE_SHEET, RULE_PLATE, RULE_SPIKE), or None."""
    if s["sheet"] > SHEET:
        return RULE_SHEET
    if s["thickness"] < PLATE:
        return RULE_PLATE
    if s["long"] >= SPIKE_LONG and s["taper"] < SPIKE_TAPER and s["fill"] <= SPIKE_FILL:
        return RULE_SPIKE
    return None


def find_rigid(character) -> RigidParts:
    """The parts of the skin that are hard (gear, shells), told from flesh by the mesh, not the weights alone.

    A piece is a welded connected component of the mesh (positions merged, so UV seams do not split
    it); it is bound rigidly when at least ALMOST_ALL (98%) of its vertices are (one joint carries >= 99%
    of the weight). A rigid binding is a choice about skinning, not evidence of metal, so a rigidly bound
    piece is decided by the first of these rules that holds (RigidParts.decided says which):

    1. a part (glTF node / primitive, Character.meta["parts"]) named like gear (GEAR_WORDS), or made of a
       material named so (GEAR_WORDS, METAL_WORDS; :func:`materials`): hard, whatever its weights (a part
       holding more than half of the vertices is the body, not gear);
    2. its shape says hard: a shell lying over other skin (SHELL_GAP: close to it, SHELL_VOLUME: holding less
       volume than what it covers), an open sheet (SHEET), a thin plate (PLATE), or a spike or shard (SPIKE_*);
    3. the body's own volume: the piece holding the most volume of the skin (at least BODY_SHARE of its
       closed pieces') and the piece the skeleton runs through most (no other piece holds more bone length at
       bind), and either bulky and rounded (not 2., BODY_FILL) or jointed (JOINTED: skinned rigidly bone by
       bone, as stylised rigs are): flesh, however it is weighted;
    4. otherwise a separate piece bound rigidly to one joint that is not the body's own volume: hard, as the
       file's artist bound it (eyes, teeth, a robot's segments); it has no edge to a soft neighbour, so
       following its bone leaves no seam to tear, and it rides the soft skin it sits on (:func:`ride`).

    Pieces that are not bound rigidly are tissue unless rule 1 names them.

    Why, from the files (figures as `jiggle inspect` reads them):

    - A round blob bound with weight 1 to its head joint, its eyes to a second joint (issue 50): the
      weights-alone rule (every rigid piece hard unless the skin rides one joint) took 973 of its 1,229
      vertices as rigid and its Walk peaked at 0.00% of its size. The shared Cat rebound so (body and ears
      on Body, eyes on Head; tests/character/test_gear.py): its body is 95% of the volume, 0.25 thick,
      fills 0.43 of its box and holds all the bone length, so rule 3 keeps it flesh; its Walk peaks within
      20% of the smoothly skinned Cat's.
    - RobotExpressive.glb (6660 vertices, 17 parts, 61 pieces): every part but the hand is bound to one
      joint with weight 1 (59 pieces, 6106 vertices). Its head holds 69% of the volume but 0.7% of the
      skeleton's bone length (the torso 14%, the hand 23%): no piece is the body's own volume, so every
      rigid piece stays hard (the torso shell had stretched 72-77 mm and torn 7-14 edges as tissue).
    - The Quaternius zoo (Horse, Cow, Frog, Cat, Orc, Demon, Goleling, Hywirl): the body is one piece
      skinned over 4-45 joints with 0-33% of its vertices rigid, so it stays tissue. The pieces rigid to one
      joint are eyes (pairs of 202-vertex balls on Head: rule 4), and the Orc's, Cat's and Goleling's small
      head pieces (ears, tongue, teeth, crest: open sheets or rule 4, 38-278 vertices on Head / Head3): hard
      as before, riding the soft head they sit on, so the zoo's jiggle is what it was.
    - CesiumMan and RiggedFigure are one piece over 19 joints (14% / 10% rigid): nothing is hard.

    Returns a RigidParts (how "auto").
    """
    rigid_v, joint = _rigid_vertices(character)
    welded = _welded(character)
    label = welded[3]
    bound = _bound_pieces(label, rigid_v)
    named, named_rule = _named_gear(character)
    shapes = piece_shapes(character, welded, gaps=np.nonzero(bound)[0]) if bound.any() else []
    rule_of = _hard_by_name_or_shape(label, bound, named, named_rule, shapes)     # rules 1 and 2
    if shapes:
        body = _body_volume(character, welded, joint, bound, shapes, rule_of)     # rule 3
        if body is not None:
            rule_of[body] = (RULE_BODY, False)
    for k in np.nonzero(bound)[0]:
        rule_of.setdefault(k, (RULE_PIECE, True))                                 # rule 4
    mask, why, soft, decided = _tally(character, label, joint, rule_of, named, named_rule)
    return _summary(character, mask | named, label, "auto", why, soft=soft, decided=decided)


def _bound_pieces(label: np.ndarray, rigid_v: np.ndarray) -> np.ndarray:
    """(pieces,) bool: the pieces (`label` (V,)) at least ALMOST_ALL of whose vertices are bound rigidly
    (`rigid_v` (V,) bool)."""
    n = int(label.max()) + 1 if len(label) else 0
    count = np.bincount(label, minlength=n)
    frac = np.bincount(label, weights=rigid_v.astype(np.float64), minlength=n) / np.maximum(count, 1)
    return frac >= ALMOST_ALL


def _named_gear(character) -> tuple[np.ndarray, np.ndarray]:
    """Rule 1: (V,) bool the vertices of parts (or materials) named like gear, none holding more than
    MAIN_BODY of the skin, and (V,) object the rule that named each (RULE_NAMED before RULE_MATERIAL), ""."""
    V = character.num_vertices
    named = np.zeros(V, bool)
    named_rule = np.full(V, "", object)
    lists = [(character.meta.get("parts", []) or [], GEAR_WORDS, RULE_NAMED),
             (materials(character), GEAR_WORDS + METAL_WORDS, RULE_MATERIAL)]
    for items, words, rule in lists:
        for name, first, cnt in items:
            if _gear_named(str(name), words) and cnt <= MAIN_BODY * V:
                new = ~named[first:first + cnt]
                named_rule[first:first + cnt][new] = rule
                named[first:first + cnt] = True
    return named, named_rule


def _hard_by_name_or_shape(label: np.ndarray, bound: np.ndarray, named: np.ndarray, named_rule: np.ndarray,
                           shapes: list) -> dict:
    """{piece: (rule, True)} for the rigidly bound pieces wholly named like gear (rule 1) or whose shape
    (piece_shapes) is a shell, a sheet, a plate or a spike (rule 2)."""
    rule_of = {}                    # piece -> (rule, hard)
    for k in np.nonzero(bound)[0]:
        vs = label == k
        if named[vs].all():
            rule_of[k] = (named_rule[np.argmax(vs)], True)
            continue
        s = shapes[k]
        if s["gap"] <= SHELL_GAP and s["over"] >= 0 and s["volume"] < SHELL_VOLUME * shapes[s["over"]]["volume"]:
            rule = RULE_SHELL
        else:
            rule = _shape_rule(s)
        if rule is not None:
            rule_of[k] = (rule, True)
    return rule_of


def _body_volume(character, welded, joint: np.ndarray, bound: np.ndarray, shapes: list, rule_of: dict) -> int | None:
    """Rule 3: the piece that is the body's own volume, when the largest closed piece is rigidly bound, not
    named as gear, holds BODY_SHARE of the closed pieces' volume, is jointed or bulky and rounded (not hard
    by its shape, BODY_FILL), and no other piece holds more bone length; else None. `joint` (V,): the joint
    of each vertex's largest weight."""
    label = welded[3]
    vol = np.array([s["volume"] for s in shapes])
    big = int(np.argmax(vol))
    s = shapes[big]
    named_big = rule_of.get(big, ("", True))[0] in (RULE_NAMED, RULE_MATERIAL)
    ridden = np.bincount(joint[label == big], minlength=character.num_joints)
    jointed = int(np.count_nonzero(ridden >= JOINTED * ridden.sum())) >= 2
    if (bound[big] and not named_big and vol[big] >= BODY_SHARE * vol.sum() > 0.0
            and (jointed or (big not in rule_of and s["fill"] >= BODY_FILL))):
        rivals = [k for k in range(len(bound)) if vol[k] > 0.0]
        inside = _skeleton_inside(character, welded, rivals)
        if inside[big] >= max(inside.values()):
            return big
    return None


def _tally(character, label: np.ndarray, joint: np.ndarray, rule_of: dict, named: np.ndarray,
           named_rule: np.ndarray) -> tuple[np.ndarray, dict, dict, tuple]:
    """What the rules decided: (V,) bool the vertices of hard pieces, {rule: vertices} hard (named parts
    that are not rigidly bound pieces counted as a whole), {rule: vertices} left soft, and one dict per
    decided piece (RigidParts.decided)."""
    mask = np.zeros(character.num_vertices, bool)
    why, soft, decided = {}, {}, []
    part_of = _part_names(character)
    for k, (rule, hard) in sorted(rule_of.items()):
        vs = np.nonzero(label == k)[0]
        if hard:
            mask[vs] = True
        (why if hard else soft)[rule] = (why if hard else soft).get(rule, 0) + len(vs)
        j = int(np.bincount(joint[vs]).argmax())
        decided.append({"piece": int(k), "part": part_of[vs[0]], "joint": character.joint_names[j],
                        "vertices": int(len(vs)), "rule": rule, "hard": bool(hard)})
    extra = named & ~mask
    if extra.any():                 # named parts that are not rigidly bound pieces: hard as a whole
        for rule in (RULE_NAMED, RULE_MATERIAL):
            c = int(np.count_nonzero(extra & (named_rule == rule)))
            if c:
                why[rule] = why.get(rule, 0) + c
    return mask, why, soft, tuple(decided)


def _part_names(character) -> np.ndarray:
    """(V,) object: the part (Character.meta["parts"]) each vertex belongs to, None outside every part."""
    out = np.full(character.num_vertices, None, object)
    for name, first, cnt in character.meta.get("parts", []) or []:
        out[first:first + cnt] = str(name)
    return out


def _summary(character, mask: np.ndarray, label: np.ndarray, how: str, why: dict, soft: dict | None = None,
             decided: tuple = ()) -> RigidParts:
    parts, partly = [], {}
    for name, first, cnt in character.meta.get("parts", []) or []:
        f = float(mask[first:first + cnt].mean()) if cnt else 0.0
        if f == 1.0:
            parts.append(str(name))
        elif f > 0.0:
            partly[str(name)] = f
    _, joint = _rigid_vertices(character)
    jc = np.bincount(joint[mask], minlength=character.num_joints)
    joints = tuple(character.joint_names[j] for j in np.argsort(-jc, kind="stable") if jc[j] > 0)
    n = int(label.max()) + 1 if len(label) else 0
    inside, total = np.bincount(label[mask], minlength=n), np.bincount(label, minlength=n)
    npieces = int(np.count_nonzero((inside == total) & (total > 0)))
    return RigidParts(mask=mask, pieces=npieces, parts=tuple(parts), partly=partly, joints=joints, how=how,
                      why=why, soft=dict(soft or {}), decided=tuple(decided))


def parse_rigid(character, spec) -> RigidParts:
    """The rigid parts a user asks for.

    spec : None or "auto": :func:`find_rigid`. "none" (or "off"): nothing is rigid. Otherwise a
        comma-separated list (or a list of str) of names, starting from the detection ("auto", implied)
        or from nothing ("none"): NAME makes rigid, -NAME (or !NAME) makes soft. A name is a part of
        Character.meta["parts"] (a glTF node's name, "node.N" for its primitive N; the node's name
        covers all its primitives) or a joint (its pieces bound rigidly to it: every vertex bound to it
        with weight >= RIGID_WEIGHT, for -JOINT every rigid vertex riding it). Matched without regard to case.

    InputError naming an unknown name and the names there are.
    """
    if isinstance(spec, RigidParts):
        return spec
    if spec is None or (isinstance(spec, str) and spec.strip().lower() == "auto"):
        return find_rigid(character)
    items = [s.strip() for s in (spec.split(",") if isinstance(spec, str) else list(spec))]
    items = [s for s in items if s]
    V = character.num_vertices
    base = "none" if any(s.lower() in ("none", "off") for s in items) else "auto"
    found = find_rigid(character) if base == "auto" else None
    mask = found.mask.copy() if found is not None else np.zeros(V, bool)
    why = dict(found.why) if found is not None else {}
    rigid_v, joint = _rigid_vertices(character)
    parts = character.meta.get("parts", []) or []
    jnames = {n.lower(): j for j, n in enumerate(character.joint_names)}
    for s in items:
        if s.lower() in ("auto", "none", "off"):
            continue
        soft = s[0] in "-!"
        name = s[1:].strip() if soft else s
        sel = np.zeros(V, bool)
        hit = False
        for pname, first, cnt in parts:
            p = str(pname).lower()
            if name.lower() in (p, re.sub(r"\.\d+$", "", p)):
                sel[first:first + cnt] = True
                hit = True
        if not hit and name.lower() in jnames:
            sel = (joint == jnames[name.lower()]) & (rigid_v | soft)
            hit = True
        if not hit:
            known = sorted({re.sub(r"\.\d+$", "", str(p[0])) for p in parts})
            raise InputError(f"{name!r} names no part and no joint of the character; parts: {', '.join(known[:20])}"
                             f"{' ...' if len(known) > 20 else ''}; joints: {', '.join(character.joint_names[:12])}"
                             f"{' ...' if character.num_joints > 12 else ''}", field="--rigid")
        if soft:
            mask &= ~sel
        else:
            mask |= sel
    how = ",".join(items)
    if mask.any():
        why = {"as asked (--rigid " + how + ")": int(mask.sum())}
    soft, decided = (found.soft, found.decided) if found is not None else ({}, ())
    return _summary(character, mask, pieces(character), how, why, soft=soft, decided=decided)




RIDE_REACH = 0.02
"""A rigid piece rides the soft skin within this fraction of the character's largest extent of it."""


@dataclass(frozen=True)
class Ride:
    """How the rigid pieces ride the tissue under them: each piece moves by one translation, the mean
    of its anchors' displacement (deformed skin - plain skinning), so it follows the jiggling body
    beneath as a whole without being stretched.

    rows : (R,) int64, the rigid vertices. piece : (R,) int64, each row's piece in 0..K-1.
    anchors : (A,) int64, soft vertices some piece rides. weights : (K, A) scipy.sparse csr, each
    piece's mean over its anchors (rows sum to 1, or 0 for a piece with no soft skin within reach:
    it follows its bones alone).
    """

    rows: np.ndarray
    piece: np.ndarray
    anchors: np.ndarray
    weights: object

    def apply(self, base: np.ndarray, skins) -> None:
        """Set every rigid vertex of each skin (T, V, 3) float32, in place, to `base` (the plain skin,
        (T, V, 3)) plus its piece's translation."""
        T = base.shape[0]
        K = self.weights.shape[0]
        b_rows = np.take(base, self.rows, axis=1)
        for sk in skins:
            if len(self.anchors):
                d = np.take(sk, self.anchors, axis=1) - np.take(base, self.anchors, axis=1)       # (T, A, 3)
                move = self.weights @ d.transpose(1, 0, 2).reshape(len(self.anchors), 3 * T)      # (K, 3T)
                move = np.asarray(move, np.float32).reshape(K, T, 3).transpose(1, 0, 2)           # (T, K, 3)
                sk[:, self.rows] = b_rows + move[:, self.piece]
            else:
                sk[:, self.rows] = b_rows


def ride(character, rigid: RigidParts, reach: float = RIDE_REACH) -> Ride:
    """The Ride of `rigid`'s pieces (welded components, rigid vertices only) on the soft skin: each
    rigid vertex's nearest soft vertex within `reach` x the largest extent is an anchor of its
    piece, counted once per such vertex (so a piece rides the part of the body it covers most)."""
    from scipy.sparse import csr_matrix
    from scipy.spatial import cKDTree
    v = np.asarray(character.vertices, np.float64)
    rows = np.nonzero(rigid.mask)[0]
    label = pieces(character)[rows]
    uniq, piece = np.unique(label, return_inverse=True)
    K = len(uniq)
    soft = np.nonzero(~rigid.mask)[0]
    size = float(np.ptp(v, axis=0).max()) if len(v) else 0.0
    if len(soft) == 0 or len(rows) == 0:
        return Ride(rows, piece.astype(np.int64), np.zeros(0, np.int64), csr_matrix((K, 0), dtype=np.float64))
    dist, near = cKDTree(v[soft]).query(v[rows], distance_upper_bound=reach * size)
    ok = np.isfinite(dist)
    used, col = np.unique(near[ok], return_inverse=True)
    w = csr_matrix((np.ones(int(ok.sum())), (piece[ok], col)), shape=(K, len(used)))
    total = np.asarray(w.sum(axis=1)).ravel()
    w = csr_matrix(w.multiply(1.0 / np.maximum(total, 1.0)[:, None]))
    return Ride(rows, piece.astype(np.int64), soft[used].astype(np.int64), w)


__all__ = ["RIGID_WEIGHT", "ALMOST_ALL", "GEAR_WORDS", "METAL_WORDS", "RIDE_REACH", "RULES", "RigidParts", "Ride",
           "pieces", "piece_shapes", "materials", "find_rigid", "parse_rigid", "ride"]
