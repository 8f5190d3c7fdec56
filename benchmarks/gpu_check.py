"""The bake on a GPU against the same bake on the CPU of the same machine: tests, agreement, speed; one table.

    python benchmarks/gpu_check.py OUT [--device cuda] [--quick] [--only tests,agree,...]
    benchmarks/gpu_check.sh OUT          (on a lent GPU machine: unpacks .gpu's parts first; gpu_check.md)

Writes OUT/gpu_check.md (the table), OUT/gpu_check.json (every figure) and OUT/gpu_check.log (each section's
output), and prints the table last. Each section runs in its own process with its own time limit, so a crash
or a hang in one is a row of the table, not the end of the check. `--device cpu` runs the whole check with the
CPU on both sides (to check the script on a machine without a GPU: the figures then compare the CPU with itself).

Sections (each "ours" figure is measured with --device D and with the CPU, in one run, same machine):
  env        Python, Warp, the devices, the GPU's name and memory, CPU cores.
  tests      pytest of tests/bake/test_device.py: the CUDA bake against the CPU bake, resume and frame-rate
             independence on the device (its tests skip where the device is missing, saying so).
  agree      the demo (built-in body, jumping jacks), CesiumMan on 02_03.bvh and the 30k-vertex body baked on
             both devices with every cache (npz, usdc, pc2): the largest difference of each cache, mm
             (target: < 0.1 mm).
  speed      per mesh (CesiumMan, the 30k body, a 100k body): the bake's frame loop (benchmarks/bench_bake.py's
             bake_loop_threads: every stage, the spread in a second thread, no files) and the whole bake with its
             caches, frames/s, against the LBS-only pipeline on the same device; the stage times per frame.
             Targets: 30k body >= 1,000 frames/s in the loop on the GPU, >= 900 frames/s (30x real time at
             30 fps) with caches, the loop within 3x of LBS-only on the GPU.
  particles  particle-steps/s of the solver (the bake's particle stage, and the kernel alone) at 1,600 and at
             1,000,000 particles (benchmarks/bench_particles.py's model, copied). Target: >= 1 G/s on the GPU.
  batch      16 bakes of CesiumMan (150 frames each, `jiggle batch --no-report` on Dask's LocalCluster) with 16
             worker processes sharing the device, against one worker baking them one after another.
  graph      (issue 45) the particle stage of the bake as a CUDA graph per chunk (sim/jiggle/graph.py) against the
             plain launches, same run, same model: 1,600 particles and 1,000,000 particles (a few frames: the
             1M particle-steps row), particle-steps/s and the largest difference; and 16 bakes packed into one
             process's one particle array (sim/jiggle/packed.py: CesiumMan's muscles at 16 jiggle strengths, each
             chunk one packed run) against one bake alone: bakes per second of the particle stage.
             On the CPU (--device cpu) the graph rows launch directly (the CPU's one-launch runs, no capture).

--precompile ARCH (benchmarks/gpu_pack.sh): no check; tiny CPU bakes of every case load every Warp module the
check uses (compiling their CPU kernels into the kernel cache, WARP_CACHE_PATH), then each module is compiled
ahead of time for sm_ARCH with Warp's NVRTC, so that a GPU machine finds them compiled.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
import traceback
from pathlib import Path
from types import MappingProxyType

os.environ.setdefault("MUJOCO_GL", "egl")
ROOT = Path(__file__).resolve().parents[1]
BENCH = Path(__file__).resolve().parent
sys.path[:0] = [str(ROOT), str(BENCH)]
ASSETS = Path(os.environ.get("JIGGLE_ASSETS", ROOT.parent / "shared" / "assets"))
CESIUM = ASSETS / "characters" / "CesiumMan.glb"
CLIP = ASSETS / "mocap" / "cmu_bvh" / "02_03.bvh"
LONG_CLIP = ASSETS / "mocap" / "cmu_bvh" / "05_02.bvh"
"""9.4 s (281 frames at 30 fps): the speed runs' CesiumMan clip (02_03 lasts 1.5 s)"""
DEFAULT = ROOT / "scenes" / "default.toml"

SECTIONS = {"env": 20, "tests": 50, "agree": 50, "speed": 170, "particles": 35, "batch": 65, "graph": 80}
"""Each section's time limit, seconds: 470 in all, so the whole check ends inside 8 minutes (an H200 machine took
26 s for the tests, 36 for the agreement; a section cut by its limit still gives the rows it finished)."""
SPEED_FRAMES_100K = 91
"""Frames of the 100k body in the speed section (run 2's 301 frames did not fit its limit)."""
FORMATS = ("npz", "usdc", "pc2")
AGREE_MM = 0.1
TARGETS = {"loop_fps_30k": 1000.0, "caches_fps_30k": 900.0, "lbs_ratio": 3.0, "steps_per_s": 1e9}


# ---------------------------------------------------------------------------------------- cases
def cases(quick: bool, long: str | None = None) -> dict:
    """{name: BakeRequest keywords} of the meshes the check bakes (CesiumMan only when the assets are here).
    long : a scene file (long_scene) for the generated bodies and 05_02.bvh for CesiumMan, for the speed runs."""
    scene = long or str(DEFAULT)
    out = {"demo": {"scene": str(DEFAULT), "fps": 30}}
    clip = LONG_CLIP if long and LONG_CLIP.exists() else CLIP
    if CESIUM.exists() and clip.exists():
        out["cesium"] = {"clip": str(clip), "character": str(CESIUM), "fps": 30}
    out["body30k"] = {"scene": scene, "fps": 30, "body": MappingProxyType({"resolution": 30000})}
    if not quick:
        out["body100k"] = {"scene": scene, "fps": 30, "body": MappingProxyType({"resolution": 100000})}
        if long:                   # the speed runs: fewer frames of the 100k body, so that it fits the limit
            out["body100k"]["frames"] = SPEED_FRAMES_100K
    return out


def long_scene(folder: str, cycles: int) -> str:
    """The demo scene with its jumping jacks looped `cycles` times (one cycle a second), written into folder."""
    src = (ROOT / "scenes" / "motions" / "jumping_jacks.toml").read_text()
    assert "cycles = 3" in src, "scenes/motions/jumping_jacks.toml changed: update long_scene"
    motion = Path(folder) / "jumping_jacks_long.toml"
    motion.write_text(src.replace("cycles = 3", f"cycles = {cycles}"))
    scene = Path(folder) / "long.toml"
    scene.write_text(DEFAULT.read_text().replace('file = "motions/jumping_jacks.toml"', f'file = "{motion}"'))
    return str(scene)


def request(kw: dict, device: str, formats=FORMATS, **more):
    from jiggle.sim.bake.setup import BakeRequest
    return BakeRequest(**{**kw, **more}, device=device, formats=tuple(formats))


# ---------------------------------------------------------------------------------------- sections
PART: Path | None = None
"""Where the running section keeps what it has measured so far (main sets it): a section stopped at its time
limit still gives the rows it finished."""


def keep(res: dict) -> None:
    if PART is not None:
        PART.write_text(json.dumps(res, indent=1, default=float))


def section_env(device: str, quick: bool) -> dict:
    import numpy as np
    import warp as wp
    t = time.perf_counter()
    wp.init()
    out = {"python": platform.python_version(), "warp": wp.__version__, "numpy": np.__version__,
           "cpu_cores": os.cpu_count(), "cpu": platform.processor() or platform.machine(),
           "warp_init_s": round(time.perf_counter() - t, 2), "devices": [d.alias for d in wp.get_devices()],
           "kernel_cache": wp.config.kernel_cache_dir}
    if device != "cpu":
        d = wp.get_device(device)
        out.update({"gpu": d.name, "gpu_memory_gb": round(d.total_memory / 2**30, 1), "arch": d.arch,
                    "sm_count": getattr(d, "sm_count", None)})
        try:
            smi = subprocess.run(["nvidia-smi", "--query-gpu=name,driver_version,memory.total,clocks.max.sm",
                                  "--format=csv,noheader"], capture_output=True, text=True, timeout=20)
            out["nvidia_smi"] = smi.stdout.strip()
        except (OSError, subprocess.TimeoutExpired) as e:
            out["nvidia_smi"] = f"not run: {e}"
    return out


def section_tests(device: str, quick: bool, out_dir: Path) -> dict:
    xml = out_dir / "tests.xml"
    cmd = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-rs", "--junitxml", str(xml),
           "tests/bake/test_device.py", "tests/jiggle/test_graph.py"]
    r = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, env={**os.environ, "PYTHONPATH": os.pathsep.join(
        [str(ROOT), os.environ.get("PYTHONPATH", "")])})
    print(r.stdout[-6000:], r.stderr[-3000:])
    import xml.etree.ElementTree as ET
    cases_ = []
    if xml.exists():
        for tc in ET.parse(xml).iter("testcase"):
            status = "passed"
            for tag in ("failure", "error", "skipped"):
                el = tc.find(tag)
                if el is not None:
                    status = {"failure": "failed", "error": "error", "skipped": "skipped"}[tag]
                    status += ": " + (el.get("message") or "")[:300]
            cases_.append({"test": tc.get("name"), "status": status, "s": round(float(tc.get("time", 0)), 2)})
    return {"exit": r.returncode, "tests": cases_}


def _compare_caches(a: str, b: str) -> dict:
    """Largest difference (mm) between the caches of two bake folders, per cache and key."""
    import numpy as np

    from jiggle.sim.bake.caches import read_pc2
    out = {}
    with np.load(os.path.join(a, "bake.npz")) as za, np.load(os.path.join(b, "bake.npz")) as zb:
        worst, key = 0.0, ""
        for k in za.files:
            x, y = za[k], zb[k]
            if x.dtype.kind != "f" or x.shape != y.shape:
                if x.shape != y.shape or (x.dtype.kind in "iub" and not np.array_equal(x, y)):
                    out.setdefault("npz_mismatch", []).append(k)
                continue
            if not (np.isfinite(x).all() and np.isfinite(y).all()):
                out.setdefault("npz_not_finite", []).append(k)
                continue
            d = float(np.abs(x.astype(np.float64) - y).max()) if x.size else 0.0
            if k.startswith(("skin", "muscle_cvs", "joint_world")) and d > worst:
                worst, key = d, k
        out["npz_mm"], out["npz_worst_key"] = 1e3 * worst, key
    pa, pb = read_pc2(os.path.join(a, "bake.pc2")), read_pc2(os.path.join(b, "bake.pc2"))
    out["pc2_mm"] = 1e3 * float(np.abs(pa.points.astype(np.float64) - pb.points).max())
    from pxr import Usd, UsdGeom
    sa, sb = Usd.Stage.Open(os.path.join(a, "bake.usdc")), Usd.Stage.Open(os.path.join(b, "bake.usdc"))
    worst = 0.0
    for prim in sa.Traverse():
        if not prim.IsA(UsdGeom.Mesh):
            continue
        pa_, pb_ = UsdGeom.Mesh(prim).GetPointsAttr(), UsdGeom.Mesh(sb.GetPrimAtPath(prim.GetPath())).GetPointsAttr()
        for t in pa_.GetTimeSamples()[::7] or [Usd.TimeCode.Default()]:
            x, y = np.asarray(pa_.Get(t), np.float64), np.asarray(pb_.Get(t), np.float64)
            worst = max(worst, float(np.abs(x - y).max()) if x.size else 0.0)
    out["usdc_mm"] = 1e3 * worst
    out["max_mm"] = max(out["npz_mm"], out["pc2_mm"], out["usdc_mm"])
    out["ok"] = out["max_mm"] < AGREE_MM and not out.get("npz_mismatch") and not out.get("npz_not_finite")
    return out


def section_agree(device: str, quick: bool, out_dir: Path) -> dict:
    from jiggle.sim.bake.baker import bake
    from jiggle.sim.bake.setup import prepare
    res = {}
    for name, kw in cases(quick).items():
        if name == "body100k":
            continue
        with tempfile.TemporaryDirectory() as tmp:
            row = {}
            for side, dev in (("a", "cpu"), ("b", device)):
                folder = os.path.join(tmp, side)
                t = time.perf_counter()
                summary = bake(prepare(request(kw, dev)), folder)
                row[f"{side}_s"] = round(time.perf_counter() - t, 2)
                row["frames"], row["vertices"] = summary["frames"], summary["vertices"]
            row.update(_compare_caches(os.path.join(tmp, "a"), os.path.join(tmp, "b")))
        print(name, row, flush=True)
        res[name] = row
        keep(res)
    return res


def section_speed(device: str, quick: bool, out_dir: Path) -> dict:
    both = os.environ.get("JIGGLE_CHECK_SPEED_CPU", "1") != "0"     # gpu_check.py --speed-cpu-from
    from bench_bake import bake_loop, bake_loop_threads, best, lbs_loop, lbs_with_caches

    from jiggle.sim.bake.baker import Baker, bake
    from jiggle.sim.bake.setup import prepare
    res = {}
    tmp_scene = tempfile.mkdtemp()
    for name, kw in cases(quick, long_scene(tmp_scene, 3 if quick else 5)).items():
        if name == "demo":
            continue
        for dev in dict.fromkeys((device, "cpu") if both else (device,)):
            repeats = 1 if quick or dev == "cpu" else 3     # the CPU's figures vary little and take long
            t = time.perf_counter()
            setup = prepare(request(kw, dev))
            prep = time.perf_counter() - t
            T = len(setup.times)
            with tempfile.TemporaryDirectory() as tmp:
                t = time.perf_counter()
                Baker(setup, defer=False).chunk(0, None)               # compiles what is not cached
                lbs_with_caches(setup, tmp)                            # imports pxr, opens the writers' paths
                warm = time.perf_counter() - t
                threaded = Baker(setup, defer=True)
                loop = best(lambda: bake_loop_threads(threaded), repeats)
                l_loop = best(lambda: lbs_loop(setup), repeats)
                whole = best(lambda: bake(setup, os.path.join(tmp, "full")), repeats)
                l_whole = best(lambda: lbs_with_caches(setup, tmp), repeats)
                stages = bake_loop(Baker(setup, defer=False))
            row = {"frames": T, "vertices": setup.character.num_vertices, "muscles": setup.rig.M,
                   "setup_s": round(prep, 2), "warm_up_s": round(warm, 2),
                   "loop_fps": T / loop, "lbs_loop_fps": T / l_loop, "loop_ratio": loop / l_loop,
                   "caches_fps": T / whole, "lbs_caches_fps": T / l_whole, "caches_ratio": whole / l_whole,
                   "stage_ms_per_frame": {k[:-2]: 1e3 * v / T for k, v in stages.items() if k != "write_s"}}
            print(name, dev, json.dumps(row), flush=True)
            res[f"{name}/{dev}"] = row
            keep(res)
    return res


def section_particles(device: str, quick: bool, out_dir: Path) -> dict:
    import numpy as np
    import warp as wp
    from bench_jiggle import copied_model, swinging_goals
    from bench_particles import CHUNK, COPIES, FPS, SUBSTEPS, bake_chunks, bake_particles, kernel_pass
    from timing import best

    from jiggle.rig.muscle.simple_arm import simple_arm
    from jiggle.sim.jiggle.params import JiggleSettings
    from jiggle.sim.jiggle.secondary import DEFAULT_GOAL_RATE, knot_times
    from jiggle.sim.jiggle.solver import ParticleSolver
    wp.init()
    arm = simple_arm()
    res = {}
    for copies in (COPIES,):          # 1,000,000 particles: the graph section (fewer frames)
        for dev in dict.fromkeys((device, "cpu")):
            # the CPU's 1M run covers fewer frames: the rates are per step
            big = copies > COPIES
            seconds = (0.5 if dev == "cpu" else 2.0) if big else (2.0 if quick else 6.0)
            model, offsets = copied_model(arm, copies, dev)
            settings = JiggleSettings(substeps=SUBSTEPS, device=dev)
            times = np.arange(int(round(seconds * FPS)) + 1) / FPS
            knots = knot_times(times, settings.goal_rate or max(DEFAULT_GOAL_RATE, FPS))
            static = swinging_goals(arm, offsets, knots)
            solver = ParticleSolver(model)
            chunks = bake_chunks(times, knots, static, settings, solver)
            n, steps = model.num_particles, sum(len(ch.grid) - 1 for ch in chunks)
            bake_particles(model, solver, chunks, times, settings)          # warm-up
            t_bake, _ = best(lambda: bake_particles(model, solver, chunks, times, settings),
                             repeats=1 if big else 3, warmup=False)
            t_kernel, _ = best(kernel_pass(model, solver, chunks, dev), repeats=2 if big else 5, warmup=True)
            row = {"particles": n, "steps": steps, "frames": len(times) - 1, "chunk": CHUNK,
                   "bake_path_steps_per_s": n * steps / t_bake, "kernel_steps_per_s": n * steps / t_kernel}
            print(copies, dev, row, flush=True)
            res[f"{n}/{dev}"] = row
            keep(res)
            del model, solver
    return res


def section_batch(device: str, quick: bool, out_dir: Path) -> dict:
    if not (CESIUM.exists() and CLIP.exists()):
        return {"skipped": f"{CESIUM} or {CLIP} not found"}
    try:
        import distributed  # noqa: F401
    except ImportError as e:
        return {"skipped": f"Dask's distributed is not installed: {e}"}
    jobs = 4 if quick else 16
    res = {}
    with tempfile.TemporaryDirectory() as tmp:
        manifest = Path(tmp) / "library.toml"
        lines = []
        for j in range(jobs):       # the same clip at 16 strengths: 16 bakes of one rig (each worker fits it once)
            lines.append(f'[[job]]\nname = "j{j:02d}"\nclip = "{LONG_CLIP if LONG_CLIP.exists() else CLIP}"\nframes = 150\njiggle = {0.5 + 0.5 * j / jobs:.3f}\n')
        manifest.write_text("\n".join(lines))
        for dev, workers in ((device, jobs), (device, 1), ("cpu", jobs)):
            key = f"{dev}/{workers}_workers"
            if key in res:
                continue
            out = Path(tmp) / key.replace("/", "_")
            cmd = [sys.executable, "-m", "jiggle", "-q", "batch", str(manifest), "--out", str(out), "--workers",
                   str(workers), "--no-report", "--character", str(CESIUM), "--device", dev, "--formats", "npz", "--fps", "30"]
            t = time.perf_counter()
            r = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=280,
                               env={**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])})
            wall = time.perf_counter() - t
            index = out / "index.json"
            done = 0
            if index.exists():
                done = sum(1 for j in json.loads(index.read_text()).get("jobs", []) if j.get("status") == "ok")
            res[key] = {"exit": r.returncode, "jobs": jobs, "done": done, "wall_s": round(wall, 2),
                        "bakes_per_min": 60.0 * done / wall, "stderr_tail": r.stderr[-800:]}
            print(key, res[key], flush=True)
            keep(res)
    return res


def _graph_rows(arm, copies: int, seconds: float, device: str, repeats: int) -> dict:
    """The particle stage of a bake of `copies` swinging arms (benchmarks/bench_particles.py) with the chunk graph
    and with the plain launches, on one device: particle-steps/s of each, the largest difference (m), the graphs
    captured and replayed."""
    import numpy as np
    from bench_jiggle import copied_model, swinging_goals
    from bench_particles import FPS, SUBSTEPS, bake_chunks, bake_particles
    from timing import best

    from jiggle.sim.jiggle.graph import ChunkGraph
    from jiggle.sim.jiggle.params import JiggleSettings
    from jiggle.sim.jiggle.secondary import DEFAULT_GOAL_RATE, knot_times
    from jiggle.sim.jiggle.solver import ParticleSolver
    model, offsets = copied_model(arm, copies, device)
    settings = JiggleSettings(substeps=SUBSTEPS, device=device)
    times = np.arange(int(round(seconds * FPS)) + 1) / FPS
    knots = knot_times(times, settings.goal_rate or max(DEFAULT_GOAL_RATE, FPS))
    static = swinging_goals(arm, offsets, knots)
    row, out = {"particles": model.num_particles, "frames": len(times) - 1}, {}
    for mode in ("plain", "graph"):
        solver = ParticleSolver(model)
        solver.graph = ChunkGraph(solver) if mode == "graph" else None
        chunks = bake_chunks(times, knots, static, settings, solver)
        steps = sum(len(ch.grid) - 1 for ch in chunks)
        out[mode] = bake_particles(model, solver, chunks, times, settings)       # warm-up: compiles, captures
        launches = solver.launches
        t, _ = best(lambda: bake_particles(model, solver, chunks, times, settings), repeats=repeats, warmup=False)
        row[f"{mode}_steps_per_s"] = model.num_particles * steps / t
        row[f"{mode}_ms_per_chunk"] = 1e3 * t / len(chunks)
        row[f"{mode}_launches_per_chunk"] = launches / len(chunks)
        row["steps"], row["chunks"] = steps, len(chunks)
        if mode == "graph":
            g = solver.graph
            row.update({"graph_capture": g.capture, "graphs_captured": g.captures, "graph_replays": g.replays})
    row["graph_over_plain"] = row["graph_steps_per_s"] / row["plain_steps_per_s"]
    row["max_diff_m"] = float(np.abs(out["graph"] - out["plain"]).max())
    return row


def _packed_rows(device: str, quick: bool, jobs: int) -> dict:
    """`jobs` bakes of CesiumMan (the demo body without the assets) at jiggle strengths 0.5..1 packed into one
    particle array (sim/jiggle/packed.py), chunk after chunk, against one bake alone: seconds of the particle stage
    and bakes per second, and bake 0's largest difference from its run alone."""
    from dataclasses import replace as dc_replace

    import numpy as np
    from timing import best

    from jiggle.sim.bake.baker import MARGIN, chunk_frames, num_chunks
    from jiggle.sim.bake.setup import prepare
    from jiggle.sim.jiggle.packed import PackedBakes
    from jiggle.sim.jiggle.particles import muscle_model
    from jiggle.sim.jiggle.simulate import TIME_EPS, goals, run
    from jiggle.sim.jiggle.solver import ParticleSolver
    kw = cases(True, long=str(DEFAULT)).get("cesium") or {"scene": str(DEFAULT), "fps": 30,
                                                           "body": MappingProxyType({"resolution": 3000})}
    s = prepare(request({**kw, "frames": 61 if quick else 121, "chunk": 30, "collisions": False, "preroll": 0.0,
                         "loop": "off"},
                        device, formats=("npz",)))
    strengths = np.linspace(0.5, 1.0, jobs)
    models = [muscle_model(s.rig, [dc_replace(j, strength=float(a)) for j in s.jiggles], device,
                           gravity=s.settings.gravity) for a in strengths]
    chunks = []
    for c in range(num_chunks(s)):
        f0, f1 = chunk_frames(s, c)
        a = max(f0 - 1, 0)
        ka = max(0, int(np.searchsorted(s.knots, s.times[a] - TIME_EPS)) - MARGIN)
        kb = min(len(s.knots), int(np.searchsorted(s.knots, s.times[f1 - 1] + TIME_EPS, side="right")) + MARGIN)
        kt = s.knots[ka:kb]
        static = s.rig.static(np.asarray(s.world_at(kt), dtype=np.float64), device=device)
        chunks.append((goals(s.rig, kt, static.cvs, s.settings), s.times[a:f1]))
    sub = s.settings.substeps
    packed = PackedBakes(models, device=device)
    alone = ParticleSolver(models[0])

    def one():
        state, out = None, []
        for track, t in chunks:
            x, state = run(models[0], track, t, sub, 0.0, alone, start=state, return_state=True)
            out.append(x)
        return out

    def many():
        states, out = [None] * jobs, []
        for track, t in chunks:
            got = packed.simulate([track] * jobs, [t] * jobs, sub, states)
            states = [g[1] for g in got]
            out.append(got[0][0])
        return out
    x1, xs = one(), many()                                              # warm-up (compiles, captures)
    t1, _ = best(one, 2 if quick else 3)
    tn, _ = best(many, 2 if quick else 3)
    return {"bakes": jobs, "frames": len(s.times), "particles_per_bake": models[0].num_particles,
            "chunks": len(chunks), "one_bake_s": t1, "packed_s": tn, "one_bakes_per_s": 1.0 / t1,
            "packed_bakes_per_s": jobs / tn, "packed_over_one": jobs * t1 / tn,
            "packed_runs": packed.packed_runs, "alone_runs": packed.alone_runs,
            "bake0_max_diff_m": float(max(np.abs(a - b).max() for a, b in zip(x1, xs)))}


def section_graph(device: str, quick: bool, out_dir: Path) -> dict:
    import warp as wp

    from jiggle.rig.muscle.simple_arm import simple_arm
    wp.init()
    arm = simple_arm()
    res = {}
    # 1,600 particles over 2 s (1 s quick); 1,000,000 particles over 0.2 s (6 frames; 100,000 particles on a CPU)
    for name, copies, seconds, repeats in (("1600", 40, 1.0 if quick else 2.0, 2 if quick else 3),
                                           ("1M", 25_000 if device != "cpu" else 2_500, 0.1 if quick else 0.2, 1)):
        row = _graph_rows(arm, copies, seconds, device, repeats)
        print("graph", name, json.dumps(row, default=float), flush=True)
        res[f"graph/{name}"] = row
        keep(res)
    row = _packed_rows(device, quick, 4 if quick else 16)
    print("packed", json.dumps(row, default=float), flush=True)
    res["packed"] = row
    keep(res)
    return res


# ---------------------------------------------------------------------------------------- precompile
def precompile(arch: int, out_dir: Path) -> None:
    """Load every Warp module the check uses with tiny CPU bakes, then compile each for sm_`arch` ahead of time."""
    import warp as wp

    from jiggle.sim.bake.baker import bake
    from jiggle.sim.bake.setup import prepare
    wp.init()
    with tempfile.TemporaryDirectory() as tmp:
        for name, kw in cases(quick=True).items():
            kw = {**kw, "frames": 8}
            if "body" in kw:
                kw["body"] = MappingProxyType({"resolution": 3000})
            bake(prepare(request(kw, "cpu")), os.path.join(tmp, name))
        bake(prepare(request({"scene": str(ROOT / "scenes" / "simple_arm.toml"), "fps": 60, "chunk": 16},
                             "cpu")), os.path.join(tmp, "arm"))
    import bench_jiggle  # noqa: F401  (their modules, for the particle section)
    from jiggle.rig.skin import smoothing_kernels  # noqa: F401  (a GPU's spread and steps: not loaded on the CPU)
    from jiggle.sim.jiggle import graph_kernels, particle_kernels, step_kernels  # noqa: F401  (graphs: CUDA only)
    from warp._src.context import user_modules
    done = []
    for name, module in list(user_modules.items()):
        try:
            wp.compile_aot_module(module, arch=arch, use_ptx=False)
            done.append(name)
        except Exception as e:  # noqa: BLE001 - a module Warp cannot compile here compiles on the device
            print(f"precompile: {name} not compiled ahead of time: {e}")
    print(f"precompile: {len(done)} modules for sm_{arch} in {wp.config.kernel_cache_dir}")


# ---------------------------------------------------------------------------------------- table
def fmt(v, spec=".0f") -> str:
    return "-" if v is None else format(v, spec)


def table(r: dict, device: str) -> str:
    env = r.get("env", {})
    L = [f"# jiggle on {env.get('gpu', device)} against the CPU of the same machine",
         "",
         f"Machine: {env.get('gpu', device)} ({env.get('gpu_memory_gb', '-')} GB, {env.get('nvidia_smi', '')}), "
         f"{env.get('cpu_cores')} CPU cores; Python {env.get('python')}, Warp {env.get('warp')}, NumPy {env.get('numpy')}. "
         f"Check run in {r.get('total_s', 0):.0f} s.", ""]
    t = r.get("tests", {})
    if t.get("tests"):
        L += ["## Tests (tests/bake/test_device.py)", "", "| test | result | s |", "| --- | --- | --- |"]
        L += [f"| {c['test']} | {c['status']} | {c['s']} |" for c in t["tests"]]
        L.append("")
    a = r.get("agree", {})
    if isinstance(a, dict) and a and "error" not in a:
        L += [f"## {device} bake against the CPU bake, largest difference (target < {AGREE_MM} mm)", "",
              f"| case | frames | vertices | npz mm | usdc mm | pc2 mm | | cpu bake s | {device} bake s |", "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
        for name, c in a.items():
            if not isinstance(c, dict):
                continue
            L.append(f"| {name} | {c['frames']} | {c['vertices']} | {c['npz_mm']:.2g} ({c['npz_worst_key']}) | "
                     f"{c['usdc_mm']:.2g} | {c['pc2_mm']:.2g} | {'ok' if c['ok'] else 'NOT ok'} | {c.get('a_s')} | "
                     f"{c.get('b_s')} |")
        L.append("")
    s = r.get("speed", {})
    if isinstance(s, dict) and s and "error" not in s:
        L += ["## Speed: frames/s (loop: every stage, no files; caches: the whole bake writing npz + usdc + pc2)", ""]
        if r.get("speed_cpu_from"):
            e = r["speed_cpu_from"]
            L += [f"The CPU rows are from the check of {e['date']} ({e['file']}; {e['machine']}): the CPU's code did not "
                  "change between the two runs.", ""]
        L += [
              "| mesh | device | vertices | frames | loop fps | LBS-only loop fps | loop / LBS | caches fps | "
              "LBS-only + caches fps | caches / LBS | per frame ms: drive, static, simulate, skin |",
              "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
        for key, c in s.items():
            if not isinstance(c, dict):
                continue
            name, dev = key.split("/")
            st = c["stage_ms_per_frame"]
            L.append(f"| {name} | {dev} | {c['vertices']} | {c['frames']} | {c['loop_fps']:.0f} | {c['lbs_loop_fps']:.0f} | "
                     f"{c['loop_ratio']:.2f}x | {c['caches_fps']:.0f} | {c['lbs_caches_fps']:.0f} | {c['caches_ratio']:.2f}x | "
                     f"{st['drive']:.3f}, {st['static']:.3f}, {st['simulate']:.3f}, {st['skin']:.3f} |")
        for name in ("cesium", "body30k", "body100k"):
            c, g = s.get(f"{name}/cpu"), s.get(f"{name}/{device}")
            if c and g and device != "cpu":
                L.append(f"\n{name}: {device} / cpu {g['loop_fps'] / c['loop_fps']:.1f}x in the loop, "
                         f"{g['caches_fps'] / c['caches_fps']:.1f}x with caches.")
        g = s.get(f"body30k/{device}")
        if g:
            L += ["", f"Targets (30k body on {device}): loop {g['loop_fps']:.0f} frames/s (>= {TARGETS['loop_fps_30k']:.0f}: "
                  f"{'met' if g['loop_fps'] >= TARGETS['loop_fps_30k'] else 'NOT met'}); caches {g['caches_fps']:.0f} frames/s "
                  f"(>= {TARGETS['caches_fps_30k']:.0f}: {'met' if g['caches_fps'] >= TARGETS['caches_fps_30k'] else 'NOT met'}); "
                  f"loop / LBS-only {g['loop_ratio']:.2f}x (<= {TARGETS['lbs_ratio']:g}x: "
                  f"{'met' if g['loop_ratio'] <= TARGETS['lbs_ratio'] else 'NOT met'})"]
        L.append("")
    p = r.get("particles", {})
    if isinstance(p, dict) and p and "error" not in p:
        L += ["## Particles: M particle-steps/s", "", "| particles | device | steps | bake path | kernel alone |",
              "| --- | --- | --- | --- | --- |"]
        for key, c in p.items():
            if not isinstance(c, dict):
                continue
            n, dev = key.split("/")
            L.append(f"| {int(n):,} | {dev} | {c['steps']} | {c['bake_path_steps_per_s'] / 1e6:,.1f} | "
                     f"{c['kernel_steps_per_s'] / 1e6:,.1f} |")
        L.append("")
    b = r.get("batch", {})
    if isinstance(b, dict) and b:
        L += ["## Batch: 16 bakes of CesiumMan (150 frames, npz) with `jiggle batch --no-report`", ""]
        if "skipped" in b:
            L.append(f"skipped: {b['skipped']}")
        else:
            L += ["| device / workers | done | wall s | bakes per minute |", "| --- | --- | --- | --- |"]
            L += [f"| {k} | {c['done']}/{c['jobs']} | {c['wall_s']} | {c['bakes_per_min']:.1f} |" for k, c in b.items()
                  if isinstance(c, dict)]
        L.append("")
    gr = r.get("graph", {})
    if isinstance(gr, dict) and gr and "error" not in gr:
        L += [f"## Chunk graphs and packed bakes on {device} (issue 45)", "",
              "| particles | frames | steps | plain M steps/s | graph M steps/s | graph / plain | launches per chunk "
              "(plain) | ms per chunk plain, graph | graphs captured, replays | largest difference m |",
              "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
        for key, c in gr.items():
            if not key.startswith("graph/") or not isinstance(c, dict):
                continue
            L.append(f"| {c['particles']:,} | {c['frames']} | {c['steps']} | {c['plain_steps_per_s'] / 1e6:,.1f} | "
                     f"{c['graph_steps_per_s'] / 1e6:,.1f} | {c['graph_over_plain']:.2f}x | "
                     f"{c['plain_launches_per_chunk']:.0f} | {c['plain_ms_per_chunk']:.2f}, {c['graph_ms_per_chunk']:.2f} | "
                     f"{c['graphs_captured']}, {c['graph_replays']}{'' if c['graph_capture'] else ' (no capture)'} | "
                     f"{c['max_diff_m']:.2g} |")
        pk = gr.get("packed")
        if isinstance(pk, dict):
            L += ["", f"Packed: {pk['bakes']} bakes ({pk['particles_per_bake']:,} particles each, {pk['frames']} frames, "
                  f"{pk['chunks']} chunks) in one process: {pk['packed_bakes_per_s']:.2f} bakes/s of the particle stage "
                  f"against {pk['one_bakes_per_s']:.2f} for one bake alone ({pk['packed_over_one']:.2f}x); "
                  f"{pk['packed_runs']} packed runs, {pk['alone_runs']} alone (warm-up and repeats); bake 0 differs from its run alone by "
                  f"{pk['bake0_max_diff_m']:.2g} m."]
        L.append("")
    for name in SECTIONS:
        e = r.get(name, {})
        if isinstance(e, dict) and ("error" in e or "cut" in e):
            L += [f"**{name}: {e.get('error') or e['cut']}**", ""]
    return "\n".join(L)


# ---------------------------------------------------------------------------------------- main
def run_section(name: str, device: str, quick: bool, out_dir: Path, log) -> dict:
    part = out_dir / f"_{name}.json"
    cmd = [sys.executable, __file__, str(out_dir), "--section", name, "--device", device] + (["--quick"] if quick else [])
    t = time.perf_counter()
    try:
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=SECTIONS[name],
                           env={**os.environ, "PYTHONUNBUFFERED": "1"})
        out, err, code = r.stdout, r.stderr, r.returncode
    except subprocess.TimeoutExpired as e:
        out, err, code = (e.stdout or b"").decode(errors="replace") if isinstance(e.stdout, bytes) else (e.stdout or ""), \
            (e.stderr or b"").decode(errors="replace") if isinstance(e.stderr, bytes) else (e.stderr or ""), "timeout"
    dt = time.perf_counter() - t
    log.write(f"\n===== {name} ({dt:.1f} s, exit {code})\n{out}\n{err}\n")
    log.flush()
    print(f"gpu_check: {name} {dt:.1f} s, exit {code}", flush=True)
    if part.exists():
        data = json.loads(part.read_text())
        part.unlink()
        if code != 0 and isinstance(data, dict) and "error" not in data:
            data["cut"] = f"exit {code} after {dt:.0f} s: the rows finished before it"
        return data
    return {"error": f"exit {code} after {dt:.0f} s: " + (err.strip().splitlines() or ["(no output)"])[-1][:300]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", help="folder for gpu_check.md, gpu_check.json, gpu_check.log")
    ap.add_argument("--device", default="cuda", help="the device to check against the CPU (default cuda)")
    ap.add_argument("--quick", action="store_true", help="fewer frames and repeats, no 100k body, 4 batch jobs")
    ap.add_argument("--only", help="comma-separated sections (default: all): " + ", ".join(SECTIONS))
    ap.add_argument("--speed-cpu-from", metavar="JSON", help="take the speed section's CPU rows from an earlier "
                    "check's gpu_check.json (same kind of machine) instead of measuring them again")
    ap.add_argument("--limits", metavar="NAME=S,...", help="other time limits of sections, seconds (e.g. "
                    "speed=120,batch=60), to fit a check into what is left of a lease")
    ap.add_argument("--section", help=argparse.SUPPRESS)
    ap.add_argument("--precompile", type=int, metavar="ARCH", help="fill the kernel cache (gpu_pack.sh), no check")
    args = ap.parse_args()
    out_dir = Path(args.out).resolve()
    out_dir.mkdir(parents=True, exist_ok=True)
    if args.precompile:
        precompile(args.precompile, out_dir)
        return
    if args.section:
        global PART
        PART = out_dir / f"_{args.section}.json"
        fn = globals()[f"section_{args.section}"]
        try:
            data = fn(args.device, args.quick) if args.section == "env" else fn(args.device, args.quick, out_dir)
        except Exception as e:  # noqa: BLE001 - the table says which section failed and how
            traceback.print_exc()
            data = {"error": f"{type(e).__name__}: {e}"[:500]}
        (out_dir / f"_{args.section}.json").write_text(json.dumps(data, indent=1, default=float))
        return
    for item in (args.limits.split(",") if args.limits else []):
        name, _, secs = item.partition("=")
        if name not in SECTIONS or not secs.replace(".", "", 1).isdigit():
            ap.error(f"--limits: expected NAME=SECONDS with NAME one of {', '.join(SECTIONS)}, got {item!r}")
        SECTIONS[name] = float(secs)
    names = args.only.split(",") if args.only else list(SECTIONS)
    unknown = [n for n in names if n not in SECTIONS]
    if unknown:
        ap.error(f"--only: unknown section {unknown[0]!r}; expected some of {', '.join(SECTIONS)}")
    t0 = time.perf_counter()
    results = {"device": args.device, "quick": args.quick, "date": time.strftime("%Y-%m-%d %H:%M:%S")}
    earlier = None
    if args.speed_cpu_from:
        earlier = json.loads(Path(args.speed_cpu_from).read_text())
        os.environ["JIGGLE_CHECK_SPEED_CPU"] = "0"
        results["speed_cpu_from"] = {"file": args.speed_cpu_from, "date": earlier.get("date"),
                                     "machine": earlier.get("env", {}).get("nvidia_smi")}
    with open(out_dir / "gpu_check.log", "w") as log:
        for name in names:
            results[name] = run_section(name, args.device, args.quick, out_dir, log)
            if name == "speed" and earlier and isinstance(results[name], dict) and "error" not in results[name]:
                results[name].update({k: v for k, v in earlier.get("speed", {}).items() if k.endswith("/cpu")})
            results["total_s"] = time.perf_counter() - t0
            # after every section: a check stopped at its time limit still leaves the sections it finished
            (out_dir / "gpu_check.json").write_text(json.dumps(results, indent=1, default=float))
            md = table(results, args.device)
            (out_dir / "gpu_check.md").write_text(md + "\n")
    print(md)


if __name__ == "__main__":
    main()
