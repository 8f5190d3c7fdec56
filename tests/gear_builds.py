"""Characters built for the gear rule's tests (rig/character/gear.py, issue 50): a shared character's skeleton
and clip kept, its skin rebound or replaced.

- rebound_rigidly(character, eyes_joint): every vertex bound with weight 1 to one joint, as game artists bind
  whole parts: each piece to its strongest joint, the pieces given in `to` to other joints (the Cat's body and
  ears on its head joint, its eyes on a second joint: a blob bound rigidly);
- plated(character): the skin replaced by what a knight in plate or a wolf of shards is made of: around every
  bone four thin plates (thickness 5% of their width) and a spike (a cone), each a piece of its own bound with
  weight 1 to the bone's joint;
- soldier, abrupt, mixamo_named: a Mixamo-named body bound bone by bone in a vest, a belt and pouches;
- bird_blob, mushroom_blob: the wild blobs of issue 61, built whole (skeleton, skin and their own cycles), also
  baked by benchmarks/zoo.py;
- slab, cone, offset_shell, surface_of_revolution: the closed meshes they are made of (a box, a cone, a shell over
  part of a skin, a profile swept about an axis).
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from jiggle.rig.character.gear import pieces


def slab(centre, axes, half) -> tuple[np.ndarray, np.ndarray]:
    """A closed box: 8 corners (8, 3) centre + sum_k +-half[k] axes[k], 12 outward triangles (12, 3)."""
    s = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float) * np.asarray(half, float)
    c = np.asarray(centre, float) + s @ np.asarray(axes, float)
    f = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                  [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    if np.linalg.det(np.asarray(axes, float)) < 0:
        f = f[:, ::-1]
    return c, f


def cone(base, tip, radius: float, n: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """A closed cone from a disc of `radius` at `base` to `tip`: n rim points, the tip, the base's centre
    ((n + 2, 3)) and 2 n outward triangles."""
    base, tip = np.asarray(base, float), np.asarray(tip, float)
    u = (tip - base) / np.linalg.norm(tip - base)
    a = np.cross(u, [1.0, 0.0, 0.0] if abs(u[0]) < 0.9 else [0.0, 1.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(u, a)
    t = 2.0 * np.pi * np.arange(n) / n
    rim = base + radius * (np.cos(t)[:, None] * a + np.sin(t)[:, None] * b)
    v = np.vstack([rim, tip, base])
    k = np.arange(n)
    side = np.stack([k, (k + 1) % n, np.full(n, n)], axis=1)
    cap = np.stack([(k + 1) % n, k, np.full(n, n + 1)], axis=1)
    return v, np.vstack([side, cap])


def rebound_rigidly(character, joint: str, to: dict | None = None):
    """`character` with every vertex bound with weight 1: the pieces listed in `to` ({piece label
    (rig.character.gear.pieces): joint name}) to theirs, every other vertex to `joint`."""
    names = list(character.joint_names)
    label = pieces(character)
    target = np.full(character.num_vertices, names.index(joint), np.int64)
    for k, name in (to or {}).items():
        target[label == k] = names.index(name)
    joints = np.zeros_like(np.asarray(character.joints))
    weights = np.zeros_like(np.asarray(character.weights))
    joints[:, 0], weights[:, 0] = target, 1.0
    return replace(character, joints=joints, weights=weights, maps=None)


def plated(character, min_bone: float = 0.04):
    """`character`'s skeleton with a skin of plates and spikes (see the module): for every bone at least
    `min_bone` of the character's height long, four plates around it and a spike on its front, bound to
    the bone's parent joint; parts "Plate.N" and "Spike.N" in meta["parts"]."""
    p = np.asarray(character.bind_world)[:, :3, 3]
    par = np.asarray(character.parents)
    height = float(np.ptp(np.asarray(character.vertices)[:, 2]))
    verts, faces, owner, parts = [], [], [], []
    n = 0
    for j in np.nonzero(par >= 0)[0]:
        a, b = p[par[j]], p[j]
        L = float(np.linalg.norm(b - a))
        if L < min_bone * height:
            continue
        u = (b - a) / L
        v = np.cross(u, [0.0, 0.0, 1.0] if abs(u[2]) < 0.9 else [1.0, 0.0, 0.0])
        v /= np.linalg.norm(v)
        w = np.cross(u, v)
        r = float(np.clip(0.3 * L, 0.02 * height, 0.08 * height))
        mid = 0.5 * (a + b)
        for k, (side, across) in enumerate(((w, v), (-w, v), (v, w), (-v, w))):
            width = 1.6 * r
            c, f = slab(mid + r * side, np.stack([u, across, np.cross(u, across)]),
                        (0.4 * L, 0.5 * width, 0.025 * width))
            parts.append([f"Plate.{len(parts)}", n, 8])
            verts.append(c), faces.append(f + n), owner.append(np.full(8, par[j]))
            n += 8
        c, f = cone(mid + 1.03 * r * w, mid + 2.2 * r * w, 0.25 * r)
        parts.append([f"Spike.{len(parts)}", n, len(c)])
        verts.append(c), faces.append(f + n), owner.append(np.full(len(c), par[j]))
        n += len(c)
    vertices, faces_, joint = np.vstack(verts), np.vstack(faces), np.concatenate(owner)
    k = character.joints.shape[1]
    joints = np.zeros((n, k), np.int64)
    weights = np.zeros((n, k))
    joints[:, 0], weights[:, 0] = joint, 1.0
    from jiggle.rig.character.normals import vertex_normals
    return replace(character, vertices=vertices, faces=faces_, normals=vertex_normals(vertices, faces_), uvs=None,
                   joints=joints, weights=weights, maps=None, name=f"{character.name or 'character'} in plate",
                   meta={**{k_: v_ for k_, v_ in character.meta.items() if k_ not in ("primitives", "materials")},
                         "parts": parts})


MIXAMO = {"Hips": "Hips", "LeftUpLeg": "LeftUpLeg", "LeftLeg": "LeftLeg", "LeftFoot": "LeftFoot",
          "LeftToeBase": "LeftToeBase", "RightUpLeg": "RightUpLeg", "RightLeg": "RightLeg", "RightFoot": "RightFoot",
          "RightToeBase": "RightToeBase", "LowerBack": "Spine", "Spine": "Spine1", "Spine1": "Spine2", "Neck": "Neck",
          "Neck1": "Neck1", "Head": "Head", "LeftShoulder": "LeftShoulder", "LeftArm": "LeftArm",
          "LeftForeArm": "LeftForeArm", "LeftHand": "LeftHand", "RightShoulder": "RightShoulder", "RightArm": "RightArm",
          "RightForeArm": "RightForeArm", "RightHand": "RightHand"}
"""A CMU BVH skeleton's joints -> Mixamo's (the rest keep their CMU name), each written "mixamorig:NAME"."""


def mixamo_named(clip):
    """`clip` (a CMU BVH) with its joints named as a Mixamo rig's ("mixamorig:Hips", ...)."""
    return replace(clip, joint_names=tuple("mixamorig:" + MIXAMO.get(n, n) for n in clip.joint_names))


def offset_shell(vertices, normals, faces_sel: np.ndarray, gap: float, thick: float):
    """A closed shell over the faces `faces_sel` (F, 3) of a mesh (vertices, unit normals (V, 3)): their vertices
    pushed out along the normals by `gap` (inner face) and `gap + thick` (outer face), the rims joined: (vertices,
    faces) of the new piece, as a vest or a helmet over skin."""
    from jiggle.rig.character.mesh_graph import mesh_edges
    v = np.asarray(vertices, float)
    nrm = np.asarray(normals, float)
    used, local = np.unique(faces_sel, return_inverse=True)
    f = local.reshape(-1, 3)
    n = len(used)
    inner = v[used] + gap * nrm[used]
    outer = v[used] + (gap + thick) * nrm[used]
    faces = [f + n, f[:, ::-1]]                      # outer faces outward, inner faces turned inward
    edges, ef = mesh_edges(f)
    for (a, b), (f0, f1) in zip(edges, ef):
        if f1 >= 0:
            continue
        tri = f[f0]
        k = list(tri).index(a)
        if tri[(k + 1) % 3] != b:                    # the rim edge as its face walks it
            a, b = b, a
        faces += [np.array([[a, b, b + n], [a, b + n, a + n]])]
    return np.vstack([inner, outer]), np.vstack(faces)


def soldier(character, spine: str = "mixamorig:Spine1", hips: str = "mixamorig:Hips"):
    """`character` (a body with Mixamo names) in a vest and a belt with pouches: the vest a closed shell 1.2% of
    the height off the torso's skin (the faces all of whose vertices ride `spine`, its parent or its child
    most), 0.6% thick, and two pouches (boxes) on its front, all bound with weight 1 to `spine`; the belt a band
    around the hips bound to `hips`. Parts "Body", "Vest", "Belt", "Pouch.L", "Pouch.R"."""
    from jiggle.rig.character.normals import vertex_normals
    names = list(character.joint_names)
    v = np.asarray(character.vertices, float)
    height = float(np.ptp(v[:, 2]))
    dom = np.asarray(character.joints)[np.arange(len(v)), np.argmax(character.weights, axis=1)]
    s = names.index(spine)
    torso = {s, int(character.parents[s])} | {j for j, p in enumerate(character.parents) if p == s}
    torso = {j for j in torso if not any(w in names[j] for w in ("Shoulder", "Arm", "Neck", "Head"))}
    f = np.asarray(character.faces)
    on = np.isin(dom, sorted(torso))
    vest_f = f[on[f].all(axis=1)]
    vv, vf = offset_shell(character.vertices, character.normals, vest_f, 0.012 * height, 0.006 * height)
    hip_z = float(np.asarray(character.bind_world)[names.index(hips), 2, 3])
    trunk = np.array([not any(w in n for w in ("Leg", "Arm", "Hand", "Foot")) for n in names])
    band = f[(np.abs(v[f, 2] - hip_z - 0.04 * height) < 0.025 * height).all(axis=1) & trunk[dom[f]].all(axis=1)]
    bv, bf = offset_shell(character.vertices, character.normals, band, 0.004 * height, 0.01 * height) if len(band) else (np.zeros((0, 3)), [])
    front = vv[np.argmin(vv[:, 1])] if len(vv) else np.zeros(3)
    out = [("Body", v, f, None)]
    out.append(("Vest", vv, vf, s))
    if len(bv):
        out.append(("Belt", bv, bf, names.index(hips)))
    centre_y = float(vv[:, 1].min()) - 0.03 * height
    for side, x in (("L", 0.06), ("R", -0.06)):
        c, pf = slab((x * height, centre_y, front[2] - 0.06 * height), np.eye(3),
                     (0.03 * height, 0.02 * height, 0.035 * height))
        out.append((f"Pouch.{side}", c, pf, s))
    verts, faces, joints, weights, parts = [], [], [], [], []
    n, k = 0, character.joints.shape[1]
    for name, pv, pf, j in out:
        verts.append(pv), faces.append(np.asarray(pf) + n), parts.append([name, n, len(pv)])
        if j is None:
            joints.append(np.asarray(character.joints)), weights.append(np.asarray(character.weights))
        else:
            jj, ww = np.zeros((len(pv), k), np.int64), np.zeros((len(pv), k))
            jj[:, 0], ww[:, 0] = j, 1.0
            joints.append(jj), weights.append(ww)
        n += len(pv)
    vertices, faces_ = np.vstack(verts), np.vstack(faces)
    normals = vertex_normals(vertices, faces_)
    normals[:len(v)] = character.normals
    return replace(character, vertices=vertices, faces=faces_, normals=normals, uvs=None, joints=np.vstack(joints),
                   weights=np.vstack(weights), maps=None, name=f"{character.name or 'body'} soldier",
                   meta={**{a: b for a, b in character.meta.items() if a not in ("primitives", "materials", "body")},
                         "parts": parts})


def abrupt(character, joints) -> object:
    """`character` with every vertex whose strongest joint is one of `joints` (names) bound to it alone (weight 1):
    where two such regions meet, as at a stylised rig's shoulder, the weights change abruptly from one vertex to
    the next."""
    names = list(character.joint_names)
    ids = [names.index(j) for j in joints]
    J, W = np.array(character.joints), np.array(character.weights, np.float64)
    top = J[np.arange(len(J)), np.argmax(W, axis=1)]
    hit = np.isin(top, ids)
    J[hit] = 0
    W[hit] = 0.0
    J[hit, 0], W[hit, 0] = top[hit], 1.0
    return replace(character, joints=J, weights=W, maps=None)


def bird_blob(height: float = 0.5, frames: int = 30, fps: float = 30.0, joints=(0.0, 0.25, 0.45, 0.65, 0.85)):
    """(character, walk): a round bird-like blob as game artists make one (issue 61): an armature root, then Body,
    Head, Head2 and Head3 up its middle; its body one closed sphere of 256 vertices, 88% or so of the skin's volume,
    skinned smoothly over Head, Head2 and Head3 (each vertex's largest weight at least 0.47); two eyes, a beak and
    three feathers, each a closed piece of its own bound with weight 1 to Head3. `walk`: a waddle of `frames` frames
    at `fps`, the body rocking side to side and the head joints nodding after it, one cycle. joints : the five
    joints' heights over the body's."""
    from jiggle.rig.motion import quat
    from jiggle.rig.character.character import Character, bind_clip
    from jiggle.rig.character.normals import vertex_normals
    from jiggle.rig.motion.clip import Clip
    r = 0.5 * height
    names = ("Root", "Body", "Head", "Head2", "Head3")
    parents = np.array([-1, 0, 1, 2, 3], np.int32)
    z = np.asarray(joints, float) * height
    bind = np.tile(np.eye(4), (5, 1, 1))
    bind[:, 2, 3] = z
    # the body: a UV sphere of 16 rings x 15 around plus its poles (242), centred at half the height
    rings, around = 16, 15
    th = np.linspace(0.0, np.pi, rings + 2)[1:-1]
    ph = 2.0 * np.pi * np.arange(around) / around
    v = np.concatenate([[[0.0, 0.0, -r]], np.stack([np.outer(np.sin(th), np.cos(ph)).ravel() * r,
                                                     np.outer(np.sin(th), np.sin(ph)).ravel() * r,
                                                     -np.repeat(np.cos(th), around) * r], 1), [[0.0, 0.0, r]]])
    v[:, 2] += r
    f = [[0, 1 + (j + 1) % around, 1 + j] for j in range(around)]
    for i in range(rings - 1):
        for j in range(around):
            a, b = 1 + i * around + j, 1 + i * around + (j + 1) % around
            c, d = a + around, b + around
            f += [[a, b, d], [a, d, c]]
    top = len(v) - 1
    f += [[top, 1 + (rings - 1) * around + j, 1 + (rings - 1) * around + (j + 1) % around] for j in range(around)]
    body_v, body_f = v, np.array(f)
    # smooth weights over Head, Head2, Head3 by height (linear between their heights, Head below, Head3 above)
    h = np.clip(np.interp(body_v[:, 2], z[2:], [0.0, 1.0, 2.0]), 0.0, 2.0)
    wts = np.zeros((len(body_v), 3))
    lo = np.floor(np.minimum(h, 1.999)).astype(int)
    t = h - lo
    wts[np.arange(len(h)), lo] = 1.0 - t
    wts[np.arange(len(h)), lo + 1] = t
    wts = np.maximum(wts, 0.0)
    keep = np.argsort(-wts, axis=1)
    body_j = (keep + 2).astype(np.int32)
    body_w = np.take_along_axis(wts, keep, axis=1)
    pieces_ = [(body_v, body_f, body_j, body_w)]

    def rigid(pv, pf):
        pieces_.append((pv, pf, np.full((len(pv), 1), 4, np.int32), np.ones((len(pv), 1))))
    for side in (-1.0, 1.0):                                   # eyes: small cubes half in the face
        rigid(*slab([side * 0.35 * r, -0.9 * r, 1.35 * r], np.eye(3), [0.12 * r] * 3))
    rigid(*cone([0.0, -0.95 * r, 1.1 * r], [0.0, -1.35 * r, 1.05 * r], 0.12 * r))          # the beak
    for k in (-1, 0, 1):                                       # feathers: thin plates on the crown
        rigid(*slab([0.2 * k * r, 0.1 * k * r, 2.0 * r], [[1, 0, 0], [0, 0.2, 0.98], [0, -0.98, 0.2]],
                    [0.06 * r, 0.22 * r, 0.01 * r]))
    V = np.concatenate([p[0] for p in pieces_])
    offs = np.cumsum([0] + [len(p[0]) for p in pieces_])
    F = np.concatenate([p[1] + o for p, o in zip(pieces_, offs)]).astype(np.int32)
    k = max(p[2].shape[1] for p in pieces_)
    J = np.zeros((len(V), k), np.int32)
    W = np.zeros((len(V), k))
    for p, o in zip(pieces_, offs):
        J[o:o + len(p[0]), :p[2].shape[1]] = p[2]
        W[o:o + len(p[0]), :p[3].shape[1]] = p[3]
    character = Character(vertices=V, faces=F, normals=vertex_normals(V, F), uvs=None, joint_names=names,
                          parents=parents, bind_world=bind, bind_matrices=bind, joints=J, weights=W,
                          skeleton=bind_clip(names, parents, bind, name="bird"), name="bird")
    rest = character.skeleton
    t = np.arange(frames) / fps
    w = 2.0 * np.pi * fps / frames * t                         # one cycle over the clip
    rot = np.repeat(rest.rest_rotations[None], frames, axis=0).copy()
    tra = np.repeat(rest.offsets[None], frames, axis=0).copy()
    rock = quat.from_axis_angle(np.array([[0.0, 1.0, 0.0]]), 0.35 * np.sin(w))        # side to side
    rot[:, 1] = quat.mul(rest.rest_rotations[1][None], rock)
    for j, lag in ((2, 0.6), (3, 1.2), (4, 1.8)):              # the head joints nod after the body
        nod = quat.from_axis_angle(np.array([[1.0, 0.0, 0.0]]), 0.25 * np.sin(w - lag))
        rot[:, j] = quat.mul(rest.rest_rotations[j][None], nod)
    tra[:, 0, 2] += 0.08 * height * np.abs(np.sin(w))          # a hop each step
    walk = Clip(joint_names=names, parents=parents, offsets=rest.offsets, rest_rotations=rest.rest_rotations,
                rotations=rot, translations=tra, fps=fps, name="Walk")
    return character, walk


def surface_of_revolution(profile, around: int = 16) -> tuple[np.ndarray, np.ndarray]:
    """(vertices, faces) of a closed surface of revolution about z: `profile` ((radius, z) pairs, bottom to top,
    radii > 0) swept `around` steps, closed by a vertex on the axis below the first ring and one above the last."""
    p = np.asarray(profile, float)
    ph = 2.0 * np.pi * np.arange(around) / around
    rings = np.stack([np.outer(p[:, 0], np.cos(ph)).ravel(), np.outer(p[:, 0], np.sin(ph)).ravel(),
                      np.repeat(p[:, 1], around)], 1)
    v = np.concatenate([[[0.0, 0.0, p[0, 1]]], rings, [[0.0, 0.0, p[-1, 1]]]])
    f = [[0, 1 + (j + 1) % around, 1 + j] for j in range(around)]
    for i in range(len(p) - 1):
        for j in range(around):
            a, b = 1 + i * around + j, 1 + i * around + (j + 1) % around
            f += [[a, b, b + around], [a, b + around, a + around]]
    top, last = len(v) - 1, 1 + (len(p) - 1) * around
    f += [[top, last + j, last + (j + 1) % around] for j in range(around)]
    return v, np.array(f)


def mushroom_blob(height: float = 0.6, fps: float = 30.0, walk_frames: int = 20, run_frames: int = 8,
                  walk=(0.3, 0.06, 0.25, 0.0), run=(0.08, 0.03, 0.05, 0.0)):
    """(character, {"Walk": clip, "Run": clip}): a mushroom blob as game artists make one (issue 61): an armature
    root, then Body, Stem and Cap up its middle; one closed surface of revolution (a stem under a wide domed cap)
    skinned smoothly by height over Body, Stem and Cap. Two cycles of its own: a Walk (the body waddling side to side
    once a cycle and hopping each step, the cap swinging after it: slow and wide) and a Run (a quick, small
    shuffle: larger accelerations, so the Run is the cycle that drives its tissue hardest, yet it swings the cap
    less than the walk does). walk, run : each cycle's (rock radians, hop over the height, the cap's swing
    radians, lurch: 0 a steady sway, else the sway bunched into a quick lurch to each side this wide)."""
    from jiggle.rig.character.character import Character, bind_clip
    from jiggle.rig.character.normals import vertex_normals
    H = float(height)
    names = ("Root", "Body", "Stem", "Cap")
    parents = np.array([-1, 0, 1, 2], np.int32)
    z = np.array([0.0, 0.1, 0.35, 0.6]) * H
    bind = np.tile(np.eye(4), (4, 1, 1))
    bind[:, 2, 3] = z
    profile = [(0.22 * H, 0.0), (0.26 * H, 0.08 * H), (0.24 * H, 0.25 * H), (0.22 * H, 0.42 * H),
               (0.45 * H, 0.5 * H), (0.55 * H, 0.6 * H), (0.5 * H, 0.75 * H), (0.36 * H, 0.88 * H),
               (0.16 * H, 0.97 * H)]
    V, F = surface_of_revolution(profile, around=18)
    h = np.clip(np.interp(V[:, 2], z[1:], [0.0, 1.0, 2.0]), 0.0, 2.0)
    lo = np.floor(np.minimum(h, 1.999)).astype(int)
    t = h - lo
    wts = np.zeros((len(V), 3))
    wts[np.arange(len(V)), lo] = 1.0 - t
    wts[np.arange(len(V)), lo + 1] = t
    keep = np.argsort(-wts, axis=1)
    J = (keep + 1).astype(np.int32)
    W = np.take_along_axis(wts, keep, axis=1)
    character = Character(vertices=V, faces=F.astype(np.int32), normals=vertex_normals(V, F), uvs=None,
                          joint_names=names, parents=parents, bind_world=bind, bind_matrices=bind, joints=J, weights=W,
                          skeleton=bind_clip(names, parents, bind, name="mushroom"), name="mushroom")
    rest = character.skeleton

    def cycle(frames, rock, hop, swing, lurch, lag, name):
        t = np.arange(frames) / fps
        w = 2.0 * np.pi * fps / frames * t
        if lurch:       # the sway bunched into a quick lurch to each side (a bump of `lurch` cycles), still between
            s = np.sin(w) * np.exp(-(np.sin(w / 2.0) ** 2 - 0.5) ** 2 / (2.0 * lurch ** 2))
            return _mushroom_clip(rest, names, parents, fps, name, rock * s, hop * H * np.abs(s),
                                  swing * np.roll(s, int(round(lag / (2.0 * np.pi) * frames))))
        return _mushroom_clip(rest, names, parents, fps, name, rock * np.sin(w), hop * H * np.abs(np.sin(w)),
                              swing * np.sin(w - lag))
    return character, {"Walk": cycle(walk_frames, *walk, 1.2, "Walk"), "Run": cycle(run_frames, *run, 0.6, "Run")}


def _mushroom_clip(rest, names, parents, fps, name, rock, hop, swing):
    """The mushroom's clip: per frame the body's rock about y (radians), the root's hop (metres) and the cap's swing
    about y (radians), each (F,)."""
    from jiggle.rig.motion import quat
    from jiggle.rig.motion.clip import Clip
    F = len(rock)
    y = np.array([[0.0, 1.0, 0.0]])
    rot = np.repeat(rest.rest_rotations[None], F, axis=0).copy()
    tra = np.repeat(rest.offsets[None], F, axis=0).copy()
    rot[:, 1] = quat.mul(rest.rest_rotations[1][None], quat.from_axis_angle(y, np.asarray(rock)))
    rot[:, 3] = quat.mul(rest.rest_rotations[3][None], quat.from_axis_angle(y, np.asarray(swing)))
    tra[:, 0, 2] += hop
    return Clip(joint_names=names, parents=parents, offsets=rest.offsets, rest_rotations=rest.rest_rotations,
                rotations=rot, translations=tra, fps=fps, name=name)
