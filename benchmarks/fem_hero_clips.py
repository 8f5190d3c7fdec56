"""The FEM hero mode (`jiggle bake --tissue fem`) on every shared CMU clip, on CesiumMan and on the generated body:
does the solid ever invert, and what does keeping it whole cost?

    python benchmarks/fem_hero_clips.py [--seconds 2] [--clips 01_01,02_03,...] [--characters cesium,generated]
                                        [--before REV]

Each clip is cut to its most vigorous `--seconds` (the window with the largest mean joint acceleration: `vigorous`;
a clip no longer than that is baked whole) and baked with the defaults and `--tissue fem` (npz only). Per bake:
frames, wall seconds, the solid's smallest det F over the output frames and at any step's end, the most tets
inverted at an output frame and on how many frames, the steps kept, the steps redone in halves and the steps ended
by the line search (sim/fem/step.py). With --before REV, CMU 09_11 on CesiumMan is also baked by REV's tree (laid out
as benchmarks/bake_identity.py does) in the same run: the time ratio of this checkout's hero mode over REV's.

Writes benchmarks/results/fem_hero_clips.{md,json}. The issue's whole run (4 s cuts) takes ~2.5 h on 2 cores; the
default 2 s cuts, ~45 min.
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

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
ASSETS = ROOT.parent / "shared" / "assets"
RESULTS = ROOT / "benchmarks" / "results"
CLIPS = ("09_11", "05_02", "02_04", "01_01", "02_03")
"""The shared CMU clips, the one the hero mode's cost is compared on first, then those with leaps and landings."""
CHARACTERS = {"cesium": ASSETS / "characters" / "CesiumMan.glb", "generated": None}


def vigorous(clip_path: Path, seconds: float) -> tuple[float, float | None]:
    """(start, end) seconds of the clip's most vigorous `seconds`: the window with the largest mean over its frames
    of the joints' mean acceleration (m/s^2, by forward kinematics of the clip); (0, None) for a clip no longer."""
    from jiggle.rig.motion.mocap import load_clip
    clip = load_clip(str(clip_path))
    _, p = clip.world()
    dt = 1.0 / clip.fps
    acc = np.linalg.norm(np.diff(p, 2, axis=0), axis=-1).mean(axis=1) / dt ** 2
    win = int(round(seconds / dt))
    if len(acc) <= win:
        return 0.0, None
    c = np.concatenate([[0.0], np.cumsum(acc)])
    i = int(np.argmax(c[win:] - c[:-win]))
    return round(i * dt, 3), round(i * dt + seconds, 3)


def bake(out: Path, clip: Path, character: Path | None, start: float, end: float | None,
         python: list[str] | None = None, env: dict | None = None) -> float:
    """Run the hero bake; its wall seconds (raises on failure)."""
    argv = (python or [sys.executable, "-m", "jiggle"]) + ["bake", "--clip", str(clip), "--tissue", "fem",
                                                           "--formats", "npz", "--out", str(out), "-q",
                                                           "--start", str(start)]
    if end is not None:
        argv += ["--end", str(end)]
    if character is not None:
        argv += ["--character", str(character)]
    t = time.perf_counter()
    r = subprocess.run(argv, capture_output=True, text=True, env={**os.environ, **(env or {})})
    if r.returncode != 0:
        raise SystemExit(f"{' '.join(argv)} failed ({r.returncode}):\n{r.stderr[-2000:]}")
    return time.perf_counter() - t


def row(out: Path, wall: float) -> dict:
    bake = json.loads((out / "bake.json").read_text())
    fem = bake["fem"]
    check = fem.get("step_check") or {}
    worst = min(fem["parts"].items(), key=lambda kv: kv[1].get("min_det", np.inf))
    return {"frames": bake["frames"], "wall_s": round(wall, 1),
            "ms_per_step": fem["ms_per_step"], "min_det": fem["min_det"], "step_min_det": check.get("step_min_det"),
            "inverted_max": fem["inverted_max"], "frames_with_inverted": fem["frames_with_inverted"],
            "steps": fem["steps"], "redone": check.get("steps_redone"), "searched": check.get("steps_line_searched"),
            "worst_part": worst[0]}


def before_tree(rev: str, work: Path) -> tuple[list[str], dict]:
    """REV's files laid at work/tree/jiggle with its stage folders, and how to run its CLI from there."""
    tree = work / "tree"
    tree.mkdir(parents=True)
    subprocess.run(f"git -C {ROOT} archive {rev} | tar -x -C {tree}", shell=True, check=True)
    code = ("import sys; sys.path.insert(0, %r); from jiggle.sim.app.cli import main; sys.exit(main())" % str(tree))
    return [sys.executable, "-c", code], {"PYTHONSAFEPATH": "1"}


def write(rows: list, a) -> None:
    """benchmarks/results/fem_hero_clips.{md,json} of the rows so far."""
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "fem_hero_clips.json").write_text(json.dumps(rows, indent=1) + "\n")
    keys = ["clip", "character", "tree", "start", "end", "frames", "wall_s", "ms_per_step", "min_det",
            "step_min_det", "inverted_max", "frames_with_inverted", "steps", "redone", "searched", "worst_part"]
    lines = ["# The FEM hero mode on every shared CMU clip", "",
             f"`python benchmarks/fem_hero_clips.py --seconds {a.seconds:g}"
             + (f" --before {a.before}" if a.before else "") + "`: each clip's most vigorous "
             f"{a.seconds:g} s (start, end: seconds of the clip; a shorter clip whole), `--tissue fem`, the defaults.",
             "", "| " + " | ".join(keys) + " |", "|" + "---|" * len(keys)]
    lines += ["| " + " | ".join(str(r.get(k)) for k in keys) + " |" for r in rows]
    this = [r for r in rows if r["tree"] == "this"]
    lines += ["", f"Bakes with an inverted tet at an output frame: {sum(r['inverted_max'] > 0 for r in this)} of "
              f"{len(this)}; smallest det F at an output frame {min((r['min_det'] for r in this), default=float('nan')):.3f}, at any kept "
              f"step {min((r['step_min_det'] for r in this if r['step_min_det'] is not None), default=float('nan')):.3f}."]
    ref = [r for r in rows if r["tree"] != "this"]
    mine = [r for r in this if r["clip"] == "09_11" and r["character"] == "cesium"]
    if ref and mine:
        lines.append(f"CMU 09_11 on CesiumMan: this checkout's hero bake takes {mine[0]['wall_s'] / ref[0]['wall_s']:.2f}x "
                     f"{a.before}'s ({mine[0]['wall_s']} s / {ref[0]['wall_s']} s; its solver steps "
                     f"{mine[0]['ms_per_step'] / ref[0]['ms_per_step']:.2f}x, {mine[0]['steps']} steps kept / "
                     f"{ref[0]['steps']}; one run, this machine).")
    (RESULTS / "fem_hero_clips.md").write_text("\n".join(lines) + "\n")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seconds", type=float, default=2.0, help="each clip's most vigorous window (seconds)")
    p.add_argument("--clips", default=",".join(CLIPS))
    p.add_argument("--characters", default=",".join(CHARACTERS))
    p.add_argument("--before", default=None, help="also bake CMU 09_11 on CesiumMan with REV's tree, for the ratio")
    a = p.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        if a.before:
            py, env = before_tree(a.before, work)
            clip = ASSETS / "mocap" / "cmu_bvh" / "09_11.bvh"
            wall = bake(work / "before", clip, CHARACTERS["cesium"], 0.0, None, py, env)
            rows.append({"clip": "09_11", "character": "cesium", "tree": a.before, "start": 0.0, "end": None,
                         **row(work / "before", wall)})
            print(rows[-1], flush=True)
        for name in a.clips.split(","):
            clip = ASSETS / "mocap" / "cmu_bvh" / f"{name}.bvh"
            start, end = vigorous(clip, a.seconds)
            for ch in a.characters.split(","):
                out = work / f"{name}_{ch}"
                wall = bake(out, clip, CHARACTERS[ch], start, end)
                rows.append({"clip": name, "character": ch, "tree": "this", "start": start, "end": end,
                             **row(out, wall)})
                print(rows[-1], flush=True)
                write(rows, a)
    write(rows, a)
    return 0


if __name__ == "__main__":
    sys.exit(main())
