"""Chains: the runs of joints that swing as secondary motion (tails, ears, hair, manes, antennae, trunks,
tentacles, fins, the fingers of a wing, capes and skirts made of bones), found on any rig.

A chain is a joint and the joints below it (a subtree: a strand, or a wing with its fingers) that carries skin
and that the tissue templates leave following its bones. `find_chains` takes them

- from names: a joint named with a word of APPENDAGE_WORDS ("Tail1", "Ear1.L", "hair_02", "Wing1.L") whose parent
  is not, with every joint below it;
- from shape: an unbranched run of at least MIN_RUN joints that carries skin, holds no tissue (no muscle rides
  it), plays no role in the body plan (limbs, spine, head) and has no limb word in its names (LIMB_WORDS: an
  arm, a finger, an IK or pole bone), hanging from a joint of the body;
- from the file: where a glTF defines spring bones (VRM's VRMC_springBone, rig.character.vrm_springs), those.

Joints a muscle rides stay with the body: a named chain whose first joints carry tissue starts below them.
Joints below a chain that carry no skin (end bones) are left out. `--chains auto|none|LIST` picks: auto the
rules above, none no chain, LIST names (joint names or globs, "Tail*"): each the root of a chain, or -NAME to
drop one auto finds.

`chain_links` measures each chain joint's link at bind: the bone from the joint to its child (a leaf's ends
where its skin ends along it), its radius from the skin the joint dominates, and its mass at tissue density;
sim.chain builds the swinging model from them.
"""
from __future__ import annotations

import fnmatch
import re
from dataclasses import dataclass

import numpy as np

from jiggle.rig.base.errors import InputError

APPENDAGE_WORDS = ("tail", "ear", "hair", "ponytail", "pony", "braid", "mane", "antenna", "antennae", "trunk",
                   "tentacle", "fin", "wing", "cape", "cloak", "skirt", "tassel", "whisker", "feather", "ribbon",
                   "strand", "bang", "bangs", "fringe", "scarf", "tie", "dangle", "earring", "flap", "tuft", "plume",
                   "crest", "frill", "tendril", "streamer")
"""Words in a joint's name that make it (and what hangs below it) a chain."""
LIMB_WORDS = ("arm", "forearm", "leg", "thigh", "calf", "shin", "hand", "foot", "feet", "finger", "thumb", "index",
              "middle", "ring", "pinky", "little", "toe", "toes", "jaw", "eye", "eyes", "tongue", "ik", "pole",
              "target", "root", "spine", "hip", "hips", "pelvis", "neck", "head", "shoulder", "clavicle", "knee",
              "elbow", "heel", "ball", "lid", "brow", "lip", "cheek", "teeth", "chest", "torso", "body", "back",
              "wrist", "ankle", "upper", "lower", "armature", "hoof", "paw")
"""Words that say a joint is part of the body's own animated frame, never a chain by shape alone."""
MIN_RUN = 2
"""Joints an unnamed run needs to be taken as a chain by its shape."""
DENSITY = 1000.0
"""kg/m^3: a link's mass is its capsule's volume at the density of soft tissue and water (hair, cartilage and
fur are near it; the swing does not depend on the mass, the springs are set per unit of inertia)."""
MIN_MASS = 0.3
"""No link of a chain is lighter than this share of its links' mean mass: a leaf bone's skin often ends in a few
vertices, and a near-massless tip would take the whole swing's energy and crack like a whip."""


def name_words(name: str) -> list[str]:
    """The lower-case words of a joint name ("FrontUpperLeg.L" -> front, upper, leg, l; "hair_02" -> hair)."""
    return [w.lower() for w in re.findall(r"[A-Z]?[a-z]+|[A-Z]+(?![a-z])", name)]


def _appendage(name: str) -> str | None:
    return next((w for w in name_words(name) if w in APPENDAGE_WORDS), None)


def _limb(name: str) -> str | None:
    return next((w for w in name_words(name) if w in LIMB_WORDS), None)


@dataclass(frozen=True)
class Chain:
    """One chain: `joints` (n,) the character's joint indices, parents first (joints[0] the root; a joint's
    parent is the root's parent `anchor` or another joint of the chain); `name` the root joint's name (what
    --chains and the per-chain parameters match); `reason` one phrase saying why it was taken; `source`
    "name", "shape", "vrm" or "user"; `spring` the file's own spring settings (VRM) or None."""

    name: str
    joints: tuple
    anchor: int
    reason: str
    source: str
    spring: dict | None = None

    def to_json(self, names=None) -> dict:
        out = {"chain": self.name, "joints": [names[j] for j in self.joints] if names is not None else
               list(self.joints), "why": self.reason, "source": self.source}
        if self.spring:
            out["spring"] = self.spring
        return out


@dataclass(frozen=True)
class Chains:
    """A character's chains and the mode that found them ("auto", "none" or the user's list)."""

    chains: tuple
    mode: str = "auto"

    def __len__(self) -> int:
        return len(self.chains)

    @property
    def names(self) -> tuple:
        return tuple(c.name for c in self.chains)

    @property
    def joints(self) -> np.ndarray:
        """(Jc,) every chain joint, chain after chain, parents first within each."""
        return np.array([j for c in self.chains for j in c.joints], np.int64)

    def describe(self, names) -> str:
        if not self.chains:
            return "chains: none" + (" (--chains none)" if self.mode == "none" else
                                     "; every appendage follows its bones (--chains NAME[,NAME] swings one)")
        rows = [f"chains: {len(self.chains)} swing as spring chains (--chains none keeps them on their bones)"]
        for c in self.chains:
            rows.append(f"  {c.name}: {len(c.joints)} joint{'s' * (len(c.joints) != 1)} "
                        f"({names[c.joints[0]]}..{names[c.joints[-1]]}), {c.reason}")
        return "\n".join(rows)

    def to_json(self, names) -> list:
        return [c.to_json(names) for c in self.chains]


def find_chains(character, tissue_joints=(), role_joints=(), mode: str | None = "auto", springs=None) -> Chains:
    """The character's chains (see the module).

    character : rig.character.character.Character. tissue_joints : joints a muscle rides (they stay with the
    body). role_joints : joints of the body plan's roles (limbs, spine, head). mode : "auto" (None too), "none",
    or a comma-separated list of joint names or globs to swing (-NAME drops a chain auto takes).
    springs : chains the file defines (rig.character.vrm_springs), taken first in auto.
    InputError (field --chains) for a name or glob that matches no joint.
    """
    mode = (mode or "auto").strip()
    names = tuple(character.joint_names)
    parents = np.asarray(character.parents)
    J = len(names)
    if mode.lower() == "none":
        return Chains((), "none")
    children = [[] for _ in range(J)]
    for j, p in enumerate(parents):
        if p >= 0:
            children[p].append(j)
    weight = np.zeros(J)
    np.add.at(weight, np.asarray(character.joints).ravel(), np.asarray(character.weights, np.float64).ravel())
    carries = weight > 1e-6                     # the joint or a joint below it carries skin
    for j in range(J - 1, -1, -1):               # parents come first: children after them
        if parents[j] >= 0 and carries[j]:
            carries[parents[j]] = True
    tissue = {int(j) for j in tissue_joints if j >= 0}
    roles = {int(j) for j in role_joints if j >= 0}
    taken: list[Chain] = []
    used = np.zeros(J, bool)

    def take(root: int, reason: str, source: str, spring=None) -> None:
        members = [k for k in _order(root, children) if carries[k] and k not in tissue and not used[k]]
        # a muscle riding the first joints keeps them with the body: the chain starts below them
        members = [k for k in members if not any(a in tissue for a in _ancestors(k, parents, root))]
        if not members:
            return
        used[members] = True
        top = members[0]
        taken.append(Chain(name=names[top], joints=tuple(members), anchor=int(parents[top]), reason=reason,
                           source=source, spring=spring))

    user = [] if mode.lower() == "auto" else [s.strip() for s in mode.split(",") if s.strip()]
    plus = [s for s in user if not s.startswith("-") and s.lower() != "auto"]
    minus = [s[1:] for s in user if s.startswith("-")]
    auto = mode.lower() == "auto" or not plus or any(s.lower() == "auto" for s in user)
    for pattern in plus + minus:
        if not any(fnmatch.fnmatchcase(n, pattern) for n in names):
            raise InputError(f"{pattern!r} matches no joint; the joints are {', '.join(names)}", field="--chains")
    for pattern in plus:
        for j in range(J):
            if fnmatch.fnmatchcase(names[j], pattern) and not used[j] and parents[j] >= 0:
                take(j, f"named by --chains ({pattern})", "user")
    if auto:
        for s in springs or ():
            j = s["joints"][0]
            if not used[j] and parents[j] >= 0:
                take(j, f"a spring bone of the file ({s.get('name') or 'VRMC_springBone'})", "vrm", s)
        for j in range(J):
            p = int(parents[j])
            if used[j] or p < 0 or not carries[j]:
                continue
            word = _appendage(names[j])
            if word and not _appendage(names[p]):
                take(j, f"named {'an' if word[0] in 'aeiou' else 'a'} {word}", "name")
        for j in range(J):
            p = int(parents[j])
            if used[j] or p < 0 or not carries[j] or used[p]:
                continue
            if not (p in tissue or p in roles) or j in tissue or j in roles:
                continue
            run = _run(j, children, carries)
            sub = _order(j, children)
            if len(run) < MIN_RUN or any(k in tissue or k in roles or _limb(names[k]) for k in sub) \
                    or _limb(names[p]) in ("ik", "pole", "target"):
                continue
            take(j, f"an unbranched run of {len(run)} joints with skin and no tissue", "shape")
    if minus:
        taken = [c for c in taken if not any(fnmatch.fnmatchcase(c.name, m) for m in minus)]
    return Chains(tuple(taken), "auto" if not user else mode)


def _order(root: int, children) -> list[int]:
    """root and its descendants, parents first (breadth first)."""
    out, queue = [], [root]
    while queue:
        k = queue.pop(0)
        out.append(k)
        queue.extend(children[k])
    return out


def _ancestors(k: int, parents, root: int) -> list[int]:
    """The joints from root down to k's parent."""
    out = []
    while k != root and k >= 0:
        k = int(parents[k])
        out.append(k)
    return out


def _run(j: int, children, carries) -> list[int]:
    """j and the joints below it while each has exactly one child that carries skin."""
    run = [j]
    while True:
        nxt = [c for c in children[run[-1]] if carries[c]]
        if len(nxt) != 1:
            return run
        run.append(nxt[0])


# ------------------------------------------------------------------------------------------------ links
@dataclass(frozen=True, eq=False)
class ChainLinks:
    """Every chain joint's link at bind, chains after one another (n joints in all).

    joints : (n,) the character's joint index of each; parent : (n,) index into these of its parent, -1 for a
    chain's root (it hangs from `anchor`). anchor : (n,) the character's joint a root hangs from (-1 for others).
    chain : (n,) which chain. local : (n, 4, 4) its bind transform in its parent's frame (the anchor's for a
    root). tip : (n, 3) metres, the far end of its bone in its own frame. radius : (n,) metres. mass : (n,) kg.
    arc : (n,) metres along the chain from the root's joint to this joint. length : (C,) metres, each chain's
    longest path from its root's joint to a tip.
    """

    joints: np.ndarray
    parent: np.ndarray
    anchor: np.ndarray
    chain: np.ndarray
    local: np.ndarray
    tip: np.ndarray
    radius: np.ndarray
    mass: np.ndarray
    arc: np.ndarray
    length: np.ndarray

    @property
    def count(self) -> int:
        return len(self.joints)


def chain_links(character, chains: Chains) -> ChainLinks:
    """Measure the links of `chains` on `character` at bind (see ChainLinks)."""
    bind = np.asarray(character.bind_world, np.float64)
    pos = bind[:, :3, 3]
    verts = np.asarray(character.vertices, np.float64)
    dominant = character.dominant_joint()
    parents = np.asarray(character.parents)
    rows = {k: [] for k in ("joints", "parent", "anchor", "chain", "local", "tip", "radius", "mass", "arc")}
    lengths = []
    for ci, c in enumerate(chains.chains):
        at = {j: len(rows["joints"]) + i for i, j in enumerate(c.joints)}
        arc: dict[int, float] = {}
        longest = 0.0
        for j in c.joints:
            p = int(parents[j])
            kids = [k for k in c.joints if parents[k] == j]
            if kids:                       # the bone runs to its farthest child in the chain
                end = pos[max(kids, key=lambda k: np.linalg.norm(pos[k] - pos[j]))]
            else:                          # a leaf: along its parent's bone, as far as its skin reaches
                d = pos[j] - pos[p]
                d = d / max(np.linalg.norm(d), 1e-12)
                own = verts[dominant == j]
                reach = float(np.percentile((own - pos[j]) @ d, 95)) if len(own) >= 3 else 0.0
                reach = reach if reach > 1e-6 else 0.5 * float(np.linalg.norm(pos[j] - pos[p]))
                end = pos[j] + d * reach
            L = float(np.linalg.norm(end - pos[j]))
            own = verts[dominant == j]
            if len(own) >= 3 and L > 1e-9:
                from jiggle.rig.character.capsules import segment_distance
                dist, _ = segment_distance(own, pos[j], end)
                r = 0.7 * float(np.percentile(dist, 20))
            else:
                r = 0.0
            r = float(np.clip(r, 0.05 * max(L, 1e-6), 0.5 * max(L, 1e-6)))
            inv = np.linalg.inv(bind[j])
            rows["joints"].append(j)
            rows["parent"].append(at.get(p, -1))
            rows["anchor"].append(p if p not in at else -1)
            rows["chain"].append(ci)
            rows["local"].append(np.linalg.inv(bind[p]) @ bind[j])
            rows["tip"].append((inv @ np.append(end, 1.0))[:3])
            rows["radius"].append(r)
            rows["mass"].append(DENSITY * np.pi * r * r * (max(L, 1e-9) + 4.0 * r / 3.0))   # the capsule's volume
            a = arc.get(p, 0.0)
            arc[j] = a + (float(np.linalg.norm(pos[j] - pos[p])) if p in at else 0.0)
            rows["arc"].append(arc[j])
            longest = max(longest, arc[j] + L)
        lengths.append(longest)
    n = len(rows["joints"])
    mass, chain = np.array(rows["mass"]), np.array(rows["chain"], np.int64)
    for ci in range(len(chains.chains)):    # a leaf's few skin vertices make a sliver: no link lighter than MIN_MASS
        mine = chain == ci
        mass[mine] = np.maximum(mass[mine], MIN_MASS * mass[mine].mean())
    rows["mass"] = mass
    return ChainLinks(joints=np.array(rows["joints"], np.int64), parent=np.array(rows["parent"], np.int64),
                      anchor=np.array(rows["anchor"], np.int64), chain=np.array(rows["chain"], np.int64),
                      local=np.array(rows["local"], np.float64).reshape(n, 4, 4),
                      tip=np.array(rows["tip"], np.float64).reshape(n, 3), radius=np.array(rows["radius"]),
                      mass=np.array(rows["mass"]), arc=np.array(rows["arc"]), length=np.array(lengths))
