"""The tissue law: a goal spring that stiffens as the offset grows, so a particle slows down smoothly
as it nears its reach instead of stopping dead there.

Soft tissue is strain-stiffening (Fung, "Biomechanics: Mechanical Properties of Living Tissues", 1993:
skin, fat and muscle stiffen roughly exponentially with strain). Per unit mass, with the offset
y = x - g from the goal, r = |y|, the particle's reach R and rho = r / R::

    a_goal = -k y - kappa phi(rho) y,      phi(rho) = A t^3,  t = max(rho - ONSET, 0) / (1 - ONSET)   (rho <= 1)

and past the reach (rho > 1, only ever met under violent driving) the stiffening force grows on in a
straight line, rho phi(rho) = A + A' (rho - 1) with A' = (rho phi)'(1) = A (1 + 3 / (1 - ONSET)): the force
and its stiffness are continuous there, and the stiffness never exceeds its value at the reach, so the
substeps that resolve the reach (below) are stable at any offset.

k = omega^2 is the linear goal spring (sim/jiggle/params.py), kappa = max(k, K_FLOOR) its stiffening
scale (a particle with a soft or no goal spring still stiffens like a K_FLOOR spring near its reach).
Below ONSET x R the law is exactly the linear spring, so every tuning made before, and the thesis's
parameters, keep their meaning; above it the stiffness grows smoothly (phi, phi' and phi'' are 0 at the
onset: the force is C^2) and without end. Its potential per unit mass is

    U(r) = k r^2 / 2 + kappa R^2 Phi(rho),   Phi(rho) = A (1 - ONSET) (ONSET T^4 / 4 + (1 - ONSET) T^5 / 5)

so a swing that the linear spring would carry to 1, 2 or 3 reaches turns back at 0.67, 0.85 and 0.96 R
(GAIN = 32, undamped): the reach is where the tissue is very stiff, not a wall. There is no projection and
no velocity removed: the energy a swing brings is stored and given back, and damping only takes it away.

Integration (sim/jiggle/solver.py, sim/jiggle/particle_kernels.py: tissue_flow): a step whose linear flow keeps the offset's
energy amplitude sqrt(|y|^2 + |u|^2 / kappa) below SAFE x ONSET x R at both ends is the exact linear flow,
the same arithmetic as a model without the law; otherwise the particle's goal part of the step is split
into n equal substeps, each a half kick of the stiffening force, the exact linear flow over h / n, and
another half kick (Strang splitting: symmetric, second order, symplectic without damping), with n the
smallest power of two that keeps the stiffest frequency at the reach, sqrt(k + kappa (phi + rho phi')(1)),
times h / n at most SUB_OMEGA. The neighbour springs' kicks around it are unchanged.

The flow rows the kernels read (ROW floats per particle and step length): the exact flow over h
(goal_flow.COEFFS), the exact flow over h / n, n, kappa.
"""
from __future__ import annotations

import math

import numpy as np

from sim.jiggle.goal_flow import COEFFS, flow_numpy

ONSET = 0.3
"""rho below which the goal spring is exactly linear (the fraction of the reach)."""
GAIN = 32.0
"""A: phi at the reach (the stiffening force there is GAIN x kappa R, against k R of the linear spring)."""
K_FLOOR = (2.0 * math.pi * 3.0) ** 2
"""1/s^2: the smallest stiffening scale kappa, that of a 3 Hz spring: how stiff tissue is near its reach is
the tissue's, not the goal weight's (an artist's choice of how loosely a CV follows), so soft goals still stiffen."""
SAFE = 0.9
"""A step takes the sub-stepped path once its energy amplitude passes SAFE x ONSET x R."""
SUB_OMEGA = 0.1
"""The largest stiffest-frequency x substep of the sub-stepped path (stability ends at 2)."""
MAX_SUBSTEPS = 256
NEAR = 0.9
"""rho from which a particle is "near its limit" (compare's near-limit fraction and the hard stops)."""
FAST = 0.1
"""A hard stop: a substep that ends near the limit in which the outward offset speed falls by more than
half without turning back, from a speed that would have covered FAST x R in the substep."""
ROW = 2 * COEFFS + 2
"""floats per particle in a tissue flow row: flow(h), flow(h / n), n, kappa."""


SLOPE = GAIN * (1.0 + 3.0 / (1.0 - ONSET))
"""A' = (rho phi)'(1): the stiffening's radial stiffness at the reach and beyond, in units of kappa."""


def phi(rho: np.ndarray) -> np.ndarray:
    """The stiffening phi(rho) >= 0 (0 below ONSET; past the reach, (A + A' (rho - 1)) / rho)."""
    rho = np.asarray(rho, dtype=np.float64)
    t = np.clip(rho - ONSET, 0.0, 1.0 - ONSET) / (1.0 - ONSET)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(rho <= 1.0, GAIN * t ** 3, (GAIN + SLOPE * (rho - 1.0)) / rho)


def tangent(rho: np.ndarray) -> np.ndarray:
    """(rho phi)'(rho): the stiffening's share of the radial tangent stiffness, in units of kappa (SLOPE
    from the reach on: its largest)."""
    rho = np.asarray(rho, dtype=np.float64)
    t = np.clip(rho - ONSET, 0.0, 1.0 - ONSET) / (1.0 - ONSET)
    return np.where(rho <= 1.0, GAIN * (t ** 3 + rho * 3.0 * t ** 2 / (1.0 - ONSET)), SLOPE)


def potential(rho: np.ndarray) -> np.ndarray:
    """Phi(rho) = int_0^rho s phi(s) ds: the stiffening's potential per unit mass in units of kappa R^2."""
    rho = np.asarray(rho, dtype=np.float64)
    T = np.clip(rho - ONSET, 0.0, 1.0 - ONSET) / (1.0 - ONSET)
    inside = GAIN * (1.0 - ONSET) * (ONSET * T ** 4 / 4.0 + (1.0 - ONSET) * T ** 5 / 5.0)
    past = np.maximum(rho - 1.0, 0.0)
    return inside + GAIN * past + 0.5 * SLOPE * past ** 2


def energy_numpy(y: np.ndarray, u: np.ndarray, k: np.ndarray, reach: np.ndarray) -> np.ndarray:
    """(n,) J/kg: each particle's goal-frame energy per unit mass under the tissue law,
    |u|^2 / 2 + k |y|^2 / 2 + kappa R^2 Phi(|y| / R) (glued particles 0)."""
    k = np.asarray(k, dtype=np.float64)
    free = np.isfinite(k)
    r = np.linalg.norm(y, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        stiff = np.where(np.isfinite(reach), kappa(k) * reach ** 2 * potential(np.where(np.isfinite(reach), r / reach, 0.0)), 0.0)
    e = 0.5 * np.sum(u * u, axis=1) + 0.5 * np.where(free, k, 0.0) * r ** 2 + stiff
    return np.where(free, e, 0.0)


def kappa(k: np.ndarray) -> np.ndarray:
    """(n,) 1/s^2: the stiffening scale max(k, K_FLOOR); 0 for glued particles (k = inf)."""
    k = np.asarray(k, dtype=np.float64)
    return np.where(np.isfinite(k), np.maximum(k, K_FLOOR), 0.0)


def substeps(k: np.ndarray, h: np.ndarray) -> np.ndarray:
    """(n,) int: the sub-stepped path's n for stiffness k (1/s^2) and step h (seconds): a power of two,
    SUB_OMEGA >= sqrt(k + kappa tangent(1)) h / n, at most MAX_SUBSTEPS."""
    k = np.asarray(k, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        w = np.sqrt(np.where(np.isfinite(k), k + kappa(k) * float(tangent(1.0)), 0.0)) * np.asarray(h)
    n = np.exp2(np.ceil(np.log2(np.maximum(w / SUB_OMEGA, 1.0))))
    return np.minimum(n, MAX_SUBSTEPS).astype(np.int64)


def rows(k: np.ndarray, c: np.ndarray, h) -> np.ndarray:
    """(n, ROW) float64 tissue flow rows for stiffness k (n,) 1/s^2 (inf: glued), damping c (n,) 1/s and
    step h seconds: a number (goal_flow.goal_flow per distinct (k, c, n)) or one per row
    (keyed.goal_flow_batch)."""
    from sim.jiggle.goal_flow import goal_flow
    from sim.jiggle.keyed import goal_flow_batch
    k = np.asarray(k, dtype=np.float64).reshape(-1)
    c = np.asarray(c, dtype=np.float64).reshape(-1)
    out = np.empty((len(k), ROW))
    if np.ndim(h) == 0:
        out[:, :COEFFS] = goal_flow(k, c, float(h))
        n = substeps(k, float(h))
        for m in np.unique(n):
            sel = n == m
            out[sel, COEFFS:2 * COEFFS] = goal_flow(k[sel], c[sel], float(h) / float(m))
    else:
        hh = np.asarray(h, dtype=np.float64).reshape(-1)
        out[:, :COEFFS] = goal_flow_batch(k, c, hh)
        n = substeps(k, hh)
        out[:, COEFFS:2 * COEFFS] = goal_flow_batch(k, c, hh / n)
    out[:, 2 * COEFFS] = n
    out[:, 2 * COEFFS + 1] = kappa(k)
    return out


# ------------------------------------------------------------------------------ the NumPy reference
def accel_numpy(y: np.ndarray, kap: np.ndarray, reach: np.ndarray) -> np.ndarray:
    """(n, 3) m/s^2: the stiffening's acceleration -kappa phi(|y| / R) y (the kernels' tissue_accel)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        rho = np.where(np.isfinite(reach), np.linalg.norm(y, axis=1) / reach, 0.0)
    return -(kap * phi(rho))[:, None] * y


def step_numpy(row: np.ndarray, y: np.ndarray, u: np.ndarray, b0, b1, b2, h: float, reach: np.ndarray):
    """The kernels' tissue_flow in float64: (y, u, stops) after the goal part of a step of h seconds from
    offsets y, u (n, 3) under forcing b0 + b1 tau + b2 tau^2 ((n, 3) each); row (n, ROW), reach (n,) metres
    (inf: no limit); stops (n,) int, the hard stops of :func:`hard_stop_numpy`."""
    row = np.asarray(row, dtype=np.float64)
    b0, b1, b2 = (np.broadcast_to(np.asarray(b, dtype=np.float64), y.shape) for b in (b0, b1, b2))
    y1, u1 = flow_numpy(row[:, :COEFFS], y, u, b0, b1, b2)
    kap = row[:, 2 * COEFFS + 1]
    stops = np.zeros(len(y), np.int64)
    with np.errstate(divide="ignore", invalid="ignore"):
        lim = (SAFE * ONSET * reach) ** 2
        amp = lambda a, b: np.sum(a * a, axis=1) + np.where(kap > 0, np.sum(b * b, axis=1) / kap, 0.0)  # noqa: E731
        sub = (kap > 0) & np.isfinite(reach) & (np.maximum(amp(y, u), amp(y1, u1)) > lim)
    for i in np.flatnonzero(sub):
        n = int(row[i, 2 * COEFFS])
        hs = h / n
        ys, us = y[i:i + 1], u[i:i + 1]
        fl = row[i:i + 1, COEFFS:2 * COEFFS]
        for j in range(n):
            tau = hs * j
            c0 = b0[i] + tau * (b1[i] + tau * b2[i])
            c1 = b1[i] + 2.0 * tau * b2[i]
            u_in = us
            us = us + 0.5 * hs * accel_numpy(ys, kap[i:i + 1], reach[i:i + 1])
            yn, un = flow_numpy(fl, ys, us, c0[None], c1[None], b2[i][None])
            un = un + 0.5 * hs * accel_numpy(yn, kap[i:i + 1], reach[i:i + 1])
            stops[i] += int(hard_stop_numpy(ys, u_in, yn, un, reach[i:i + 1], hs)[0])
            ys, us = yn, un
        y1[i], u1[i] = ys[0], us[0]
    return y1, u1, stops


def hard_stop_numpy(y0, u0, y1, u1, reach, h) -> np.ndarray:
    """(n,) bool: substeps (y0, u0) -> (y1, u1) of h seconds that end near the limit (|y1| >= NEAR R) with
    the outward offset speed fallen by more than half and not turned back, from a speed that would have
    covered FAST x R in the substep: the signature of a wall (a smooth turn, resolved by the substeps,
    takes many substeps to lose half its speed)."""
    n0, n1 = np.linalg.norm(y0, axis=1), np.linalg.norm(y1, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        v0 = np.where(n0 > 0, np.sum(u0 * y0, axis=1) / n0, 0.0)
        v1 = np.where(n1 > 0, np.sum(u1 * y1, axis=1) / n1, 0.0)
    return (n1 >= NEAR * reach) & (v0 * h > FAST * reach) & (v1 >= 0.0) & (v1 < 0.5 * v0)


def equilibrium_numpy(y_lin: np.ndarray, k: np.ndarray, reach: np.ndarray) -> np.ndarray:
    """(n, 3) the quasi-static offsets under the tissue law that carry the same goal force as the linear
    spring's offsets y_lin (n, 3): along y_lin, |y| solving k |y| + kappa phi(|y| / R) |y| = k |y_lin|
    (monotone in |y|: bisection), below the reach whatever the force."""
    y_lin = np.asarray(y_lin, dtype=np.float64)
    r_lin = np.linalg.norm(y_lin, axis=1)
    kap = kappa(k)
    ok = np.isfinite(reach) & np.isfinite(k) & (r_lin > ONSET * np.where(np.isfinite(reach), reach, np.inf))
    if not ok.any():
        return y_lin
    kk, kp, R, target = np.asarray(k)[ok], kap[ok], np.asarray(reach)[ok], (np.asarray(k) * r_lin)[ok]
    lo, hi = np.zeros(ok.sum()), np.minimum(r_lin[ok], R * 2.0)
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        f = kk * mid + kp * phi(mid / R) * mid
        below = f < target
        lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
    out = y_lin.copy()
    out[ok] *= (0.5 * (lo + hi) / r_lin[ok])[:, None]
    return out
