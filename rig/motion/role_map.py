"""Which joint of a skeleton plays each humanoid role (rig.motion.retarget.ROLES), by name or by shape.

:func:`resolve_roles` takes an explicit joint map (a preset name, a TOML path or a
:class:`rig.motion.retarget.JointMap`), else a built-in preset that fits the skeleton's names, else
:func:`auto_roles`, which reads the roles off the joint tree and the rest pose alone, so any naming
works. :func:`facing` gives a rest pose's front and left directions from its roles.

Role semantics are those of the presets: a role names the joint at the *start* of its bone
("left_upper_arm" is the shoulder joint, "left_lower_arm" the elbow, "left_hand" the wrist,
"left_upper_leg" the hip joint, "left_lower_leg" the knee, "left_foot" the ankle, "left_toe" the
ball of the foot, "left_shoulder" the collar bone's joint); "left" is the character's own left.
"""
from __future__ import annotations

import os
import warnings

import numpy as np

from jiggle.rig.base.errors import InputError, JiggleWarning
from jiggle.rig.motion.body_plan import check_roles, detect_body_plan, quadruped_roles
from jiggle.rig.motion.clip import Clip
from jiggle.rig.motion.retarget import ROLES, JointMap, presets
from jiggle.rig.motion.skeleton_tree import SkeletonTree

UP = np.array([0.0, 0.0, 1.0])
OTHER_LIMB = 0.6
"""Two tips lie on different limbs when their chains part at least this fraction of the way from the
first tip to where its limb leaves the trunk (the fingers of one hand part at the wrist, the two
hands at the chest)."""
HEAD_MARKER = 0.17
"""A childless last joint of the neck chain, without an end site, whose bone is longer than this
fraction of the hip height is a head-top marker (Mixamo's HeadTop_End), not the head joint: the head
is then its parent. Neck bones are ~0.1 of the hip height, a whole head ~0.25."""


def auto_roles(clip: Clip) -> dict[str, int]:
    """{role: joint index} found from the joint tree and the rest pose only (any joint names).

    clip : any skeleton (its rest pose: offsets and rest rotations, Z-up metres); the largest joint
        tree is used when there are several roots.

    How the roles are found (points are joints and end sites; "groups" merge consecutive joints of a
    chain that sit at the same place, a group's role goes to its first joint):

    1. Head and feet: the head top is the highest point. The first foot is the lowest tip (end site
       or childless joint) ending a leg-like chain (three or more joints off the path to the head
       top, starting well above the tip: not a root or IK joint on the floor); the second foot is
       the lowest such tip on another limb (its chain parts from the first foot's near the trunk,
       not at the ankle like a heel's). hips = the joint where the feet's and the head's chains
       meet (the pelvis, or the root above a separate pelvis joint).
    2. Hands: the point off the legs and the hips-to-head path that lies farthest along the tree
       from that path (a fingertip or a wrist's end site: the arms are the trunk's longest branches
       besides the legs, in any pose), then the farthest on another limb. chest = where the hands'
       chains leave the hips-to-head path. spine = the first joint above the hips on that path,
       even at the hips' place (CMU's LowerBack); left out when the chest is the hips' child. When
       the arms leave at the hips themselves, spine and chest are both left out.
    3. neck = the first joint after the chest on the path to the head top; head = the last one
       (its parent when the last is a long childless marker without end site, see HEAD_MARKER).
    4. Arms, along the chest-to-hand path: upper_arm starts the longest bone that has two joints
       after it (the humerus is the longest arm bone); lower_arm and hand are the next two groups;
       shoulder is the group before upper_arm, if any (no collar bone: left out).
    5. Legs, along the hips-to-foot path: upper_leg starts the longest pair of consecutive bones
       (thigh + shin), lower_leg and foot are the next two groups; toe = the first joint past the
       ankle towards the ankle's farthest descendant point (the toes rather than a heel), if any.
    6. Sides: the front is where the toes point (ankle to its farthest descendant, horizontal, both
       feet summed); failing that where the knees stand out of the hip-ankle lines; failing that -Y
       (glTF's front), with a JiggleWarning. left = cross(up, front) with up = +Z; the leg (arm)
       whose joints lie further along left is the left one.

    Roles that do not exist (no collar bone, no toe, no spine joint) are left out. Limitations: a
    rest pose with the arms above the head, upper arms or shins split into twist segments along the
    chain, and face joints above the head top can fool it; give a joint map then.

    Raises InputError when no two legs, two arms and a head can be told apart.
    """
    return _AutoRoles(clip).roles


def resolve_roles(clip: Clip, joint_map: str | os.PathLike | JointMap | None = None) -> dict[str, int]:
    """{role: joint index} of `clip`'s skeleton, checked against its shape
    (rig.motion.body_plan.check_roles: a map the geometry contradicts is refused, never applied).

    joint_map : None: the first built-in preset (rig.motion.retarget.presets()) whose roles all find a
        joint in the skeleton and fit its shape, else the automatic map of its body plan
        (rig.motion.body_plan): :func:`auto_roles` for a biped, the quadruped roles for a quadruped. A
        preset name, a TOML path or a JointMap: that map, resolved against the joint names (InputError
        naming the file and key when a joint is missing or the preset/file does not exist).

    Names come first: a map resolved by names (a preset, a file) is checked for its chains' order and
    for swapped sides only, not for mirror symmetry, so a bind pose with a foot forward or an arm raised
    keeps its named roles; only a map found by shape must also mirror (check_roles' `mirror`).
    """
    if joint_map is None:
        for name in presets():
            try:
                roles = JointMap.load(name).resolve(clip.joint_names)
                check_roles(clip, roles, mirror=False)
                return roles
            except InputError:
                continue
        if detect_body_plan(clip).kind == "quadruped":
            roles = quadruped_roles(clip)
        else:
            roles = auto_roles(clip)
        check_roles(clip, roles)
        return roles
    jm = joint_map if isinstance(joint_map, JointMap) else JointMap.load(joint_map)
    label = f"of {clip.source or clip.name}" if (clip.source or clip.name) else ""
    roles = jm.resolve(clip.joint_names, label)
    check_roles(clip, roles, mirror=False)
    return roles


def facing(positions: np.ndarray, roles: dict[str, int]) -> tuple[np.ndarray, np.ndarray]:
    """Front and left (3,) unit horizontal directions of a pose (Z-up).

    positions : (J, 3) joint positions, metres.
    roles : {role: joint index}, with left/right_upper_leg (or, failing those, a quadruped's
        left/right_hind_upper_leg, then left/right_upper_arm or front_upper_leg).

    left = horizontal part of left_upper_leg - right_upper_leg (the next pair when the legs are not
    mapped or coincide); front = cross(left, up), up = +Z. CesiumMan: left = +X, front = -Y.
    Raises InputError when neither pair is mapped or both pairs coincide horizontally.
    """
    pos = np.asarray(positions, dtype=float)
    for limb in ("upper_leg", "hind_upper_leg", "upper_arm", "front_upper_leg"):
        a, b = roles.get(f"left_{limb}"), roles.get(f"right_{limb}")
        if a is None or b is None:
            continue
        left = pos[a] - pos[b]
        left[2] = 0.0
        n = np.linalg.norm(left)
        if n > 1e-9:
            left /= n
            front = np.cross(left, UP)
            return front, left
    raise InputError("cannot tell the character's front: the roles left/right_upper_leg and "
                     "left/right_upper_arm are not mapped, or each pair sits at one place",
                     field="roles")


class _AutoRoles(SkeletonTree):
    """The steps of :func:`auto_roles` on one skeleton (see its docstring)."""

    def __init__(self, clip: Clip):
        super().__init__(clip)
        self.roles = self._find()

    def _fail(self, what: str) -> InputError:
        return InputError(f"cannot find the {what} from the skeleton's shape (joints: "
                          f"{', '.join(self.clip.joint_names)}); give a joint map", self.where, field="roles")

    def other_limb(self, first: int, trunk: int) -> np.ndarray:
        """(P,) bool: points whose chain parts from point `first`'s at least OTHER_LIMB of the way
        from it to `trunk` (where its limb leaves the trunk)."""
        return self.parts_from(first, trunk, OTHER_LIMB)

    # ------------------------------------------------------------------ the steps
    def _find(self) -> dict[str, int]:
        pts, owner = self.pts, self.owner
        # 1. head top and feet
        top = int(np.argmax(pts[:, 2]))
        head_tip = int(owner[top])
        # feet: the lowest tips (end sites, childless joints) ending a leg-like chain, which leaves
        # the head's path high up and has hip, knee and ankle (not a root or IK joint on the floor)
        tip = self.tips
        for i in np.flatnonzero(tip):
            start = self.lca(int(owner[i]), head_tip)
            chain = self.path(start, int(owner[i]))
            tip[i] = (len(self.groups(chain)) >= 3
                      and self.pos[chain[0], 2] - pts[i, 2] > 0.25 * (pts[top, 2] - pts[i, 2]))
        if not tip.any():
            raise self._fail("legs")
        foot1 = int(np.flatnonzero(tip)[np.argmin(pts[tip, 2])])
        trunk1 = self.lca(int(owner[foot1]), head_tip)
        cand = tip & self.other_limb(foot1, trunk1)
        if not cand.any():
            raise self._fail("second leg")
        foot2 = int(np.flatnonzero(cand)[np.argmin(pts[cand, 2])])
        hips = self.lca(trunk1, int(owner[foot2]))
        legs = [self.path(hips, int(owner[f])) for f in (foot1, foot2)]
        if hips == head_tip:
            raise self._fail("head above the legs")

        # 2. hands, chest and spine
        trunk_path = set([hips] + self.path(hips, head_tip))
        leg_roots = {leg[0] for leg in legs}
        arm_ok = np.array([self.under(int(o), hips) and int(o) not in trunk_path
                           and not any(self.under(int(o), r) for r in leg_roots) for o in owner])
        if not arm_ok.any():
            raise self._fail("arms")
        # length along the tree from the hips-head path: arms are the longest branches off the trunk
        # (besides the legs), whatever their pose (a T-pose, or hanging straight down)
        along = np.zeros(len(self.pos))
        for j, p in enumerate(self.parents):
            if p >= 0 and j not in trunk_path:
                along[j] = along[p] + np.linalg.norm(self.pos[j] - self.pos[p])
        reach = along[owner] + np.linalg.norm(pts - self.pos[owner], axis=1)
        hand1 = int(np.flatnonzero(arm_ok)[np.argmax(reach[arm_ok])])
        cand = arm_ok & self.other_limb(hand1, self.lca(int(owner[hand1]), head_tip))
        if not cand.any() or reach[cand].max() < 0.5 * reach[hand1]:
            raise self._fail("second arm")
        hand2 = int(np.flatnonzero(cand)[np.argmax(reach[cand])])
        leave = [self.lca(int(owner[h]), head_tip) for h in (hand1, hand2)]
        chest = min(leave, key=lambda j: self.depth[j])  # the lower, if the arms leave at two joints
        arms = [self.path(chest, int(owner[h])) for h in (hand1, hand2)]
        spine_path = self.path(hips, chest)
        roles: dict[str, int] = {"hips": hips}
        if len(spine_path) >= 2:
            roles["spine"] = spine_path[0]
        if chest != hips:
            roles["chest"] = chest

        # 3. neck and head
        neck = self.groups(self.path(chest, head_tip))
        if not neck:
            raise self._fail("head")
        last = neck[-1][-1]
        hip_height = self.pos[hips, 2] - pts[foot1, 2]
        if (len(neck) >= 3 and not self.kids[last] and not self.has_end[last]
                and np.linalg.norm(self.pos[neck[-1][0]] - self.pos[neck[-2][0]]) > HEAD_MARKER * hip_height):
            neck = neck[:-1]
        roles["head"] = neck[-1][0]
        if len(neck) >= 2:
            roles["neck"] = neck[0][0]

        # 4./5. limbs, then 6. sides
        arm_roles = [self._arm(a) for a in arms]
        leg_roles = [self._leg(g) for g in legs]
        front = self._front(leg_roles)
        left = np.cross(UP, front)
        for limbs, keys in ((leg_roles, ("upper_leg", "lower_leg", "foot")),
                            (arm_roles, ("upper_arm", "lower_arm", "hand"))):
            side = [float(np.mean([self.pos[r[k]] for k in keys], axis=0) @ left) for r in limbs]
            order = ("left", "right") if side[0] >= side[1] else ("right", "left")
            for s, r in zip(order, limbs):
                roles.update({f"{s}_{k}": j for k, j in r.items()})
        return {r: roles[r] for r in ROLES if r in roles}

    def _arm(self, chain: list[int]) -> dict[str, int]:
        g = self.groups(chain)
        if len(g) < 3:
            raise self._fail("arm joints (shoulder, elbow and wrist)")
        bone = [np.linalg.norm(self.pos[g[i + 1][0]] - self.pos[g[i][0]]) for i in range(len(g) - 2)]
        i = int(np.argmax(bone))
        out = {"upper_arm": g[i][0], "lower_arm": g[i + 1][0], "hand": g[i + 2][0]}
        if i >= 1:
            out["shoulder"] = g[i - 1][0]
        return out

    def _leg(self, chain: list[int]) -> dict[str, int]:
        g = self.groups(chain)
        if len(g) < 3:
            raise self._fail("leg joints (hip, knee and ankle)")
        bone = [np.linalg.norm(self.pos[g[i + 1][0]] - self.pos[g[i][0]]) for i in range(len(g) - 1)]
        i = int(np.argmax([bone[k] + bone[k + 1] for k in range(len(g) - 2)]))
        out = {"upper_leg": g[i][0], "lower_leg": g[i + 1][0], "foot": g[i + 2][0]}
        # toe: the first joint away from the ankle towards its farthest descendant point
        ankle = g[i + 2][-1]
        far = self.farthest_below(ankle)
        if far >= 0:
            for j in self.path(ankle, int(self.owner[far])):
                if np.linalg.norm(self.pos[j] - self.pos[ankle]) >= self.eps:
                    out["toe"] = j
                    break
        return out

    def _front(self, legs: list[dict[str, int]]) -> np.ndarray:
        """(3,) unit horizontal front of the rest pose from the feet (or knees)."""
        toes = np.zeros(3)
        for r in legs:
            ankle = r["foot"]
            far = self.farthest_below(ankle)
            if far >= 0:
                toes += self.pts[far] - self.pos[ankle]
        toes[2] = 0.0
        if np.linalg.norm(toes) > 10 * self.eps:
            return toes / np.linalg.norm(toes)
        # knees stand forward of the hip-ankle line (flexed) in a relaxed rest pose
        lat = self.pos[legs[0]["upper_leg"]] - self.pos[legs[1]["upper_leg"]]
        lat[2] = 0.0
        lat = lat / max(np.linalg.norm(lat), 1e-12)
        knee = np.zeros(3)
        for r in legs:
            knee += self.pos[r["lower_leg"]] - 0.5 * (self.pos[r["upper_leg"]] + self.pos[r["foot"]])
        knee[2] = 0.0
        knee -= (knee @ lat) * lat
        if np.linalg.norm(knee) > 2 * self.eps:
            return knee / np.linalg.norm(knee)
        warnings.warn(f"{self.where + ': ' if self.where else ''}neither the toes nor the knees show which way "
                      f"the skeleton faces; assuming -Y (glTF's front) to tell left from right",
                      JiggleWarning, stacklevel=5)  # auto_roles' caller
        return np.array([0.0, -1.0, 0.0])
