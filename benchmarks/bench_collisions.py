"""The cost of collisions, measured in one run: collisions on against off, per frame.

    .venv/bin/python benchmarks/bench_collisions.py [--frames N] [--clip BVH ...]

1. The demo (scenes/default.toml: a generated body, 28 muscles, jumping jacks): the bake's simulate stage
   (sim.jiggle.simulate over chunks of 64 frames, as sim/bake/baker.py runs it: goal track, colliders on
   the knots, the particles) per frame, off and on, and the skin check (skin vertices inside another
   part's capsule, both skins) the bake adds with collisions, per frame; and the whole bake per frame
   (sim.bake.baker.bake after setup, npz caches), off and on.
2. 40 muscles x 40 particles: fat pads in a column (a torso's worth of soft tissue) swaying and bending
   at their own phases over 20 capsules near them (each pad checked against every capsule: the broad
   phase, not a short list, keeps it cheap), 30 fps, 4 substeps: ParticleSolver.integrate per frame, off
   and on, and how many particle-steps touched.
3. The skin table: for each clip given (default: the shared CMU BVH clips of tests/conftest.py and the CMU
   AMC with its ASF, when present) on the generated body and on each --character (default CesiumMan), a
   bake with collisions on: the skin vertices inside another part's capsule per frame, static and final
   skin (max and mean per frame), and the frames where the final skin has more than the static.

Times are the best of several repeats after a warm-up (kernel compiles excluded), off and on alternated
(a busy spell of the shared machine slows both alike); ratios on / off are of the same run.

    .venv/bin/python benchmarks/bench_collisions.py --clip            # timings only, no skin table
    .venv/bin/python benchmarks/bench_collisions.py --no-timing       # the skin table only
"""
from __future__ import annotations

import argparse
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import json  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from dataclasses import replace  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

from conftest import ASSETS, CMU_BVH  # noqa: E402
from timing import best, chunk_spans  # noqa: E402

from jiggle.rig.character.capsules import BoneCapsules  # noqa: E402
from jiggle.sim.jiggle.colliders import ColliderModel, collider_model, skin_check  # noqa: E402
from jiggle.sim.jiggle.goal_track import build_track  # noqa: E402
from jiggle.sim.jiggle.params import MuscleJiggle, section_goals  # noqa: E402
from jiggle.sim.jiggle.particles import ParticleBuilder, muscle_model  # noqa: E402
from jiggle.sim.jiggle.simulate import goals, simulate, step_times  # noqa: E402
from jiggle.sim.jiggle.solver import ParticleSolver  # noqa: E402


def paired(off, on, repeats: int) -> tuple[float, float]:
    """(seconds off, seconds on): the fastest of `repeats` calls of each, alternated after one warm-up call
    of each, so that a busy spell of the shared machine slows both alike."""
    off(), on()
    t_off, t_on = [], []
    for _ in range(repeats):
        for fn, ts in ((off, t_off), (on, t_on)):
            t = time.perf_counter()
            fn()
            ts.append(time.perf_counter() - t)
    return min(t_off), min(t_on)


def demo(frames: int) -> dict:
    from jiggle.sim.bake.setup import BakeRequest, prepare
    s = prepare(BakeRequest(frames=frames, collisions=True))
    rig = s.rig
    model = muscle_model(rig, list(s.jiggles), "cpu", gravity=s.settings.gravity)
    cm = collider_model(rig, s.character, floor=s.floor)
    check = skin_check(s.character, cm.capsules)
    times = s.times
    world = np.asarray(s.world_at(s.knots))
    static = rig.static(world)
    chunks = chunk_spans(s.times, s.knots)

    def bake(on: bool):
        solver = ParticleSolver(model)
        state = None
        for c, (_, f1, a, ka, kb) in enumerate(chunks):
            track = goals(rig, s.knots[ka:kb], static.cvs[ka:kb], s.settings)
            col = cm.at(s.knots[ka:kb], world[ka:kb], track.cut) if on else None
            _, state = simulate(model, track, times[a:f1], s.settings, solver=solver, preroll=None if c == 0 else 0.0,
                                start=state, colliders=col, contacts={})
    off_s, on_s = paired(lambda: bake(False), lambda: bake(True), repeats=7)
    skin = np.asarray(s.skin.character.vertices, np.float32)[None].repeat(64, axis=0)
    w64 = np.asarray(s.world_at(times[:64]))
    skin = skin[:len(w64)]
    # both skins counted and the final one kept out (SkinCheck.keep_out, one launch): the final skin a few mm
    # off the static one (pulled back in place on the first call, then nothing more moves)
    final = skin + np.random.default_rng(0).normal(scale=0.003, size=skin.shape).astype(np.float32)
    check_s, _ = best(lambda: check.keep_out(w64, skin, final), repeats=3, warmup=True)
    T = len(times)
    return {"frames": T, "muscles": rig.M, "particles": model.num_particles, "capsules": cm.num_capsules,
            "pairs": len(cm.pair_capsule), "off_ms": 1e3 * off_s / T, "on_ms": 1e3 * on_s / T,
            "ratio": on_s / off_s, "skin_check_ms": 1e3 * check_s / len(w64)}


def whole_bake(frames: int, repeats: int = 2) -> dict:
    """The demo's whole bake (jiggle bake: setup excluded, the chunked loop: static muscles, particles,
    skinning, skin checks, caches in npz) per frame, collisions off and on."""
    import contextlib
    import io

    from jiggle.sim.bake.baker import bake
    from jiggle.sim.bake.setup import BakeRequest, prepare
    setups = {on: prepare(BakeRequest(frames=frames, collisions=on, formats=("npz",))) for on in (False, True)}

    def run(on):
        with tempfile.TemporaryDirectory() as out, contextlib.redirect_stderr(io.StringIO()):
            bake(setups[on], out)
    off_s, on_s = paired(lambda: run(False), lambda: run(True), repeats)
    T = len(setups[True].times)
    return {"frames": T, "off_ms": 1e3 * off_s / T, "on_ms": 1e3 * on_s / T, "ratio": on_s / off_s}


def grid(muscles: int = 40, capsules: int = 20, seconds: float = 2.0) -> dict:
    """40 fat pads in a column swaying, 20 capsules beside and between them."""
    rng = np.random.default_rng(0)
    a = 2 * np.pi * np.arange(8) / 8
    ring = np.stack([np.cos(a) * 0.03, np.zeros(8), np.sin(a) * 0.03], axis=1)
    pad = np.concatenate([ring + [0, y, 0] for y in np.linspace(-0.06, 0.06, 5)])
    centres = np.stack([np.full(muscles, 0.12), np.tile([-0.1, 0.1], muscles // 2),
                        np.repeat(np.linspace(0.0, 1.2, muscles // 2), 2)], axis=1)
    rest = np.concatenate([pad + c for c in centres])
    # reach 6 cm: two radii, a fat pad's default (sim/jiggle/params.py MAX_OFFSET_RADII)
    jig = MuscleJiggle(name="pad", frequency_hz=3.0, damping_ratio=0.3, goal=section_goals(0.5, 0.2), density=900.0,
                       spring_frequency_hz=6.0, spring_damping_ratio=0.3, max_offset=0.06)
    b = ParticleBuilder()
    b.add_muscles(rest, np.full(muscles, 3e-4), [replace(jig, name=f"pad{m}") for m in range(muscles)])
    model = b.finalize("cpu")
    fps, knot_rate = 30.0, 120.0
    knots = np.arange(0, seconds + 1e-9, 1 / knot_rate)
    phase = rng.uniform(0, 2 * np.pi, muscles)
    # each pad swings forward (x) by up to 6 cm at 2-3 Hz: into the capsules in front of the column
    amp = 0.06 * np.sin(2 * np.pi * 2.5 * knots[:, None] + phase[None])                 # (S, M)
    goal = rest[None].repeat(len(knots), 0).reshape(len(knots), muscles, 40, 3)
    goal[..., 0] += amp[..., None]
    track = build_track(knots, goal.reshape(len(knots), -1, 3), cuts=np.zeros(len(knots) - 1, bool))
    # capsules: limbs in front of the column (x = 0.2), reached by the pads' swing, along the column
    z = np.linspace(0.0, 1.2, capsules)
    ends = np.stack([np.stack([np.full(capsules, 0.21), np.full(capsules, -0.25), z], 1),
                     np.stack([np.full(capsules, 0.21), np.full(capsules, 0.25), z], 1)], axis=1)
    caps = BoneCapsules(joint=np.zeros(capsules), child=np.full(capsules, -1), local=ends, radius=np.full(capsules, 0.03),
                        names=[f"c{c}" for c in range(capsules)], parents=np.array([-1]))
    cm = ColliderModel.from_pairs(caps, np.ones((muscles, capsules), bool), floor=-0.05)
    col = cm.on_track(knots, np.repeat(ends.reshape(1, -1, 3), len(knots), 0))
    out_times = np.arange(0, seconds - 0.05, 1 / fps)
    g = step_times(out_times, knots, 4, ParticleSolver(model).max_step)
    control = track.to_device()
    record = np.flatnonzero(np.isin(np.round(g, 9), np.round(out_times, 9)))
    record = record[record > 0]
    solver = ParticleSolver(model)
    s_in, s_out = model.state(), model.state()
    x0 = track.sample(0.0)[0]

    def go(on):
        s_in.assign(x0, np.zeros_like(x0))
        return solver.integrate(s_in, s_out, control, g, record=record, colliders=col if on else None)
    off_s, on_s = paired(lambda: go(False), lambda: go(True), repeats=9)
    touched = int((solver.contact_records[..., 2] >= 0).sum())
    T = len(out_times) - 1
    return {"muscles": muscles, "particles": model.num_particles, "capsules": capsules, "frames": T,
            "off_ms": 1e3 * off_s / T, "on_ms": 1e3 * on_s / T, "ratio": on_s / off_s,
            "touching_particle_frames": touched}


def skin_table(clips: list[tuple[str, str | None]], frames: int, characters: list[str | None]) -> list[dict]:
    """Per (clip, character) a bake with collisions on: the skin vertices inside another part's capsule per
    frame, static and final skin (max and mean), the frames where the final has more than the static, the
    worst frame of each, and the particle contacts. clips : (clip path, ASF path or None)."""
    from jiggle.sim.app.commands.bake import run_bake
    from jiggle.sim.bake.setup import BakeRequest
    rows = []
    for character in characters:
        for clip, asf in clips:
            with tempfile.TemporaryDirectory() as out:
                summary = run_bake(BakeRequest(clip=clip, skeleton=asf, character=character, frames=frames,
                                               collisions=True, formats=("npz",)), out)
            c = summary["contacts"]
            si = c["skin_inside"]
            st, fi = np.asarray(si["static"]), np.asarray(si["final"])
            rows.append({"clip": os.path.basename(clip),
                         "character": os.path.basename(character) if character else "generated body",
                         "frames": len(st), "max_static": int(st.max()), "max_final": int(fi.max()),
                         "mean_static": float(st.mean()), "mean_final": float(fi.mean()),
                         "worst_static_frame": int(st.argmax()), "worst_final_frame": int(fi.argmax()),
                         "frames_final_above_static": int((fi > st).sum()),
                         "max_kept_out": si.get("max_kept_out"), "max_pull_mm": si.get("max_pull_mm"),
                         "contact_frames": c.get("frames_in_contact"),
                         "max_penetration_mm": c.get("max_penetration_mm")})
    return rows


def print_timing(d: dict, g: dict) -> None:
    print(f"demo ({d['frames']} frames, {d['muscles']} muscles, {d['particles']} particles, {d['capsules']} capsules, "
          f"{d['pairs']} muscle-capsule pairs): simulate off {d['off_ms']:.3f} ms/frame, on {d['on_ms']:.3f} ms/frame, "
          f"ratio {d['ratio']:.2f}x; skin check and pull-back (both skins, one launch) {d['skin_check_ms']:.3f} ms/frame")
    print(f"40 x 40 ({g['particles']} particles, {g['capsules']} capsules, {g['frames']} frames): integrate off "
          f"{g['off_ms']:.3f} ms/frame, on {g['on_ms']:.3f} ms/frame, ratio {g['ratio']:.2f}x; "
          f"{g['touching_particle_frames']} particle-frames in contact")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--frames", type=int, default=300, help="demo frames (default 300)")
    p.add_argument("--clip", nargs="*", help="clips for the skin table (default: the shared CMU BVH clips)")
    p.add_argument("--clip-frames", type=int, default=240, help="frames per clip in the skin table")
    p.add_argument("--character", nargs="*", default=[str(ASSETS / "characters" / "CesiumMan.glb")],
                   help="characters of the skin table besides the generated body (default: CesiumMan when present)")
    p.add_argument("--no-timing", action="store_true", help="only the skin table")
    args = p.parse_args()
    d = g = None
    if not args.no_timing:
        d, g = demo(args.frames), grid()
        print_timing(d, g)
        w = whole_bake(args.frames)
        d["whole_bake"] = w
        print(f"demo whole bake ({w['frames']} frames, npz): off {w['off_ms']:.2f} ms/frame, on {w['on_ms']:.2f} "
              f"ms/frame, ratio {w['ratio']:.2f}x")
    if args.clip is not None:
        clips = [(c, None) for c in args.clip]
    else:
        clips = [(str(ASSETS / "mocap" / "cmu_bvh" / f"{c}.bvh"), None) for c in CMU_BVH]
        clips.append((str(ASSETS / "mocap" / "cmu_amc" / "01_01.amc"), str(ASSETS / "mocap" / "cmu_amc" / "01.asf")))
    clips = [c for c in clips if os.path.isfile(c[0])]
    characters = [None] + [c for c in args.character if os.path.isfile(c)]
    rows = skin_table(clips, args.clip_frames, characters) if clips else []
    if rows:
        print("\n| clip | character | frames | skin inside, static: max / mean per frame | final: max / mean | "
              "frames final > static | pulled back: vertices (max per frame) / longest mm | contact frames | "
              "max penetration mm |\n|---|---|---|---|---|---|---|---|---|")
        for r in rows:
            print(f"| {r['clip']} | {r['character']} | {r['frames']} | {r['max_static']} / {r['mean_static']:.1f} | "
                  f"{r['max_final']} / {r['mean_final']:.1f} | {r['frames_final_above_static']} | "
                  f"{r['max_kept_out']} / {r['max_pull_mm']} | "
                  f"{r['contact_frames']} | {r['max_penetration_mm']} |")
    print(json.dumps({"demo": d, "grid": g, "skin_table": rows}, indent=1))


if __name__ == "__main__":
    main()
