"""The project's own four-legged test character: a dog-like skeleton that walks and trots, keyed in
``scenes/motions/quadruped_walk.toml`` and ``quadruped_trot.toml``, a body generated around it with
automatic weights, written to one .glb with both motions as glTF animations.

:func:`write_gait_toml` writes the two motion files (``python -m scenes.quadruped --motions`` writes
them again); :func:`make_quadruped_gltf` builds the character from them and writes the .glb
(``python -m scenes.quadruped OUT.glb``).

The gaits are keyed by inverse kinematics: each paw follows a stance/swing path (planted on the floor
while in stance, lifted in a smooth arc while it swings forward) and the leg's joint angles are solved
for it at every key, so the paws do not slide or sink. World Z-up, metres, the dog faces -Y with its
left side at +X, like the human clips.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

MOTIONS = Path(__file__).resolve().parent / "motions"

# (name, parent, offset from the parent at rest, metres); parents first. The dog is ~0.6 m at the
# withers, ~0.8 m from chest to rump; paws rest 2.5 cm above the floor so their pads touch it.
# Listed depth-first (children in this order), the order a glTF reader walks the skin's joints, so
# the character written to glTF reads back with its joints in the same order.
JOINTS = [
    ("hips", "", (0.0, 0.30, 0.54)),
    ("spine", "hips", (0.0, -0.30, 0.02)),
    ("chest", "spine", (0.0, -0.28, -0.01)),
    ("neck", "chest", (0.0, -0.12, 0.07)),
    ("head", "neck", (0.0, -0.10, 0.15)),
]
for _s, _x in (("left", 1.0), ("right", -1.0)):
    JOINTS += [
        (f"{_s}_front_shoulder", "chest", (0.06 * _x, -0.01, 0.03)),
        (f"{_s}_front_upper_leg", f"{_s}_front_shoulder", (0.04 * _x, -0.09, -0.17)),
        (f"{_s}_front_lower_leg", f"{_s}_front_upper_leg", (0.0, 0.10, -0.15)),
        (f"{_s}_front_foot", f"{_s}_front_lower_leg", (0.0, -0.05, -0.20)),
        (f"{_s}_front_toe", f"{_s}_front_foot", (0.0, -0.02, -0.035)),
    ]
JOINTS += [
    ("tail", "hips", (0.0, 0.12, 0.03)),
    ("tail_1", "tail", (0.0, 0.10, 0.0)),
    ("tail_2", "tail_1", (0.0, 0.10, -0.03)),
    ("tail_3", "tail_2", (0.0, 0.09, -0.05)),
]
for _s, _x in (("left", 1.0), ("right", -1.0)):
    JOINTS += [
        (f"{_s}_hind_upper_leg", "hips", (0.09 * _x, 0.03, -0.05)),
        (f"{_s}_hind_lower_leg", f"{_s}_hind_upper_leg", (0.01 * _x, -0.08, -0.18)),
        (f"{_s}_hind_foot", f"{_s}_hind_lower_leg", (0.0, 0.11, -0.19)),
        (f"{_s}_hind_toe", f"{_s}_hind_foot", (0.0, -0.02, -0.095)),
    ]
ENDS = [("head", (0.0, -0.20, -0.05)), ("tail_3", (0.0, 0.08, -0.06))] + [
    (f"{s}_{e}_toe", (0.0, -0.05, -0.015)) for s in ("left", "right") for e in ("front", "hind")]

ROLES = """# ROLES (rig.motion.body_plan.QUADRUPED_ROLES): every joint plays the role of its name
#   hips = root and hind girdle; spine; chest = front girdle (the front legs hang from it); neck; head;
#   tail = tail base (tail_1..tail_3 follow it to the tip);
#   per side s in left/right: s_front_shoulder = scapula, s_front_upper_leg = shoulder joint,
#   s_front_lower_leg = elbow, s_front_foot = carpus, s_front_toe = paw;
#   s_hind_upper_leg = hip joint, s_hind_lower_leg = stifle, s_hind_foot = hock, s_hind_toe = paw.
#   End sites: head top (muzzle tip), tail tip, and each paw's toe tip."""


@dataclass(frozen=True)
class Gait:
    """One gait: cycle period T (s), forward speed (m/s), duty factor (share of the cycle a paw is planted),
    touch-down phase of each leg (share of the cycle), swing height (m), how much lower than at rest the
    root travels (m, so the legs keep some bend), root bob (m, twice a cycle) and
    the amplitudes (degrees) of the body's sway that makes fat move."""

    name: str
    period: float
    speed: float
    duty: float
    touchdown: dict
    lift: float
    crouch: float
    bob: float
    sway: float
    head: float
    tail: float
    cycles: int
    dt: float = 0.05


# walk: lateral sequence (left hind, left fore, right hind, right fore, a quarter cycle apart);
# trot: diagonal pairs (left hind + right fore, then right hind + left fore).
WALK = Gait("quadruped_walk", 1.0, 0.5, 0.65,
            {"left_hind": 0.0, "left_front": 0.25, "right_hind": 0.5, "right_front": 0.75},
            lift=0.06, crouch=0.02, bob=0.008, sway=3.0, head=3.0, tail=10.0, cycles=3)
TROT = Gait("quadruped_trot", 0.6, 1.0, 0.5,
            {"left_hind": 0.0, "right_front": 0.0, "right_hind": 0.5, "left_front": 0.5},
            lift=0.08, crouch=0.03, bob=0.015, sway=2.0, head=4.0, tail=14.0, cycles=3)


def _rest():
    names = [j[0] for j in JOINTS]
    parents = [names.index(p) if p else -1 for _, p, _ in JOINTS]
    offsets = np.array([o for _, _, o in JOINTS], dtype=float)
    return names, parents, offsets


def _rx(deg: float) -> Rotation:
    return Rotation.from_rotvec([np.radians(deg), 0.0, 0.0])


def _pitch(v: np.ndarray) -> float:
    """Angle (degrees) of vector v in the Y-Z plane, measured like a rotation about +X."""
    return float(np.degrees(np.arctan2(v[2], v[1])))


def _two_link(a: np.ndarray, c: np.ndarray, u1: np.ndarray, u2: np.ndarray) -> tuple[float, float]:
    """World pitch rotations (degrees about +X) of two segments with rest vectors u1, u2 (3,) so that the
    chain from a (3,) ends at c (3,) in the Y-Z plane, bending the way it bends at rest."""
    l1, l2 = np.hypot(u1[1], u1[2]), np.hypot(u2[1], u2[2])
    d = np.array([c[1] - a[1], c[2] - a[2]])
    r = np.clip(np.linalg.norm(d), abs(l1 - l2) + 1e-6, l1 + l2 - 1e-6)
    bend = np.sign(u1[1] * u2[2] - u1[2] * u2[1])            # which side the knee points at rest
    cos_a = (l1 * l1 + r * r - l2 * l2) / (2 * l1 * r)
    ang = np.arctan2(d[1], d[0]) + bend * np.arccos(np.clip(cos_a, -1, 1))
    b = a[1:] + l1 * np.array([np.cos(ang), np.sin(ang)])
    e = a[1:] + d / np.linalg.norm(d) * r
    th1 = np.degrees(ang) - _pitch(u1)
    th2 = _pitch(np.r_[0.0, e - b]) - _pitch(u2)
    return float(th1), float(th2)


def _paw_path(g: Gait, leg: str, t: float) -> tuple[float, float, float]:
    """Paw offset (metres) from its rest place in the body's travelling frame: (dy, dz) and the phase's
    swing share (0 in stance, 0..1 in swing), at time t (s)."""
    p = (t / g.period - g.touchdown[leg]) % 1.0
    s = g.speed * g.duty * g.period                   # how far the body travels over a planted paw
    if p < g.duty:
        return -s / 2 + s * p / g.duty, 0.0, 0.0
    q = (p - g.duty) / (1 - g.duty)
    m = g.speed * (1 - g.duty) * g.period             # the paw leaves and lands at rest in the world
    h00, h10, h01, h11 = 2 * q**3 - 3 * q**2 + 1, q**3 - 2 * q**2 + q, -2 * q**3 + 3 * q**2, q**3 - q**2
    dy = h00 * s / 2 + h10 * m + h01 * (-s / 2) + h11 * m
    return dy, g.lift * np.sin(np.pi * q) ** 2, q


def gait_keys(g: Gait) -> list[tuple[float, np.ndarray, dict]]:
    """[(time s, root (3,) m, {joint: XYZ euler degrees})] for every key of the gait."""
    names, parents, offsets = _rest()
    J = len(names)
    rest_world = np.zeros((J, 3))
    for j in range(J):
        rest_world[j] = offsets[j] + (rest_world[parents[j]] if parents[j] >= 0 else 0)
    times = np.round(np.arange(0, g.period * g.cycles + 1e-9, g.dt), 6)
    keys = []
    for t in times:
        w = 2 * np.pi * t / g.period
        local = {n: Rotation.identity() for n in names}
        eul = {}
        # body: a roll and yaw of the hips, lateral bend of the spine, a nod of the neck twice a cycle,
        # a tail that swings side to side with a lag along it (this is what makes fat jiggle)
        eul["hips"] = (0.0, g.sway * np.sin(w), 0.6 * g.sway * np.sin(w + 0.5))
        eul["spine"] = (0.5 * g.sway * np.sin(2 * w), 0.0, -g.sway * np.sin(w))
        eul["chest"] = (-0.5 * g.sway * np.sin(2 * w), -0.5 * g.sway * np.sin(w), -0.5 * g.sway * np.sin(w))
        eul["neck"] = (g.head * np.sin(2 * w + 1.0), 0.0, 0.5 * g.sway * np.sin(w + 1.0))
        eul["head"] = (-0.6 * g.head * np.sin(2 * w + 1.6), 0.0, 0.0)
        for k, tj in enumerate(("tail", "tail_1", "tail_2", "tail_3")):
            eul[tj] = ((12.0 if k == 0 else 0.0) + 2 * np.sin(2 * w - 0.6 * k), 0.0,
                       g.tail * (0.6 + 0.2 * k) * np.sin(w - 0.7 * k))
        for n, e in eul.items():
            local[n] = Rotation.from_euler("XYZ", e, degrees=True)
        root = rest_world[0] + np.array([0.0, -g.speed * t, -g.crouch - g.bob * (1 + np.cos(2 * w)) / 2])

        def world(j: int) -> tuple[Rotation, np.ndarray]:
            if parents[j] < 0:
                return local[names[j]], root
            r, p = world(parents[j])
            return r * local[names[j]], p + r.apply(offsets[j])

        for leg in ("left_front", "right_front", "left_hind", "right_hind"):
            front = "front" in leg
            up, lo, ft, toe = (names.index(f"{leg}_{r}") for r in ("upper_leg", "lower_leg", "foot", "toe"))
            dy, dz, q = _paw_path(g, leg, t)
            reach = dy / (g.speed * g.duty * g.period / 2)       # -1 forward .. +1 back, in stance
            if front:   # the shoulder blade swings with the leg
                local[f"{leg}_shoulder"] = _rx(12.0 * np.clip(reach, -1.3, 1.3))
            r_up, a = world(up)
            paw = rest_world[toe] + np.array([0.0, -g.speed * t + dy, dz])
            # the foot (pastern / hock to paw) leans with the leg in stance and folds back in swing
            fold = np.sin(np.pi * q) ** 2
            lean = 10.0 * reach + (70.0 if front else 20.0) * fold
            foot_world = _rx(lean)
            c = paw - foot_world.apply(offsets[toe])
            th1, th2 = _two_link(a, c, offsets[lo], offsets[ft])
            parent_rot = r_up * local[names[up]].inv()                 # the upper leg's parent, in the world
            local[names[up]] = parent_rot.inv() * _rx(th1)
            local[names[lo]] = _rx(th2 - th1)
            local[names[ft]] = _rx(lean - th2)
            local[names[toe]] = _rx(-lean + (80.0 if front else 40.0) * fold)  # the pad stays flat when planted
        rot = {n: r.as_euler("XYZ", degrees=True) for n, r in local.items() if r.magnitude() > 1e-9}
        keys.append((float(t), root, rot))
    return keys


def gait_toml(g: Gait) -> str:
    """The TOML text of a gait (rig.motion.keyframes layout)."""
    names, parents, offsets = _rest()
    out = [f"# Built-in quadruped motion: {g.name.split('_')[1]}, written by scenes/quadruped.py (run it again",
           "# to change it): each paw's path is keyed and its leg solved by inverse kinematics, so planted",
           "# paws stay put on the floor. Lengths in metres, world Z-up; the dog faces -Y, its left side at +X.",
           f"# Cycle {g.period:g} s, {g.speed:g} m/s forward along -Y, duty factor {g.duty:g}; touch-downs "
           + ", ".join(f"{k} {v:g}" for k, v in g.touchdown.items()) + " (share of the cycle).",
           "# The keys cover every cycle (loop = false) because the root travels forward.",
           "# Angles: degrees, intrinsic XYZ.", ROLES,
           f'name = "{g.name}"', "fps = 60", 'euler = "XYZ"', "loop = false", ""]
    for n, p, o in JOINTS:
        out += ["[[joints]]", f'name = "{n}"', f'parent = "{p}"', f"offset = [{o[0]:.3f}, {o[1]:.3f}, {o[2]:.3f}]"]
    for p, o in ENDS:
        out += ["[[ends]]", f'parent = "{p}"', f"offset = [{o[0]:.3f}, {o[1]:.3f}, {o[2]:.3f}]"]
    for t, root, rot in gait_keys(g):
        out += ["", "[[keys]]", f"time = {t:.3f}", f"root = [{root[0]:.4f}, {root[1]:.4f}, {root[2]:.4f}]",
                "[keys.rotate]"]
        out += [f"{n} = [{e[0]:.2f}, {e[1]:.2f}, {e[2]:.2f}]" for n, e in rot.items()]
    return "\n".join(out) + "\n"


def make_quadruped_gltf(path: str | os.PathLike, resolution: int = 15000, k: int = 4, options=None):
    """Build the test dog and write it as one skinned .glb/.gltf with its animations "walk" and "trot".

    Reads the two motion files in scenes/motions, generates the body around the skeleton
    (rig.character.quadruped_body, `resolution` vertices or `options`, a BodyOptions), weights it by bone
    heat (`k` influences) and writes it with rig.character.gltf_write. Returns the Character written
    (its skeleton is the walk's rest pose; the clips are on it joint for joint).
    """
    from jiggle.rig.character.body import BodyOptions
    from jiggle.rig.character.gltf_write import write_character
    from jiggle.rig.character.load import body_character
    from jiggle.rig.motion.keyframes import read_keyframes
    walk = read_keyframes(MOTIONS / f"{WALK.name}.toml")
    trot = read_keyframes(MOTIONS / f"{TROT.name}.toml")
    character = body_character(walk, options or BodyOptions(resolution=resolution), k=k)
    write_character(character, path, name="quadruped", animations={"walk": walk, "trot": trot},
                    extras={"jiggle": {"generated": "scenes/quadruped.py", "resolution": int(resolution)}})
    return character


def write_gait_toml(folder: str | os.PathLike = MOTIONS) -> list[Path]:
    """Write quadruped_walk.toml and quadruped_trot.toml into `folder`; returns their paths."""
    paths = []
    for g in (WALK, TROT):
        p = Path(folder) / f"{g.name}.toml"
        p.write_text(gait_toml(g))
        paths.append(p)
    return paths


if __name__ == "__main__":
    # python -m scenes.quadruped OUT.glb: the test dog with its walk and trot;
    # python -m scenes.quadruped --motions: write the two motion files again from the gaits above
    import sys
    if sys.argv[1:] == ["--motions"]:
        for p in write_gait_toml():
            print(p)
    elif len(sys.argv) == 2 and sys.argv[1].lower().endswith((".glb", ".gltf")):
        make_quadruped_gltf(sys.argv[1])
        print(sys.argv[1])
    else:
        sys.exit("usage: python -m scenes.quadruped OUT.glb | --motions")
