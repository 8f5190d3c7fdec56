"""Re-simulating a bake with other jiggle values, fast enough to follow a slider.

A bake's setup is rebuilt once from its bake.json (`request_from_params` -> sim.bake.setup.prepare), and
checked: the rebuilt parameter set must hash to the bake's key, and its static muscle shapes must equal
the bake's. What no slider changes is then kept: the fitted rig and bound skin, and per chunk of the bake
the drive's joint transforms, the static shapes and the goal track. A `Tuning` (per-muscle strength,
frequency, damping ratio, goal weight scale; the global blend) re-runs only the particles, the blend and
the final skin (`Tuner.run`), chunk by chunk over the bake's own chunks, with the arithmetic of
sim.bake.baker.Baker.chunk: the result equals, bit for bit, `jiggle bake` of the same values (the
scene `scene_file.tuned_scene` writes; tests/app/test_view.py checks it).
"""
from __future__ import annotations

import hashlib
import math
import os
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from types import MappingProxyType
from typing import Callable, Mapping

import numpy as np

from jiggle.rig.base.errors import InputError
from jiggle.rig.skin.muscle_skin import skin_frames
from jiggle.sim.bake.baker import MARGIN, Baker, chunk_frames, num_chunks
from jiggle.sim.bake.setup import BakeRequest, BakeSetup, prepare
from jiggle.sim.jiggle.blend import blend, blend_weights, needs_simulation
from jiggle.sim.jiggle.params import BlendCurve, MuscleJiggle
from jiggle.sim.jiggle.particles import muscle_model
from jiggle.sim.jiggle.simulate import TIME_EPS, goals, simulate
from jiggle.sim.jiggle.solver import ParticleSolver

KNOBS = ("strength", "frequency", "damping", "goal_scale")
"""What a slider sets per muscle: jiggle strength J in [0, 1], the goal springs' frequency (Hz) and damping
ratio, and a factor on every goal weight of the muscle (the result clipped to [0, 1])."""


class NotTunable(Exception):
    """The bake's setup cannot be rebuilt exactly (the reason is the message); it still plays."""


@dataclass(frozen=True)
class Tuning:
    """The sliders' values over a bake's own.

    muscles : muscle name -> {knob: value} (keys of KNOBS); a muscle or knob not given keeps the bake's.
    blend : the global static_dyn_blend for every muscle (as `jiggle bake --blend`: every muscle's own
        curve is dropped), or None for the bake's curves.
    """

    muscles: Mapping[str, Mapping[str, float]] = field(default_factory=lambda: MappingProxyType({}))
    blend: float | None = None

    def with_muscle(self, name: str, **values) -> "Tuning":
        mine = {**self.muscles.get(name, {}), **values}
        return replace(self, muscles=MappingProxyType({**self.muscles, name: MappingProxyType(mine)}))

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
    character, template, output times, drive, skinning, jiggle settings); NotTunable when a file it
    read is gone or changed, or the bake predates a field."""
    try:
        settings = params["settings"]
        scene = params.get("scene")
        scene_path = _same_file(scene, "scene", "path") if scene else None
        common = dict(fps=float(params["fps"]), start=float(params["start_s"]), end=float(params["end_s"]),
                      frames=int(params["frames"]), substeps=int(settings["substeps"]),
                      gravity=bool(settings["gravity"]), preroll=float(settings["preroll"]),
                      collisions=bool(settings.get("collisions", False)),
                      colliders=settings.get("colliders", "bone"),
                      muscle_collisions=bool(settings.get("muscle_collisions", False)),
                      jiggle=None if settings.get("strength") is None else float(settings["strength"]),
                      skinning=params["skinning"]["deformer"], method=params["skinning"]["method"],
                      mush=params["skinning"]["mush"], chunk=int(params["chunk"]), formats=("npz",))
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
                           chain_params=chain_params, **common)
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
        req = request_from_params(params)
        t = time.perf_counter()
        rigs: dict = {}
        try:
            setup = prepare(req, log, rigs)
        except InputError as e:
            raise NotTunable(f"the setup does not rebuild: {e}") from None
        if setup.key != summary.get("key"):
            changed = params_diff(params, setup.params) or ["key"]
            raise NotTunable(f"the rebuilt setup differs from the bake in {', '.join(changed[:6])}")
        self.request, self.setup = req, setup
        self.fitted = next(iter(rigs.values()), None)
        """sim.bake.setup.FittedRig (character, musculature, skin), None for a built-in scene."""
        self.prepare_s = time.perf_counter() - t
        t = time.perf_counter()
        self.chunks = [self._chunk(c) for c in range(num_chunks(setup))]
        self.cache_s = time.perf_counter() - t
        static = np.concatenate([c.static for c in self.chunks]).astype(np.float32)
        if static_cvs is not None and (static.shape != static_cvs.shape or
                                       not np.array_equal(static, static_cvs)):
            err = float(np.max(np.abs(static - static_cvs))) if static.shape == static_cvs.shape else math.inf
            raise NotTunable(f"the rebuilt static muscles differ from the bake's (by {err:.3g} m): the clip was read "
                             "with options bake.json does not keep (--skeleton, --scale, --tpose, a joint map?)")
        self._lock = threading.Lock()

    @property
    def jiggles(self) -> tuple:
        return self.setup.jiggles

    def default_jiggles(self) -> list[MuscleJiggle]:
        """Each muscle's jiggle before the scene's tables and the global strength: the template's (or the
        kind's), what a scene's [jiggle.muscles] tables are written against."""
        from jiggle.sim.jiggle.params import default_jiggles
        if self.fitted is not None:
            mus = self.fitted.musculature
            return default_jiggles(mus.rig, [m.spec.jiggle for m in mus.muscles])
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
        static = rig.static(world_k, device=s.settings.device)
        track = goals(rig, kt, static.cvs, s.settings)
        return _Chunk(f0, f1, a, static.cvs[at], static.curve[at], world_k[at], track)

    def tuned_setup(self, tuning: Tuning) -> BakeSetup:
        """The setup with `tuning` applied to its jiggles and settings (its params and key stay the bake's)."""
        s = self.setup
        jiggles, settings = apply_tuning(s.jiggles, s.settings, tuning)
        return replace(s, jiggles=tuple(jiggles), settings=settings)

    def run(self, tuning: Tuning) -> Motion:
        """The clip re-simulated with `tuning`: particles, blend and final skin, chunk after chunk (the
        skin of chunk c finished in a worker thread while chunk c + 1 simulates, as the bake does)."""
        with self._lock:
            t = time.perf_counter()
            s = self.tuned_setup(tuning)
            T, N, V = len(s.times), len(s.rig.rest_cvs), s.character.num_vertices
            cvs_out = np.empty((T, N, 3), np.float32)
            skin_out = np.empty((T, V, 3), np.float32)
            if getattr(s.settings, "collisions", False):
                self._run_baker(s, cvs_out, skin_out)
            else:
                self._run_cached(s, cvs_out, skin_out)
            if not np.isfinite(skin_out).all():
                raise InputError("these values make the skin blow up (not finite); try a softer setting",
                                 field="tuning")
            return Motion(cvs_out, skin_out, time.perf_counter() - t)

    def _run_cached(self, s: BakeSetup, cvs_out, skin_out) -> None:
        """Baker.chunk's arithmetic over the cached static shapes and goal tracks (no collisions). The final
        skin is posed alone (the static one is the bake's): skin_frames poses each set on its own, unless the
        skin masks or spreads the jiggle against the static set (the RBF skin), which then goes along."""
        alone = getattr(s.skin, "jiggle_mask", None) is None and getattr(s.skin, "jiggle_spread", None) is None
        weights = blend_weights(s.jiggles, s.settings, s.times)
        model = solver = None
        if needs_simulation(weights):
            model = muscle_model(s.rig, list(s.jiggles), s.settings.device, gravity=s.settings.gravity)
            solver = ParticleSolver(model)
        state = None
        with ThreadPoolExecutor(max_workers=1, thread_name_prefix="jiggle-view") as pool:
            pending = None
            for c, ch in enumerate(self.chunks):
                if model is None:
                    dyn = ch.static
                else:
                    dyn, state = simulate(model, ch.track, s.times[ch.a:ch.f1], s.settings, solver=solver,
                                          preroll=None if c == 0 else 0.0, start=state if c > 0 else None)
                    dyn = dyn[1:] if c > 0 else dyn
                cvs = blend(ch.static, dyn, weights[ch.f0:ch.f1])
                cvs_out[ch.f0:ch.f1] = cvs
                finish = skin_frames(s.skin, ch.world, (cvs,) if alone else (ch.static, cvs), ch.curve,
                                     np.arange(ch.f0, ch.f1), defer=True)

                def done(finish=finish, ch=ch):
                    skin_out[ch.f0:ch.f1] = finish()[-1]
                if pending is not None:
                    pending.result()
                pending = pool.submit(done)
            if pending is not None:
                pending.result()

    def _run_baker(self, s: BakeSetup, cvs_out, skin_out) -> None:
        """sim.bake.baker.Baker's own chunks (drive and static shapes again: what the cache leaves out, such
        as the colliders of a bake with collisions, is then the bake's by construction)."""
        baker = Baker(s, defer=True)
        state = None
        with ThreadPoolExecutor(max_workers=1, thread_name_prefix="jiggle-view") as pool:
            pending = None
            for c in range(num_chunks(s)):
                arrays = baker.chunk(c, state)
                state = (arrays["state_x"], arrays["state_v"]) if "state_x" in arrays else None
                f0, f1 = (int(x) for x in arrays["frames"])
                cvs_out[f0:f1] = arrays["cvs_dynamic"]

                finish = arrays.pop("finish")

                def done(finish=finish, f0=f0, f1=f1):
                    skin_out[f0:f1] = finish()["skin_final"]
                if pending is not None:
                    pending.result()            # before chunk c + 2 reuses chunk c's skin buffers
                pending = pool.submit(done)
            if pending is not None:
                pending.result()
