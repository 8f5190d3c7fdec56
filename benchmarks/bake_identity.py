"""Bit-for-bit check of a behaviour-preserving change: the same bakes made by an earlier commit and by this checkout,
on this machine, compared file by file.

    python benchmarks/bake_identity.py --before REV [--case NAME ...] [--work DIR] [--before-only]

Both sides are laid, in turn, at one path (WORK/tree: REV's files by `git archive`, then this checkout's files as they
are, its uncommitted changes included; the checkout itself is never touched), since a scene's path is part of what
a bake records, and each case is baked there with this interpreter importing that tree's jiggle. Then every array of
bake.npz must be equal to the bit (dtype, shape and bytes: NaN equals NaN, -0.0 differs from 0.0), bake.json and the
demo's metrics.json must be equal value for value, the key included, leaving out only wall-clock time (WALL_KEYS),
the demo's report.html equal but for its folder and timings, and every other file (usdc, pc2, glb, the demo's plots,
renders and video) equal byte for byte. The before bakes are kept in WORK by REV and case, so a rerun bakes only the
after side.

The cases (CASES): the built-in demo, two shared CMU clips on CesiumMan (02_04's jump and landing, and 09_11, the
case the tissue is calibrated on), zoo characters' own cycles (the Cat's Walk; the Horse's Gallop, whose tail and
ears swing as chains) and a short hero-mode (FEM) bake. No array hash goes into the test suite: floating point differs
between CPUs, so the comparison is only meaningful on one machine, as here.

Writes benchmarks/results/bake_identity.md (the table) and exits 1 when any case differs.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import shutil
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
    "cesiumman_02_04": ("bake", "--clip", "{assets}/mocap/cmu_bvh/02_04.bvh",
                        "--character", "{assets}/characters/CesiumMan.glb"),
    "cesiumman_09_11": ("bake", "--clip", "{assets}/mocap/cmu_bvh/09_11.bvh",
                        "--character", "{assets}/characters/CesiumMan.glb"),
    "cat_walk": ("bake", "--character", "{assets}/characters/zoo/Cat.glb", "--animation", "Walk"),
    "horse_gallop": ("bake", "--character", "{assets}/characters/zoo/Horse.glb", "--animation", "Gallop"),
    "cat_walk_fem": ("bake", "--character", "{assets}/characters/zoo/Cat.glb", "--animation", "Walk",
                     "--tissue", "fem", "--frames", "12"),
}
"""name -> `jiggle` arguments ({assets}: ../shared/assets), each written with every cache format."""
FORMATS = ("--formats", "npz,usdc,pc2,glb")
WALL_KEYS = ("timings", "timings_s", "seconds", "ms_per_step", "fit_s")
"""JSON entries that are wall-clock time, different on every run of the same code (bake.json's timings, the loop's
warm-up and the chains' seconds, the FEM's cost per step, the glb's fit; metrics.json's timings_s)."""
WALL_HTML = re.compile(r"timings \(s\):[^<]*")
"""The report's line of wall-clock timings."""


def lay(work: Path, rev: str | None) -> Path:
    """work/tree holding REV's files (`git archive`), or with REV None this checkout's as they are now (the files git
    tracks and the untracked ones it does not ignore); its path. Both sides are baked from this one path, since a
    scene's path is part of what a bake records (and so of its key)."""
    tree = work / "tree"
    if tree.exists():
        shutil.rmtree(tree)
    tree.mkdir(parents=True)
    if rev is not None:
        files = subprocess.run(["git", "-C", str(ROOT), "archive", rev], capture_output=True, check=True).stdout
    else:
        names = subprocess.run(["git", "-C", str(ROOT), "ls-files", "-z", "-co", "--exclude-standard"],
                               capture_output=True, check=True).stdout
        names = b"\0".join(n for n in names.split(b"\0") if n and os.path.lexists(ROOT / os.fsdecode(n)))
        files = subprocess.run(["tar", "-c", "-C", str(ROOT), "--null", "-T", "-"], input=names, capture_output=True,
                               check=True).stdout
    subprocess.run(["tar", "-x", "-C", str(tree)], input=files, check=True)
    return tree


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
    """A JSON value less its wall-clock entries (WALL_KEYS)."""
    if isinstance(x, dict):
        return {k: _strip_wall(v) for k, v in x.items() if k not in WALL_KEYS}
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
        elif name.endswith(".json"):        # metrics.json names its files by the bake's folder
            ja = json.loads(a.read_text().replace(str(before), "<out>"))
            jb = json.loads(b.read_text().replace(str(after), "<out>"))
            diffs += [f"{name}{d}" for d in _json_diffs(_strip_wall(ja), _strip_wall(jb))]
        elif name.endswith(".html"):
            ta = WALL_HTML.sub("", a.read_text().replace(str(before), "<out>"))
            if ta != WALL_HTML.sub("", b.read_text().replace(str(after), "<out>")):
                diffs.append(f"{name}: differs (beyond its folder and timings)")
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
    sha = subprocess.run(["git", "-C", str(ROOT), "rev-parse", a.before], capture_output=True, text=True,
                         check=True).stdout.strip()
    cases = a.case or list(CASES)
    befores = {case: a.work / f"bake-{sha[:12]}" / case for case in cases}
    if not all((d / "bake.json").exists() for d in befores.values()):
        tree = lay(a.work, sha)
        for case, before in befores.items():
            if not (before / "bake.json").exists():
                print(f"{case}: baking with {a.before} ({bake(tree, case, before):.1f} s)", flush=True)
    rows, failed = [], False
    if not a.before_only:
        tree = lay(a.work, None)
        for case, before in befores.items():
            after = a.work / "after" / case
            if after.exists():
                shutil.rmtree(after)
            t_after = bake(tree, case, after)
            n, diffs = compare(before, after)
            failed |= bool(diffs)
            rows.append((case, n, diffs, t_after))
            print(f"{case}: {n} files, {'equal bit for bit' if not diffs else f'{len(diffs)} differences'} "
                  f"(after {t_after:.1f} s)", flush=True)
            for d in diffs[:20]:
                print(f"  {d}")
    if a.before_only:
        return 0
    head = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True,
                          text=True).stdout.strip()
    lines = [f"# Bake identity: {a.before} against this checkout (HEAD {head}, with its uncommitted changes)", "",
             "`python benchmarks/bake_identity.py --before " + a.before + "`, both sides baked on the same machine.", "",
             "| case | files | result | bake s (after) |", "|---|---|---|---|"]
    for case, n, diffs, ta in rows:
        lines.append(f"| {case} | {n} | {'equal bit for bit' if not diffs else f'{len(diffs)} differ'} | {ta:.1f} |")
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "bake_identity.md").write_text("\n".join(lines) + "\n")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
