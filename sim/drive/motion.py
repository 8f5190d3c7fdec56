"""The skeleton driven over a clip: bone world transforms at output frames (a Motion).

Three drives: kinematic (MuJoCo poses the skeleton from the clip with mj_kinematics), physics (a
MuJoCo humanoid follows the clip on a floor, sim/drive/physics_drive.py) and a user's own MJCF model
(sim/drive/mjcf_drive.py). Each returns a :class:`Motion`.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np

from jiggle.rig.motion.clip import Clip
from jiggle.sim.drive.skeleton import Skeleton


@dataclass(frozen=True)
class Motion:
    """Bone world transforms sampled at output frames, with the tree they belong to.

    times : (N,) seconds from the clip's start.
    rotations : (N, J, 4) world rotations, w,x,y,z.
    positions : (N, J, 3) world joint positions, metres, Z-up.
    joint_names : (J,) names; parents : (J,) parent index or -1.
    end_parents : (E,) joint of each end site; end_points : (N, E, 3) metres.
    info : facts about how it was made (drive, tracking error, ...).
    arrays : per-frame data of the drive saved beside the transforms (physics: foot_force (N, F)
        newtons, foot_joints (F,), joint_error (N, J) metres).
    """

    times: np.ndarray
    rotations: np.ndarray
    positions: np.ndarray
    joint_names: tuple[str, ...]
    parents: np.ndarray
    end_parents: np.ndarray
    end_points: np.ndarray
    info: dict
    arrays: dict = field(default_factory=dict)


def _clip_motion(clip: Clip, times, rot, pos, info, arrays=None) -> Motion:
    return Motion(times, rot, pos, clip.joint_names, clip.parents, clip.end_parents,
                  clip.end_world(rot, pos), info, arrays or {})


def drive_kinematic(clip: Clip, times: np.ndarray, progress=None, chunk: int = 256) -> Motion:
    """MuJoCo poses the skeleton from the clip (interpolated at `times`) with mj_kinematics."""
    sk = Skeleton(clip)
    rot = np.empty((len(times), clip.num_joints, 4))
    pos = np.empty((len(times), clip.num_joints, 3))
    for a in range(0, len(times), chunk):
        b = min(a + chunk, len(times))
        rot[a:b], pos[a:b] = sk.kinematics(sk.qpos_at(times[a:b]))
        if progress is not None:
            progress(b - a)
    return _clip_motion(clip, times, rot, pos, {"drive": "kinematic", "body_mass_kg": round(sk.total_mass, 2)})


def drive_physics(clip: Clip, times: np.ndarray, progress=None) -> Motion:
    """MuJoCo simulates the body on a floor, following the clip (see sim.drive.physics_drive)."""
    from jiggle.sim.drive.physics_drive import PhysicsDrive

    drive = PhysicsDrive(clip)
    done = [0]

    def report(k, total):
        if progress is not None:
            progress(k - done[0])
            done[0] = k

    res = drive.run(times, progress=report)
    return _clip_motion(clip, times, res.rotations, res.positions, {"drive": "physics", **res.summary()},
                        {"foot_force": res.foot_force, "foot_joints": np.array(res.foot_joints),
                         "joint_error": res.joint_error})


def drive_mjcf(clip: Clip, times: np.ndarray, xml_path: str, joint_map: dict[str, str] | None = None,
               progress=None) -> Motion:
    """A user's MuJoCo model posed from the clip (see sim.drive.mjcf_drive); joints are the model's bodies."""
    from jiggle.sim.drive.mjcf_drive import MjcfDrive

    drive = MjcfDrive(xml_path, clip, joint_map)
    rot, pos = drive.world(times)
    if progress is not None:
        progress(len(times))
    parents = np.asarray(drive.model.body_parentid[1:], dtype=np.int64) - 1  # world (0) becomes -1
    return Motion(times, rot, pos, drive.body_names, parents, np.zeros(0, np.int64),
                  np.zeros((len(times), 0, 3)),
                  {"drive": "kinematic", "mjcf": os.path.abspath(xml_path),
                   "mapped_joints": len(drive.mapping),
                   "rest_misalignment_deg": round(float(drive.rest_misalignment_deg), 3),
                   "body_mass_kg": round(float(np.sum(drive.model.body_mass)), 2)})
