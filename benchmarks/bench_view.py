"""`jiggle view`'s tuning loop: a slider change on the demo -> its new motion on the page, measured in one run.

    .venv/bin/python benchmarks/bench_view.py [--out DIR] [--repeats 5]

The demo (`jiggle demo`: 91 frames, the 11.9k-vertex generated body, 28 muscles) is baked into --out (a
temporary folder by default; an existing bake there is reused) and opened in a viewer page in this process
(sim.app.view.page.ViewerPage: a real viser server, no browser). The setup is rebuilt once (timed apart: it
is the server's start-up, not a slider's cost). Then, --repeats times, belly_fat's strength slider is set to
another value and the time is taken until the page has swapped the new motion in and redrawn the frame
(`ViewerPage.wait_motion`): the re-simulation (particles, blend, final skin over the cached static shapes and
goal tracks: Tuner.run), the new displacements and amplitudes (Playback.replace_motion) and the frame's
meshes queued to the browsers. Its parts are printed, and the ratio against recomputing the clip the way a
bake does (sim.bake.baker.Baker: drive, static shapes, particles, blend, both skins, no files) and against
rebuilding the setup for every change.

Target (issue 22): a slider change shows its new motion in under 1 s on the 2-core machine.
"""
from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))
os.environ.setdefault("MUJOCO_GL", "egl")


def bake_demo(out: str) -> None:
    from jiggle.sim.app.cli import main
    if os.path.isfile(os.path.join(out, "bake.npz")) and os.path.isfile(os.path.join(out, "bake.json")):
        return
    print(f"baking the demo into {out} ...", flush=True)
    code = main(["-q", "demo", "--out", out, "--formats", "npz", "--no-render"])
    if code != 0:
        raise SystemExit(f"the demo bake failed ({code})")


def baker_loop(setup) -> None:
    """The clip recomputed as a bake computes it (Baker.chunk and its skins), no files."""
    from jiggle.sim.bake.baker import Baker, num_chunks
    baker = Baker(setup, defer=False)
    state = None
    for c in range(num_chunks(setup)):
        arrays = baker.chunk(c, state)
        state = (arrays["state_x"], arrays["state_v"]) if "state_x" in arrays else None


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", help="the demo bake's folder (default: a temporary one)")
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    from timing import best

    from jiggle.sim.app.commands.view import open_viewer
    with tempfile.TemporaryDirectory() as tmp:
        out = args.out or os.path.join(tmp, "demo")
        bake_demo(out)
        t = time.perf_counter()
        page = open_viewer(out, port=0, paused=True, tune=True, log=lambda s: None)
        try:
            if not page.wait_tuner(300):
                raise SystemExit(f"tuning is off: {page.tune_error}")
            tuner, pb = page.tuner, page.pb
            start_s = time.perf_counter() - t
            print(f"demo: {pb.T} frames, {pb.V} vertices, {len(pb.muscles)} muscles; viewer up and setup rebuilt in "
                  f"{start_s:.1f} s (once per server: prepare {tuner.prepare_s:.1f} s, static shapes and goal "
                  f"tracks cached in {tuner.cache_s:.2f} s)")
            page.select(next(m for m, i in enumerate(pb.muscles) if i.name == "belly_fat"))
            page.g_t_both.value = False
            base = float(page.g_t_strength.value)
            values = [1.0 if base != 1.0 else 0.25, base]
            before = page.motion_version
            page.g_t_strength.value = values[0]                     # warm-up: kernels loaded, buffers made
            page.wait_motion(before, 120)
            totals, runs = [], []
            for r in range(args.repeats):
                v = values[(r + 1) % 2]
                before = page.motion_version
                t = time.perf_counter()
                page.g_t_strength.value = v
                if not page.wait_motion(before, 120):
                    raise SystemExit("the re-simulation did not finish")
                totals.append(time.perf_counter() - t)
                runs.append(page.last_run_s)
            from jiggle.sim.app.view.tuning import Tuning
            replace_s, _ = best(lambda: pb.replace_motion(pb.cvs_dynamic, pb.skin_final), 3)
            draw_s, _ = best(lambda: page.draw(pb.T // 2), 3)
            setup = tuner.tuned_setup(Tuning().with_muscle("belly_fat", strength=values[0]))
            bake_s, _ = best(lambda: baker_loop(setup), 2)
            fast = min(totals)
            print(f"slider change -> new motion shown: best {fast:.3f} s, median {statistics.median(totals):.3f} s "
                  f"over {len(totals)} changes (target < 1 s: {'met' if fast < 1.0 else 'NOT met'})")
            print(f"  re-simulate + re-skin (Tuner.run): best {min(runs):.3f} s; displacements and amplitudes "
                  f"{replace_s:.3f} s; one frame's meshes queued {draw_s:.3f} s")
            print(f"  vs recomputing the clip as a bake does (Baker, every stage, no files): {bake_s:.3f} s "
                  f"-> {bake_s / fast:.2f}x faster")
            print(f"  vs rebuilding the setup for each change: {tuner.prepare_s + bake_s:.1f} s "
                  f"-> {(tuner.prepare_s + bake_s) / fast:.0f}x faster")
        finally:
            page.stop()


if __name__ == "__main__":
    main()
