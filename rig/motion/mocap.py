"""Load any supported mocap file into a :class:`~rig.motion.clip.Clip`, chosen by extension."""
from __future__ import annotations

import os

from jiggle.rig.base.errors import InputError, require_file
from jiggle.rig.motion.clip import Clip

CLIP_EXTENSIONS = (".bvh", ".amc", ".asf", ".glb", ".gltf", ".fbx", ".toml")


def load_clip(path: str | os.PathLike, *, skeleton: str | os.PathLike | None = None,
              animation: str | int | None = None, scale: float | None = None,
              tpose: str = "auto") -> Clip:
    """Read a clip.

    path : .bvh; .amc (its .asf from `skeleton`, else the one .asf beside it); .asf alone (its rest
        pose as a one-frame clip); .glb/.gltf with animations (`animation` by name or index, default
        the first); .fbx (binary or ASCII, FBX 6.1 and 7.x), its takes read through Blender's importer
        (rig.motion.fbx); .toml keyframes (rig.motion.keyframes, as the built-in demo motion).
    scale : metres per file unit for BVH (None: recognise CMU or guess, see rig.motion.bvh).
    tpose : BVH first-frame handling, "auto", "skip" or "keep".
    """
    p = require_file(path, "clip file")
    ext = os.path.splitext(p)[1].lower()
    if ext == ".bvh":
        from jiggle.rig.motion.bvh import read_bvh
        return read_bvh(p, scale=scale, tpose=tpose)
    if ext == ".amc":
        from jiggle.rig.motion.acclaim import find_asf, read_amc, read_asf
        asf = read_asf(skeleton if skeleton is not None else find_asf(p))
        return read_amc(p, asf)
    if ext == ".asf":
        from jiggle.rig.motion.acclaim import read_asf
        return read_asf(p).rest_clip()
    if ext == ".fbx":
        from jiggle.rig.motion.fbx import through_gltf
        from jiggle.rig.motion.gltf_anim import read_gltf_animation
        return through_gltf(p, read_gltf_animation, animation)
    if ext in (".glb", ".gltf"):
        from jiggle.rig.motion.gltf_anim import read_gltf_animation
        return read_gltf_animation(p, animation)
    if ext == ".toml":
        from jiggle.rig.motion.keyframes import read_keyframes
        return read_keyframes(p)
    raise InputError(f"unknown clip format {ext or '(no extension)'!r}; expected one of "
                     f"{', '.join(CLIP_EXTENSIONS)}", p)
