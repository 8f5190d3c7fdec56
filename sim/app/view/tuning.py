"""Re-simulating a bake with other jiggle values, fast enough to follow a slider.

A bake's setup is rebuilt once from its bake.json (`request_from_params` -> sim.bake.setup.prepare), and
checked: the rebuilt parameter set must hash to the bake's key, and its static muscle shapes must equal
the bake's. What no slider changes is then kept: the fitted rig and bound skin, and per chunk of the bake
the drive's joint transforms, the static shapes and the goal track. A `Tuning` (per-muscle strength,
frequency, damping ratio, goal weight scale; the global blend; per-chain stiffness, damping, gravity, drag)
re-runs only the particles, the blend and the final skin (`Tuner.run`), chunk by chunk over the bake's own
chunks, with the arithmetic of sim.bake.baker.Baker.chunk (a looping bake's first chunk going on from the
cycle's steady state, as the bake's): the result equals, bit for bit, `jiggle bake` of the same values (the
scene `scene_file.tuned_scene` writes; tests/app/test_view.py and test_view_chains.py check it).

Chains (sim.chain). A chain knob is applied as `jiggle bake --chain-KNOB NAME=V` applies it: the chain setup is
made again (sim.chain.build.make) from the bake's own per-chain values (the ones the user set, by exact name)
with the tuned values after them, so the model's step (set by the fastest stiffness) and its springs are the
bake's arithmetic. The chains swing once per chain setup (cached, a few kept): a tuning that changes no chain
value reuses the bake's own swing, and the chains' share of the skin is added to each chunk's final skin as
Baker.chunk's finish adds it.
"""
from __future__ import annotations

import hashlib
import math
import os
import threading
import time
from collections import OrderedDict
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from types import MappingProxyType, SimpleNamespace
from typing import Callable, Mapping

import numpy as np

from jiggle.rig.base.errors import InputError
from jiggle.rig.skin.muscle_skin import skin_frames
from jiggle.sim.bake.baker import MARGIN, Baker, chunk_frames, num_chunks
from jiggle.sim.bake.setup import BakeRequest, BakeSetup, prepare
from jiggle.sim.jiggle.blend import blend, blend_weights, needs_simulation
from jiggle.sim.jiggle.keyed_solver import make_solver
from jiggle.sim.jiggle.params import BlendCurve, MuscleJiggle
from jiggle.sim.jiggle.particles import muscle_model
from jiggle.sim.jiggle.simulate import TIME_EPS, goals, simulate

KNOBS = ("strength", "frequency", "damping", "goal_scale")
"""What a slider sets per muscle: jiggle strength J in [0, 1], the goal springs' frequency (Hz) and damping
ratio, and a factor on every goal weight of the muscle (the result clipped to [0, 1])."""
CHAIN_KNOBS = ("stiffness", "damping", "gravity", "drag")
"""What a slider sets per chain (sim.chain.params.CHAIN_PARAMETERS): the swing frequency of its root (Hz), the damping
ratio of its springs, the share of g it feels, and the air density times this on its links."""
CHAIN_CACHE = 4
"""Chain setups (and their swings) a Tuner keeps besides the bake's own: the last few slider positions."""


class NotTunable(Exception):
    """The bake's setup cannot be rebuilt exactly (the reason is the message); it still plays."""


@dataclass(frozen=True)
class Tuning:
    """The sliders' values over a bake's own.

    muscles : muscle name -> {knob: value} (keys of KNOBS); a muscle or knob not given keeps the bake's.
    blend : the global static_dyn_blend for every muscle (as `jiggle bake --blend`: every muscle's own
        curve is dropped), or None for the bake's curves.
    chains : chain name (its root joint's) -> {knob: value} (keys of CHAIN_KNOBS), as `jiggle bake --chain-KNOB
        NAME=VALUE`; a chain or knob not given keeps the bake's.
    """

    muscles: Mapping[str, Mapping[str, float]] = field(default_factory=lambda: MappingProxyType({}))
    blend: float | None = None
    chains: Mapping[str, Mapping[str, float]] = field(default_factory=lambda: MappingProxyType({}))

    def with_muscle(self, name: str, **values) -> "Tuning":
        mine = {**self.muscles.get(name, {}), **values}
        return replace(self, muscles=MappingProxyType({**self.muscles, name: MappingProxyType(mine)}))

    def with_chain(self, name: str, **values) -> "Tuning":
        mine = {**self.chains.get(name, {}), **values}
        return replace(self, chains=MappingProxyType({**self.chains, name: MappingProxyType(mine)}))

    def with_blend(self, value: float | None) -> "Tuning":
        return replace(self, blend=value)


def apply_tuning(jiggles, settings, tuning: Tuning):
    """(jiggles, settings) with `tuning` applied to the bake's (sim.jiggle.params MuscleJiggle list and
    JiggleSettings); InputError for an unknown muscle or knob, or a value out of range."""
    names = [j.name for j in jiggles]
    unknown = sorted(set(tuning.muscles) - set(names))
    if unknown:
        raise InputError(f"no muscle {', '.join(map(repr, unknown))} in this bake", field="muscle")
    out = []
    for j in jiggles:
        values = tuning.muscles.get(j.name, {})
        bad = sorted(set(values) - set(KNOBS))
        if bad:
            raise InputError(f"unknown knob {', '.join(bad)}; expected {', '.join(KNOBS)}", field=j.name)
        kw = {}
        if "strength" in values:
            kw["strength"] = float(values["strength"])
        if "frequency" in values:
            kw["frequency_hz"] = float(values["frequency"])
        if "damping" in values:
            kw["damping_ratio"] = float(values["damping"])
        if "goal_scale" in values:
            s = float(values["goal_scale"])
            if not (math.isfinite(s) and s >= 0):
                raise InputError(f"goal weight scale must be >= 0, got {s:g}", field=f"{j.name}.goal_scale")
            kw["goal"] = np.clip(j.goal * s, 0.0, 1.0)
        out.append(replace(j, **kw) if kw else j)
    if tuning.blend is not None:
        b = float(tuning.blend)
        if not 0.0 <= b <= 1.0:
            raise InputError(f"blend must be in [0, 1], got {b:g}", field="blend")
        settings = replace(settings, blend=BlendCurve.constant(b))
        out = [replace(j, blend=None) for j in out]
    return out, settings


def chain_entries(chains, tuning: Tuning) -> list:
    """The per-chain parameter entries (sim.chain.params.chain_params) that give the chains of `chains` (a bake's
    sim.chain.build.ChainSetup or None) their bake values with `tuning`'s over them: each chain's values the user set
    (by exact name, as the bake resolved them), then the tuned ones. InputError for an unknown chain or knob, for a
    knob the bake keys over time (a slider sets a constant: edit the keys in the scene), or a value out of range."""
    from jiggle.sim.chain.params import check_value
    names = list(chains.chains.names) if chains is not None else []
    unknown = sorted(set(tuning.chains) - set(names))
    if unknown:
        raise InputError(f"no chain {', '.join(map(repr, unknown))} in this bake", field="chain")
    entries = []
    for name, p in zip(names, chains.params if chains is not None else ()):
        if p.given:
            entries.append((name, {k: getattr(p, k) for k in p.given}, f"the bake's {name}"))
    for name, values in tuning.chains.items():
        bad = sorted(set(values) - set(CHAIN_KNOBS))
        if bad:
            raise InputError(f"unknown chain knob {', '.join(bad)}; expected {', '.join(CHAIN_KNOBS)}", field=name)
        p = chains.params[names.index(name)]
        keyed = [k for k in values if k in p.keyed()]
        if keyed:
            raise InputError(f"the bake keys {', '.join(keyed)} of chain {name!r} over time; a slider sets a constant: "
                             "edit the keys in the scene", field=f"{name}.{keyed[0]}")
        table = {k: check_value(k, float(v), f"{name}.{k}") for k, v in values.items()}
        if table:
            entries.append((name, table, f"tuned {name}"))
    return entries


# ---------------------------------------------------------------------------------------- rebuilding
def _digest(path: str) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _same_file(entry, what: str, key: str = "file") -> str | None:
    """The path of a {"file" (or `key`), "sha256"} entry of bake.json, checked unchanged; NotTunable
    otherwise."""
    if not isinstance(entry, dict) or not entry.get(key):
        return None
    path = entry[key]
    if not os.path.isfile(path):
        raise NotTunable(f"the {what} {path} is gone")
    if entry.get("sha256") and _digest(path) != entry["sha256"]:
        raise NotTunable(f"the {what} {path} changed since the bake")
    return path


def request_from_params(params: dict) -> BakeRequest:
    """The BakeRequest that rebuilds the bake whose bake.json "params" is `params` (scene, clip,
    character, template, output times, drive, skinning, jiggle settings, chains); NotTunable when a file it
    read is gone or changed, or the bake predates a field. A glTF clip's animation is params["clip"]["animation"]
    where bake.json records it, else the file's first (request_candidates tries the others)."""
    return next(request_candidates(params))


def _gltf_animations(path: str) -> list:
    """The animations of a glTF file, each as load_clip's `animation` argument: its name where that names it alone,
    else its index."""
    from jiggle.rig.motion.gltf_io import GltfDocument
    names = [a.name for a in GltfDocument(path).gltf.animations]
    return [n if n and names.count(n) == 1 else k for k, n in enumerate(names)]


def request_candidates(params: dict):
    """The BakeRequests that may have made the bake whose bake.json "params" is `params`, most likely first
    (request_from_params's first). A bake.json that does not record which animation of a glTF clip it baked
    (`--animation`; older bakes) gives one request per animation of the file whose duration is the bake's clip's,
    the first animation first: the caller keeps the one whose rebuilt key is the bake's."""
    loop = params.get("loop") if isinstance(params.get("loop"), dict) else {}
    looped = bool(loop.get("on"))
    # a looping bake writes one whole period (an open cycle's without its end) unless cut with --frames or --end
    period = (loop.get("cycle_frames") or 0) + (1 if loop.get("repeats_first") else 0)
    whole = looped and params.get("frames") == period
    for req in _animations(params, _request(params, cut=not whole)):
        yield req
        if looped:                                  # the other reading of the output times
            yield replace(req, start=float(params["start_s"]), end=float(params["end_s"]),
                          frames=int(params["frames"])) if whole else \
                replace(req, start=None, end=None, frames=None)


def _animations(params: dict, req: BakeRequest):
    """`req` once per animation of its glTF clip that may be the bake's (request_candidates)."""
    clip = req.clip
    recorded = isinstance(params.get("clip"), dict) and params["clip"].get("animation") is not None
    if recorded or clip is None or not str(clip).lower().endswith((".glb", ".gltf")):
        yield req
        return
    import warnings

    from jiggle.rig.motion.mocap import load_clip
    try:
        duration = float(params["clip"]["duration_s"])
        animations = _gltf_animations(clip)
    except Exception:  # noqa: BLE001 - unreadable here: prepare says why
        yield req
        return
    if len(animations) < 2:
        yield req
        return
    found = False
    for k, anim in enumerate(animations):
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                d = load_clip(clip, animation=anim).duration
        except Exception:  # noqa: BLE001 - an animation that does not read is not the bake's
            continue
        if d == duration:
            found = True
            yield req if k == 0 else replace(req, animation=anim)
    if not found:
        yield req


def _request(params: dict, cut: bool = True) -> BakeRequest:
    """request_from_params without the search for a glTF clip's animation (see there). cut : the output times
    as --start, --end and --frames (False: none, the clip's or the loop's own: a looping bake's period is measured
    to the end given, so an --end equal to the last frame's time is not the bake's)."""
    try:
        settings = params["settings"]
        scene = params.get("scene")
        scene_path = _same_file(scene, "scene", "path") if scene else None
        loop = params.get("loop") if isinstance(params.get("loop"), dict) else {}
        fps = float(loop["fps_asked"]) if loop.get("on") and loop.get("fps_asked") else float(params["fps"])
        common = dict(fps=fps, start=float(params["start_s"]) if cut else None,
                      end=float(params["end_s"]) if cut else None, frames=int(params["frames"]) if cut else None,
                      loop=loop.get("mode") if loop.get("mode") not in (None, "auto") else None,
                      substeps=int(settings["substeps"]),
                      gravity=bool(settings["gravity"]), preroll=float(settings["preroll"]),
                      collisions=bool(settings.get("collisions", False)),
                      colliders=settings.get("colliders", "bone"),
                      muscle_collisions=bool(settings.get("muscle_collisions", False)),
                      jiggle=None if settings.get("strength") is None else float(settings["strength"]),
                      skinning=params["skinning"]["deformer"], method=params["skinning"]["method"],
                      mush=params["skinning"]["mush"], chunk=int(params["chunk"]), formats=("npz",),
                      activation="on" if (params.get("activation") or {}).get("on") else "off")
        curve = settings["blend"]
        if len(curve["times"]) == 1 and all(m.get("blend") is None for m in params["muscles"].values()):
            common["blend"] = float(curve["values"][0])     # --blend (or a constant with no muscle's own)
        if scene and scene.get("builtin"):
            return BakeRequest(scene=scene_path, **common)
        from jiggle.sim.bake.scene import load_scene
        spec = load_scene(scene_path) if scene_path else None
        clip_entry = params["clip"]
        clip = clip_entry.get("file")
        scene_clip = None
        if spec is not None and spec.clip is not None:
            scene_clip = spec.clip.source or spec.path
        if clip and scene_clip and os.path.abspath(clip) == os.path.abspath(scene_clip):
            clip = None                                     # the scene's own [motion]
        elif clip:
            clip = _same_file(clip_entry, "clip")
        animation = clip_entry.get("animation") if clip else None
        character = params["character"]
        char_file = _same_file(character, "character") if "file" in character else None
        if char_file and spec is not None and spec.character.file and \
                os.path.abspath(spec.character.file) == char_file:
            char_file = None
        body = MappingProxyType(dict(character["generated"])) if "generated" in character else \
            MappingProxyType({})
        template = params.get("template")
        if isinstance(template, dict):
            template = _same_file(template, "template")
        rigid = (params.get("rigid") or {}).get("option")
        chains = params.get("chains") or {}
        # the chains' parameters the user set (by exact name: a glob's are recorded per chain), as they were
        chain_params = tuple((c["chain"], {k: c[k] for k in c.get("set_by_user") or ()}, f"bake.json {c['chain']}")
                             for c in chains.get("chains") or () if c.get("set_by_user"))
        return BakeRequest(scene=scene_path, clip=clip, character=char_file, template=template, body=body,
                           drive=params["drive"], influences=params["skinning"]["influences"],
                           rigid=None if rigid in (None, "auto") else rigid,
                           chains=chains.get("mode") if chains.get("mode") not in (None, "auto") else None,
                           chain_params=chain_params, animation=animation, **common)
    except (KeyError, TypeError, ValueError, AttributeError) as e:
        raise NotTunable(f"bake.json lacks what a rebuild needs ({type(e).__name__}: {e})") from None


def params_diff(a, b, prefix="") -> list[str]:
    """Dotted keys whose values differ between two parameter dicts."""
    if isinstance(a, dict) and isinstance(b, dict):
        out = []
        for k in sorted(set(a) | set(b)):
            out += params_diff(a.get(k), b.get(k), f"{prefix}{k}.")
        return out
    return [] if a == b else [prefix.rstrip(".")]


@dataclass(eq=False)
class _Chunk:
    """What no slider changes in one chunk of the bake: its frames, the static CVs, action curves and
    joint transforms at its output frames, and its goal track."""

    f0: int
    f1: int
    a: int
    static: np.ndarray
    curve: np.ndarray
    world: np.ndarray
    track: object


@dataclass(frozen=True, eq=False)
class Motion:
    """A re-simulated clip. cvs_dynamic : (T, N, 3) float32 metres, the blended CVs; skin_final :
    (T, V, 3) float32 metres; seconds : the time the run took."""

    cvs_dynamic: np.ndarray
    skin_final: np.ndarray
    seconds: float


class Tuner:
    """A bake's setup rebuilt and its unchanging parts cached (see the module).

    summary : the bake's bake.json. static_cvs : (T, N, 3) float32, the bake's muscle_cvs_static, checked
    against the rebuilt static shapes (None skips the check). log : progress lines.
    """

    def __init__(self, summary: dict, static_cvs: np.ndarray | None = None,
                 log: Callable[[str], None] = lambda s: None):
        params = summary.get("params") if isinstance(summary, dict) else None
        if not isinstance(params, dict):
            raise NotTunable("bake.json has no parameters")
        # a slider sets one number per muscle; keys over time are edited in the scene (or on the command line)
        muscles = params.get("muscles") if isinstance(params.get("muscles"), dict) else {}
        keyed = sorted(name for name, m in muscles.items() if isinstance(m, dict) and any(
            isinstance(m.get(k), dict) for k in ("strength", "frequency", "damping", "goal_scale")))
        if keyed:
            raise NotTunable(f"this bake keys jiggle parameters over time ({', '.join(keyed[:4])}"
                             f"{' ...' if len(keyed) > 4 else ''}); the sliders set constants: edit the keys in "
                             "the scene, or tune a bake without keys")
        t = time.perf_counter()
        rigs: dict = {}
        why = None
        for req in request_candidates(params):        # one, unless bake.json does not say which animation
            try:
                setup = prepare(req, log, rigs)
            except InputError as e:
                why = why or f"the setup does not rebuild: {e}"
                continue
            if setup.key != summary.get("key"):
                changed = params_diff(params, setup.params) or ["key"]
                why = why or f"the rebuilt setup differs from the bake in {', '.join(changed[:6])}"
                continue
            self.request, self.setup = req, setup
            t_cache = time.perf_counter()
            self.chunks = [self._chunk(c) for c in range(num_chunks(setup))]
            self.cache_s = time.perf_counter() - t_cache
            static = np.concatenate([c.static for c in self.chunks]).astype(np.float32)
            if static_cvs is not None and (static.shape != static_cvs.shape or
                                           not np.array_equal(static, static_cvs)):
                err = float(np.max(np.abs(static - static_cvs))) if static.shape == static_cvs.shape else math.inf
                why = why or (f"the rebuilt static muscles differ from the bake's (by {err:.3g} m): the clip was read "
                              "with options bake.json does not keep (--skeleton, --scale, --tpose, a joint map?)")
                continue
            break
        else:
            raise NotTunable(why or "bake.json lacks what a rebuild needs")
        self.fitted = next(iter(rigs.values()), None)
        """sim.bake.setup.FittedRig (character, musculature, skin), None for a built-in scene."""
        self.prepare_s = time.perf_counter() - t - self.cache_s
        self._chain_lock = threading.RLock()
        self._chain_setups: OrderedDict = OrderedDict()
        """chain values (chain_key) -> ChainSetup, the last CHAIN_CACHE tuned ones."""
        self._chain_swings: dict = {}
        """id of a ChainSetup -> (it, its swing: SimpleNamespace of Baker._swing_chains' attributes)."""
        self._lock = threading.Lock()

    @property
    def jiggles(self) -> tuple:
        """The bake's jiggles as the sliders set them (with activation on: before the working muscles' stiffening,
        which every run applies again over the tuned values, as `jiggle bake` does)."""
        return self.setup.relaxed_jiggles or self.setup.jiggles

    def default_jiggles(self) -> list[MuscleJiggle]:
        """Each muscle's jiggle before the scene's tables and the global strength: the template's (or the
        kind's; what it leaves to its material, from the material at the bake's real size), what a scene's [jiggle.muscles] tables are written against. The generic template's springs are
        held under the limit by the bake itself (sim.bake.setup.prepare), before the scene's tables, and a scene's bake
        holds them alike: its base is the bake's own jiggle (a table's values applied again on it give the same)."""
        from jiggle.rig.muscle.generic import GENERIC
        from jiggle.sim.jiggle.materials import default_jiggles
        if self.fitted is not None:
            mus = self.fitted.musculature
            if getattr(mus.template, "name", None) == GENERIC:
                return list(self.jiggles)
            return default_jiggles(mus.rig, [m.spec.jiggle for m in mus.muscles],
                                   scale=getattr(self.setup, "real_scale", 1.0) or 1.0)
        return default_jiggles(self.setup.rig)

    def _chunk(self, c: int) -> _Chunk:
        """Chunk c's unchanging arrays, as sim.bake.baker.Baker.chunk computes them."""
        s, rig = self.setup, self.setup.rig
        f0, f1 = chunk_frames(s, c)
        a = max(f0 - 1, 0)
        times = s.times
        ka = max(0, int(np.searchsorted(s.knots, times[a] - TIME_EPS)) - MARGIN)
        kb = min(len(s.knots), int(np.searchsorted(s.knots, times[f1 - 1] + TIME_EPS, side="right")) + MARGIN)
        kt = s.knots[ka:kb]
        at = np.searchsorted(kt, times[f0:f1] - TIME_EPS)
        world_k = np.asarray(s.world_at(kt), dtype=np.float64)
        static = s.static_at(kt, world_k)
        track = goals(rig, kt, static.cvs, s.settings)
        return _Chunk(f0, f1, a, static.cvs[at], static.curve[at], world_k[at], track)

    def tuned_setup(self, tuning: Tuning) -> BakeSetup:
        """The setup with `tuning` applied to its jiggles, settings and chains (its params and key stay the bake's)."""
        s = self.setup
        jiggles, settings = apply_tuning(self.jiggles, s.settings, tuning)
        relaxed = None
        if s.activation is not None:
            from jiggle.sim.jiggle.activation import stiffened
            relaxed = tuple(jiggles)
            jiggles, _ = stiffened(jiggles, s.rig, s.activation, s.times, scale=s.real_scale)
        return replace(s, jiggles=tuple(jiggles), relaxed_jiggles=relaxed, settings=settings,
                       chains=self.tuned_chains(tuning))

    # ------------------------------------------------------------------------------------ chains
    @staticmethod
    def _chain_key(params) -> str:
        from jiggle.sim.jiggle.keyed import jsonable_value
        return repr([[jsonable_value(getattr(p, k)) for k in CHAIN_KNOBS] for p in params])

    def tuned_chains(self, tuning: Tuning):
        """The bake's chain setup (sim.chain.build.ChainSetup, None without chains) with `tuning`'s chain values: the
        bake's own object when they change no chain's parameters, else one made as `jiggle bake --chain-KNOB
        NAME=V` makes it (cached: the last CHAIN_CACHE)."""
        ch = self.setup.chains
        if ch is None:
            if tuning.chains:
                raise InputError(f"no chain {', '.join(map(repr, sorted(tuning.chains)))} in this bake: it swings "
                                 "none", field="chain")
            return None
        if not tuning.chains:
            return ch
        from jiggle.sim.chain.build import make
        from jiggle.sim.chain.params import chain_params
        entries = chain_entries(ch, tuning)
        c = self.setup.character
        size = float(np.ptp(np.asarray(c.vertices), axis=0).max())
        params = chain_params(ch.chains.names, ch.links.length, size, entries, [x.spring for x in ch.chains.chains])
        key = self._chain_key(params)
        if key == self._chain_key(ch.params):
            return ch                                   # the bake's values (a slider moved back)
        with self._chain_lock:
            got = self._chain_setups.get(key)
            if got is None:
                s = self.setup
                got = make(c, ch.chains, ch.model.capsules, ch.model.floor, entries, s.knots, s.world_at)
                self._chain_setups[key] = got
                while len(self._chain_setups) > CHAIN_CACHE:
                    old = self._chain_setups.popitem(last=False)[1]
                    self._chain_swings.pop(id(old), None)
            self._chain_setups.move_to_end(key)
            return got

    def chain_swing(self, s: BakeSetup):
        """The swing of `s`'s chains (s a tuned_setup; None without chains): what Baker.__init__ computes
        (Baker._swing_chains: chain_run, chain_riders, chain_joints, chain_skin, chain_report, chain_tips), once per
        chain setup."""
        if s.chains is None:
            return None
        with self._chain_lock:
            got = self._chain_swings.get(id(s.chains))
            if got is None or got[0] is not s.chains:
                holder = SimpleNamespace(setup=s)
                Baker._swing_chains(holder)             # the bake's own arithmetic on the bake's own inputs
                del holder.setup
                got = (s.chains, holder)
                self._chain_swings[id(s.chains)] = got
            return got[1]

    # ------------------------------------------------------------------------------------ runs
    def run(self, tuning: Tuning) -> Motion:
        """The clip re-simulated with `tuning`: particles, blend, chains and final skin, chunk after chunk (the
        skin of chunk c finished in a worker thread while chunk c + 1 simulates, as the bake does)."""
        with self._lock:
            t = time.perf_counter()
            s = self.tuned_setup(tuning)
            swing = self.chain_swing(s)
            T, N, V = len(s.times), len(s.rig.rest_cvs), s.character.num_vertices
            cvs_out = np.empty((T, N, 3), np.float32)
            skin_out = np.empty((T, V, 3), np.float32)
            if getattr(s.settings, "collisions", False):
                self._run_baker(s, cvs_out, skin_out, swing, tuning)
            else:
                self._run_cached(s, cvs_out, skin_out, swing, tuning)
            if not np.isfinite(skin_out).all():
                raise InputError("these values make the skin blow up (not finite); try a softer setting",
                                 field="tuning")
            return Motion(cvs_out, skin_out, time.perf_counter() - t)

    def _warm_state(self, s: BakeSetup, tuning_key, model, solver, colliders=None, tissue=None):
        """A looping bake's particle state at the cycle's start in its steady state (sim.bake.loop.warm_up, as
        sim.bake.baker.bake reaches it before chunk 0), or None for a bake that does not loop; the last one kept
        (keyed by the muscle values and the blend: a chain knob alone does not warm up again)."""
        if s.loop is None or model is None:
            return None
        from jiggle.sim.bake.loop import warm_up
        key = (tuning_key, colliders is not None)
        last = getattr(self, "_warm", None)
        if last is None or last[0] != key:
            state, _ = warm_up(s, model, solver, colliders, tissue, MARGIN)
            last = self._warm = (key, tuple(np.array(a, copy=True) for a in state))
        return tuple(np.array(a, copy=True) for a in last[1])        # the run's own: the kept one stays as it was

    @staticmethod
    def _tuning_key(tuning: Tuning):
        return (tuple(sorted((n, tuple(sorted(k.items()))) for n, k in tuning.muscles.items())), tuning.blend)

    def _run_cached(self, s: BakeSetup, cvs_out, skin_out, swing=None, tuning: Tuning | None = None) -> None:
        """Baker.chunk's arithmetic over the cached static shapes and goal tracks (no collisions). The final
        skin is posed alone (the static one is the bake's): skin_frames poses each set on its own, unless the
        skin masks or spreads the jiggle against the static set (the RBF skin), which then goes along. swing :
        chain_swing(s) (the chains' share of the final skin is added as Baker.chunk's finish adds it)."""
        from jiggle.sim.chain.simulate import chain_world
        alone = getattr(s.skin, "jiggle_mask", None) is None and getattr(s.skin, "jiggle_spread", None) is None
        weights = blend_weights(s.jiggles, s.settings, s.times)
        model = solver = None
        if needs_simulation(weights):
            model = muscle_model(s.rig, list(s.jiggles), s.settings.device, gravity=s.settings.gravity)
            solver = make_solver(model, s.jiggles)
        state = self._warm_state(s, self._tuning_key(tuning or Tuning()), model, solver)
        scale = np.float32(s.scale)
        with ThreadPoolExecutor(max_workers=1, thread_name_prefix="jiggle-view") as pool:
            pending = None
            for c, ch in enumerate(self.chunks):
                if model is None:
                    dyn = ch.static
                else:
                    given = state if c > 0 or s.loop is not None else None
                    dyn, state = simulate(model, ch.track, s.times[ch.a:ch.f1], s.settings, solver=solver,
                                          preroll=0.0 if given is not None else None, start=given)
                    dyn = dyn[1:] if c > 0 else dyn
                cvs = blend(ch.static, dyn, weights[ch.f0:ch.f1])
                cvs_out[ch.f0:ch.f1] = cvs if s.scale == 1.0 else (cvs.astype(np.float32) * scale)
                finish = skin_frames(s.skin, ch.world, (cvs,) if alone else (ch.static, cvs), ch.curve,
                                     np.arange(ch.f0, ch.f1), defer=True)
                chain = None
                if swing is not None:
                    swung = chain_world(ch.world, s.chains.model, swing.chain_run.rotations[ch.f0:ch.f1],
                                        swing.chain_riders)
                    chain = (swing.chain_skin.vertices, swing.chain_skin.delta(ch.world, swung))

                def done(finish=finish, ch=ch, chain=chain):
                    skin = finish()[-1]
                    if chain is not None:
                        skin[:, chain[0]] += chain[1]
                    skin_out[ch.f0:ch.f1] = skin if s.scale == 1.0 else (skin * scale).astype(np.float32)
                if pending is not None:
                    pending.result()
                pending = pool.submit(done)
            if pending is not None:
                pending.result()

    def _run_baker(self, s: BakeSetup, cvs_out, skin_out, swing=None, tuning: Tuning | None = None) -> None:
        """sim.bake.baker.Baker's own chunks (drive and static shapes again: what the cache leaves out, such
        as the colliders of a bake with collisions, is then the bake's by construction), a looping bake's going
        on from the warm-up's state as the bake's; the chains' swing given (chain_swing(s)) or swung here."""
        baker = _SwungBaker(s, swing) if swing is not None else Baker(s, defer=True)
        state = self._warm_state(s, self._tuning_key(tuning or Tuning()), baker.model, baker.solver,
                                 baker.colliders, baker.tissue)
        with ThreadPoolExecutor(max_workers=1, thread_name_prefix="jiggle-view") as pool:
            pending = None
            for c in range(num_chunks(s)):
                arrays = baker.chunk(c, state)
                state = (arrays["state_x"], arrays["state_v"]) if "state_x" in arrays else None
                f0, f1 = (int(x) for x in arrays["frames"])
                finish = arrays.pop("finish")

                def done(finish=finish, f0=f0, f1=f1):
                    out = finish()
                    cvs_out[f0:f1] = out["cvs_dynamic"]
                    skin_out[f0:f1] = out["skin_final"]
                if pending is not None:
                    pending.result()            # before chunk c + 2 reuses chunk c's skin buffers
                pending = pool.submit(done)
            if pending is not None:
                pending.result()


class _SwungBaker(Baker):
    """A Baker whose chains are swung already (Tuner.chain_swing): Baker.__init__ takes the swing given rather than
    swinging them again."""

    def __init__(self, setup: BakeSetup, swing):
        self._swing = swing
        super().__init__(setup, defer=True)

    def _swing_chains(self) -> None:
        for k, v in vars(self._swing).items():
            setattr(self, k, v)
