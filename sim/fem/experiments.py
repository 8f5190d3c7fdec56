"""The calibration's experiments: simple lofted parts and the ring-down drive.

- `ellipsoid_rig(length, radii)`: a one-joint MuscleRig (rig.muscle.model) holding one fusiform muscle fitted to
  an ellipsoid of that length (metres, along +X) and minor radii (metres), at bind on joint 0 (identity).
- `step_drive(...)`: the bone's rigid transforms for a short step in velocity: from rest it accelerates evenly to
  `speed` (m/s) along `direction` over `ramp` seconds, holds that speed for `hold` seconds, decelerates evenly to
  rest over `ramp` seconds (stopping at t_stop) and stays: the part swings past its place at the stop and rings
  down, the free decay that measure.ringdown reads.
- `ringdown_run(mesh, material, ...)`: the FEM of that drive (the part's goals carried by it: a rigid goal, the
  static shape of a part on a bone moving without turning), and its ring-down measured on the surface offsets
  from the goal.
"""
from __future__ import annotations

import math

import numpy as np

from jiggle.rig.muscle.material import Material
from jiggle.rig.muscle.model import MuscleRig, MuscleSpec, build_muscle_rig
from jiggle.sim.fem import measure
from jiggle.sim.fem.solve import DT, ITERATIONS, FemRun, carried_goals, simulate_part
from jiggle.sim.fem.tet_mesh import TetMesh


def ellipsoid_rig(length: float, radii=(0.02, 0.02), n: int = 600) -> MuscleRig:
    """A MuscleRig of one muscle fitted to the ellipsoid centred at the origin with half-length length / 2 along
    +X and minor radii (2,) along (+Y, +Z), riding joint 0 of a one-joint skeleton at bind (identity)."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    r = np.sqrt(1.0 - z * z)
    phi = math.pi * (1.0 + 5 ** 0.5) * i
    surface = np.stack([z * 0.5 * length, r * np.cos(phi) * radii[0], r * np.sin(phi) * radii[1]], axis=1)
    ends = np.array([[-0.5 * length, 0, 0], [0.5 * length, 0, 0]])
    points = np.array([ends[0] - (0.05 * length, 0, 0), ends[0], ends[1], ends[1] + (0.05 * length, 0, 0)])
    spec = MuscleSpec(name=f"ellipsoid_{length * 100:.0f}x{radii[0] * 100:.1f}", kind="muscle", group="test", bone=0,
                      bones=(0, 0, 0, 0), points=points, ends=ends, up=np.array([0.0, 1.0, 0.0]), surface=surface)
    return build_muscle_rig([spec], np.eye(4)[None])


def step_drive(direction=(0.0, 1.0, 0.0), speed: float = 0.5, ramp: float = 0.05, hold: float = 0.1,
               rate: float = 1000.0) -> tuple[np.ndarray, np.ndarray, float]:
    """knots (K,) seconds, carry (K, 4, 4) (pure translations from the identity) at `rate` Hz, and t_stop (s)."""
    d = np.asarray(direction, dtype=np.float64)
    d = d / np.linalg.norm(d)
    a = speed / ramp
    t_stop = 2 * ramp + hold
    t = np.arange(0.0, t_stop + 1e-9, 1.0 / rate)
    s = np.where(t < ramp, 0.5 * a * t ** 2,
                 np.where(t < ramp + hold, 0.5 * a * ramp ** 2 + speed * (t - ramp),
                          0.5 * a * ramp ** 2 + speed * hold + speed * (t - ramp - hold)
                          - 0.5 * a * (t - ramp - hold) ** 2))
    carry = np.tile(np.eye(4), (len(t), 1, 1))
    carry[:, :3, 3] = s[:, None] * d
    return t, carry, float(t_stop)


def ringdown_run(mesh: TetMesh, material: Material, *, duration: float = 1.0, fps: float = 200.0,
                 frequency_hz: float | None = None, k_damp: float | None = None, dt: float = DT,
                 iterations: int = ITERATIONS, window: float | None = None, stiffening: float = 0.0,
                 alpha: float = 0.0, **drive) -> tuple[FemRun, measure.Ringdown]:
    """The FEM of `mesh` of `material` under step_drive(**drive) (its goals carried rigidly) sampled at fps for
    `duration` seconds after the stop, and its ring-down (measure.ringdown of the mean surface offset from the goal).
    Damping (k_damp, alpha), dt, iterations, stiffening as simulate_part; window as measure.ringdown. stiffening defaults to 0: a
    ring-down calibrates the small-strain fundamental (the step drive's 0.5 m/s swings a soft fat ellipsoid far
    enough for the stiffening to raise its frequency ~10%; at 0.1 m/s it changes it by 0.5%)."""
    knots, carry, t_stop = step_drive(**drive)
    times = np.arange(0.0, t_stop + duration + 1e-9, 1.0 / fps)
    run = simulate_part(mesh, material, carried_goals(mesh, carry), knots, times, frequency_hz=frequency_hz,
                        k_damp=k_damp, dt=dt, iterations=iterations, stiffening=stiffening, alpha=alpha)
    S = mesh.surface_count
    offsets = measure.goal_offsets(run.positions[:, :S], run.goals[:, :S])
    return run, measure.ringdown(measure.principal_signal(offsets), times, t_stop, window)


__all__ = ["ellipsoid_rig", "step_drive", "ringdown_run"]
