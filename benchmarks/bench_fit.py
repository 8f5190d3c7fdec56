"""Fitting the default musculoskeletal template (rig.muscle.fit.fit_musculature) on CesiumMan and on a
~30k-vertex generated body, with the stage split (segmentation, fit, muscle model), and two ratios
measured in this one run:

- conforming: rig.muscle.conform.conform on every fitted muscle's ellipsoid mesh (embree, all of a muscle's
  rays in one batched call) against a per-ray reference loop (one mesh.ray.intersects_location call per
  ray) run on a subset of rays and scaled per ray;
- ellipsoid moments: rig.muscle.ellipsoid.surface_moments (vectorised over triangles) against a per-triangle
  Python loop on the largest fitted region, run whole.

    .venv/bin/python benchmarks/bench_fit.py [rays]

The issue's budgets (3 s on CesiumMan, 10 s on a 30k-vertex body) are printed beside the measured
figures as information, not asserted. CesiumMan comes from ../shared/assets; that part is skipped with
a message when the assets are absent. The body's generation is not timed. The muscle model stage solves
small least-squares systems through the BLAS, so its time depends on the BLAS's threads and the
machine's load: the best and the worst of the repeats are both printed.
"""
from __future__ import annotations

import os
import sys
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from timing import best  # noqa: E402  (benchmarks/timing.py)

from jiggle.rig.base.errors import JiggleWarning  # noqa: E402
from jiggle.rig.character.body import BodyOptions  # noqa: E402
from jiggle.rig.character.load import body_character, load_character  # noqa: E402
from jiggle.rig.motion.mocap import load_clip  # noqa: E402
from jiggle.rig.muscle.conform import conform, first_hits  # noqa: E402
from jiggle.rig.muscle.ellipsoid import surface_moments  # noqa: E402
from jiggle.rig.muscle.fit import FitOptions, _chain, _face_regions, fit_musculature  # noqa: E402

CESIUM = ROOT.parent / "shared" / "assets" / "characters" / "CesiumMan.glb"
CLIP = ROOT / "scenes" / "motions" / "jumping_jacks.toml"
STAGES = ("segmentation", "fit", "muscle model")
BUDGET_CESIUM, BUDGET_BODY = 3.0, 10.0


def fit(character):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", JiggleWarning)  # skipped muscles are listed in Musculature.skipped
        return fit_musculature(character)


def fit_repeats(character, repeats: int):
    """(best wall seconds, its Musculature, worst wall seconds) over `repeats` fits."""
    runs = [best(lambda: fit(character), repeats=1) for _ in range(repeats)]
    t_best, musc = min(runs, key=lambda r: r[0])
    return t_best, musc, max(r[0] for r in runs)


def print_fit(label: str, character, t_best: float, musc, t_worst: float, repeats: int, budget: float) -> None:
    V, F, _ = musc.skin
    print(f"{label}: {character.num_vertices} vertices, {len(character.faces)} faces "
          f"(fitted on {len(V)} vertices, {len(F)} faces); {len(musc.muscles)} muscles fitted, "
          f"{len(musc.skipped)} skipped")
    print(f"  {'stage (best run)':50s} {'seconds':>9s}")
    for k in STAGES:
        print(f"  {k:50s} {musc.timings[k]:9.4f}")
    print(f"  {f'fit_musculature total, best of {repeats} (budget {budget:g} s)':50s} {t_best:9.4f}")
    print(f"  {f'fit_musculature total, worst of {repeats}':50s} {t_worst:9.4f}")


# ---------------------------------------------------------------------------------- conforming
def allowed_faces(musc, label: str) -> np.ndarray:
    """(F',) bool: the skin triangles of the template bone `label` ("parent>child"), as fit_musculature
    builds them (the regions of the bone segments on the joint chain, majority of a triangle's corners)."""
    c = musc.character
    p, q = (c.joint_names.index(n) for n in label.split(">"))
    chain = _chain(c.parents, p, q)
    segs = musc.segmentation.segments
    on_chain = np.isin(segs.parent, chain[:-1]) & np.isin(segs.child, chain[1:])
    _, F, region = musc.skin
    out = np.zeros(len(F), bool)
    out[np.isin(_face_regions(region, F), np.nonzero(on_chain)[0])] = True
    return out


def rays(e, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The conforming rays of rig.muscle.conform.conform: from each vertex's foot on the major axis outward."""
    a = e.axes[0]
    s = (pts - e.centre) @ a
    foot = e.centre + s[:, None] * a
    radial = pts - foot
    r = np.linalg.norm(radial, axis=1)
    ok = r > 1e-9 * e.radii[0]
    return foot[ok], radial[ok] / r[ok, None]


def per_ray_loop(mesh, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """Reference: one intersects_location call per ray; distance to the first hit (inf on a miss)."""
    out = np.full(len(origins), np.inf)
    for i in range(len(origins)):
        loc, _, _ = mesh.ray.intersects_location(origins[i:i + 1], directions[i:i + 1], multiple_hits=False)
        if len(loc):
            d = float((loc[0] - origins[i]) @ directions[i])
            out[i] = d if d >= 0 else np.inf
    return out


def bench_conform(musc, label: str, subset: int) -> None:
    import trimesh
    options = FitOptions()
    V, F, _ = musc.skin
    skin = trimesh.Trimesh(V, F, process=False)
    allowed = {label: allowed_faces(musc, label) for label in {m.bone_label for m in musc.muscles}}
    jobs = []
    for m in musc.muscles:
        pts, tri = m.ellipsoid.mesh(options.subdivisions)
        jobs.append((m, pts, tri))

    def conform_all():
        return [conform(m.ellipsoid, pts, skin, nu=m.spec.nu, plane=m.plane, reach=options.reach,
                        allowed=allowed[m.bone_label], faces=tri, smoothing=options.smoothing)[0]
                for m, pts, tri in jobs]

    t_conform, out = best(conform_all, repeats=3, warmup=True)  # warm-up builds the skin's embree scene
    same = max(float(np.abs(o - m.vertices).max()) for o, (m, _, _) in zip(out, jobs))
    origins, directions = (np.concatenate(x) for x in zip(*(rays(m.ellipsoid, pts) for m, pts, _ in jobs)))
    n_rays = len(origins)
    t_batched, dist = best(lambda: first_hits(skin, origins, directions)[0], repeats=3)
    idx = np.random.default_rng(0).choice(n_rays, size=min(subset, n_rays), replace=False)
    t_loop, ref = best(lambda: per_ray_loop(skin, origins[idx], directions[idx]), repeats=1)
    t_loop_all = t_loop * n_rays / len(idx)
    both = np.isfinite(ref) & np.isfinite(dist[idx])
    agree = np.mean(np.isfinite(ref) == np.isfinite(dist[idx]))
    err = float(np.abs(ref[both] - dist[idx][both]).max()) if both.any() else 0.0

    print(f"conforming on the {label} fit: {len(jobs)} muscles, {n_rays} rays "
          f"(icosphere level {options.subdivisions}), skin {len(F)} triangles")
    print(f"  {'conform, every muscle (batched embree rays)':50s} {t_conform:9.4f}")
    print(f"  {'first hits alone, all rays in one call':50s} {t_batched:9.4f}")
    print(f"  {f'per-ray loop, {len(idx)} rays':50s} {t_loop:9.4f}")
    print(f"  {'per-ray loop, scaled to all rays':50s} {t_loop_all:9.4f}")
    print(f"  ratio per-ray loop / conform (all of it):          {t_loop_all / t_conform:7.1f}x")
    print(f"  ratio per-ray loop / batched first hits:           {t_loop_all / t_batched:7.1f}x")
    print(f"  subset: same hit/miss {agree:.2%}, max |distance difference| {err:.1e} m; "
          f"conform reproduces the fitted meshes to {same:.1e} m")


# ---------------------------------------------------------------------------------- moments
def moments_loop(vertices: np.ndarray, faces: np.ndarray):
    """Reference: area, mean and covariance of points spread over the triangles, one triangle at a time."""
    total, first, second = 0.0, np.zeros(3), np.zeros((3, 3))
    for f in faces:
        a, b, c = vertices[f[0]], vertices[f[1]], vertices[f[2]]
        area = 0.5 * np.linalg.norm(np.cross(b - a, c - a))
        s = a + b + c
        total += area
        first += area * s
        second += area * (np.outer(a, a) + np.outer(b, b) + np.outer(c, c) + np.outer(s, s))
    mean = first / (3.0 * total)
    return total, mean, second / (12.0 * total) - np.outer(mean, mean)


def bench_moments(musc, label: str) -> None:
    V, F, _ = musc.skin
    m = max(musc.muscles, key=lambda m: len(m.region))
    faces = F[m.region]
    t_vec, (area, mean, cov) = best(lambda: surface_moments(V, faces), repeats=5, warmup=True)
    t_loop, (area_r, mean_r, cov_r) = best(lambda: moments_loop(V, faces), repeats=1)
    d_area = abs(area - area_r) / area_r
    d_mean = float(np.abs(mean - mean_r).max())
    d_cov = float(np.abs(cov - cov_r).max() / np.abs(cov_r).max())
    print(f"ellipsoid moments on the largest region of the {label} fit ({m.name}, {len(faces)} triangles)")
    print(f"  {'surface_moments, vectorised':50s} {t_vec:9.6f}")
    print(f"  {'per-triangle Python loop':50s} {t_loop:9.6f}")
    print(f"  ratio loop / vectorised:                           {t_loop / t_vec:7.1f}x")
    print(f"  differences: area {d_area:.1e} (relative), mean {d_mean:.1e} m, covariance {d_cov:.1e} (relative)")


def main(subset: int = 200) -> None:
    t_run = time.perf_counter()
    blas = os.environ.get("OPENBLAS_NUM_THREADS") or os.environ.get("OMP_NUM_THREADS") or "default"
    print(f"{os.cpu_count()} CPUs; BLAS threads: {blas}")
    verdict = []
    cesium = None
    if CESIUM.exists():
        cesium = load_character(CESIUM)
        t_c, cesium, t_c_worst = fit_repeats(cesium, 3)
        print_fit("CesiumMan", cesium.character, t_c, cesium, t_c_worst, 3, BUDGET_CESIUM)
        verdict.append(f"CesiumMan {t_c:.2f} s (budget {BUDGET_CESIUM:g} s: "
                       f"{'within' if t_c <= BUDGET_CESIUM else 'OVER'})")
    else:
        print(f"skipped CesiumMan: {CESIUM} not found (../shared/assets is absent)")
        verdict.append("CesiumMan skipped")

    t0 = time.perf_counter()
    body = body_character(load_clip(str(CLIP)), BodyOptions(resolution=30000))
    t_gen = time.perf_counter() - t0
    t_b, musc_b, t_b_worst = fit_repeats(body, 2)
    print(f"(body generated in {t_gen:.2f} s from {CLIP.name}, not timed below)")
    print_fit("generated body, resolution 30000", body, t_b, musc_b, t_b_worst, 2, BUDGET_BODY)
    verdict.append(f"{body.num_vertices}-vertex body {t_b:.2f} s (budget {BUDGET_BODY:g} s: "
                   f"{'within' if t_b <= BUDGET_BODY else 'OVER'})")

    subject, label = (cesium, "CesiumMan") if cesium is not None else (musc_b, "generated body")
    bench_conform(subject, label, subset)
    bench_moments(subject, label)
    print("verdict (information, not an assert): " + "; ".join(verdict))
    print(f"(benchmark ran {time.perf_counter() - t_run:.1f} s)")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 200)
