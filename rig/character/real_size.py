"""A character's real size, where its file does not say it: a game character modelled 5 units tall may be a cat.

A material in physical units (rig/muscle/material.py) wobbles at a frequency that depends on the part's real size
(sim/jiggle/materials.py): a horse's belly slower than a cat's. The file's unit gives that size for a scan or a
film character in metres; a game file's unit is arbitrary. So the size is taken, first that applies:

1. the user's: ``--height METRES`` (the character's real height);
2. its own walk: dynamic similarity (Alexander & Jayes 1983, J Zool 201:135-152: animals of any size walk alike at
   the same Froude number v^2 / (g h), h the hip height) makes a walk's stride period T = K_WALK sqrt(h / g):
   K_WALK = 3.5 is a human's (hip 0.9 m, stride 1.06 s) and within 20% of a horse's and a dog's. A character whose
   file has a looping animation named like a walk, and legs that reach the floor, is as many times its file's size
   as g (T / K_WALK)^2 is its hip height in the file. A walker without legs (a blob that waddles or hops, a
   snake's slither) vaults over its base as an inverted pendulum of its centre of mass: its centre of mass height
   (the skin's, area-weighted) stands for the hip height, as it nearly does for a human (0.55 of the height against
   the hip's 0.52);
3. the file's unit, taken as metres (after --unit and the human template's own size rule, rig.character.character
   template_scale).

Game cycles are often played fast, so an inferred size is good to about 30%: it is recorded with its source
(bake.json "real_size", `jiggle inspect`), and ``--height`` overrides it.
"""
from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

G = 9.81
"""m/s^2."""
K_WALK = 3.5
"""A walk's stride period over sqrt(hip height / g) (see the module)."""
SCALE_RANGE = (0.01, 100.0)
"""An inferred scale outside this (real size over the file's) is a misread, not a size: the file's unit is kept."""
WALK_WORDS = ("walk",)


@dataclass(frozen=True)
class RealSize:
    """scale : the character's real size over its size as simulated (1: as simulated). height_m : its real height,
    metres. source : "height" (--height), "walk" (its own walk cycle) or "file" (the file's unit). why : one
    sentence."""

    scale: float
    height_m: float
    source: str
    why: str

    def to_json(self) -> dict:
        return {"scale": round(self.scale, 6), "height_m": round(self.height_m, 4), "source": self.source,
                "why": self.why}


CONTROL_WORDS = ("ik", "pole", "target", "ctrl", "control")
"""Joints named so are rig controls (IK targets on the floor), not legs."""


def leg_height(bind_world: np.ndarray, parents: np.ndarray, floor_z: float, height: float,
               names=None) -> float | None:
    """metres: the median hip height of the legs of a skeleton at bind (J, 4, 4) world transforms, (J,) parents;
    floor_z the rest skin's lowest z, height its height, names the joints' (to leave rig controls out). A leg is a
    run from an end joint in the lowest 30% of the height (a foot, or a game rig's lower leg whose bone reaches the
    hoof) up through single-child joints to the joint where the skeleton branches (the pelvis, the chest): its hip
    is the last joint before that branch. None without two such legs."""
    p = np.asarray(bind_world, np.float64)[:, :3, 3]
    par = np.asarray(parents, np.int64)
    J = len(par)
    kids = np.bincount(par[par >= 0], minlength=J)

    def control(j):
        words = [w for w in re.split(r"[^a-z]+", str(names[j]).lower()) if w] if names is not None else []
        return any(w.startswith(c) for w in words for c in CONTROL_WORDS)
    hips = set()
    for j in np.flatnonzero((p[:, 2] - floor_z <= 0.3 * height) & (kids == 0)):
        if control(j):
            continue
        k = int(j)
        while par[k] >= 0 and kids[par[k]] == 1 and not control(int(par[k])):
            k = int(par[k])
        if par[k] >= 0 and p[k, 2] - floor_z > 0.2 * height and not control(k):
            hips.add(k)
    if len(hips) < 2:
        return None
    return float(np.median([p[k, 2] - floor_z for k in hips]))


def centre_height(vertices: np.ndarray, faces: np.ndarray) -> float | None:
    """metres: the height above its lowest point of the area-weighted centroid of a skin's triangles (vertices
    (V, 3), faces (F, 3)); the vertices' mean without faces. None for an empty skin."""
    v = np.asarray(vertices, np.float64)
    if not len(v):
        return None
    f = np.asarray(faces, np.int64).reshape(-1, 3) if faces is not None and np.size(faces) else None
    if f is None:
        return float(v[:, 2].mean() - v[:, 2].min())
    t = v[f]
    area = 0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1)
    if not area.sum() > 0:
        return float(v[:, 2].mean() - v[:, 2].min())
    return float((area * t[:, :, 2].mean(axis=1)).sum() / area.sum() - v[:, 2].min())


def is_walk(name: str) -> bool:
    words = [w for w in re.split(r"[^a-z]+", str(name).lower()) if w]
    return any(w.startswith(k) for w in words for k in WALK_WORDS)


def real_size(character, height_m: float | None = None, walk: tuple[str, float] | None = None) -> RealSize:
    """The RealSize of `character` (as simulated: rig.character.character.Character): from `height_m` (the user's,
    metres), else from `walk` ((its name, its period in seconds): the character's own looping walk cycle), else its
    file's unit (see the module)."""
    v = np.asarray(character.vertices, np.float64)
    h = float(np.ptp(v[:, 2])) if len(v) else 0.0
    if height_m is not None:
        k = float(height_m) / max(h, 1e-12)
        return RealSize(k, float(height_m), "height", f"--height {height_m:g} m: {k:.3g} x the file's {h:.3g} m")
    if walk is not None and h > 0:
        name, period = walk
        hip = leg_height(character.bind_world, character.parents, float(v[:, 2].min()), h, character.joint_names)
        what = "its hips are"
        if hip is None:
            hip, what = centre_height(v, getattr(character, "faces", None)), "it has no legs: its centre of mass is"
        if hip is not None and hip > 0 and period > 0:
            real_hip = G * (period / K_WALK) ** 2
            k = real_hip / hip
            if SCALE_RANGE[0] <= k <= SCALE_RANGE[1]:
                return RealSize(k, h * k, "walk",
                                f"its walk {name!r} strides in {period:.3g} s, as a body of hip height {real_hip:.3g} m "
                                f"walks (dynamic similarity, T = {K_WALK:g} sqrt(h / g)); {what} {hip:.3g} m "
                                f"high in the file: {h * k:.3g} m tall, {k:.3g} x the file's size")
    return RealSize(1.0, h, "file", f"the file's unit taken as metres ({h:.3g} m tall): no --height, and no walk "
                                    "cycle with legs to infer the size from")


__all__ = ["G", "K_WALK", "RealSize", "leg_height", "centre_height", "is_walk", "real_size"]
