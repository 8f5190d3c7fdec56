"""The thesis's simple example: a cylinder skinned to two bones, one muscle on the upper bone.

Hoehne's thesis builds its muscle system on a cylindrical "arm": an upper and a lower bone, smooth
skinning, and one fusiform muscle on the upper bone whose insertion rides the forearm, so bending the
elbow shortens the belly and, with its volume kept, makes it bulge. The scene is made here, needs no
file, and is small enough for tests (a few thousand vertices).

Geometry (metres, Z-up world): the arm hangs along -Z from the shoulder at the origin; the elbow is
UPPER below it, the wrist FORE below the elbow. Flexing the elbow by angle a rotates the forearm about
+X, swinging it toward the front (+Y), where the biceps lies.

Motion for the secondary-motion demo (`jiggle simulate` with no scene): :func:`flex_angle`, a fast
flex (0 -> FLEX_PEAK degrees in FLEX_RISE seconds along a smoothstep), a hold, the same back, and a
hold; :meth:`SimpleArm.world_at` gives the joint transforms at any times. The smoothstep's
deceleration is largest at the instant the forearm stops, so the dynamic biceps swings past its
static shape there and rings down over the hold.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from jiggle.rig.character.character import Character, bind_clip
from jiggle.rig.character.normals import vertex_normals
from jiggle.rig.muscle.model import MuscleRig, MuscleSpec, build_muscle_rig

UPPER, FORE = 0.30, 0.26     # bone lengths
RADIUS = 0.055               # the cylinder's radius
BLEND = 0.05                 # half-width of the elbow's weight blend along the arm
JOINT_NAMES = ("shoulder", "elbow", "wrist")
# the fast flex (seconds, degrees): still for FLEX_START, up in FLEX_RISE, held FLEX_HOLD, down in
# FLEX_RISE, held FLEX_HOLD again. A real fast curl takes ~0.15-0.2 s; 0.12 s makes the default muscle
# (7 Hz, damping 0.5) swing ~9 mm past its static shape at the stop, clearly visible on a 2 cm belly.
FLEX_START, FLEX_RISE, FLEX_HOLD, FLEX_PEAK = 0.1, 0.12, 0.6, 130.0
FLEX_DURATION = FLEX_START + 2.0 * (FLEX_RISE + FLEX_HOLD)
PARENTS = np.array([-1, 0, 1], np.int32)


@dataclass(frozen=True)
class SimpleArm:
    """The scene: the skinned cylinder and its muscle rig (both at bind)."""

    character: Character
    rig: MuscleRig

    def world(self, elbow_deg) -> np.ndarray:
        """Joint world transforms (3, 4, 4) for an elbow angle in degrees, or (T, 3, 4, 4) for (T,) angles."""
        return arm_world(elbow_deg)

    def world_at(self, times) -> np.ndarray:
        """Joint world transforms (K, 3, 4, 4) of the fast flex (:func:`flex_angle`) at times (K,) seconds:
        the `world_at` that sim.jiggle.secondary.jiggle_rig takes."""
        return flex_world(times)


def smoothstep(x) -> np.ndarray:
    """3x^2 - 2x^3 of x clipped to [0, 1]: 0 -> 1 with zero slope at both ends."""
    x = np.clip(np.asarray(x, dtype=np.float64), 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def flex_angle(t, start: float = FLEX_START, rise: float = FLEX_RISE, hold: float = FLEX_HOLD,
               peak: float = FLEX_PEAK) -> np.ndarray:
    """Elbow angle (degrees, same shape as t) of the fast flex at times t (seconds): 0 until `start`,
    up to `peak` over `rise` seconds (smoothstep), held `hold` seconds, back to 0 over `rise`, then 0."""
    t = np.asarray(t, dtype=np.float64)
    down = start + rise + hold
    return peak * (smoothstep((t - start) / rise) - smoothstep((t - down) / rise))


def flex_world(times) -> np.ndarray:
    """Joint world transforms (K, 3, 4, 4) of the fast flex at times (K,) seconds."""
    return arm_world(np.atleast_1d(flex_angle(times)))


def arm_world(elbow_deg) -> np.ndarray:
    """Joint world transforms of the arm: (3, 4, 4) for a scalar angle (degrees), (T, 3, 4, 4) for (T,)."""
    a = np.radians(np.asarray(elbow_deg, dtype=np.float64))
    flat = np.atleast_1d(a)
    c, s = np.cos(flat), np.sin(flat)
    rx = np.zeros((len(flat), 3, 3))
    rx[:, 0, 0] = 1.0
    rx[:, 1, 1], rx[:, 1, 2], rx[:, 2, 1], rx[:, 2, 2] = c, -s, s, c
    w = np.tile(np.eye(4), (len(flat), 3, 1, 1))
    w[:, 1, :3, 3] = (0.0, 0.0, -UPPER)
    w[:, 1, :3, :3] = rx
    w[:, 2, :3, :3] = rx
    w[:, 2, :3, 3] = w[:, 1, :3, 3] + rx @ np.array([0.0, 0.0, -FORE])
    return w[0] if np.ndim(a) == 0 else w


def capped_tube(z: np.ndarray, r: np.ndarray, around: int) -> tuple[np.ndarray, np.ndarray]:
    """A closed surface of revolution about the Z axis: rings at heights z (R,) metres, going down
    (-Z), of radii r (R,) metres, `around` vertices each, and a centre vertex capping each end.
    Returns vertices (R * around + 2, 3) and faces (F, 3) int32, outward."""
    rings = len(z)
    t = 2.0 * np.pi * np.arange(around) / around
    v = np.concatenate([np.column_stack([(r[:, None] * np.cos(t)).ravel(), (r[:, None] * np.sin(t)).ravel(),
                                         np.repeat(z, around)]), [(0.0, 0.0, 0.0), (0.0, 0.0, z[-1])]])
    i = np.arange(rings - 1)[:, None] * around
    j = np.arange(around)[None, :]
    a, b = i + j, i + (j + 1) % around
    c, d = a + around, b + around
    # rings go down (-Z) and angles turn counter-clockwise about +Z: (a, c, b) faces outward
    side = np.concatenate([np.stack([a, c, b], -1).reshape(-1, 3), np.stack([b, c, d], -1).reshape(-1, 3)])
    top, bottom = len(v) - 2, len(v) - 1
    jj = np.arange(around)
    caps = np.concatenate([np.stack([np.full(around, top), (jj + 1) % around, jj], 1),
                           np.stack([np.full(around, bottom), (rings - 1) * around + jj,
                                     (rings - 1) * around + (jj + 1) % around], 1)])
    return v, np.concatenate([side, caps]).astype(np.int32)


def cylinder(rings: int = 64, around: int = 48) -> tuple[np.ndarray, np.ndarray]:
    """A capped cylinder from the shoulder to the wrist: vertices (V, 3), faces (F, 3) outward."""
    z = -np.linspace(0.0, UPPER + FORE, rings)
    return capped_tube(z, np.full(rings, RADIUS), around)


def arm_character(rings: int = 64, around: int = 48) -> Character:
    """The cylinder skinned to the shoulder and elbow joints: weight 1 to the upper bone above the
    elbow's blend zone, 1 to the forearm below it, a smoothstep between (the thesis's smooth bind)."""
    v, f = cylinder(rings, around)
    x = np.clip((-v[:, 2] - (UPPER - BLEND)) / (2.0 * BLEND), 0.0, 1.0)
    lower = x * x * (3.0 - 2.0 * x)
    joints = np.tile(np.array([[0, 1]], np.int32), (len(v), 1))
    weights = np.stack([1.0 - lower, lower], axis=1)
    # strongest influence first, as Character expects
    swap = weights[:, 1] > weights[:, 0]
    joints[swap] = joints[swap][:, ::-1]
    weights[swap] = weights[swap][:, ::-1]
    bind = arm_world(0.0)
    return Character(vertices=v, faces=f, normals=vertex_normals(v, f), uvs=None, joint_names=JOINT_NAMES,
                     parents=PARENTS, bind_world=bind, bind_matrices=bind, joints=joints,
                     weights=weights.astype(np.float32),
                     skeleton=bind_clip(JOINT_NAMES, PARENTS, bind, name="simple arm"),
                     name="simple arm", meta={"weights": "smoothstep"})


def biceps_spec(n: int = 600) -> MuscleSpec:
    """The muscle: an ellipsoidal belly on the front (+Y) of the upper arm, 3 mm under the skin, from
    the shoulder to just below the elbow (its insertion rides the forearm)."""
    top, bottom = -0.05, -0.25
    centre = np.array([0.0, 0.030, 0.5 * (top + bottom)])
    radii = np.array([0.5 * (top - bottom), 0.022, 0.020])      # along the arm, front-back, side
    axes = np.array([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])
    i = np.arange(n) + 0.5
    zz = 1.0 - 2.0 * i / n
    rr = np.sqrt(1.0 - zz * zz)
    phi = np.pi * (1.0 + 5 ** 0.5) * i
    sphere = np.stack([zz, rr * np.cos(phi), rr * np.sin(phi)], axis=1)
    surface = centre + (sphere * radii) @ axes
    ends = np.array([centre + radii[0] * axes[0] * -1.0, centre + radii[0] * axes[0]])
    points = np.array([(0.0, 0.012, -0.01), ends[0], ends[1], (0.0, 0.02, -UPPER - 0.04)])
    return MuscleSpec(name="biceps", kind="muscle", group="upper_arm", bone=0, bones=(0, 0, 0, 1),
                      points=points, ends=ends, up=np.array([0.0, 1.0, 0.0]), surface=surface)


def simple_arm(rings: int = 64, around: int = 48) -> SimpleArm:
    """The thesis's simple example at bind (see the module docstring)."""
    ch = arm_character(rings, around)
    return SimpleArm(character=ch, rig=build_muscle_rig([biceps_spec()], ch.bind_world))
