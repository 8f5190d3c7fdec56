"""Gear and hard surfaces: the parts of a character's skin that are not tissue.

Armour plates, helmets, pouches, weapons, a robot's metal shells: they ride the body under them
without stretching. :func:`find_rigid` finds them from the skin alone (its docstring gives the rule
and the figures it was set from); :func:`parse_rigid` reads the user's override (``--rigid``);
rig.skin.muscle_skin.MuscleSkin keeps the shell deformers off them, so they follow plain skinning
(their bone, rigidly, for a shell bound to one joint) in the static and the jiggling skin alike.
"""
from __future__ import annotations

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
"""Words in a part's (glTF node's) name that mark it as gear."""
MAIN_BODY = 0.5
"""A part named like gear holding more than this fraction of the skin's vertices is the body, not gear."""


@dataclass(frozen=True)
class RigidParts:
    """What of a character's skin is not tissue.

    mask : (V,) bool, the vertices that follow plain skinning (no shell deformer, no jiggle).
    pieces : number of welded connected components wholly in `mask`.
    parts : the parts (Character.meta["parts"] names) wholly rigid; `partly`: {part: fraction} of those
        only partly so.
    joints : the joints the rigid vertices ride (their largest weight), most vertices first.
    how : "auto" (detected), "none", or the --rigid value that set it.
    why : {reason: vertices}, e.g. {"bound rigidly to one joint": 6106}.
    """

    mask: np.ndarray
    pieces: int = 0
    parts: tuple = ()
    partly: dict = field(default_factory=dict)
    joints: tuple = ()
    how: str = "auto"
    why: dict = field(default_factory=dict)

    @property
    def count(self) -> int:
        return int(np.count_nonzero(self.mask))

    @property
    def any(self) -> bool:
        return bool(self.mask.any())

    def to_json(self) -> dict:
        """bake.json's / inspect's record (no per-vertex data)."""
        V = len(self.mask)
        return {"how": self.how, "vertices": self.count, "of": V, "pieces": self.pieces, "parts": list(self.parts),
                "partly": {k: round(v, 3) for k, v in self.partly.items()}, "joints": list(self.joints),
                "why": dict(self.why)}

    def describe(self) -> str:
        """One line for the bake's log."""
        if not self.any:
            return f"rigid parts ({self.how}): none; all the skin is tissue"
        names = list(self.parts) + [f"{k} ({v:.0%})" for k, v in self.partly.items()]
        shown = ", ".join(names[:10]) + (f" and {len(names) - 10} more" if len(names) > 10 else "")
        return (f"rigid parts ({self.how}): {self.count} of {len(self.mask)} vertices in {self.pieces} piece(s) follow "
                f"their bones without jiggle: {shown} (on {', '.join(self.joints[:8])}"
                f"{' ...' if len(self.joints) > 8 else ''}); --rigid overrides")


def pieces(character) -> np.ndarray:
    """(V,) int64: the welded connected component of each vertex (positions closer than WELD x the
    largest extent are one vertex, so UV and normal seams do not split a piece)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    from jiggle.rig.character.bone_heat import WELD_TOLERANCE, weld
    v = np.asarray(character.vertices, np.float64)
    f = np.asarray(character.faces, np.int64)
    size = float(np.ptp(v, axis=0).max()) if len(v) else 0.0
    _, wf, inverse = weld(v, f, max(WELD_TOLERANCE, WELD * size))
    P = int(inverse.max()) + 1 if len(inverse) else 0
    a = np.concatenate([wf[:, 0], wf[:, 1], wf[:, 2]])
    b = np.concatenate([wf[:, 1], wf[:, 2], wf[:, 0]])
    g = coo_matrix((np.ones(len(a)), (a, b)), shape=(P, P))
    _, label = connected_components(g, directed=False)
    return label[inverse].astype(np.int64)


def _rigid_vertices(character) -> tuple[np.ndarray, np.ndarray]:
    """(V,) bool bound rigidly (one weight >= RIGID_WEIGHT) and (V,) int64 the joint of each vertex's
    largest weight."""
    w = np.asarray(character.weights, np.float64)
    j = np.asarray(character.joints, np.int64)
    k = np.argmax(w, axis=1)
    rows = np.arange(len(w))
    return w[rows, k] >= RIGID_WEIGHT, j[rows, k]


def _gear_named(name: str) -> bool:
    words = re.split(r"[^a-z]+", name.lower())
    return any(w.startswith(g) for w in words if w for g in GEAR_WORDS)


def find_rigid(character) -> RigidParts:
    """The parts of the skin that are hard (gear, shells), found from the skin alone.

    Rule: a piece is hard when it is a welded connected component of the mesh (positions merged, so
    UV seams do not split it) of which at least ALMOST_ALL (98%) of the vertices are bound rigidly
    (one joint carries >= 99% of the weight), unless the whole skin is made of such pieces all riding
    one single joint (then that is a body that moves as one, a blob, whose tissue must jiggle: nothing is
    hard). A part (glTF node / primitive of Character.meta["parts"]) named like gear (GEAR_WORDS) is
    hard as a whole, whatever its weights, unless it holds more than half of the vertices (the body).

    Why, from the files (figures as `jiggle inspect` reads them):

    - RobotExpressive.glb (6660 vertices, 17 parts, 61 pieces): every part but the hand is bound to
      one joint with weight 1 at every vertex (Torso.0/1 on Body, Head_13.* on Head, Leg.L on
      UpperLeg.L, ...; 59 pieces, 6106 vertices); the hand (Hand.R.0/1, 554 vertices, one piece) is
      skinned over 12 joints, only 32% of it rigidly. Treated as tissue, the torso shell stretched by
      72-77 mm at its waist edge and tore 7-14 edges (gradient p99.9 0.99-1.10) on the Running clip: a
      metal can does not jiggle.
    - The Quaternius zoo (Horse, Cow, Frog, Cat, Orc, Demon, Goleling, Hywirl): the body is one piece
      skinned over 4-45 joints with 0-33% of its vertices rigid (Horse 20%, Frog 13%, Cat 0%, Orc 0.7%),
      so it stays tissue. The pieces rigid to one joint are eyes (pairs of 202-vertex balls on Head),
      and the Orc's, Cat's and Goleling's small head pieces (tongue, teeth, crest, ears: 38-278
      vertices on Head / Head3): hard in the file's own skinning, and hard here; they ride the soft
      head they sit on (:func:`ride`), so the zoo's jiggle is what it was (max 16-81 mm, unchanged).
      Demon's, Hywirl's and Cow's eyes share their weight with the neck (Head 0.5-0.95): they stay
      tissue, as the file skins them.
    - CesiumMan and RiggedFigure are one piece over 19 joints (14% / 10% rigid): nothing is hard.
    - A piece rigid to one bone counts even when it is large (the robot's head, 1742 vertices over 30
      pieces): what makes it hard is that the file's artist bound it so, and a separate piece has no
      edge to a soft neighbour, so following its bone exactly leaves no seam to tear. Only a skin that
      is wholly rigid to ONE joint is left soft: nothing else would move it.

    Returns a RigidParts (how "auto").
    """
    V = character.num_vertices
    rigid_v, joint = _rigid_vertices(character)
    label = pieces(character)
    n = int(label.max()) + 1 if V else 0
    count = np.bincount(label, minlength=n)
    frac = np.bincount(label, weights=rigid_v.astype(np.float64), minlength=n) / np.maximum(count, 1)
    hard_piece = frac >= ALMOST_ALL
    if hard_piece.all() and len(np.unique(joint[rigid_v])) <= 1:
        hard_piece[:] = False           # one body riding one joint: its tissue jiggles as a whole
    mask = hard_piece[label]
    why = {}
    if mask.any():
        why["bound rigidly to one joint"] = int(mask.sum())
    named = np.zeros(V, bool)
    for name, first, cnt in character.meta.get("parts", []) or []:
        if _gear_named(str(name)) and cnt <= MAIN_BODY * V:
            named[first:first + cnt] = True
    if (named & ~mask).any():
        why["named like gear"] = int((named & ~mask).sum())
    return _summary(character, mask | named, label, "auto", why)


def _summary(character, mask: np.ndarray, label: np.ndarray, how: str, why: dict) -> RigidParts:
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
                      why=why)


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
    return _summary(character, mask, pieces(character), how, why)




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


__all__ = ["RIGID_WEIGHT", "ALMOST_ALL", "GEAR_WORDS", "RIDE_REACH", "RigidParts", "Ride", "pieces", "find_rigid",
           "parse_rigid", "ride"]
