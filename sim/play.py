"""Play a clip on its skeleton through MuJoCo and write what a person can look at.

This is the pipeline as far as it goes today (clip -> MuJoCo skeleton -> bone world transforms);
later stages (muscles, jiggle, skinning, caches) hang off the transforms it produces.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass, field

import numpy as np

from rig.clip import Clip, transforms
from rig.atomic import atomic_path
from .skeleton import Skeleton


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
    """MuJoCo simulates the body on a floor, following the clip (see sim.physics_drive)."""
    from .physics_drive import PhysicsDrive

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
    """A user's MuJoCo model posed from the clip (see sim.mjcf_drive); joints are the model's bodies."""
    from .mjcf_drive import MjcfDrive

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


def write_outputs(motion: Motion, name: str, out_dir: str, poses: int = 8, render: bool = True,
                  source: str = "", character=None, skin_method: str = "lbs") -> dict:
    """Write `skeleton.png` (film strip), `trajectories.png`, `motion.npz` and `summary.json`; with a
    `character` (rig.character.Character) also `character.png`, the skinned character at the same
    poses as the skeleton strip, and a "character" entry in the summary.

    motion.npz keys: times (N,) s; joint_names (J,); parents (J,); joint_world (N, J, 4, 4) metres,
    Z-up; end_sites (N, E, 3) metres; fps; plus the drive's `Motion.arrays`. Returns the summary.
    """
    from .plots import plot_joint_trajectories

    os.makedirs(out_dir, exist_ok=True)
    files = {}
    times = motion.times
    fps = (len(times) - 1) / (times[-1] - times[0]) if len(times) > 1 else 0.0
    with atomic_path(os.path.join(out_dir, "motion.npz")) as tmp:
        np.savez_compressed(tmp, times=times, joint_names=np.array(motion.joint_names),
                            parents=motion.parents, joint_world=transforms(motion.rotations, motion.positions),
                            end_sites=motion.end_points, fps=fps, **motion.arrays)
    files["motion"] = "motion.npz"
    picks = _trajectory_joints(motion.positions)
    with atomic_path(os.path.join(out_dir, "trajectories.png")) as tmp:
        plot_joint_trajectories(times, motion.positions[:, picks], [motion.joint_names[j] for j in picks],
                                tmp, title=f"{name}: joint trajectories ({motion.info['drive']} drive)")
    files["trajectories"] = "trajectories.png"
    if render:
        from .render import render_skeleton_over_time
        with atomic_path(os.path.join(out_dir, "skeleton.png")) as tmp:
            render_skeleton_over_time(np.concatenate([motion.positions, motion.end_points], axis=1),
                                      motion.parents, motion.end_parents, times, tmp, poses=poses,
                                      title=f"{name}: skeleton over time")
        files["skeleton"] = "skeleton.png"
    extra = {}
    if character is not None:
        extra["character"] = _character_outputs(character, motion, name, out_dir, poses, render, skin_method, files)
    summary = {
        "clip": name, "source": source, "joints": len(motion.joint_names),
        "frames": int(len(times)), "fps": round(float(fps), 6), "duration_s": float(times[-1] - times[0]),
        "root_travel_m": float(np.linalg.norm(motion.positions[-1, 0, :2] - motion.positions[0, 0, :2])),
        "height_range_m": [float(motion.positions[..., 2].min()), float(motion.positions[..., 2].max())],
        **motion.info, **extra, "files": files,
    }
    with atomic_path(os.path.join(out_dir, "summary.json")) as tmp:
        with open(tmp, "w") as fh:
            json.dump(summary, fh, indent=2)
    return summary


def _character_outputs(character, motion: Motion, name: str, out_dir: str, poses: int, render: bool,
                       method: str, files: dict) -> dict:
    from .skin_pass import skin_motion
    n = len(motion.times)
    frames = np.unique(np.linspace(0, n - 1, min(poses, n)).round().astype(int))
    skinned = skin_motion(character, motion, method=method, frames=frames)
    if not np.all(np.isfinite(skinned)):
        raise FloatingPointError("skinning produced non-finite vertices")  # a bug, never user input
    if render:
        from .render import render_skin_over_time
        with atomic_path(os.path.join(out_dir, "character.png")) as tmp:
            render_skin_over_time(skinned, character.faces, motion.times[frames], tmp,
                                  title=f"{name}: {character.name or 'character'} skinned ({method.upper()})")
        files["character"] = "character.png"
    return {"name": character.name, "source": character.source, "vertices": character.num_vertices,
            "faces": int(len(character.faces)), "joints": character.num_joints,
            "weights": character.meta.get("weights", ""), "skinning": method,
            "height_m": round(character.height, 4)}


def _trajectory_joints(positions: np.ndarray, k: int = 6) -> list[int]:
    """The root and the joints that move most relative to it (hands, feet, head), at most k.

    positions : (N, J, 3) world joint positions over the clip.
    """
    rel = positions - positions[:, :1]
    spread = np.linalg.norm(rel.max(axis=0) - rel.min(axis=0), axis=1)
    first = positions[0]
    picks = [0]
    for j in np.argsort(-spread):
        if len(picks) >= k:
            break
        # skip joints within 10 cm of one already picked (a hand and its finger)
        if all(np.linalg.norm(first[j] - first[i]) > 0.1 for i in picks):
            picks.append(int(j))
    return picks
