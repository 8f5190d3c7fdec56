"""Play a clip on its skeleton through MuJoCo and write what a person can look at.

This is the pipeline as far as it goes today (clip -> MuJoCo skeleton -> bone world transforms);
later stages (muscles, jiggle, skinning, caches) hang off the transforms it produces.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass

import numpy as np

from rig.clip import Clip
from .atomic import atomic_path
from .skeleton import Skeleton, transforms


@dataclass(frozen=True)
class Motion:
    """Bone world transforms sampled at output frames.

    times : (N,) seconds from the clip's start.
    rotations : (N, J, 4) world rotations, w,x,y,z.
    positions : (N, J, 3) world joint positions, metres, Z-up.
    info : facts about how it was made (drive, tracking error, ...).
    """

    times: np.ndarray
    rotations: np.ndarray
    positions: np.ndarray
    info: dict


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
    return Motion(times, rot, pos, {"drive": "kinematic", "body_mass_kg": round(sk.total_mass, 2)})


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
    return Motion(times, res.rotations, res.positions, {"drive": "physics", **res.summary()})


def write_outputs(clip: Clip, motion: Motion, out_dir: str, poses: int = 8, render: bool = True) -> dict:
    """Write `skeleton.png` (film strip), `trajectories.png`, `motion.npz` and `summary.json`.

    motion.npz keys: times (N,) s; joint_names (J,); parents (J,); joint_world (N, J, 4, 4) metres,
    Z-up; end_sites (N, E, 3) metres. Returns the summary.
    """
    from .plots import plot_joint_trajectories

    os.makedirs(out_dir, exist_ok=True)
    ends = clip.end_world(motion.rotations, motion.positions)
    files = {}
    with atomic_path(os.path.join(out_dir, "motion.npz")) as tmp:
        np.savez_compressed(tmp, times=motion.times, joint_names=np.array(clip.joint_names),
                            parents=clip.parents, joint_world=transforms(motion.rotations, motion.positions),
                            end_sites=ends, fps=clip.fps)
    files["motion"] = "motion.npz"
    picks = _trajectory_joints(clip, motion.positions)
    with atomic_path(os.path.join(out_dir, "trajectories.png")) as tmp:
        plot_joint_trajectories(motion.times, motion.positions[:, picks], [clip.joint_names[j] for j in picks],
                                tmp, title=f"{clip.name}: joint trajectories ({motion.info['drive']} drive)")
    files["trajectories"] = "trajectories.png"
    if render:
        from .render import render_skeleton_over_time
        with atomic_path(os.path.join(out_dir, "skeleton.png")) as tmp:
            render_skeleton_over_time(np.concatenate([motion.positions, ends], axis=1), clip.parents,
                                      clip.end_parents, motion.times, tmp, poses=poses,
                                      title=f"{clip.name}: skeleton over time")
        files["skeleton"] = "skeleton.png"
    summary = {
        "clip": clip.name, "source": clip.source, "joints": clip.num_joints,
        "frames": int(len(motion.times)), "fps": clip.fps, "duration_s": float(motion.times[-1] - motion.times[0]),
        "root_travel_m": float(np.linalg.norm(motion.positions[-1, 0, :2] - motion.positions[0, 0, :2])),
        "height_range_m": [float(motion.positions[..., 2].min()), float(motion.positions[..., 2].max())],
        **motion.info, "files": files,
    }
    with atomic_path(os.path.join(out_dir, "summary.json")) as tmp:
        with open(tmp, "w") as fh:
            json.dump(summary, fh, indent=2)
    return summary


def _trajectory_joints(clip: Clip, positions: np.ndarray, k: int = 6) -> list[int]:
    """The root and the joints that move most relative to it (hands, feet, head), at most k.

    positions : (N, J, 3) world joint positions over the clip.
    """
    rel = positions - positions[:, :1]
    spread = np.linalg.norm(rel.max(axis=0) - rel.min(axis=0), axis=1)
    _, rest = clip.rest_world()
    picks = [0]
    for j in np.argsort(-spread):
        if len(picks) >= k:
            break
        # skip joints within 10 cm of one already picked at rest (a hand and its finger)
        if all(np.linalg.norm(rest[j] - rest[i]) > 0.1 for i in picks):
            picks.append(int(j))
    return picks
