"""Which tissue the shared zoo takes as its default: every zoo character's most vigorous cycle baked with its default
springs and with the literature's materials at its inferred real size, the skin's peak against the zoo's gates.

    python benchmarks/zoo_materials.py [--out DIR] [--characters Cat,Cow]

Variants (each a `jiggle bake` of the cycle, `--formats npz`, measured as benchmarks/zoo.py measures a row: the
skin's largest jiggle over the body's size):
- default: the bake as it is (the human template's parts from their materials; the quadruped's written-out springs;
  the generic template's tuned to the character's most vigorous cycle);
- kinds: every part its kind's material (`fat` for fat, relaxed `muscle` for the others: rig/muscle/material.py);
- fat, muscle: every part that one material;
- mixed: a volume mix of the two by the reference adult's shares (ICRP 89: skeletal muscle 29 kg, adipose 18.2 kg,
  so 42% adipose by volume), E by the rule of mixtures (10 kPa), rho 1000 kg/m^3, zeta 0.42.

The zoo's gates (benchmarks/zoo.py TARGETS): no cycle above 1.5% of the size; a most vigorous cycle at least 0.3%.
Writes benchmarks/results/zoo_materials.md and .json.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import zoo  # noqa: E402
from fem_suite import zoo_cycle  # noqa: E402

RESULTS = HERE / "results"
MIXED = "E=10kPa,nu=0.49,rho=1000,zeta=0.42"
VARIANTS = ("default", "kinds", "fat", "muscle", "mixed")


def materials_of(variant: str, kinds: dict) -> list[str]:
    """The --material entries of a variant; kinds: {muscle name: kind} of the character's fit."""
    if variant == "kinds":
        return ["muscle"] + [f"{n}=fat" for n, k in kinds.items() if k == "fat"]
    return {"default": [], "fat": ["fat"], "muscle": ["muscle"], "mixed": [MIXED]}[variant]


def bake(path: Path, cycle: str, out: Path, materials: list[str]) -> dict:
    """A bake of the character's cycle with the materials given; its row's figures (zoo.measure)."""
    cmd = zoo.jiggle_command() + ["bake", "--character", str(path), "--animation", cycle, "--out", str(out),
                                  "--formats", "npz", "-q"]
    for m in materials:
        cmd += ["--material", m]
    t = time.perf_counter()
    p = subprocess.run(cmd, capture_output=True, text=True)
    if p.returncode:
        return {"error": zoo.last_line(p.stderr)}
    row = zoo.Row(path.stem, cycle, "baked")
    zoo.measure(row, out)
    params = json.loads((out / "bake.json").read_text())["params"]
    return {"peak_pct": row.peak_pct, "peak_mm": row.peak_mm, "size_m": row.size_m, "seconds": time.perf_counter() - t,
            "real_scale": params["tissue"]["real_size"]["scale"], "template": params["tissue"].get("template"),
            "kinds": {n: m["kind"] for n, m in params["muscles"].items()},
            "springs_from": sorted({m.get("springs_from") for m in params["muscles"].values()} - {None})}


def passes(pct: float | None) -> bool:
    return pct is not None and zoo.TARGETS["peak_min_pct"] <= pct <= zoo.TARGETS["peak_max_pct"]


def write(rows: list[dict], seconds: float) -> None:
    lines = ["# The zoo's default tissue: springs or materials (benchmarks/zoo_materials.py)", "",
             f"`python benchmarks/zoo_materials.py`: each zoo character's most vigorous cycle, {len(VARIANTS)} bakes "
             f"each, {seconds / 60:.0f} min. The skin's peak jiggle in % of the body's size (its largest extent), "
             f"against the zoo's gates: at most {zoo.TARGETS['peak_max_pct']}% on any cycle and at least "
             f"{zoo.TARGETS['peak_min_pct']}% on the most vigorous one (**bold**: outside).", "",
             "- default: the bake as it is; kinds: each part its kind's material (fat 3 kPa, relaxed muscle 15 kPa); "
             "fat, muscle: every part that material; mixed: muscle and adipose by volume as in the reference adult "
             f"(ICRP 89), {MIXED}. All at the inferred real size.", "",
             "| character | cycle | template | real size (x file) | size m | " + " | ".join(VARIANTS) + " |",
             "|---|---|---|---|---|" + "---|" * len(VARIANTS)]
    for r in rows:
        d = r["variants"].get("default", {})
        cells = []
        for v in VARIANTS:
            x = r["variants"].get(v, {})
            p = x.get("peak_pct")
            cells.append("error" if p is None else (f"{p:.2f}" if passes(p) else f"**{p:.2f}**"))
        lines.append(f"| {r['character']} | {r['cycle']} | {d.get('template') or '-'} | {d.get('real_scale', 0):.3g} | "
                     f"{(d.get('size_m') or 0) * (d.get('real_scale') or 1):.2f} | " + " | ".join(cells) + " |")
    ok = {v: sum(passes(r["variants"].get(v, {}).get("peak_pct")) for r in rows) for v in VARIANTS}
    lines += ["", "Passing both gates: " + ", ".join(f"{v} {ok[v]} of {len(rows)}" for v in VARIANTS) + ".", ""]
    (RESULTS / "zoo_materials.md").write_text("\n".join(lines))
    (RESULTS / "zoo_materials.json").write_text(json.dumps(rows, indent=1))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="/tmp/zoo_materials", help="the bakes' folder")
    ap.add_argument("--characters", help="comma-separated zoo character names (default: all)")
    args = ap.parse_args(argv)
    if not (zoo.CHARACTERS / "zoo").is_dir():
        print(f"skipped: no shared zoo at {zoo.CHARACTERS / 'zoo'}")
        return 0
    only = {c.strip().lower() for c in args.characters.split(",")} if args.characters else None
    t, rows = time.perf_counter(), []
    for path in sorted((zoo.CHARACTERS / "zoo").glob("*.glb")):
        cycle = zoo_cycle(path)
        if cycle is None or (only and path.stem.lower() not in only):
            continue
        row = {"character": path.stem, "cycle": cycle, "variants": {}}
        kinds = {}
        for v in VARIANTS:
            res = bake(path, cycle, Path(args.out) / f"{path.stem}_{v}", materials_of(v, kinds))
            kinds = kinds or res.get("kinds", {})
            row["variants"][v] = res
            print(f"{path.stem:10s} {cycle:12s} {v:8s} {res.get('peak_pct', float('nan')):.2f}% "
                  f"{res.get('error', '')}", flush=True)
        rows.append(row)
    write(rows, time.perf_counter() - t)
    return 0


if __name__ == "__main__":
    sys.exit(main())
