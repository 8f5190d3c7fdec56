"""The viewer's "save scene": a scene TOML (sim.bake.scene's layout) holding a bake's setup and the tuned
jiggle values, which `jiggle bake SCENE` bakes to the same frames as the viewer's re-simulation.

The scene is the bake's own, completed and tuned: its [motion] and [character] (their paths made absolute,
so the file may live anywhere) with what bake.json says over them ([output] fps, chunk and formats,
[skeleton] drive, the skinning, the generated body, every [jiggle] setting, as the bake ran them, command
line included), its [jiggle.muscles.NAME] tables kept, and the tuned values written over them (a goal
weight scale as the scaled goal weights; the global `strength` of the bake, which overrides every muscle's,
written into each muscle once one muscle's strength is tuned), the glTF animation the bake read (`animation`), and
the chains: [chains] `swing` (the bake's mode) and one [chains."NAME"] table per chain with the values the bake's
user set and the tuned ones (sim.bake.scene reads them: stiffness, damping, gravity, drag). Before it is kept, the
file is read back and the jiggle and chain values it gives are checked against the tuned ones (check_scene). The output
times a scene cannot hold (a bake cut with --start/--end/--frames) are returned as command-line
arguments and written in the file's header, with a built-in scene's skinning (it takes no [character]).
"""
from __future__ import annotations

import json
import math
import os
import re
from dataclasses import replace

import numpy as np

from jiggle.rig.base.atomic import atomic_path
from jiggle.rig.base.errors import InputError
from jiggle.rig.base.tomlfile import read_toml
from jiggle.sim.bake.setup import output_times
from jiggle.sim.jiggle.params import RING, SECTIONS, BlendCurve

_BODY = ("resolution", "belly", "chest", "glutes", "upper_arms")
_BARE = re.compile(r"^[A-Za-z0-9_-]+$")


# ---------------------------------------------------------------------------------------- TOML text
def _key(k: str) -> str:
    return k if _BARE.match(k) else json.dumps(k)


def _value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        v = float(v)
        if not math.isfinite(v):
            raise ValueError(f"cannot write {v} to a scene")
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v, ensure_ascii=False)
    if isinstance(v, (list, tuple, np.ndarray)):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {type(v).__name__} to a scene")


def toml_text(doc: dict, header: str = "") -> str:
    """`doc` (nested dicts of str, int, float, bool and lists of them) as TOML: top-level keys, then one
    [table] per dict, depth first."""
    lines = [f"# {h}" if h else "#" for h in header.splitlines()]

    def table(path: list[str], d: dict) -> None:
        plain = {k: v for k, v in d.items() if not isinstance(v, dict)}
        subs = {k: v for k, v in d.items() if isinstance(v, dict)}
        if path and (plain or not subs):
            lines.extend(["", "[" + ".".join(_key(p) for p in path) + "]"])
        lines.extend(f"{_key(k)} = {_value(v)}" for k, v in plain.items())
        for k, v in subs.items():
            table(path + [k], v)
    table([], doc)
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------------------------------- the scene
def _absolute(table: dict, keys, scene_path: str, where: str) -> dict:
    """`table` with its path values (keys) made absolute from the scene's folder (${VAR} expanded)."""
    from jiggle.sim.bake.scene import expand_path
    here = os.path.dirname(os.path.abspath(scene_path))
    out = dict(table)
    for k in keys:
        v = out.get(k)
        if isinstance(v, str) and v:
            if k == "template" and not v.lower().endswith((".toml", ".xml")):
                continue                                    # a built-in template's name
            out[k] = os.path.normpath(os.path.join(here, expand_path(v, scene_path, f"{where}.{k}")))
    return out


def _blend_value(curve: BlendCurve):
    """A blend curve as a scene writes it: a number, or keys [[t_s, b], ...]."""
    if len(curve.times) == 1:
        return float(curve.values[0])
    return [[float(t), float(b)] for t, b in zip(curve.times, curve.values)]


def _goal_value(goal: np.ndarray) -> list[float]:
    """Goal weights as a scene writes them: one per section when each section's ring agrees, else 40."""
    rows = np.asarray(goal).reshape(SECTIONS, RING)
    if np.all(rows == rows[:, :1]):
        return [float(g) for g in rows[:, 0]]
    return [float(g) for g in np.asarray(goal).reshape(-1)]


def _chain_value(v):
    """A chain parameter as a scene writes it: a number, keys [[t_s, v], ...] (linear), or {keys, interpolation}."""
    from jiggle.sim.jiggle.keyed import Curve
    if not isinstance(v, Curve):
        return float(v)
    keys = [[float(t), float(x)] for t, x in zip(v.times, v.values)]
    return keys if v.interpolation == "linear" else {"keys": keys, "interpolation": v.interpolation}


def _check_chains(scene, path: str, setup) -> None:
    """InputError unless the scene gives the chains of `setup` (mode and every chain's parameters)."""
    want_mode = (setup.params.get("chains") or {}).get("mode") or "auto"
    if (scene.chains or "auto") != want_mode:
        raise InputError(f"the scene would swing other chains ({scene.chains!r}, not {want_mode!r}); not saved", path)
    ch = setup.chains
    if ch is None:
        return
    from jiggle.sim.chain.params import chain_params
    from jiggle.sim.jiggle.keyed import jsonable_value
    size = float(np.ptp(np.asarray(setup.character.vertices), axis=0).max())
    got = chain_params(ch.chains.names, ch.links.length, size, scene.chain_entries,
                       [c.spring for c in ch.chains.chains])
    for name, a, b in zip(ch.chains.names, got, ch.params):
        keys = [k for k in ("stiffness", "damping", "gravity", "drag")
                if jsonable_value(getattr(a, k)) != jsonable_value(getattr(b, k))]
        if keys:
            raise InputError(f"the scene would swing chain {name!r} with other {', '.join(keys)}; not saved", path)


def check_scene(path: str, tuner, setup) -> None:
    """InputError unless the scene at `path` gives every muscle's jiggle and the jiggle settings of `setup`
    (what sim.bake.setup.prepare makes of a scene's [jiggle]: its tables over the template's defaults, then
    the global strength over every muscle's), and its chains' parameters."""
    from jiggle.sim.bake.scene import load_scene
    from jiggle.sim.bake.setup import jsonable
    from jiggle.sim.jiggle.params import JiggleSettings
    scene = load_scene(path)
    settings = scene.jiggle if scene.jiggle is not None else JiggleSettings()
    jiggles = scene.apply_jiggle(tuner.default_jiggles())
    if settings.strength is not None:
        jiggles = [replace(j, strength=settings.strength) for j in jiggles]
    for a, b in zip(jiggles, setup.relaxed_jiggles or setup.jiggles):     # before activation's stiffening
        got, want = jsonable(a), jsonable(b)
        if got != want:
            keys = [k for k in want if got.get(k) != want[k]]
            raise InputError(f"the scene would bake muscle {b.name!r} with other {', '.join(keys)}; not saved", path)
    got, want = jsonable(settings), jsonable(setup.settings)
    keys = [k for k in want if k not in ("device", "strength") and got.get(k) != want[k]]
    if keys:
        raise InputError(f"the scene would bake with other jiggle settings ({', '.join(keys)}); not saved", path)
    _check_chains(scene, path, setup)


def output_args(params: dict, times: np.ndarray) -> list[str]:
    """The `jiggle bake` arguments that give the bake's output times when the scene's clip alone would give
    others (a bake cut with --start/--end/--frames): [] or ["--start", S, "--end", E(, "--frames", N)]."""
    fps = float(params["fps"])
    full = output_times(float(params["clip"]["duration_s"]), fps, None, None, None)
    if len(full) == len(times) and np.array_equal(full, times):
        return []
    s, e = float(times[0]), float(times[-1])
    args = ["--start", repr(s), "--end", repr(e)]
    if len(output_times(float(params["clip"]["duration_s"]), fps, s, e, None)) != len(times):
        args += ["--frames", str(len(times))]
    return args


def tuned_scene(tuner, tuning, formats=("npz", "usdc")) -> tuple[dict, list[str]]:
    """(scene document, extra `jiggle bake` arguments) of the bake behind `tuner` (view.tuning.Tuner) with
    `tuning` (view.tuning.Tuning) applied; see the module."""
    setup = tuner.tuned_setup(tuning)
    params, req = setup.params, tuner.request
    scene = params.get("scene") or {}
    builtin = scene.get("builtin")
    orig = {}
    if req.scene is not None:
        _, orig = read_toml(req.scene, "scene file")
    doc: dict = {"name": f"{orig.get('name', setup.name)} tuned"}
    if builtin:
        doc["builtin"] = builtin
    else:
        if req.clip is None and "motion" in orig:
            doc["motion"] = _absolute(orig["motion"], ("file", "skeleton"), req.scene, "motion")
        else:
            doc["motion"] = {"file": os.path.abspath(params["clip"]["file"])}
            if req.animation is not None:               # a glTF clip's animation other than its first
                doc["motion"]["animation"] = req.animation
    character = _absolute(orig.get("character", {}), ("file", "template"), req.scene, "character") \
        if req.scene else {}
    skinning = params["skinning"]
    character.update({"skinning": skinning["deformer"], "method": skinning["method"], "mush": int(skinning["mush"])})
    if not builtin:
        if req.character is not None:
            character = {k: v for k, v in character.items() if k not in _BODY}
            character["file"] = os.path.abspath(req.character)
        template = params.get("template")
        character["template"] = template["file"] if isinstance(template, dict) else template
        character["influences"] = int(skinning["influences"])
        generated = params["character"].get("generated")
        if generated:
            character.update({k: generated[k] for k in _BODY if k in generated})
        doc["skeleton"] = {"drive": params["drive"]}
        doc["character"] = character
    extra = []
    if builtin:                             # a built-in scene takes no [character]: its skinning on the command line
        for flag, key, default in (("--skinning", "deformer", "shell"), ("--method", "method", "lbs"),
                                   ("--mush", "mush", 0)):
            if skinning[key] != default:
                extra += [flag, str(skinning[key])]
    if req.loop is not None:                # a scene holds no --loop
        extra += ["--loop", req.loop]
    if req.activation is not None:          # nor --activation
        extra += ["--activation", req.activation]
    # the rate asked for (a looping bake's is nudged to fit its period: asked again, it is nudged again alike)
    output = {"fps": float(req.fps if req.fps is not None else params["fps"]), "chunk": int(params["chunk"]),
              "formats": list(formats)}
    if "focus" in orig.get("output", {}):
        output["focus"] = orig["output"]["focus"]
    doc["output"] = output
    st = setup.settings
    orig_jiggle = orig.get("jiggle", {}) if isinstance(orig.get("jiggle"), dict) else {}
    jiggle = {k: v for k, v in orig_jiggle.items() if k not in ("muscles", "strength", "goal_rate")}
    jiggle["substeps"] = int(st.substeps)
    if st.goal_rate is not None:
        jiggle["goal_rate"] = float(st.goal_rate)
    jiggle.update({"gravity": bool(st.gravity), "preroll": float(st.preroll), "blend": _blend_value(st.blend),
                   "cut_ratio": float(st.cut_ratio), "cut_jump": float(st.cut_jump)})
    jiggle["collisions"] = bool(st.collisions)      # always: the default (on) is not every bake's
    if st.colliders != "bone" or "colliders" in jiggle:
        jiggle["colliders"] = st.colliders
    if st.muscle_collisions or "muscle_collisions" in jiggle:
        jiggle["muscle_collisions"] = bool(st.muscle_collisions)
    tables = {n: dict(t) for n, t in (orig_jiggle.get("muscles") or {}).items() if isinstance(t, dict)}
    # the values the sliders set: with activation on, the springs before the working muscles' stiffening
    jiggles = setup.relaxed_jiggles or setup.jiggles
    by_name = {j.name: j for j in jiggles}
    if st.strength is not None:             # the bake's global strength (scene or --jiggle): over every muscle's
        if any("strength" in knobs for knobs in tuning.muscles.values()):
            for j in jiggles:               # one tuned: each muscle's own, since a global one would override it
                tables.setdefault(j.name, {})["strength"] = float(j.strength)
        else:
            jiggle["strength"] = float(st.strength)
    for name, knobs in tuning.muscles.items():
        j, t = by_name[name], tables.setdefault(name, {})
        for knob, key, attr in (("strength", "strength", "strength"), ("frequency", "frequency", "frequency_hz"),
                                ("damping", "damping", "damping_ratio")):
            if knob in knobs:
                t[key] = float(getattr(j, attr))
        if "goal_scale" in knobs:
            for k in ("goal_tendon", "goal_belly"):
                t.pop(k, None)
            t["goal"] = _goal_value(j.goal)
    for j in jiggles:
        if j.blend is None and "blend" in tables.get(j.name, {}):
            del tables[j.name]["blend"]     # the bake's --blend (or the tuned one) replaced the muscle's own
    tables = {n: t for n, t in tables.items() if t}
    if tables:
        jiggle["muscles"] = tables
    doc["jiggle"] = jiggle
    chains = _chains_doc(orig, params, setup)
    if chains:
        doc["chains"] = chains
    # a request without --start/--end/--frames (a looping bake's: its period is measured to the clip's end) gives
    # the scene's own times; one with them the arguments that cut the scene's clip alike
    uncut = req.start is None and req.end is None and req.frames is None
    return doc, ([] if uncut else output_args(params, setup.times)) + extra


def _chains_doc(orig: dict, params: dict, setup) -> dict:
    """The scene's [chains]: the bake's scene's own tables, `swing` the bake's mode (other than "auto"), and per chain
    the values the bake's user set and the tuned ones (by exact name: over any glob table)."""
    doc = {k: (dict(v) if isinstance(v, dict) else v) for k, v in (orig.get("chains") or {}).items()} \
        if isinstance(orig.get("chains"), dict) else {}
    mode = (params.get("chains") or {}).get("mode") or "auto"
    if mode != "auto":
        doc["swing"] = mode
    ch = setup.chains
    if ch is not None:
        for name, p in zip(ch.chains.names, ch.params):
            if p.given:
                table = doc.setdefault(name, {})
                table.update({k: _chain_value(getattr(p, k)) for k in p.given})
    return doc


def save_tuned_scene(tuner, tuning, path: str, formats=("npz", "usdc"), source: str = "") -> list[str]:
    """Write the tuned scene to `path` (atomically) and read it back as `jiggle bake` will: an InputError (and
    no file) when it does not load or would not give the tuned jiggle (check_scene); return the extra
    `jiggle bake` arguments (see output_args)."""
    doc, args = tuned_scene(tuner, tuning, formats)
    cmd = " ".join(["jiggle bake", os.path.basename(path), *args, "--out", "OUT"])
    header = (f"Written by `jiggle view`{' from the bake in ' + source if source else ''}, with the values tuned "
              f"there.\nBake it (the frames the viewer showed, exactly): {cmd}")
    text = toml_text(doc, header)
    folder = os.path.dirname(os.path.abspath(path))
    os.makedirs(folder, exist_ok=True)
    with atomic_path(path) as tmp:
        with open(tmp, "w", encoding="utf-8") as fh:
            fh.write(text)
    try:
        check_scene(path, tuner, tuner.tuned_setup(tuning))
    except Exception:
        os.remove(path)
        raise
    return args
