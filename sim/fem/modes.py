"""A part's small-strain vibration modes, and the Rayleigh damping that gives its material's ratio across them.

The solid's modes about its goal shape (linear elasticity: shear modulus mu, Lame lambda; lumped masses; the
attached vertices fixed) by the generalized eigenproblem K phi = omega^2 M phi (scipy's shift-invert Lanczos).
A lofted part has several low modes: its sway (the mode that carries most of its free mass: the wobble of its
centre of mass that the calibration's ring-downs read) and, below it, modes that bend or twist it against its
attached core (CesiumMan's belly fat: 4.3 and 5.9 Hz under its 8.0 Hz sway). A damping proportional to the stiffness
alone (VBD's tet damping) gives each mode zeta omega / omega_sway: the lower modes ring on at a fraction of the
material's ratio, and a clip that excites them (a run stopping dead) rings on longer than the material says.

Rayleigh damping, alpha M + beta K, gives zeta(omega) = alpha / (2 omega) + beta omega / 2: set to the material's
ratio at the lowest mode and at the sway (or at twice the lowest, if the sway is below that), it stays within a few
percent of it between them (at least 2 sqrt(w1 w2) / (w1 + w2) of it) and rises above. The beta part is VBD's tet
damping (k_damp = beta mu / 2, VBD's own numerical damping ~NUMERICAL_DAMPING omega dt taken off); the alpha part
is a drag on each free vertex's velocity relative to its goal's (sim/fem/fem_kernels.goal_drag), as the particles'
goal dampers act on their velocity relative to the goal.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from jiggle.rig.muscle.material import Material


@dataclass(frozen=True)
class Modes:
    """frequencies_hz : (n,) ascending, Hz. means : (n, 3) each mode's mass-weighted mean displacement, normalized
    (sum m phi / sqrt(sum m sum m |phi|^2)): its share of the free mass moved as a whole along each axis.
    shares : (n,) |means|^2, the fraction of the free mass each mode moves as a whole (1 for a rigid translation).
    sway : the index of the largest share."""

    frequencies_hz: np.ndarray
    means: np.ndarray

    @property
    def shares(self) -> np.ndarray:
        return (np.asarray(self.means) ** 2).sum(axis=1)

    def along(self, direction) -> int:
        """The index of the mode that moves the most mass along `direction` (3,)."""
        d = np.asarray(direction, np.float64)
        return int(np.argmax((np.asarray(self.means) @ (d / np.linalg.norm(d))) ** 2))

    @property
    def sway(self) -> int:
        return int(np.argmax(self.shares))

    @property
    def lowest_hz(self) -> float:
        return float(self.frequencies_hz[0])

    @property
    def sway_hz(self) -> float:
        return float(self.frequencies_hz[self.sway])


def stiffness(points: np.ndarray, tets: np.ndarray, material: Material):
    """(3N, 3N) scipy CSR: the linear-elastic stiffness (N/m) of tets (T, 4) over points (N, 3) metres."""
    import scipy.sparse as sp
    x = np.asarray(points, np.float64)
    T = np.asarray(tets, np.int64)
    mu, lam = material.shear_pa, material.lame_pa
    Dm = np.stack([x[T[:, i]] - x[T[:, 0]] for i in (1, 2, 3)], axis=2)
    vol = np.abs(np.linalg.det(Dm)) / 6.0
    inv = np.linalg.inv(Dm)                                          # rows: the gradients of barycentrics 1..3
    G = np.concatenate([-inv.sum(axis=1, keepdims=True), inv], axis=1)   # (T, 4, 3)
    gg = np.einsum("tak,tbk->tab", G, G)
    Ke = vol[:, None, None, None, None] * (mu * gg[:, :, None, :, None] * np.eye(3)[None, None, :, None, :]
                                           + mu * np.einsum("taj,tbi->taibj", G, G)
                                           + lam * np.einsum("tai,tbj->taibj", G, G))
    dof = (3 * T[:, :, None] + np.arange(3)[None, None, :]).reshape(len(T), 12)
    rows, cols = np.repeat(dof, 12, axis=1).ravel(), np.tile(dof, (1, 12)).ravel()
    return sp.csr_matrix((Ke.reshape(len(T), 144).ravel(), (rows, cols)), shape=(3 * len(x), 3 * len(x)))


def modes(mesh, material: Material, count: int = 12, points: np.ndarray | None = None) -> Modes:
    """The lowest `count` modes of `mesh` (sim.fem.tet_mesh.TetMesh; its attached vertices fixed) of `material`,
    at `points` (N, 3) metres (None: its rest points)."""
    import scipy.sparse as sp
    from scipy.sparse.linalg import eigsh
    x = np.asarray(mesh.points if points is None else points, np.float64)
    T = np.asarray(mesh.tets, np.int64)
    free = np.flatnonzero(~np.asarray(mesh.attached, bool))
    vol = np.abs(np.linalg.det(np.stack([x[T[:, i]] - x[T[:, 0]] for i in (1, 2, 3)], axis=2))) / 6.0
    m = np.zeros(len(x))
    np.add.at(m, T.ravel(), np.repeat(vol * material.density / 4.0, 4))
    fd = (3 * free[:, None] + np.arange(3)).ravel()
    K = stiffness(x, T, material)[fd][:, fd]
    mm = np.repeat(m[free], 3)
    k = int(min(count, len(fd) - 2))
    w2, phi = eigsh(K, k=k, M=sp.diags(mm), sigma=0.0, which="LM")
    order = np.argsort(w2)
    w2, phi = w2[order], phi[:, order]
    v = phi.reshape(len(free), 3, -1)
    means = np.einsum("f,fik->ki", m[free], v) / np.sqrt(m[free].sum() * (mm[:, None] * phi ** 2).sum(axis=0))[:, None]
    return Modes(frequencies_hz=np.sqrt(np.maximum(w2, 0.0)) / (2.0 * math.pi), means=means)


def band(found: Modes) -> tuple[float, float]:
    """(f1, f2) Hz where the Rayleigh damping takes the material's ratio: the lowest mode and the sway, the second
    at least twice the first."""
    f1 = found.lowest_hz
    return f1, max(found.sway_hz, 2.0 * f1)


def rayleigh(zeta: float, f1: float, f2: float, shear_pa: float, dt: float | None = None,
             numerical: float = 0.0) -> tuple[float, float]:
    """(alpha 1/s, k_damp Pa s): zeta(omega) = alpha / (2 omega) + beta omega / 2 equal to `zeta` at f1 and f2 Hz,
    beta = 2 k_damp / shear_pa (VBD's tet damping, sim/fem/solve.py); with dt (seconds), the solver's own
    `numerical` omega dt (stiffness-like: beta 2 numerical dt) taken off beta (not below 0)."""
    w1, w2 = 2.0 * math.pi * f1, 2.0 * math.pi * f2
    alpha = 2.0 * zeta * w1 * w2 / (w1 + w2)
    beta = 2.0 * zeta / (w1 + w2)
    if dt is not None:
        beta = max(beta - 2.0 * numerical * dt, 0.0)
    return alpha, 0.5 * beta * shear_pa


__all__ = ["Modes", "stiffness", "modes", "band", "rayleigh"]
