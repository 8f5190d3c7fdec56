"""What a bake runs on, resolved from a scene and the command line: the motion, the character, its
fitted muscles and skin, the jiggle parameters, the output times, and the parameter set that names
the bake (stored in every cache and used to check that `--resume` goes on with the same bake).

`BakeRequest` is what the user asked for (every field None means "the scene's, else the default");
`prepare(request)` does the slow, one-off work (read files, generate a body, retarget, fit the
template, bind the skin, drive the skeleton) and returns a `BakeSetup`, which `sim.bake.baker` turns into
caches frame chunk by frame chunk.
"""
from __future__ import annotations

import copy
import functools
import hashlib
import json
import math
import os
import re
import time
from dataclasses import dataclass, field, fields, is_dataclass, replace
from types import MappingProxyType
from typing import Callable, Mapping, MutableMapping

import numpy as np

from jiggle.rig.base.errors import InputError
from jiggle.sim.jiggle.keyed import Curve
from jiggle.sim.jiggle.params import BlendCurve, JiggleSettings
from jiggle.sim.jiggle.secondary import DEFAULT_GOAL_RATE, knot_times

BAKE_FPS = 30.0
"""Output frames per second when neither the command line nor the scene says."""
DEFAULT_FORMATS = ("npz", "usdc")
DEFAULT_CHUNK = 64
"""Frames per chunk: each chunk is simulated, skinned and written on its own (and resumed from)."""
VERSION = 3
"""3: the chains swing (sim.chain). Bumped when the bake's arithmetic changes, so `--resume` never splices two versions' chunks."""


@dataclass(frozen=True)
class BakeRequest:
    """A bake as asked for; None: the scene's value, else the default.

    scene : scene TOML path (None: the clip alone, or the built-in demo scene without a clip).
    clip : motion file (BVH, AMC, glTF), over the scene's [motion]; skeleton, animation, scale, tpose
        read it (rig.motion.mocap.load_clip).
    character : skinned glTF/GLB (the clip is retargeted onto it), over the scene's [character] file.
    template : muscle template, a built-in name or a .toml/.xml path.
    fps, substeps, blend (static_dyn_blend of every muscle), jiggle (strength J of every muscle; blend and
    jiggle are numbers or sim.jiggle.keyed.Curve), gravity (bool), preroll (seconds), collisions (bool),
    colliders ("bone", "model"), muscle_collisions (bool): over the scene's [jiggle].
    muscles : per-muscle entries from the command line, (pattern, {OVERRIDES key: value}, flag text) in the
        order given (pattern a muscle name or a glob), over the scene's tables (sim.bake.scene.apply_entries).
    materials : per-muscle tissue materials, "[NAME=]MATERIAL" each (NAME a muscle or glob, every muscle without it;
        MATERIAL fat, muscle, or E=...,nu=...,rho=...,zeta=...; rig.muscle.material), in order: the goal springs,
        damping and density they give (sim.jiggle.materials) replace the template's; `muscles` entries still override.
    height : the character's real height, metres (None: inferred, rig.character.real_size), for the materials' rule.
    tissue : "particles" (None too: the goal-spring particles) or "fem" (the hero mode: every simulated part a
        Neo-Hookean solid of its material, sim/fem/tissue.py).
    activation : "on", "off" or None (the default: on wherever the character has muscles, fat alone not, with the
        particles; off with the FEM hero mode): each muscle's activation from the clip's own joint torques
        (sim.drive.inverse, sim.jiggle.activation), stiffening and bulging each working muscle, written to the caches
        (bake.npz's activation) and bake.json.
    start, end : seconds of the clip. frames : only the first N output frames.
    drive : "kinematic" or "physics". formats : cache formats (sim.bake.scene.FORMATS). chunk : frames per chunk.
    body : BodyOptions keywords of a generated body. influences, skinning ("shell"/"influence"),
    method ("lbs"/"dqs"), clip_map, character_map (the character's roles, for the template and for
    retargeting), skin, unit: as `jiggle simulate`; mush:
    Delta Mush steps on the smooth skin (0: off).
    loop : "auto" (None too), "on" or "off": a cycle baked in its periodic steady state (sim/bake/loop.py).
    chains : which chains swing (rig.character.chains.find_chains: "auto" (None too), "none" or a list of joints and
        globs); chain_params : per-chain parameters from the command line, (pattern, {name: value}, flag text) in the
        order given (sim.chain.params.chain_params), over the scene's [chains.NAME] tables.
    device : the Warp device every kernel of the bake runs on ("cpu", "cuda", "cuda:N"; None: "cpu").
    """

    scene: str | None = None
    clip: str | None = None
    skeleton: str | None = None
    animation: str | int | None = None
    scale: float | None = None
    tpose: str = "auto"
    character: str | None = None
    template: str | None = None
    fps: float | None = None
    substeps: int | None = None
    blend: float | Curve | None = None
    jiggle: float | Curve | None = None
    muscles: tuple = ()
    materials: tuple = ()
    height: float | None = None
    tissue: str | None = None
    activation: str | None = None
    gravity: bool | None = None
    preroll: float | None = None
    collisions: bool | None = None
    colliders: str | None = None
    muscle_collisions: bool | None = None
    device: str | None = None
    start: float | None = None
    end: float | None = None
    frames: int | None = None
    drive: str | None = None
    formats: tuple | None = None
    chunk: int | None = None
    jiggle_bones: int | None = None
    max_influences: int = 4
    body: Mapping = field(default_factory=lambda: MappingProxyType({}))
    influences: int | None = None
    skinning: str | None = None
    method: str | None = None
    clip_map: str | None = None
    character_map: str | None = None
    skin: int | None = None
    unit: str | None = None
    mush: int | None = None
    rigid: str | None = None
    loop: str | None = None
    chains: str | None = None
    chain_params: tuple = ()


@dataclass(frozen=True, eq=False)
class BakeSetup:
    """Everything the chunked bake needs.

    name : the bake's title. skin : rig.skin.muscle_skin.MuscleSkin (character, muscle rig, deformers).
    jiggles : one MuscleJiggle per muscle. settings : JiggleSettings.
    times : (T,) output times, seconds of the clip. fps : output rate. knots : (K,) goal knot times.
    world_at : knot times (k,) -> (k, J, 4, 4) the character's joint world transforms (the drive's).
    joints_at : output times (t,) -> (t, J_clip, 4, 4) the clip's own joints (the npz's joint_world).
    joint_names : the clip's own joint names. formats, chunk : caches to write, frames per chunk.
    params : the full parameter set (JSON-ready); key : its hash, naming this bake.
    timings : seconds spent preparing, by step.
    floor : metres, world z of the floor the particles collide with (settings.collisions), None: none.
    capsules : the bone capsules (rig.character.capsules.BoneCapsules) the particles collide with, None:
        the character's own (built by the baker).
    scale : the file's metres per simulated metre: a character simulated at its template's size
        (rig.character.character.template_scale) is written back at its file's size (every position of the
        caches times `scale`); 1.0 for the others.
    chains : sim.chain.build.ChainSetup, the chains that swing (their model and parameters), or None.
    tissue_solver : "particles" or "fem" (BakeRequest.tissue). real_scale : real metres per simulated metre
        (rig.character.real_size.RealSize.scale): the FEM's materials are in real units.
    activation : (T, M) float32 in [0, 1] at the output times, each muscle's activation (BakeRequest.activation
        "on"), or None.
    """

    name: str
    skin: object
    jiggles: tuple
    settings: JiggleSettings
    times: np.ndarray
    fps: float
    knots: np.ndarray
    world_at: Callable
    joints_at: Callable
    joint_names: tuple
    formats: tuple
    chunk: int
    params: dict
    key: str
    timings: dict
    floor: float | None = None
    capsules: object = None
    glb: Mapping = field(default_factory=lambda: MappingProxyType({}))
    scale: float = 1.0
    loop: object = None
    """sim.bake.loop.Loop: whether the bake loops, its period and how it was judged; None: a plain bake."""
    chains: object = None
    tissue_solver: str = "particles"
    real_scale: float = 1.0
    activation: np.ndarray | None = None
    relaxed_jiggles: tuple | None = None
    """With activation on: the jiggles before the working muscles' stiffening (what the scene and the command line
    set, and the viewer's sliders tune; `jiggles` is them stiffened by sim.jiggle.activation.stiffened)."""

    @property
    def rig(self):
        return self.skin.rig

    def activation_at(self, t: np.ndarray) -> np.ndarray | None:
        """(K, M) the muscles' activation at times t (K,) seconds, linear between the output frames (None when
        activation is off)."""
        if self.activation is None:
            return None
        a = np.asarray(self.activation, np.float64)
        t = np.asarray(t, np.float64)
        return np.stack([np.interp(t, self.times, a[:, m]) for m in range(a.shape[1])], axis=1)

    def static_at(self, t: np.ndarray, world: np.ndarray):
        """The static muscle shapes (rig.muscle.model.StaticShape, (K, ...)) at times t (K,) seconds posed by joint
        world transforms (K, J, 4, 4): rig.static, each working muscle's belly bulged by its activation
        (rig.muscle.bulge) when activation is on."""
        static = self.rig.static(world, device=self.settings.device)
        if self.activation is None:
            return static
        from jiggle.rig.muscle.bulge import bulged
        from jiggle.rig.muscle.model import StaticShape
        return StaticShape(*bulged(static.cvs, static.curve, self.activation_at(t), table=self.bulge_table))

    @functools.cached_property
    def bulge_table(self) -> np.ndarray:
        """rig.muscle.bulge.growth_table of the rig's rest shapes, once a setup (static_at reads it)."""
        from jiggle.rig.muscle.bulge import growth_table
        return growth_table(self.rig.rest_cvs, working=np.asarray(self.activation).max(axis=0) > 0)

    @property
    def character(self):
        return self.skin.character


def file_digest(path: str) -> str:
    """sha256 of a file's bytes (hex), so a bake names exactly what it read."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def jsonable(x):
    """x with dataclasses, BlendCurves, numpy arrays and scalars turned into JSON values
    (non-finite floats become strings, so the JSON stays strict)."""
    if isinstance(x, Curve):
        return x.to_json()
    if is_dataclass(x) and not isinstance(x, type):
        return {f.name: jsonable(getattr(x, f.name)) for f in fields(x)}
    if isinstance(x, Mapping):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return jsonable(x.tolist())
    if isinstance(x, np.generic):
        return jsonable(x.item())
    if isinstance(x, float) and not math.isfinite(x):
        return str(x)
    return x


UNKEYED = ("template_why",)
"""params entries that say why, not what: the same bake asked for in other words (a template named rather than found
by auto, as export and the viewer rebuild it) has the same key."""


def params_key(params: dict) -> str:
    """A short hash of the canonical JSON of `params` (less UNKEYED)."""
    text = json.dumps({k: v for k, v in params.items() if k not in UNKEYED}, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


@dataclass(frozen=True, eq=False)
class FittedRig:
    """The per-character part of a setup, shared by every clip baked on the same character: the
    character (rig.character.Character), its fitted musculature (rig.muscle.fit) and the bound
    MuscleSkin. Nothing in a bake changes them."""

    character: object
    musculature: object
    skin: object


def fitted_key(req: BakeRequest, pick: Callable, character_file: str | None, body, template: str, clip) -> str:
    """What the FittedRig of a request depends on, hashed: the character file's bytes and how it is read
    (skin, unit, influences), or for a generated body the clip it is generated around (every array of
    it) and the body options; the template and joint map (their bytes when files); the skin's deformer,
    method and Delta Mush steps."""
    def named(path):
        return {"file": os.path.abspath(path), "sha256": file_digest(path)} if path and os.path.isfile(path) else path
    if character_file is not None:
        character = {"file": named(character_file), "skin": pick("skin", 0), "unit": pick("unit", None)}
    else:
        h = hashlib.sha256()
        for name in ("parents", "offsets", "rest_rotations", "rotations", "translations", "end_parents",
                     "end_offsets"):
            a = np.ascontiguousarray(getattr(clip, name))
            h.update(f"{name}{a.dtype.str}{a.shape}".encode())
            h.update(a.tobytes())
        h.update(json.dumps([list(clip.joint_names), clip.fps, clip.name, clip.source,
                             jsonable(dict(clip.meta))], sort_keys=True, default=str).encode())
        character = {"generated": jsonable(body), "clip": h.hexdigest()}
    return params_key({"jiggle_bake": VERSION, "character": character, "influences": pick("influences", 4),
                       "template": named(str(template)), "character_map": named(req.character_map),
                       "skinning": [pick("skinning", "shell"), pick("method", "lbs"), pick("mush", 0)],
                       **({"rigid": req.rigid} if req.rigid not in (None, "auto") else {}),
                       **({"device": req.device} if req.device not in (None, "cpu") else {})})


def output_times(duration: float, fps: float, start: float | None, end: float | None,
                 frames: int | None) -> np.ndarray:
    """(T,) seconds of the clip: start..end (default the whole clip) every 1/fps, the first `frames`."""
    s = 0.0 if start is None else float(start)
    e = duration if end is None else float(end)
    if duration <= 0.0 and start is None and end is None:
        raise InputError("the motion is a single pose (one frame, 0 s long): there is no motion to bake; give a clip "
                         "that moves (a take with no keys, as in a skeleton exported with its bind pose only, holds still)",
                         field="--clip")
    if not 0.0 <= s < e <= duration + 1e-9:
        raise InputError(f"expected 0 <= start < end <= {duration:.4g} s (the motion's length), got start {s:g}, "
                         f"end {e:g}", field="--start/--end")
    times = s + np.arange(int(np.floor((e - s) * fps + 1e-9)) + 1) / fps
    return times if frames is None else times[:frames]


def prepare_from(clip, character, musculature=None, req: BakeRequest | None = None, *,
                 character_file: str | None = None, log: Callable[[str], None] = lambda s: None) -> BakeSetup:
    """`prepare` for a clip (rig.motion.clip.Clip), a character (rig.character.character.Character) and its
    muscles (rig.muscle.fit.Musculature; None: fitted with the request's template) already in memory, as the
    public API's `jiggle.simulate` has them; the request gives the rest (fps, strength, ...; its clip, character
    and scene are not read). character_file : the character's glTF/FBX, to retarget the clip onto it; None: the
    clip must be on the character's own skeleton."""
    req = req or BakeRequest()
    if req.scene is not None or req.clip is not None or req.character is not None:
        raise ValueError("prepare_from takes the clip and character themselves, not a request's files")
    return prepare(replace(req, character=character_file), log, given=(clip, character, musculature))


def prepare(req: BakeRequest, log: Callable[[str], None] = lambda s: None,
            rigs: MutableMapping | None = None, given: tuple | None = None) -> BakeSetup:
    """Resolve `req` against its scene and do the one-off work (see the module), as a sequence of steps: each
    decides one stage and owns its part of the bake's record (`params`, put together by `_record`).

    rigs : a cache of the per-character work (the character read or generated, its fitted muscles and
        bound skin: a FittedRig), by fitted_key; given, a request whose key is in it skips that work
        (`jiggle batch` keeps one per worker), and a new one is stored in it. The setup, its params and
        key are the same either way: nothing in that work depends on the clip beyond what the key names.
    given : (clip, character, musculature or None) in memory, used instead of reading them (`prepare_from`).
    """
    if req.device is not None:
        warp_device(req.device)             # before any work: a device that is not here is the user's mistake
    timings = {}
    t = time.perf_counter()
    solver = tissue_solver(req)
    scene = _scene(req, given)
    if scene is not None and scene.builtin is not None:
        return _prepare_builtin(req, scene, log)
    inputs = _inputs(req, scene, given, solver)
    timings["read_s"] = time.perf_counter() - t
    body = _timed(timings, "character_s", _character, req, inputs, rigs, given, log)
    fit = _timed(timings, "fit_s", _fit, req, inputs, body, rigs, given, log)
    timing = _timing(req, inputs, fit)
    world_at = _timed(timings, "drive_s", _drive, fit.clip, inputs.drive, timing.knots, log)
    tissue = _tissue(req, inputs, body, fit, timing, world_at, log, timings)
    motion = _motion(req, inputs, body, fit, timing, world_at, log)
    chains = _timed(timings, "chains_s", _chains, req, inputs.scene, fit.character, fit.mus, motion.knots,
                    motion.world_at, log)
    contacts = _collisions(tissue.settings, inputs.drive, fit, motion, log)
    activation, jiggles, act_record = _timed(timings, "activation_s", _activation, req, fit, motion, tissue, log)
    params = _record(inputs.record, body.record, fit.record, tissue.record, motion.record, chains.record,
                     contacts.record, act_record)
    return BakeSetup(name=scene.name if scene is not None else inputs.source.name, skin=fit.skin,
                     jiggles=tuple(jiggles), settings=tissue.settings, times=motion.times, fps=motion.fps,
                     knots=motion.knots, world_at=motion.world_at, joints_at=motion.joints_at,
                     joint_names=motion.joint_names, formats=_formats(req, scene), chunk=params["chunk"],
                     params=params, key=params_key(params), timings=timings, floor=contacts.floor,
                     capsules=contacts.capsules, glb=_glb(req),
                     scale=1.0 / fit.character.meta.get("template_scale", 1.0),
                     loop=motion.loop if motion.loop.on else None, chains=chains.chains, tissue_solver=solver,
                     real_scale=tissue.size.scale, activation=activation,
                     relaxed_jiggles=tuple(tissue.jiggles) if activation is not None else None)


RECORD_ORDER = ("jiggle_bake", "scene", "clip", "character", "template", "body_plan", "template_why", "tissue",
                "rigid", "parts", "size_scale", "file_unit_m", "vertices", "drive", "fps", "frames", "start_s", "end_s",
                "skinning", "settings", "muscles", "chunk", "loop", "pose_shapes", "chains", "collisions", "activation")
"""The order of bake.json's setup entries (`params`); a step's entry not named here comes after them all."""


def _record(*parts: Mapping) -> dict:
    """The bake's parameter set (`params`, JSON-ready): every step's part of it, in RECORD_ORDER."""
    merged = {k: v for part in parts for k, v in part.items()}
    return {**{k: merged[k] for k in RECORD_ORDER if k in merged}, **merged}


def _timed(timings: dict, name: str, step: Callable, *args):
    """step(*args), its wall seconds stored in timings[name]."""
    t = time.perf_counter()
    out = step(*args)
    timings[name] = time.perf_counter() - t
    return out


def _scene(req: BakeRequest, given: tuple | None):
    """The scene the request bakes (sim.bake.scene.Scene): --scene's, else the built-in demo's when nothing else
    gives a clip or a character with its own animation; None: the command line alone."""
    from jiggle.sim.bake.scene import default_scene, load_scene
    if req.scene is not None:
        return load_scene(req.scene)
    own = req.character is not None and str(req.character).lower().endswith((".glb", ".gltf", ".fbx"))
    if req.clip is None and not own and given is None:   # a glTF character alone bakes its own
        return load_scene(default_scene())
    return None


@dataclass(frozen=True)
class Inputs:
    """What the request reads: its scene (or None), pick (the request's value over the scene's [character] one, see
    _picker), the drive ("kinematic", "physics"), the clip as read (`source`, before any retarget) and its file
    (clip_source: an absolute path, or the in-memory clip's name), the tissue solver; record: their bake.json part."""

    scene: object
    pick: Callable
    drive: str
    source: object
    clip_source: str
    solver: str
    record: Mapping


def _inputs(req: BakeRequest, scene, given: tuple | None, solver: str) -> Inputs:
    """Step 1, the inputs: the motion read (or given) and what the request and its scene ask for."""
    pick = _picker(req, scene.character if scene is not None else None)
    drive = req.drive or (scene.drive if scene is not None else "kinematic")
    source, clip_source = (given[0], given[0].name) if given is not None else _clip(req, scene)
    record = {"jiggle_bake": VERSION,
              "scene": None if scene is None else {"path": scene.path, "sha256": file_digest(scene.path)},
              "clip": {"file": clip_source,
                       "sha256": file_digest(clip_source) if os.path.isfile(clip_source) else None,
                       "name": source.name, "duration_s": source.duration},
              "drive": drive, "chunk": _chunk(req, scene)}
    return Inputs(scene, pick, drive, source, clip_source, solver, MappingProxyType(record))


@dataclass(frozen=True)
class Retarget:
    """A clip onto a character file's skeleton, at its scale, through the roles its fit found; a character with no file
    (a generated body, one given in memory) is on the clip's own skeleton already.

    source : the bake's clip as read (rig.motion.clip.Clip). character_file : the character's glTF/FBX or None.
    skin : which skin of the file. clip_map, character_map : the joint maps (BakeRequest). log : progress lines.
    """

    source: object
    character_file: str | None
    skin: int
    clip_map: str | None
    character_map: str | None
    log: Callable

    def onto(self, character, mus, src=None):
        """The clip (`src`, else the bake's) on `character`'s skeleton, at its scale, through the roles its fit found
        (`mus`)."""
        src = self.source if src is None else src
        if self.character_file is None:
            return src
        from jiggle.rig.character.body_skeleton import hang, placed_parts
        from jiggle.rig.motion.retarget_onto import retarget_onto
        placed = placed_parts(character)
        return retarget_onto(src, self.character_file, self.skin, self.clip_map, self.character_map, self.log,
                             scale=character.meta.get("unit_scale", 1.0), character_roles=_fit_roles(character, mus),
                             follow=(lambda c: hang(c, placed, character.bind_world)) if placed else None)


def _fit_roles(character, mus):
    """The fit's roles as a JointMap (rig.motion.retarget) for retargeting, one role a joint; None when the fit found
    roles that are not retargeting's."""
    from jiggle.rig.motion.retarget import ROLES, JointMap
    if not (mus.roles and all(r in ROLES for r in mus.roles)):
        return None
    seen = {}              # the fit may alias a missing spine to the hips: one role a joint
    for r, j in mus.roles.items():
        seen.setdefault(j, r)
    return JointMap(roles={r: (character.joint_names[j],) for j, r in seen.items()}, name="the fit's roles")


@dataclass(frozen=True)
class Body:
    """The character as read or generated (before the fit's size rule): file (its glTF/FBX, None for a generated or
    given one), the template asked for, the character, `cached` (this character's FittedRig from `rigs`, else None)
    and rig_key (its key in `rigs`), retarget (the clip onto it); record: its bake.json part (a generated body's
    options among it)."""

    file: str | None
    template: str
    character: object
    cached: FittedRig | None
    rig_key: str | None
    retarget: Retarget
    record: Mapping


def _character(req: BakeRequest, inputs: Inputs, rigs: MutableMapping | None, given: tuple | None, log) -> Body:
    """Step 2, the character: read from its file, given, reused from `rigs`, or generated around the clip."""
    from jiggle.rig.character.body import BodyOptions
    from jiggle.rig.character.load import body_character, load_character
    t = time.perf_counter()
    spec, pick, clip = inputs.scene.character if inputs.scene is not None else None, inputs.pick, inputs.source
    character_file = req.character or (spec.file if spec is not None else None)
    body = None
    if character_file is not None and req.body:
        raise InputError(f"{', '.join('--' + k.replace('_', '-') for k in req.body)} shape a generated body; "
                         f"the character {os.path.basename(character_file)} has its own", field="--character")
    if character_file is None and given is None:
        body = BodyOptions(**{**(dict(spec.body) if spec is not None else {}), **dict(req.body)})
    template = req.template or (spec.template if spec is not None else None) or "auto"
    rig_key = cached = None
    if rigs is not None and given is None:
        rig_key = fitted_key(req, pick, character_file, body, template, clip)
        cached = rigs.get(rig_key)
    if cached is not None:
        character = cached.character
    elif given is not None:
        character = given[1]
    elif character_file is not None:
        character = load_character(character_file, k=pick("influences", 4), unit=pick("unit", None),
                                   skin=pick("skin", 0))
    else:
        character = body_character(clip, body, k=pick("influences", 4))
    what = os.path.basename(character_file) if character_file is not None else "generated body"
    log(f"character: {what}, {character.num_vertices} vertices, {character.num_joints} joints "
        f"({'reused, ' if cached is not None else ''}{time.perf_counter() - t:.1f} s)")
    record = {"character": ({"file": os.path.abspath(character_file), "sha256": file_digest(character_file)}
                            if character_file else {"generated": jsonable(body)} if given is None
                            else {"in_memory": character.name or "character"})}
    retarget = Retarget(clip, character_file, pick("skin", 0), req.clip_map, req.character_map, log)
    return Body(character_file, template, character, cached, rig_key, retarget, MappingProxyType(record))


@dataclass(frozen=True)
class Fit:
    """The character as simulated (maybe at its template's size), its fitted musculature (rig.muscle.fit), the bound
    skin (rig.skin.muscle_skin.MuscleSkin, with this bake's pose shapes), the clip on the character, the template's
    name, the template's default jiggles (their materials at the character's real size `size`,
    rig.character.real_size.RealSize), idle ((M,) bool: muscles that drive nothing); record: its bake.json part."""

    character: object
    mus: object
    skin: object
    clip: object
    template: str
    jiggles: list
    idle: np.ndarray
    record: Mapping
    size: object = None


def _fit(req: BakeRequest, inputs: Inputs, body: Body, rigs: MutableMapping | None, given: tuple | None, log) -> Fit:
    """Step 3, the fit: the template's muscles fitted to the character, the clip onto it, the skin bound."""
    from jiggle.sim.jiggle.materials import default_jiggles
    t = time.perf_counter()
    character, mus = _musculature(req, inputs.pick, body, given, log)
    clip = body.retarget.onto(character, mus)
    template = mus.template.name if body.template == "auto" else body.template
    log(f"body plan: {mus.plan.kind} ({mus.plan.reason}); template {mus.template.name}: {mus.why}")
    for p in mus.parts:             # the generic template: what each body part got, and why
        if p.segments or p.kind is None:
            log(f"  {p.label}: {p.kind or 'no tissue'} ({p.reason})")
    size = _real_size(character, body.file, mus, body.retarget.onto, req.height, log)
    jiggles = default_jiggles(mus.rig, [m.spec.jiggle for m in mus.muscles], scale=size.scale)
    skin, skin_record = _skin(req, inputs, body, character, mus, rigs, log)
    idle = idle_of(skin, mus.rig.M)
    if idle.any():
        names = [mus.rig.names[m] for m in np.nonzero(idle)[0]]
        log(f"not simulated: {len(names)} of {mus.rig.M} muscles drive nothing, none of their skin being soft "
            f"({', '.join(names[:8])}{' ...' if len(names) > 8 else ''})")
        skin_record["rigid"]["not_simulated"] = names      # the rigid record says which muscles that leaves idle
    log(f"muscles: {mus.rig.M} from template {os.path.basename(str(template))!r}, {skin.num_pairs} (vertex, muscle) "
        f"pairs ({'reused, ' if body.cached is not None else ''}{time.perf_counter() - t:.1f} s)")
    record = {"template": template if not os.path.isfile(str(template)) else
              {"file": os.path.abspath(template), "sha256": file_digest(template)},
              "body_plan": mus.plan.to_json(), "template_why": mus.why or None,
              "parts": [p.to_json() for p in mus.parts] or None,
              "size_scale": character.meta.get("template_scale", 1.0),
              # metres per unit of the character's file, as its caches are written: a DCC that imported the file as
              # it is (Blender: a glTF unit a Blender unit) divides the caches' positions by it to land on its mesh
              "file_unit_m": character.meta.get("unit_scale", 1.0) / character.meta.get("template_scale", 1.0),
              "vertices": character.num_vertices, **skin_record}
    return Fit(character, mus, skin, clip, template, jiggles, idle, MappingProxyType(record), size)


def _musculature(req: BakeRequest, pick: Callable, body: Body, given: tuple | None, log) -> tuple:
    """(character, musculature): the cached or given fit, else the template fitted to the character; a character file
    whose size is outside its template's heights (and whose unit is not given) is scaled to the template's size and
    fitted again, since the defaults are made for it (rig.character.character.template_scale)."""
    from jiggle.rig.character.character import TEMPLATE_HEIGHT_M, template_scale
    from jiggle.rig.muscle.fit import FitOptions, fit_musculature
    character = body.character
    if body.cached is not None:
        return character, body.cached.musculature
    if given is not None and given[2] is not None:
        return character, given[2]
    mus = fit_musculature(character, body.template, FitOptions(joint_map=req.character_map))
    if body.file is not None and pick("unit", None) in (None, "auto"):
        # defaults are made for the template's size: a 0.22 m human is simulated at 1.7 m, scaled back
        height = float(np.ptp(np.asarray(character.vertices)[:, 2]))
        k = template_scale(mus.template.name, height)
        if k != 1.0:
            log(f"size: {height:.3g} m tall by the file, outside the {mus.template.name} template's "
                f"{TEMPLATE_HEIGHT_M[mus.template.name][1]:g}-{TEMPLATE_HEIGHT_M[mus.template.name][2]:g} m: "
                f"simulated at {height * k:.3g} m, the result scaled back to the file's size (--unit says "
                f"the file's unit instead)")
            character = character.scaled(k)
            character = replace(character, meta={**character.meta, "template_scale": k})
            mus = fit_musculature(character, body.template, FitOptions(joint_map=req.character_map))
    return character, mus


def _skin(req: BakeRequest, inputs: Inputs, body: Body, character, mus, rigs: MutableMapping | None, log) -> tuple:
    """(skin, record): the skin bound to the fitted muscles (the cached one, else bound and stored in `rigs`), this
    bake's copy carrying the scene's pose shapes; the rigid pieces it decided, logged. record: the bake.json entries
    skinning, rigid and pose_shapes."""
    from jiggle.rig.skin.muscle_skin import MuscleSkin
    pick, scene = inputs.pick, inputs.scene
    skinning, method, mush = pick("skinning", "shell"), pick("method", "lbs"), pick("mush", 0)
    if body.cached is not None:
        skin = body.cached.skin
    else:
        skin = MuscleSkin.from_musculature(mus, skinning=skinning, method=method, character_path=body.file,
                                           mush=mush, device=warp_device(req.device or "cpu"), rigid=req.rigid or "auto")
        if rigs is not None:
            rigs[body.rig_key] = FittedRig(character, mus, skin)
    if scene is not None and scene.pose_shapes:
        # the fitted skin (maybe a worker's cached one) stays as it is: this bake's copy carries the shapes
        skin = copy.copy(skin)
        skin.rig = scene.apply_pose_shapes(mus.rig, character)
        log(f"pose shapes: {len(skin.rig.pose_shapes.shapes)} muscle(s) shaped by joint bends")
    rigid = getattr(skin, "rigid", None)
    # the decisions, also when every rigidly bound piece is flesh (RBF skinning keeps no piece rigid)
    gear = getattr(skin, "gear", None) if getattr(skin, "skinning", "shell") != "rbf" else None
    decided = rigid if rigid is not None else gear if gear is not None and gear.decided else None
    log(decided.describe() if decided is not None else "rigid parts: none; all the skin is tissue")
    record = {"rigid": {"option": req.rigid or "auto", "parts": decided.to_json() if decided is not None else None},
              "skinning": {"deformer": skinning, "method": method, "influences": pick("influences", 4), "mush": mush}}
    if skin.rig.pose_shapes is not None:
        record["pose_shapes"] = [{"muscle": sh.muscle, "joint": sh.joint, "angles_deg": list(sh.angles),
                                  "scales": [list(r) for r in sh.scales]} for sh in skin.rig.pose_shapes.shapes]
    return skin, record


@dataclass(frozen=True)
class Timing:
    """The output times before any loop: fps (frames per second), times ((T,) seconds of the clip), the muscles'
    solver settings (the scene's and the command line's), their goal rate (Hz, None: the default) and knots ((K,)
    goal knot times, seconds)."""

    fps: float
    times: np.ndarray
    solver_settings: JiggleSettings
    goal_rate: float | None
    knots: np.ndarray


def _timing(req: BakeRequest, inputs: Inputs, fit: Fit) -> Timing:
    """Step 4, the timing: output frames and goal knots over the clip."""
    scene = inputs.scene
    fps = float(req.fps or (scene.fps if scene is not None else None) or BAKE_FPS)
    times = output_times(fit.clip.duration, fps, req.start, req.end, req.frames)
    solver_settings = _settings(req, scene, fit.jiggles)[0]     # the muscles' own settings follow the drive
    goal_rate = solver_settings.goal_rate
    knots = knot_times(times, goal_rate or max(DEFAULT_GOAL_RATE, fps))
    return Timing(fps, times, solver_settings, goal_rate, knots)


@dataclass(frozen=True)
class Tissue:
    """The tissue as simulated: jiggles (one MuscleJiggle a muscle, every layer of parameters applied), settings
    (JiggleSettings), size (rig.character.real_size.RealSize); record: its bake.json part."""

    jiggles: list
    settings: JiggleSettings
    size: object
    record: Mapping


def _tissue(req: BakeRequest, inputs: Inputs, body: Body, fit: Fit, timing: Timing, world_at, log,
            timings: dict) -> Tissue:
    """Step 5, the tissue: a creature's held once for the character (HELD_TEMPLATES), its real size, the materials asked
    for, then the scene's and the command line's parameters over them."""
    jiggles, mus = fit.jiggles, fit.mus
    tissue_from = {"template": os.path.basename(str(fit.template))}
    if mus.template.name in HELD_TEMPLATES and not fit.idle.all():
        # one tissue per creature: its materials at real size, held under the limit on its own cycles
        jiggles, tissue_from = _timed(timings, "tune_s", _character_tissue, jiggles, mus, fit.skin,
                                      timing.solver_settings, fit.character, body.file, body.retarget.onto, fit.clip,
                                      world_at, log)
    size = fit.size
    held = tissue_from.get("held_factor", 1.0)
    springs = {n: (("material" if held == 1.0 else f"material, held x {held:.3g}")
                   if "frequency_hz" in m.spec.jiggle.from_material else "template")
               for n, m in zip(mus.rig.names, mus.muscles)}
    materials_used = {}
    if req.materials:
        jiggles, materials_used = apply_materials(jiggles, mus.rig, req.materials, log, scale=size.scale)
        springs.update({n: "--material" for n in materials_used})
    before = jiggles
    settings, jiggles = _settings(req, inputs.scene, jiggles)
    for m, (a, b) in enumerate(zip(before, jiggles)):
        changed = [k for k in ("frequency_hz", "damping_ratio", "density") if getattr(a, k) is not getattr(b, k)
                   and not np.array_equal(np.asarray(getattr(a, k)), np.asarray(getattr(b, k)))]
        if changed:
            springs[mus.rig.names[m]] = "overridden: " + ", ".join(changed)
    record = {"tissue": {"solver": inputs.solver, **tissue_from, "materials": materials_used or None,
                         "real_size": size.to_json(), "material_rule": MATERIAL_RULE},
              "settings": jsonable(settings),
              "muscles": _muscle_params(mus.rig, jiggles, fit.idle, scale=size.scale, springs=springs)}
    return Tissue(jiggles, settings, size, MappingProxyType(record))


HELD_TEMPLATES = ("generic", "quadruped")
"""The templates whose tissue (each part's material at the character's real size) is held under the limit on the
character's own cycles (_character_tissue): creatures, whose size and soft mass the human's calibration never saw."""


MATERIAL_RULE = ("each part's goal springs, their damping and its density come from its material (muscles.NAME."
                 "springs_from 'material': the template's, rig.muscle.material, at the character's real size) by "
                 "sim.jiggle.materials: f_fem = FEM_C_SLENDER (r / L)^FEM_A sqrt(mu / rho) / r at the part's mean "
                 "radius r and rest length L (radius_m and length_m x real_size.scale), frequency_hz = f_fem / "
                 "sqrt(w / (1 - w)) of its belly's goal weight w, damping_ratio so the part rings down with the "
                 "material's ratio. Springs set otherwise (springs_from 'template': the template's own values; "
                 "'material, held x G': a creature's material (the generic and quadruped templates) with every spring G times stiffer, so that "
                 "no cycle of the character jiggles past the limit (tissue.held_on); '--material'; 'overridden': "
                 "a scene table or the command line) still stand for a material, muscles.NAME.material (E from "
                 "frequency_hz by the same rule inverted)")
"""bake.json's tissue.material_rule: how a part's springs and its material relate."""


@dataclass(frozen=True)
class Motion:
    """The motion as baked, a game cycle extended periodically (sim.bake.loop): fps, times ((T,) seconds), knots
    ((K,) seconds), world_at (knot times -> (k, J, 4, 4) the character's joints), joints_at and joint_names (the
    clip's own joints, for the npz), loop (sim.bake.loop.Loop); record: its bake.json part."""

    fps: float
    times: np.ndarray
    knots: np.ndarray
    world_at: Callable
    joints_at: Callable
    joint_names: tuple
    loop: object
    record: Mapping


def _motion(req: BakeRequest, inputs: Inputs, body: Body, fit: Fit, timing: Timing, world_at, log) -> Motion:
    """Step 6, the loop: whether the clip is a game cycle, baked in its periodic steady state (its times, knots and
    drive extended periodically), and the clip's own joints for the caches."""
    from jiggle.sim.bake.loop import judge
    source, clip, character = inputs.source, fit.clip, fit.character
    fps, times, knots = timing.fps, timing.times, timing.knots
    if source is clip:
        joints_at, joint_names = world_at, tuple(clip.joint_names)
    else:
        from jiggle.rig.motion.clip import transforms
        from jiggle.sim.drive.skeleton import Skeleton
        sk = Skeleton(source)
        joints_at = lambda ts: transforms(*sk.world(np.asarray(ts)))  # noqa: E731
        joint_names = tuple(source.joint_names)
    loop = judge(req.loop, clip=clip, drive=inputs.drive, world_at=world_at, height=float(np.ptp(np.asarray(
        character.vertices)[:, 2])), times=times, fps=fps, end=req.end, frames=req.frames, own=body.file is not None
        and os.path.abspath(body.file) == inputs.clip_source, goal_rate=timing.goal_rate,
        joints_at=None if source is clip else joints_at, log=log)
    if loop.on:
        fps, times, knots, world_at = loop.fps, loop.times, loop.knots, loop.world_at
        joints_at = world_at if source is clip else loop.joints_at
    record = {"fps": fps, "frames": len(times), "start_s": float(times[0]), "end_s": float(times[-1]),
              "loop": loop.to_json()}
    return Motion(fps, times, knots, world_at, joints_at, joint_names, loop, MappingProxyType(record))


@dataclass(frozen=True)
class Chains:
    """The chains that swing (sim.chain.build.ChainSetup, None: none); record: their bake.json part."""

    chains: object
    record: Mapping


@dataclass(frozen=True)
class Collisions:
    """What the particles collide with: floor (metres, world z; None: none), capsules (rig.character.capsules
    BoneCapsules of --colliders model; None: the character's own bone capsules); record: their bake.json part."""

    floor: float | None
    capsules: object
    record: Mapping


def _collisions(settings: JiggleSettings, drive: str, fit: Fit, motion: Motion, log) -> Collisions:
    """Step 8, the collisions (settings.collisions): a body that stands at rest has a floor, a flying or floating one
    (no limb on the ground) has none; --colliders model takes the MuJoCo model's capsules."""
    if not settings.collisions:
        return Collisions(None, None, MappingProxyType({}))
    floor = _floor(fit.character, drive, motion.world_at, motion.knots) if fit.mus.plan.ground_limbs > 0 else None
    record = {"capsules": settings.colliders, "floor_m": None if floor is None else round(floor, 6)}
    capsules = None
    if settings.colliders == "model":
        capsules, record["model_geoms"] = _model_capsules(fit.clip, fit.character, log)
    return Collisions(floor, capsules, MappingProxyType({"collisions": record}))


ACTIVATION = ("on", "off")


def body_mass(character, scale: float) -> tuple[float, str]:
    """(kg, how): the character's mass at real size (lengths x `scale`): its skin's volume at the body's density
    (sim.drive.inverse.BODY_DENSITY) when the skin is closed (every edge shared by two triangles), else its height
    at a reference adult's body mass index of 22.5 kg/m^2."""
    from jiggle.sim.drive.inverse import BODY_DENSITY
    v = np.asarray(character.vertices, np.float64) * scale
    f = np.asarray(character.faces, np.int64)
    edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    if len(f) and (counts == 2).all():
        volume = abs(float(np.einsum("ij,ij->i", v[f[:, 0]], np.cross(v[f[:, 1]], v[f[:, 2]])).sum()) / 6.0)
        return BODY_DENSITY * volume, f"its closed skin's {volume:.4g} m^3 at {BODY_DENSITY:g} kg/m^3"
    h = float(np.ptp(v[:, 2])) if len(v) else 0.0
    return 22.5 * h * h, f"its height {h:.3g} m at a body mass index of 22.5 (the skin is not closed)"


def _activation(req: BakeRequest, fit: Fit, motion: Motion, tissue: Tissue, log
                ) -> tuple[np.ndarray | None, list, Mapping]:
    """Step 9, the muscles' activation (BakeRequest.activation "on", or its default): the clip's joint torques by inverse dynamics
    with the ground (sim.drive.inverse), shared among the muscles by least effort (sim.jiggle.activation), at the
    output times ((T, M) float32, None when off); the tissue's jiggles with each working muscle's springs stiffened
    by its fibres' tension (sim.jiggle.activation.stiffened; as they are when off); its bake.json part."""
    mode = req.activation
    if mode is None:            # the default: on wherever muscles work, with the particles (the FEM does not take it)
        works = any(k != "fat" for k in fit.mus.rig.kinds)
        mode = "on" if works and tissue_solver(req) != "fem" else "off"
        if works and mode == "off":
            log("activation: off (the FEM hero mode does not take it yet)")
    if mode not in ACTIVATION:
        raise InputError(f"expected one of {', '.join(ACTIVATION)}, got {mode!r}", field="--activation")
    if mode == "off":
        return None, list(tissue.jiggles), MappingProxyType({})
    if tissue_solver(req) == "fem":
        raise InputError("--activation on stiffens the particles' springs; the FEM hero mode (--tissue fem) does not "
                         "take it yet: drop one of them", field="--activation")
    from jiggle.sim.drive.inverse import joint_torques
    from jiggle.sim.jiggle.activation import activations, stiffened
    clip, rig = fit.clip, fit.mus.rig
    mass, how = body_mass(fit.character, fit.size.scale)
    times = np.asarray(motion.times, np.float64)
    period = float(clip.duration)
    # a looped bake's times run past the clip: its loads are the cycle's own, at the same phase
    at = np.mod(times, period) if motion.loop.on and period > 0 else np.clip(times, 0.0, period)
    # the physics at the body's real size: its mass is the real body's, so its lengths must be too
    loads = joint_torques(clip.scaled(fit.size.scale), np.array([0.0, max(period, 1e-6)]), mass, roles=fit.mus.roles)
    act = activations(rig, motion.world_at, loads, clip.parents, fit.character.bind_world, times,
                      scale=fit.size.scale, load_times=at, roles=fit.mus.roles)
    a = np.asarray(act.activation, np.float32)
    jiggles, factor = stiffened(tissue.jiggles, rig, a, times, scale=tissue.size.scale)
    muscles = {n: {"peak": round(float(a[:, m].max()), 4), "mean": round(float(a[:, m].mean()), 4),
                   "stiffening_peak": round(float(factor[:, m].max()), 4)}
               for m, n in enumerate(rig.names) if rig.kinds[m] != "fat"}
    saturated = float(np.asarray(act.saturated).any(axis=1).mean()) if len(a) else 0.0
    roles = bool(fit.mus.roles) and all(r in fit.mus.roles for r in ("left_upper_leg", "right_upper_leg"))
    log(f"activation: {len(muscles)} muscles from the clip's joint torques (body {mass:.1f} kg from {how}); "
        f"saturated in {100 * saturated:.0f}% of the frames")
    record = {"activation": {
        "on": True, "body_mass_kg": round(mass, 3), "body_mass_from": how,
        "segments": "de Leva 1996 (the skeleton's human roles)" if roles else "the skeleton's capsules",
        "torques": "inverse dynamics of the clip on the drive's skeleton in MuJoCo (mj_inverse), the ground pushing "
                   "touching feet (sim/drive/inverse.py)",
        "rule": "least-effort static optimization over the muscles' moment arms and strengths, then 10/40 ms "
                "activation dynamics (sim/jiggle/activation.py); fat never activated; on a human skeleton the leg's "
                "deep muscles (iliopsoas, adductors, abductors, tibialis anterior: Rajagopal et al. 2016's paths and "
                "forces, sim/jiggle/deep_muscles.py) share the torques and are listed in deep_muscles",
        "stiffening": "a working muscle's goal springs keyed by sqrt(1 + (f_t / f_0)^2): f_t = sqrt(a 0.6 MPa / rho) "
                      "/ (2 L) the sway of its belly under its fibres' tension, f_0 its relaxed material's "
                      "(sim.jiggle.activation.stiffened); params.muscles gives the springs before it",
        "saturated_frames": round(saturated, 4), "muscles": muscles,
        "deep_muscles": {n: {"peak": round(float(act.deep_activation[:, d].max()), 4),
                             "mean": round(float(act.deep_activation[:, d].mean()), 4)}
                         for d, n in enumerate(act.deep_names)}}}
    return a, jiggles, MappingProxyType(record)


def tissue_joints(rig) -> set:
    """The joints a muscle rides (its origin's and the one its middle rides): they stay with the body, no chain
    swings them."""
    joints = np.asarray(getattr(rig, "joints", np.zeros((0, 11), np.int64)))
    return set(joints[:, [0, 8]].ravel().tolist()) if joints.size else set()


def _chains(req: BakeRequest, scene, character, mus, knots: np.ndarray, world_at, log) -> Chains:
    """Step 7, the chains that swing (sim.chain.build.ChainSetup) or None, logged: found on the character (--chains),
    their parameters from the scene's [chains.NAME] tables and the command line."""
    from jiggle.rig.character.capsules import bone_capsules
    from jiggle.rig.character.chains import find_chains
    from jiggle.sim.chain.build import make
    mode = req.chains or (scene.chains if scene is not None else None) or "auto"
    springs = character.meta.get("spring_bones") or None
    found = find_chains(character, tissue_joints(mus.rig), set((mus.roles or {}).values()), mode, springs)
    log(found.describe(character.joint_names))
    entries = list(scene.chain_entries if scene is not None else ()) + list(req.chain_params)
    if not len(found):
        if entries:
            raise InputError(f"chain parameters are given but no chain swings (--chains {mode})",
                             field=entries[0][2] if isinstance(entries[0][2], str) else "--chains")
        return Chains(None, MappingProxyType({"chains": {"mode": mode, "chains": []}}))
    chains = make(character, found, bone_capsules(character), _chain_floor(character, mus, world_at, knots), entries,
                  knots, world_at)
    record = {"chains": {"mode": mode, "chains": chains.to_json(character.joint_names) if chains is not None else []}}
    return Chains(chains, MappingProxyType(record))


def _chain_floor(character, mus, world_at, knots):
    """The floor chains collide with: the particles' (a body standing at rest has one), else None."""
    if mus.plan is None or mus.plan.ground_limbs <= 0:
        return None
    return _floor(character, "kinematic", world_at, knots)


TISSUE_SOLVERS = ("particles", "fem")


def tissue_solver(req: BakeRequest) -> str:
    """The bake's tissue solver (BakeRequest.tissue; None: "particles"); InputError naming --tissue otherwise."""
    solver = req.tissue or "particles"
    if solver not in TISSUE_SOLVERS:
        raise InputError(f"expected one of {', '.join(TISSUE_SOLVERS)}, got {solver!r}", field="--tissue")
    return solver


def apply_materials(jiggles, rig, entries, log=lambda s: None, scale: float = 1.0) -> tuple[list, dict]:
    """(jiggles, used): `entries` ("[NAME=]MATERIAL" each, BakeRequest.materials) applied in order: every muscle NAME
    matches (a name or a glob; every muscle without NAME) gets the goal springs, damping ratio and density its
    material gives at its mean rest radius at real size (times `scale`: rig.character.real_size.RealSize.scale;
    sim.jiggle.materials.with_material). used : {muscle: the Material's
    record and the entry that set it}. InputError naming the entry for a bad material or a NAME matching nothing."""
    import fnmatch

    from jiggle.rig.muscle.material import KEYS, parse_material
    from jiggle.sim.jiggle.materials import with_material
    radii = rig.mean_radii(rig.rest_cvs)
    lengths = np.asarray(rig.rest_length, np.float64)
    out, used = list(jiggles), {}
    for entry in entries:
        text = str(entry).strip()
        head, _, rest = text.partition("=")
        name, spec = (head.strip(), rest) if rest and head.strip() not in KEYS else ("*", text)
        material = parse_material(spec, where=f"--material {text}")
        hits = [m for m, n in enumerate(rig.names) if n == name or fnmatch.fnmatchcase(n, name)]
        if not hits:
            raise InputError(f"--material {text}: no muscle is named or matches {name!r}; the muscles are "
                             f"{', '.join(rig.names[:12])}{' ...' if rig.M > 12 else ''}", field="--material")
        for m in hits:
            out[m] = with_material(out[m], material, float(radii[m]) * scale, float(lengths[m]) * scale,
                                   rig.rest_cvs[rig.cv_offsets[m]:rig.cv_offsets[m + 1]])
            used[rig.names[m]] = {**material.to_json(), "entry": text}
        log(f"material {material.name} ({material.youngs_pa:g} Pa, nu {material.poisson:g}, {material.density:g} "
            f"kg/m^3, zeta {material.damping_ratio:g}) on {len(hits)} muscle(s) matching {name!r}")
    return out, used


REFERENCE_ANIMATIONS = 48
"""The most animations of a character file _own_cycles looks through."""
ACTION_WORDS = ("attack", "bite", "hit", "death", "die", "dead", "jump", "punch", "kick", "headbutt", "react", "weapon",
                "shoot", "fall", "land", "throw", "slash", "spawn")
"""Words that make an animation a one-off action (it may return to its start pose, but it is not how the character
moves): never one the tissue is held on (_under_limit), since held on it the tissue would be stiffened for the
character's harshest moment."""
GESTURE_NAMES = ("yes", "no", "nod", "wave", "shake", "headshake")
"""Whole words that make an animation a gesture (a head shake whips a small body hard, but it is not how the body
moves): never the reference either."""
_CYCLES = {}
"""_own_cycles' results per character file and fit (its path, size and time, template, muscles)."""
_TISSUE = {}
"""_character_tissue's results: _own_cycles' key and the skinning -> (frequencies, record)."""


def _file_key(character_file, mus):
    """The key of a glTF character file and its fit for the per-process caches, or None for any other character."""
    if character_file is None or not str(character_file).lower().endswith((".glb", ".gltf")) \
            or not os.path.isfile(character_file):
        return None
    st = os.stat(character_file)
    return (os.path.realpath(character_file), st.st_size, st.st_mtime_ns, mus.template.name, mus.rig.M,
            tuple(mus.rig.names))


def _own_cycles(character_file, character, mus, onto, only=None) -> list:
    """The character file's own animations that loop (sim.bake.loop.judge), each (name, the clip on the character,
    its kinematic drive world_at, the times it was sampled at (MOTION_RATE), its Loop); [] for a character that is
    no glTF file. Read once per file and fit in a process. only : a test of an animation's name: those alone are
    read (and nothing is remembered), unless every one already was."""
    key = _file_key(character_file, mus)
    if key is None:
        return []
    if key in _CYCLES:
        return [c for c in _CYCLES[key] if only is None or only(c[0])]
    from jiggle.rig.motion.gltf_io import GltfDocument
    from jiggle.rig.motion.mocap import load_clip
    from jiggle.sim.bake.loop import judge
    from jiggle.sim.jiggle.params import MOTION_RATE
    names = [a.name or f"animation{k}" for k, a in enumerate(GltfDocument(character_file).gltf.animations)]
    height = float(np.ptp(np.asarray(character.vertices)[:, 2]))
    out = []
    for k, name in enumerate(names[:REFERENCE_ANIMATIONS]):
        if only is not None and not only(name):
            continue
        try:
            own = onto(character, mus, load_clip(character_file, animation=k))
        except InputError:
            continue
        if own.duration <= 0:
            continue
        ts = np.linspace(0.0, own.duration, max(int(round(own.duration * MOTION_RATE)), 2) + 1)
        at = _drive(own, "kinematic", ts, lambda s: None)
        lp = judge("auto", clip=own, drive="kinematic", world_at=at, height=height, times=ts[:1], fps=MOTION_RATE,
                   end=None, frames=None, own=True, goal_rate=None)
        if lp.on:
            out.append((name, own, at, ts, lp))
    if only is None:
        _CYCLES[key] = out
    return out


def _real_size(character, character_file, mus, onto, height, log):
    """rig.character.real_size.RealSize of the character as simulated: --height, else its own looping walk cycle's
    period (dynamic similarity), else the file's unit; logged."""
    from jiggle.rig.character.real_size import is_walk, real_size
    walk = None
    if height is None:
        walk = next(((n, lp.period) for n, _, _, _, lp in _own_cycles(character_file, character, mus, onto,
                                                                       only=is_walk)), None)
    size = real_size(character, height, walk)
    log(f"real size: {size.why}")
    return size


def _character_tissue(jiggles, mus, skin, settings, character, character_file, onto, clip, world_at,
                      log) -> tuple[list, dict]:
    """(jiggles, record): a creature's tissue (the HELD_TEMPLATES'), once for the character, not per clip: each
    part's material at the character's real size (the generic template's fat on the soft core and muscle on the
    limbs, rig.muscle.generic; the quadruped's muscles and fat; their goal springs as sim.jiggle.materials gives
    them), held so that none of the character's own cycles (its file's animations that loop, _own_cycles, without
    one-off actions and gestures) jiggles the skin more than PEAK_LIMIT of its size
    on a probe (_under_limit): a creature's soft mass at its real size can swing several percent of its body (the
    Cat's fat, 3.3% on its Walk; benchmarks/results/zoo_materials.md), which reads as a flap, not a jiggle. Every
    clip of the character then gets the same tissue, and a calmer clip jiggles less. Remembered per file for the
    process (batch, the viewer). A character with no looping animation of its own (a mesh given a mocap clip, a
    generated body) is held on the bake's clip, and the record says so."""
    key = _file_key(character_file, mus)
    key = None if key is None else key + (getattr(skin, "skinning", None),)
    if key is not None and key in _TISSUE:
        freqs, record = _TISSUE[key]
        log(f"tissue: as held on {record['held_on']} (this character's, remembered)")
        return [replace(j, frequency_hz=f) for j, f in zip(jiggles, freqs)], record
    cycles = []
    for name, own, at, _, _ in _own_cycles(character_file, character, mus, onto):
        words = [w for w in re.split(r"[^a-z]+", name.lower()) if w]
        if any(w.startswith(a) for w in words for a in ACTION_WORDS) or any(w in GESTURE_NAMES for w in words):
            continue
        cycles.append((name, own, at))
    if cycles:
        held_on = "its own cycles: " + ", ".join(n for n, _, _ in cycles)
    else:
        cycles, held_on = [("the bake's clip", clip, world_at)], "the bake's clip"
    jiggles, peaks, factor = _under_limit(jiggles, skin, settings, character, cycles, log)
    record = {"template": mus.template.name, "held_on": held_on, "cycles_peak_size": peaks,
              "held_factor": round(factor, 4),
              "why": "each part's material at the character's real size, its goal springs scaled alike (held_factor) "
                     f"where a cycle of its own would jiggle the skin more than {100 * PEAK_LIMIT:g}% of its size "
                     "(no cycle may be damaged by its tissue); one tissue for every clip of the character"}
    log("tissue: its material at real size" + (f", held x {factor:.2f}" if factor != 1.0 else "") +
        f" on {held_on}")
    if key is not None:
        _TISSUE[key] = ([float(j.frequency_hz) for j in jiggles], record)
    return jiggles, record


PEAK_SIZE = 0.01
"""Where a cycle would jiggle the skin more than PEAK_LIMIT of the body's size (its rest skin's largest extent), the
tissue is stiffened until it jiggles about this share (_under_limit): visible on a blob's hop or a hovering
creature, far from a flap."""
PEAK_LIMIT = 1.2 * PEAK_SIZE
"""No cycle of a character may jiggle its skin more than this share of its size on a probe (_under_limit), well
under the zoo's 1.5% for a bake."""
PROBE_FPS, PROBE_SECONDS = 30.0, 4.0
"""The probe bakes: this rate over the clip's first seconds (so neither the bake's rate nor its frame range changes
the result)."""


def _under_limit(jiggles, skin, settings, character, cycles, log) -> tuple[list, dict, float]:
    """(jiggles, peaks, factor): `jiggles` held so that none of `cycles` ((name, clip, world_at) each) jiggles the
    skin more than PEAK_LIMIT of the body's size on a probe (_probe: the skin's response, not a model of it, since
    how much of a part's swing reaches the skin depends on the body: a blob's one fat mass moves its whole skin, a
    creature's limbs a part of theirs). Where one does, every goal spring's frequency is scaled alike by the
    smallest factor (found within HOLD_STEP, at most HOLD_ROUNDS probes) at which that cycle jiggles no more than
    PEAK_SIZE: stepped up by sqrt(peak / target) (the quasi-static swing goes as 1 / f^2), at least doubling (a soft
    part swinging to its reach answers less), then bisected; the other cycles are probed again at the factor found,
    and one still over the limit is searched for next. peaks : {cycle: its probe's peak over the body's size, with
    the final springs}; factor : the springs' total scale (1: as given)."""
    size = _body_size(character)
    probes = {name: _probe(skin, settings, clip, at) for name, clip, at in cycles}
    probes = {n: p for n, p in probes.items() if p is not None}

    def peak(name: str, g: float) -> float:
        return probes[name]([replace(j, frequency_hz=float(j.frequency_hz * g)) for j in jiggles]) / size
    factor = 1.0
    peaks = {n: peak(n, factor) for n in probes}
    for _ in range(len(probes)):
        name = max(peaks, key=peaks.get, default=None)
        if name is None or peaks[name] <= PEAK_LIMIT:
            break
        log(f"tissue: {100 * peaks[name]:.2f}% of the body on a probe of {name}, over {100 * PEAK_LIMIT:g}%")
        lo, hi, top = factor, None, peaks[name]
        for _ in range(HOLD_ROUNDS):
            if hi is None:
                g = lo * max(math.sqrt(top / PEAK_SIZE), 2.0)
            elif hi / lo <= HOLD_STEP:
                break
            else:
                g = math.sqrt(lo * hi)
            at = peak(name, g)
            if at <= PEAK_SIZE:
                hi = g
            else:
                lo, top = g, at
        factor = hi if hi is not None else g                 # never under: the stiffest tried
        peaks = {n: peak(n, factor) for n in probes}
        log(f"tissue: goal springs x {factor:.2f}: {name} {100 * peaks[name]:.2f}% of the body")
    return ([replace(j, frequency_hz=float(j.frequency_hz * factor)) for j in jiggles],
            {n: round(float(v), 5) for n, v in peaks.items()}, factor)


HOLD_STEP, HOLD_ROUNDS = 1.15, 8
"""_under_limit's search: the springs' factor found within this ratio, in at most this many probes of a cycle."""


def _body_size(character) -> float:
    """The body's size (its rest skin's largest extent), in the file's units."""
    return float(np.ptp(np.asarray(character.vertices), axis=0).max())


def _probe(skin, settings, clip, world_at):
    """The probe bake of `clip` (the bake's stages in one go, without collisions, at PROBE_FPS over its first
    PROBE_SECONDS), as a function of the jiggles -> the skin's largest jiggle (file units); None for a clip too
    short to probe."""
    from jiggle.rig.skin.muscle_skin import skin_frames
    from jiggle.sim.jiggle.keyed_solver import make_solver
    from jiggle.sim.jiggle.particles import muscle_model
    from jiggle.sim.jiggle.simulate import goals, simulate
    times = np.arange(0.0, min(clip.duration, PROBE_SECONDS) + 1e-9, 1.0 / PROBE_FPS)
    if len(times) < 3:
        return None
    settings = replace(settings, collisions=False)
    rig = skin.rig
    knots = knot_times(times, settings.goal_rate or DEFAULT_GOAL_RATE)
    world_k = np.asarray(world_at(knots), np.float64)
    static = rig.static(world_k, device=settings.device)
    at = np.clip(np.searchsorted(knots, times - 1e-9), 0, len(knots) - 1)       # the frames among the knots
    track = goals(rig, knots, static.cvs, settings)

    def peak(jiggles) -> float:
        model = muscle_model(rig, list(jiggles), settings.device, gravity=settings.gravity)
        dyn, _ = simulate(model, track, times, settings, solver=make_solver(model, jiggles))
        st, fin = skin_frames(skin, world_k[at], (static.cvs[at], dyn), static.curve[at], np.arange(len(times)))
        return float(np.linalg.norm(np.asarray(fin) - np.asarray(st), axis=2).max())
    return peak


def _model_capsules(clip, character, log):
    """(capsules, geoms kept) of --colliders model (sim.drive.skeleton.model_capsules), logged."""
    from jiggle.sim.drive.skeleton import model_capsules
    caps, geoms, kept = model_capsules(clip, character)
    log(f"colliders: {kept} of the MuJoCo model's {geoms} capsule geoms inside the skin, "
        f"{caps.count - kept} bone capsules where a joint has none")
    return caps, kept


def _floor(character, drive: str, world_at, knots: np.ndarray) -> float:
    """metres: the floor the particles collide with: the physics drive's plane, else the lowest foot at rest
    lowered where the clip's joints reach below the bind pose's (sim.jiggle.colliders.rest_floor)."""
    from jiggle.sim.jiggle.colliders import rest_floor
    height = getattr(world_at, "floor_height", None)
    if drive == "physics" and height is not None:
        return float(height)
    lowest = min(float(np.min(np.asarray(world_at(knots[a:a + 512]))[..., 2, 3])) for a in range(0, len(knots), 512))
    return rest_floor(character, lowest)


def _prepare_builtin(req: BakeRequest, scene, log) -> BakeSetup:
    """The thesis's simple arm (rig/muscle/simple_arm.py): its cylinder, biceps and fast flex."""
    for name in ("clip", "character", "template", "drive", "clip_map", "character_map"):
        if getattr(req, name) is not None:
            raise InputError(f"the built-in scene {scene.builtin!r} makes its own character and motion; "
                             f"drop --{name.replace('_', '-')}", field=f"--{name.replace('_', '-')}")
    if (req.activation or "off") == "on":
        raise InputError(f"the built-in scene {scene.builtin!r} has no clip skeleton to take joint torques from; "
                         "drop --activation", field="--activation")
    from jiggle.rig.muscle.simple_arm import FLEX_DURATION, simple_arm
    from jiggle.rig.skin.muscle_skin import MuscleSkin
    from jiggle.sim.jiggle.materials import default_jiggles
    arm = simple_arm()
    pick = _picker(req, scene.character)
    skinning, method, mush = pick("skinning", "shell"), pick("method", "lbs"), pick("mush", 0)
    skin = MuscleSkin(arm.character, arm.rig, skinning=skinning, method=method, mush=mush)
    jiggles = default_jiggles(arm.rig)
    fps = float(req.fps or scene.fps or BAKE_FPS)
    times = output_times(FLEX_DURATION, fps, req.start, req.end, req.frames)
    settings, jiggles = _settings(req, scene, jiggles)
    if settings.collisions and settings.colliders == "model":
        raise InputError(f"the built-in scene {scene.builtin!r} has no MuJoCo model, so no geoms to collide with; "
                         "use --colliders bone", field="--colliders")
    knots = knot_times(times, settings.goal_rate or max(DEFAULT_GOAL_RATE, fps))
    if req.loop == "on":
        raise InputError(f"the built-in scene {scene.builtin!r} is a single motion, not a cycle: drop --loop on",
                         field="--loop")
    log(f"built-in scene {scene.builtin}: {arm.character.num_vertices} vertices, {arm.rig.M} muscle")
    floor = _floor(arm.character, "kinematic", arm.world_at, knots) if settings.collisions else None
    params = {
        "jiggle_bake": VERSION, "scene": {"path": scene.path, "sha256": file_digest(scene.path),
                                          "builtin": scene.builtin},
        "clip": {"file": None, "name": scene.builtin, "duration_s": FLEX_DURATION},
        "character": {"builtin": scene.builtin}, "template": None, "vertices": arm.character.num_vertices,
        "drive": "kinematic", "fps": fps, "frames": len(times), "start_s": float(times[0]),
        "end_s": float(times[-1]), "skinning": {"deformer": skinning, "method": method, "influences": None,
                                                  "mush": mush},
        "settings": jsonable(settings), "muscles": _muscle_params(arm.rig, jiggles), "chunk": _chunk(req, scene),
    }
    if floor is not None:
        params["collisions"] = {"capsules": "bone", "floor_m": round(floor, 6)}
    solver = tissue_solver(req)
    if solver != "particles":
        params["tissue"] = {"solver": solver}
    return BakeSetup(name=scene.name, skin=skin, jiggles=tuple(jiggles), settings=settings, times=times, fps=fps,
                     knots=knots, world_at=arm.world_at, joints_at=arm.world_at,
                     joint_names=tuple(arm.character.joint_names), formats=_formats(req, scene),
                     chunk=params["chunk"], params=params, key=params_key(params), timings={}, floor=floor,
                     glb=_glb(req), tissue_solver=solver)


def _picker(req: BakeRequest, spec):
    """pick(name, default): the request's value, else the scene's [character] one, else default."""
    def pick(name, default):
        v = getattr(req, name)
        if v is None and spec is not None:
            v = getattr(spec, name)
        return default if v is None else v
    return pick


def _clip(req: BakeRequest, scene):
    """(clip, its file) from --clip over the scene's [motion]; without either, a skinned glTF
    character's own animation (--animation, else its first)."""
    character = req.character or (scene.character.file if scene is not None and scene.character else None)
    if req.clip is None and (scene is None or scene.clip is None) and character is not None \
            and str(character).lower().endswith((".glb", ".gltf", ".fbx")):
        req = replace(req, clip=character)
    if req.clip is not None:
        from jiggle.rig.motion.mocap import load_clip
        if not os.path.isfile(req.clip):
            raise InputError("clip file not found", req.clip, field="--clip")
        anim = req.animation
        if isinstance(anim, str) and anim.lstrip("-").isdigit():
            anim = int(anim)
        clip = load_clip(req.clip, skeleton=req.skeleton, animation=anim, scale=req.scale, tpose=req.tpose)
        return clip, os.path.abspath(req.clip)
    if scene.clip is None:
        raise InputError("the scene has no [motion]: give the clip with --clip FILE (BVH, AMC or glTF)",
                         scene.path, field="--clip")
    return scene.clip, scene.clip.source or scene.path


def _settings(req: BakeRequest, scene, jiggles):
    """(JiggleSettings, jiggles): the scene's [jiggle] with the command line's over it. The muscles'
    parameters, each over the one before: the template's, the scene's [jiggle] strength, the scene's
    [jiggle.muscles.NAME] tables (names and globs), the command line's global --strength and --blend
    (every muscle's, over the scene's own), then its NAME=VALUE entries (req.muscles)."""
    settings = scene.jiggle if scene is not None and scene.jiggle is not None else JiggleSettings()
    if scene is not None:
        jiggles = scene.apply_jiggle(jiggles)
    given = {"substeps": req.substeps, "strength": req.jiggle, "gravity": req.gravity, "preroll": req.preroll,
             "collisions": req.collisions, "colliders": req.colliders, "muscle_collisions": req.muscle_collisions,
             "device": None if req.device is None else warp_device(req.device),
             "blend": None if req.blend is None else BlendCurve.parse(req.blend, "--blend")}
    settings = replace(settings, **{k: v for k, v in given.items() if v is not None})
    if req.blend is not None:
        jiggles = [replace(j, blend=None) for j in jiggles]
    if req.jiggle is not None:
        jiggles = [replace(j, strength=settings.strength) for j in jiggles]
    if req.muscles:
        from jiggle.sim.bake.scene import apply_entries
        jiggles = apply_entries(jiggles, req.muscles)
    return settings, list(jiggles)


def warp_device(name: str) -> str:
    """`name` checked against the Warp devices of this machine ("cpu", "cuda", "cuda:0", ...), as Warp
    names it; InputError naming --device and the devices there are otherwise (a machine without a GPU
    has "cpu" only)."""
    import warp as wp
    wp.init()
    have = ", ".join(str(d) for d in wp.get_devices())
    if str(name).startswith("cuda") and not wp.is_cuda_available():
        # asked before Warp tries the driver (which prints its own errors on a machine without one)
        raise InputError(f"no Warp device {name!r} here: Warp finds no CUDA driver or GPU; this machine has: {have}",
                         field="--device")
    try:
        return str(wp.get_device(name))
    except (RuntimeError, ValueError, TypeError) as e:
        raise InputError(f"no Warp device {name!r} here ({type(e).__name__}: {e}); this machine has: {have}",
                         field="--device") from None


def _formats(req: BakeRequest, scene) -> tuple:
    return tuple(req.formats or (scene.formats if scene is not None else None) or DEFAULT_FORMATS)


def _glb(req: BakeRequest) -> Mapping:
    """The glb's options (sim/bake/glb.py): jiggle bones (None: the template's default) and influences."""
    return MappingProxyType({"bones": req.jiggle_bones, "max_influences": int(req.max_influences)})


def _chunk(req: BakeRequest, scene) -> int:
    return int(req.chunk or (scene.chunk if scene is not None else None) or DEFAULT_CHUNK)


def _drive(clip, drive: str, knots: np.ndarray, log) -> Callable:
    """world_at for the knots: the clip's skeleton posed by MuJoCo (kinematic), or simulated by MuJoCo
    on a floor following the clip (physics, run once over every knot since it carries state)."""
    from jiggle.rig.motion.clip import transforms
    from jiggle.sim.drive.skeleton import Skeleton
    if drive == "kinematic":
        sk = Skeleton(clip)
        return lambda ts: transforms(*sk.world(np.asarray(ts, dtype=np.float64)))
    if drive != "physics":
        raise InputError(f"expected 'kinematic' or 'physics', got {drive!r}", field="--drive")
    from jiggle.sim.drive.motion import drive_physics
    t = time.perf_counter()
    motion = drive_physics(clip, knots)
    world = transforms(motion.rotations, motion.positions)
    log(f"physics drive: {len(knots)} knots simulated ({time.perf_counter() - t:.1f} s)")

    def world_at(ts):
        ts = np.asarray(ts, dtype=np.float64)
        k = np.clip(np.searchsorted(knots, ts - 1e-9), 0, len(knots) - 1)
        if np.any(np.abs(knots[k] - ts) > 1e-9):
            raise ValueError("the physics drive was run at the goal knots only")
        return world[k]
    world_at.floor_height = motion.info.get("floor_height_m")
    return world_at


MUSCLE_KEYS = {"strength": "strength", "frequency": "frequency_hz", "damping": "damping_ratio",
               "goal_scale": "goal_scale", "goal": "goal", "density": "density",
               "spring_frequency": "spring_frequency_hz", "spring_damping": "spring_damping_ratio", "friction": "friction", "blend": "blend",
               "max_offset": "max_offset"}
"""bake.json's per-muscle parameter names (the scene's [jiggle.muscles.NAME] keys) -> MuscleJiggle attributes."""


def _muscle_params(rig, jiggles, idle=None, scale: float = 1.0, springs: Mapping | None = None) -> dict:
    """Per muscle: kind, rest volume, mass and every jiggle parameter under its scene key (MUSCLE_KEYS; a
    keyed one as {"times", "values", "interpolation"}), max_offset in metres at strength 1 (None: no
    limit) and reach_m, the reach at the largest strength (JSON-ready). A muscle flagged in `idle` ((M,)
    bool, rig.skin.muscle_skin.MuscleSkin.idle) drives no skin and is not simulated: "simulated" false and
    reach_m None, so compare leaves it out of the near-reach counts. springs : {name: what set its springs}
    (springs_from; see MATERIAL_RULE), left out when None."""
    from jiggle.sim.jiggle.materials import material_of
    volumes = rig.volumes(rig.rest_cvs)
    radii = rig.mean_radii(rig.rest_cvs)
    out = {}
    for m, j in enumerate(jiggles):
        d = {key: jsonable(getattr(j, attr)) for key, attr in MUSCLE_KEYS.items()}
        d["max_offset"] = j.max_offset if math.isfinite(j.max_offset) else None
        still = idle is not None and bool(idle[m])
        out[rig.names[m]] = {"kind": rig.kinds[m], "volume_m3": float(volumes[m]),
                             "mass_kg": float(volumes[m] * j.density), **d,
                             "reach_m": j.reach if math.isfinite(j.reach) and not still else None,
                             "radius_m": float(radii[m]), "length_m": float(rig.rest_length[m]),
                             "material": material_of(j, rig.kinds[m], radii[m] * scale, rig.rest_length[m] * scale,
                                                     rig.rest_cvs[rig.cv_offsets[m]:rig.cv_offsets[m + 1]]).to_json(),
                             **({"springs_from": springs[rig.names[m]]} if springs else {}),
                             **({"simulated": False} if still else {})}
    return out


def idle_of(skin, M: int) -> np.ndarray:
    """(M,) bool: the muscles the skin says drive nothing (MuscleSkin.idle), none when it does not say."""
    idle = getattr(skin, "idle", None)
    return np.zeros(M, bool) if idle is None or len(idle) != M else np.asarray(idle, bool)

