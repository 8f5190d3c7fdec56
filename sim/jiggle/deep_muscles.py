"""The leg's deep muscles: the hip flexors, adductors and abductors and the shin's dorsiflexor, which share a joint's
torque with the fitted muscles but lie under them (no shell is fitted for them, and nothing of them is simulated or
drawn).

A fitted human body has the muscles one sees (the template's quadriceps, hamstrings, glutes and calves). A hip's
torque is also carried by the iliopsoas (flexion: the swing leg's pull forward), the adductors and the gluteus
medius and minimus (the frontal plane: a stance leg holding the pelvis level), and an ankle's by the tibialis
anterior (dorsiflexion: the foot lifted in swing, lowered after a heel strike). Without them, the static
optimization (sim.jiggle.activation) hands their torques to whichever fitted muscle turns the joint that way: the
glute holds the pelvis level, the quadriceps swings the leg forward, and their activations read as no
musculoskeletal model's do.

Each deep muscle is a path of points, each riding one joint of the character's human roles (rig.motion.role_map:
hips, upper_leg, lower_leg, foot), placed at the bind pose in the frame of the segment it lies on: its right,
up and forward axes (right from the left hip to the right one, up the segment's own axis from its lower joint to its
upper one, the pelvis's and the foot's the world's up; forward up x right), offset from the segment's upper joint
(the pelvis's and the thigh's: the hip; the shank's: the knee; the foot's: the ankle) in proportion to the
segment's length (REFERENCE_LENGTHS), the left side mirrored. The points and the largest forces are those of Rajagopal et al. 2016's full-body model (IEEE
TBME 63:2068) as MyoSuite's myolegs26 (PyPI myo-sim 0.2.4) has them, standing (its qpos0, leg length 0.795 m,
its subject 75.3 kg): the forces scale with the body's mass.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

REFERENCE_LENGTHS = {"pelvis": 0.7950, "thigh": 0.3950, "shank": 0.4000, "foot": 0.1376}
"""metres, of the model the points are taken from (myolegs26 standing): each segment's offsets scale with the
character's length of the same: the leg (hip to ankle) for the pelvis, hip to knee, knee to ankle, ankle to the
toes' joint (the shank's where the skeleton has no toe)."""
REFERENCE_MASS_KG = 75.3
"""The mass of the subject the forces are for (Rajagopal et al. 2016)."""


@dataclass(frozen=True)
class DeepMuscle:
    """name : without its side. force_n : largest isometric force, N, at REFERENCE_MASS_KG. points : ((segment,
    (right, up, forward)), ...) the path from origin to insertion, segment one of pelvis, thigh, shank, foot, the
    offsets in metres at REFERENCE_LENGTHS (the right side's; see the module)."""

    name: str
    force_n: float
    points: tuple


DEEP_MUSCLES = (
    DeepMuscle("iliopsoas", 2586.0, (("pelvis", (-0.0546, 0.1548, 0.0060)), ("pelvis", (-0.0076, 0.0091, 0.0469)),
                                     ("pelvis", (-0.0022, -0.0132, 0.0422)), ("thigh", (0.0038, -0.0507, 0.0021)),
                                     ("thigh", (0.0104, -0.0599, -0.0182)))),
    DeepMuscle("hip_adductors", 3872.0, (("pelvis", (-0.0580, -0.0513, -0.0025)),
                                         ("thigh", (0.0339, -0.1211, -0.0034)))),
    DeepMuscle("hip_abductors", 4323.0, (("pelvis", (-0.0069, 0.1106, -0.0148)),
                                         ("thigh", (0.0527, -0.0060, -0.0257)))),
    DeepMuscle("tibialis_anterior", 2042.0, (("shank", (0.0115, -0.1624, 0.0179)),
                                             ("shank", (-0.0177, -0.3951, 0.0329)),
                                             ("foot", (-0.0226, -0.0242, 0.0678)))),
)
"""myolegs26's iliopsoas (lumbar origin, over the pelvic brim, to the lesser trochanter; its via point that slides
with the hip's flexion in place of a wrap is fixed where it stands), adductors, abductors (gluteus medius and minimus) and tibialis anterior (the tibia's front, under the ankle's
retinaculum, to the medial cuneiform), right side, standing."""

SEGMENT_JOINTS = {"pelvis": ("hips", "upper_leg"), "thigh": ("upper_leg", "upper_leg"),
                  "shank": ("lower_leg", "lower_leg"), "foot": ("foot", "foot")}
"""segment -> (the role its points ride, the role of the joint its offsets are from), per side."""


def leg_roles(roles: dict | None) -> bool:
    """Whether `roles` (role -> joint index) has the hips and both legs' upper_leg, lower_leg and foot."""
    need = ["hips"] + [f"{s}_{r}" for s in ("left", "right") for r in ("upper_leg", "lower_leg", "foot")]
    return bool(roles) and all(r in roles for r in need)


def deep_paths(bind_world: np.ndarray, roles: dict, scale: float = 1.0):
    """The deep muscles of a body whose bind pose is `bind_world` (J, 4, 4) with human `roles`: (names (D,), points
    (D, P, 3) world metres at the bind pose x `scale` (a path shorter than P repeats its last point), point joints
    (D, P) int, forces (D,) N at REFERENCE_MASS_KG). None where the roles lack a leg."""
    if not leg_roles(roles):
        return None
    world = np.asarray(bind_world, np.float64)
    pos = world[:, :3, 3] * scale
    up_world = np.array([0.0, 0.0, 1.0])
    right = pos[roles["right_upper_leg"]] - pos[roles["left_upper_leg"]]
    right /= max(float(np.linalg.norm(right)), 1e-12)
    P = max(len(d.points) for d in DEEP_MUSCLES)
    names, points, joints, forces = [], [], [], []
    for side, sign in (("right", 1.0), ("left", -1.0)):
        j = {r: roles[f"{side}_{r}"] for r in ("upper_leg", "lower_leg", "foot")}
        j["hips"] = roles["hips"]
        length = lambda a, b: float(np.linalg.norm(pos[a] - pos[b])) or 1.0  # noqa: E731
        shank = length(j["lower_leg"], j["foot"])
        sizes = {"pelvis": length(j["upper_leg"], j["foot"]), "thigh": length(j["upper_leg"], j["lower_leg"]),
                 "shank": shank, "foot": length(j["foot"], roles[f"{side}_toe"]) if f"{side}_toe" in roles else
                 shank * REFERENCE_LENGTHS["foot"] / REFERENCE_LENGTHS["shank"]}
        axes = {"pelvis": _frame(right, up_world), "thigh": _frame(right, pos[j["upper_leg"]] - pos[j["lower_leg"]]),
                "shank": _frame(right, pos[j["lower_leg"]] - pos[j["foot"]]), "foot": _frame(right, up_world)}
        for d in DEEP_MUSCLES:
            pts, js = [], []
            for seg, off in d.points:
                ride, base = SEGMENT_JOINTS[seg]
                o = np.array(off) * sizes[seg] / REFERENCE_LENGTHS[seg]
                o[0] *= sign                                          # the left side mirrored
                pts.append(pos[j[base]] + axes[seg] @ o)
                js.append(j[ride])
            pts += [pts[-1]] * (P - len(pts))
            js += [js[-1]] * (P - len(js))
            names.append(f"{side}_{d.name}")
            points.append(pts)
            joints.append(js)
            forces.append(d.force_n)
    return names, np.array(points), np.array(joints, np.int64), np.array(forces)


def _frame(right: np.ndarray, up: np.ndarray) -> np.ndarray:
    """(3, 3) columns right, up, forward: `up` (3,) normalized, `right` made square to it, forward = up x right."""
    u = up / max(float(np.linalg.norm(up)), 1e-12)
    r = right - np.dot(right, u) * u
    r /= max(float(np.linalg.norm(r)), 1e-12)
    return np.stack([r, u, np.cross(u, r)], axis=1)


__all__ = ["DeepMuscle", "DEEP_MUSCLES", "REFERENCE_LENGTHS", "REFERENCE_MASS_KG", "leg_roles", "deep_paths"]
