"""glTF 2.0 animations (.glb, .gltf) as a :class:`~rig.motion.clip.Clip`.

Readings where glTF leaves a choice, stated once here (the joint set, axes and the folding of scale
into a rigid clip are those of :mod:`rig.motion.gltf_skeleton`, whose docstring says them):
- Joints: the joints of skin `skin` (default the first) and the nodes joining them into a tree. With
  ``skin=None``, or in a file without skins, the nodes the animation targets instead. Joints that no
  channel animates keep their rest TRS; animated nodes above the tree (an animated armature) still
  move the root, because everything above the root is accumulated into it frame by frame.
- Channels: translation, rotation and scale; "weights" (morph targets) are skipped. Interpolation as
  the spec says: LINEAR (lerp; slerp on the shortest arc for rotations), STEP (the key at or before
  t), CUBICSPLINE (cubic Hermite with the in/out tangents multiplied by the key interval, rotations
  normalised afterwards). Before the first key a channel holds its first value, after the last its last.
- Channels on nodes that are neither joints of the skin nor above them (a prop, a camera, another
  character, the skinned mesh node, whose transform the spec ignores) do not move the skeleton: they
  are ignored with a JiggleWarning naming them.
- Scale, for a clip that poses a skin (`skin` given): every joint and node above the skeleton must
  scale uniformly and positively at every frame (rig.motion.gltf_io), else InputError naming the node
  and channel; an animated uniform scale moves the joints exactly but cannot scale the skin around a
  rigid joint, which a JiggleWarning says. With ``skin=None`` (mocap only) any scale is read.
- Key times must be finite, start at or after 0 and increase strictly (glTF 2.0 spec); anything else
  is an InputError naming the sampler's input accessor.
- Time: the clip starts at the earliest key of the animation (``meta["start_time"]`` keeps it: clip
  time t is animation time t + start_time) and ends at or just before the latest key.
- Frame rate: `fps` if given. Otherwise, when the distinct key times of all channels together are
  evenly spaced (within 0.1 % of the interval) at 10 fps or faster, that rate (snapped to a whole
  number within 0.1 %), so frames land on keys; else 30 fps. ``meta["fps_rule"]`` says which.
- Rotations read from normalized integer accessors (BYTE, UBYTE, SHORT, USHORT) are mapped to
  [-1, 1] as the spec says and renormalised.
"""
from __future__ import annotations

import os
import warnings

import numpy as np

from jiggle.rig.base.errors import InputError, JiggleWarning
from jiggle.rig.motion import quat
from jiggle.rig.motion.clip import Clip
from jiggle.rig.motion.gltf_io import (
    Z_UP,
    GltfDocument,
    check_uniform_scale,
    joint_tree,
    rigid_locals,
    scale_problem,
    trs_matrix,
)

_WIDTH = {"translation": 3, "rotation": 4, "scale": 3}
_INTERP = ("LINEAR", "STEP", "CUBICSPLINE")
MIN_KEY_FPS = 10.0
DEFAULT_FPS = 30.0


def sample_keys(times: np.ndarray, values: np.ndarray, interpolation: str, t: np.ndarray,
                rotation: bool = False) -> np.ndarray:
    """Evaluate one glTF sampler at times `t`.

    Parameters
    ----------
    times : (K,) seconds, non-decreasing key times.
    values : (K, C) key values, or (K, 3, C) in-tangent, value, out-tangent for CUBICSPLINE; for
        rotations w,x,y,z quaternions.
    interpolation : "LINEAR", "STEP" or "CUBICSPLINE".
    t : (T,) seconds.
    rotation : slerp (LINEAR) and normalise (CUBICSPLINE) as quaternions.

    Returns (T, C) float64.
    """
    t = np.asarray(t, dtype=float)
    K = times.shape[0]
    v = values[:, 1] if interpolation == "CUBICSPLINE" else values
    if K == 1:
        out = np.broadcast_to(v[0], (t.shape[0], v.shape[-1])).copy()
        return quat.normalize(out) if rotation else out
    after = np.searchsorted(times, t, side="right") - 1  # last key at or before t (-1 before the first)
    if interpolation == "STEP":
        out = v[np.clip(after, 0, K - 1)]
        return quat.normalize(out) if rotation else out
    i = np.clip(after, 0, K - 2)
    dt = times[i + 1] - times[i]
    s = np.where(dt > 0, (t - times[i]) / np.where(dt > 0, dt, 1.0), 1.0)
    s = np.clip(s, 0.0, 1.0)
    if interpolation == "LINEAR":
        if rotation:
            return quat.slerp(v[i], v[i + 1], s)
        return v[i] + s[:, None] * (v[i + 1] - v[i])
    # CUBICSPLINE (glTF 2.0 spec, Appendix C): p(s) = (2s^3 - 3s^2 + 1) v_i + (s^3 - 2s^2 + s) dt b_i
    #   + (-2s^3 + 3s^2) v_{i+1} + (s^3 - s^2) dt a_{i+1}, with a the in-tangent and b the out-tangent.
    s2, s3 = s * s, s * s * s
    h00, h10, h01, h11 = 2 * s3 - 3 * s2 + 1, s3 - 2 * s2 + s, -2 * s3 + 3 * s2, s3 - s2
    a_next, b_here = values[i + 1, 0], values[i, 2]
    out = (h00[:, None] * v[i] + (h10 * dt)[:, None] * b_here + h01[:, None] * v[i + 1]
           + (h11 * dt)[:, None] * a_next)
    return quat.normalize(out) if rotation else out


def _choose(doc: GltfDocument, animation) -> int:
    anims = doc.gltf.animations
    names = [a.name or f"animation{k}" for k, a in enumerate(anims)]
    listing = ", ".join(f"{k}: {n!r}" for k, n in enumerate(names))
    if animation is None:
        return 0
    if isinstance(animation, (int, np.integer)) and not isinstance(animation, bool):
        if not 0 <= animation < len(anims):
            raise InputError(f"animation index {animation} is out of range; the file has {listing}", doc.path,
                             field="animation")
        return int(animation)
    if isinstance(animation, str):
        hits = [k for k, a in enumerate(anims) if a.name == animation]
        if not hits:
            hits = [k for k, n in enumerate(names) if n == animation]
        if not hits and animation.strip().isdigit():  # an index typed on the command line
            return _choose(doc, int(animation))
        if not hits:
            raise InputError(f"no animation named {animation!r}; the file has {listing}", doc.path,
                             field="animation")
        return hits[0]
    raise InputError(f"animation must be a name or an index, got {animation!r}; the file has {listing}",
                     doc.path, field="animation")


def _channels(doc: GltfDocument, ai: int) -> list[tuple[int, str, str, np.ndarray, np.ndarray]]:
    """Decoded TRS channels of animation `ai`: (node, path, interpolation, key times (K,), values)."""
    g = doc.gltf
    anim = g.animations[ai]
    out = []
    for ci, ch in enumerate(anim.channels):
        where = f"animations[{ai}].channels[{ci}]"
        tgt = ch.target
        if tgt is None or tgt.path not in (*_WIDTH, "weights"):
            raise InputError(f"target path {getattr(tgt, 'path', None)!r} is not translation, rotation, scale "
                             f"or weights", doc.path, field=f"{where}.target.path")
        if tgt.path == "weights" or tgt.node is None:
            continue  # morph weights do not move joints; a channel without node is ignored by the spec
        if not 0 <= tgt.node < len(g.nodes):
            raise InputError(f"node {tgt.node} does not exist", doc.path, field=f"{where}.target.node")
        if not 0 <= ch.sampler < len(anim.samplers):
            raise InputError(f"sampler {ch.sampler} does not exist", doc.path, field=f"{where}.sampler")
        sw = f"animations[{ai}].samplers[{ch.sampler}]"
        smp = anim.samplers[ch.sampler]
        interp = smp.interpolation or "LINEAR"
        if interp not in _INTERP:
            raise InputError(f"interpolation {interp!r}; expected LINEAR, STEP or CUBICSPLINE", doc.path,
                             field=f"{sw}.interpolation")
        times = doc.accessor(smp.input, f"{sw}.input")
        if times.shape[1] != 1 or times.shape[0] == 0:
            raise InputError("key times must be a non-empty SCALAR accessor", doc.path, field=f"{sw}.input")
        times = times[:, 0]
        acc = f"{sw}.input (accessors[{smp.input}])"
        if not np.all(np.isfinite(times)):
            k = int(np.nonzero(~np.isfinite(times))[0][0])
            raise InputError(f"key time {k} is {times[k]}; key times must be finite seconds", doc.path, field=acc)
        if times[0] < 0:
            raise InputError(f"the first key time is {times[0]:g} s; glTF key times start at or after 0",
                             doc.path, field=acc)
        if np.any(np.diff(times) <= 0):
            k = int(np.nonzero(np.diff(times) <= 0)[0][0])
            raise InputError(f"key times must increase strictly (glTF 2.0 spec), but key {k + 1} is at "
                             f"{times[k + 1]:g} s after key {k} at {times[k]:g} s", doc.path, field=acc)
        vals = doc.accessor(smp.output, f"{sw}.output")
        w = _WIDTH[tgt.path]
        per_key = 3 if interp == "CUBICSPLINE" else 1
        if vals.shape != (times.shape[0] * per_key, w):
            raise InputError(f"expected {times.shape[0] * per_key} values of {w} components for "
                             f"{times.shape[0]} {interp} keys of {tgt.path}, found {vals.shape[0]} of "
                             f"{vals.shape[1]}", doc.path, field=f"{sw}.output")
        if not np.all(np.isfinite(vals)):
            raise InputError("key values hold NaN or inf", doc.path, field=f"{sw}.output")
        if tgt.path == "rotation":
            vals = quat.from_xyzw(vals)  # the permutation is linear: tangents convert the same way
        if per_key == 3:
            vals = vals.reshape(times.shape[0], 3, w)
        if g.nodes[tgt.node].matrix is not None:
            raise InputError("a node with a matrix cannot be animated (glTF 2.0 spec)", doc.path,
                             field=f"{where}.target.node")
        out.append((int(tgt.node), tgt.path, interp, times, vals))
    return out


def _frame_rate(channels) -> tuple[float, str]:
    keys = np.unique(np.concatenate([c[3] for c in channels]))
    if keys.shape[0] >= 2:
        d = np.diff(keys)
        step = float(np.median(d))
        if step > 0 and np.all(np.abs(d - step) <= 1e-3 * step) and 1.0 / step >= MIN_KEY_FPS:
            fps = 1.0 / step
            if abs(fps - round(fps)) <= 1e-3 * fps:
                fps = float(round(fps))
            return fps, "key rate (evenly spaced keys)"
    return DEFAULT_FPS, f"default {DEFAULT_FPS:g} fps (keys not evenly spaced at >= {MIN_KEY_FPS:g} fps)"


def _check_scales(doc: GltfDocument, ai: int, aname: str, nodes, trs: dict, times: np.ndarray) -> None:
    """For a clip that poses a skin: InputError when a joint or a node above the skeleton scales
    non-uniformly or negatively at some frame; JiggleWarning when an animation changes a uniform
    scale (rigid joints cannot follow it: the skin keeps its rest scale around that joint)."""
    chan = {(c.target.node, c.target.path): ci for ci, c in enumerate(doc.gltf.animations[ai].channels)
            if c.target is not None}
    changed = []
    for nd in sorted(nodes):
        d = trs[nd]
        if d["matrix"] is not None or (nd, "scale") not in chan:
            check_uniform_scale(doc, nd)
            continue
        sc = d["scale"]
        bad = scale_problem(sc[:, None, :] * np.eye(3))
        if bad is not None:
            k = bad[1]
            check_uniform_scale(doc, nd, sc[k:k + 1], when=f" at {times[k]:g} s",
                                field=f'animations[{ai}].channels[{chan[nd, "scale"]}] (node {nd} '
                                      f'"{doc.node_names[nd]}", animation {aname!r})')
        rest = doc.node_trs(nd)[2]
        if np.abs(sc - rest).max() > 1e-4 * max(float(np.abs(rest).max()), 1e-12):
            changed.append(f"{doc.node_names[nd]!r} ({sc.min():.4g}..{sc.max():.4g})")
    if changed:
        warnings.warn(f"{doc.path}: animation {aname!r} scales {', '.join(changed[:6])}"
                      f"{' and more' if len(changed) > 6 else ''}: jiggle's joints are rigid, so joint positions "
                      f"follow the scale but the skin around those joints keeps its rest size", JiggleWarning,
                      stacklevel=3)


def read_gltf_animation(path: str | os.PathLike, animation: str | int | None = None, fps: float | None = None,
                        skin: int | None = 0) -> Clip:
    """Read one animation of a glTF/GLB file as a Clip (Z-up, metres); see the module docstring.

    Parameters
    ----------
    path : .glb or .gltf (external or data-URI buffers).
    animation : name or index (a string of digits that is no animation's name counts as an index);
        None for the first.
    fps : frames per second to sample at; None for the key rate or 30 (module docstring).
    skin : which skin's joints form the skeleton; None for the animated nodes instead.
    """
    doc = GltfDocument(path)
    g = doc.gltf
    if not g.animations:
        raise InputError(f"the file has no animation (it holds {doc.contents()})", doc.path, field="animations")
    if fps is not None and (not np.isfinite(fps) or fps <= 0):
        raise InputError(f"fps must be a positive number, got {fps}", doc.path, field="fps")
    ai = _choose(doc, animation)
    channels = _channels(doc, ai)
    aname = g.animations[ai].name or f"animation{ai}"
    if not channels:
        raise InputError(f"animation {aname!r} has no translation, rotation or scale channel", doc.path,
                         field=f"animations[{ai}].channels")
    order, parents = joint_tree(doc, _skeleton_members(doc, skin, channels))

    t0 = min(float(c[3][0]) for c in channels)
    t1 = max(float(c[3][-1]) for c in channels)
    if fps is None:
        fps, rule = _frame_rate(channels)
    else:
        rule = "given"
    times = _frame_times(t0, t1, fps)

    trs, animated = _sample_nodes(doc, order, parents, channels, times, aname, skin)
    if skin is not None and g.skins:
        _check_scales(doc, ai, aname, set(trs), trs, times)
    rot, tra = _posed_locals(doc, order, parents, trs, times.shape[0])
    rest_rot, rest_tra = _rest_locals(doc, order, parents)

    meta = {"format": "glTF", "animation": aname, "animation_index": ai, "start_time": t0,
            "end_time": t1, "fps_rule": rule, "channels": len(channels),
            "animated_joints": sum(nd in animated for nd in order),
            "joint_source": f"skin {skin}" if (skin is not None and g.skins) else "animated nodes"}
    return Clip(joint_names=[doc.node_names[nd] for nd in order], parents=parents, offsets=rest_tra,
                rest_rotations=rest_rot, rotations=rot, translations=tra, fps=fps,
                name=os.path.splitext(os.path.basename(doc.path))[0], source=doc.path, meta=meta)


def _skeleton_members(doc: GltfDocument, skin: int | None, channels) -> list[int]:
    """The nodes the skeleton is built from: the joints of skin `skin`, or, with ``skin=None`` or
    in a file without skins, the nodes the channels animate."""
    g = doc.gltf
    if skin is not None and g.skins:
        if not isinstance(skin, (int, np.integer)) or not 0 <= skin < len(g.skins):
            raise InputError(f"skin {skin!r} does not exist; the file has skins 0..{len(g.skins) - 1}",
                             doc.path, field="skin")
        members = list(g.skins[skin].joints or [])
        if not members:
            raise InputError("the skin lists no joints", doc.path, field=f"skins[{skin}].joints")
    else:
        members = sorted({c[0] for c in channels})
    return members


def _frame_times(t0: float, t1: float, fps: float) -> np.ndarray:
    """(T,) seconds: frames at `fps` from `t0` to `t1` or just before it (a frame within 1e-4 of a
    frame interval of `t1` lands on it)."""
    span = (t1 - t0) * fps
    n = int(round(span)) + 1 if abs(span - round(span)) < 1e-4 else int(np.floor(span)) + 1
    return t0 + np.arange(n) / fps


def _sample_nodes(doc: GltfDocument, order: list[int], parents, channels, times: np.ndarray, aname: str,
                  skin: int | None) -> tuple[dict[int, dict], set[int]]:
    """Every node the clip depends on (the joints `order` and everything above the roots) posed at
    `times` (T,): {node: {"translation": (T, 3), "rotation": (T, 4) w,x,y,z, "scale": (T, 3),
    "matrix": (4, 4) or None}}, its rest TRS where no channel drives it; and the animated nodes
    among them. Channels on other nodes are ignored with a JiggleWarning."""
    T = times.shape[0]
    needed = set(order)
    for j, nd in enumerate(order):
        if parents[j] < 0:
            needed.update(doc.ancestors(nd))
    trs = {}
    for nd in needed:
        t, r, s, m = doc.node_trs(nd)
        trs[nd] = {"translation": np.broadcast_to(t, (T, 3)).copy(), "rotation": np.broadcast_to(r, (T, 4)).copy(),
                   "scale": np.broadcast_to(s, (T, 3)).copy(), "matrix": m}
    animated, outside = set(), {}
    for nd, path_, interp, kt, kv in channels:
        if nd in trs:
            trs[nd][path_] = sample_keys(kt, kv, interp, times, rotation=path_ == "rotation")
            animated.add(nd)
        else:
            outside.setdefault(doc.node_names[nd], []).append(path_)
    if outside:
        listed = ", ".join(f"{n!r} ({'/'.join(p)})" for n, p in list(outside.items())[:8])
        more = f" and {len(outside) - 8} more" if len(outside) > 8 else ""
        warnings.warn(f"{doc.path}: animation {aname!r} also drives {len(outside)} node(s) that are not joints of "
                      f"skin {skin} nor above them, ignored: {listed}{more}", JiggleWarning, stacklevel=3)
    return trs, animated


def _node_matrix(d: dict, T: int) -> np.ndarray:
    """(T, 4, 4) local matrices of a node sampled by `_sample_nodes`."""
    if d["matrix"] is not None:
        return np.broadcast_to(d["matrix"], (T, 4, 4))
    return trs_matrix(d["translation"], d["rotation"], d["scale"])


def _posed_locals(doc: GltfDocument, order: list[int], parents, trs: dict[int, dict], T: int
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Rigid local rotations (T, J, 4) and translations (T, J, 3) of the joints `order` per frame,
    everything above a root (and Z-up) folded into it (rig.motion.gltf_io.rigid_locals)."""
    J = len(order)
    local_m = np.stack([_node_matrix(trs[nd], T) for nd in order], axis=1)
    local_r = np.stack([trs[nd]["rotation"] for nd in order], axis=1)
    above = np.broadcast_to(np.eye(4), (T, J, 4, 4)).copy()
    for j, nd in enumerate(order):
        if parents[j] < 0:
            m = np.broadcast_to(Z_UP, (T, 4, 4)).copy()
            for a in doc.ancestors(nd)[::-1]:
                m = m @ _node_matrix(trs[a], T)
            above[:, j] = m
    rot, tra, _ = rigid_locals(parents, above, local_m, local_r)
    return rot, tra


def _rest_locals(doc: GltfDocument, order: list[int], parents) -> tuple[np.ndarray, np.ndarray]:
    """Rest pose: rigid local rotations (J, 4) and translations (J, 3), the same folding as
    `_posed_locals` on the nodes' own TRS."""
    J = len(order)
    rest = [doc.node_trs(nd) for nd in order]
    rest_m = np.stack([m if m is not None else trs_matrix(t, r, s) for t, r, s, m in rest])[None]
    rest_r = np.stack([r for _, r, _, _ in rest])[None]
    rest_above = np.broadcast_to(np.eye(4), (1, J, 4, 4)).copy()
    for j, nd in enumerate(order):
        if parents[j] < 0:
            m = Z_UP.copy()
            for a in doc.ancestors(nd)[::-1]:
                t, r, s, mm = doc.node_trs(a)
                m = m @ (mm if mm is not None else trs_matrix(t, r, s))
            rest_above[0, j] = m
    rest_rot, rest_tra, _ = rigid_locals(parents, rest_above, rest_m, rest_r)
    return rest_rot[0], rest_tra[0]
