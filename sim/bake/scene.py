"""Scenes: a TOML file naming the motion, how to play it and how its muscles jiggle (the built-in
default is scenes/default.toml).

Layout (paths relative to the scene file)::

    name = "default"
    builtin = "simple_arm"        # optional: a scene made in code (rig/muscle/simple_arm.py, the thesis's
                                  # example: its cylinder, muscle and flex); no [motion]/[character] then
    [motion]                      # optional: without it, `jiggle bake SCENE --clip FILE` gives the motion
    file = "jumping_jacks.toml"   # keyframed TOML (rig.motion.keyframes) or any clip: BVH, AMC, glTF;
                                  # ${VAR} takes an environment variable ("${JIGGLE_ASSETS}/mocap/...")
    skeleton = "01.asf"           # optional, for an AMC (${VAR} too)
    animation = 0                 # optional, for glTF
    start = 0.0                   # optional, seconds
    end = 2.0                     # optional, seconds
    [character]                   # optional: default a body generated around the clip's skeleton
    file = "${JIGGLE_ASSETS}/characters/CesiumMan.glb"   # a skinned glTF/GLB (the clip is retargeted)
    skin = 0                      # which skin of the glTF
    unit = "m"                    # the file's unit
    template = "auto"             # muscle template: auto (by body plan), a built-in name or .toml/.xml (relative)
    resolution = 20000            # generated body: vertex count; belly, chest, glutes, upper_arms:
    belly = 0.04                  #   metres of fat (rig.character.body.BodyOptions)
    influences = 4                # skin weights kept per vertex
    skinning = "shell"            # how muscles move the skin: "shell", "influence" or "rbf"
    method = "lbs"                # smooth skinning underneath: "lbs" or "dqs"
    mush = 0                      # Delta Mush steps on the smooth skin (0: off; rig/skin/delta_mush.py)
    [skeleton]
    drive = "kinematic"           # or "physics"
    [output]
    fps = 60                      # optional, default the clip's
    focus = ["belly_fat"]         # optional: muscles `jiggle simulate` frames and draws (default: the
                                  # most jiggling ones)
    formats = ["npz", "usdc"]     # `jiggle bake` caches: npz, usdc or usda, pc2
    chunk = 64                    # `jiggle bake` frames per chunk written (and resumed)
    [jiggle]                      # optional: the secondary motion (`jiggle simulate`), sim.jiggle.params
    substeps = 4                  # integration steps per output frame, >= 1
    goal_rate = 120               # Hz, goal sampling (default max(120, fps))
    gravity = false
    preroll = 0.0                 # seconds
    strength = 1.0                # jiggle strength J in [0, 1] of every muscle (default: each muscle's); keyable
    blend = 1.0                   # static_dyn_blend: a number in [0, 1] or keys [[t_s, b], ...]
    cut_ratio = 8.0
    cut_jump = 0.1                # metres
    collisions = true             # particles collide with other body parts' bone capsules and the floor
    colliders = "bone"            # which capsules: "bone" (fitted to the skin) or "model" (the MuJoCo model's geoms)
    muscle_collisions = false     # particles of muscles of different body parts collide with each other too
    [jiggle.muscles.belly_fat]    # per muscle, keys of sim.jiggle.params.OVERRIDES
    damping = 0.3
    blend = [[0.0, 0.0], [0.5, 1.0]]
    strength = {keys = [[0.0, 1.0], [2.0, 0.2]], interpolation = "smooth"}
    [jiggle.muscles."*_fat"]      # or a glob (fnmatch) of muscles: for each key an exact name beats a glob,
    goal_scale = 0.8              #   a later glob an earlier one; a glob that matches nothing is an error
    [[pose_shapes]]               # any number: a muscle's sections scaled by a joint's bend
    muscle = "left_biceps"        #   a muscle's name or a glob ("*_biceps")
    joint = "lelbow"              #   the joint whose bend drives it (the character's joint name)
    angles = [0, 90, 140]         #   degrees the joint is rotated away from its rest pose, increasing
    scales = [1.0, 1.25, [1, 1.2, 1.45, 1.2, 1]]   # per angle: all five sections, or each (origin
                                  #   rim, bulge, middle, bulge, insertion rim); linear between angles
    [chains]                      # optional: tails, ears, hair, wing fingers that swing (sim/chain)
    swing = "auto"                # "auto", "none" or a list of joints (globs) that start one (--chains)
    [chains."Ear*"]               # per chain (its root joint's name) or glob: keys of
    damping = 0.6                 #   sim.chain.params.CHAIN_PARAMETERS (stiffness Hz, damping, gravity, drag),
    [chains.Tail1]                #   numbers or curves; an exact name beats a glob, a glob matching no chain
    stiffness = [[0.0, 2.0], [1.5, 6.0]]   # is an error

A ``${VAR}`` at the start of a path whose value is relative is taken from the current directory, as
the shell would (``JIGGLE_ASSETS=../shared/assets jiggle simulate scenes/belly_run.toml``); an unset
variable is an error naming it. Key times (blend, strength, frequency, damping, goal_scale: numbers or
curves, sim/jiggle/keyed.py) are seconds of the motion as played (after start/end).
Muscle names and globs under [jiggle.muscles] are checked against the rig when they are applied
(:meth:`Scene.apply_jiggle`), since the scene does not know the character's muscles. The scene's [jiggle]
strength is every muscle's; a muscle's own table (by name or glob) goes over it.

The thesis's simple arm (rig/muscle/simple_arm.py) has no scene file: its cylinder, bones and fast flex
are made in code, and it is what `jiggle simulate` runs when given no scene and no clip.
"""
from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Mapping, Sequence

from jiggle.rig.base.errors import InputError
from jiggle.rig.base.tomlfile import read_toml
from jiggle.rig.motion.clip import Clip
from jiggle.sim.jiggle.keyed import parse_curve
from jiggle.sim.jiggle.params import COLLIDERS, OVERRIDES, BlendCurve, JiggleSettings, MuscleJiggle, override, section_goals

_JIGGLE_SETTINGS = ("substeps", "goal_rate", "gravity", "preroll", "strength", "blend", "cut_ratio", "cut_jump",
                    "collisions", "colliders", "muscle_collisions")
_BODY = ("resolution", "belly", "chest", "glutes", "upper_arms")
_CHARACTER = {"file", "skin", "unit", "template", "influences", "skinning", "method", "mush", *_BODY}
_KNOWN = {"name": None, "builtin": None,
          "motion": {"file", "skeleton", "animation", "start", "end", "scale", "tpose"},
          "character": _CHARACTER, "skeleton": {"drive"}, "output": {"fps", "focus", "formats", "chunk"},
          "jiggle": set(_JIGGLE_SETTINGS) | {"muscles"}, "pose_shapes": None, "chains": None}
_POSE_SHAPE_KEYS = ("muscle", "joint", "angles", "scales")
BUILTINS = ("simple_arm",)
FORMATS = ("npz", "usdc", "usda", "pc2", "glb")
"""Formats `jiggle bake` writes: caches (usdc and usda are one USD stage, crate or text) and glb, a skinned glTF
with jiggle bones fitted from the finished npz (sim/bake/glb.py; asking for glb writes the npz too)."""


MAX_FPS = 10000.0            # output frames per second
MAX_UNIT = 1000.0            # metres per motion file unit
MAX_FAT = 1.0                # metres of fat on a generated body (belly, chest, glutes, upper_arms)
MAX_RESOLUTION = 2_000_000   # vertices of a generated body
MAX_COUNT = 1_000_000        # skin, influences, mush
MAX_SUBSTEPS = 1000          # jiggle substeps per frame


def default_scene() -> str:
    """Path of the built-in demo scene, scenes/default.toml."""
    from importlib import resources
    return str(resources.files("jiggle.scenes").joinpath("default.toml"))


@dataclass(frozen=True)
class CharacterSpec:
    """A scene's [character] table, checked; None: not given (the command's default applies).

    file : absolute path of a skinned glTF/GLB, None for a body generated around the clip's skeleton.
    template : a built-in template name or an absolute .toml/.xml path.
    body : BodyOptions keywords for a generated body (resolution, belly, chest, glutes, upper_arms).
    """

    file: str | None = None
    skin: int | None = None
    unit: str | None = None
    template: str | None = None
    body: Mapping = field(default_factory=lambda: MappingProxyType({}))
    influences: int | None = None
    skinning: str | None = None
    method: str | None = None
    mush: int | None = None


_VAR = re.compile(r"\$\{([A-Za-z_][A-Za-z0-9_]*)\}")


@dataclass(frozen=True)
class Scene:
    """A loaded scene. fps: output frames per second (None: the clip's).

    jiggle : the [jiggle] section's settings (sim.jiggle.params.JiggleSettings), None without one.
    muscle_jiggle : muscle name -> its [jiggle.muscles.NAME] table (keys of
        sim.jiggle.params.OVERRIDES, values checked; blends parsed to BlendCurve), read-only.
    focus : muscles the pictures frame ([output] focus), () for the default.
    clip : the motion, None when the scene has no [motion] (the command line gives it) or is built in.
    character : the [character] table (CharacterSpec). builtin : a scene made in code (BUILTINS).
    formats : `jiggle bake` cache formats ([output] formats), None for the default. chunk : frames
        per bake chunk, None for the default.
    pose_shapes : the [[pose_shapes]] tables (rig.muscle.pose_shapes.SectionShape), checked against the
        rig and the character when applied (:meth:`apply_pose_shapes`).
    chains : the [chains] section's `swing` (rig.character.chains.find_chains's mode: "auto", "none" or a list of
        joints and globs), None without one. chain_entries : its [chains.NAME] tables (NAME a chain, its root
        joint's name, or a glob), (NAME, {parameter: value}, (where, path, line)) in the file's order
        (sim.chain.params.CHAIN_PARAMETERS, values checked).
    """

    name: str
    path: str
    clip: Clip | None
    drive: str
    fps: float | None
    jiggle: JiggleSettings | None = None
    muscle_jiggle: Mapping[str, Mapping] = field(default_factory=lambda: MappingProxyType({}))
    focus: tuple[str, ...] = ()
    character: CharacterSpec = CharacterSpec()
    builtin: str | None = None
    formats: tuple[str, ...] | None = None
    chunk: int | None = None
    pose_shapes: tuple = ()
    chains: str | None = None
    chain_entries: tuple = ()

    def apply_pose_shapes(self, rig, character):
        """`rig` (rig.muscle.model.MuscleRig) with this scene's pose shapes bound to it and to the
        character's skeleton (the rig itself when the scene has none); InputError naming the scene's
        line for an unknown muscle or joint, or bad keys."""
        from dataclasses import replace

        from jiggle.rig.muscle.pose_shapes import bind_section_shapes
        if not self.pose_shapes:
            return rig
        shapes = bind_section_shapes(self.pose_shapes, rig, character.joint_names, character.parents,
                                     character.bind_world)
        return replace(rig, pose_shapes=shapes)

    def apply_jiggle(self, jiggles: Sequence) -> list:
        """`jiggles` (sim.jiggle.params.MuscleJiggle, one per muscle of the rig) with this scene's [jiggle]
        strength (every muscle's) and then its per-muscle tables (names or globs) applied; InputError naming
        the scene's line for a muscle the rig lacks or a glob that matches none, with the rig's muscles."""
        if self.jiggle is not None and self.jiggle.strength is not None:
            from dataclasses import replace
            jiggles = [replace(j, strength=self.jiggle.strength) for j in jiggles]
        return apply_muscle_jiggle(jiggles, self.muscle_jiggle, self.path)


def apply_muscle_jiggle(jiggles: Sequence, tables: Mapping[str, Mapping], path: str | None = None) -> list:
    """Each MuscleJiggle in `jiggles` with the tables of `tables` (muscle name or fnmatch glob -> OVERRIDES
    keys, in file order) that name it applied, key by key the most specific (sim.jiggle.keyed.resolve_tables:
    an exact name beats a glob, a later glob an earlier one)."""
    lines = _Lines(path) if path is not None else None
    entries = [(n, t, (f"jiggle.muscles.{n}", path, lines.table(f"jiggle.muscles.{n}") if lines else None))
               for n, t in tables.items()]
    return apply_entries(jiggles, entries, path, lines)


def apply_entries(jiggles: Sequence, entries: Sequence[tuple], path: str | None = None, lines=None) -> list:
    """`jiggles` with entries (pattern, {OVERRIDES key: value}, where) applied as apply_muscle_jiggle does;
    where is a name for messages (a flag: "--damping *_fat=0.2") or (name, path, line)."""
    from jiggle.sim.jiggle.keyed import resolve_tables
    names = [j.name for j in jiggles]
    merged = resolve_tables(entries, names)
    out = []
    for j in jiggles:
        if j.name in merged:
            # keys that came from one entry are applied together, so its errors name it
            by_where: dict = {}
            for k, (v, where) in merged[j.name].items():
                by_where.setdefault(where, {})[k] = v
            for where, table in by_where.items():
                if isinstance(where, tuple):
                    j = _override(j, table, where[0], path, lines)
                    continue
                try:                                        # a command-line flag: its errors name the flag
                    j = override(j, dict(table), where)
                except InputError as e:
                    message = e.message.removeprefix(f"{where}: ").removeprefix(f"muscle {j.name!r}: ")
                    raise InputError(f"{message} (muscle {j.name!r})", field=where) from None
        out.append(j)
    return out


def _override(mj: MuscleJiggle, table: Mapping, where: str, path: str | None, lines: "_Lines | None" = None):
    """override(mj, table) with its errors naming the file, the line when known and `where`.KEY."""
    try:
        return override(mj, dict(table), where)
    except InputError as e:
        key = e.field or ""
        key = key[len(where) + 1:] if key.startswith(f"{where}.") else key   # override names the user's key
        message = e.message
        for prefix in (f"muscle {mj.name!r}: ", f"{where}: "):
            message = message.removeprefix(prefix)
        at = (lines.key(where, key) if key in OVERRIDES else lines.table(where)) if lines else None
        raise InputError(message, path, at, field=f"{where}.{key}" if key in OVERRIDES else where) from None
    except (TypeError, ValueError) as e:   # e.g. a goal that is not a list of numbers
        raise InputError(f"bad value: {e}", path, lines.table(where) if lines else None, field=where) from None


def expand_path(value, path: str, field_name: str, line: int | None = None) -> str:
    """A scene path with ${VAR} replaced by the environment variable (made absolute from the current
    directory when it starts the path); InputError naming the variable when it is unset or empty."""
    if not isinstance(value, str) or not value:
        raise InputError(f"expected a file name (a string), found {value!r}", path, line, field=field_name)

    def sub(m: re.Match) -> str:
        v = os.environ.get(m.group(1))
        if not v:
            raise InputError(f"environment variable {m.group(1)} is not set; set it to the folder the path "
                             f"{value!r} needs (e.g. {m.group(1)}=../shared/assets)", path, line, field=field_name)
        return os.path.abspath(v) if m.start() == 0 else v
    return _VAR.sub(sub, value)


def load_scene(path: str | os.PathLike) -> Scene:
    p, doc = read_toml(path, "scene file")
    lines = _Lines(p)
    for key, sub in doc.items():
        if key not in _KNOWN:
            raise InputError(f"unknown section; expected one of {', '.join(_KNOWN)}", p, lines.table(key), field=key)
        if _KNOWN[key] is not None:
            if not isinstance(sub, dict):
                raise InputError("expected a table", p, lines.key("", key), field=key)
            for k in sub:
                if k not in _KNOWN[key]:
                    raise InputError(f"unknown key; expected one of {', '.join(sorted(_KNOWN[key]))}", p,
                                     lines.key(key, k), field=f"{key}.{k}")
    here = os.path.dirname(os.path.abspath(p))
    builtin = doc.get("builtin")
    if builtin is not None:
        if builtin not in BUILTINS:
            raise InputError(f"unknown built-in scene {builtin!r}; expected one of {', '.join(BUILTINS)}", p,
                             lines.key("", "builtin"), field="builtin")
        for key in ("motion", "character"):
            if key in doc:
                raise InputError(f"a built-in scene ({builtin}) makes its own {key}; remove [{key}]", p,
                                 lines.table(key), field=key)
    motion = doc.get("motion", {})
    if motion and "file" not in motion:
        raise InputError("[motion] needs a file (or leave [motion] out and give --clip)", p,
                         lines.table("motion"), field="motion.file")
    clip = None if not motion else _read_motion(motion, p, here, lines)
    drive = doc.get("skeleton", {}).get("drive", "kinematic")
    if drive not in ("kinematic", "physics"):
        raise InputError(f"expected 'kinematic' or 'physics', found {drive!r}", p, field="skeleton.drive")
    output = doc.get("output", {})
    fps = output.get("fps")
    if fps is not None and not (_real(fps) and 0 < fps <= MAX_FPS):
        raise InputError(f"expected a positive number (at most {MAX_FPS:g} frames per second), found {fps!r}", p,
                         lines.key("output", "fps"), field="output.fps")
    focus = output.get("focus", [])
    focus = [focus] if isinstance(focus, str) else focus
    if not isinstance(focus, list) or not all(isinstance(f, str) and f for f in focus):
        raise InputError(f"expected a muscle name or a list of them, found {focus!r}", p,
                         lines.key("output", "focus"), field="output.focus")
    formats = output.get("formats")
    if formats is not None:
        formats = parse_formats(formats, p, lines.key("output", "formats"), "output.formats")
    chunk = output.get("chunk")
    if chunk is not None and (isinstance(chunk, bool) or not isinstance(chunk, int) or chunk < 1):
        raise InputError(f"expected a whole number >= 1 of frames, found {chunk!r}", p, lines.key("output", "chunk"),
                         field="output.chunk")
    character = _character(doc.get("character", {}), p, here, lines)
    settings, tables = (None, {}) if "jiggle" not in doc else _jiggle_section(doc["jiggle"], p, lines)
    pose_shapes = _pose_shapes(doc.get("pose_shapes"), p)
    chains, chain_entries = _chains_section(doc.get("chains"), p, lines)
    return Scene(chains=chains, chain_entries=chain_entries, name=str(doc.get("name", os.path.splitext(os.path.basename(p))[0])), path=p, clip=clip,
                 drive=drive, fps=None if fps is None else float(fps), jiggle=settings,
                 muscle_jiggle=MappingProxyType(tables), focus=tuple(focus), character=character,
                 builtin=builtin, formats=formats, chunk=chunk, pose_shapes=pose_shapes)


def _chains_section(sec, p: str, lines: "_Lines") -> tuple:
    """([chains] swing or None, its [chains.NAME] tables as entries), checked (Scene.chains)."""
    if sec is None:
        return None, ()
    if not isinstance(sec, dict):
        raise InputError("expected a table [chains]", p, lines.table("chains"), field="chains")
    from jiggle.sim.chain.params import CHAIN_PARAMETERS, check_value
    mode = None
    entries = []
    for k, v in sec.items():
        if k == "swing":
            if isinstance(v, list) and all(isinstance(x, str) for x in v):
                v = ",".join(v)
            if not isinstance(v, str) or not v.strip():
                raise InputError(f"expected \"auto\", \"none\" or a list of joints, found {v!r}", p,
                                 lines.key("chains", k), field="chains.swing")
            mode = v
        elif isinstance(v, dict):
            where = f"chains.{k}"
            for name, value in v.items():
                if name not in CHAIN_PARAMETERS:
                    raise InputError(f"unknown key; expected one of {', '.join(CHAIN_PARAMETERS)}", p,
                                     lines.key(where, name), field=f"{where}.{name}")
                try:
                    check_value(name, value, f"{where}.{name}")
                except InputError as e:
                    raise InputError(e.message, p, lines.key(where, name), field=f"{where}.{name}") from None
            entries.append((k, dict(v), (where, p, lines.table(where))))
        else:
            raise InputError("expected swing = ... or tables [chains.NAME]", p, lines.key("chains", k),
                             field=f"chains.{k}")
    return mode, tuple(entries)


def parse_formats(value, path=None, line=None, where="--formats") -> tuple[str, ...]:
    """Cache formats from a list (or a comma-separated string): a tuple of FORMATS, no duplicates,
    at most one of usdc/usda; InputError naming `where` otherwise."""
    items = value.split(",") if isinstance(value, str) else value
    if not isinstance(items, (list, tuple)) or not items or not all(isinstance(f, str) for f in items):
        raise InputError(f"expected a list of {', '.join(FORMATS)}, found {value!r}", path, line, field=where)
    items = [f.strip().lower().lstrip(".") for f in items]
    bad = [f for f in items if f not in FORMATS]
    if bad:
        raise InputError(f"unknown cache format {', '.join(map(repr, bad))}; expected some of {', '.join(FORMATS)}",
                         path, line, field=where)
    if "usdc" in items and "usda" in items:
        raise InputError("usdc and usda are the same stage; pick one", path, line, field=where)
    if "glb" in items and "npz" not in items:
        items.insert(0, "npz")                  # the glb is fitted from the finished npz, which stays beside it
    return tuple(dict.fromkeys(items))


def _read_motion(motion: dict, p: str, here: str, lines: "_Lines") -> Clip:
    mfile = os.path.join(here, expand_path(motion["file"], p, "motion.file", lines.key("motion", "file")))
    if not os.path.isfile(mfile):
        raise InputError(f"motion file {mfile} not found", p, lines.key("motion", "file"), field="motion.file")
    if mfile.lower().endswith(".toml"):
        from jiggle.rig.motion.keyframes import read_keyframes
        clip = read_keyframes(mfile)
    else:
        from jiggle.rig.motion.mocap import load_clip
        skel = motion.get("skeleton")
        skel = os.path.join(here, expand_path(skel, p, "motion.skeleton", lines.key("motion", "skeleton"))) if skel else None
        scale = motion.get("scale")
        if scale is not None and not (_real(scale) and 0 < scale <= MAX_UNIT):
            raise InputError(f"expected metres per file unit in (0, {MAX_UNIT:g}], found {scale!r}", p,
                             lines.key("motion", "scale"), field="motion.scale")
        for k, choices in (("tpose", ("auto", "skip", "keep")),):
            if k in motion and motion[k] not in choices:
                raise InputError(f"expected one of {', '.join(choices)}, found {motion[k]!r}", p,
                                 lines.key("motion", k), field=f"motion.{k}")
        animation = motion.get("animation")
        if animation is not None and (isinstance(animation, bool) or not isinstance(animation, (str, int))):
            raise InputError(f"expected an animation name or index, found {animation!r}", p,
                             lines.key("motion", "animation"), field="motion.animation")
        clip = load_clip(mfile, skeleton=skel, animation=animation, scale=scale, tpose=motion.get("tpose", "auto"))
    if "start" in motion or "end" in motion:
        for k in ("start", "end"):
            if k in motion and not (_real(motion[k]) and 0 <= motion[k] < math.inf):
                raise InputError(f"expected seconds >= 0, found {motion[k]!r}", p, lines.key("motion", k),
                                 field=f"motion.{k}")
        try:
            clip = clip.between(float(motion.get("start", 0.0)), motion.get("end"))
        except InputError as e:
            k = "end" if "end" in motion else "start"
            raise InputError(e.message, p, lines.key("motion", k), field=f"motion.{k}") from None
    return clip


def _real(v) -> bool:
    """A finite int or float, not a bool."""
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _character(table: dict, p: str, here: str, lines: "_Lines") -> CharacterSpec:
    """The [character] table checked, paths expanded and made absolute."""
    def at(k):
        return lines.key("character", k)
    kw, body = {}, {}
    for k, v in table.items():
        where = f"character.{k}"
        if k in ("file", "template"):
            if k == "template" and isinstance(v, str) and v and not v.lower().endswith((".toml", ".xml")):
                kw[k] = v                                   # a built-in template's name
                continue
            f = os.path.join(here, expand_path(v, p, where, at(k)))
            if not os.path.isfile(f):
                raise InputError(f"file {f} not found", p, at(k), field=where)
            kw[k] = f
        elif k in ("skinning", "method"):
            choices = ("shell", "influence", "rbf") if k == "skinning" else ("lbs", "dqs")
            if v not in choices:
                raise InputError(f"expected one of {', '.join(choices)}, found {v!r}", p, at(k), field=where)
            kw[k] = v
        elif k == "unit":
            if not isinstance(v, (str, int, float)) or isinstance(v, bool):
                raise InputError(f"expected a unit (m, cm, mm, in, ft) or metres per unit, found {v!r}", p, at(k),
                                 field=where)
            kw[k] = str(v)
        elif k in ("skin", "influences", "resolution", "mush"):
            least = 0 if k in ("skin", "mush") else 1
            most = MAX_RESOLUTION if k == "resolution" else MAX_COUNT
            if isinstance(v, bool) or not isinstance(v, int) or not least <= v <= most:
                raise InputError(f"expected a whole number >= {least} (at most {most:,}), found {v!r}", p, at(k),
                                 field=where)
            (body if k == "resolution" else kw)[k] = v
        else:                                               # fat volumes, metres
            if not (_real(v) and 0 <= v <= MAX_FAT):
                raise InputError(f"expected metres >= 0 (at most {MAX_FAT:g}), found {v!r}", p, at(k), field=where)
            body[k] = float(v)
    if body and "file" in kw:
        raise InputError(f"{', '.join(body)} shape a generated body; a character file has its own shape", p,
                         at(next(iter(body))), field=f"character.{next(iter(body))}")
    return CharacterSpec(body=MappingProxyType(body), **kw)


def _jiggle_section(sec: dict, p: str, lines: "_Lines"):
    """(JiggleSettings, {muscle: checked table}) of a [jiggle] table."""
    kw = {}
    for k in _JIGGLE_SETTINGS:
        if k not in sec:
            continue
        v, where = sec[k], f"jiggle.{k}"
        line = lines.key("jiggle", k)
        if k in ("blend", "strength"):
            try:
                v = BlendCurve.parse(v, where) if k == "blend" else parse_curve(v, "strength", where)
            except InputError as e:
                message = f"jiggle {e.message}" if k == "strength" else e.message
                raise InputError(message, p, line, field=where) from None
            kw[k] = v
            continue
        elif k in ("gravity", "collisions", "muscle_collisions"):
            if not isinstance(v, bool):
                raise InputError(f"expected true or false, found {v!r}", p, line, field=where)
        elif k == "colliders":
            if v not in COLLIDERS:
                raise InputError(f"expected one of {', '.join(map(repr, COLLIDERS))}, found {v!r}", p, line,
                                 field=where)
            kw[k] = v
            continue
        elif k == "substeps":
            if isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= MAX_SUBSTEPS:
                raise InputError(f"expected a whole number >= 1 (at most {MAX_SUBSTEPS}), found {v!r}", p, line,
                                 field=where)
        elif isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise InputError(f"expected a number, found {v!r}", p, line, field=where)
        elif k == "preroll" and v < 0:
            raise InputError(f"expected seconds >= 0, found {v!r}", p, line, field=where)
        kw[k] = float(v) if k in ("goal_rate", "preroll", "cut_ratio", "cut_jump") else v
    try:
        settings = JiggleSettings(**kw)
    except InputError as e:
        f = e.field if e.field in _JIGGLE_SETTINGS else None
        raise InputError(e.message, p, lines.key("jiggle", f) if f else None,
                         field=f"jiggle.{f}" if f else "jiggle") from None

    muscles = sec.get("muscles", {})
    if not isinstance(muscles, dict):
        raise InputError("expected tables [jiggle.muscles.NAME]", p, lines.key("jiggle", "muscles"),
                         field="jiggle.muscles")
    # a stand-in muscle checks each table's values now, so a typo fails before any fitting or simulation
    probe = MuscleJiggle(name="probe", frequency_hz=7.0, damping_ratio=0.5, goal=section_goals(0.9, 0.4),
                         density=1000.0)
    tables = {}
    for name, table in muscles.items():
        where = f"jiggle.muscles.{name}"
        if not isinstance(table, dict):
            raise InputError(f"expected a table of {', '.join(OVERRIDES)}", p, lines.key("jiggle.muscles", name),
                             field=where)
        for k in table:
            if k not in OVERRIDES:
                raise InputError(f"unknown key; expected one of {', '.join(OVERRIDES)}", p, lines.key(where, k),
                                 field=f"{where}.{k}")
        t = dict(table)
        if "blend" in t:
            try:
                t["blend"] = BlendCurve.parse(t["blend"], f"{where}.blend")
            except InputError as e:
                raise InputError(e.message, p, lines.key(where, "blend"), field=e.field) from None
        _override(probe, t, where, p, lines)
        tables[name] = MappingProxyType(t)
    return settings, tables


def _pose_shapes(tables, p: str) -> tuple:
    """The [[pose_shapes]] tables as SectionShape (types checked here, with the line of each table's
    header; ranges, muscles and joints when they are bound to a rig)."""
    from jiggle.rig.muscle.pose_shapes import SectionShape
    if tables is None:
        return ()
    with open(p, encoding="utf-8") as fh:
        heads = [i for i, s in enumerate(fh.read().splitlines(), 1) if re.match(r"\s*\[\[\s*pose_shapes\s*\]\]", s)]
    if not isinstance(tables, list) or not all(isinstance(t, dict) for t in tables):
        raise InputError("expected [[pose_shapes]] tables", p, heads[0] if heads else None, field="pose_shapes")
    out = []
    for n, t in enumerate(tables):
        line = heads[n] if n < len(heads) else None
        where = f"pose_shapes[{n + 1}]"
        for k in t:
            if k not in _POSE_SHAPE_KEYS:
                raise InputError(f"unknown key {k!r}; expected {', '.join(_POSE_SHAPE_KEYS)}", p, line, field=where)
        missing = [k for k in _POSE_SHAPE_KEYS if k not in t]
        if missing:
            raise InputError(f"missing {', '.join(missing)}; a pose shape needs {', '.join(_POSE_SHAPE_KEYS)}", p,
                             line, field=where)
        for k in ("muscle", "joint"):
            if not isinstance(t[k], str) or not t[k]:
                raise InputError(f"expected a name, found {t[k]!r}", p, line, field=f"{where}.{k}")
        angles, scales = t["angles"], t["scales"]
        if not isinstance(angles, list) or not angles or not all(_real(a) for a in angles):
            raise InputError(f"expected a list of degrees, found {angles!r}", p, line, field=f"{where}.angles")
        ok = isinstance(scales, list) and len(scales) == len(angles) and all(
            _real(v) or (isinstance(v, list) and len(v) == 5 and all(_real(x) for x in v)) for v in scales)
        if not ok:
            raise InputError(f"expected one scale per angle ({len(angles)}), each a number or 5 numbers (one per "
                             f"section), found {scales!r}", p, line, field=f"{where}.scales")
        rows = tuple(tuple(float(x) for x in v) if isinstance(v, list) else (float(v),) * 5 for v in scales)
        out.append(SectionShape(t["muscle"], t["joint"], tuple(float(a) for a in angles), rows, p, line))
    return tuple(out)


class _Lines:
    """Best-effort line numbers of TOML tables and keys (tomllib gives none), for error messages."""

    _HEADER = re.compile(r"^\s*\[\s*([^\[\]]+?)\s*\]\s*(#.*)?$")

    def __init__(self, path: str):
        try:
            with open(path, encoding="utf-8") as fh:
                self._text = fh.read().splitlines()
        except (OSError, UnicodeDecodeError):
            self._text = []

    @staticmethod
    def _norm(name: str) -> str:
        return ".".join(part.strip().strip('"\'') for part in name.split("."))

    def table(self, name: str) -> int | None:
        """1-based line of the header [name], or of a key `name = ...` at the top."""
        for i, s in enumerate(self._text, 1):
            m = self._HEADER.match(s)
            if m and self._norm(m.group(1)) == name:
                return i
        return self.key("", name) if "." not in name else None

    def key(self, table: str, key: str) -> int | None:
        """1-based line of `key = ...` inside [table] ("" for the top), or of the header [table.key]."""
        current = ""
        pat = re.compile(r"^\s*[\"']?" + re.escape(key) + r"[\"']?\s*=")
        for i, s in enumerate(self._text, 1):
            m = self._HEADER.match(s)
            if m:
                current = self._norm(m.group(1))
                name = f"{table}.{key}" if table else key
                if current == name or current.startswith(f"{name}."):
                    return i
            elif current == table and pat.match(s):
                return i
        return None
