"""The volumetric reference as a suite: the FEM solid against the particles on every shared clip and character, not
on three hand-picked cases.

    python benchmarks/fem_suite.py [--workers 2] [--only NAME,...] [--subset]

Cases (each with the character's largest fat part and its largest muscle, where it has both):
- every shared CMU clip on CesiumMan and on the generated body: 01_01 and 05_02 cut to their most vigorous 4 s
  (benchmarks/fem_hero_clips.vigorous), 02_03, 02_04 and 09_11 whole;
- every shared zoo character on its most vigorous cycle (benchmarks/zoo.py's order: Run, Gallop, Fast_Flying, then
  Walk), 2 s of it.

Each case is benchmarks/fem_reference.py's `case`: the bake's own drive (relaxed tissue: --activation off, as the
solid has no activation), then the last pose held 1.5 s; the FEM
(TetGen mesh of the part, Neo-Hookean, Rayleigh damping at its material's ratio, the det F check of sim/fem/step.py)
and the particles on the same goals, twice: with the bake's default goal springs, and with the springs the part's
material gives (sim.jiggle.materials.with_material). Per case: peak, ring-down frequency and logarithmic decrement
of each, the FEM's over the particles', the FEM's smallest det F at an output frame and at any step, the steps it
redid. The summary gives, for the default and for the material springs, how many cases are within 25% (peak), 15%
(ring-down frequency) and 30% (decrement), the median and the worst ratio, with plots (one per case, and the
ratios of all cases: benchmarks/results/fem_suite/).

Writes benchmarks/results/fem_suite.{md,json}. The whole suite took 35 min on this machine with one worker (beside
other bakes); two workers take about half; `--subset` (the CMU clips on CesiumMan and 4 zoo characters) about a
third of the cases.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import fem_hero_clips  # noqa: E402
import fem_reference  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
ASSETS = ROOT.parent / "shared" / "assets"
RESULTS = ROOT / "benchmarks" / "results"
PLOTS = RESULTS / "fem_suite"
SECONDS, ZOO_SECONDS = 4.0, 2.0
CUT = ("01_01", "05_02")
SUBSET_ZOO = ("Cat", "Horse", "Hywirl", "Frog")


def zoo_cycle(path: Path) -> str | None:
    """The zoo character's most vigorous cycle (benchmarks/zoo.py's VIGOROUS order among its cycles), None: none."""
    from pygltflib import GLTF2

    import zoo
    names = [a.name or f"animation {i}" for i, a in enumerate(GLTF2().load(str(path)).animations or [])]
    cycles = zoo.cycles_of(names)
    return next((n for v in zoo.VIGOROUS for n in cycles if n.split("|")[-1].lower() == v), cycles[0] if cycles else None)


def specs(subset: bool) -> dict:
    """{name: case spec} (fem_reference.case_drive's)."""
    out = {}
    chars = {"cesium": "characters/CesiumMan.glb"} if subset else {"cesium": "characters/CesiumMan.glb",
                                                                     "generated": None}
    for clip in fem_hero_clips.CLIPS:
        path = ASSETS / "mocap" / "cmu_bvh" / f"{clip}.bvh"
        if not path.exists():
            continue
        start, end = fem_hero_clips.vigorous(path, SECONDS) if clip in CUT else (0.0, None)
        for ch, file in chars.items():
            for kind in ("fat", "muscle"):
                out[f"{clip}_{ch}_{kind}"] = {"clip": f"mocap/cmu_bvh/{clip}.bvh", "character": file, "part": None,
                                              "kind": kind, "start": start, "seconds": SECONDS}
    for path in sorted((ASSETS / "characters" / "zoo").glob("*.glb")):
        if subset and path.stem not in SUBSET_ZOO:
            continue
        cycle = zoo_cycle(path)
        if cycle is None:
            continue
        rel = str(path.relative_to(ASSETS))
        for kind in ("fat", "muscle"):
            out[f"{path.stem}_{cycle.split('|')[-1]}_{kind}"] = {
                "clip": rel, "character": rel, "animation": cycle, "part": None, "kind": kind, "seconds": ZOO_SECONDS}
    return out


def run_case(item) -> dict:
    name, spec = item
    import warnings
    warnings.simplefilter("ignore")
    fem_reference.quiet()
    lines = []
    t = time.perf_counter()
    try:
        out = fem_reference.case(name, {}, lines.append, spec=spec, plots=PLOTS)
    except LookupError as e:                # a character without a part of the kind (a creature's tissue is fat)
        return {"case": name, "skipped": str(e)}
    except Exception as e:  # noqa: BLE001 - a case that cannot run is reported, the suite goes on
        return {"case": name, "error": f"{type(e).__name__}: {e}", "log": lines}
    out["seconds"] = round(time.perf_counter() - t, 1)
    out["spec"] = spec
    return out


def ratios(r: dict, which: str) -> tuple:
    """(peak, ring f, decrement): FEM over the particles `which` ("particles": the defaults, "particles_material")."""
    p, f = r["fem"], r[which]
    return (p["peak_mm"] / max(r[which]["peak_mm"], 1e-12), p["ring_f_hz"] / max(f["ring_f_hz"], 1e-12),
            p["log_dec"] / max(f["log_dec"], 1e-12))


def within(q: tuple) -> tuple:
    return tuple(abs(1.0 / x - 1.0) <= tol for x, tol in zip(q, fem_reference.TOLERANCES))


def summary(rows: list) -> list[str]:
    ok = [r for r in rows if "error" not in r and "skipped" not in r]
    L = []
    for which, label in (("particles", "default springs"), ("particles_material", "springs from the material")):
        q = np.array([ratios(r, which) for r in ok])
        w = np.array([within(tuple(x)) for x in q]) if len(q) else np.zeros((0, 3), bool)
        if not len(q):
            continue
        off = np.abs(1.0 / q - 1.0)
        worst = [ok[int(i)]["case"] for i in np.argmax(off, axis=0)]
        L += [f"**{label}** ({len(ok)} cases): within 25% peak {w[:, 0].sum()}, 15% ring-down frequency "
              f"{w[:, 1].sum()}, 30% decrement {w[:, 2].sum()}; all three {w.all(axis=1).sum()}.",
              "", "| FEM / particles | median | worst | worst case |", "|---|---|---|---|"]
        for j, n in enumerate(("peak", "ring-down frequency", "log decrement")):
            L.append(f"| {n} | {np.median(q[:, j]):.2f} | {q[int(np.argmax(off[:, j])), j]:.2f} | {worst[j]} |")
        L.append("")
    dets = [r["min_det"] for r in ok]
    steps = [r.get("step_min_det", np.nan) for r in ok]
    if ok:
        L.append(f"The reference's solid: smallest det F at an output frame {min(dets):.3f} (median {np.median(dets):.3f}),"
                 f" at any step {np.nanmin(steps):.3f}; steps redone {sum(r.get('steps_redone', 0) for r in ok)}, "
                 f"line-searched {sum(r.get('steps_line_searched', 0) for r in ok)}.")
    return L


def plot_ratios(rows: list) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    ok = [r for r in rows if "error" not in r and "skipped" not in r]
    if not ok:
        return
    fig, axes = plt.subplots(1, 3, figsize=(15, max(4, 0.22 * len(ok))), sharey=True)
    y = np.arange(len(ok))
    for j, (ax, n, tol) in enumerate(zip(axes, ("peak", "ring-down frequency", "log decrement"),
                                         fem_reference.TOLERANCES)):
        for which, mk in (("particles", "o"), ("particles_material", "s")):
            ax.scatter([ratios(r, which)[j] for r in ok], y, marker=mk, label=which.replace("_", " from "))
        ax.axvspan(1 / (1 + tol), 1 / (1 - tol), color="g", alpha=0.12)
        ax.axvline(1.0, color="k", lw=0.5)
        ax.set_xscale("log")
        ax.set_title(f"FEM / particles: {n}")
    axes[0].set_yticks(y, [r["case"] for r in ok], fontsize=7)
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(PLOTS / "ratios.png", dpi=90)
    plt.close(fig)


def write(rows: list, argv_text: str, wall: float) -> None:
    (RESULTS / "fem_suite.json").write_text(json.dumps(rows, indent=1, default=float) + "\n")
    L = ["# The volumetric reference as a suite (benchmarks/fem_suite.py)", "",
         f"`python benchmarks/fem_suite.py {argv_text}`: {len(rows)} cases in {wall / 60:.0f} min. FEM over particles; "
         "the particles with the bake's default springs, then with the springs the part's material gives. Within: "
         "the particles' peak within 25% of the FEM's, ring-down frequency within 15%, log decrement within 30%.", ""]
    skipped = [f"{r['case']} ({r['skipped']})" for r in rows if "skipped" in r]
    L += summary(rows) + ([f"Left out: {', '.join(skipped)}."] if skipped else []) + ["", "![ratios](fem_suite/ratios.png)", "",
                          "| case | part | kind | r mm | FEM peak mm | FEM ring Hz | FEM decrement | default: peak / f / "
                          "decrement | material: peak / f / decrement | FEM min det F (step) | redone | plot |",
                          "|" + "---|" * 12]
    for r in rows:
        if "skipped" in r:
            continue
        if "error" in r:
            L.append(f"| {r['case']} | could not run: {r['error']} |" + " |" * 10)
            continue
        d, m = ratios(r, "particles"), ratios(r, "particles_material")
        fmt = lambda q: " / ".join(("" if ok else "**") + f"{x:.2f}" + ("" if ok else "**")  # noqa: E731
                                   for x, ok in zip(q, within(q)))
        L.append(f"| {r['case']} | {r['part']} | {r['kind']} | {r['r_mm']:.0f} | {r['fem']['peak_mm']:.1f} | "
                 f"{r['fem']['ring_f_hz']:.2f} | {r['fem']['log_dec']:.2f} | {fmt(d)} | {fmt(m)} | "
                 f"{r['min_det']:.2f} ({r.get('step_min_det', float('nan')):.2f}) | {r.get('steps_redone', 0)} | "
                 f"[png](fem_suite/fem_reference_{r['case']}.png) |")
    (RESULTS / "fem_suite.md").write_text("\n".join(L) + "\n")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--only", default=None, help="comma-separated case names")
    p.add_argument("--subset", action="store_true", help="the CMU clips on CesiumMan and 4 zoo characters")
    a = p.parse_args(argv)
    cases = specs(a.subset)
    if a.only:
        cases = {k: v for k, v in cases.items() if k in a.only.split(",")}
    PLOTS.mkdir(parents=True, exist_ok=True)
    t = time.perf_counter()
    rows = []
    with ProcessPoolExecutor(max_workers=a.workers) as pool:
        for r in pool.map(run_case, cases.items()):
            rows.append(r)
            print(r["case"], r.get("skipped") or r.get("error") or f"FEM {r['fem']['peak_mm']:.1f} mm {r['fem']['ring_f_hz']:.2f} Hz | "
                  f"default {ratios(r, 'particles')} | material {ratios(r, 'particles_material')} | "
                  f"min det {r['min_det']:.2f} ({r['seconds']} s)", flush=True)
            write(rows, " ".join(argv if argv is not None else sys.argv[1:]), time.perf_counter() - t)
    plot_ratios(rows)
    write(rows, " ".join(argv if argv is not None else sys.argv[1:]), time.perf_counter() - t)
    print("\n".join(summary(rows)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
