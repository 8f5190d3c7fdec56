"""Bit-for-bit check of a behaviour-preserving change: the same bakes made by an earlier commit and by this checkout,
on this machine, compared file by file.

    python benchmarks/bake_identity.py --before REV [--case NAME ...] [--work DIR] [--keep]

REV's tree is exported (`git archive`, nothing of this checkout touched) into the work folder and each case is baked
twice with this interpreter: once importing REV's jiggle (PYTHONPATH at the export), once this checkout's. Then every
array of bake.npz must be equal to the bit (dtype, shape and bytes: NaN equals NaN, -0.0 differs from 0.0), bake.json
must be equal value for value, the key included, leaving out only the seconds each step took (`timings`, `*_s` wall
times of the FEM), and every other cache file (usdc, pc2, glb) must be equal byte for byte. The before bakes are kept
in the work folder by REV and case, so a rerun bakes only the after side.

The cases (CASES): the built-in demo, two shared CMU clips on CesiumMan (a walk and the 09_11 case the tissue is
calibrated on), a zoo character's own cycle (the Cat's Walk) and a short hero-mode (FEM) bake. No array hash goes
into the test suite: floating point differs between CPUs, so the comparison is only meaningful on one machine, as
here.

Writes benchmarks/results/bake_identity.md (the table) and exits 1 when any case differs.
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

CASES = {
    "demo": ("demo", "--frames", "45"),
    "cesiumman_02_03": ("bake", "--clip", "{assets}/mocap/cmu_bvh/02_03.bvh",
                        "--character", "{assets}/characters/CesiumMan.glb", "--end", "4"),
    "cesiumman_09_11": ("bake", "--clip", "{assets}/mocap/cmu_bvh/09_11.bvh",
                        "--character", "{assets}/characters/CesiumMan.glb"),
    "cat_walk": ("bake", "--character", "{assets}/characters/zoo/Cat.glb", "--animation", "Walk"),
    "cat_walk_fem": ("bake", "--character", "{assets}/characters/zoo/Cat.glb", "--animation", "Walk",
                     "--tissue", "fem", "--frames", "12"),
}
"""name -> `jiggle` arguments ({assets}: ../shared/assets), each written with every cache format."""
FORMATS = ("--formats", "npz,usdc,pc2,glb")
WALL_KEYS = ("timings",)
"""bake.json entries that are wall-clock seconds, different on every run of the same code."""


def export(rev: str, work: Path) -> Path:
    """REV's tree exported into work/src-<sha> (once); its path."""
    sha = subprocess.run(["git", "-C", str(ROOT), "rev-parse", rev], capture_output=True, text=True,
                         check=True).stdout.strip()
    src = work / f"src-{sha[:12]}"
    if not (src / "jiggle" / "__init__.py").exists():
        src.mkdir(parents=True, exist_ok=True)
        archive = subprocess.run(["git", "-C", str(ROOT), "archive", sha], capture_output=True, check=True).stdout
        subprocess.run(["tar", "-x", "-C", str(src)], input=archive, check=True)
    return src


def bake(src: Path, case: str, out: Path) -> float:
    """Bake `case` with the jiggle of `src` into `out`; its wall seconds. Raises SystemExit on failure."""
    argv = [a.format(assets=ASSETS) for a in CASES[case]]
    argv += [*FORMATS, "--out", str(out)] if argv[0] == "bake" else ["--out", str(out)]
    env = {**os.environ, "PYTHONPATH": str(src), "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    t = time.perf_counter()
    r = subprocess.run([sys.executable, "-c", "import jiggle, sys; assert jiggle.__file__.startswith(sys.argv[1]), "
                        "jiggle.__file__; from jiggle.sim.app.cli import main; sys.exit(main(sys.argv[2:]))",
                        str(src), *argv], capture_output=True, text=True, env=env, cwd=str(src))
    if r.returncode != 0:
        raise SystemExit(f"{case} with {src}: jiggle {' '.join(argv)} failed ({r.returncode}):\n{r.stderr[-3000:]}")
    return time.perf_counter() - t


def _strip_wall(x):
    """bake.json less its wall-clock entries (WALL_KEYS and the FEM's `*_s` seconds)."""
    if isinstance(x, dict):
        return {k: _strip_wall(v) for k, v in x.items() if k not in WALL_KEYS and not k.endswith("_s")
                or k in ("duration_s", "start_s", "end_s")}
    if isinstance(x, list):
        return [_strip_wall(v) for v in x]
    return x


def _json_diffs(a, b, where="") -> list[str]:
    """Where two JSON values differ, as 'path: before != after' lines."""
    if isinstance(a, dict) and isinstance(b, dict):
        out = [f"{where}.{k}: only {'before' if k in a else 'after'}" for k in sorted(set(a) ^ set(b))]
        if list(k for k in a if k in b) != list(k for k in b if k in a):
            out.append(f"{where}: keys in another order")
        for k in a:
            if k in b:
                out += _json_diffs(a[k], b[k], f"{where}.{k}")
        return out
    if isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        return [d for i, (u, v) in enumerate(zip(a, b)) for d in _json_diffs(u, v, f"{where}[{i}]")]
    return [] if a == b and type(a) is type(b) else [f"{where}: {str(a)[:80]} != {str(b)[:80]}"]


def compare(before: Path, after: Path) -> tuple[int, list[str]]:
    """(files compared, differences) between two bake folders."""
    diffs, n = [], 0
    names = sorted({p.name for p in before.iterdir()} | {p.name for p in after.iterdir()})
    for name in names:
        a, b = before / name, after / name
        if not (a.is_file() and b.is_file()):
            diffs.append(f"{name}: only in {'before' if a.exists() else 'after'}")
            continue
        n += 1
        if name.endswith(".npz"):
            with np.load(a, allow_pickle=False) as za, np.load(b, allow_pickle=False) as zb:
                if sorted(za.files) != sorted(zb.files):
                    diffs.append(f"{name}: arrays {sorted(set(za.files) ^ set(zb.files))} in one only")
                for k in za.files:
                    if k in zb.files:
                        u, v = za[k], zb[k]
                        if u.dtype != v.dtype or u.shape != v.shape or u.tobytes() != v.tobytes():
                            diffs.append(f"{name}[{k}]: {u.dtype}{u.shape} != {v.dtype}{v.shape} or its bytes")
        elif name.endswith(".json"):
            ja, jb = json.loads(a.read_text()), json.loads(b.read_text())
            diffs += [f"{name}{d}" for d in _json_diffs(_strip_wall(ja), _strip_wall(jb))]
        elif a.read_bytes() != b.read_bytes():
            diffs.append(f"{name}: bytes differ")
    return n, diffs


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--before", required=True, help="the commit to compare with (e.g. the one before a refactor)")
    p.add_argument("--case", action="append", choices=sorted(CASES), help="only these cases (default: all)")
    p.add_argument("--work", type=Path, default=Path(tempfile.gettempdir()) / "jiggle-bake-identity",
                   help="where REV's export and its bakes are kept between runs")
    p.add_argument("--before-only", action="store_true", help="only bake REV's side (to compare later)")
    a = p.parse_args(argv)
    if not ASSETS.is_dir():
        print(f"skipped: {ASSETS} is absent")
        return 0
    src = export(a.before, a.work)
    rows, failed = [], False
    for case in a.case or list(CASES):
        before = a.work / src.name.replace("src-", "bake-") / case
        if not (before / "bake.json").exists():
            t_before = bake(src, case, before)
        else:
            t_before = float("nan")
        if a.before_only:
            print(f"{case}: baked by {a.before} in {before}", flush=True)
            continue
        with tempfile.TemporaryDirectory(prefix=f"jiggle-identity-{case}-") as tmp:
            t_after = bake(ROOT, case, Path(tmp) / case)
            n, diffs = compare(before, Path(tmp) / case)
        failed |= bool(diffs)
        rows.append((case, n, diffs, t_before, t_after))
        print(f"{case}: {n} files, {'equal bit for bit' if not diffs else f'{len(diffs)} differences'} "
              f"(before {t_before:.1f} s, after {t_after:.1f} s)", flush=True)
        for d in diffs[:20]:
            print(f"  {d}")
    if a.before_only:
        return 0
    head = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True,
                          text=True).stdout.strip()
    lines = [f"# Bake identity: {a.before} against this checkout (HEAD {head}, with its uncommitted changes)", "",
             "`python benchmarks/bake_identity.py --before " + a.before + "`, both sides baked on the same machine.", "",
             "| case | files | result | bake s (before / after) |", "|---|---|---|---|"]
    for case, n, diffs, tb, ta in rows:
        lines.append(f"| {case} | {n} | {'equal bit for bit' if not diffs else f'{len(diffs)} differ'} | "
                     f"{tb:.1f} / {ta:.1f} |")
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "bake_identity.md").write_text("\n".join(lines) + "\n")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
