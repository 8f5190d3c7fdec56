"""The skeleton a character's body plan and roles are read from: its own, with the helper bones set aside.

Game rigs hang IK targets and pole targets, and sometimes the feet themselves, off a root bone that carries no
skin (RobotExpressive, CC0: "Bone" holds Body, Foot.L, Foot.R, PoleTarget.L and PoleTarget.R; the legs end at
the knees). Read as it is, such a tree has one limb on the ground (both feet part at the root, beside each
other) and legs without feet: no template fits it. The skin says what the body is:

- bones whose whole subtree carries no skin weight, hanging off the weightless joints at the top of the tree
  (IK and pole targets, extra roots), are not part of the body: they are set aside (made roots of their own,
  so the body's tree no longer holds them);
- a small weighted part hanging there beside the body (a foot an IK chain places: at most a quarter of the
  body's joints and of its skin weight) belongs where it sits: it is hung under the body's joint nearest to it
  at rest (the foot under its lower leg).

Nothing else changes: weightless bones inside the body (end joints, twist helpers) stay, and a rig whose top
carries skin, or has one weighted child, is read as it is (the same clip object). Only the reading of the body
plan and roles uses this tree (rig.muscle.fit); the animation still moves the skeleton the file has.

The body's clip carries the skin weight each of its joints carries (``meta["joint_weight"]``, (J,) in its own
joint order): a quadruped's head end is the end whose off-leg part carries more skin (rig.motion.body_plan), so
a lowered head, a raised tail, horns or pole bones do not turn it around. A quadruped read as it is therefore
comes back as a copy of the file's skeleton with that entry; a biped's skeleton read as it is comes back itself.

When the joints alone still give no body plan (rig.motion.body_plan: "other"), the skin gives the bones their
tips: each chain's last joint without an end site gets one at the farthest skin vertex it moves most. A paw
whose last joint is the wrist then reaches the ground where its skin does (the glTF Fox's front legs end at
b_RightHand_08, a fifth of the height up), a tail ends where its skin ends. Skeletons with a plan are read
without them, so what they were read as does not change.
"""
from __future__ import annotations

import numpy as np

from jiggle.rig.base.frozen import frozen_array
from jiggle.rig.motion import quat
from jiggle.rig.motion.clip import Clip

SMALL_PART = 0.25
"""A weighted part beside the body with at most this share of the body's joints and skin weight is a placed part
(an IK foot), hung under its nearest body joint; a larger one is a body half, and the tree is left as it is."""


def joint_weight(character) -> np.ndarray:
    """(J,) the skin weight each joint carries, summed over the vertices."""
    w = np.zeros(character.num_joints)
    j = np.asarray(character.joints).ravel()
    wt = np.asarray(character.weights, float).ravel()
    live = j >= 0
    np.add.at(w, j[live], wt[live])
    return w


def body_skeleton(character) -> tuple[Clip, np.ndarray]:
    """(clip, order): the skeleton the body plan and roles are read from (see the module) and, for each of its
    joints, the index of that joint in character.skeleton (roles found on `clip` map back through `order`).
    clip.meta["joint_weight"] : (J,) the skin weight each of its joints carries (joint_weight, in clip's order).
    When no helper is set aside and the joints give a biped, `clip` is character.skeleton itself and `order`
    the identity; a quadruped read as it is is a copy that only adds the weights."""
    clip = character.skeleton
    J = clip.num_joints
    parents = np.asarray(clip.parents).copy()
    own = joint_weight(character)
    sub = own.copy()
    count = np.ones(J)
    for j in range(J - 1, -1, -1):
        if parents[j] >= 0:
            sub[parents[j]] += sub[j]
            count[parents[j]] += count[j]
    kids = [[] for _ in range(J)]
    for j, p in enumerate(parents):
        if p >= 0:
            kids[p].append(j)
    roots = [j for j in range(J) if parents[j] < 0]
    _, pos = clip.rest_world()
    changed = False
    r = max(roots, key=lambda j: sub[j])               # the tree that carries the skin
    while own[r] == 0:
        weighted = [c for c in kids[r] if sub[c] > 0]
        if not weighted:
            break
        main = max(weighted, key=lambda c: sub[c])
        placed = [c for c in weighted if c != main]
        if any(count[c] > SMALL_PART * count[main] or sub[c] > SMALL_PART * sub[main] for c in placed):
            break                                       # two body halves: read the tree as it is
        for c in kids[r]:
            if sub[c] == 0:
                parents[c] = -1                         # an IK or pole target: not the body
                changed = True
        in_body = np.zeros(J, bool)
        stack = [main]
        while stack:
            k = stack.pop()
            in_body[k] = True
            stack.extend(kids[k])
        cand = np.nonzero(in_body)[0]
        for c in placed:                                # a placed part: under the body joint nearest to it
            parents[c] = int(cand[np.argmin(np.linalg.norm(pos[cand] - pos[c], axis=1))])
            changed = True
        r = main                                        # on down the weightless top (the Horse: a root, then Body)
    order = _order(parents) if changed else np.arange(J)
    weight = frozen_array(own[order])
    body = _reparented(clip, parents, weight) if changed else clip
    from jiggle.rig.motion.body_plan import detect_body_plan
    kind = detect_body_plan(body, weights=weight).kind
    if kind == "other":
        tipped = _skin_tips(body, order, character, weight)
        if tipped is not None and detect_body_plan(tipped).kind != "other":
            return tipped, order
    if kind == "quadruped" and body is clip:
        # the head end is read from the skin: the weights travel with the clip (fit reads the plan and roles
        # from it through detect_body_plan and resolve_roles)
        import dataclasses
        body = dataclasses.replace(clip, meta={**clip.meta, "joint_weight": weight})
    return body, order


def _skin_tips(clip: Clip, order: np.ndarray, character, weight: np.ndarray) -> Clip | None:
    """`clip` with an end site at the farthest skin vertex of each childless joint that has none (the vertices
    each joint moves most, the character's first influence); None when no joint gets one."""
    J = clip.num_joints
    dominant = np.asarray(character.joints)[:, 0]
    vertices = np.asarray(character.vertices, float)
    new = np.empty(J, np.int64)
    new[order] = np.arange(J)
    has_kids = np.zeros(J, bool)
    has_kids[np.asarray(clip.parents)[np.asarray(clip.parents) >= 0]] = True
    has_end = np.zeros(J, bool)
    has_end[np.asarray(clip.end_parents, np.int64)] = True
    rot, pos = clip.rest_world()
    ends, offsets = [], []
    for k in np.nonzero(~has_kids & ~has_end)[0]:
        mine = vertices[dominant == order[k]]
        if not len(mine):
            continue
        far = mine[np.argmax(np.linalg.norm(mine - pos[k], axis=1))]
        ends.append(k)
        offsets.append(quat.rotate(quat.conj(rot[k]), far - pos[k]))
    if not ends:
        return None
    import dataclasses
    return dataclasses.replace(clip, end_parents=np.concatenate([clip.end_parents, ends]).astype(np.int32),
                               end_offsets=np.concatenate([np.reshape(clip.end_offsets, (-1, 3)), offsets]),
                               meta={**clip.meta, "body_skeleton": "bone tips from the skin", "joint_weight": weight})


def placed_parts(character) -> dict[int, int]:
    """{joint: body joint}: the small weighted parts body_skeleton hangs under a body joint (IK-placed feet), in
    the character's own joint indices; empty for a rig read as it is."""
    body, order = body_skeleton(character)
    if body is character.skeleton:
        return {}
    now = original_parents(body, order)
    was = np.asarray(character.parents)
    return {int(j): int(now[j]) for j in range(len(was)) if now[j] >= 0 and now[j] != was[j]}


def hang(clip: Clip, placed: dict[int, int], bind_world: np.ndarray) -> Clip:
    """`clip` (on the character's own skeleton) with each placed part moved rigidly with its body joint, keeping
    their relative transform in the bind pose `bind_world` (J, 4, 4): a retargeted clip moves the legs of an IK
    rig, not its foot targets, so without this the feet would stay where they stood at rest."""
    if not placed:
        return clip
    import dataclasses
    bind_world = np.asarray(bind_world, float)
    rest_r, rest_p = quat.from_matrix(bind_world[:, :3, :3]), bind_world[:, :3, 3]
    rot, pos = clip.world()
    rot, pos = rot.copy(), pos.copy()
    local_r, local_t = np.array(clip.rotations), np.array(clip.translations)
    for j, b in sorted(placed.items()):
        inv = quat.conj(rest_r[b])
        rel_r = quat.mul(inv, rest_r[j])
        rel_t = quat.rotate(inv, rest_p[j] - rest_p[b])
        rot[:, j] = quat.mul(rot[:, b], rel_r[None])
        pos[:, j] = pos[:, b] + quat.rotate(rot[:, b], rel_t[None])
        p = int(clip.parents[j])
        if p < 0:
            local_r[:, j], local_t[:, j] = rot[:, j], pos[:, j]
        else:
            pinv = quat.conj(rot[:, p])
            local_r[:, j] = quat.mul(pinv, rot[:, j])
            local_t[:, j] = quat.rotate(pinv, pos[:, j] - pos[:, p])
    return dataclasses.replace(clip, rotations=local_r, translations=local_t)


def original_parents(clip: Clip, order: np.ndarray) -> np.ndarray:
    """(J,) int32: the tree of body_skeleton's `clip` in the character's own joint indices (for the skin's
    segmentation and the bones' chains, which index the character's joints)."""
    out = np.full(len(order), -1, np.int32)
    for k, p in enumerate(np.asarray(clip.parents)):
        if p >= 0:
            out[order[k]] = order[p]
    return out


def _order(parents: np.ndarray) -> np.ndarray:
    """Joints in an order that lists parents before children (depth first, in the original order)."""
    J = len(parents)
    kids = [[] for _ in range(J)]
    for j, p in enumerate(parents):
        if p >= 0:
            kids[p].append(j)
    out, stack = [], [j for j in range(J - 1, -1, -1) if parents[j] < 0]
    while stack:
        j = stack.pop()
        out.append(j)
        stack.extend(sorted(kids[j], reverse=True))
    return np.array(out, np.int64)


def _reparented(clip: Clip, parents: np.ndarray, weight: np.ndarray) -> Clip:
    """`clip`'s rest pose (one frame) on the tree `parents`, the joints reordered so parents come first; every
    joint keeps its rest world rotation and position, every end site its place. weight : (J,) each joint's skin
    weight in the new order (meta["joint_weight"])."""
    order = _order(parents)
    new = np.empty(len(order), np.int64)
    new[order] = np.arange(len(order))
    rot, pos = clip.rest_world()
    par = np.array([new[parents[j]] if parents[j] >= 0 else -1 for j in order], np.int32)
    local_rot = rot[order].copy()
    offsets = pos[order].copy()
    for k, j in enumerate(order):
        p = parents[j]
        if p >= 0:
            inv = quat.conj(rot[p])
            local_rot[k] = quat.mul(inv, rot[j])
            offsets[k] = quat.rotate(inv, pos[j] - pos[p])
    return Clip(joint_names=[clip.joint_names[j] for j in order], parents=par, offsets=offsets,
                rest_rotations=local_rot, rotations=local_rot[None], translations=offsets[None], fps=clip.fps,
                end_parents=new[np.asarray(clip.end_parents, np.int64)], end_offsets=clip.end_offsets,
                name=clip.name, source=clip.source,
                meta={**clip.meta, "body_skeleton": "helpers set aside", "joint_weight": weight})
