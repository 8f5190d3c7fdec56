"""The cost of contacts between muscles of different body parts, measured in one run: on against off, per frame,
capsules and floor on in both.

    .venv/bin/python benchmarks/bench_tissue_contacts.py [--frames N] [--no-demo]

1. The demo (scenes/default.toml: a generated body, its muscles, jumping jacks): the bake's simulate stage
   (sim.jiggle.simulate over chunks of 64 frames, as sim/bake/baker.py runs it: goal track, colliders on the
   knots, the particles) per frame, tissue contacts off and on, and how many particle-frames touched another
   muscle.
2. 40 muscles x 40 particles: fat pads in two columns (each its own body part), bobbing at their own phases
   into their neighbours (a worst case: most particles touch another muscle every frame), beside 20
   capsules, 30 fps, 4 substeps: sim.jiggle.simulate.run per frame, off and on.

Both split "on" into the contact passes (TissuePass.run: broad phase, hash grid, contact kernel) and the rest
(the solver stepped one step a launch, its capsules included).

Times are the best of several repeats after a warm-up (kernel compiles excluded), off and on alternated (a busy
spell of the shared machine slows both alike); ratios on / off are of the same run.
"""
from __future__ import annotations

import argparse
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from dataclasses import replace  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from timing import chunk_spans  # noqa: E402

from jiggle.rig.character.capsules import BoneCapsules  # noqa: E402
from jiggle.sim.jiggle.colliders import ColliderModel, collider_model  # noqa: E402
from jiggle.sim.jiggle.goal_track import build_track  # noqa: E402
from jiggle.sim.jiggle.params import MuscleJiggle, section_goals  # noqa: E402
from jiggle.sim.jiggle.particles import ParticleBuilder, muscle_model  # noqa: E402
from jiggle.sim.jiggle.simulate import goals, run, simulate, step_times  # noqa: E402
from jiggle.sim.jiggle.solver import ParticleSolver  # noqa: E402
from jiggle.sim.jiggle.tissue_contacts import TissueContactModel, TissuePass, tissue_contact_model  # noqa: E402


def pass_seconds(fn) -> float:
    """Seconds spent in the contact passes (TissuePass.run: broad phase, hash grid, contact kernel) during fn()."""
    spent = [0.0]
    orig = TissuePass.run

    def timed(self, *a, **k):
        t = time.perf_counter()
        orig(self, *a, **k)
        spent[0] += time.perf_counter() - t
    TissuePass.run = timed
    try:
        fn()
    finally:
        TissuePass.run = orig
    return spent[0]


def paired(off, on, repeats: int) -> tuple[float, float]:
    """(seconds off, seconds on): the fastest of `repeats` calls of each, alternated after one warm-up call
    of each."""
    off(), on()
    t_off, t_on = [], []
    for _ in range(repeats):
        for fn, ts in ((off, t_off), (on, t_on)):
            t = time.perf_counter()
            fn()
            ts.append(time.perf_counter() - t)
    return min(t_off), min(t_on)


def demo(frames: int, repeats: int = 3) -> dict:
    from jiggle.sim.bake.setup import BakeRequest, prepare
    s = prepare(BakeRequest(frames=frames, collisions=True))
    rig = s.rig
    model = muscle_model(rig, list(s.jiggles), "cpu", gravity=s.settings.gravity)
    cm = collider_model(rig, s.character, floor=s.floor)
    tm = tissue_contact_model(rig, model)
    times = s.times
    world = np.asarray(s.world_at(s.knots))
    static = rig.static(world)
    chunks = chunk_spans(s.times, s.knots)
    touched = [0]

    def bake(on: bool):
        solver = ParticleSolver(model)
        state = None
        for c, (_, f1, a, ka, kb) in enumerate(chunks):
            track = goals(rig, s.knots[ka:kb], static.cvs[ka:kb], s.settings)
            col = cm.at(s.knots[ka:kb], world[ka:kb], track.cut)
            sink = {}
            _, state = simulate(model, track, times[a:f1], s.settings, solver=solver, preroll=None if c == 0 else 0.0,
                                start=state, colliders=col, contacts=sink, tissue=tm if on else None)
            if on:
                touched[0] += int((sink["records"][..., 2] > cm.num_capsules).sum())
    off_s, on_s = paired(lambda: bake(False), lambda: bake(True), repeats)
    touched[0] = 0
    pass_s = min(pass_seconds(lambda: bake(True)) for _ in range(2))
    T = len(times)
    return {"frames": T, "muscles": rig.M, "particles": model.num_particles, "bones": len(set(tm.bone.tolist())),
            "pairs_of_muscles_that_may_touch": int(tm.mask.sum() // 2), "off_ms": 1e3 * off_s / T,
            "on_ms": 1e3 * on_s / T, "ratio": on_s / off_s, "contact_pass_ms": 1e3 * pass_s / T,
            "stepping_one_step_a_launch_ms": 1e3 * (on_s - pass_s) / T,
            "tissue_particle_frames_per_run": touched[0] // 2}


def column(muscles: int = 40, capsules: int = 20, seconds: float = 2.0, repeats: int = 5) -> dict:
    """40 fat pads in two columns (each pad its own body part) swaying into their neighbours, 20 capsules."""
    rng = np.random.default_rng(0)
    a = 2 * np.pi * np.arange(8) / 8
    ring = np.stack([np.cos(a) * 0.03, np.zeros(8), np.sin(a) * 0.03], axis=1)
    pad = np.concatenate([ring + [0, y, 0] for y in np.linspace(-0.06, 0.06, 5)])
    # two columns 14 cm apart (y), pads 6.6 cm apart up each (z): 6 cm across, neighbours 6 mm apart
    centres = np.stack([np.full(muscles, 0.12), np.tile([-0.07, 0.07], muscles // 2),
                        np.repeat(np.arange(muscles // 2) * 0.066, 2)], axis=1)
    rest = np.concatenate([pad + c for c in centres])
    jig = MuscleJiggle(name="pad", frequency_hz=3.0, damping_ratio=0.3, goal=section_goals(0.5, 0.2), density=900.0,
                       spring_frequency_hz=6.0, spring_damping_ratio=0.3, max_offset=0.06)
    b = ParticleBuilder()
    b.add_muscles(rest, np.full(muscles, 3e-4), [replace(jig, name=f"pad{m}") for m in range(muscles)])
    model = b.finalize("cpu")
    fps, knot_rate = 30.0, 120.0
    knots = np.arange(0, seconds + 1e-9, 1 / knot_rate)
    phase = rng.uniform(0, 2 * np.pi, muscles)
    # each pad bobs up and down (z) by up to 3 cm and swings toward the other column (y) at 2-3 Hz, at its own
    # phase: into the pads above, below and across
    amp = np.sin(2 * np.pi * 2.5 * knots[:, None] + phase[None])                        # (S, M)
    goal = rest[None].repeat(len(knots), 0).reshape(len(knots), muscles, 40, 3)
    goal[..., 2] += 0.03 * amp[..., None]
    goal[..., 1] -= 0.03 * np.sign(centres[:, 1])[None, :, None] * np.abs(amp)[..., None]
    track = build_track(knots, goal.reshape(len(knots), -1, 3), cuts=np.zeros(len(knots) - 1, bool))
    z = np.linspace(0.0, 1.2, capsules)
    ends = np.stack([np.stack([np.full(capsules, 0.21), np.full(capsules, -0.25), z], 1),
                     np.stack([np.full(capsules, 0.21), np.full(capsules, 0.25), z], 1)], axis=1)
    caps = BoneCapsules(joint=np.zeros(capsules), child=np.full(capsules, -1), local=ends,
                        radius=np.full(capsules, 0.03),
                        names=[f"c{c}" for c in range(capsules)], parents=np.array([-1]))
    cm = ColliderModel.from_pairs(caps, np.ones((muscles, capsules), bool), floor=-0.05)
    col = cm.on_track(knots, np.repeat(ends.reshape(1, -1, 3), len(knots), 0))
    tm = TissueContactModel.build(rest, model.group_offsets, np.arange(muscles))
    out_times = np.arange(0, seconds - 0.05, 1 / fps)
    solver = ParticleSolver(model)
    sink = {}

    def go(on):
        return run(model, track, out_times, substeps=4, solver=solver, colliders=col, contacts=sink,
                   tissue=tm if on else None)
    off_s, on_s = paired(lambda: go(False), lambda: go(True), repeats)
    # the parts of "on": the contact passes, and the rest (stepping one step a launch)
    pass_s = min(pass_seconds(lambda: go(True)) for _ in range(3))
    touched = int((sink["records"][..., 2] > capsules).sum())
    grid = step_times(out_times, knots, 4, solver.max_step)
    T = len(out_times) - 1
    return {"muscles": muscles, "particles": model.num_particles, "capsules": capsules, "frames": T,
            "steps_per_frame": (len(grid) - 1) / T, "off_ms": 1e3 * off_s / T, "on_ms": 1e3 * on_s / T,
            "ratio": on_s / off_s, "contact_pass_ms": 1e3 * pass_s / T,
            "stepping_one_step_a_launch_ms": 1e3 * (on_s - pass_s) / T, "tissue_particle_frames": touched}


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--frames", type=int, default=120, help="demo frames")
    p.add_argument("--no-demo", action="store_true", help="only the 40 x 40 column")
    a = p.parse_args()
    out = {"column_40x40": column()}
    print(json.dumps(out, indent=1), flush=True)
    if not a.no_demo:
        out["demo"] = demo(a.frames)
        print(json.dumps({"demo": out["demo"]}, indent=1))


if __name__ == "__main__":
    main()
