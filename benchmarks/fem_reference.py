"""The volumetric reference of the tissue (sim/fem) against the particles (sim/jiggle), both driven by the same goal
shape: the static CVs of every knot (rig.static(world).cvs), the FEM's vertices through their loft coordinates.

    .venv/bin/python benchmarks/fem_reference.py [--case belly|thighs|cat|all|none] [--no-calibration]
        [--no-damping] [--no-particle-damping] [--quick]

1. Damping (--damping, default on): an ellipsoid part of muscle, rung down undamped at several steps and VBD
   iteration counts (VBD's numerical damping), then at requested damping ratios 0.1 and 0.3 (k_damp from
   sim.fem.solve.damping_coefficient, with and without the numerical part taken off).
2. Calibration (--calibration, default on): ring-downs (accelerate, hold, stop, hold: sim.fem.experiments.step_drive,
   the goal carried rigidly) of ellipsoids of several radii and lengths and of CesiumMan's largest fitted parts, for
   FAT and MUSCLE, undamped: f_fem, C = f_fem r / shear_speed (r = MuscleRig.mean_radii) and the other size
   measures (V^(1/3), L/2, thickness V/A) with their spread, and a two-parameter fit C(r, L) = C0 (r/L)^a; and the
   particles' ring-down frequency of the same parts and drive at frequency_hz = 1 (default goal weights):
   F_p = f_particles / frequency_hz, so frequency_hz = f_fem / F_p makes the particles ring as the FEM.
3. Cases (--case): CesiumMan's belly fat on CMU 09_11 (its first ~3 s: the clip is 1.4 s), the generated body's
   right quadriceps on CMU 02_04 (the jump and landing, 4 s), the shared Cat's fat on its Walk (2 s of the cycle).
   Every case holds the last pose 1.5 s at the end, so both solvers ring down; both at the character's real size.
   The FEM (the part's material, Rayleigh-damped across its mesh's low modes: sim.fem.modes), the particles as a
   bake with the defaults sets them (prepare's jiggles), and the
   particles set from the material (sim.jiggle.materials.particle_params_from when present, else frequency_hz = C_p shear_speed / r with
   C_p = C / F_p from the calibration, damping = the material's ratio). Per solver: peak CV offset from the goal
   (mm), dominant frequency of the detrended offset during the motion, ring-down frequency and log decrement in
   the hold (from successive extrema, measure.decrement); a PNG per case (offset magnitude over time); whether the
   particles' peak, frequency and decrement are within the issue's 25% / 15% / 30% of the FEM's.
4. Particle damping (--no-particle-damping to skip): the particles' ring-downs of the calibration parts against
   their linearized sway mode's damping ratio: sim.jiggle.materials.MODAL_GAIN.

Writes benchmarks/results/fem_reference.md and .json (sections run are replaced, others kept) and
benchmarks/results/fem_reference_<case>.png.
"""
from __future__ import annotations

import argparse
import json
import math
import time
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np

from jiggle.rig.muscle import loft
from jiggle.rig.muscle.material import FAT, MUSCLE, Material, material_for
from jiggle.sim.fem import measure
from jiggle.sim.fem.experiments import ellipsoid_rig, ringdown_run, step_drive
from jiggle.sim.fem.solve import DT, ITERATIONS, NUMERICAL_DAMPING, damping_coefficient, simulate_part
from jiggle.sim.fem.tet_mesh import part_mesh

ROOT = Path(__file__).resolve().parents[1]
ASSETS = ROOT.parent / "shared" / "assets"
CESIUM = ASSETS / "characters" / "CesiumMan.glb"
OUT = ROOT / "benchmarks" / "results"
SHAPES = [(0.15, (0.02, 0.02)), (0.20, (0.03, 0.025)), (0.30, (0.03, 0.03)), (0.30, (0.05, 0.04)),
          (0.40, (0.04, 0.04))]
"""(length, (radius up, radius side)) metres of the ellipsoid parts."""
CESIUM_PARTS = ("belly_fat", "left_hamstrings", "right_triceps", "right_love_handle")
HOLD = 1.5
"""seconds the last pose is held at the end of a case (the ring-down)."""
RATE = 120.0
"""Hz of the hold's knots (the goal stands still on them)."""
FPS = 200.0
"""Hz of the measured frames."""
GUESS_C = 0.15
"""C of the first guess of a part's frequency: the ring-down is fitted over 3 periods of it (a fundamental fitted
over the whole hold is outweighed by slower, weaker modes ringing on after it: ellipsoid_15x2 muscle read 9.7 Hz,
below its fat's 10.8 Hz, without the window)."""
DEFAULT_C = 0.15
"""C = f r / shear_speed when no calibration has been run (the previous table's geometric mean)."""


def quiet():
    warnings.simplefilter("ignore")


# ------------------------------------------------------------------------------------------------ particles
def particle_cvs(rig, jiggles, knots, static, times):
    """Dynamic CVs (T, N, 3) of every part of rig with `jiggles` for static CVs (K, N, 3) at knots (K,), sampled at
    times (T,): the project's solver, no colliders, no gravity, starting settled on the goal (preroll 0)."""
    from jiggle.sim.jiggle.keyed_solver import make_solver
    from jiggle.sim.jiggle.params import JiggleSettings
    from jiggle.sim.jiggle.particles import muscle_model
    from jiggle.sim.jiggle.simulate import goals, simulate
    settings = JiggleSettings()
    track = goals(rig, knots, static, settings, cuts=np.zeros(len(knots) - 1, bool))
    model = muscle_model(rig, jiggles)
    dyn, _ = simulate(model, track, times, settings, solver=make_solver(model, jiggles), preroll=0.0)
    return dyn


def particle_rule(material: Material, rig, m: int, jiggle, C_p: float, scale: float = 1.0):
    """The MuscleJiggle of part m of rig made of `material`, from `jiggle` (its default), and how it was set: the
    rule of sim/jiggle/materials.py when present (with_material(jiggle, material, r), or particle_params_from(material,
    rig, m) -> (frequency_hz, damping_ratio)), else frequency_hz = C_p shear_speed / r and the material's ratio."""
    r = float(rig.mean_radii(rig.rest_cvs)[m]) * scale          # real metres
    try:
        from jiggle.sim.jiggle import materials
    except ImportError:
        materials = None
    if materials is not None and hasattr(materials, "shape_constant"):
        L = float(rig.rest_length[m]) * scale
        return (materials.with_material(jiggle, material, r, L, rig.rest_cvs[rig.cv_offsets[m]:rig.cv_offsets[m + 1]]),
                f"sim.jiggle.materials.with_material (r, L: C {materials.shape_constant(r, L):.4f})")
    if materials is not None and hasattr(materials, "with_material"):
        fc = getattr(materials, "FEM_C", float("nan"))
        return materials.with_material(jiggle, material, r), f"sim.jiggle.materials.with_material (FEM_C {fc:g})"
    if materials is not None and hasattr(materials, "particle_params_from"):
        f, z = materials.particle_params_from(material, rig, m)
        return replace(jiggle, frequency_hz=float(f), damping_ratio=float(z)), "sim.jiggle.materials.particle_params_from"
    return (replace(jiggle, frequency_hz=C_p * material.shear_speed / r, damping_ratio=material.damping_ratio),
            f"C_p shear_speed / r, C_p = {C_p:.4f}")


# ------------------------------------------------------------------------------------------------ sizes
def sizes(rig, m: int) -> dict:
    """Size measures of part m (metres): r, V^(1/3), L/2, thickness V/A (A: its loft mesh's area)."""
    cvs = rig.rest_cvs[rig.cv_offsets[m]:rig.cv_offsets[m + 1]]
    pts = loft.points(cvs.reshape(1, 5, 8, 3))[0]
    f = pts[loft.FACES]
    area = 0.5 * np.linalg.norm(np.cross(f[:, 1] - f[:, 0], f[:, 2] - f[:, 0]), axis=1).sum()
    V = float(rig.volumes(rig.rest_cvs)[m])
    return {"r": float(rig.mean_radii(rig.rest_cvs)[m]), "V^(1/3)": V ** (1 / 3), "L/2": float(0.5 * rig.rest_length[m]),
            "V/A": V / area, "L": float(rig.rest_length[m])}


def across(cvs: np.ndarray) -> np.ndarray:
    """A unit direction across a part of CVs (40, 3): perpendicular to its axis, as near world Z as it can be."""
    c = cvs.reshape(5, 8, 3).mean(axis=1)
    a = c[-1] - c[0]
    a /= np.linalg.norm(a)
    d = np.array([0.0, 0.0, 1.0]) - a[2] * a
    if np.linalg.norm(d) < 0.3:
        d = np.array([1.0, 0.0, 0.0]) - a[0] * a
    return d / np.linalg.norm(d)


# ------------------------------------------------------------------------------------------------ 1. damping
def damping(log, quick: bool) -> dict:
    """Ring-downs of one ellipsoid (muscle; fat at the end) measured at 1 kHz over 2.5 periods of its fundamental."""
    rig = ellipsoid_rig(0.2, (0.03, 0.025))
    mesh = part_mesh(rig.rest_cvs)
    rows = []

    def ring(mat, k, dt=DT, it=ITERATIONS, f=None):
        window = None if f is None else 2.5 / f
        run, rd = ringdown_run(mesh, mat, duration=0.3 if mat is not FAT and mat.name != "fat" else 0.5, fps=1000.0,
                               k_damp=k, dt=dt, iterations=it, window=window)
        return run, rd

    _, rd = ring(MUSCLE, 0.0)
    f0 = rd.frequency_hz
    settings = [(1e-3, 10), (5e-4, 10), (1e-3, 20), (1e-3, 5), (2e-3, 20)] if not quick else [(1e-3, 10), (5e-4, 10)]
    for dt, it in settings:
        run, rd = ring(MUSCLE, 0.0, dt, it, f0)
        rows.append({"material": "muscle", "dt": dt, "iterations": it, "requested": 0.0, "k_damp": 0.0,
                     "f_hz": rd.frequency_hz, "zeta": rd.damping_ratio, "ms_per_step": run.ms_per_step})
        log(f"  dt {dt * 1e3:.1f} ms, {it:2d} iterations, undamped: f {rd.frequency_hz:6.2f} Hz, zeta "
            f"{rd.damping_ratio:.3f}  ({run.ms_per_step:.1f} ms/step)")
    z_num = rows[0]["zeta"]
    cases = [(MUSCLE, 0.1), (MUSCLE, 0.3), (MUSCLE, 0.5), (FAT, 0.3)]
    f_fat = None
    for base, z in cases[:2] if quick else cases:
        mat = replace(base, damping_ratio=z)
        if base is FAT and f_fat is None:
            f_fat = ring(FAT, 0.0)[1].frequency_hz
        f = f0 if base is MUSCLE else f_fat
        for net in (False, True):
            k = damping_coefficient(mat, f, DT if net else None)
            run, rd = ring(mat, k, f=f)
            rows.append({"material": base.name, "dt": DT, "iterations": ITERATIONS, "requested": z, "net": net,
                         "k_damp": k, "f_hz": rd.frequency_hz, "zeta": rd.damping_ratio, "ms_per_step": run.ms_per_step})
            log(f"  {base.name} requested zeta {z:.2f}{' (numerical taken off)' if net else ''}: k_damp {k:.2f} Pa s -> "
                f"f {rd.frequency_hz:6.2f} Hz, zeta {rd.damping_ratio:.3f}")
    return {"part": rig.names[0], "f0_hz": f0, "zeta_numerical": z_num, "rows": rows}


# ------------------------------------------------------------------------------------------------ 2. calibration
def cesium_parts(log):
    from jiggle.rig.character.load import load_character
    from jiggle.rig.muscle.fit import fit_musculature
    if not CESIUM.exists():
        log(f"  (no {CESIUM}: its parts are skipped)")
        return []
    with warnings.catch_warnings():
        quiet()
        rig = fit_musculature(load_character(str(CESIUM)), "auto").rig
    return [(n, rig, rig.names.index(n)) for n in CESIUM_PARTS if n in rig.names]


def calibration_parts(log, quick: bool) -> list:
    """[(name, rig, muscle index)]: the lofted ellipsoids of SHAPES and CesiumMan's CESIUM_PARTS (fewer with quick)."""
    shapes = SHAPES[:2] if quick else SHAPES
    parts = [(rig.names[0], rig, 0) for rig in (ellipsoid_rig(L, r) for L, r in shapes)]
    return parts + cesium_parts(log)[:1 if quick else None]


def step_goals(rig, direction, duration: float, ramp: float = 0.05, hold: float = 0.1, fps: float = FPS):
    """(knots (K,), static CVs (K, rig CVs, 3), times (T,) at fps, t_stop): the whole rig's rest CVs carried by
    step_drive(direction, ramp, hold), then held `duration` seconds."""
    knots, carry, t_stop = step_drive(direction=tuple(direction), ramp=ramp, hold=hold)
    static = rig.rest_cvs[None] + carry[:, None, :3, 3]
    knots = np.append(knots, knots[-1] + np.arange(1, int(duration * RATE) + 2) / RATE)
    static = np.concatenate([static, np.repeat(static[-1:], len(knots) - len(static), axis=0)])
    return knots, static, np.arange(0.0, t_stop + duration + 1e-9, 1.0 / fps), t_stop


def particle_ringdown(rig, m, jiggles, direction, duration: float, frequency_hz: float) -> measure.Ringdown:
    """The particles of part m (frequency_hz, damping 0, no reach, the rest of jiggles[m] kept) under step_drive(direction) of
    the whole rig's rest CVs, rung down for `duration` seconds."""
    knots, static, times, t_stop = step_goals(rig, direction, duration)
    jig = list(jiggles)
    # no reach: the tissue law stiffens the goal spring beyond half the reach, and a 1 Hz part on this drive swings
    # past it (it then rang at ~5 Hz whatever its frequency): F_p is the linear spring's
    jig[m] = replace(jig[m], frequency_hz=frequency_hz, damping_ratio=0.0, max_offset=math.inf)
    dyn = particle_cvs(rig, jig, knots, static, times)
    from jiggle.sim.fem.solve import GoalCurve
    goal = np.stack([GoalCurve(knots, static)(t)[0] for t in times])
    sl = slice(rig.cv_offsets[m], rig.cv_offsets[m + 1])
    return measure.ringdown(measure.principal_signal(dyn[:, sl] - goal[:, sl]), times, t_stop)


def calibration(log, quick: bool) -> dict:
    from jiggle.sim.jiggle.materials import default_jiggles
    parts = calibration_parts(log, quick)
    rows = []
    for name, rig, m in parts:
        s = sizes(rig, m)
        cvs = rig.rest_cvs[rig.cv_offsets[m]:rig.cv_offsets[m + 1]]
        mesh = part_mesh(cvs)
        d = across(cvs)
        jiggles = default_jiggles(rig)
        for mat in (FAT, MUSCLE):
            t = time.perf_counter()
            f_guess = GUESS_C * mat.shear_speed / s["r"]
            duration = min(max(4.0 / f_guess, 0.25), 0.8)
            ramp = min(0.05, 0.3 / f_guess)          # a stop sharp against the period rings the fundamental
            run, rd = ringdown_run(mesh, mat, duration=duration, fps=1000.0, k_damp=0.0, direction=tuple(d),
                                   window=3.0 / f_guess, ramp=ramp, hold=0.1)
            row = {"part": name, "material": mat.name, "tets": int(len(mesh.tets)), "f_fem_hz": rd.frequency_hz,
                   "zeta_numerical": rd.damping_ratio, "min_det": float(run.min_det.min()),
                   "ms_per_step": run.ms_per_step, "seconds": time.perf_counter() - t, **s}
            for k in ("r", "V^(1/3)", "L/2", "V/A"):
                row[f"C[{k}]"] = rd.frequency_hz * s[k] / mat.shear_speed
            rows.append(row)
            log(f"  {name:24s} {mat.name:6s} f_fem {rd.frequency_hz:6.2f} Hz  zeta_num {rd.damping_ratio:.3f}  "
                f"C[r] {row['C[r]']:.3f}  min det {row['min_det']:.2f}  ({row['seconds']:.1f} s, {len(mesh.tets)} tets)")
        # the particles: F_p at 1 Hz, and again at the frequency that should reproduce the FEM (fat's)
        p1 = particle_ringdown(rig, m, jiggles, d, 4.0, 1.0)
        f_fat = rows[-2]["f_fem_hz"]
        p2 = particle_ringdown(rig, m, jiggles, d, 1.0, f_fat / p1.frequency_hz)
        for row in rows[-2:]:
            row.update({"F_p": p1.frequency_hz, "F_p_at_fat": p2.frequency_hz / (f_fat / p1.frequency_hz),
                        "goal_mean": float(np.mean(jiggles[m].goal_weights())),
                        "ring_factor": float(np.sqrt(np.mean(jiggles[m].goal_weights()[8:32]) /
                                                     (1 - np.mean(jiggles[m].goal_weights()[8:32]))))})
        log(f"  {name:24s} particles at 1 Hz ring at {p1.frequency_hz:.3f} Hz (F_p); at {f_fat / p1.frequency_hz:.2f} Hz "
            f"they ring at {p2.frequency_hz:.2f} Hz (FEM fat {f_fat:.2f} Hz)")
    consts = {}
    for k in ("r", "V^(1/3)", "L/2", "V/A"):
        c = np.array([r[f"C[{k}]"] for r in rows])
        consts[k] = {"C": float(np.exp(np.mean(np.log(c)))), "spread": float(np.std(c) / np.mean(c)),
                     "min": float(c.min()), "max": float(c.max())}
    # two parameters: C = C0 (r / L)^a, least squares in the logs
    x = np.log([r["r"] / r["L"] for r in rows])
    y = np.log([r["C[r]"] for r in rows])
    a, b = np.polyfit(x, y, 1)
    pred = np.exp(b + a * x)
    ratio = np.exp(y) / pred
    consts["r, (r/L)^a"] = {"C": float(np.exp(b)), "a": float(a), "spread": float(np.std(ratio) / np.mean(ratio)),
                            "min": float(ratio.min()), "max": float(ratio.max())}
    best = min(consts, key=lambda k: consts[k]["spread"])
    F_p = float(np.mean([r["F_p"] for r in rows]))
    F_pm = float(np.mean([r["F_p_at_fat"] for r in rows]))
    log("  C per size measure: " + ", ".join(f"{k}: {v['C']:.3f} (spread {100 * v['spread']:.0f}%)"
                                              for k, v in consts.items()) + f"; best: {best}; F_p mean {F_p:.3f}")
    return {"rows": rows, "constants": consts, "best": best, "C": consts["r"]["C"], "F_p": F_p, "F_p_matched": F_pm}


def particle_damping(log, quick: bool) -> dict:
    """The particles' own ring-down damping against their linearized sway mode's (sim.jiggle.materials.sway_mode):
    every calibration part, each material's rule frequency (sim.jiggle.materials.fem_frequency), rung down as the
    FEM's calibration is (step_drive) at goal-spring damping_ratio 0, half and all of the material's; the ring-down's
    ratio from its logarithmic decrement (measure.decrement, as the cases read it). MODAL_GAIN = the geometric mean
    of measured over modal (damping_ratio > 0). The neighbour springs' dampers and the stiff tendon CVs' goal dampers
    (2 zeta omega_i m_i at each CV's own omega_i) add to the sway: the rule (sim.jiggle.materials.particle_damping)
    inverts MODAL_GAIN x sway_mode's ratio."""
    from jiggle.sim.fem.solve import GoalCurve
    from jiggle.sim.jiggle import materials
    from jiggle.sim.jiggle.materials import default_jiggles
    parts = calibration_parts(log, quick)
    rows = []
    for name, rig, m in parts:
        s = sizes(rig, m)
        sl = slice(rig.cv_offsets[m], rig.cv_offsets[m + 1])
        cvs = rig.rest_cvs[sl]
        d = across(cvs)
        jiggles = default_jiggles(rig)
        for mat in (FAT, MUSCLE):
            f = materials.fem_frequency(mat, s["r"], s["L"])
            ramp = min(0.05, 0.3 / f)
            duration = min(max(4.0 / f, 0.25), 0.8)
            knots, static, times, t_stop = step_goals(rig, d, duration, ramp=ramp, fps=1000.0)
            goal = np.stack([GoalCurve(knots, static)(t)[0] for t in times])
            base = replace(jiggles[m], frequency_hz=f / materials.ring_factor(jiggles[m]), density=mat.density)
            for zs in (0.0, 0.5 * mat.damping_ratio, mat.damping_ratio):
                jig = list(jiggles)
                jig[m] = replace(base, damping_ratio=zs)
                dyn = particle_cvs(rig, jig, knots, static, times)
                delta, n = measure.decrement(measure.principal_signal(dyn[:, sl] - goal[:, sl]), times, t_stop)
                zeta = delta / math.sqrt(4 * math.pi ** 2 + delta ** 2)
                f_mode, z_mode = materials.sway_mode(jig[m], cvs)
                rows.append({"part": name, "kind": rig.kinds[m], "material": mat.name, "zeta_set": zs, "zeta": zeta,
                             "extrema": n, "zeta_modal": z_mode, "f_modal_hz": f_mode})
                log(f"  {name:24s} {mat.name:6s} zeta set {zs:.3f}: rings down with {zeta:.3f} ({n} extrema); "
                    f"sway mode {f_mode:6.2f} Hz, zeta {z_mode:.3f}")
    used = [r for r in rows if r["zeta_set"] > 0 and r["zeta_modal"] > 0 and np.isfinite(r["zeta"])]
    q = np.array([r["zeta"] / r["zeta_modal"] for r in used])
    gain = float(np.exp(np.mean(np.log(q))))
    fit = {"gain": gain, "spread": float(np.std(q) / np.mean(q)), "min": float(q.min()), "max": float(q.max()),
           "n": int(len(q))}
    log(f"  measured / modal: {gain:.3f} (spread {100 * fit['spread']:.0f}%, {q.min():.2f}-{q.max():.2f}, "
        f"{len(q)} ring-downs)")
    return {"rows": rows, "fit": fit}


# ------------------------------------------------------------------------------------------------ 3. cases
CASES = {
    "belly": {"clip": "mocap/cmu_bvh/09_11.bvh", "character": "characters/CesiumMan.glb", "part": "belly_fat",
              "seconds": 3.0},
    "thighs": {"clip": "mocap/cmu_bvh/02_04.bvh", "character": None, "part": "right_quadriceps", "seconds": 4.0},
    "cat": {"clip": "characters/zoo/Cat.glb", "animation": "Walk", "character": "characters/zoo/Cat.glb", "part": None, "seconds": 2.0},
}


def case_drive(name: str, log, spec: dict | None = None):
    """(rig, m, knots (K,), static CVs (K, N, 3), times (T,), t_hold, the bake's jiggles, real_scale) of a case: the
    bake's own drive, then HOLD s; real_scale its real metres per simulated metre (BakeSetup.real_scale). spec (None:
    CASES[name]): clip, character (None: the generated body), animation, part (None: the largest of `kind`, "fat"
    by default, else any), seconds of motion from `start` (seconds of the clip, default 0)."""
    from jiggle.sim.bake.setup import BakeRequest, prepare
    spec = CASES[name] if spec is None else spec
    clip = ASSETS / spec["clip"]
    if not clip.exists():
        raise FileNotFoundError(clip)
    # relaxed tissue, as the solid is (the activation's stiffening is the particles' alone: --tissue fem refuses it)
    req = BakeRequest(clip=str(clip), character=str(ASSETS / spec["character"]) if spec["character"] else None,
                      animation=spec.get("animation"), formats=("npz",), start=spec.get("start"), activation="off")
    with warnings.catch_warnings():
        quiet()
        setup = prepare(req, log=lambda s: None)
    rig = setup.rig
    if spec["part"]:
        m = rig.names.index(spec["part"])
    else:                                             # the biggest part of the kind (fat unless said)
        kind = spec.get("kind", "fat")
        fat = [i for i in range(rig.M) if rig.kinds[i] == kind]
        if not fat and "kind" in spec:
            raise LookupError(f"the character has no {kind} part")
        fat = fat or list(range(rig.M))
        m = max(fat, key=lambda i: rig.rest_volume[i])
    t0 = float(setup.times[0])
    if setup.loop is not None and getattr(setup.loop, "on", False):
        t_end = t0 + spec["seconds"]                  # a cycle: world_at goes on periodically
        knots = np.arange(t0, t_end + 1e-9, 1.0 / RATE)
    else:
        t_end = min(float(setup.times[-1]), t0 + spec["seconds"])
        knots = setup.knots[(setup.knots >= t0 - 1e-9) & (setup.knots <= t_end + 1e-9)]
        t_end = float(knots[-1])
    world = setup.world_at(knots)
    hold = t_end + np.arange(1, int(HOLD * RATE) + 1) / RATE
    knots = np.concatenate([knots, hold])
    world = np.concatenate([world, np.repeat(world[-1:], len(hold), axis=0)])
    static = rig.static(world).cvs
    times = np.arange(t0, knots[-1] + 1e-9, 1.0 / FPS)
    log(f"  {name}: {rig.names[m]} ({rig.kinds[m]}), {t_end - t0:.2f} s of motion + {HOLD} s hold, "
        f"{len(knots)} knots, r {1e3 * rig.mean_radii(rig.rest_cvs)[m]:.1f} mm")
    return rig, m, knots, static, times, t_end, list(setup.jiggles), float(getattr(setup, "real_scale", 1.0))


def metrics(off: np.ndarray, times: np.ndarray, t_hold: float, window: float | None = None) -> dict:
    """Peak (mm), dominant frequency of the detrended signal while moving (Hz), ring-down in the hold (fitted over
    `window` seconds: ~3 periods of the expected mode) and its logarithmic decrement from successive extrema
    (measure.decrement: log_dec; the single-mode fit's: log_dec_fit)."""
    sig = measure.principal_signal(off)
    moving = times <= t_hold
    f_dom = measure.dominant_frequency(measure.detrend(sig[moving], times[moving]), times[moving], fmin=0.5)
    # the ring-down along the hold's own principal direction: the whole run's is the motion's, which the free
    # decay after the stop need not follow (projected on it, the ring is weak and a slower drift outweighs it)
    hold = times >= t_hold - 1e-12
    sig_hold = measure.principal_signal(off[hold])
    rd = measure.ringdown(sig_hold, times[hold], t_hold, window)
    delta, n = measure.decrement(sig_hold, times[hold], t_hold)
    return {"peak_mm": 1e3 * measure.peak_displacement(off), "log_dec_fit": rd.log_decrement, "extrema": n,
            "peak_moving_mm": 1e3 * measure.peak_displacement(off[moving]),
            "peak_hold_mm": 1e3 * measure.peak_displacement(off[times >= t_hold]), "f_dom_hz": f_dom,
            "ring_f_hz": rd.frequency_hz, "zeta": rd.damping_ratio, "log_dec": delta,
            "ring_amp_mm": 1e3 * rd.amplitude, "magnitude": measure.offset_magnitude(off)}


def case(name: str, cal: dict, log, spec: dict | None = None, plots: Path | None = None) -> dict:
    """A case's record (spec: case_drive's; plots: the folder of its plot, None: OUT)."""
    from jiggle.sim.jiggle.materials import default_jiggles
    rig, m, knots, static, times, t_hold, baked, k = case_drive(name, log, spec)
    sl = slice(rig.cv_offsets[m], rig.cv_offsets[m + 1])
    mat = material_for(rig.kinds[m])
    # both solvers at the character's real size (a game file's own unit is arbitrary: rig.character.real_size): the
    # FEM's mesh and goals scaled by k, the particles' offsets (linear in the size: their springs are set in Hz)
    s = {key: v * k for key, v in sizes(rig, m).items()}
    C, F_p = cal.get("C", DEFAULT_C), cal.get("F_p_matched", cal.get("F_p", 1.0))
    from jiggle.sim.jiggle.materials import fem_frequency
    f_rule = fem_frequency(mat, s["r"], s["L"])               # the product's rule (its slender form)
    t = time.perf_counter()
    mesh = part_mesh(k * rig.rest_cvs[sl])
    from jiggle.sim.fem.modes import band, modes, rayleigh
    found = modes(mesh, mat)
    f1, f2 = band(found)
    alpha, k_damp = rayleigh(mat.damping_ratio, f1, f2, mat.shear_pa, DT, NUMERICAL_DAMPING)
    run = simulate_part(mesh, mat, mesh.goals(k * static[:, sl]), knots, times, k_damp=k_damp, alpha=alpha)
    fem_t = time.perf_counter() - t
    from jiggle.sim.fem.solve import GoalCurve
    curve = GoalCurve(knots, static[:, sl])
    goal = k * np.stack([curve(t)[0] for t in times])          # the static CVs on the particles' goal curve
    goal_cvs = mesh.cvs(run.goals)                             # the FEM's CVs embedded in its goal
    out = {"case": name, "part": rig.names[m], "kind": rig.kinds[m], "material": mat.name, "r_mm": 1e3 * s["r"],
           "real_scale": k,
           "f_rule_hz": f_rule, "k_damp": k_damp, "alpha": alpha, "f_lowest_hz": found.lowest_hz,
           "f_sway_hz": found.sway_hz, "band_hz": [f1, f2], "tets": int(len(mesh.tets)),
           "min_det": float(run.min_det.min()), "step_min_det": float(run.step_min_det),
           "steps_redone": int(run.redone), "steps_line_searched": int(run.searched),
           "whole_parts_drawn_back": int(run.whole),
           "ms_per_step": run.ms_per_step, "fem_seconds": fem_t,
           "t_hold": t_hold - float(times[0]), "max_energy_J": float(run.energy.max()),
           "goal_cv_err_mm": float(1e3 * np.abs(goal_cvs - goal).max())}
    res = {"fem": metrics(mesh.cvs(run.positions) - goal_cvs, times, t_hold, 3.0 / f_rule)}
    jig = baked if len(baked) == rig.M else default_jiggles(rig)    # what a bake with the defaults uses
    dyn = particle_cvs(rig, jig, knots, static, times)
    res["particles"] = metrics(k * dyn[:, sl] - goal, times, t_hold, 3.0 / (F_p * jig[m].frequency_hz))
    jig_m = list(jig)
    jig_m[m], how = particle_rule(mat, rig, m, jig[m], C / F_p, k)
    f_mat, z_mat = float(jig_m[m].frequency_hz), float(jig_m[m].damping_ratio)
    dyn_m = particle_cvs(rig, jig_m, knots, static, times)
    res["particles_material"] = metrics(k * dyn_m[:, sl] - goal, times, t_hold, 3.0 / (F_p * f_mat))
    out.update({"particles_default_f_hz": float(jig[m].frequency_hz), "particles_default_zeta": float(jig[m].damping_ratio),
                "particles_material_f_hz": f_mat, "particles_material_zeta": z_mat, "particles_material_rule": how})
    for k, v in res.items():
        out[k] = {kk: vv for kk, vv in v.items() if kk != "magnitude"}
    for k in ("particles", "particles_material"):
        out[f"peak_ratio_fem_{k}"] = res["fem"]["peak_mm"] / max(res[k]["peak_mm"], 1e-12)
        out[f"freq_ratio_fem_{k}"] = res["fem"]["ring_f_hz"] / max(res[k]["ring_f_hz"], 1e-12)
    log(f"  {name}: FEM peak {res['fem']['peak_mm']:.2f} mm, ring {res['fem']['ring_f_hz']:.2f} Hz, zeta "
        f"{res['fem']['zeta']:.2f} ({run.ms_per_step:.1f} ms/step, {fem_t:.0f} s) | particles default "
        f"{res['particles']['peak_mm']:.2f} mm {res['particles']['ring_f_hz']:.2f} Hz zeta {res['particles']['zeta']:.2f}"
        f" | particles from material {res['particles_material']['peak_mm']:.2f} mm "
        f"{res['particles_material']['ring_f_hz']:.2f} Hz zeta {res['particles_material']['zeta']:.2f}")
    plot(name, out, times - times[0], t_hold - times[0], res, plots)
    return out


def plot(name, out, t, t_hold, res, folder: Path | None = None) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(10, 4.2), dpi=100)
    ax.plot(t, 1e3 * res["fem"]["magnitude"], label=f"FEM ({out['material']}, {out['tets']} tets)", color="k", lw=1.6)
    ax.plot(t, 1e3 * res["particles"]["magnitude"], label=f"particles, default ({out['particles_default_f_hz']:.1f} Hz, "
            f"zeta {out['particles_default_zeta']:.2f})", color="tab:blue", lw=1.2)
    ax.plot(t, 1e3 * res["particles_material"]["magnitude"], label=f"particles from the material "
            f"({out['particles_material_f_hz']:.1f} Hz, zeta {out['particles_material_zeta']:.2f})", color="tab:orange",
            lw=1.2)
    ax.axhline(0.0, color="0.5", lw=0.8, label="static (goal)")
    ax.axvline(t_hold, color="0.5", ls="--", lw=0.8)
    ax.text(t_hold, ax.get_ylim()[1] * 0.03, " hold", va="bottom", color="0.4")   # under the legend
    ax.set_xlabel("time (s)")
    ax.set_ylabel("largest CV offset from the goal (mm)")
    ax.set_title(f"{name}: {out['part']} - FEM vs particles, both driven by the static shape")
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    fig.savefig((OUT if folder is None else folder) / f"fem_reference_{name}.png")
    plt.close(fig)


TOLERANCES = (0.25, 0.15, 0.30)
"""The issue's: the particles' peak, ring-down frequency and log decrement within these fractions of the FEM's."""


def tolerance_ratios(r: dict) -> tuple:
    """(peak, ring f, log decrement): the FEM's over the particles' from the material, of a case's record."""
    pm = r["particles_material"]
    return (r["fem"]["peak_mm"] / max(pm["peak_mm"], 1e-12), r["fem"]["ring_f_hz"] / max(pm["ring_f_hz"], 1e-12),
            r["fem"]["log_dec"] / max(pm["log_dec"], 1e-12))


def tolerance_pass(ratios) -> tuple:
    """Whether each of tolerance_ratios' is within TOLERANCES (the particles' figure within that fraction of the FEM's)."""
    return tuple(abs(1.0 / q - 1.0) <= tol for q, tol in zip(ratios, TOLERANCES))


# ------------------------------------------------------------------------------------------------ output
def write(result: dict) -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "fem_reference.json").write_text(json.dumps(result, indent=1, default=float))
    L = ["# FEM reference vs particles (benchmarks/fem_reference.py)", "",
         "Both solvers are driven by the same goal: the part's static CVs at every knot (the FEM's tet vertices through "
         "their loft coordinates); offsets are dynamic minus goal at the 40 CVs (the FEM's embedded in its tets).", ""]
    d = result.get("damping")
    if d:
        L += [f"## Damping (part {d['part']}, muscle; VBD numerical zeta at dt {DT * 1e3:g} ms / {ITERATIONS} iterations: "
              f"{d['zeta_numerical']:.3f})", "",
              "| material | dt ms | iterations | requested zeta | numerical taken off | k_damp Pa s | f Hz | measured zeta | ms/step |",
              "|---|---|---|---|---|---|---|---|---|"]
        for r in d["rows"]:
            L.append(f"| {r.get('material', 'muscle')} | {r['dt'] * 1e3:g} | {r['iterations']} | {r['requested']:.2f} | {'yes' if r.get('net') else 'no'} | "
                     f"{r['k_damp']:.2f} | {r['f_hz']:.2f} | {r['zeta']:.3f} | {r['ms_per_step']:.1f} |")
        L.append("")
    c = result.get("calibration")
    if c:
        L += ["## Calibration: undamped ring-downs, f_fem = C shear_speed / s", "",
              "| part | material | tets | r mm | L mm | f_fem Hz | zeta (numerical) | C[r] | C[V^(1/3)] | C[L/2] | C[V/A] | "
              "min det F | F_p (particles at 1 Hz) | F_p at the fat frequency | sqrt(w/(1-w)) of the belly |", "|" + "---|" * 15]
        for r in c["rows"]:
            L.append(f"| {r['part']} | {r['material']} | {r['tets']} | {1e3 * r['r']:.1f} | {1e3 * r['L']:.0f} | "
                     f"{r['f_fem_hz']:.2f} | {r['zeta_numerical']:.3f} | {r['C[r]']:.3f} | {r['C[V^(1/3)]']:.3f} | "
                     f"{r['C[L/2]']:.3f} | {r['C[V/A]']:.3f} | {r['min_det']:.2f} | {r['F_p']:.3f} | {r['F_p_at_fat']:.3f} | {r.get('ring_factor', float('nan')):.3f} |")
        L += ["", "| size measure | C (geometric mean) | spread (std/mean) | min | max |", "|---|---|---|---|---|"]
        for k, v in c["constants"].items():
            extra = f" (a = {v['a']:.3f}; min/max of the ratio to the fit)" if "a" in v else ""
            L.append(f"| {k}{extra} | {v['C']:.4f} | {100 * v['spread']:.1f}% | {v['min']:.3f} | {v['max']:.3f} |")
        L += ["", f"Best size measure: {c['best']}. F_p (mean over parts) = {c['F_p']:.3f}: particles at frequency_hz f "
              f"ring at F_p f, so frequency_hz = f_fem / F_p. At the frequency that should match the fat FEM, F_p "
              f"(mean) = {c.get('F_p_matched', float('nan')):.3f}: not a constant (see the report).", ""]
    pd = result.get("particle_damping")
    if pd and "fit" in pd:
        L += ["## Particle damping: the ring-down's ratio against the sway mode's (calibration parts, each material's "
              "rule frequency, the step drive)", "",
              "| part | kind | material | damping_ratio set | ring-down zeta (decrement) | extrema | sway mode Hz | "
              "sway mode zeta |", "|---|---|---|---|---|---|---|---|"]
        for r in pd["rows"]:
            L.append(f"| {r['part']} | {r['kind']} | {r['material']} | {r['zeta_set']:.3f} | {r['zeta']:.3f} | "
                     f"{r['extrema']} | {r['f_modal_hz']:.2f} | {r['zeta_modal']:.3f} |")
        v = pd["fit"]
        L += ["", f"Measured over modal (damping_ratio > 0): {v['gain']:.3f}, spread {100 * v['spread']:.1f}% "
              f"({v['min']:.2f}-{v['max']:.2f}, {v['n']} ring-downs): sim.jiggle.materials.MODAL_GAIN. The rule sets "
              "damping_ratio so that MODAL_GAIN x the sway mode's ratio is the material's.", ""]
    cs = result.get("cases")
    if cs:
        L += ["## Cases: FEM vs particles on the same drive (last pose held 1.5 s at the end)", "",
              "| case | part | solver | f set Hz | zeta set | peak mm | peak while moving mm | peak in hold mm | "
              "dominant f moving Hz | ring-down f Hz | fit's zeta | fit's log decrement | log decrement (extrema) |",
              "|" + "---|" * 13]
        for r in cs.values():
            sets = {"fem": (r["f_rule_hz"], None), "particles": (r["particles_default_f_hz"], r["particles_default_zeta"]),
                    "particles_material": (r["particles_material_f_hz"], r["particles_material_zeta"])}
            for k, (f, z) in sets.items():
                v = r[k]
                zs = f"{z:.2f}" if z is not None else f"k_damp {r['k_damp']:.2f}"
                L.append(f"| {r['case']} | {r['part']} | {k} | {f:.2f} | {zs} | {v['peak_mm']:.2f} | {v.get('peak_moving_mm', float('nan')):.2f} | {v['peak_hold_mm']:.2f} | "
                         f"{v['f_dom_hz']:.2f} | {v['ring_f_hz']:.2f} | {v['zeta']:.2f} | "
                         f"{v.get('log_dec_fit', float('nan')):.2f} | {v['log_dec']:.2f} ({v.get('extrema', 0)}) |")
        L += ["", "| case | real scale | FEM/particles peak | FEM/particles peak while moving | FEM/particles ring f | "
              "FEM/particles-from-material peak | ring f | log decrement | within 25% / 15% / 30% | FEM ms/step | tets | "
              "min det F | plot |", "|" + "---|" * 13]
        for r in cs.values():
            pm = r["fem"].get("peak_moving_mm", float("nan")) / max(r["particles"].get("peak_moving_mm", 1e-12), 1e-12)
            ratios = tolerance_ratios(r)
            verdict = " / ".join("yes" if ok else "**no**" for ok in tolerance_pass(ratios))
            L.append(f"| {r['case']} | {r.get('real_scale', 1.0):.3g} | {r['peak_ratio_fem_particles']:.2f} | {pm:.2f} | "
                     f"{r['freq_ratio_fem_particles']:.2f} | {ratios[0]:.2f} | {ratios[1]:.2f} | {ratios[2]:.2f} | "
                     f"{verdict} | {r['ms_per_step']:.1f} | {r['tets']} | {r['min_det']:.2f} | fem_reference_{r['case']}.png |")
        L += ["", "Ratios are FEM over the particles from the material; within: the particles' peak within 25% of the FEM's, "
              "their ring-down frequency within 15%, their log decrement within 30% (|particles / FEM - 1|)."]
        L += [""] + [f"- {r['case']}: particles from the material set by {r.get('particles_material_rule', '?')}; "
                     + (f"FEM: Rayleigh damping, the material's zeta at {r['band_hz'][0]:.2f} and {r['band_hz'][1]:.2f} Hz "
                        f"(its mesh's lowest mode, and its sway {r['f_sway_hz']:.2f} Hz or twice the lowest): k_damp "
                        f"{r['k_damp']:.2f} Pa s (VBD's own damping taken off), alpha {r['alpha']:.2f} 1/s."
                        if "band_hz" in r else f"FEM damped at k_damp {r['k_damp']:.2f} Pa s.") for r in cs.values()]
        L.append("")
    (OUT / "fem_reference.md").write_text("\n".join(L) + "\n")


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--case", default="all", choices=["belly", "thighs", "cat", "all", "none"])
    ap.add_argument("--no-calibration", action="store_true")
    ap.add_argument("--no-damping", action="store_true")
    ap.add_argument("--no-particle-damping", action="store_true")
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args(argv)
    log = lambda s: print(s, flush=True)  # noqa: E731
    path = OUT / "fem_reference.json"
    result = json.loads(path.read_text()) if path.exists() else {}
    result = {k: v for k, v in result.items() if k in ("damping", "calibration", "particle_damping", "cases") and isinstance(v, dict)}
    t_all = time.perf_counter()
    if not args.no_damping:
        log("damping: requested vs measured (ellipsoid, muscle)")
        result["damping"] = damping(log, args.quick)
        write(result)
    if not args.no_calibration:
        log("calibration: undamped ring-downs, FEM and particles")
        result["calibration"] = calibration(log, args.quick)
        write(result)
    if not args.no_particle_damping:
        log("particle damping: the particles' ring-down zeta against their goal springs' (calibration parts)")
        result["particle_damping"] = particle_damping(log, args.quick)
        write(result)
    cal = result.get("calibration") or {}
    names = [] if args.case == "none" else (list(CASES) if args.case == "all" else [args.case])
    if names:
        log("cases: FEM vs particles")
        cases = dict(result.get("cases") or {})
        for n in names:
            try:
                cases[n] = case(n, cal, log)
            except FileNotFoundError as e:
                log(f"  {n}: skipped ({e} is absent)")
            result["cases"] = cases
            write(result)
    log(f"done in {time.perf_counter() - t_all:.0f} s")
    return result


if __name__ == "__main__":
    main()
