"""A skeleton's body plan (biped, quadruped, other) from its rest pose's geometry, the roles of a
four-legged skeleton, and the geometric checks every role map must pass before it is used.

Detection (:func:`detect_body_plan`), from the joint tree and the rest pose (no names), and the skin
weight per joint when it is known:

1. Ground limbs: tips (end sites, childless joints) within GROUND of the skeleton's height above its
   lowest point, grouped by limb: two tips are on different limbs when their chains part at least
   LIMB_SPLIT of the height away from the lower tip (a heel and a toe part at the ankle, two feet at
   the pelvis, a front and a hind paw at the spine).
2. Two ground limbs whose chains meet (the hips) below the skeleton's highest point by a spine
   steeper than UPRIGHT degrees: a biped. Four ground limbs that pair into two girdles (the pairing
   whose meeting joints lie nearest their paws, the girdles being distinct joints) joined by a spine
   flatter than UPRIGHT: a quadruped. Anything else: other (no built-in template fits it: the fit puts
   tissue on it with the generic template, rig.muscle.generic).
3. Quadruped: which end is the front. When the skin weight each joint carries is known (``weights``,
   or ``clip.meta["joint_weight"]``, which rig.character.body_skeleton sets), the head end is the girdle
   whose off-leg part beyond it (the joints hanging there, not on a leg nor on the spine between the
   girdles) carries at least SKIN_DECIDES times the other's skin: a head and neck carry most of it, a
   tail is a thin chain, horns and IK or pole bones carry little or none, so neither a lowered head, a
   raised tail nor horns turn it around. Without weights, or when neither end clearly carries more (a
   skin spread evenly over the joints), the head end is the one nearer the highest point off the legs.
   With weights, the head is then read along that end's main line, from the chest: the line goes on
   into the child whose subtree carries HEAD_BRANCH times the skin of its siblings' together (the only
   child with skin, or the neck past a mane's bone) and stops where it ends or branches into comparable
   parts (two ears, two horns): that joint is the head (a skinless head-top marker does not count; a
   lone jaw joint below the head is read as the head, as the chain to the muzzle's tip was before);
   without, the head is the last joint of the chain to the farthest point past the highest one. The girdle
   at the head end is the chest (front legs), the other the hips (hind legs). A tail is a chain that reaches
   back past the hips by at least TAIL_REACH of the spine's length and starts at the hips (its first joint
   within TAIL_START of the spine's length of them, so an IK or pole target hung off the root is none); with
   weights, it carries skin.

Quadruped roles (:data:`QUADRUPED_ROLES`; a role names the joint at the start of its bone, as the
human ones do): hips (hind girdle), spine (first joint after the hips towards the chest), chest
(front girdle), neck and head (first and last joint towards the head top: a childless head joint, as
glTF has them, is the head), tail (its first joint),
and per leg ``<side>_<front|hind>_`` + shoulder (front only: a scapula joint above the shoulder),
upper_leg (shoulder or hip joint), lower_leg (elbow or stifle), foot (carpus or hock), toe (the paw
joint, when the chain's last joint sits within TOE_HEIGHT of the leg's height above the ground).
Legs are read from the paw up, so extra joints at the girdle (a pelvis joint per leg) are ignored.

Checks (:func:`check_roles`), on any role map, human or quadruped, preset, file or automatic: each
limb's roles follow one chain of the tree down from its girdle in order. A map found by shape must also
mirror: each ``left_X`` / ``right_X`` pair mirrors across the body's mid-plane (the plane through the
hips whose normal is the horizontal left-right direction of the paired upper legs) within MIRROR of the
limb's length. A map found by names (a preset, a file) need not: its names say left and right, and a
bind pose with a foot forward or an arm raised is no reason to refuse them; it is only refused when its
left leg clearly stands on the character's right (the toes say where the front is; see SWAPPED). A map
that fails is refused with the roles found and the ones missing, never applied.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from jiggle.rig.base.errors import InputError
from jiggle.rig.motion.clip import Clip
from jiggle.rig.motion.retarget import ROLES
from jiggle.rig.motion.skeleton_tree import SkeletonTree

UP = np.array([0.0, 0.0, 1.0])
GROUND = 0.1
"""Tips this share of the skeleton's height above its lowest point stand on the ground."""
LIMB_SPLIT = 0.3
"""Ground tips whose chains part at least this share of the height away from them are on different limbs."""
UPRIGHT = 45.0
"""Degrees above the horizontal: a steeper spine is upright (biped), a flatter one horizontal (quadruped)."""
TAIL_REACH = 0.15
"""A tail reaches back past the hips by at least this share of the hips-to-chest distance."""
TOE_HEIGHT = 0.12
"""A leg's last joint within this share of the leg's height above the ground is a toe (paw) joint."""
SKIN_DECIDES = 2.0
"""The skin decides which end is the head's when one end carries at least this many times the other's skin."""
HEAD_BRANCH = 3.0
"""The neck's line goes on into a child whose subtree carries this many times the skin of its siblings together."""
TAIL_START = 0.5
"""A tail's first joint lies within this share of the hips-to-chest distance of the hips."""
MIRROR = 0.25
"""A left role and its right twin mirrored across the mid-plane lie within this share of the limb's length."""
SWAPPED = 0.5
"""A name map's left and right are swapped when its left hip stands on the character's right by more than this
share of the hips' horizontal spacing (cos 60 deg off the left), the front being where the toes point, and only
when they point clearly (their summed horizontal reach at least this share of their length)."""

SIDES = ("left", "right")
ENDS = ("front", "hind")
FRONT_LEG = ("shoulder", "upper_leg", "lower_leg", "foot", "toe")
HIND_LEG = ("upper_leg", "lower_leg", "foot", "toe")
QUADRUPED_ROLES = ("hips", "spine", "chest", "neck", "head", "tail") + tuple(
    f"{s}_{e}_{r}" for s in SIDES for e in ENDS for r in (FRONT_LEG if e == "front" else HIND_LEG))
QUADRUPED_REQUIRED = ("hips", "chest", "head") + tuple(
    f"{s}_{e}_{r}" for s in SIDES for e in ENDS for r in ("upper_leg", "lower_leg", "foot"))
TEMPLATE_OF_PLAN = {"biped": "human", "quadruped": "quadruped"}


@dataclass(frozen=True)
class BodyPlan:
    """What a skeleton is, from its rest pose.

    kind : "biped", "quadruped" or "other".
    ground_limbs : limbs that reach the ground at rest.
    spine_deg : the spine's angle above the horizontal, degrees (hips to head top for a biped, hips to
        chest for a quadruped; NaN when there is no spine).
    tail : a tail was found (quadrupeds).
    reason : one sentence saying why, for messages and reports.
    """

    kind: str
    ground_limbs: int
    spine_deg: float
    tail: bool
    reason: str

    @property
    def template(self) -> str | None:
        """The built-in template for this plan, or None (other)."""
        return TEMPLATE_OF_PLAN.get(self.kind)

    def to_json(self) -> dict:
        return {"kind": self.kind, "ground_limbs": self.ground_limbs,
                "spine_deg": None if not np.isfinite(self.spine_deg) else round(self.spine_deg, 1),
                "tail": self.tail, "reason": self.reason}


def detect_body_plan(clip: Clip, *, weights: np.ndarray | None = None) -> BodyPlan:
    """The body plan of `clip`'s skeleton (its rest pose; see the module docstring).

    weights : (J,) the skin weight each joint carries (summed over the vertices; any unit), which tells a
        quadruped's head end from its tail's; default clip.meta["joint_weight"], else none (geometry only).
    """
    return _Plan(clip, weights).plan


def quadruped_roles(clip: Clip, *, weights: np.ndarray | None = None) -> dict[str, int]:
    """{role: joint index} (QUADRUPED_ROLES) of a four-legged skeleton; InputError naming what could not
    be found when the skeleton is not a quadruped. weights : as detect_body_plan's."""
    p = _Plan(clip, weights)
    if p.plan.kind != "quadruped":
        raise InputError(f"not a four-legged skeleton: {p.plan.reason}", clip.source or None, field="roles")
    return p.quadruped_roles()


# ------------------------------------------------------------------------------------- checks
def _pairs(roles: dict[str, int]) -> list[tuple[str, int, int]]:
    """(role without side, left joint, right joint) of every role mapped on both sides."""
    return [(r[5:], j, roles["right_" + r[5:]]) for r, j in roles.items()
            if r.startswith("left_") and "right_" + r[5:] in roles]


def check_roles(clip: Clip, roles: dict[str, int], known: tuple[str, ...] | None = None, *,
                mirror: bool = True) -> None:
    """Refuse a role map the skeleton's geometry contradicts (see the module docstring).

    roles : {role: joint index} of `clip`'s skeleton. known : every role the map could hold (for the
    message's list of missing roles); default the human roles or QUADRUPED_ROLES, by the keys.
    mirror : True for a map found by shape: left and right roles must mirror each other at rest. False for
        a map found by names (a preset, a file): the bind pose may be asymmetric; only a left hip clearly on
        the character's right (left and right swapped) is refused.
    Raises InputError naming the first failing pair or chain, the roles found and the ones missing.
    """
    if not roles:
        return
    known = known or (QUADRUPED_ROLES if any(r in QUADRUPED_ROLES and r not in ROLES for r in roles) else ROLES)
    _, pos = clip.rest_world()
    names = clip.joint_names
    problems = []
    pairs = _pairs(roles)
    paired = {k for k, _, _ in pairs}
    tops = [k for k in ("upper_leg", "hind_upper_leg", "front_upper_leg", "upper_arm") if k in paired]
    if not mirror:
        swapped = _swapped(pos, roles, names)
        if swapped:
            problems.append(swapped)
    elif tops:
        left = np.zeros(3)
        for k, a, b in pairs:
            if k in tops:
                d = pos[a] - pos[b]
                left += d - (d @ UP) * UP
        mid = np.mean([0.5 * (pos[a] + pos[b]) for k, a, b in pairs if k in tops], axis=0)
        if np.linalg.norm(left) < 1e-9:
            problems.append(f"the left and right {tops[0]} sit at one place")
        else:
            left /= np.linalg.norm(left)
            reflect = np.eye(3) - 2.0 * np.outer(left, left)
            length = _limb_length(pos, roles)
            for k, a, b in pairs:
                mirrored = mid + (pos[b] - mid) @ reflect.T
                err = float(np.linalg.norm(mirrored - pos[a]))
                if err > MIRROR * length:
                    problems.append(f"left_{k} ({names[a]}) and right_{k} ({names[b]}) do not mirror each "
                                    f"other ({err:.3g} m apart once mirrored; limbs are {length:.3g} m long)")
    for chain in _chains(roles):
        present = [r for r in chain if r in roles]
        for hi, lo in zip(present[:-1], present[1:]):
            a, b = roles[hi], roles[lo]
            j = b
            while j >= 0 and j != a:
                j = int(clip.parents[j])
            if j != a or a == b:
                problems.append(f"{lo} ({names[b]}) is not below {hi} ({names[a]}) in the joint tree")
    if problems:
        missing = [r for r in known if r not in roles]
        raise InputError(f"the role map does not fit the skeleton's shape: {'; '.join(problems[:3])}. Roles found: "
                         f"{', '.join(f'{r}={names[j]}' for r, j in roles.items())}; missing: "
                         f"{', '.join(missing) or 'none'}. Give a joint map that fits (or the right --template)",
                         clip.source or None, field="roles")


def _swapped(pos: np.ndarray, roles: dict[str, int], names: tuple[str, ...]) -> str:
    """Why a name map's left and right are swapped against the rest pose, or "" when they are not (or the pose
    cannot tell). The front is where the toes point (ankle to ball, both feet summed: a foot forward or an arm
    raised leaves it alone); left = up x front; the left hip must not stand clearly on that right side."""
    keys = ("upper_leg", "foot", "toe")
    if not all(f"{s}_{k}" in roles for s in SIDES for k in keys):
        return ""
    reach = [pos[roles[f"{s}_toe"]] - pos[roles[f"{s}_foot"]] for s in SIDES]
    toes = np.sum(reach, axis=0)
    toes[2] = 0.0
    if np.linalg.norm(toes) < SWAPPED * sum(np.linalg.norm(r) for r in reach):
        return ""                                       # toes straight down or splayed apart: no front to go by
    left = np.cross(UP, toes / np.linalg.norm(toes))
    hips = pos[roles["left_upper_leg"]] - pos[roles["right_upper_leg"]]
    hips[2] = 0.0
    if hips @ left < -SWAPPED * np.linalg.norm(hips):
        a, b = roles["left_upper_leg"], roles["right_upper_leg"]
        return (f"left_upper_leg ({names[a]}) stands on the character's right of right_upper_leg ({names[b]}), "
                f"the toes pointing to the front: left and right are swapped")
    return ""


def _limb_length(pos: np.ndarray, roles: dict[str, int]) -> float:
    """A limb's length (metres): the longest upper-leg-to-foot (or shoulder-to-hand) span mapped."""
    spans = [np.linalg.norm(pos[roles[a]] - pos[roles[b]])
             for s in SIDES for a, b in ((f"{s}_upper_leg", f"{s}_foot"), (f"{s}_hind_upper_leg", f"{s}_hind_foot"),
                                         (f"{s}_front_upper_leg", f"{s}_front_foot"), (f"{s}_upper_arm", f"{s}_hand"))
             if a in roles and b in roles]
    return float(max(spans)) if spans else float(np.ptp(pos, axis=0).max())


def _chains(roles: dict[str, int]) -> list[tuple[str, ...]]:
    out = [("hips", "spine", "chest", "neck", "head")]
    for s in SIDES:
        out += [tuple(f"{s}_{r}" for r in ("shoulder", "upper_arm", "lower_arm", "hand")),
                tuple(f"{s}_{r}" for r in ("upper_leg", "lower_leg", "foot", "toe")),
                tuple(f"{s}_front_{r}" for r in FRONT_LEG), tuple(f"{s}_hind_{r}" for r in HIND_LEG)]
    return out


# ------------------------------------------------------------------------------------- detection
class _Plan(SkeletonTree):
    """Detection on one skeleton (see the module docstring)."""

    def __init__(self, clip: Clip, weights: np.ndarray | None = None):
        super().__init__(clip)
        w = clip.meta.get("joint_weight") if weights is None else weights
        # (J,) skin weight per joint, or None: a list of another length belongs to another skeleton
        self.weight = np.asarray(w, float) if w is not None and len(w) == clip.num_joints else None
        self.head_joint = -1                            # found by the skin, else
        self.head_pt = -1                               # the head end's highest point
        pts = self.pts
        self.floor = float(pts[:, 2].min())
        self.height = float(np.ptp(pts[:, 2]))
        self.limbs = self._ground_limbs()
        self.plan = self._classify()

    def _ground_limbs(self) -> list[int]:
        """Point index of the lowest tip of each limb that reaches the ground."""
        low = self.tips & (self.pts[:, 2] <= self.floor + GROUND * self.height)
        limbs: list[int] = []
        for i in np.flatnonzero(low)[np.argsort(self.pts[low, 2], kind="stable")]:
            o = int(self.owner[i])
            if all(np.linalg.norm(self.pos[self.lca(o, int(self.owner[r]))] - self.pts[i]) >= LIMB_SPLIT * self.height
                   for r in limbs):
                limbs.append(int(i))
        return limbs

    def _angle(self, a: np.ndarray, b: np.ndarray) -> float:
        d = b - a
        return float(np.degrees(np.arctan2(abs(d[2]), np.linalg.norm(d[:2]))))

    def _classify(self) -> BodyPlan:
        n = len(self.limbs)
        own = [int(self.owner[i]) for i in self.limbs]
        if n == 2:
            hips = self.lca(*own)
            off = ~np.array([any(self.under(int(o), self.path(hips, f)[0]) for f in own) for o in self.owner])
            top = int(np.flatnonzero(off)[np.argmax(self.pts[off, 2])]) if off.any() else -1
            if top >= 0:
                ang = self._angle(self.pos[hips], self.pts[top])
                if ang >= UPRIGHT and self.pts[top, 2] > self.pos[hips, 2]:
                    self.hips = hips
                    return BodyPlan("biped", 2, ang, False, f"two legs to the ground and an upright spine "
                                    f"({ang:.0f} deg above the horizontal)")
                return BodyPlan("other", 2, ang, False, f"two legs to the ground but a spine {ang:.0f} deg above "
                                f"the horizontal (a biped's is upright, above {UPRIGHT:g} deg)")
            return BodyPlan("other", 2, float("nan"), False, "two legs to the ground and nothing above them")
        if n == 4:
            best = None
            for a, b, c, d in ((0, 1, 2, 3), (0, 2, 1, 3), (0, 3, 1, 2)):
                g1, g2 = self.lca(own[a], own[b]), self.lca(own[c], own[d])
                if g1 == g2:
                    continue
                cost = sum(np.linalg.norm(self.pos[g] - self.pts[self.limbs[i]])
                           for g, i in ((g1, a), (g1, b), (g2, c), (g2, d)))
                if best is None or cost < best[0]:
                    best = (cost, (g1, (a, b)), (g2, (c, d)))
            if best is None:
                return BodyPlan("other", 4, float("nan"), False, "four limbs to the ground that all meet at one "
                                "joint (no front and hind girdle)")
            (g1, p1), (g2, p2) = best[1], best[2]
            ang = self._angle(self.pos[g1], self.pos[g2])
            if ang >= UPRIGHT:
                return BodyPlan("other", 4, ang, False, f"four limbs to the ground but a spine {ang:.0f} deg above "
                                f"the horizontal (a quadruped's is flatter than {UPRIGHT:g} deg)")
            ends = self._ends(own, g1, g2)
            if ends is not None and max(ends[g1], ends[g2]) >= SKIN_DECIDES * min(ends[g1], ends[g2]):
                # the skin says which end is the head's
                (chest, front), (hips, hind) = ((g1, p1), (g2, p2)) if ends[g1] > ends[g2] else ((g2, p2), (g1, p1))
                how = ", the head end carrying more skin"
            else:
                head = self._head_top(own)
                if head < 0:
                    return BodyPlan("other", 4, ang, False, "four limbs to the ground and no head off them")
                hp = self.pts[head]
                near = lambda g: np.linalg.norm((hp - self.pos[g])[:2])  # noqa: E731
                (chest, front), (hips, hind) = sorted([(g1, p1), (g2, p2)], key=lambda x: near(x[0]))
                self.head_pt = head
                how = ", the head end the higher"
            if ends is not None:
                self.head_joint = self._head_line(chest, ends["off"], ends["spine"])
            self.girdles = {"chest": chest, "hips": hips}
            self.legs = {"front": [self.limbs[i] for i in front], "hind": [self.limbs[i] for i in hind]}
            self.tail_pt = self._tail(own)
            return BodyPlan("quadruped", 4, ang, self.tail_pt >= 0,
                            f"four legs to the ground and a horizontal spine ({ang:.0f} deg)"
                            + (", a tail" if self.tail_pt >= 0 else "") + how)
        return BodyPlan("other", n, float("nan"), False, f"{n} limb{'s' if n != 1 else ''} reach the ground at rest "
                        f"(a biped has two, a quadruped four)")

    def _limb_firsts(self, feet: list[int]) -> set[int]:
        """The first joint of each ground limb: below the deepest joint where its foot's chain meets another
        foot's (its girdle)."""
        firsts = set()
        for a in feet:
            g = max((self.lca(a, b) for b in feet if b != a), key=lambda j: self.depth[j])
            firsts.add(self.path(g, a)[0] if g != a else a)
        return firsts

    def _off_limbs(self, feet: list[int]) -> np.ndarray:
        """(P,) bool: points on no ground limb."""
        firsts = self._limb_firsts(feet)
        return ~np.array([any(self.under(int(o), f) for f in firsts) for o in self.owner])

    def _ends(self, feet: list[int], g1: int, g2: int) -> dict | None:
        """{g1: skin, g2: skin} beyond each girdle (off the legs and the spine between them), "off": (J,) bool
        off-leg joints, "spine": the joints from one girdle to the other}; None when no weights are known."""
        if self.weight is None:
            return None
        firsts = self._limb_firsts(feet)
        top = self.lca(g1, g2)
        spine = {top, *self.path(top, g1), *self.path(top, g2)}
        off = np.array([self.in_tree[j] and not any(self.under(j, f) for f in firsts)
                        for j in range(len(self.parents))])
        # each off-leg joint's end: the girdle it hangs from, walking up to the spine (a joint hanging
        # between the girdles, or above the spine's top, belongs to neither end)
        mass = {g1: 0.0, g2: 0.0}
        for j in np.flatnonzero(off):
            a = int(j)
            while a >= 0 and a not in spine:
                a = int(self.parents[a])
            if a in mass and int(j) != a:
                mass[a] += self.weight[j]
        return {**mass, "off": off, "spine": spine}

    def _head_line(self, chest: int, off: np.ndarray, spine: set[int]) -> int:
        """The head joint along the head end's main line from the chest (see the module docstring), or -1
        when nothing with skin hangs beyond the chest."""
        # the skin each off-leg joint's subtree carries (deepest joints first)
        sub = np.where(off, self.weight, 0.0)
        for j in np.argsort(-self.depth, kind="stable"):
            if self.parents[j] >= 0 and off[j]:
                sub[self.parents[j]] += sub[j]
        line = lambda j: [int(k) for k in self.kids[j] if off[k] and k not in spine and sub[k] > 0]  # noqa: E731
        kids = line(chest)
        if not kids:
            return -1
        head = max(kids, key=lambda k: sub[k])
        while line(head):
            nxt = max(line(head), key=lambda k: sub[k])
            if sub[nxt] < HEAD_BRANCH * (sub[line(head)].sum() - sub[nxt]):
                break                                   # two ears, two horns: the line branches at the head
            head = nxt                                  # the neck goes on (past a mane's or a dewlap's bone)
        return head

    def _head_top(self, feet: list[int]) -> int:
        off = self._off_limbs(feet)
        return int(np.flatnonzero(off)[np.argmax(self.pts[off, 2])]) if off.any() else -1

    def _tail(self, feet: list[int]) -> int:
        """Point index of the tail's farthest point, or -1 when no chain that starts at the hips (and, with
        weights, carries skin) reaches back past them."""
        hips, chest = self.girdles["hips"], self.girdles["chest"]
        axis = self.pos[hips] - self.pos[chest]
        length = np.linalg.norm(axis[:2])
        if length < 1e-9:
            return -1
        axis = np.array([axis[0], axis[1], 0.0]) / length
        back = (self.pts - self.pos[hips]) @ axis  # metres behind the hips; the spine and head are ahead
        cand = self._off_limbs(feet) & (back > TAIL_REACH * length)
        for i in np.flatnonzero(cand)[np.argsort(-back[cand], kind="stable")]:
            chain = self.path(self.lca(hips, int(self.owner[i])), int(self.owner[i]))
            if not chain:
                continue
            if np.linalg.norm(self.pos[chain[0]] - self.pos[hips]) > TAIL_START * length:
                continue                                # starts away from the hips: an IK or pole target
            if self.weight is not None and self.weight[chain].sum() <= 0:
                continue                                # no skin: a helper bone
            return int(i)
        return -1

    # -------------------------------------------------------------------------------- roles
    def quadruped_roles(self) -> dict[str, int]:
        hips, chest = self.girdles["hips"], self.girdles["chest"]
        roles: dict[str, int] = {"hips": hips, "chest": chest}
        if self.under(chest, hips):
            spine = self.groups(self.path(hips, chest))
            if len(spine) >= 2:
                roles["spine"] = spine[0][0]
        if self.head_joint >= 0 and self.under(self.head_joint, chest):
            last = self.head_joint                      # found by the skin: the head joint itself
        elif self.head_pt >= 0:
            head_joint = int(self.owner[self.head_pt])
            far = self.farthest_below(head_joint)
            last = int(self.owner[far]) if far >= 0 else head_joint  # the chain goes on to the muzzle's tip
        else:
            last = chest                                # no head: refused below
        neck = self.groups(self.path(chest, last)) if self.under(last, chest) else []
        if not neck:
            raise InputError("cannot find the head below the chest (the front girdle) in the joint tree",
                             self.where, field="roles")
        roles["head"] = neck[-1][0]
        if roles["head"] != neck[0][0]:
            roles["neck"] = neck[0][0]
        if self.tail_pt >= 0:
            t = int(self.owner[self.tail_pt])
            base = self.lca(hips, t)
            chain = self.path(base, t)
            if chain:
                roles["tail"] = chain[0]
        front = self.pos[chest] - self.pos[hips]
        front = np.array([front[0], front[1], 0.0]) / np.linalg.norm(front[:2])
        left = np.cross(UP, front)
        for end, girdle in (("front", chest), ("hind", hips)):
            legs = [self._leg(girdle, p, end) for p in self.legs[end]]
            side = [float(np.mean([self.pos[j] for j in r.values()], axis=0) @ left) for r in legs]
            order = ("left", "right") if side[0] >= side[1] else ("right", "left")
            for s, r in zip(order, legs):
                roles.update({f"{s}_{end}_{k}": j for k, j in r.items()})
        return {r: roles[r] for r in QUADRUPED_ROLES if r in roles}

    def _leg(self, girdle: int, paw: int, end: str) -> dict[str, int]:
        """Roles of one leg, read from the paw up (see the module docstring)."""
        g = self.groups(self.path(girdle, int(self.owner[paw])))
        if len(g) < 3:
            raise InputError(f"a {end} leg has {len(g)} joints below the girdle; a leg needs at least "
                             f"three (upper, lower leg and foot)", self.where, field="roles")
        names = ("upper_leg", "lower_leg", "foot")
        leg_height = self.pos[g[0][0], 2] - self.floor
        toe = len(g) >= 4 and self.pos[g[-1][0], 2] - self.floor <= TOE_HEIGHT * max(leg_height, 1e-9)
        if toe:
            names += ("toe",)
        out = dict(zip(names, [grp[0] for grp in g[-len(names):]]))
        if end == "front" and len(g) > len(names):
            out["shoulder"] = g[-len(names) - 1][0]
        return out
