"""Best-fit ellipsoids of skin regions (Pratscher et al. 2005, section 3.2).

A region of skin is a set of triangles. Its points are taken as uniformly spread over those
triangles, so the fit does not depend on how densely the artist tessellated each part: the mean and
covariance are the exact surface moments (for a triangle with corners a, b, c and s = a + b + c,
E[x] = s / 3 and E[x x^T] = (a a^T + b b^T + c c^T + s s^T) / 12), summed with area weights.
The eigenvectors of the covariance give the ellipsoid's axes and the square roots of its eigenvalues
the half-lengths, as in the paper (no extra scale factor: the paper reads the fit as the Gaussian that
best explains the points, one standard deviation per axis; conforming then inflates it toward the
skin). A region flatter than `thickness_min` (a patch of skin, or a region with few triangles) gets that
half-thickness, and is pushed inward so that its outer side stays where the patch was: at the skin's
height in the middle of the patch (an area-weighted average over the triangles near the mean, Gaussian
weights of width MIDDLE_WIDTH tangential standard deviations). The mean itself lies above a hollow
patch (the skin between a belly and the ribs): measured from the mean, a hollow's outer side would
poke out of the skin.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from jiggle.rig.base.frozen import frozen_array

MIDDLE_WIDTH = 0.5
"""Width of the weights that measure a flat patch's height at its middle, in tangential standard deviations."""


@dataclass(frozen=True, eq=False)
class Ellipsoid:
    """An ellipsoid in world space (metres).

    centre : (3,) float64.
    axes : (3, 3) float64, rows are unit axes, the major axis first; right-handed.
    radii : (3,) float64 half-lengths along `axes`, descending.
    """

    centre: np.ndarray
    axes: np.ndarray
    radii: np.ndarray

    def __post_init__(self):
        for k in ("centre", "axes", "radii"):
            object.__setattr__(self, k, frozen_array(getattr(self, k)))

    @property
    def matrix(self) -> np.ndarray:
        """(4, 4) E taking the unit sphere to this ellipsoid: x = E @ [p_l, 1]."""
        E = np.eye(4)
        E[:3, :3] = self.axes.T * self.radii
        E[:3, 3] = self.centre
        return E

    @property
    def ends(self) -> np.ndarray:
        """(2, 3) the ends of the major axis, centre -/+ radius along axes[0]."""
        a = self.axes[0] * self.radii[0]
        return np.stack([self.centre - a, self.centre + a])

    @property
    def volume(self) -> float:
        """Cubic metres."""
        return float(4.0 / 3.0 * np.pi * np.prod(self.radii))

    def mesh(self, subdivisions: int = 3) -> tuple[np.ndarray, np.ndarray]:
        """Triangle mesh: vertices (n, 3) metres on the surface, faces (f, 3) int32 outward."""
        import trimesh
        sphere = trimesh.creation.icosphere(subdivisions=subdivisions)
        v = np.asarray(sphere.vertices, dtype=np.float64)
        return v @ (self.axes.T * self.radii).T + self.centre, np.asarray(sphere.faces, dtype=np.int32)

    def local(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) points in the ellipsoid's space, where it is the unit sphere at the origin."""
        return ((np.asarray(points, float) - self.centre) @ self.axes.T) / self.radii


def surface_moments(vertices: np.ndarray, faces: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Area (m^2), mean (3,) and covariance (3, 3) of points spread uniformly over triangles (F, 3)."""
    tri = np.asarray(vertices, dtype=np.float64)[np.asarray(faces)]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    total = float(area.sum())
    if total <= 0.0:
        return 0.0, np.full(3, np.nan), np.full((3, 3), np.nan)
    s = tri.sum(axis=1)
    mean = (area @ s) / (3.0 * total)
    second = (np.einsum("f,fki,fkj->ij", area, tri, tri) + np.einsum("f,fi,fj->ij", area, s, s)) / (12.0 * total)
    return total, mean, second - np.outer(mean, mean)


def fit_ellipsoid(vertices: np.ndarray, faces: np.ndarray, *, along: np.ndarray, outward: np.ndarray | None = None,
                  thickness_min: float = 0.004) -> Ellipsoid:
    """Best-fit ellipsoid of the skin triangles `faces` (F, 3) of `vertices` (V, 3) metres.

    along : (3,) direction the major axis is signed to follow (the bone's direction).
    outward : (3,) direction, pointing out of the body, that the minor axis is signed to follow and
        along which a too-thin fit is pushed inward; default: from the bone line is not known here,
        so the minor axis is only signed.
    thickness_min : metres, the least half-length of any axis.
    Raises ValueError when the triangles have no area.
    """
    area, mean, cov = surface_moments(vertices, faces)
    if not area > 0.0:
        raise ValueError("the region has no area")
    w, v = np.linalg.eigh(cov)
    order = np.argsort(w)[::-1]
    w, axes = np.clip(w[order], 0.0, None), v[:, order].T.copy()
    if axes[0] @ along < 0:
        axes[0] = -axes[0]
    if outward is not None and axes[2] @ outward < 0:
        axes[2] = -axes[2]
    axes[1] = np.cross(axes[2], axes[0])
    radii = np.sqrt(w)
    centre = mean.copy()
    short = thickness_min - radii
    for k in (1, 2):
        if short[k] > 0:
            # a flat patch: the fitted sheet lies in the skin; keep its outer side at the skin's
            # height (along axes[k], outward) in the middle of the patch
            if outward is not None:
                sign = 1.0 if axes[k] @ outward >= 0 else -1.0
                middle = _middle_height(vertices, faces, mean, axes, np.maximum(radii, thickness_min), k)
                centre -= sign * (thickness_min - sign * middle) * axes[k] * (abs(axes[k] @ outward))
            radii[k] = thickness_min
    radii[0] = max(radii[0], thickness_min)
    order = np.argsort(radii[1:])[::-1] + 1  # keep radii descending after the minimum was applied
    if order[0] != 1:
        axes = axes[[0, 2, 1]]
        radii = radii[[0, 2, 1]]
        axes[2] = np.cross(axes[0], axes[1])
    return Ellipsoid(centre=centre, axes=axes, radii=radii)


def _middle_height(vertices: np.ndarray, faces: np.ndarray, mean: np.ndarray, axes: np.ndarray,
                   radii: np.ndarray, k: int) -> float:
    """Height along axes[k] above `mean` of the skin triangles near the patch's middle: their centroids'
    heights averaged with weights area x exp(-q^2 / (2 MIDDLE_WIDTH^2)), q the tangential distance
    from the mean in standard deviations `radii` along the other two axes."""
    tri = np.asarray(vertices, dtype=np.float64)[np.asarray(faces)]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    rel = tri.mean(axis=1) - mean
    q2 = sum(((rel @ axes[i]) / radii[i]) ** 2 for i in range(3) if i != k)
    weight = area * np.exp(-0.5 * q2 / MIDDLE_WIDTH ** 2)
    return float(weight @ (rel @ axes[k]) / weight.sum()) if weight.sum() > 0 else 0.0
