"""How much the FEM solid of one part depends on its tetrahedral mesh: the same part meshed from rest CVs that differ
only in their last bits, as another CPU's arithmetic makes them (NumPy's SIMD sin/cos and sums differ between AVX2 and
AVX-512; FMA changes a rounding).

    python benchmarks/fem_mesh_spread.py [--meshes 8] [--ringdown] [--noise 1e-12] [--out fem_mesh_spread.md]

The part is the one tests/fem/test_modes.py rings (sim.fem.experiments.ellipsoid_rig(0.2, (0.03, 0.025)), the
material FAT). Mesh 0 is meshed from its CVs as they are; mesh k > 0 from the CVs times (1 + 1e-12 n), n standard
normal (seeded): 1e-13 m, far below anything physical. For each mesh: TetGen's node and tet counts, the vertices
attached to the bone, the lowest mode and the sway (sim.fem.modes), the mode Modes.along picks for a drive along z
and along y, and with --ringdown the frequency an undamped ring-down of the simulated solid rings at along each
(sim.fem.experiments.ringdown_run, as the test runs it; ~10 s each). The structured mesh of the same CVs
(sim.fem.tet_mesh.structured_part_mesh) is meshed the same way for comparison.

Writes benchmarks/results/fem_mesh_spread.md: one row a mesh and the spread (max - min over the median) of each
figure. A spread far above the perturbation means the reference solid, and every calibration fitted to it, depends on
the machine that meshed it (issue 59: test_the_sway_is_where_the_solid_rings failed on an AVX-512 machine).

Since TetGen's input is snapped to a grid (sim.fem.tet_mesh.snapped, SNAP_BITS), CVs 1e-12 apart give one mesh
(fem_mesh_spread.md: every row the same). `--noise 1e-5 --out fem_mesh_spread_grid.md` moves the CVs across that grid
and shows what snapping does not change: a coarse TetGen mesh's own spread, a property of the reference solid that
every calibration fitted to it carries (a 1-2 tet thick free layer over a core attached by a distance threshold).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
NOISE = 1e-12
"""Relative perturbation of the rest CVs (last bits of a float64)."""
Z, Y = (0.0, 0.0, 1.0), (0.0, 1.0, 0.0)


def row(name: str, mesh, material, ringdown: bool) -> dict:
    """The figures of one mesh (see the module)."""
    from jiggle.sim.fem.experiments import ringdown_run
    from jiggle.sim.fem.modes import modes
    found = modes(mesh, material)
    f = found.frequencies_hz
    out = {"mesh": name, "nodes": len(mesh.points), "tets": len(mesh.tets), "attached": int(mesh.attached.sum()),
           "lowest_hz": found.lowest_hz, "sway_hz": found.sway_hz, "along_z_hz": float(f[found.along(Z)]),
           "along_y_hz": float(f[found.along(Y)])}
    if ringdown:
        for axis, d in (("z", Z), ("y", Y)):
            fa = out[f"along_{axis}_hz"]
            _, rd = ringdown_run(mesh, material, duration=0.5, fps=1000.0, k_damp=0.0, direction=d, window=3.0 / fa)
            out[f"ring_{axis}_hz"] = float(rd.frequency_hz)
            out[f"ring_{axis}_off"] = fa / float(rd.frequency_hz) - 1.0
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--meshes", type=int, default=8, help="meshes of the part (the first unperturbed)")
    p.add_argument("--noise", type=float, default=NOISE,
                   help="relative perturbation of the CVs (default 1e-12: another CPU's last bits; 1e-5 moves them "
                        "across TetGen's snapping grid, sim.fem.tet_mesh.SNAP_BITS, and shows the mesh's own spread)")
    p.add_argument("--out", default="fem_mesh_spread.md", help="file under benchmarks/results")
    p.add_argument("--ringdown", action="store_true", help="also ring each mesh down along z and y (~20 s a mesh)")
    a = p.parse_args(argv)
    try:
        import newton  # noqa: F401
        import tetgen  # noqa: F401
    except ImportError as e:
        print(f"skipped: {e.name} is not installed")
        return 0
    from jiggle.rig.muscle.material import FAT
    from jiggle.sim.fem.experiments import ellipsoid_rig
    from jiggle.sim.fem.tet_mesh import part_mesh, structured_part_mesh
    cvs = np.asarray(ellipsoid_rig(0.2, (0.03, 0.025)).rest_cvs, np.float64)
    rng = np.random.default_rng(0)
    rows = []
    for k in range(a.meshes):
        c = cvs if k == 0 else cvs * (1.0 + a.noise * rng.standard_normal(cvs.shape))
        rows.append(row(f"TetGen {k}", part_mesh(c), FAT, a.ringdown))
        print(rows[-1], flush=True)
    structured = [row(f"structured {k}", structured_part_mesh(
        (cvs if k == 0 else cvs * (1.0 + a.noise * rng.standard_normal(cvs.shape))).reshape(5, 8, 3)), FAT, a.ringdown)
        for k in range(2)]
    keys = [k for k in rows[0] if k != "mesh"]
    lines = ["# The FEM solid's dependence on its mesh", "",
             f"`python benchmarks/fem_mesh_spread.py --meshes {a.meshes}{' --ringdown' if a.ringdown else ''}`: one "
             f"part (tests/fem/test_modes.py's), its rest CVs perturbed by {a.noise:g} relative (mesh 0: as they are).",
             "", "| mesh | " + " | ".join(keys) + " |", "|---" * (len(keys) + 1) + "|"]
    for r in rows + structured:
        lines.append(f"| {r['mesh']} | " + " | ".join(f"{r[k]:.3g}" if isinstance(r[k], float) else str(r[k])
                                                     for k in keys) + " |")
    spread = {k: float(np.ptp([r[k] for r in rows]) / abs(np.median([r[k] for r in rows])))
              for k in keys if k.endswith("_hz")}
    identical = sum(r["nodes"] == rows[0]["nodes"] and r["tets"] == rows[0]["tets"] for r in rows[1:])
    lines += ["", f"TetGen meshes with mesh 0's node and tet counts: {identical} of {len(rows) - 1}. Spread (max - min "
              "over the median) across the TetGen meshes: " + ", ".join(f"{k} {v:.0%}" for k, v in spread.items()) + "."]
    if a.ringdown:
        worst = max(abs(r[f"ring_{x}_off"]) for r in rows for x in "zy")
        lines.append(f"Largest gap between the mode Modes.along picks and the ring-down: {worst:.0%} (the test allows "
                     "8%).")
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / a.out).write_text("\n".join(lines) + "\n")
    print("\n".join(lines[-2:]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
