"""`jiggle bake`: a clip baked into caches, chunk by chunk, resumable.

    BakeSetup (sim.bake.setup: motion, character, muscles, skin, jiggle, output times)
      per chunk of `chunk` output frames, each stage one or a few Warp launches for the whole chunk:
        goal knots of the chunk (+ MARGIN each side) --drive (sim.drive)--> joint world transforms
          --MuscleRig.static (rig.muscle, one launch)--> static CVs
          --goals, simulate (sim.jiggle.simulate, one launch per cut-free stretch)--> dynamic CVs
          --blend (sim.jiggle.blend)--> final CVs
          --skin_frames (rig.skin.muscle_skin: LBS + shell deformers)--> skin_static, skin_final
          (+ the smooth skin alone, skin_lbs, that compare's skin quality reads against)
        -> straight into every cache (sim.bake.writer.BakeWriter, in OUT/.partial/, by a second thread
           while the next chunk is computed), then OUT/.partial/chunk_NNNNN.npz (atomic): the particles'
           state at the chunk's last frame and the caches' progress
      all chunks -> the caches completed and renamed into OUT (bake.npz, bake.usdc|usda, bake.pc2),
      bake.json; .partial removed. Memory holds a chunk or two, whatever the clip's length.

Resuming: a chunk goes on from the particle state stored with the one before it, over the same step
grid and the same goal knots (the knots of a chunk reach MARGIN knots past its ends, so the knot
velocities and cut tests inside it see the same neighbours whatever was baked before). An
interrupted bake resumed with `--resume` therefore repeats exactly the arithmetic of an unbroken one:
its caches are equal bit for bit (tests/bake/test_bake.py kills a bake to show it). The manifest stores
the parameter set's key; resuming with other parameters is refused, naming what differs.

A resumed bake reopens the caches in .partial at the last finished chunk (the npz and pc2 are filled
in place, the USD is written again from the npz: sim/bake/writer.py).

A looping bake (sim/bake/loop.py, BakeSetup.loop) first warms up: the cycle simulated until the state at its
start repeats, stored in OUT/.partial/loop.npz (a resumed bake reads it back); its first chunk goes on from that
state as any later chunk goes on from the one before, and bake.json's "loop" records the decision, the warm-up and
the seam (the jiggle offset's jump from the last frame to the first).

A folder holds either a finished bake (its caches and bake.json) or an unfinished one (.partial/):
starting a new bake removes first the files the old bake and `jiggle compare` recorded writing (bake.json's
"files", the manifest's "files", compare's record COMPARE_RECORD) and nothing else: a user's own files
in the folder stay. The caches grow under temporary names in .partial and are renamed into the
folder only once every chunk is in them, so no cache that looks complete is ever a partial one.
"""
from __future__ import annotations

import contextlib
import functools
import json
import os
import re
import shutil
import time
import warnings
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Callable

import numpy as np

from jiggle.rig.base.atomic import atomic_path
from jiggle.rig.base.errors import InputError, JiggleWarning
from jiggle.rig.skin.muscle_skin import skin_frames
from jiggle.sim.bake.setup import BakeSetup
from jiggle.sim.bake.writer import BakeWriter
from jiggle.sim.jiggle.blend import blend, blend_weights, needs_simulation
from jiggle.sim.jiggle.colliders import collider_model, contact_summary, muscle_contacts, skin_check
from jiggle.sim.jiggle.goal_track import find_cuts
from jiggle.sim.jiggle.keyed_solver import make_solver
from jiggle.sim.jiggle.params import glued
from jiggle.sim.jiggle.particles import muscle_model
from jiggle.sim.jiggle.simulate import TIME_EPS, goals, simulate
from jiggle.sim.jiggle.tissue_contacts import tissue_contact_model

PARTIAL = ".partial"
MANIFEST = "manifest.json"
MANIFEST_FORMAT = "jiggle.partial/2"
"""/2: chunk files hold the particle state and the caches' progress; the frames are in the caches (sim/bake/writer.py)."""
SUMMARY = "bake.json"
LOOP_STATE = "loop.npz"
"""In .partial: a looping bake's steady state at the cycle's start and its warm-up record (sim/bake/loop.py)."""
MARGIN = 3
"""Goal knots past each end of a chunk (>= 2: a knot velocity needs its two neighbours, a cut test
an interval's two neighbours)."""
PAUSE_ENV = "JIGGLE_BAKE_PAUSE"
"""Seconds to wait after each chunk is written (0 when unset): lets a test kill a bake between chunks."""
CACHE_NAMES = {"npz": "bake.npz", "usdc": "bake.usdc", "usda": "bake.usda", "pc2": "bake.pc2"}


SCALED_KEYS = ("skin_static", "skin_final", "skin_lbs", "cvs_static", "cvs_dynamic", "skin_pulled_m", "contact_depth")
"""A chunk's arrays that are lengths of the character (metres), written at the file's size (BakeSetup.scale)."""


def idle_muscles(setup: BakeSetup) -> np.ndarray:
    """(M,) bool: the setup's muscles that drive no skin (its skin's MuscleSkin.idle; none for a skin without it)."""
    from jiggle.sim.bake.setup import idle_of
    return idle_of(setup.skin, setup.rig.M)


def chunk_path(out_dir: str, c: int) -> str:
    return os.path.join(out_dir, PARTIAL, f"chunk_{c:05d}.npz")


def chunk_frames(setup: BakeSetup, c: int) -> tuple[int, int]:
    """Output frames [f0, f1) of chunk c."""
    return c * setup.chunk, min(len(setup.times), (c + 1) * setup.chunk)


def num_chunks(setup: BakeSetup) -> int:
    return -(-len(setup.times) // setup.chunk)


@dataclass(frozen=True)
class _ChunkSpan:
    """Where a chunk lies: its output frames [f0, f1), the frame `a` its run starts from (f0 - 1 after the first
    chunk: it goes on from the frame before it), its goal knots (K,) seconds (MARGIN past each end) and its output
    frames' places among them, `at` (F,)."""
    f0: int
    f1: int
    a: int
    knots: np.ndarray
    at: np.ndarray


def _chunk_span(setup: BakeSetup, c: int) -> _ChunkSpan:
    """Chunk c's frames and goal knots (see _ChunkSpan)."""
    f0, f1 = chunk_frames(setup, c)
    a = max(f0 - 1, 0)                       # a chunk after the first goes on from the frame before it
    times = setup.times
    ka = max(0, int(np.searchsorted(setup.knots, times[a] - TIME_EPS)) - MARGIN)
    kb = min(len(setup.knots), int(np.searchsorted(setup.knots, times[f1 - 1] + TIME_EPS, side="right")) + MARGIN)
    kt = setup.knots[ka:kb]
    at = np.searchsorted(kt, times[f0:f1] - TIME_EPS)     # the output frames among the knots
    return _ChunkSpan(f0, f1, a, kt, at)


# ---------------------------------------------------------------------------------------- chunks
def fem_tissue(setup: BakeSetup, idle: np.ndarray, colliders=None):
    """The hero mode's solid (sim.fem.tissue.FemTissue) of the setup's simulated muscles: each one's material the
    one its goal springs stand for (sim.jiggle.materials.material_of, --material's when given) at the character's
    real size (setup.real_scale), damped at its ratio across its mesh's low modes (sim.fem.modes); contacts with the
    colliders' capsules (the particles' pairs) and floor when given."""
    from jiggle.sim.fem.tissue import FemTissue, fem_parts
    from jiggle.sim.jiggle.materials import material_of
    rig, k = setup.rig, float(setup.real_scale)
    radii, lengths = rig.mean_radii(rig.rest_cvs) * k, np.asarray(rig.rest_length, np.float64) * k
    jiggles = setup.jiggles
    materials = {m: material_of(jiggles[m], rig.kinds[m], float(radii[m]), float(lengths[m]),
                                rig.rest_cvs[rig.cv_offsets[m]:rig.cv_offsets[m + 1]])
                 for m in range(rig.M) if not idle[m]}
    parts = fem_parts(rig.rest_cvs, rig.cv_offsets, rig.names, materials, k)
    kw = {}
    if colliders is not None:
        kw = {"pairs": (colliders.pair_offsets, colliders.pair_capsule), "capsule_radius": colliders.capsules.radius,
              "floor": colliders.floor}
    return FemTissue(parts, rig.cv_offsets, device=setup.settings.device, **kw)


class Baker:
    """Bakes the chunks of one BakeSetup in order; holds the particle model and solver (built once)
    and the time spent per stage (seconds)."""

    def __init__(self, setup: BakeSetup, defer: bool = False):
        self.setup, self.defer = setup, defer
        s = setup
        self.blend = blend_weights(s.jiggles, s.settings, s.times)
        self.model = self.solver = None
        self.smooth = hasattr(s.skin, "lbs_batch")
        """whether the chunks bring the smooth skin alone (skin_lbs, what compare's skin quality reads against)"""
        self.timings = dict.fromkeys(("drive_s", "static_s", "simulate_s", "skin_s", "write_s"), 0.0)
        self.colliders = self.skin_check = None
        # muscles none of whose skin is soft drive nothing (rig.skin.muscle_skin.MuscleSkin.idle): glued to their
        # static shape; when every muscle is so, nothing is simulated
        self.idle = idle_muscles(s)
        jiggles = glued(s.jiggles, self.idle) if self.idle.any() else list(s.jiggles)
        if s.settings.collisions:
            self.colliders = collider_model(s.rig, s.character, capsules=s.capsules, floor=s.floor,
                                            device=s.settings.device)
            self.skin_check = skin_check(s.character, self.colliders.capsules)
        self.fem = None
        if needs_simulation(self.blend) and not (self.idle.size and self.idle.all()):
            # blend 0 everywhere: the static CVs, no simulation
            if s.tissue_solver == "fem":            # the hero mode: the parts as solids (sim/fem/tissue.py)
                t = time.perf_counter()
                self.fem = fem_tissue(s, self.idle, self.colliders)
                self.timings["fem_setup_s"] = time.perf_counter() - t
            else:
                self.model = muscle_model(s.rig, jiggles, s.settings.device, gravity=s.settings.gravity)
                self.solver = make_solver(self.model, jiggles)
        self.chain_run = None
        if s.chains is not None:                # the chains swung over the whole clip at once (tens of bodies)
            t = time.perf_counter()
            self._swing_chains()
            self.timings["chains_s"] = time.perf_counter() - t
        self.tissue = None
        if self.colliders is not None and s.settings.muscle_collisions and self.model is not None:
            # the particles of muscles of different body parts collide with each other too (one launch per step)
            self.tissue = tissue_contact_model(s.rig, self.model, device=s.settings.device)

    def _swing_chains(self) -> None:
        """The chains' rotations at every output frame (sim.chain.simulate.swing), the joints they move and the skin
        they move, and their figures (sim.chain.measure) for bake.json."""
        from jiggle.rig.skin.chain_skin import ChainSkin
        from jiggle.sim.chain.measure import measure
        from jiggle.sim.chain.simulate import chain_world, riders_of, swing
        s = self.setup
        ch = s.chains
        self.chain_run = swing(ch.model, ch.params, s.times, s.knots, s.world_at, loop=s.loop)
        if ch.skin is not None:                 # made with the setup (sim.chain.build.make)
            self.chain_riders, self.chain_joints, self.chain_skin = list(ch.riders), ch.moved, ch.skin
        else:
            self.chain_riders = riders_of(ch.model, s.character.parents)
            moved = [int(j) for j in ch.links.joints] + [j for j, _ in self.chain_riders]
            self.chain_joints = np.array(moved, np.int64)
            self.chain_skin = ChainSkin(s.character, self.chain_joints)
        tips = {"static": [], "final": []}
        report = None
        for a in range(0, len(s.times), 256):
            w = np.asarray(s.world_at(s.times[a:a + 256]), np.float64)
            wd = chain_world(w, ch.model, self.chain_run.rotations[a:a + 256], self.chain_riders)
            part = measure(w, wd, ch.links, ch.model.capsules, ch.apart, ch.model.floor, ch.chains.names)
            report = part if report is None else {
                n: {**r, "tip_peak_m": max(r["tip_peak_m"], part[n]["tip_peak_m"]),
                    "swing_share": max(r["swing_share"], part[n]["swing_share"]),
                    "penetrations": r["penetrations"] + part[n]["penetrations"],
                    "deepest_m": max(r["deepest_m"], part[n]["deepest_m"]),
                    "tip_static": np.concatenate([r["tip_static"], part[n]["tip_static"]]),
                    "tip_final": np.concatenate([r["tip_final"], part[n]["tip_final"]])} for n, r in report.items()}
        self.chain_report = report
        self.chain_tips = {k: np.stack([report[n]["tip_" + k] for n in ch.chains.names], axis=1) for k in tips}

    def chain_json(self) -> dict:
        """bake.json's "chains": what swung, how far, and the run."""
        s, run = self.setup, self.chain_run
        per = []
        for n, r in self.chain_report.items():
            per.append({"chain": n, **{k: v for k, v in r.items() if not k.startswith("tip_") or k == "tip_peak_m"}})
        return {"chains": per, "steps": run.steps, "steps_with_warmup": run.steps_all, "step_s": run.dt, "seconds": round(run.seconds, 4),
                "warmup": run.warmup, "joints": [s.character.joint_names[j] for j in self.chain_joints],
                "penetration_rule": "link-frames where a link's capsule sinks deeper than 25% of its radius into a body "
                                    "capsule the animated pose keeps it clear of, or below the floor",
                "swing_rule": "the tip's (the end of the chain's farthest bone) largest distance from where the "
                              "animation puts it, over the chain's length"}

    def chunk(self, c: int, state) -> dict:
        """Arrays of chunk c (see the module), going on from `state` ((x, v) of the particles at the
        chunk's first frame - 1, None for chunk 0). One stage after another, each for the whole chunk:
        drive -> static CVs -> goals, simulate -> blend -> skin."""
        s, rig = self.setup, self.setup.rig
        span = _chunk_span(s, c)
        f0, f1 = span.f0, span.f1

        with self._timed("drive_s"):
            world_k = np.asarray(s.world_at(span.knots), dtype=np.float64)
            joints = np.asarray(s.joints_at(s.times[f0:f1]), dtype=np.float32)
        with self._timed("static_s"):
            static = s.static_at(span.knots, world_k)
            st, curve, world = static.cvs[span.at], static.curve[span.at], world_k[span.at]
        with self._timed("simulate_s"):
            dyn, new_state, contacts = self._simulate(c, state, span, world_k, static, st)
            cvs = blend(st, dyn, self.blend[f0:f1])
        swung = chain = None
        with self._timed("skin_s"):
            # reuse: the skins of chunk c live in buffers chunk c + 2 writes again; the bake finishes and writes
            # chunk c before it starts chunk c + 2 (bake(), sim/bake/baker.py)
            pending = skin_frames(s.skin, world, (st, cvs), curve, np.arange(f0, f1), defer=True, smooth=self.smooth,
                                  reuse=self.defer)
            if self.chain_run is not None:      # the swung chains on the skeleton, and what they move of the skin
                from jiggle.sim.chain.simulate import chain_world
                swung = chain_world(world, s.chains.model, self.chain_run.rotations[f0:f1], self.chain_riders)
                chain = (self.chain_skin.vertices, self.chain_skin.delta(world, swung))
        out = self._chunk_arrays(span, joints, st, cvs, swung, new_state, contacts)
        finish = functools.partial(self._finish, span, world, out, pending, chain)
        if self.defer:
            out["finish"] = finish
            return out
        return finish()

    def _simulate(self, c: int, state, span: _ChunkSpan, world_k: np.ndarray, static, st: np.ndarray):
        """(dyn, new_state, contacts) of chunk c: its dynamic CVs (F, N, 3) metres at its output frames (the FEM
        solids', the particles', or the static CVs `st` when nothing is simulated), the (x, v) state at its end
        (None without one) and its contact arrays {CONTACT_KEYS key: array}. world_k (K, J, 4, 4): the joints at
        the chunk's knots; static: rig.static's result there."""
        # a loop's first chunk goes on from the cycle's steady state (sim/bake/loop.py), as a later chunk
        # goes on from the one before
        given = state if c > 0 or self.setup.loop is not None else None
        if self.fem is not None:
            return self._simulate_fem(c, given, span, world_k, static, st)
        if self.model is None:
            return st, None, {}
        return self._simulate_particles(c, given, span, world_k, static)

    def _simulate_fem(self, c: int, given, span: _ChunkSpan, world_k: np.ndarray, static, st: np.ndarray):
        """The hero mode's chunk (sim.fem.tissue.FemTissue.run) from the frame before it: the static CVs `st`
        (F, N, 3) with the solids' CVs put in, the solids' state at its end, and per frame the smallest det F
        and the inverted tets."""
        s, kt = self.setup, span.knots
        cuts = find_cuts(kt, static.cvs, s.settings.cut_ratio, s.settings.cut_jump)
        ends = None if self.colliders is None else \
            self.colliders.capsules.ends(world_k).reshape(len(kt), -1, 3)
        part, new_state, rec = self.fem.run(kt, static.cvs, s.times[span.a:span.f1], start=given, cuts=cuts,
                                            capsule_ends=ends)
        skip = 1 if c > 0 else 0
        dyn = np.array(st, np.float64)
        dyn[:, self.fem.cv_index] = part[skip:]
        contacts = {"fem_min_det": rec["min_det"][skip:].astype(np.float32),
                    "fem_inverted": rec["inverted"][skip:].astype(np.int32),
                    "fem_part_min_det": rec["part_min_det"][skip:].astype(np.float32)}
        return dyn, new_state, contacts

    def _simulate_particles(self, c: int, given, span: _ChunkSpan, world_k: np.ndarray, static):
        """The particles' chunk (sim.jiggle.simulate: goals, simulate) from the frame before it: the dynamic CVs
        (F, N, 3), the particles' (x, v) at its end, and the contacts per frame and muscle (with colliders) and
        the chunk's hard stops per muscle."""
        s, rig, kt = self.setup, self.setup.rig, span.knots
        self.solver.stops.zero_()                # this chunk's hard stops only
        track = goals(rig, kt, static.cvs, s.settings)
        colliders = None if self.colliders is None else self.colliders.at(kt, world_k, track.cut)
        sink = {}
        dyn, new_state = simulate(self.model, track, s.times[span.a:span.f1], s.settings, solver=self.solver,
                                  preroll=0.0 if given is not None else None, start=given,
                                  colliders=colliders, contacts=sink, tissue=self.tissue)
        dyn = dyn[1:] if c > 0 else dyn
        contacts = {}
        if colliders is not None:
            per = muscle_contacts(sink["records"][1:] if c > 0 else sink["records"], rig.cv_offsets)
            contacts = {"contact_depth": per["depth"].astype(np.float32),
                        "contact_hit": per["hit"].astype(np.int32),
                        "contact_impulse": per["impulse"].astype(np.float32)}
        # the tissue law's hard stops in this chunk, per muscle (sim/jiggle/tissue_law.py: it makes none)
        stops = self.solver.hard_stops()
        contacts["hard_stops"] = np.add.reduceat(stops, rig.cv_offsets[:-1]).astype(np.int64) \
            if len(stops) else np.zeros(rig.M, np.int64)
        return dyn, new_state, contacts

    def _chunk_arrays(self, span: _ChunkSpan, joints: np.ndarray, st: np.ndarray, cvs: np.ndarray, swung,
                      new_state, contacts: dict) -> dict:
        """The chunk's arrays but its skins: frames [f0, f1], joint_world (F, J, 4, 4), cvs_static and cvs_dynamic
        (F, N, 3) float32; with chains (swung: (F, J, 4, 4) the swung skeleton) their joints and tips at the file's
        size; the state at its end; its contacts."""
        s, f0, f1 = self.setup, span.f0, span.f1
        out = {"frames": np.array([f0, f1]), "joint_world": joints, "cvs_static": st.astype(np.float32),
               "cvs_dynamic": cvs.astype(np.float32)}
        if swung is not None:
            cw = np.array(swung[:, self.chain_joints], np.float32)
            cw[..., :3, 3] *= np.float32(s.scale)
            out["chain_world"] = cw
            out["chain_tips_static"] = (self.chain_tips["static"][f0:f1] * s.scale).astype(np.float32)
            out["chain_tips_final"] = (self.chain_tips["final"][f0:f1] * s.scale).astype(np.float32)
        if getattr(s, "activation", None) is not None:
            out["activation"] = np.asarray(s.activation[f0:f1], np.float32)
        if new_state is not None:
            out["state_x"], out["state_v"] = new_state
        out.update(contacts)
        return out

    def _finish(self, span: _ChunkSpan, world: np.ndarray, out: dict, pending, chain) -> dict:
        """The chunk's skins finished (the surface spread) and checked: the arrays to save. out: the chunk's arrays
        (_chunk_arrays); pending: skin_frames's deferred skins; chain: (vertices, offsets) the chains move, or None."""
        s, f0, times = self.setup, span.f0, self.setup.times
        t = time.perf_counter()
        skin_static, skin_final, *smooth = pending()
        if chain is not None:               # the chains' share of the final skin (rig/skin/chain_skin.py)
            skin_final[:, chain[0]] += chain[1]
            out["chain_delta"] = (chain[1] * np.float32(s.scale)).astype(np.float32)
        self.timings["skin_s"] += time.perf_counter() - t
        for name, skin in (("skin_static", skin_static), ("skin_final", skin_final)):
            bad = ~np.isfinite(skin)
            if bad.any():                   # never into a cache: stop while the chunks so far are kept
                k, v = np.argwhere(bad)[0][:2]
                raise InputError(f"not finite at frame {f0 + k} (t = {times[f0 + k]:.4f} s), vertex {v}; "
                                 "nothing of this chunk was written", field=name)
        arrays = {k: v for k, v in out.items() if k != "finish"}
        if smooth:
            arrays["skin_lbs"] = smooth[0]
        if self.skin_check is not None:
            # the jiggle keeps the final skin out of other parts' capsules the static skin is not in (in
            # place, before anything is written), and both skins' vertices inside are counted per frame
            kept = self.skin_check.keep_out(world, skin_static, skin_final, s.settings.device,
                                            rigid=getattr(s.skin, "ride", None))
            arrays["inside_static"], arrays["inside_final"] = kept["static"], kept["final"]
            arrays["skin_kept_out"], arrays["skin_pulled_m"] = kept["kept"], kept["pulled_m"]
        arrays = {**arrays, "skin_static": skin_static, "skin_final": skin_final}
        if s.scale != 1.0:          # simulated at its template's size: written at the file's (BakeSetup.scale)
            for k in SCALED_KEYS:
                if k in arrays:
                    arrays[k] = (arrays[k] * np.float32(s.scale)).astype(arrays[k].dtype)
        return arrays

    @contextlib.contextmanager
    def _timed(self, stage: str):
        t = time.perf_counter()
        try:
            yield
        finally:
            self.timings[stage] += time.perf_counter() - t


# ---------------------------------------------------------------------------------------- files
@contextlib.contextmanager
def _writing(path: str):
    try:
        with atomic_path(path) as tmp:
            yield tmp
    except OSError as e:
        raise InputError(f"cannot write: {e.strerror or e}; the bake so far is kept (run again with --resume)",
                         path) from None


def _save_chunk(path: str, arrays: dict) -> None:
    with _writing(path) as tmp:
        with open(tmp, "wb") as fh:
            np.savez(fh, **arrays)


def _load_chunk(path: str, key_frames) -> dict | None:
    """A chunk's arrays, or None when the file is missing or unreadable (it is then baked again)."""
    try:
        with np.load(path, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except Exception:  # noqa: BLE001 - a damaged chunk of any kind is baked again
        return None
    if list(data.get("frames", [])) != list(key_frames):
        return None
    return data


def _write_json(path: str, obj) -> None:
    with _writing(path) as tmp:
        with open(tmp, "w", encoding="utf-8") as fh:
            json.dump(obj, fh, indent=2, allow_nan=False)
            fh.write("\n")


def cache_paths(out_dir: str, formats) -> dict:
    """{format: path} of the caches among `formats` (the glb is made after them, from the npz)."""
    return {f: os.path.join(out_dir, CACHE_NAMES[f]) for f in formats if f in CACHE_NAMES}


COMPARE_NAMES = ("metrics.json", "displacement.npz", "amplitude.png", "limits.png", "energy.png", "spectrum.png",
                 "displacement.png", "quality.png", "chains.png", "contacts.png", "activation.png", "peak.png",
                 "quality_closeups.png",
                 "glb_closeup.png", "clip.mp4", "clip.gif", "report.html")
"""The names `jiggle compare` writes beside a bake (sim/app/report/compare.py) when they are free."""
COMPARE_RECORD = "compare.json"
"""`jiggle compare`'s record of the files it wrote into a bake folder: {"format": COMPARE_RECORD_FORMAT,
"files": [names]} (under compare.jiggle.json, compare.jiggle2.json, ... when the folder holds a
compare.json of its own). A bake or compare removes or overwrites only files such a record lists."""
COMPARE_RECORD_FORMAT = "jiggle.compare-files/1"
COMPARE_FORMAT = "jiggle.compare/1"
"""metrics.json's format: its "files" are the record of a compare from before COMPARE_RECORD existed."""
_PARTIAL_FILE = re.compile(r"manifest\.json|chunk_\d{5}\.npz|loop\.npz|\..+\.tmp.*")


def _read_json(path: str):
    try:
        with open(path, encoding="utf-8") as fh:
            return json.load(fh)
    except (OSError, ValueError):
        return None


def _plain_name(name) -> bool:
    """A bare file name inside the folder: no folder part, no way out of it."""
    return (isinstance(name, str) and name not in ("", ".", "..") and os.path.basename(name) == name
            and "/" not in name and (os.altsep is None or os.altsep not in name))


def compare_records(out_dir: str) -> list[str]:
    """Names of compare's records in out_dir (see COMPARE_RECORD): compare*.json files of that format."""
    try:
        entries = sorted(os.listdir(out_dir))
    except OSError:
        return []
    out = []
    for name in entries:
        if not (name.startswith("compare") and name.endswith(".json")):
            continue
        path = os.path.join(out_dir, name)
        if os.path.islink(path) or not os.path.isfile(path):
            continue
        rec = _read_json(path)
        if isinstance(rec, dict) and rec.get("format") == COMPARE_RECORD_FORMAT and isinstance(rec.get("files"),
                                                                                               list):
            out.append(name)
    return out


def compare_files(out_dir: str) -> set[str]:
    """Names of the files an earlier `jiggle compare` recorded writing into out_dir (its record, else
    the metrics.json of a compare from before the record), the record itself included; only bare names."""
    names = set()
    for rec_name in compare_records(out_dir):
        rec = _read_json(os.path.join(out_dir, rec_name))
        names |= {n for n in rec["files"] if _plain_name(n)} | {rec_name}
    metrics = _read_json(os.path.join(out_dir, "metrics.json"))
    if isinstance(metrics, dict) and metrics.get("format") == COMPARE_FORMAT and isinstance(metrics.get("files"),
                                                                                             dict):
        names |= {n for n in metrics["files"].values() if _plain_name(n)} | {"metrics.json"}
    return names


def remove_listed(out_dir: str, names) -> None:
    """Remove the regular files `names` (bare names, see _plain_name) from out_dir. A name with a folder
    part or leading out of the folder, a symlink (never followed) or anything but a plain file is left."""
    for name in names:
        if not _plain_name(name):
            continue
        path = os.path.join(out_dir, name)
        if os.path.islink(path) or not os.path.isfile(path):
            continue
        with contextlib.suppress(FileNotFoundError):
            os.remove(path)


def _bake_files(out_dir: str) -> set[str]:
    """Names of the files the folder's earlier bake recorded: bake.json's caches and bake.json, and the
    caches an unfinished bake's manifest meant to write (an older manifest without the list: every
    cache name)."""
    names = set()
    summary = _read_json(os.path.join(out_dir, SUMMARY))
    if isinstance(summary, dict) and "key" in summary and isinstance(summary.get("files"), dict):
        names |= {n for n in summary["files"].values() if _plain_name(n)} | {SUMMARY}
    manifest = _read_json(os.path.join(out_dir, PARTIAL, MANIFEST))
    if isinstance(manifest, dict) and manifest.get("format") == MANIFEST_FORMAT:
        listed = manifest.get("files")
        names |= {n for n in listed if _plain_name(n)} if isinstance(listed, list) else set(CACHE_NAMES.values())
    return names


def _partial_is_ours(partial: str) -> bool:
    """True when .partial holds nothing but an unfinished bake's files (manifest, chunks, temporaries)."""
    if os.path.islink(partial):
        return False
    try:
        entries = list(os.scandir(partial))
    except OSError:
        return False
    return all(e.is_file(follow_symlinks=False) and _PARTIAL_FILE.fullmatch(e.name) for e in entries)


def _remove_finished(out_dir: str) -> None:
    """Drop what earlier bakes and compares recorded writing here (their caches, summary, comparison),
    so the folder never mixes two bakes; every file they did not record is left as it is."""
    remove_listed(out_dir, _bake_files(out_dir) | compare_files(out_dir))


def _diff(a, b, prefix="") -> list[str]:
    """Keys (dotted) whose values differ between two parameter dicts."""
    if isinstance(a, dict) and isinstance(b, dict):
        out = []
        for k in sorted(set(a) | set(b)):
            out += _diff(a.get(k), b.get(k), f"{prefix}{k}.")
        return out
    return [] if a == b else [prefix.rstrip(".")]


# ---------------------------------------------------------------------------------------- bake
def bake(setup: BakeSetup, out_dir: str, *, resume: bool = False, progress: Callable[[int], None] | None = None,
         log: Callable[[str], None] = lambda s: None) -> dict:
    """Bake `setup` into `out_dir` (see the module) and return the summary written to bake.json.

    resume : go on with the unfinished bake in out_dir (InputError when there is none, or when it
        was started with other parameters).
    progress : called with the number of frames each chunk adds (resumed chunks included once).
    """
    out_dir = os.path.abspath(out_dir)
    partial = os.path.join(out_dir, PARTIAL)
    manifest_path = os.path.join(partial, MANIFEST)
    try:
        os.makedirs(out_dir, exist_ok=True)
    except OSError as e:
        raise InputError(f"cannot create the output folder: {e.strerror or e}", out_dir, field="--out") from None
    if not os.access(out_dir, os.W_OK | os.X_OK):
        raise InputError("the output folder is not writable", out_dir, field="--out")
    manifest = _manifest(setup, out_dir)
    t_start = time.perf_counter()
    done, state, crcs = 0, None, None
    if resume:
        done, state, crcs = _reopen(setup, out_dir, manifest_path, manifest, log)
    else:
        _start_over(out_dir, partial, manifest_path, manifest, log)
    if progress is not None and done:
        progress(chunk_frames(setup, done - 1)[1])
    contact_parts = _resumed_contacts(out_dir, done) if done else {}
    baker = Baker(setup, defer=True)
    warmup = None
    if setup.loop is not None and (baker.model is not None or baker.fem is not None):
        warmup, loop_state = _warm_up(setup, baker, os.path.join(partial, LOOP_STATE), log)
        if not done:
            state = loop_state
    t = time.perf_counter()
    writer = BakeWriter(setup, partial, None if not done else (crcs, chunk_frames(setup, done - 1)[1]),
                        smooth=baker.smooth)
    baker.timings["write_s"] += time.perf_counter() - t
    save = _ChunkSaver(setup, out_dir, baker, writer, contact_parts, progress)
    files, seam, loop_s, write_s = _bake_chunks(setup, baker, save, done, state, t_start)
    summary = _summary(setup, out_dir, files, baker, loop_s, write_s, resumed=done)
    _add_records(summary, setup, baker, warmup, seam, contact_parts)
    _warn_inverted(summary.get("fem"), len(setup.times))
    _write_json(os.path.join(out_dir, SUMMARY), summary)
    shutil.rmtree(partial, ignore_errors=True)
    if "glb" in setup.formats:                  # fitted from the finished npz; recorded in bake.json when written
        _add_glb(setup, out_dir, summary, log)
    return summary


def _manifest(setup: BakeSetup, out_dir: str) -> dict:
    """The unfinished bake's manifest (.partial/manifest.json): the parameters' key and the caches this bake will
    write (a new bake removes those of one interrupted while writing them, and nothing else)."""
    n = num_chunks(setup)
    return {"format": MANIFEST_FORMAT, "key": setup.key, "frames": len(setup.times), "chunk": setup.chunk,
            "chunks": n, "params": setup.params,
            "files": sorted(os.path.basename(p) for p in cache_paths(out_dir, setup.formats).values())}


def _reopen(setup: BakeSetup, out_dir: str, manifest_path: str, manifest: dict,
            log) -> tuple[int, tuple | None, dict | None]:
    """--resume: (chunks already baked, the particle state after them, the caches' progress then) of the unfinished
    bake (_resume), its manifest listing this bake's caches too."""
    done, state, crcs = _resume(setup, out_dir, manifest_path, log)
    old = _read_json(manifest_path)
    if isinstance(old, dict) and old.get("files") != manifest["files"]:     # same key: list the caches
        _write_json(manifest_path, {**old, "files": sorted(set(old.get("files") or []) | set(manifest["files"]))})
    return done, state, crcs


def _start_over(out_dir: str, partial: str, manifest_path: str, manifest: dict, log) -> None:
    """A new bake: what earlier bakes and compares recorded writing here removed, an unfinished bake's .partial
    with them (InputError when .partial holds anything else), and the new manifest written."""
    if os.path.lexists(partial) and not _partial_is_ours(partial):
        raise InputError(f"{PARTIAL} here holds files that are not an unfinished bake's; move it away, or bake "
                         "into another folder", partial, field="--out")
    _remove_finished(out_dir)           # reads the old manifest's list: before .partial goes
    if os.path.isdir(partial):
        log(f"removing an unfinished bake in {out_dir} (--resume would have finished it)")
    shutil.rmtree(partial, ignore_errors=True)
    _write_json(manifest_path, manifest)


@dataclass(frozen=True)
class _ChunkSaver:
    """The bake's last step for each chunk, in the worker thread (_bake_chunks): its skins finished, its frames
    written into the caches, its marker into .partial, its progress reported; its CONTACT_KEYS arrays kept in
    contact_parts ({chunk: {key: array}}) for bake.json."""
    setup: BakeSetup
    out_dir: str
    baker: Baker
    writer: BakeWriter
    contact_parts: dict
    progress: Callable[[int], None] | None

    def __call__(self, c: int, arrays: dict) -> None:
        """In the worker thread: finish chunk c's skins, write its frames into the caches and its marker
        (the particle state and the caches' progress), report it."""
        finish = arrays.pop("finish", None)     # out of the dict first: the closure holds the dict, a cycle
        if finish is not None:                  # would keep every chunk's skins until the garbage collector ran
            arrays = finish()
        t = time.perf_counter()
        f0, f1 = chunk_frames(self.setup, c)
        crcs = self.writer.append(f0, arrays)
        marker = {"frames": arrays["frames"], "progress": np.array(json.dumps(crcs))}
        if "state_x" in arrays:
            marker["state_x"], marker["state_v"] = arrays["state_x"], arrays["state_v"]
        for k in CONTACT_KEYS:                  # the contacts and skin checks, for bake.json after a resume
            if k in arrays:
                marker[k] = arrays[k]
                self.contact_parts[c] = {**self.contact_parts.get(c, {}), k: arrays[k]}
        _save_chunk(chunk_path(self.out_dir, c), marker)
        self.baker.timings["write_s"] += time.perf_counter() - t
        if os.environ.get(PAUSE_ENV):
            time.sleep(float(os.environ[PAUSE_ENV]))
        if self.progress is not None:
            self.progress(f1 - f0)


def _bake_chunks(setup: BakeSetup, baker: Baker, save: _ChunkSaver, done: int, state,
                 t_start: float) -> tuple[dict, dict | None, float, float]:
    """The chunks from `done` on baked in order, the first going on from `state` ((x, v) or None), each saved by
    `save`; then the caches completed into the folder. (files {format: path}, the loop's seam (_seam) or None,
    seconds from t_start to the last chunk written, seconds completing the caches). The caches' writer is closed
    whatever happens; an interrupted bake lets the chunk in the worker land first."""
    writer = save.writer
    # chunk c's skins are finished and written in a worker thread while chunk c + 1 is driven, shaped
    # and simulated here: the two cores share the work, the arithmetic (and so every cache) is the same
    worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="jiggle-bake")
    pending = None
    try:
        for c in range(done, num_chunks(setup)):
            arrays = baker.chunk(c, state)
            state = (arrays["state_x"], arrays["state_v"]) if "state_x" in arrays else None
            if pending is not None:
                pending.result()                # chunk c - 1 written (or its error raised here)
            pending = worker.submit(save, c, arrays)
        if pending is not None:
            done_chunk, pending = pending, None
            done_chunk.result()
        loop_s = time.perf_counter() - t_start
        t = time.perf_counter()
        seam = _seam(setup, writer) if setup.loop is not None else None
        files = writer.finish(save.out_dir, {f: os.path.basename(p)
                                             for f, p in cache_paths(save.out_dir, setup.formats).items()})
        write_s = time.perf_counter() - t
    finally:
        if pending is not None:                 # interrupted: let the chunk in the worker land first
            with contextlib.suppress(Exception):
                pending.result()
        worker.shutdown(wait=True)
        writer.close()
    return files, seam, loop_s, write_s


def _add_records(summary: dict, setup: BakeSetup, baker: Baker, warmup: dict | None, seam: dict | None,
                 contact_parts: dict) -> None:
    """bake.json's records of the stages added to `summary`: "loop" (with its warm-up and seam), "tissue" (with
    particles), "fem", "contacts" (with colliders) and "chains"."""
    if setup.loop is not None:
        summary["loop"] = {**setup.loop.to_json(), "warmup": warmup, "seam": seam}
    else:
        summary["loop"] = setup.params.get("loop") if isinstance(setup.params, dict) else None
    if baker.model is not None:
        summary["tissue"] = _tissue_json(setup, contact_parts)
    summary["fem"] = _fem_json(setup, baker, contact_parts) if baker.fem is not None else None
    if baker.colliders is not None:
        summary["contacts"] = _contacts_json(setup, baker, contact_parts)
    summary["chains"] = baker.chain_json() if baker.chain_run is not None else None


def _warn_inverted(fem: dict | None, frames: int) -> None:
    """A JiggleWarning when the hero solid (bake.json "fem") inverted tets at any output frame: the skin rides CVs
    embedded in it and can look clean, so the bake says so rather than writing it silently."""
    if fem and fem.get("inverted_max"):
        warnings.warn(JiggleWarning(
            f"the hero solid inverted: up to {fem['inverted_max']} tets on {fem.get('frames_with_inverted')} of "
            f"{frames} output frames (smallest det F {fem.get('min_det')}); the caches hold the skin it drove "
            "(bake.json fem, compare's fem_inverted_tets target)"), stacklevel=3)


def _add_glb(setup: BakeSetup, out_dir: str, summary: dict, log) -> None:
    """The glb's jiggle bones fitted from the finished npz and written (sim.bake.glb.write_for_bake); its record
    added to `summary` ("glb", files' "glb")."""
    from jiggle.sim.bake.glb import write_for_bake
    log("fitting jiggle bones for the glb")
    rep = write_for_bake(setup, out_dir, bones=setup.glb.get("bones"),
                         max_influences=setup.glb.get("max_influences", 4))
    summary["glb"] = {k: v for k, v in rep.items() if k != "bone_names"}
    summary["files"]["glb"] = rep["file"]


def _warm_up(setup: BakeSetup, baker: Baker, path: str, log) -> tuple[dict, tuple]:
    """(the warm-up's record, the steady state (x, v)) of a looping bake: read from .partial/loop.npz when an
    interrupted bake left it (the same parameters: the manifest's key says so), else reached
    (sim.bake.loop.warm_up) and stored there."""
    from jiggle.sim.bake.loop import warm_up
    try:
        with np.load(path, allow_pickle=False) as z:
            return json.loads(str(z["record"])), (z["state_x"], z["state_v"])
    except Exception:  # noqa: BLE001 - none, or damaged: reached again (the same arithmetic)
        pass
    t = time.perf_counter()
    if baker.fem is not None:
        from jiggle.sim.bake.loop import warm_up_fem
        state, rec = warm_up_fem(setup, baker.fem, baker.colliders, MARGIN, log)
    else:
        state, rec = warm_up(setup, baker.model, baker.solver, baker.colliders, baker.tissue, MARGIN, log)
    rec["seconds"] = round(time.perf_counter() - t, 3)
    _save_chunk(path, {"state_x": state[0], "state_v": state[1], "record": np.array(json.dumps(rec))})
    return rec, state


def _seam(setup: BakeSetup, writer: BakeWriter) -> dict | None:
    """bake.json's loop "seam" from the finished frames 0, T-2, T-1 (as sim.bake.loop.wrap_figures): the jiggle
    offset's jump from the last frame to the first (wrap_mm: ideally 0 where the last frame repeats the first, an
    ordinary step for an open cycle) and the step a player looping the cycle takes across the seam (wrap_step_mm:
    second-to-last to first where the last repeats the first), in mm; None for a bake cut short by --frames."""
    T = len(setup.times)
    if T != setup.loop.frames or T < 3:
        return None
    d = [writer.npz.read("skin_final", f, f + 1)[0].astype(np.float64) - writer.npz.read("skin_static", f, f + 1)[0]
         for f in (0, T - 2, T - 1)]
    wrap = round(float(np.linalg.norm(d[2] - d[0], axis=-1).max()) * 1e3, 5)
    step = round(float(np.linalg.norm(d[0] - d[1], axis=-1).max()) * 1e3, 5) if setup.loop.repeats_first else wrap
    return {"wrap_mm": wrap, "wrap_step_mm": step}


CONTACT_KEYS = ("contact_depth", "contact_hit", "contact_impulse", "inside_static", "inside_final", "skin_kept_out",
                "skin_pulled_m", "hard_stops", "fem_min_det", "fem_inverted", "fem_part_min_det")
"""Arrays a chunk's marker keeps for bake.json: with collisions, per frame and muscle the deepest contact (m),
what it hit, the summed impulse (N s); the skin vertices inside another part's capsule; the final skin's
vertices pulled back out of one and the longest pull-back (m); and with a simulation, the chunk's hard stops
per muscle (M,); in the FEM hero mode, per frame the smallest det F over its tets, how many are inverted, and each
part's smallest det F (F, P)."""


def _tissue_json(setup: BakeSetup, parts: dict) -> dict:
    """bake.json's "tissue": the tissue law's constants and the hard stops per muscle over the whole bake (a
    resumed bake adds its earlier chunks' from their markers)."""
    from jiggle.sim.jiggle import tissue_law
    M = setup.rig.M
    stops = np.zeros(M, np.int64)
    for c in sorted(parts):
        if "hard_stops" in parts[c] and len(parts[c]["hard_stops"]) == M:
            stops += parts[c]["hard_stops"].astype(np.int64)
    return {"law": "goal spring stiffening from onset x reach (cubic), straight on past the reach; no projection "
                   "(sim/jiggle/tissue_law.py)",
            "onset": tissue_law.ONSET, "gain": tissue_law.GAIN, "near": tissue_law.NEAR,
            "hard_stop_rule": f"a substep ending at >= {tissue_law.NEAR:g} x reach whose outward offset speed fell by more "
                              f"than half without turning back, from a speed covering {tissue_law.FAST:g} x reach in "
                              "the substep",
            # muscles that drive nothing are not simulated: left out of the counts (sim.bake.baker.idle_muscles)
            "hard_stops": {n: int(k) for n, k, i in zip(setup.rig.names, stops, idle_muscles(setup)) if not i},
            "hard_stops_total": int(stops[~idle_muscles(setup)].sum())}


def _fem_json(setup: BakeSetup, baker: Baker, parts: dict) -> dict:
    """bake.json's "fem" (the hero mode): the parts' meshes and materials, the solver, and over the whole bake (a
    resumed bake's earlier chunks from their markers) the smallest det F and the inverted tets."""
    order = sorted(parts)
    det = [parts[c]["fem_min_det"] for c in order if "fem_min_det" in parts[c]]
    inv = [parts[c]["fem_inverted"] for c in order if "fem_inverted" in parts[c]]
    det = np.concatenate(det) if det else np.zeros(0)
    inv = np.concatenate(inv) if inv else np.zeros(0, np.int64)
    out = baker.fem.to_json(setup.real_scale)
    per = [parts[c]["fem_part_min_det"] for c in order if "fem_part_min_det" in parts[c]]
    if per:                                     # each part's smallest det F at the output frames
        per = np.concatenate(per).min(axis=0)
        for p, d in zip(baker.fem.parts, per):
            out["parts"][p.name]["min_det"] = round(float(d), 6)
    out.update({"min_det": round(float(det.min()), 6) if len(det) else None,
                "inverted_max": int(inv.max()) if len(inv) else 0,
                "frames_with_inverted": int((inv > 0).sum()),
                "inverted_rule": "det F of a tet against its goal shape (its rest shape at that moment) <= 0, at the "
                                 "output frames"})
    return out


def _resumed_contacts(out_dir: str, done: int) -> dict:
    """{chunk: {key: array}} of CONTACT_KEYS stored with the first `done` chunks."""
    parts = {}
    for c in range(done):
        try:
            with np.load(chunk_path(out_dir, c), allow_pickle=False) as z:
                parts[c] = {k: z[k] for k in CONTACT_KEYS if k in z.files}
        except Exception:  # noqa: BLE001 - a marker read at resume; a damaged one was baked again
            continue
    return parts


def _contacts_json(setup: BakeSetup, baker: Baker, parts: dict) -> dict:
    """bake.json's "contacts": the colliders, per frame which muscle hit what and how deep, per pair the
    totals (sim.jiggle.colliders.contact_summary), and per frame the skin vertices inside another body
    part's capsule, static and final skin."""
    cm = baker.colliders
    order = sorted(parts)

    def cat(k, shape):
        got = [parts[c][k] for c in order if k in parts[c]]
        return np.concatenate(got) if got else np.zeros(shape)
    M, T = setup.rig.M, len(setup.times)
    out = {"method": "projection with Coulomb friction after every step (sim/jiggle/contact_kernels.py)",
           "friction": cm.friction, "floor_m": cm.floor, "colliders": list(cm.names),
           "capsule_radius_mm": [round(1000.0 * float(r), 3) for r in cm.capsules.radius],
           "pairs_checked": int(len(cm.pair_capsule)), "pairs_touching_at_rest": int(cm.excluded_rest.sum())}
    names = cm.names
    if baker.tissue is not None:            # hit ids past the floor: the particles of another muscle
        tm = baker.tissue
        names = tm.hit_names(cm.names)
        out["muscle_collisions"] = {
            "method": "particle against particle of muscles of different bones, a Jacobi projection with friction "
                      "after every step (sim/jiggle/tissue_contacts.py)",
            "muscle_pairs": int(np.triu(tm.mask, 1).sum()), "share": tm.share,
            "largest_radius_mm": round(1000.0 * float(np.max(tm.radius)), 3) if tm.num_particles else 0.0}
    depth = cat("contact_depth", (0, M))
    if len(depth) == T:
        out.update(contact_summary(depth, cat("contact_hit", (0, M)).astype(np.int64), cat("contact_impulse", (0, M)),
                                   setup.rig.names, names, setup.times))
    inside_s, inside_f = cat("inside_static", (0,)), cat("inside_final", (0,))
    if len(inside_s) == T:
        out["skin_inside"] = {"static": inside_s.astype(int).tolist(), "final": inside_f.astype(int).tolist(),
                              "max_static": int(inside_s.max()) if T else 0,
                              "max_final": int(inside_f.max()) if T else 0,
                              "frames_final_above_static": int((inside_f > inside_s).sum())}
        kept, pulled = cat("skin_kept_out", (0,)), cat("skin_pulled_m", (0,))
        if len(kept) == T:                      # older partial bakes resumed have no pull-back records
            out["skin_inside"].update({
                "kept_out": kept.astype(int).tolist(), "max_kept_out": int(kept.max()) if T else 0,
                "max_pull_mm": round(1000.0 * float(pulled.max()), 4) if T else 0.0,
                "method": "final vertices the jiggle took into another part's capsule are pulled back along "
                          "their jiggle to its surface (sim.jiggle.colliders.SkinCheck.keep_out)"})
    return out


def _resume(setup: BakeSetup, out_dir: str, manifest_path: str, log) -> tuple[int, tuple | None, dict | None]:
    """(chunks already baked, particle state after the last of them, the caches' progress then) of the
    unfinished bake."""
    if not os.path.isfile(manifest_path):
        if os.path.isfile(os.path.join(out_dir, SUMMARY)):
            raise InputError("this bake is already finished; nothing to resume (run without --resume to bake "
                             "again)", out_dir, field="--resume")
        raise InputError("no unfinished bake here to resume; run without --resume", out_dir, field="--resume")
    try:
        with open(manifest_path, encoding="utf-8") as fh:
            old = json.load(fh)
    except (OSError, ValueError) as e:
        raise InputError(f"the unfinished bake's manifest is unreadable ({e}); run without --resume", manifest_path,
                         field="--resume") from None
    if old.get("format") != MANIFEST_FORMAT or old.get("key") != setup.key:
        changed = _diff(old.get("params", {}), setup.params) or ["format"]
        raise InputError(f"the unfinished bake was started with other parameters ({', '.join(changed[:8])}"
                         f"{', ...' if len(changed) > 8 else ''}); give the same ones to --resume, or run without "
                         f"--resume to start over", out_dir, field="--resume")
    done, state, crcs = 0, None, None
    for c in range(num_chunks(setup)):
        data = _load_chunk(chunk_path(out_dir, c), chunk_frames(setup, c))
        if data is None or "progress" not in data:
            break
        done = c + 1
        state = (data["state_x"], data["state_v"]) if "state_x" in data else None
        crcs = json.loads(str(data["progress"]))
    log(f"resuming: {done} of {num_chunks(setup)} chunks already baked "
        f"({chunk_frames(setup, done - 1)[1] if done else 0} of {len(setup.times)} frames)")
    return done, state, crcs


def _summary(setup: BakeSetup, out_dir: str, files: dict, baker: Baker, loop_s: float, write_s: float,
             resumed: int) -> dict:
    """bake.json: what was baked, the files, the speed and the largest jiggle."""
    T = len(setup.times)
    baked = T - (chunk_frames(setup, resumed - 1)[1] if resumed else 0)
    return {
        "name": setup.name, "frames": T, "fps": setup.fps,
        "start_s": float(setup.times[0]), "end_s": float(setup.times[-1]),
        "vertices": setup.character.num_vertices, "muscles": setup.rig.M, "chunks": num_chunks(setup),
        "resumed_after_chunks": resumed, "key": setup.key,
        "files": {f: os.path.relpath(p, out_dir) for f, p in files.items()},
        "timings": {**{k: round(v, 4) for k, v in setup.timings.items()},
                    **{k: round(v, 4) for k, v in baker.timings.items()},
                    "frames_s": round(loop_s, 4), "caches_s": round(write_s, 4),
                    "frames_per_s": round(baked / loop_s, 2) if loop_s > 0 and baked else None},
        "params": setup.params,
    }


def bake_in_memory(setup: BakeSetup) -> "BakeData":
    """The bake's arrays (sim.bake.caches.BakeData) without a folder of the user's: `bake` into a temporary folder
    with the npz alone, read back, the folder removed (the public API's `jiggle.simulate`)."""
    import tempfile
    from dataclasses import replace

    from jiggle.sim.bake.caches import read_npz
    with tempfile.TemporaryDirectory(prefix="jiggle-") as tmp:
        bake(replace(setup, formats=("npz",)), tmp)
        return read_npz(os.path.join(tmp, "bake.npz"))
