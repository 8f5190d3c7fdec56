"""The bake's particle stage: particle-steps per second, against Blender's soft body on the same particles.

    .venv/bin/python benchmarks/bench_particles.py [--quick] [--seconds 10] [--device cpu] [--blender-threads 1]

The model: the simple arm's biceps copied 40 times on a grid (benchmarks/bench_jiggle.py's copied_model,
default jiggles): 1,600 particles and their springs (sim.jiggle.particles); goals from bench_jiggle's
swinging_goals (each copy's elbow swinging at its own phase, the grid swaying) at the goal knots the
bake uses (120 Hz and every output frame, sim.jiggle.secondary.knot_times), 30 fps output, 10 s.

1. Ours, the bake path: the particle stage exactly as sim/bake/baker.py's Baker.chunk runs it, per chunk
   of 64 output frames: the chunk's goal track (its knots +- MARGIN, built with build_track beforehand:
   the bake's `goals` is the drive's work, not timed here), then sim.jiggle.simulate.simulate(model, track,
   the chunk's times with the frame before it, JiggleSettings(substeps=4), solver=..., preroll=None for
   the first chunk else 0, start=the state the chunk before returned). Best of 3 after a warm-up.
   Particle-steps = particles x the solver's steps (step_times over each chunk's times and knots with
   the solver's max_step: 4 substeps a frame, each split further to the neighbour springs' limit).
   When the solver has a `launches` count, launches per chunk are reported.
2. Ours, the kernel alone: ParticleSolver.integrate over the same step grids and goal tracks (uploaded
   beforehand), chunk after chunk, nothing read back.
3. The peer, Blender's soft body (`bpy`, the extra "blender", in .venv/blender: bpy pins numpy < 2, so it
   runs benchmarks/blender_softbody.py in a subprocess and the two exchange .npz files; JIGGLE_BPY_PYTHON
   names another interpreter; JIGGLE_BLENDER=0 or no bpy: skipped, the reason printed). A mesh of the
   same 1,600 vertices (rest positions) and edges (the model's springs); goals played by a Mesh Cache
   modifier (PC2 of the same goal motion at the 30 fps frames, which Blender interpolates linearly
   inside a frame) under a Soft Body modifier with goals and edge springs, gravity off, no collisions,
   step_min = step_max = our solver's steps per frame (Heun, two force evaluations a step; Blender's
   diagnose output confirms the count), the same frame count; one thread (render threads FIXED 1, as
   Warp's CPU kernels run on one). Timed: scene.frame_set over the frames (depsgraph evaluated: mesh
   cache, soft body, its point cache in memory), best of 3. Particle-steps/s = vertices x steps per
   frame x frames / seconds.
   Parameters: Blender's goal springs in its own units are not ours, so only their shape is mapped:
   each vertex's final goal f is the particle's goal weight w (0.9 tendon .. 0.4 belly), which with
   goal_spring 0.999 gives ks = f s / (1 - f s) ~ w / (1 - w), our k_i's dependence on w; goal friction 5,
   edge pull = push = 0.05, damping 0.5, mass 1, no media friction (BLENDER below). Blender's edge springs
   keep the mesh's rest lengths (ours: zero-length springs between offsets, the goal shape's current edge),
   and stiffer edges (pull 0.5) or lighter vertices (mass 0.1) blow up at this step count. The point is
   the cost of a step; each run's offsets from its goals are printed to show both simulate.
4. The table: the rates, ms per frame, the ratio ours / Blender, and the issue's targets (bake path
   >= 25 M particle-steps/s at 1,600 particles; >= 10x Blender's soft body) marked met / NOT met.

One core for ours: OPENBLAS_NUM_THREADS=1 before NumPy loads; Warp's CPU kernels run on one thread.
"""
from __future__ import annotations

import argparse
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import json  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
from dataclasses import dataclass  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import warp as wp  # noqa: E402

wp.config.quiet = True
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_jiggle import copied_model, swinging_goals  # noqa: E402
from timing import best, chunk_spans  # noqa: E402  (benchmarks/timing.py)

from jiggle.rig.muscle.simple_arm import simple_arm  # noqa: E402
from jiggle.sim.jiggle.goal_track import build_track  # noqa: E402
from jiggle.sim.jiggle.params import JiggleSettings  # noqa: E402
from jiggle.sim.jiggle.materials import default_jiggles  # noqa: E402
from jiggle.sim.jiggle.secondary import DEFAULT_GOAL_RATE, knot_times  # noqa: E402
from jiggle.sim.jiggle.simulate import simulate, step_times  # noqa: E402
from jiggle.sim.jiggle.solver import ParticleSolver  # noqa: E402

FPS, CHUNK, COPIES, SUBSTEPS = 30, 64, 40, 4
TARGET_RATE = 25e6          # particle-steps/s, the bake path at 1,600 particles
TARGET_RATIO = 10.0         # ours / Blender's soft body
BLENDER = {"goal_spring": 0.999, "goal_friction": 5.0, "pull": 0.05, "push": 0.05, "damping": 0.5, "mass": 1.0,
           "friction": 0.0}
"""Blender's soft body settings (benchmarks/blender_softbody.py; the module says why these)."""
BLENDER_SCRIPT = Path(__file__).resolve().parent / "blender_softbody.py"


# ---------------------------------------------------------------------------------- the bake's chunks
@dataclass
class Chunk:
    f0: int                 # output frames [f0, f1)
    f1: int
    a: int                  # the chunk's first time index: f0 - 1 after the first chunk
    track: object           # GoalTrack of the chunk's knots (+- MARGIN)
    grid: np.ndarray        # the solver's step times over times[a:f1]


def bake_chunks(times, knots, static, settings, solver) -> list[Chunk]:
    """The chunks of sim/bake/baker.py's Baker.chunk: frames, knots +- MARGIN, goal track, step grid."""
    out = []
    for f0, f1, a, ka, kb in chunk_spans(times, knots, CHUNK):
        track = build_track(knots[ka:kb], static[ka:kb], ratio=settings.cut_ratio, jump=settings.cut_jump)
        assert not track.cut.any(), "the swinging goals have no cut"
        out.append(Chunk(f0, f1, a, track, step_times(times[a:f1], track.times, settings.substeps,
                                                       solver.max_step)))
    return out


def bake_particles(model, solver, chunks, times, settings) -> np.ndarray:
    """(T, N, 3) dynamic positions: simulate() chunk after chunk, as Baker.chunk calls it."""
    out, state = np.empty((len(times), model.num_particles, 3)), None
    for c, ch in enumerate(chunks):
        dyn, state = simulate(model, ch.track, times[ch.a:ch.f1], settings, solver=solver,
                              preroll=None if c == 0 else 0.0, start=state if c > 0 else None)
        out[ch.f0:ch.f1] = dyn[1:] if c > 0 else dyn
    return out


def kernel_pass(model, solver, chunks, device: str):
    """A function that runs ParticleSolver.integrate over every chunk's step grid and goal track (uploaded here,
    beforehand), chunk after chunk, nothing read back: the kernels alone."""
    controls = [ch.track.to_device(device) for ch in chunks]
    s_a, s_b = model.state(), model.state()

    def integrate_all():
        a, b = s_a, s_b
        solver.glue(a, controls[0], chunks[0].grid[0])
        for ctrl, ch in zip(controls, chunks):
            solver.integrate(a, b, ctrl, ch.grid)
            a, b = b, a
        wp.synchronize_device(device)
    return integrate_all


def launch_count(solver):
    """The solver's launch counter when it has one (an int, or a method returning one), else None."""
    v = getattr(solver, "launches", None)
    if callable(v):
        v = v()
    return int(v) if isinstance(v, (int, np.integer)) and not isinstance(v, bool) else None


# ---------------------------------------------------------------------------------- Blender
def bpy_python() -> tuple[str | None, str]:
    """(an interpreter that imports bpy, '') or (None, why not): JIGGLE_BLENDER=0 skips; JIGGLE_BPY_PYTHON,
    this interpreter or ./dev.sh's .venv/blender."""
    if os.environ.get("JIGGLE_BLENDER", "1") == "0":
        return None, "JIGGLE_BLENDER=0"
    env = os.environ.get("JIGGLE_BPY_PYTHON")
    for py in [env] if env else [sys.executable, str(ROOT / ".venv" / "blender" / "bin" / "python")]:
        if not py or not os.path.exists(py):
            continue
        try:
            if subprocess.run([py, "-c", "import bpy"], capture_output=True, timeout=300).returncode == 0:
                return py, ""
        except (OSError, subprocess.TimeoutExpired):
            pass
    return None, ("bpy (Blender as a Python module) is not installed: ./dev.sh install puts it in .venv/blender "
                  "(extra 'blender'), or set JIGGLE_BPY_PYTHON")


def blender_softbody(py: str, model, goal: np.ndarray, goals: np.ndarray, steps: int, threads: int,
                     repeats: int) -> tuple[dict | None, str]:
    """(result, '') or (None, why): Blender's soft body over goals (F + 1, N, 3) at `steps` per frame."""
    with tempfile.TemporaryDirectory(prefix="jiggle_bench_particles_") as tmp:
        src, out = os.path.join(tmp, "in.npz"), os.path.join(tmp, "out.npz")
        np.savez(src, rest=model.rest, edges=model.springs, goal=goal, goals=goals)
        params = {**BLENDER, "steps_per_frame": steps, "fps": FPS, "threads": threads, "repeats": repeats}
        try:
            r = subprocess.run([py, str(BLENDER_SCRIPT), src, out, json.dumps(params)], capture_output=True,
                               text=True, timeout=600)
        except subprocess.TimeoutExpired:
            return None, "Blender's run took over 600 s"
        if r.returncode != 0 or not os.path.exists(out):
            return None, f"Blender failed (exit {r.returncode}): {(r.stdout + r.stderr)[-1500:]}"
        with np.load(out) as d:
            return {"seconds": d["seconds"], "sampled": d["sampled"], "positions": d["positions"],
                    "info": json.loads(str(d["info"]))}, ""


# ---------------------------------------------------------------------------------- main
def verdict(ok: bool) -> str:
    return "met" if ok else "NOT met"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="2 s of motion, one repeat")
    ap.add_argument("--seconds", type=float, default=10.0, help="seconds of motion (default 10)")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--blender-threads", type=int, default=1, help="Blender's soft body threads (default 1)")
    args = ap.parse_args()
    seconds = 2.0 if args.quick else args.seconds
    repeats = 1 if args.quick else 3
    wp.init()

    arm = simple_arm()
    model, offsets = copied_model(arm, COPIES, args.device)
    settings = JiggleSettings(substeps=SUBSTEPS, device=args.device)
    times = np.arange(int(round(seconds * FPS)) + 1) / FPS
    knots = knot_times(times, settings.goal_rate or max(DEFAULT_GOAL_RATE, FPS))
    static = swinging_goals(arm, offsets, knots)
    solver = ParticleSolver(model)
    chunks = bake_chunks(times, knots, static, settings, solver)
    frames = len(times) - 1
    n = model.num_particles
    steps = sum(len(ch.grid) - 1 for ch in chunks)
    per_frame = steps / frames
    print(f"## {COPIES} x the simple arm's biceps: {n} particles, {model.num_springs} springs; {seconds:g} s at {FPS} fps "
          f"({frames} frames, {len(chunks)} chunks of {CHUNK}), goal knots at {settings.goal_rate or max(DEFAULT_GOAL_RATE, FPS):g} Hz, "
          f"substeps {SUBSTEPS}: {steps} solver steps ({per_frame:g} per frame; max step "
          f"{solver.max_step * 1e3:.2f} ms), device {args.device}")

    # 1. the bake path
    l0 = launch_count(solver)
    bake_particles(model, solver, chunks, times, settings)            # warm-up (kernel compiles), and launches
    l1 = launch_count(solver)
    t_bake, xs = best(lambda: bake_particles(model, solver, chunks, times, settings), repeats=repeats, warmup=False)

    # 2. the kernel alone
    t_kernel, _ = best(kernel_pass(model, solver, chunks, args.device), repeats=repeats, warmup=True)

    goals_f = swinging_goals(arm, offsets, times)                     # the goals at the output frames
    ours_off = np.linalg.norm(xs - goals_f, axis=2)
    rate_bake, rate_kernel = n * steps / t_bake, n * steps / t_kernel
    if l0 is not None and l1 is not None:
        print(f"  solver.launches: {(l1 - l0) / len(chunks):.1f} per chunk ({l1 - l0} in one pass of "
              f"{len(chunks)} chunks)")
    elif hasattr(solver, "launches"):
        print(f"  solver.launches = {getattr(solver, 'launches')!r}")
    print(f"  ours: offsets from the goals max {ours_off.max() * 1e3:.2f} mm, mean {ours_off.mean() * 1e3:.2f} mm; "
          f"finite: {bool(np.isfinite(xs).all())}")

    # 3. Blender
    blender, why = None, ""
    py, why = bpy_python()
    if py is not None:
        bsteps = int(round(per_frame))
        goal = np.tile(default_jiggles(arm.rig)[0].goal, COPIES)     # copied_model's jiggle on every copy
        blender, why = blender_softbody(py, model, goal, goals_f, bsteps, args.blender_threads, repeats)
    if blender is None:
        print(f"  Blender's soft body skipped: {why}")
    else:
        info = blender["info"]
        t_bl = float(np.min(blender["seconds"]))
        bsteps = info["steps_per_frame"][0]
        rate_bl = info["vertices"] * bsteps * info["frames"] / t_bl
        diag = info["diagnose_steps_per_frame"]
        print(f"  Blender {info['blender']} soft body: {info['vertices']} vertices, {info['edges']} edge springs, "
              f"step_min = step_max = {bsteps} (diagnose: {sorted(set(diag))} steps/frame over {len(diag)} "
              f"frames; 2x steps takes {info['time_ratio_2x_steps']:.2f}x the time), {info['threads']} thread(s), "
              f"{info['frames']} frames, repeats {np.round(blender['seconds'], 3).tolist()} s (equal: "
              f"{info['repeats_equal']})")
        print(f"  Blender: goals played back within {info['goal_playback_max_err_m'] * 1e6:.2f} um (soft body off); "
              f"offsets from the goals max {info['max_offset_m'] * 1e3:.2f} mm, mean {info['mean_offset_m'] * 1e3:.2f} "
              f"mm at frames {blender['sampled'].tolist()}")
        if bsteps != per_frame:
            print(f"  (Blender takes {bsteps} steps per frame, ours {per_frame:g}: rates are per step)")

    # 4. the table
    print("\n| run | M particle-steps/s | ms per frame | target | |")
    print("| --- | --- | --- | --- | --- |")
    print(f"| ours, bake path (simulate per chunk) | {rate_bake / 1e6:.1f} | {t_bake * 1e3 / frames:.3f} | "
          f">= {TARGET_RATE / 1e6:.0f} M/s | {verdict(rate_bake >= TARGET_RATE)} |")
    print(f"| ours, kernel only (ParticleSolver.integrate) | {rate_kernel / 1e6:.1f} | {t_kernel * 1e3 / frames:.3f} | | |")
    if blender is None:
        print(f"| Blender soft body | skipped: {why} | | | |")
    else:
        ratio = rate_bake / rate_bl
        print(f"| Blender soft body ({info['threads']} thread) | {rate_bl / 1e6:.2f} | {t_bl * 1e3 / info['frames']:.3f} "
              f"| | |")
        print(f"| ours / Blender (bake path) | {ratio:.1f}x | | >= {TARGET_RATIO:.0f}x | {verdict(ratio >= TARGET_RATIO)} |")
        print(f"| ours / Blender (kernel only) | {rate_kernel / rate_bl:.1f}x | | | |")


if __name__ == "__main__":
    main()
