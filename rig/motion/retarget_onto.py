"""A clip onto a skinned glTF character's skeleton: which joint maps to use (given, a built-in preset,
or found from each skeleton's shape), or none at all when the clip moves the character's own skeleton.
"""
from __future__ import annotations

import os

from jiggle.rig.base.errors import InputError
from jiggle.rig.motion.clip import Clip
from jiggle.rig.motion.retarget import JointMap, identity, presets, retarget, same_skeleton, scaled_skeleton
from jiggle.rig.motion.role_map import resolve_roles


def joint_map_for(given, skeleton: Clip, option: str, owner: str) -> JointMap:
    """The JointMap `given` (a TOML path or preset name, checked against the skeleton's joint names),
    else the first built-in preset that fits, else the roles found from the skeleton's shape
    (rig.motion.role_map.resolve_roles); InputError naming `option` when none can be had."""
    names = skeleton.joint_names
    if given is not None:
        jm = JointMap.load(given)
        jm.resolve(names, owner)
        return jm
    for name in presets():
        jm = JointMap.load(name)
        try:
            jm.resolve(names, owner)
            return jm
        except InputError:
            continue
    try:
        roles = resolve_roles(skeleton)
    except InputError as e:
        raise InputError(f"no built-in joint map ({', '.join(presets())}) fits the skeleton of {owner}, and its "
                         f"roles cannot be found from its shape ({e.message}); write a joint map (see "
                         f"rig/motion/retarget.py) and pass it with {option}", field=option) from None
    return JointMap(roles={r: (names[j],) for r, j in roles.items()}, source="", name="found from the shape")


def retarget_onto(clip, character_file, skin=0, clip_map=None, character_map=None, log=print, scale=1.0,
                  follow=None, character_roles: JointMap | None = None):
    """`clip` retargeted onto the skeleton of a skinned glTF (joint maps given, built-in presets, or roles
    found from the skeletons' shapes: :func:`joint_map_for`).
    A clip of the character's own skeleton (the same joints by name and parent, e.g. the character's
    own animation, or another file exported from its rig) needs no map: it is taken as it is.
    scale : metres per unit of the character file (rig.character.character.unit_scale of its --unit),
        as the character is read with: the skeleton the clip lands on is scaled alike, so the skin and
        its bones agree.
    follow : None, or a function applied to the retargeted clip (not to the character's own animation): the
        bake hangs an IK rig's placed feet under its legs with it (rig.character.body_skeleton.hang).
    character_roles : the character's roles as the fit found them on its body (helper bones set aside, IK feet
        hung under their legs), used for the character's side when no character_map is given, before presets
        and the roles of its raw skeleton (which an IK rig's feet off the root can hide)."""
    from jiggle.rig.motion.fbx import fbx_to_gltf, is_fbx
    from jiggle.rig.motion.gltf_skeleton import read_gltf_skeleton
    skeleton_file = fbx_to_gltf(character_file) if is_fbx(character_file) else character_file
    character = scaled_skeleton(read_gltf_skeleton(skeleton_file, skin), scale)
    if clip_map is None and character_map is None:
        idx = same_skeleton(clip, character)
        if idx is not None:
            log(f"{clip.name!r} moves the skeleton of {os.path.basename(character_file)}: no retargeting")
            return identity(clip, idx, character.parents, scale)
    cmap = joint_map_for(clip_map, clip, "--clip-map", clip.source or clip.name)
    chmap = character_roles if character_map is None and character_roles is not None else \
        joint_map_for(character_map, character.to_clip(), "--character-map", character_file)
    out = retarget(clip, cmap, character, chmap)
    if follow is not None:      # parts an IK rig places (its feet) ride the body joints they hang under
        out = follow(out)
    log(f"retargeted {clip.name!r} ({cmap.name} map) onto {os.path.basename(character_file)} ({chmap.name} map)")
    return out
