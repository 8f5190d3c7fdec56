"""The FEM hero mode's cost: `jiggle bake --tissue fem` against the particle bake of the same clip, in one run.

    python benchmarks/bench_fem_bake.py [--clip mocap/cmu_bvh/09_11.bvh] [--character characters/CesiumMan.glb]

Bakes the clip on the character twice (the particles, then the FEM hero mode; npz only), runs `jiggle compare`
on both, and writes benchmarks/results/fem_bake.{md,json}: each bake's wall time (the whole command) and its
frames' time (bake.json timings.frames_s), their ratio, the FEM's step cost and its smallest det F / inverted tets,
and both bakes' skin figures (peak, torn edges, gradient p99.9, folds over LBS's).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
ASSETS = ROOT.parent / "shared" / "assets"
RESULTS = ROOT / "benchmarks" / "results"


def jiggle(*argv) -> float:
    """Run `jiggle ARGV` (this interpreter's package), return its wall seconds; raise on failure."""
    t = time.perf_counter()
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    r = subprocess.run([sys.executable, "-m", "jiggle", *argv], capture_output=True, text=True, env=env)
    if r.returncode != 0:
        raise SystemExit(f"jiggle {' '.join(argv)} failed ({r.returncode}):\n{r.stderr[-2000:]}")
    return time.perf_counter() - t


def figures(out: Path) -> dict:
    bake = json.loads((out / "bake.json").read_text())
    metrics = json.loads((out / "metrics.json").read_text())
    t = metrics["skin_quality"]["targets"]
    row = {"frames": bake["frames"], "frames_s": bake["timings"]["frames_s"], "peak_mm": metrics["skin"]["max_mm"],
           "torn_edges": t["torn_edges"]["value"], "gradient_p999": t["gradient_p999"]["value"],
           "folds_over_lbs": t["folds_added_over_lbs"]["value"]}
    if bake.get("fem"):                  # null with the particles
        f = bake["fem"]
        row.update({"tets": f["tets"], "steps": f["steps"], "ms_per_step": f["ms_per_step"], "min_det": f["min_det"],
                    "inverted_max": f["inverted_max"], "fem_setup_s": bake["timings"].get("fem_setup_s")})
    return row


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--clip", default="mocap/cmu_bvh/09_11.bvh")
    p.add_argument("--character", default="characters/CesiumMan.glb")
    a = p.parse_args(argv)
    clip, character = ASSETS / a.clip, ASSETS / a.character
    if not (clip.exists() and character.exists()):
        print(f"skipped: {clip} or {character} is absent")
        return {}
    rows = {}
    with tempfile.TemporaryDirectory(prefix="jiggle-fem-bench-") as tmp:
        for solver in ("particles", "fem"):
            out = Path(tmp) / solver
            wall = jiggle("bake", "--clip", str(clip), "--character", str(character), "--tissue", solver,
                          "--formats", "npz", "--out", str(out), "-q")
            jiggle("compare", str(out), "--no-render")
            rows[solver] = {"wall_s": wall, **figures(out)}
            print(solver, json.dumps(rows[solver]), flush=True)
    p_, f_ = rows["particles"], rows["fem"]
    result = {"clip": a.clip, "character": a.character, "rows": rows,
              "ratio_wall": f_["wall_s"] / p_["wall_s"], "ratio_frames": f_["frames_s"] / p_["frames_s"]}
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "fem_bake.json").write_text(json.dumps(result, indent=1))
    lines = ["# FEM hero mode vs particles (benchmarks/bench_fem_bake.py)", "",
             f"{a.character} on {a.clip}, {p_['frames']} frames, one run on this machine; wall = the whole "
             "`jiggle bake` command, frames = bake.json timings.frames_s (the chunks: drive, static, simulate, skin).",
             "", "| tissue | wall s | frames s | peak mm | torn edges | gradient p99.9 | folds / LBS | tets | ms/step | "
                 "min det F | inverted |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    for k, r in rows.items():
        lines.append(f"| {k} | {r['wall_s']:.1f} | {r['frames_s']:.2f} | {r['peak_mm']:.2f} | {r['torn_edges']} | "
                     f"{r['gradient_p999']:.3f} | {r['folds_over_lbs']:.3f} | {r.get('tets', '-')} | "
                     f"{r.get('ms_per_step', '-')} | {r.get('min_det', '-')} | {r.get('inverted_max', '-')} |")
    lines += ["", f"FEM / particles: **{result['ratio_wall']:.1f}x** the whole command, "
                  f"**{result['ratio_frames']:.0f}x** the frames."]
    (RESULTS / "fem_bake.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return result


if __name__ == "__main__":
    main()
