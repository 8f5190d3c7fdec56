"""The exact update of a particle's goal spring over one step, for any step length.

For the offset y = x - g of a particle from its goal and u = y', the goal spring, its damping and the
drag give the linear ODE (per unit mass, per axis)

    y'' + c y' + k y = F(tau),   F(tau) = b0 + b1 tau + b2 tau^2,   tau in [0, h]

with k = omega^2 (1/s^2), c = 2 zeta omega + mu (1/s), and F collecting gravity, the goal's
acceleration (linear in tau: the goal path is a cubic in each knot interval) and the drag's pull
toward the goal's velocity (quadratic). Its solution is exact for every h:

    [y, u](h) = E [y, u](0) + Q [b0, b1, b2]

where E = exp(A h) with A = [[0, 1], [-k, -c]] and Q = int_0^h exp(A (h - tau)) [0, 1]^T [1, tau, tau^2]
d tau, both read off the exponential of one 5x5 augmented matrix (Van Loan): the forcing's own
state (1, tau, tau^2 / 2) is appended to (y, u). k = c = 0 gives free flight (y = y0 + u0 h + b0
h^2 / 2 ...) from the same formula, so free fall needs no special case. k = inf (a glued particle)
gives E = Q = 0: the offset stays exactly zero.

The step of a neighbour spring system around this exact flow is in sim/jiggle/solver.py.
"""
from __future__ import annotations

import numpy as np
from scipy.linalg import expm

COEFFS = 10
"""Per particle: E00, E01, E10, E11, Q00, Q01, Q02, Q10, Q11, Q12 (row-major E, then Q)."""


def goal_flow(k: np.ndarray, c: np.ndarray, h: float) -> np.ndarray:
    """Exact flow coefficients (n, 10) float64 of the goal ODE over a step h > 0 seconds.

    k : (n,) 1/s^2 stiffness per unit mass (inf: glued); c : (n,) 1/s damping per unit mass.
    """
    k = np.asarray(k, dtype=np.float64)
    c = np.asarray(c, dtype=np.float64)
    out = np.zeros((k.size, COEFFS))
    free = np.isfinite(k)
    if not free.any():
        return out
    # few distinct (k, c) pairs in practice: one exponential each
    pairs, inverse = np.unique(np.stack([k[free], c[free]], axis=1), axis=0, return_inverse=True)
    n = len(pairs)
    a = np.zeros((n, 5, 5))
    a[:, 0, 1] = 1.0
    a[:, 1, 0] = -pairs[:, 0]
    a[:, 1, 1] = -pairs[:, 1]
    a[:, 1, 2] = 1.0            # u' += e0
    a[:, 2, 3] = 1.0            # e0' = e1
    a[:, 3, 4] = 1.0            # e1' = e2
    f = expm(a * h)
    coeffs = np.empty((n, COEFFS))
    coeffs[:, 0:4] = f[:, 0:2, 0:2].reshape(n, 4)
    # e(0) = (b0, b1, 2 b2) makes e0(tau) = b0 + b1 tau + b2 tau^2: fold the 2 into Q's last column
    q = f[:, 0:2, 2:5] * np.array([1.0, 1.0, 2.0])
    coeffs[:, 4:10] = q.reshape(n, 6)
    out[free] = coeffs[inverse.reshape(-1)]
    return out


def flow_numpy(coeffs: np.ndarray, y: np.ndarray, u: np.ndarray, b0: np.ndarray, b1: np.ndarray,
               b2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Apply coefficients (n, 10) to offsets y, u (n, 3) under forcing b0, b1, b2 (n, 3): (y, u) at h."""
    e = coeffs[:, :, None]
    y1 = e[:, 0] * y + e[:, 1] * u + e[:, 4] * b0 + e[:, 5] * b1 + e[:, 6] * b2
    u1 = e[:, 2] * y + e[:, 3] * u + e[:, 7] * b0 + e[:, 8] * b1 + e[:, 9] * b2
    return y1, u1
