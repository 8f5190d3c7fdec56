"""What the chains cost: each shared zoo character that has chains, baked on its most vigorous cycle with the
defaults, against the same bake with `--chains none`, measured in one run:

- the bake loop's time (bake.json's timings frames_s: drive, tissue, chains, skin and caches of every chunk, the
  looping warm-ups included) with chains over without, the median of --repeats alternating pairs (the issue's
  gate: at most 1.25x);
- the chains' own share (timings chains_s), their MuJoCo steps and the time per step.

    .venv/bin/python benchmarks/bench_chains.py [--repeats 3] [--out benchmarks/results/chains.md]

Each setup is prepared once (reading, fitting and the drive are not the loop); the assets' absence ends the
benchmark with a message.
"""
from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
ASSETS = Path(os.environ.get("JIGGLE_ASSETS", ROOT.parent / "shared" / "assets"))
CASES = (("Horse", "Gallop"), ("Cow", "Gallop"), ("Demon", "Fast_Flying"), ("Goleling", "Fast_Flying"))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3, help="alternating pairs of bakes per character (default 3)")
    ap.add_argument("--out", default=None, help="also write the table as Markdown to this file")
    ap.add_argument("--characters", default=None, help="comma-separated names of CASES to run (default: all)")
    args = ap.parse_args()
    zoo = ASSETS / "characters" / "zoo"
    if not zoo.is_dir():
        print(f"the shared zoo is not under {zoo}: nothing to measure")
        return 0
    import warnings

    from jiggle.rig.base.errors import JiggleWarning
    from jiggle.sim.bake.baker import bake
    from jiggle.sim.bake.setup import BakeRequest, prepare
    warnings.simplefilter("ignore", JiggleWarning)
    rows = []
    only = set(args.characters.split(",")) if args.characters else None
    for name, clip in CASES:
        if only is not None and name not in only:
            continue
        path = zoo / f"{name}.glb"
        if not path.is_file():
            continue
        req = BakeRequest(character=str(path), animation=clip, formats=("npz",))
        with_chains, without = prepare(req), prepare(replace(req, chains="none"))
        if with_chains.chains is None:
            continue
        loops = {"with": [], "without": []}
        chain_s, steps = [], 0
        with tempfile.TemporaryDirectory(prefix="jiggle-bench-chains-") as tmp:
            for r in range(args.repeats):
                for label, setup in (("with", with_chains), ("without", without)):
                    t = time.perf_counter()
                    summary = bake(setup, os.path.join(tmp, f"{label}{r}"))
                    loops[label].append(summary["timings"]["frames_s"])
                    if label == "with":
                        chain_s.append(summary["timings"]["chains_s"])
                        steps = summary["chains"]["steps_with_warmup"]
                    print(f"{name} {clip} {label} chains: loop {loops[label][-1]:.3f} s "
                          f"({time.perf_counter() - t:.1f} s in all)", flush=True)
        a, b = statistics.median(loops["with"]), statistics.median(loops["without"])
        cs = statistics.median(chain_s)
        rows.append((name, clip, len(with_chains.chains.chains), a, b, a / b, cs, steps, cs / max(steps, 1) * 1e6))
    head = ["character", "cycle", "chains", "loop with chains (s)", "loop without (s)", "ratio", "chains (s)",
            "MuJoCo steps (warm-up too)", "us per step (all chain work)"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        lines.append(f"| {r[0]} | {r[1]} | {r[2]} | {r[3]:.3f} | {r[4]:.3f} | {r[5]:.2f}x | {r[6]:.3f} | {r[7]} | "
                     f"{r[8]:.0f} |")
    table = "\n".join(lines)
    print(table)
    if args.out:
        Path(args.out).write_text(f"# Chains: the bake loop with and without\n\n`python benchmarks/bench_chains.py "
                                  f"--repeats {args.repeats}`, medians of alternating runs, 2-core CPU.\n\n"
                                  f"{table}\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
