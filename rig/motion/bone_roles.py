"""Roles of a skeleton's bones (trunk, neck, head, limb), found from the joint tree and rest pose
alone, so any naming works. Used to size MuJoCo capsules and generated bodies."""
from __future__ import annotations

import numpy as np

from jiggle.rig.motion.clip import Clip


def bone_roles(clip: Clip) -> list[list[str]]:
    """Role of every bone, per joint: ``roles[j][k]`` for the k-th bone leaving joint j, bones listed
    as in the MJCF (children in order, then end sites). Roles: "trunk", "neck", "head", "limb".

    Found from the tree and the rest pose, so that it works for any naming:
    - spine: from a root, follow the child holding more than half of the joints below while there is
      one; the chest is the last joint on that path with two or more children, and it must lie above
      the root in the rest pose. No chest (a lone leg, a chain): every bone is a limb.
    - trunk: the spine bones up to the chest, and the pelvis bones, which leave the root (or a joint
      at the root's place, like CMU's LHipJoint) towards a child off the spine.
    - neck and head: from the chest, the chain that reaches highest in the rest pose; its last bone
      of non-zero length is the head, the others are neck.
    """
    J = clip.num_joints
    kids = [clip.children(j) for j in range(J)]
    ends = [[o for e, o in zip(clip.end_parents, clip.end_offsets) if e == j] for j in range(J)]
    roles = [["limb"] * (len(kids[j]) + len(ends[j])) for j in range(J)]
    size = np.ones(J, int)
    for j in range(J - 1, -1, -1):
        if clip.parents[j] >= 0:
            size[clip.parents[j]] += size[j]
    rest_rot, rest_pos = clip.rest_world()
    end_z = clip.end_world(rest_rot[None], rest_pos[None])[0][:, 2] if len(clip.end_parents) else np.zeros(0)
    top = rest_pos[:, 2].copy()  # highest rest z in each subtree, end sites included
    for e, z in zip(clip.end_parents, end_z):
        top[e] = max(top[e], z)
    for j in range(J - 1, -1, -1):
        if clip.parents[j] >= 0:
            top[clip.parents[j]] = max(top[clip.parents[j]], top[j])

    bone = clip.bone_translations

    def length(j: int, k: int) -> float:
        tip = bone[kids[j][k]] if k < len(kids[j]) else ends[j][k - len(kids[j])]
        return float(np.linalg.norm(tip))

    for root in np.nonzero(clip.parents < 0)[0]:
        path = [int(root)]
        while kids[path[-1]]:
            big = max(kids[path[-1]], key=lambda c: size[c])
            if size[big] <= 0.5 * (size[path[-1]] - 1):
                break
            path.append(big)
        branch = [i for i, j in enumerate(path) if len(kids[j]) >= 2]
        if not branch:
            continue
        path = path[:branch[-1] + 1]
        chest = path[-1]
        if chest == root or rest_pos[chest, 2] <= rest_pos[root, 2]:
            continue
        for a, b in zip(path[:-1], path[1:]):
            roles[a][kids[a].index(b)] = "trunk"
        # joints sitting at the root's place (zero offsets), e.g. CMU's LHipJoint under Hips
        at_root, stack = [], [int(root)]
        while stack:
            j = stack.pop()
            at_root.append(j)
            stack += [c for c in kids[j] if np.linalg.norm(bone[c]) < 1e-4]
        for j in at_root:
            for k, c in enumerate(kids[j]):
                if c not in path and c not in at_root:
                    roles[j][k] = "trunk"
        # neck chain: from the chest towards the highest point of the rest pose
        chain, j = [], chest
        while kids[j] or ends[j]:
            opts = [(top[c], k) for k, c in enumerate(kids[j])]
            opts += [(z, len(kids[j]) + i) for i, z in enumerate(end_z[clip.end_parents == j])]
            k = max(opts)[1]
            chain.append((j, k))
            if k >= len(kids[j]):
                break
            j = kids[j][k]
        chain = [(j, k) for j, k in chain if length(j, k) >= 1e-4]
        for i, (j, k) in enumerate(chain):
            roles[j][k] = "head" if i == len(chain) - 1 else "neck"
    return roles
