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


# A hierarchy that exercises the format: 6 channels on a non-root joint, unusual channel orders,
# position channels placed after rotations, a joint without channels, End Sites, two roots.
ODD_HIERARCHY = """HIERARCHY
ROOT base
{
  OFFSET 1.0 2.0 3.0
  CHANNELS 6 Xposition Yposition Zposition Yrotation Xrotation Zrotation
  JOINT arm
  {
    OFFSET 0.0 10.0 0.0
    CHANNELS 3 Xrotation Zrotation Yrotation
    JOINT slider
    {
      OFFSET 5.0 0.0 0.0
      CHANNELS 6 Zrotation Xrotation Yrotation Xposition Yposition Zposition
      JOINT fixed
      {
        OFFSET 0.0 0.0 4.0
        CHANNELS 0
        End Site
        {
          OFFSET 1.0 1.0 1.0
        }
      }
    }
  }
  JOINT twist
  {
    OFFSET -3.0 0.0 0.0
    CHANNELS 1 Yrotation
    End Site
    {
      OFFSET 0.0 -2.0 0.0
    }
  }
}
ROOT prop
{
  OFFSET 0.0 0.0 0.0
  CHANNELS 3 Xposition Yposition Zposition
  End Site
  {
    OFFSET 0.0 1.0 0.0
  }
}
"""


def write_odd_bvh(path, frames=40, seed=0):
    g = np.random.default_rng(seed)
    n_ch = 6 + 3 + 6 + 0 + 1 + 3
    data = g.uniform(-90, 90, size=(frames, n_ch))
    data[:, :3] = g.uniform(-5, 5, size=(frames, 3))      # root position
    data[:, 12:15] = g.uniform(-2, 8, size=(frames, 3))   # slider local translation
    data[:, 16:19] = g.uniform(-1, 1, size=(frames, 3))   # prop position
    body = "\n".join(" ".join(f"{v:.6f}" for v in row) for row in data)
    path.write_text(ODD_HIERARCHY + f"MOTION\nFrames: {frames}\nFrame Time: 0.04\n{body}\n")
    return path


# BVH joint -> the ASF bone whose rotation it carries (the bone starting where the BVH joint is
# meant to sit). Hahne's BVH conversion drops three ASF bones but keeps every rotation: `thorax`
# (Spine1 carries its rotation; Neck/LeftShoulder/RightShoulder then sit at the thorax START, with
# zero offset) and `lwrist`/`rwrist` (LeftHand/RightHand carry their rotation; the FingerBase and
# Thumb joints sit at the wrist START). So a BVH joint above one of those bones sits at its ASF
# bone's start minus the world vectors of the dropped bones on its chain; see `_chain_positions`.
BVH_TO_ASF = {
    "Hips": "root", "LHipJoint": "lhipjoint", "LeftUpLeg": "lfemur", "LeftLeg": "ltibia",
    "LeftFoot": "lfoot", "LeftToeBase": "ltoes", "RHipJoint": "rhipjoint", "RightUpLeg": "rfemur",
    "RightLeg": "rtibia", "RightFoot": "rfoot", "RightToeBase": "rtoes", "LowerBack": "lowerback",
    "Spine": "upperback", "Spine1": "thorax", "Neck": "lowerneck", "Neck1": "upperneck",
    "Head": "head", "LeftShoulder": "lclavicle", "LeftArm": "lhumerus", "LeftForeArm": "lradius",
    "LeftHand": "lwrist", "LeftFingerBase": "lhand", "LeftHandIndex1": "lfingers",
    "LThumb": "lthumb", "RightShoulder": "rclavicle", "RightArm": "rhumerus",
    "RightForeArm": "rradius", "RightHand": "rwrist", "RightFingerBase": "rhand",
    "RightHandIndex1": "rfingers", "RThumb": "rthumb",
}
DROPPED_BY_BVH = ("thorax", "lwrist", "rwrist")
