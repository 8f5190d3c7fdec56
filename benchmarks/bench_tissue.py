"""The tissue law (sim/jiggle/tissue_law.py) measured: how much of a clip the muscles spend near their
reach, the ring-down it gives, and what it costs in the simulate stage.

    .venv/bin/python benchmarks/bench_tissue.py limits [--json OUT]       # every shared clip, default settings
    .venv/bin/python benchmarks/bench_tissue.py ringdown                   # pulse, free ring-down, a 10x pulse
    .venv/bin/python benchmarks/bench_tissue.py timing [--baseline TREE]   # the simulate stage, ms per frame

limits: bakes (default settings, npz only) the demo scene, the generated body and CesiumMan on every shared
CMU clip (BVH and the AMC with its ASF), and reads each bake's CVs (bake.npz) and reaches (bake.json's
reach_m): per muscle the fraction of frames in which some CV sits at >= 97% (the limit as the old inelastic
stop held it) and >= 90% of its reach, and the hard stops bake.json's "tissue" counts. It reads only files
every bake writes, so the same script run in an older checkout measures the code before the law (copy it
there with the helper it uses: `git worktree add /tmp/old REV && cp benchmarks/bench_tissue.py benchmarks/timing.py
/tmp/old/benchmarks/`; --baseline runs that copy).

timing: the bake's simulate stage (sim.jiggle.simulate over chunks of 64 frames as sim/bake/baker.py runs
it, collisions on as by default) per frame on the demo and on CesiumMan 02_04, the best of 7 after a
warm-up. With --baseline TREE the same measurement runs in TREE's code too, alternated with this checkout's
in separate processes (3 rounds each, the best kept), and the ratio is printed: both in one run.
"""
from __future__ import annotations

import argparse
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import json  # noqa: E402
import math  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

ASSETS = ROOT.parent / "shared" / "assets"
BVH = ("01_01", "02_03", "02_04", "05_02", "09_11")
CESIUM = ASSETS / "characters" / "CesiumMan.glb"


def cases() -> list[tuple[str, dict]]:
    """(label, BakeRequest keywords) of every case: the demo, then each clip on the generated body and on
    CesiumMan (those present)."""
    out = [("demo", {})]
    clips = [(ASSETS / "mocap" / "cmu_bvh" / f"{c}.bvh", None) for c in BVH]
    clips.append((ASSETS / "mocap" / "cmu_amc" / "01_01.amc", ASSETS / "mocap" / "cmu_amc" / "01.asf"))
    for character in (None, CESIUM):
        if character is not None and not character.exists():
            continue
        for clip, asf in clips:
            if not clip.exists():
                continue
            kw = {"clip": str(clip), "character": None if character is None else str(character)}
            if asf is not None:
                kw["skeleton"] = str(asf)
            who = "generated body" if character is None else character.stem
            out.append((f"{who} {clip.name}", kw))
    return out


def limits_of(out: str) -> dict:
    """From a finished bake in `out`: per muscle the fraction of frames at >= 97% and >= 90% of its reach,
    its peak over reach, and bake.json's hard stops (None where the bake does not count them)."""
    from jiggle.sim.bake.caches import read_npz
    data = read_npz(os.path.join(out, "bake.npz"))
    with open(os.path.join(out, "bake.json"), encoding="utf-8") as fh:
        summary = json.load(fh)
    table = json.loads(data.params).get("muscles", {})
    d = data.muscle_cvs_dynamic.astype(np.float64) - data.muscle_cvs_static
    dist = np.linalg.norm(d, axis=2)
    o = data.muscle_cv_offsets
    stops = (summary.get("tissue") or {}).get("hard_stops")
    res = {}
    for m, name in enumerate(data.muscle_names):
        reach = (table.get(name) or {}).get("reach_m")
        if not reach:
            continue
        rho = dist[:, o[m]:o[m + 1]].max(axis=1) / reach
        res[name] = {"at97": float((rho >= 0.97).mean()), "at90": float((rho >= 0.9).mean()),
                     "peak": float(rho.max()), "peak_mm": 1e3 * float(rho.max() * reach), "reach_mm": 1e3 * reach,
                     "hard_stops": None if stops is None else int(stops.get(name, 0))}
    return {"frames": int(len(data.times)), "muscles": res,
            "simulate_s": summary.get("timings", {}).get("simulate_s")}


def limits(json_out: str | None) -> list[dict]:
    import contextlib
    import io

    from jiggle.sim.app.commands.bake import run_bake
    from jiggle.sim.bake.setup import BakeRequest
    rows = []
    for label, kw in cases():
        with tempfile.TemporaryDirectory() as out, contextlib.redirect_stderr(io.StringIO()):
            run_bake(BakeRequest(formats=("npz",), **kw), out)
            r = limits_of(out)
        mus = r["muscles"]
        touch = [n for n, x in mus.items() if x["at97"] > 0]
        worst = sorted(mus.items(), key=lambda kv: -kv[1]["at90"])[:3]
        all90 = float(np.mean([x["at90"] for x in mus.values()])) if mus else 0.0
        stops = [x["hard_stops"] for x in mus.values() if x["hard_stops"] is not None]
        row = {"case": label, "frames": r["frames"], "muscles": len(mus), "touch97": len(touch),
               "max_at97": max((x["at97"] for x in mus.values()), default=0.0),
               "max_at90": max((x["at90"] for x in mus.values()), default=0.0), "all_at90": all90,
               "over5pct_at90": sum(x["at90"] > 0.05 for x in mus.values()),
               "hard_stops": sum(stops) if stops else None,
               "worst": [(n, round(100 * x["at90"], 1), round(x["peak"], 2)) for n, x in worst],
               "per_muscle": mus}
        rows.append(row)
        print(f"{label:32s} {r['frames']:5d} fr  touch>=97%: {len(touch):2d}/{len(mus)}  "
              f"max>=97%: {100 * row['max_at97']:5.1f}%  max>=90%: {100 * row['max_at90']:5.1f}%  "
              f"all>=90%: {100 * all90:5.2f}%  >5%: {row['over5pct_at90']}  hard stops: {row['hard_stops']}  "
              f"worst: {row['worst']}", flush=True)
    if json_out:
        with open(json_out, "w", encoding="utf-8") as fh:
            json.dump(rows, fh, indent=1)
    return rows


# ------------------------------------------------------------------------------------------------ ringdown
def ringdown() -> list[dict]:
    """Single particles (goal weight 1/2, strength 1, no neighbours) given a pulse of offset velocity, then
    free: the measured frequency and damping ratio against the set ones (a pulse of 0.2 reach: linear), and a
    pulse ten times larger (a linear swing of 2 reaches): its peak over the reach, whether the peaks fall
    every half cycle, and how long it stays within 1% of its largest offset (a plateau would be long)."""
    from jiggle.sim.jiggle.goal_track import build_track
    from jiggle.sim.jiggle.particles import ParticleBuilder
    from jiggle.sim.jiggle.solver import ParticleSolver
    R, rows = 0.02, []
    for f, z in ((2.0, 0.1), (4.0, 0.2), (4.0, 0.3), (8.0, 0.4)):
        w = 2 * math.pi * f
        b = ParticleBuilder()
        for _ in range(2):
            b.add_particle([0, 0, 0], 0.01, w * w, 2 * z * w, reach=R)
        model = b.finalize()
        grid = np.linspace(0, 3, 3001)                     # 1 ms steps, the goals' knots on them (a still goal)
        track = build_track(grid, np.zeros((len(grid), 2, 3)))
        solver = ParticleSolver(model)
        a, o = model.state(), model.state()
        u0 = np.array([[0.2 * R * w, 0, 0], [2.0 * R * w, 0, 0]])
        a.assign(np.zeros((2, 3)), u0)
        xs = solver.integrate(a, o, track.to_device(), grid, record=np.arange(1, len(grid)))[:, :, 0]
        t = grid[1:]
        res = {"f_hz": f, "zeta": z}
        for k, name in ((0, "small"), (1, "large")):
            s = xs[:, k]
            zc = np.flatnonzero(np.sign(s[:-1]) != np.sign(s[1:]))
            up = np.flatnonzero((s[:-1] < 0) & (s[1:] >= 0))
            tc = t[up] - s[up] * (t[up + 1] - t[up]) / (s[up + 1] - s[up])
            peaks = np.array([np.abs(s[i + 1:j + 1]).max() for i, j in zip(zc[:-1], zc[1:])])
            if name == "small":
                delta = math.log(peaks[0] / peaks[2])
                res["f_measured"] = 1.0 / float(np.diff(tc[:3]).mean()) / math.sqrt(1 - z * z)
                res["zeta_measured"] = delta / math.sqrt(4 * math.pi ** 2 + delta ** 2)
            else:
                res["large_peak_over_reach"] = float(np.abs(s).max() / R)
                res["large_peaks_fall"] = bool(np.all(np.diff(peaks) < 0))
                res["large_top_ms"] = 1e3 * float((np.abs(s) >= 0.99 * np.abs(s).max()).sum() * (t[1] - t[0]))
                res["large_period_ms"] = 1e3 / f
        res["hard_stops"] = int(solver.hard_stops().sum()) if hasattr(solver, "hard_stops") else None
        rows.append(res)
        print(f"f {f:4.1f} Hz zeta {z:.2f}: measured f {res['f_measured']:6.3f} Hz "
              f"({100 * (res['f_measured'] / f - 1):+.2f}%), zeta {res['zeta_measured']:.4f} "
              f"({100 * (res['zeta_measured'] / z - 1):+.2f}%); 10x pulse: peak {res['large_peak_over_reach']:.3f} "
              f"reach, peaks fall {res['large_peaks_fall']}, within 1% of its top {res['large_top_ms']:.1f} ms "
              f"of a {res['large_period_ms']:.0f} ms period, hard stops {res['hard_stops']}", flush=True)
    return rows


# ------------------------------------------------------------------------------------------------ timing
def simulate_stage(clip=None, character=None, repeats: int = 7) -> dict:
    """The bake's simulate stage per frame (ms), collisions on, best of `repeats` after a warm-up."""
    from jiggle.sim.bake.setup import BakeRequest, prepare
    from jiggle.sim.jiggle.colliders import collider_model
    from jiggle.sim.jiggle.particles import muscle_model
    from jiggle.sim.jiggle.simulate import goals, simulate
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from timing import chunk_spans
    from jiggle.sim.jiggle.solver import ParticleSolver
    s = prepare(BakeRequest(clip=clip, character=character, formats=("npz",)))
    rig = s.rig
    model = muscle_model(rig, list(s.jiggles), "cpu", gravity=s.settings.gravity)
    cm = collider_model(rig, s.character, capsules=s.capsules, floor=s.floor)
    times = s.times
    world = np.asarray(s.world_at(s.knots))
    static = rig.static(world)
    chunks = []
    for _, f1, a, ka, kb in chunk_spans(s.times, s.knots):
        tr = goals(rig, s.knots[ka:kb], static.cvs[ka:kb], s.settings)
        chunks.append((a, f1, tr, cm.at(s.knots[ka:kb], world[ka:kb], tr.cut)))

    def bake():
        solver = ParticleSolver(model)
        state = None
        for c, (a, f1, tr, col) in enumerate(chunks):
            _, state = simulate(model, tr, times[a:f1], s.settings, solver=solver, preroll=None if c == 0 else 0.0,
                                start=state, colliders=col, contacts={})
    bake()
    best = math.inf
    for _ in range(repeats):
        t = time.perf_counter()
        bake()
        best = min(best, time.perf_counter() - t)
    return {"frames": len(times), "ms_per_frame": 1e3 * best / len(times)}


def timing(baseline: str | None, json_out: str | None) -> dict:
    runs = {"demo": {}, "CesiumMan 02_04": {"clip": str(ASSETS / "mocap" / "cmu_bvh" / "02_04.bvh"),
                                             "character": str(CESIUM)}}
    if not CESIUM.exists():
        runs.pop("CesiumMan 02_04")
    if baseline is None:
        out = {k: simulate_stage(**kw) for k, kw in runs.items()}
        for k, v in out.items():
            print(f"{k:20s} simulate stage {v['ms_per_frame']:.3f} ms/frame ({v['frames']} frames)")
    else:
        trees = {"this": ROOT, "baseline": Path(baseline).resolve()}
        best = {t: {} for t in trees}
        for _ in range(3):                      # alternated: a busy spell of the machine slows both alike
            for t, tree in trees.items():
                res = subprocess.run([sys.executable, str(tree / "benchmarks" / "bench_tissue.py"), "timing",
                                      "--json", "-"], capture_output=True, text=True, cwd=tree, check=True)
                got = json.loads(res.stdout.strip().splitlines()[-1])
                for k, v in got.items():
                    best[t][k] = min(best[t].get(k, math.inf), v["ms_per_frame"])
        out = {k: {"this_ms": best["this"][k], "baseline_ms": best["baseline"][k],
                   "ratio": best["this"][k] / best["baseline"][k]} for k in best["this"]}
        for k, v in out.items():
            print(f"{k:20s} simulate stage: this {v['this_ms']:.3f} ms/frame, baseline {v['baseline_ms']:.3f}, "
                  f"ratio {v['ratio']:.3f}")
    if json_out == "-":
        print(json.dumps(out))
    elif json_out:
        with open(json_out, "w", encoding="utf-8") as fh:
            json.dump(out, fh, indent=1)
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("what", choices=("limits", "ringdown", "timing"), nargs="?", default="limits")
    p.add_argument("--json", default=None, help="write the figures here (- : stdout, last line)")
    p.add_argument("--baseline", default=None, help="timing: a checkout to measure side by side")
    a = p.parse_args(argv)
    if a.what == "limits":
        limits(a.json)
    elif a.what == "ringdown":
        ringdown()
    else:
        timing(a.baseline, a.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
