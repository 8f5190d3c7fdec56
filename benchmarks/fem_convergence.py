"""Is the volumetric reference converged? Its parts' sway frequency under mesh refinement, and left against right.

    python benchmarks/fem_convergence.py [--out benchmarks/results]

The particles are checked against the FEM reference (benchmarks/fem_reference.py, fem_suite.py), so the reference's
own answer must not depend on its mesh. For CesiumMan's mirrored parts (fitted on the CMU run 09_11) and its belly,
the small-strain sway (sim.fem.modes: the mode that carries the most free mass, the fundamental the ring-downs read)
of each part's material at real size:

- on the reference's mesh (sim.fem.tet_mesh.part_mesh: TetGen's ~1-2k tets, the bone-attached core the Steiner
  vertices that fall within CORE of the axis), for the left part and its mirror;
- on the structured mesh of its loft coordinates with the same attachment made exact (rings at rho <= CORE ride the
  bone, the end tenth of the axis too), at 4 refinements (9 x 16 x 4 rings, 13 x 24 x 6, 17 x 32 x 8, 25 x 48 x 12);
- the materials' rule (sim.jiggle.materials.fem_frequency).

What it shows (benchmarks/results/fem_convergence.md): mirrored parts sway at different frequencies on TetGen's
meshes (left over right 0.27-1.76: its core is whichever Steiner vertices land near the axis), where the structured
meshes keep a pair together (0.97-1.02, but for a quadriceps whose two nearest modes trade places); and the
structured meshes' sway falls, refinement after refinement, by 10-23% from the coarsest to the finest for the fat
and the calves: linear tetrahedra lock at nu 0.49, so every solid the suite measures is stiffer than the continuum
by an amount that depends on its mesh. A converged reference needs a locking-free element (quadratic or mixed
pressure) first; the particles are then calibrated against that.
"""
from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ASSETS = HERE.parent.parent / "shared" / "assets"
PAIRS = ("hamstrings", "biceps", "calf", "quadriceps", "love_handle")
LEVELS = ((9, 16, 4), (13, 24, 6), (17, 32, 8), (25, 48, 12))
"""(rows, columns, rings) of the structured meshes."""


def rings(n: int, core: float) -> tuple:
    """n rings' rho, ending at 1, with rings at and inside `core` (the bone-attached part)."""
    inner = max(1, round(n * core))
    return tuple(list(np.linspace(0, core, inner + 1)[1:]) + list(np.linspace(core, 1, n - inner + 1)[1:]))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(HERE / "results"))
    a = ap.parse_args(argv)
    character, clip = ASSETS / "characters" / "CesiumMan.glb", ASSETS / "mocap" / "cmu_bvh" / "09_11.bvh"
    if not character.is_file() or not clip.is_file():
        print(f"skipped: CesiumMan or 09_11.bvh not found under {ASSETS}")
        return 0
    from jiggle.rig.muscle.material import material_for
    from jiggle.sim.bake.setup import BakeRequest, prepare
    from jiggle.sim.fem.modes import modes
    from jiggle.sim.fem.tet_mesh import CORE, END, part_mesh, structured_part_mesh
    from jiggle.sim.jiggle.materials import fem_frequency
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        setup = prepare(BakeRequest(clip=str(clip), character=str(character), formats=("npz",)), log=lambda s: None)
    rig, k = setup.rig, float(setup.real_scale)
    radii = rig.mean_radii(rig.rest_cvs)
    names = [n for n in rig.names if any(p in n for p in PAIRS)] + ["belly_fat"]
    t0 = time.perf_counter()
    rows = []
    for n in names:
        m = rig.names.index(n)
        cvs = k * rig.rest_cvs[rig.cv_offsets[m]:rig.cv_offsets[m + 1]]
        mat = material_for(rig.kinds[m])
        row = {"part": n, "rule": fem_frequency(mat, k * radii[m], k * rig.rest_length[m]),
               "tetgen": modes(part_mesh(cvs), mat).sway_hz, "structured": []}
        for r, c, n_rings in LEVELS:
            mesh = structured_part_mesh(cvs, rows=r, cols=c, core=CORE, end=END, layers=rings(n_rings, CORE))
            row["structured"].append((len(mesh.tets), modes(mesh, mat).sway_hz))
        rows.append(row)
        print(n, f"{row['tetgen']:.2f}", [f"{f:.2f}" for _, f in row["structured"]], flush=True)
    head = " | ".join(f"{t} tets" for t, _ in rows[0]["structured"])
    lines = ["# Is the volumetric reference converged? (benchmarks/fem_convergence.py)", "",
             f"`python benchmarks/fem_convergence.py`: {len(rows)} of CesiumMan's parts (fitted on CMU 09_11), each "
             f"one's small-strain sway (Hz) at its material and real size, in {time.perf_counter() - t0:.0f} s. "
             "TetGen: the reference's mesh (its bone-attached core the Steiner vertices within 0.35 radii of the "
             "axis). Structured: the loft-coordinate mesh with that core made exact, refined (tet counts of the "
             "first part).", "",
             f"| part | rule | TetGen | {head} |", "|---|---|---|" + "---|" * len(LEVELS)]
    for r in rows:
        lines.append(f"| {r['part']} | {r['rule']:.1f} | {r['tetgen']:.1f} | " +
                     " | ".join(f"{f:.1f}" for _, f in r["structured"]) + " |")
    left = {r["part"][5:]: r for r in rows if r["part"].startswith("left_")}
    pairs = [(p, left[p], next(r for r in rows if r["part"] == "right_" + p)) for p in left
             if any(r["part"] == "right_" + p for r in rows)]
    lines += ["", "Left over right (a mirrored pair is one part twice): TetGen " + ", ".join(
        f"{p} {a['tetgen'] / b['tetgen']:.2f}" for p, a, b in pairs) + "; the finest structured mesh " + ", ".join(
        f"{p} {a['structured'][-1][1] / b['structured'][-1][1]:.2f}" for p, a, b in pairs) + ".",
              "", "Finest over coarsest structured mesh: " + ", ".join(
                  f"{r['part']} {r['structured'][-1][1] / r['structured'][0][1]:.2f}" for r in rows) + "."]
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "fem_convergence.md").write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
