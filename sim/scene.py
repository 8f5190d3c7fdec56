"""Scenes: a TOML file naming the motion and how to play it (the built-in default is scenes/default.toml).

Layout (paths relative to the scene file)::

    name = "default"
    [motion]
    file = "jumping_jacks.toml"   # keyframed TOML (rig.keyframes) or any clip: BVH, AMC, glTF
    skeleton = "01.asf"           # optional, for an AMC
    animation = 0                 # optional, for glTF
    start = 0.0                   # optional, seconds
    end = 2.0                     # optional, seconds
    [skeleton]
    drive = "kinematic"           # or "physics"
    [output]
    fps = 60                      # optional, default the clip's
"""
from __future__ import annotations

import os
from dataclasses import dataclass

from rig.clip import Clip
from rig.errors import InputError
from rig.tomlfile import read_toml

_KNOWN = {"name": None, "motion": {"file", "skeleton", "animation", "start", "end", "scale", "tpose"},
          "skeleton": {"drive"}, "output": {"fps"}}


@dataclass(frozen=True)
class Scene:
    """A loaded scene. fps: output frames per second (None: the clip's)."""

    name: str
    path: str
    clip: Clip
    drive: str
    fps: float | None


def load_scene(path: str | os.PathLike) -> Scene:
    p, doc = read_toml(path, "scene file")
    for key, sub in doc.items():
        if key not in _KNOWN:
            raise InputError(f"unknown section; expected one of {', '.join(_KNOWN)}", p, field=key)
        if _KNOWN[key] is not None:
            if not isinstance(sub, dict):
                raise InputError("expected a table", p, field=key)
            for k in sub:
                if k not in _KNOWN[key]:
                    raise InputError(f"unknown key; expected one of {', '.join(sorted(_KNOWN[key]))}", p,
                                     field=f"{key}.{k}")
    motion = doc.get("motion", {})
    if "file" not in motion:
        raise InputError("a scene needs a motion file", p, field="motion.file")
    here = os.path.dirname(os.path.abspath(p))
    mfile = os.path.join(here, motion["file"])
    if mfile.lower().endswith(".toml"):
        from rig.keyframes import read_keyframes
        clip = read_keyframes(mfile)
    else:
        from rig.mocap import load_clip
        skel = motion.get("skeleton")
        clip = load_clip(mfile, skeleton=os.path.join(here, skel) if skel else None,
                         animation=motion.get("animation"), scale=motion.get("scale"),
                         tpose=motion.get("tpose", "auto"))
    if "start" in motion or "end" in motion:
        clip = clip.between(float(motion.get("start", 0.0)), motion.get("end"))
    drive = doc.get("skeleton", {}).get("drive", "kinematic")
    if drive not in ("kinematic", "physics"):
        raise InputError(f"expected 'kinematic' or 'physics', found {drive!r}", p, field="skeleton.drive")
    fps = doc.get("output", {}).get("fps")
    if fps is not None and (not isinstance(fps, (int, float)) or not fps > 0):
        raise InputError(f"expected a positive number, found {fps!r}", p, field="output.fps")
    return Scene(name=str(doc.get("name", os.path.splitext(os.path.basename(p))[0])), path=p, clip=clip,
                 drive=drive, fps=None if fps is None else float(fps))
