"""Static update of 28 thesis muscles (rig.muscle.model.MuscleRig.static): all CVs of one frame,
vectorised over muscles, against the tests' per-muscle, per-frame Python reference
(tests/muscle/test_muscle_model.py: reference_static, scipy splines and the loft mesh built point by point),
and the Warp kernel path (rig/muscle/static_kernels.py, device "cpu", the default) against the NumPy
path (device=None) on chunks of 256 frames, as the bake calls it; all measured in this one run.

    .venv/bin/python benchmarks/bench_muscle_update.py

The skeleton is 14 two-bone arms (42 joints) placed and turned at random; each arm carries a
biceps-like muscle (belly on the upper arm, insertion on the forearm) and one spanning the elbow
(its action curve bends), so half the muscles exercise the measured-volume correction off the
straight case; 28 muscles, as the human template. Poses: random elbow flexion 0..140 deg and random
arm orientations per frame. Times are the best of several calls after a warm-up (the kernel's
compilation stays out of the figures).

NumPy's temporaries here are a few hundred kB; whether glibc hands them back to the system after
each call (and page-faults them in again on the next) depends on what the process freed before.
The figures are taken after building the rig, as in a real session.
"""
from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT / "tests" / "muscle"))

import test_muscle_model as ref  # noqa: E402  the tests' arm, muscles and per-muscle reference
from timing import best  # noqa: E402  (benchmarks/timing.py)

from jiggle.rig.muscle.model import VOLUME_RULES, build_muscle_rig  # noqa: E402

ARMS, FRAMES, CHUNK = 14, 100, 256


def placed(spec, g: np.ndarray, first_joint: int):
    """`spec` built on the tests' arm (joints 0..2) moved by the rigid transform g (4, 4) onto the
    arm whose joints start at `first_joint`."""
    move = lambda p: np.asarray(p) @ g[:3, :3].T + g[:3, 3]  # noqa: E731
    return dataclasses.replace(spec, bone=spec.bone + first_joint, bones=np.asarray(spec.bones) + first_joint,
                               points=move(spec.points), ends=move(spec.ends), up=spec.up @ g[:3, :3].T,
                               surface=move(spec.surface))


def world(roots: np.ndarray, elbows: np.ndarray) -> np.ndarray:
    """(3 ARMS, 4, 4) joint transforms of all arms: arm i is the tests' arm at elbow angle elbows[i]
    moved by roots[i] (4, 4)."""
    return np.concatenate([ref.arm_world(a, root=g) for g, a in zip(roots, elbows)])


def random_roots(rng) -> np.ndarray:
    g = np.tile(np.eye(4), (ARMS, 1, 1))
    g[:, :3, :3] = Rotation.random(ARMS, random_state=rng.integers(1 << 31)).as_matrix()
    g[:, :3, 3] = rng.uniform(-1.0, 1.0, size=(ARMS, 3))
    return g


def main() -> None:
    rng = np.random.default_rng(0)
    bind_roots = random_roots(rng)
    bind = world(bind_roots, np.zeros(ARMS))
    specs = [placed(make(), g, 3 * i) for i, g in enumerate(bind_roots) for make in (ref.biceps, ref.brachio)]
    t_build, rig = best(lambda: build_muscle_rig(specs, bind), repeats=1)

    poses = np.stack([world(random_roots(rng), rng.uniform(0.0, 140.0, ARMS)) for _ in range(FRAMES)])
    one = poses[0]
    t_rule = {rule: best(lambda: rig.static(one, volume=rule, device=None), repeats=300, warmup=True)[0]
              for rule in VOLUME_RULES}
    t_ref, (ref_cvs, _) = best(lambda: ref.reference_static(specs, bind, rig.sections, one), repeats=3)
    cvs, _ = rig.static(one, device=None)
    t_batch, batch = best(lambda: rig.static(poses, device=None), repeats=5, warmup=True)
    drift = np.abs(rig.volumes(batch.cvs) / rig.rest_volume - 1.0)
    thesis = np.abs(rig.volumes(rig.static(poses, volume="thesis").cvs) / rig.rest_volume - 1.0)
    # a bake chunk: CHUNK frames per call, NumPy path against the kernel (one launch per call)
    chunk = poses[rng.integers(0, FRAMES, CHUNK)]
    t_chunk, diff = {}, {}
    for rule in VOLUME_RULES:
        t_np, a = best(lambda: rig.static(chunk, volume=rule, device=None), repeats=5, warmup=True)
        t_wp, b = best(lambda: rig.static(chunk, volume=rule, device="cpu"), repeats=10, warmup=True)
        t_chunk[rule] = (t_np / CHUNK, t_wp / CHUNK)
        diff[rule] = max(np.abs(a.cvs - b.cvs).max(), np.abs(a.curve - b.curve).max())
    t_one_wp = best(lambda: rig.static(one, device="cpu"), repeats=300, warmup=True)[0]

    print(f"{rig.M} muscles ({rig.M * rig.CVS_PER_MUSCLE} section CVs), {rig.num_joints} joints")
    print(f"build (fit of {rig.M} lofts): {t_build:.2f} s; fit rms {rig.fit_rms.mean() * 1e3:.3f} mm mean, "
          f"max {rig.fit_max.max() * 1e3:.3f} mm")
    print(f"{'stage':52s} {'ms':>8s}")
    for rule, t in t_rule.items():
        print(f"{f'static numpy, one frame, volume={rule!r}':52s} {t * 1e3:8.3f}")
    print(f"{'static warp cpu, one frame (exact)':52s} {t_one_wp * 1e3:8.3f}")
    print(f"{f'static numpy, {FRAMES}-frame batch, per frame (exact)':52s} {t_batch / FRAMES * 1e3:8.3f}")
    print(f"{'per-muscle Python reference, one frame (exact)':52s} {t_ref * 1e3:8.3f}")
    print(f"ratio reference / static numpy (exact, one frame): {t_ref / t_rule['exact']:7.1f}x")
    print(f"max |static - reference| {np.abs(cvs - ref_cvs).max():.1e} m; over {FRAMES} random frames "
          f"max |V / V_rest - 1|: exact {drift.max():.1e}, thesis {thesis.max():.3f}")
    print(f"\nchunks of {CHUNK} frames, ms per frame        numpy     warp   numpy/warp   max |warp - numpy| m")
    for rule, (t_np, t_wp) in t_chunk.items():
        print(f"  volume={rule!r:10s}                    {t_np * 1e3:8.4f} {t_wp * 1e3:8.4f} {t_np / t_wp:9.1f}x"
              f"   {diff[rule]:.1e}")

if __name__ == "__main__":
    main()
