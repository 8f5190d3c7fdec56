"""A bake as a standard skinned glTF any engine plays: the character, its skeleton animated as baked, and jiggle
bones carrying what the muscles add (`jiggle bake --formats glb`, `jiggle export BAKE_DIR --glb OUT.glb`).

The file holds the character's rest skin (its material copied from its glTF when it has one), its joints with
the drive's world transforms at every output frame (what the bake skinned), and the jiggle bones
(rig.skin.jiggle_bones: fitted to skin_final - skin_lbs, hung under the joints they ride with, named
`<muscle>_jiggle_<k>`, one animation channel each); JOINTS_0/WEIGHTS_0 (and _1 with 8 influences) hold the
character's weights with the bones' shares. One animation, "jiggle", LINEAR keys at the output frames. A looping
bake's (sim/bake/loop.py) runs from 0 to the period, its last key the first pose and jiggle again, so an engine
looping it (three.js LoopRepeat, Unity/Unreal loop time) wraps without a jump; extras.jiggle.loop records it.

What it reports (bake.json "glb", and returned): per frame the RMS, 99th percentile and largest distance in mm
between the skin the file plays (the file read back: its own quantized weights and keys, `played_from_file`) and
skin_final;
`share`, sum |played - lbs| / sum |final - lbs| per frame (how much of the muscles' motion the bones make), and
`explained`, 1 - sum |played - final| / sum |final - lbs| (how much of it they make right); bones used, file
bytes against the bytes of the same frames as a pc2 cache, and the fit's seconds.
"""
from __future__ import annotations

import os
import time

import numpy as np

from jiggle.rig.base.errors import InputError

DEFAULT_BONES = {"human": 128, "quadruped": 128}
"""Jiggle bones per built-in template at most; another template gets two per muscle at most."""
VERTICES_PER_BONE = 64
"""The default budget grows with the skin, a bone per this many vertices (at least MIN_BONES), up to the template's:
a 3k-vertex game character gets about 50, a 12k body the template's 128 (each meets RMS 1 mm, p99 3 mm)."""
MIN_BONES = 32
GLB_NAME = "bake.glb"


def default_bones(template: str | None, muscles: int, vertices: int) -> int:
    cap = DEFAULT_BONES.get(str(template or ""), 2 * muscles)
    return int(min(cap, max(MIN_BONES, vertices // VERTICES_PER_BONE)))


def export_glb(character, world: np.ndarray, data, path: str, *, bones: int, max_influences: int = 4,
               source: str | None = None, fps: float | None = None, muscle_joint=None, loop: dict | None = None) -> dict:
    """Write the glb (module docstring) and return its report.

    character : the bake's character (rig.character.character.Character). world : (T, J, 4, 4) its joints' world
    transforms at the output frames. data : sim.bake.caches.BakeData of the bake (skin_final, skin_lbs, muscle
    CVs). path : the .glb to write (atomically). bones : the jiggle bone budget. max_influences : 4 or 8.
    source : the glTF the character came from (its material is copied), None for a plain one.
    muscle_joint : (M,) the joint each muscle rides (the rig's middle slot), None: unknown.
    loop : a looping bake's record (sim.bake.loop.Loop.to_json), kept in the file's extras (jiggle.loop) for a
        client to know the animation is one period whose last key repeats the first; None: a plain bake.
    """
    from jiggle.rig.skin import jiggle_bones as jb
    if max_influences not in (4, 8):
        raise InputError(f"--max-influences must be 4 or 8 (JOINTS_0, or JOINTS_0 and JOINTS_1), got "
                         f"{max_influences}", field="--max-influences")
    if bones < 0:
        raise InputError(f"--jiggle-bones must be >= 0, got {bones}", field="--jiggle-bones")
    c = character
    if c.weights.shape[1] > max_influences:
        raise InputError(f"the character has {c.weights.shape[1]} influences per vertex and --max-influences is "
                         f"{max_influences}: bake with --influences {max_influences} or export with "
                         f"--max-influences 8", field="--max-influences")
    T = len(world)
    final = np.asarray(data.skin_final, np.float64)
    if final.shape != (T, c.num_vertices, 3):
        raise InputError(f"the bake's skin is {final.shape}, the character {c.num_vertices} vertices over {T} "
                         f"frames: the bake and its character do not match", path)
    t0 = time.perf_counter()
    mats = c.skin_matrices(np.asarray(world, np.float64))
    if data.skin_lbs is not None:
        lbs = np.asarray(data.skin_lbs, np.float64)
    else:                                       # an older bake without its smooth skin: the character's own LBS
        from jiggle.rig.skin.skinning import pose_character
        lbs = pose_character(c, np.asarray(world, np.float64)).astype(np.float64)
    muscle = jb.nearest_muscle(data.skin_static[0], data.muscle_cvs_static[0], data.muscle_cv_offsets)
    fitted = jb.fit(c.vertices, c.joints, c.weights, mats, final, muscle, data.muscle_names, bones,
                    max_influences=max_influences, muscle_joint=muscle_joint)
    fit_s = time.perf_counter() - t0
    ext, clip = _with_bones(c, np.asarray(world, np.float64), fitted, fps or data.fps)
    from jiggle.rig.character.gltf_write import write_character
    try:
        write_character(ext, path, source=source, name=c.name or "character", animations={"jiggle": clip},
                        compact=True,
                        extras={"jiggle": {"from": os.path.basename(c.source) if c.source else "",
                                           "jiggle_bones": list(fitted.names),
                                           **({"loop": loop} if loop else {})}})
    except OSError as e:
        raise InputError(f"cannot write: {e.strerror or e}", path) from None
    played = played_from_file(path, len(world))
    return {"file": os.path.basename(path), **report(played, lbs, final), "bones": len(fitted.names),
            "max_influences": max_influences, "bytes": os.path.getsize(path),
            "pc2_bytes": 32 + T * c.num_vertices * 12, "fit_s": round(fit_s, 3),
            "bone_names": list(fitted.names)}


def played_from_file(path: str, frames: int | None = None) -> np.ndarray:
    """(T, V, 3) float64 the skin a glb plays at each of its animation's keys, read back as an engine reads the
    file (its own quantized weights and keys; jiggle's glTF reader, rig.character.gltf_character)."""
    from jiggle.rig.character.load import load_character
    from jiggle.rig.motion.clip import transforms
    from jiggle.rig.motion.mocap import load_clip
    from jiggle.rig.skin.skinning import pose_character
    c = load_character(path, k=8)                 # every influence the file holds (JOINTS_0 and _1)
    clip = load_clip(path)
    T = clip.num_frames if frames is None else min(frames, clip.num_frames)
    world = transforms(*clip.world())[:T][:, [clip.joint_names.index(n) for n in c.joint_names]]
    return pose_character(c, world).astype(np.float64)


def report(played: np.ndarray, lbs: np.ndarray, final: np.ndarray) -> dict:
    """Per-frame figures of a played skin against the final one (module docstring), in mm and shares."""
    err = np.linalg.norm(np.asarray(played, np.float64) - final, axis=2) * 1000.0
    disp = np.linalg.norm(final - lbs, axis=2)
    made = np.linalg.norm(np.asarray(played, np.float64) - lbs, axis=2)
    total = np.maximum(disp.sum(axis=1), 1e-12)
    share = made.sum(axis=1) / total
    explained = 1.0 - err.sum(axis=1) / 1000.0 / total
    rms = np.sqrt((err ** 2).mean(axis=1))
    p99 = np.percentile(err, 99, axis=1)
    r = lambda a: [round(float(x), 4) for x in a]                       # noqa: E731
    return {"rms_mm": r(rms), "p99_mm": r(p99), "max_mm": r(err.max(axis=1)), "share": r(share),
            "explained": r(explained), "worst_frame": int(np.argmax(p99)),
            "summary": {"rms_mm_max": float(rms.max()), "p99_mm_max": float(p99.max()),
                        "max_mm": float(err.max()), "share_min": float(share.min()),
                        "explained_min": float(explained.min()), "displacement_max_mm": float(disp.max() * 1000)}}


def _with_bones(c, world: np.ndarray, fitted, fps: float):
    """(the character with the jiggle bones as joints and their weights, its Clip: every joint's world transform
    per frame)."""
    import dataclasses

    from jiggle.rig.motion import quat
    from jiggle.rig.motion.clip import Clip, local_from_world
    K = len(fitted.names)
    hosts = fitted.hosts.astype(np.int64)
    parents = np.r_[c.parents, hosts].astype(np.int32)
    bind_world = np.concatenate([c.bind_world, c.bind_world[hosts]])
    bind_mats = np.concatenate([c.bind_matrices, c.bind_matrices[hosts]])
    bone_world = fitted.skin @ c.bind_matrices[hosts][None]             # (T, K, 4, 4): skin @ its bind
    all_world = np.concatenate([world, bone_world], axis=1)
    rot, tra = local_from_world(parents, quat.from_matrix(all_world[..., :3, :3]), all_world[..., :3, 3])
    b_rot, b_tra = local_from_world(parents, quat.from_matrix(bind_world[:, :3, :3]), bind_world[:, :3, 3])
    names = tuple(c.joint_names) + tuple(fitted.names)
    clip = Clip(names, parents, b_tra, b_rot, rot, tra, fps, name="jiggle")
    skeleton = Clip(names, parents, b_tra, b_rot, b_rot[None], b_tra[None], fps, name=c.skeleton.name)
    ext = dataclasses.replace(c, joint_names=names, parents=parents, bind_world=bind_world, bind_matrices=bind_mats,
                              joints=fitted.joints, weights=fitted.weights, skeleton=skeleton)
    return ext, clip


def write_for_bake(setup, out_dir: str, bones: int | None = None, max_influences: int = 4,
                   path: str | None = None) -> dict:
    """The glb of a finished bake in out_dir (its bake.npz), from its setup (sim.bake.setup.BakeSetup); the
    report, also stored in bake.json under "glb"."""
    import json

    from jiggle.rig.base.atomic import atomic_path
    from jiggle.sim.bake.caches import read_npz
    data = read_npz(os.path.join(out_dir, "bake.npz"))
    world = setup.world_at(np.asarray(data.times, np.float64))
    loop = getattr(setup, "loop", None)
    if loop is not None and not loop.repeats_first and len(data.times) == loop.frames:
        data, world = _period_end(data, world, setup)
    template = setup.params.get("template") if isinstance(setup.params, dict) else None
    template = template.get("file") if isinstance(template, dict) else template
    budget = default_bones(template, len(data.muscle_names), setup.character.num_vertices) if bones is None \
        else bones
    source = _material_source(setup.character)
    out = path or os.path.join(out_dir, GLB_NAME)
    rig = setup.rig
    muscle_joint = np.asarray(rig.joints)[:, 8] if getattr(rig, "joints", None) is not None and \
        len(rig.joints) == len(data.muscle_names) else None
    if setup.scale != 1.0:      # the caches hold the file's size (BakeSetup.scale): so do the skin and its bones
        world = np.array(world)
        world[..., :3, 3] *= setup.scale
    data, world = with_chains(data, world, setup.character.joint_names)
    rep = export_glb(setup.character.scaled(setup.scale), world, data, out, bones=budget, max_influences=max_influences,
                     source=source, fps=setup.fps, muscle_joint=muscle_joint,
                     loop=setup.loop.to_json() if getattr(setup, "loop", None) is not None else None)
    summary_path = os.path.join(out_dir, "bake.json")
    if os.path.isfile(summary_path) and path is None:
        with open(summary_path, encoding="utf-8") as fh:
            summary = json.load(fh)
        summary["glb"] = {k: v for k, v in rep.items() if k != "bone_names"}
        summary.setdefault("files", {})["glb"] = GLB_NAME
        with atomic_path(summary_path) as tmp, open(tmp, "w", encoding="utf-8") as fh:
            json.dump(summary, fh, indent=1)
    return rep


def with_chains(data, world: np.ndarray, joint_names) -> tuple:
    """(data, world) with the swung chains on their own bones: the chain joints' world transforms (bake.npz
    chain_world) in `world` (T, J, 4, 4), and the smooth skin (skin_lbs) following them (plus chain_delta, what the
    swing adds to linear skinning), so the file's joints play the chains and its jiggle bones fit the tissue alone.
    Unchanged without chains."""
    import dataclasses
    if getattr(data, "chain_names", None) is None or not len(data.chain_names):
        return data, world
    world = np.array(world, np.float64)
    index = {n: i for i, n in enumerate(joint_names)}
    cols = [index[n] for n in data.chain_names if n in index]
    have = [k for k, n in enumerate(data.chain_names) if n in index]
    world[:, cols] = np.asarray(data.chain_world, np.float64)[:len(world), have]
    if data.skin_lbs is not None and data.chain_delta is not None:
        lbs = np.array(data.skin_lbs)
        lbs[:, data.chain_vertices] += data.chain_delta
        data = dataclasses.replace(data, skin_lbs=lbs)
    return data, world


def _period_end(data, world: np.ndarray, setup):
    """An open cycle's frames 0..n-1 (sim/bake/loop.py) with the key at the period added: frame 0 again, moved by
    the root travel (its jiggle is frame 0's in the steady state), so the glb's keys run from 0 to the period and an
    engine looping them wraps with an ordinary step. (data, world) with T + 1 frames."""
    import dataclasses
    lp = setup.loop
    P = float(lp.cycle_times[-1])
    shift = (np.asarray(lp.delta, np.float64) * setup.scale).astype(np.float32)
    more = {}
    for k in ("skin_static", "skin_final", "skin_lbs", "muscle_cvs_static", "muscle_cvs_dynamic"):
        a = getattr(data, k)
        if a is not None:
            more[k] = np.concatenate([a, (a[:1] + shift).astype(a.dtype)])
    jw = np.array(data.joint_world[:1])
    jw[..., :3, 3] += shift
    more["joint_world"] = np.concatenate([data.joint_world, jw.astype(data.joint_world.dtype)])
    if getattr(data, "chain_world", None) is not None:      # the chains at the period: frame 0's, moved alike
        cw = np.array(data.chain_world[:1])
        cw[..., :3, 3] += shift
        more["chain_world"] = np.concatenate([data.chain_world, cw.astype(data.chain_world.dtype)])
        for k in ("chain_tips_static", "chain_tips_final"):
            a = getattr(data, k)
            more[k] = np.concatenate([a, (a[:1] + shift).astype(a.dtype)])
        more["chain_delta"] = np.concatenate([data.chain_delta, data.chain_delta[:1]])
    if getattr(data, "activation", None) is not None:       # frame 0's, as its jiggle
        more["activation"] = np.concatenate([data.activation, data.activation[:1]])
    more["times"] = np.r_[np.asarray(data.times, np.float64), P]
    return dataclasses.replace(data, **more), np.concatenate([world, setup.world_at(np.array([P]))])


def _material_source(character) -> str | None:
    """The glTF whose material the glb copies: the character's own file, or the glTF an FBX was read as."""
    src = character.source or ""
    low = src.lower()
    if low.endswith((".glb", ".gltf")) and os.path.isfile(src):
        return src
    if low.endswith(".fbx") and os.path.isfile(src):
        from jiggle.rig.motion.fbx import fbx_to_gltf
        return fbx_to_gltf(src)
    return None
