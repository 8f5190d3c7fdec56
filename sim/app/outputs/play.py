"""`jiggle play`: a clip on its skeleton through MuJoCo, written as what a person can look at.

The skeleton is driven by sim/drive (a Motion: bone world transforms per frame); this writes the
motion's npz and json, joint trajectory plots, skeleton renders and, with a character, its skin
posed over time.
"""
from __future__ import annotations

import json
import os

import numpy as np

from jiggle.rig.base.atomic import atomic_path
from jiggle.rig.motion.clip import transforms
from jiggle.sim.drive.motion import Motion


def write_outputs(motion: Motion, name: str, out_dir: str, poses: int = 8, render: bool = True,
                  source: str = "", character=None, skin_method: str = "lbs") -> dict:
    """Write `skeleton.png` (film strip), `trajectories.png`, `motion.npz` and `summary.json`; with a
    `character` (rig.character.character.Character) also `character.png`, the skinned character at the same
    poses as the skeleton strip, and a "character" entry in the summary.

    motion.npz keys: times (N,) s; joint_names (J,); parents (J,); joint_world (N, J, 4, 4) metres,
    Z-up; end_sites (N, E, 3) metres; fps; plus the drive's `Motion.arrays`. Returns the summary.
    """
    from jiggle.sim.app.report.plots import plot_joint_trajectories

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
        from jiggle.sim.app.report.render import render_skeleton_over_time
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
    from jiggle.sim.app.skin_pass import skin_motion
    n = len(motion.times)
    frames = np.unique(np.linspace(0, n - 1, min(poses, n)).round().astype(int))
    skinned = skin_motion(character, motion, method=method, frames=frames)
    if not np.all(np.isfinite(skinned)):
        raise FloatingPointError("skinning produced non-finite vertices")  # a bug, never user input
    if render:
        from jiggle.sim.app.report.render import render_skin_over_time
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
