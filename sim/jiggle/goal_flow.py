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


# --------------------------------------------------------------------------------------- batched expm
_PADE13 = (64764752532480000.0, 32382376266240000.0, 7771770303897600.0, 1187353796428800.0,
           129060195264000.0, 10559470521600.0, 670442572800.0, 33522128640.0, 1323241920.0, 40840800.0,
           960960.0, 16380.0, 182.0, 1.0)
_THETA13 = 5.371920351148152


def expm_batch(a: np.ndarray) -> np.ndarray:
    """exp of each matrix of a (n, d, d) float64: scaling and squaring with the degree 13 Pade
    approximant (Higham 2005, the s chosen per matrix from its 1-norm), vectorised over the batch. Agrees
    with scipy.linalg.expm to ~1e-15 relative on the goal flow's matrices (tests/jiggle/test_keyed.py)."""
    a = np.asarray(a, dtype=np.float64)
    n, d, _ = a.shape
    if n == 0:
        return a.copy()
    norm = np.abs(a).sum(axis=1).max(axis=1)
    s = np.maximum(0, np.ceil(np.log2(np.maximum(norm, 1e-300) / _THETA13))).astype(np.int64)
    a = a / (2.0 ** s)[:, None, None]
    b = _PADE13
    eye = np.broadcast_to(np.eye(d), a.shape)
    a2 = a @ a
    a4 = a2 @ a2
    a6 = a4 @ a2
    u = a @ (a6 @ (b[13] * a6 + b[11] * a4 + b[9] * a2) + b[7] * a6 + b[5] * a4 + b[3] * a2 + b[1] * eye)
    v = a6 @ (b[12] * a6 + b[10] * a4 + b[8] * a2) + b[6] * a6 + b[4] * a4 + b[2] * a2 + b[0] * eye
    r = np.linalg.solve(v - u, v + u)
    for k in range(int(s.max()) if n else 0):
        sq = s > k
        r[sq] = r[sq] @ r[sq]
    return r


def goal_flow_batch(k: np.ndarray, c: np.ndarray, h: np.ndarray) -> np.ndarray:
    """sim.jiggle.goal_flow.goal_flow for a (k, c, h) per row: (n, 10) float64 coefficients of the goal ODE
    over steps h (n,) seconds for stiffness k (n,) 1/s^2 (inf: glued, all zero) and damping c (n,) 1/s."""
    k, c, h = (np.asarray(x, dtype=np.float64).reshape(-1) for x in (k, c, h))
    out = np.zeros((len(k), COEFFS))
    free = np.isfinite(k)
    if not free.any():
        return out
    # distinct (k, c, h) rows through 1-D codes: np.unique(axis=0) sorts rows as records, ~100x slower
    key = np.zeros(int(free.sum()), np.int64)
    for x in (k[free], c[free], h[free]):
        values, code = np.unique(x, return_inverse=True)
        key = key * len(values) + code.reshape(-1)
    _, first, inverse = np.unique(key, return_index=True, return_inverse=True)
    trip = np.stack([k[free], c[free], h[free]], axis=1)[first]
    n = len(trip)
    a = np.zeros((n, 5, 5))
    a[:, 0, 1] = 1.0
    a[:, 1, 0] = -trip[:, 0]
    a[:, 1, 1] = -trip[:, 1]
    a[:, 1, 2] = 1.0
    a[:, 2, 3] = 1.0
    a[:, 3, 4] = 1.0
    f = expm_batch(a * trip[:, 2, None, None])
    coeffs = np.empty((n, COEFFS))
    coeffs[:, 0:4] = f[:, 0:2, 0:2].reshape(n, 4)
    coeffs[:, 4:10] = (f[:, 0:2, 2:5] * np.array([1.0, 1.0, 2.0])).reshape(n, 6)
    out[free] = coeffs[inverse.reshape(-1)]
    return out
