"""Skin a character over a motion: bone world transforms per frame -> skinned vertices per frame.

The Skinner (rig.skin.skinning) holds the rest skin and weights on the device once; per frame only the
(J, 4, 4) skin matrices go up. The motion's joints are matched to the character's by name.
"""
from __future__ import annotations

import numpy as np

from jiggle.rig.character.character import Character
from jiggle.rig.motion.clip import transforms
from jiggle.rig.skin.skinning import character_skinner
from jiggle.sim.drive.motion import Motion


def skin_motion(character: Character, motion: Motion, method: str = "lbs", device: str = "cpu",
                frames: np.ndarray | None = None, progress=None) -> np.ndarray:
    """Skinned vertex positions (N, V, 3) float32 metres at `frames` (indices into the motion,
    default all), by "lbs" or "dqs"."""
    order = character.joint_order(motion.joint_names)
    frames = np.arange(len(motion.times)) if frames is None else np.asarray(frames)
    world = transforms(motion.rotations[frames][:, order], motion.positions[frames][:, order])
    mats = character.skin_matrices(world)
    skinner = character_skinner(character, device)
    out = np.empty((len(frames), character.num_vertices, 3), np.float32)
    for i, m in enumerate(mats):
        out[i] = skinner.skin(m, method=method)
        if progress is not None:
            progress(1)
    return out
