"""An independent BVH forward kinematics for tests: its own tokenizer, 4x4 matrices, elementary
rotation matrices composed in channel order, no code shared with rig/.

World positions come out in the file's units and axes; `to_zup_metres` applies jiggle's convention
(Y-up -> Z-up: (x, y, z) -> (x, -z, y)).
"""
import numpy as np


def _rot(axis, deg):
    a = np.radians(deg)
    c, s = np.cos(a), np.sin(a)
    m = np.eye(4)
    i, j = {"X": (1, 2), "Y": (2, 0), "Z": (0, 1)}[axis]
    m[i, i], m[i, j], m[j, i], m[j, j] = c, -s, s, c
    return m


def parse(text):
    """-> joints [(name, parent, offset, channels)], ends [(parent, offset)], frames (F, C), frame_time."""
    tok = text.split()
    i = 0
    joints, ends, stack = [], [], []
    while tok[i] != "MOTION":
        t = tok[i]
        if t in ("ROOT", "JOINT"):
            joints.append([tok[i + 1], stack[-1] if stack else -1, None, []])
            stack.append(len(joints) - 1)
            i += 3  # name, "{"
        elif t == "End":
            off = np.array(tok[i + 4:i + 7], float)
            ends.append((stack[-1], off))
            i += 8  # End Site { OFFSET x y z }
        elif t == "OFFSET":
            joints[stack[-1]][2] = np.array(tok[i + 1:i + 4], float)
            i += 4
        elif t == "CHANNELS":
            n = int(tok[i + 1])
            joints[stack[-1]][3] = tok[i + 2:i + 2 + n]
            i += 2 + n
        elif t == "}":
            stack.pop()
            i += 1
        else:
            i += 1
    nframes = int(tok[i + 2])
    dt = float(tok[i + 5])
    vals = np.array(tok[i + 6:], float)
    return joints, ends, vals.reshape(nframes, -1), dt


def world_positions(joints, frames):
    """(F, J, 3) joint positions in file units and axes, one 4x4 product per joint per frame."""
    F, J = frames.shape[0], len(joints)
    out = np.zeros((F, J, 3))
    for f in range(F):
        col = 0
        mats = []
        for name, parent, offset, chans in joints:
            trans = offset.copy()
            rot = np.eye(4)
            for c in chans:
                v = frames[f, col]
                col += 1
                if c.endswith("position"):
                    trans["XYZ".index(c[0])] = v
                else:
                    rot = rot @ _rot(c[0], v)
            local = np.eye(4)
            local[:3, 3] = trans
            local = local @ rot
            m = local if parent < 0 else mats[parent] @ local
            mats.append(m)
            out[f, len(mats) - 1] = m[:3, 3]
    return out


def to_zup_metres(p, scale):
    return np.stack([p[..., 0], -p[..., 2], p[..., 1]], axis=-1) * scale
