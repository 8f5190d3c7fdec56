"""A two-bone arm and muscles fitted to ellipsoids on it: synthetic fixtures for the muscle-model,
muscle-frame and influence tests (no file, no fit)."""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from jiggle.rig.muscle.model import MuscleSpec

UPPER, FORE = 0.30, 0.25    # metres, arm bone lengths


def fibonacci_sphere(n: int) -> np.ndarray:
    """(n, 3) nearly uniform unit vectors."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    r = np.sqrt(1.0 - z * z)
    phi = np.pi * (1.0 + 5 ** 0.5) * i
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def ellipsoid_points(centre, axes, radii, n: int = 500) -> np.ndarray:
    """(n, 3) points on the ellipsoid with unit axes (3, 3) rows and half-lengths radii (3,)."""
    return np.asarray(centre) + (fibonacci_sphere(n) * radii) @ np.asarray(axes)


def arm_world(elbow_deg: float = 0.0, root: np.ndarray | None = None) -> np.ndarray:
    """(3, 4, 4) shoulder, elbow, wrist of an arm hanging along -Z from the origin; the elbow flexes
    about +X, swinging the forearm toward the front (+Y). `root` (4, 4) moves the whole arm."""
    rx = Rotation.from_euler("x", elbow_deg, degrees=True).as_matrix()
    w = np.tile(np.eye(4), (3, 1, 1))
    w[1, :3, 3] = (0.0, 0.0, -UPPER)
    w[1, :3, :3] = rx
    w[2, :3, :3] = rx
    w[2, :3, 3] = w[1, :3, 3] + rx @ (0.0, 0.0, -FORE)
    return w if root is None else root @ w


ARM_BIND = arm_world(0.0)


def spec_from_ellipsoid(name, ends, up, radii, bones, origin, insertion, hinges=None, bone=0, **kw):
    """A MuscleSpec whose conformed shape is the ellipsoid spanning `ends` with minor radii (2,) and
    2nd axis `up`; hinges default to the belly ends."""
    ends = np.asarray(ends, dtype=float)
    axis = (ends[1] - ends[0]) / np.linalg.norm(ends[1] - ends[0])
    up = np.asarray(up, dtype=float)
    up = up - (up @ axis) * axis
    up /= np.linalg.norm(up)
    axes = np.stack([axis, up, np.cross(axis, up)])
    radii = (np.linalg.norm(ends[1] - ends[0]) / 2, *radii)
    surface = ellipsoid_points(ends.mean(axis=0), axes, radii)
    oh, ih = ends if hinges is None else hinges
    return MuscleSpec(name=name, kind="muscle", group=name, bone=bone, bones=bones,
                      points=np.stack([origin, oh, ih, insertion]), ends=ends, up=up, surface=surface, **kw)


def biceps(**kw) -> MuscleSpec:
    """Belly on the front of the upper arm; the insertion rides the forearm 4 cm below the elbow."""
    return spec_from_ellipsoid("biceps", [(0, 0.035, -0.06), (0, 0.035, -0.24)], (0, 1, 0), (0.025, 0.02),
                               bones=(0, 0, 0, 1), origin=(0, 0.01, -0.01), insertion=(0, 0.02, -0.34), **kw)


def brachio(**kw) -> MuscleSpec:
    """Spans the elbow: o_hinge rides the upper arm, i_hinge the forearm, so its action curve bends."""
    return spec_from_ellipsoid("brachio", [(0, 0.03, -0.22), (0, 0.03, -0.40)], (0, 1, 0), (0.02, 0.015),
                               bones=(0, 0, 1, 1), origin=(0, 0.02, -0.18), insertion=(0, 0.015, -0.52), **kw)
