"""The secondary motion's speed and its independence of the frame rate, measured in one run.

    .venv/bin/python benchmarks/bench_jiggle.py [--quick] [--device cpu]

1. 40 muscles x 40 particles (the simple arm's biceps copied 40 times on a grid, default jiggles), goals
   at 30 fps from each copy's elbow swinging at its own phase while the whole grid sways, 8 substeps
   per frame: ms per frame of sim.jiggle.simulate.run (which also uploads the track and reads every frame back)
   and of ParticleSolver.integrate alone, against the float64 NumPy reference step_numpy doing the same
   steps. The issue's budget: under 1 ms per frame on one core. Also the largest position difference
   from the reference, for run and for ParticleSolver.step called step by step: integrate merges each
   step's closing half kick with the next one's opening, which with damped springs is not quite K steps.
2. 1e5 particles (2500 copies): one ParticleSolver.step, and integrate over 8 steps / 8, against one
   step_numpy on the same model (goal >= 3x), and the largest difference after 8 steps.
3. Frame rate / substep independence: jiggle_rig at 24, 30, 60, 120 fps x 1..16 substeps against
   120 fps x 16 substeps, for the simple arm's fast flex (tests/jiggle/test_jiggle_clips.py) and for every
   muscle of a generated body fitted with the human template running 09_11.bvh (when ../shared/assets
   exists; its first 4/3 s, a frame at every rate), default jiggles: max over common times and CVs of
   |dynamic - ref| / peak, peak = the largest |dynamic - static| of the reference over the muscle set;
   also the worst muscle against its own peak and the belly fat. A markdown table. Then the end
   effect: the whole clip, whose end is no 24 fps frame, at 24 against 120 fps.

One core: OPENBLAS_NUM_THREADS=1 is set before NumPy loads; Warp's CPU kernels run on one thread.
Warp times are the best of several repeats after a warm-up (kernel compiles excluded).
"""
from __future__ import annotations

import argparse
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import sys  # noqa: E402
import time  # noqa: E402
from dataclasses import replace  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import warp as wp  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT / "tests" / "jiggle"))

import test_jiggle_clips as clips  # noqa: E402  the tests' elbow flex and frame helper
from conftest import ASSETS  # noqa: E402  ../shared/assets, or $JIGGLE_ASSETS
from timing import best  # noqa: E402  (benchmarks/timing.py)

from jiggle.rig.muscle.simple_arm import arm_world, simple_arm  # noqa: E402
from jiggle.sim.jiggle.goal_track import build_track  # noqa: E402
from jiggle.sim.jiggle.params import JiggleSettings  # noqa: E402
from jiggle.sim.jiggle.materials import default_jiggles  # noqa: E402
from jiggle.sim.jiggle.particles import ParticleBuilder  # noqa: E402
from jiggle.sim.jiggle.secondary import jiggle_rig  # noqa: E402
from jiggle.sim.jiggle.simulate import run, step_times  # noqa: E402
from jiggle.sim.jiggle.solver import ParticleSolver, step_numpy  # noqa: E402

FPS, SUBSTEPS = 30, 8
SPACING = 0.3            # metres between copies of the arm


# ---------------------------------------------------------------------------------- scenes
def grid_offsets(copies: int) -> np.ndarray:
    """(copies, 3) metres: a square grid in the XY plane, SPACING apart."""
    side = int(np.ceil(np.sqrt(copies)))
    i = np.arange(copies)
    return np.column_stack([(i % side) * SPACING, (i // side) * SPACING, np.zeros(copies)])


def copied_model(arm, copies: int, device: str):
    """The biceps copied `copies` times on a grid: the ParticleModel and each copy's offset (copies, 3)."""
    offsets = grid_offsets(copies)
    rest = (arm.rig.rest_cvs[None] + offsets[:, None]).reshape(-1, 3)
    jig = default_jiggles(arm.rig)[0]
    b = ParticleBuilder()
    b.add_muscles(rest, np.repeat(arm.rig.rest_volume, copies),
                  [replace(jig, name=f"{jig.name}_{i}") for i in range(copies)])
    return b.finalize(device), offsets


def swinging_goals(arm, offsets: np.ndarray, times: np.ndarray) -> np.ndarray:
    """(S, copies * 40, 3) goals: copy i's elbow swings 0..120 deg at 1.5 Hz with phase 2 pi i / copies,
    its static CVs (rig.static) placed at its offset, and the grid sways 5 cm along X at 1 Hz."""
    n = len(offsets)
    phase = 2.0 * np.pi * np.arange(n) / n
    angle = 60.0 * (1.0 - np.cos(2.0 * np.pi * 1.5 * times[:, None] + phase[None]))     # (S, n)
    cvs = arm.rig.static(arm_world(angle.reshape(-1))).cvs.reshape(len(times), n, -1, 3)
    sway = 0.05 * np.sin(2.0 * np.pi * times)[:, None, None, None] * np.array([1.0, 0.0, 0.0])
    return (cvs + offsets[None, :, None] + sway).reshape(len(times), -1, 3)


def warp_steps(model, solver, control, grid: np.ndarray) -> np.ndarray:
    """ParticleSolver.step called once per step of `grid` from the goals at grid[0]: positions
    (len(grid), N, 3) (integrate merges each step's closing half kick with the next one's opening)."""
    a, b = model.state(), model.state()
    solver.glue(a, control, grid[0])
    out = [a.numpy()[0]]
    for t0, t1 in zip(grid[:-1], grid[1:]):
        solver.step(a, b, control, t0, t1 - t0)
        a, b = b, a
        out.append(a.numpy()[0])
    return np.array(out)


def numpy_steps(model, solver, track, grid: np.ndarray):
    """step_numpy over the steps of `grid` from the goals at grid[0]: positions (len(grid), N, 3)."""
    g, gv, _ = track.sample(grid[0])
    x, v = g.copy(), gv.copy()
    out = [x]
    for a, b in zip(grid[:-1], grid[1:]):
        x, v = step_numpy(model, solver.flow(b - a)[0], track, x, v, a, b - a)
        out.append(x)
    return np.array(out)


# ---------------------------------------------------------------------------------- 1. 40 x 40
def bench_frame(arm, device: str, quick: bool) -> None:
    duration = 1.0 if quick else 4.0
    model, offsets = copied_model(arm, 40, device)
    times = clips.frames(FPS, duration)
    track = build_track(times, swinging_goals(arm, offsets, times))
    solver = ParticleSolver(model)
    grid = step_times(times, track.times, SUBSTEPS, solver.max_step)
    frames = len(times) - 1
    control = track.to_device(device)
    state, nxt = model.state(), model.state()

    def run_all():
        return run(model, track, times, SUBSTEPS, solver=solver)

    def integrate_all():
        solver.glue(state, control, times[0])
        solver.integrate(state, nxt, control, grid)
        wp.synchronize_device(device)

    t_run, xs = best(run_all, repeats=5, warmup=True)
    t_int, _ = best(integrate_all, repeats=5, warmup=True)
    # the NumPy reference over the first frames (its cost per frame does not change along the clip)
    nf = 3 if quick else 10
    sub = grid[grid <= times[nf] + 1e-9]
    t_np, ref = best(lambda: numpy_steps(model, solver, track, sub), repeats=1 if quick else 2)
    at = np.searchsorted(sub, times[:nf + 1] - 1e-9)
    err = np.abs(xs[:nf + 1] - ref[at]).max()
    err_step = np.abs(warp_steps(model, solver, control, sub) - ref).max()
    amp = np.linalg.norm(xs - track.pos, axis=2).max()
    ms_run, ms_int, ms_np = (t * 1e3 / f for t, f in ((t_run, frames), (t_int, frames), (t_np, nf)))
    print(f"## 40 muscles x 40 particles ({model.num_particles} particles, {model.num_springs} springs), "
          f"{FPS} fps, {SUBSTEPS} substeps ({(len(grid) - 1) / frames:.1f} steps per frame, max step "
          f"{solver.max_step * 1e3:.2f} ms), {frames} frames, device {device}")
    print(f"  sim.jiggle.simulate.run                     {ms_run:7.3f} ms/frame   ({'<' if ms_run < 1 else '>='} 1 ms: "
          f"{'holds' if ms_run < 1 else 'FAILS'})")
    print(f"  ParticleSolver.integrate alone    {ms_int:7.3f} ms/frame")
    print(f"  NumPy reference (step_numpy)      {ms_np:7.3f} ms/frame   run is {ms_np / ms_run:.1f}x faster, "
          f"integrate {ms_np / ms_int:.1f}x")
    print(f"  Warp vs NumPy over {nf} frames: max |x| difference {err * 1e6:.2f} um for run (integrate), "
          f"{err_step * 1e6:.2f} um for ParticleSolver.step chained (largest jiggle offset {amp * 1e3:.1f} mm)")


# ---------------------------------------------------------------------------------- 2. 1e5
def bench_large(arm, device: str, quick: bool) -> None:
    copies = 2500
    t0 = time.perf_counter()
    model, offsets = copied_model(arm, copies, device)
    t_build = time.perf_counter() - t0
    h = 1.0 / (FPS * SUBSTEPS)
    times = np.arange(4) / FPS
    track = build_track(times, swinging_goals(arm, offsets, times))
    solver = ParticleSolver(model)
    assert h <= solver.max_step
    control = track.to_device(device)
    a, b = model.state(), model.state()
    solver.glue(a, control, 0.0)
    steps = 0.0 + h * np.arange(9)

    def one_step():
        solver.step(a, b, control, 0.0, h)
        wp.synchronize_device(device)

    def eight_steps():
        solver.integrate(a, b, control, steps)
        wp.synchronize_device(device)

    reps = 5 if quick else 20
    t_step, _ = best(one_step, repeats=reps, warmup=True)
    t_eight, _ = best(eight_steps, repeats=max(2, reps // 4), warmup=True)
    x0, v0 = a.numpy()
    flow = solver.flow(h)[0]
    t_np, _ = best(lambda: step_numpy(model, flow, track, x0, v0, 0.0, h), repeats=1 if quick else 3)
    ref = numpy_steps(model, solver, track, steps)[-1]
    eight_steps()
    err = np.abs(b.numpy()[0] - ref).max()
    err_step = np.abs(warp_steps(model, solver, control, steps)[-1] - ref).max()
    amp = np.linalg.norm(ref - track.sample(steps[-1])[0], axis=1).max()
    print(f"\n## {model.num_particles} particles ({copies} muscles x 40, {model.num_springs} springs), "
          f"step {h * 1e3:.2f} ms, device {device}; model built in {t_build:.1f} s")
    print(f"  ParticleSolver.step               {t_step * 1e3:7.2f} ms   NumPy is {t_np / t_step:.1f}x slower "
          f"(goal >= 3)")
    print(f"  integrate over 8 steps / 8        {t_eight * 1e3 / 8:7.2f} ms   {t_np * 8 / t_eight:.1f}x")
    print(f"  step_numpy (float64 reference)    {t_np * 1e3:7.2f} ms")
    print(f"  after 8 steps: max |x_warp - x_numpy| {err * 1e6:.2f} um for integrate, {err_step * 1e6:.2f} um "
          f"for 8 x step (largest offset from the goals {amp * 1e3:.2f} mm)")


# ---------------------------------------------------------------------------------- 3. rates
def independence(name: str, bake, muscles, rates, substeps) -> list[str]:
    """Table rows for bake(fps, substeps) -> (JiggleResult, seconds) against 120 fps x 16 substeps."""
    ref, _ = bake(*clips.REF)
    d_ref = np.linalg.norm(ref.dynamic - ref.static, axis=2)
    M = len(ref.names)
    peak = d_ref.max()
    own = d_ref.reshape(len(ref.times), M, -1).max(axis=(0, 2))          # (M,) each muscle's peak
    fat = ref.names.index("belly_fat") if "belly_fat" in ref.names else None
    rows = []
    for fps in rates:
        for sub in substeps:
            r, secs = bake(fps, sub)
            k = np.round(r.times * clips.REF[0]).astype(int)
            e = np.linalg.norm(r.dynamic - ref.dynamic[k], axis=2).reshape(len(k), M, -1).max(axis=(0, 2))
            rel = np.where(own > 1e-4, e / np.maximum(own, 1e-300), 0.0)   # muscles that move < 0.1 mm: none
            m = int(np.argmax(rel))
            cells = [name, str(fps), str(sub), f"{secs * 1e3:.0f}", f"{e.max() / peak:.2%}",
                     f"{ref.names[m]} {rel[m]:.2%}", f"{rel[fat]:.2%}" if fat is not None else "-"]
            rows.append("| " + " | ".join(cells) + " |")
    print(f"  {name}: {M} muscle(s) ({muscles}), peak {peak * 1e3:.2f} mm, reference "
          f"{clips.REF[0]} fps x {clips.REF[1]} substeps")
    return rows


def end_effect(rig, jiggles, world_at, duration: float, device: str) -> None:
    """The whole clip at 24 fps (its last frame falls before the clip's end) against 120 fps x 16
    substeps over the whole clip: the goal track ends at the last output frame (sim/jiggle/secondary.py), so its
    one-sided end velocity, and the particles near the end, depend on where the frames stop."""
    bakes = {fps: jiggle_rig(rig, jiggles, world_at, clips.frames(fps, duration),
                             JiggleSettings(substeps=16, device=device)) for fps in (24, 120)}
    r, ref = bakes[24], bakes[120]
    k = np.round(r.times * 120).astype(int)
    d_ref = np.linalg.norm(ref.dynamic - ref.static, axis=2).reshape(len(ref.times), len(ref.names), -1)
    own = d_ref.max(axis=(0, 2))
    e = np.linalg.norm(r.dynamic - ref.dynamic[k], axis=2).reshape(len(k), len(r.names), -1).max(axis=2)
    rel = e / np.maximum(own, 1e-300)
    f, m = np.unravel_index(np.argmax(rel), rel.shape)
    print(f"  end effect, whole clip ({duration:.4f} s): 24 fps x 16 (last frame {r.times[-1]:.4f} s) vs 120 fps x 16: "
          f"worst {rel[f, m]:.2%} of {r.names[m]}'s own peak at frame {f} of {len(k) - 1} "
          f"({e.max() / d_ref.max():.2%} of the set's peak); before the last frame {rel[:-1].max():.2%}")


def bench_rates(arm, device: str, quick: bool) -> None:
    rates = (24, 120) if quick else clips.RATES
    substeps = (1, 16) if quick else clips.SUBSTEPS
    print("\n## frame rate / substep independence (error at common times / peak amplitude; issue: < 2%)")

    def timed(rig, jiggles, world_at, duration):
        cache = {}

        def bake(fps, sub):
            if (fps, sub) not in cache:
                t = time.perf_counter()
                r = jiggle_rig(rig, jiggles, world_at, clips.frames(fps, duration),
                               JiggleSettings(substeps=sub, device=device))
                cache[fps, sub] = r, time.perf_counter() - t
            return cache[fps, sub]
        return bake

    rows = independence("simple arm flex", timed(arm.rig, default_jiggles(arm.rig),
                                                 lambda t: arm_world(clips.flex_angle(t)), clips.CLIP_S),
                        "biceps", rates, substeps)
    bvh = ASSETS / "mocap" / "cmu_bvh" / "09_11.bvh"
    if bvh.exists():
        from jiggle.rig.character.body import BodyOptions
        from jiggle.rig.character.load import body_character
        from jiggle.rig.motion.mocap import load_clip
        from jiggle.rig.muscle.fit import fit_musculature
        clip = load_clip(bvh)
        t = time.perf_counter()
        mus = fit_musculature(body_character(clip, BodyOptions(resolution=8000 if quick else 20000)), "human")
        print(f"  (body and musculature for 09_11 built in {time.perf_counter() - t:.1f} s)")
        jiggles = default_jiggles(mus.rig, [m.spec.jiggle for m in mus.muscles])
        world_at = clips.clip_world(clip)
        # a whole number of 1/6 s, a frame at every rate: every bake's goal track ends at the same time
        common = np.floor(clip.duration * 6.0 + 1e-9) / 6.0
        rows += independence(f"body 09_11.bvh, {common:.3f} s", timed(mus.rig, jiggles, world_at, common),
                             "human template, default jiggles", rates, substeps)
        end_effect(mus.rig, jiggles, world_at, clip.duration, device)
    else:
        print(f"  (no {bvh}: body row skipped)")
    print("\n| scene | fps | substeps | run ms | max err / peak | worst muscle (err / own peak) "
          "| belly_fat (err / own peak) |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    print("\n".join(rows))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="shorter clips, fewer repeats and rates")
    ap.add_argument("--device", default="cpu")
    args = ap.parse_args()
    wp.init()
    arm = simple_arm()
    bench_frame(arm, args.device, args.quick)
    bench_large(arm, args.device, args.quick)
    bench_rates(arm, args.device, args.quick)


if __name__ == "__main__":
    main()
