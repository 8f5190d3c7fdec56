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

(T = min(t, 1); past the reach Phi grows by A (rho - 1) + A' (rho - 1)^2 / 2), so a swing that the linear
spring would carry to 1, 2, 3 or 4 reaches turns back at 0.73, 0.86, 0.94 and 1.0 R (kappa = k, undamped):
the reach is where the tissue is very stiff, not a wall. There is no projection and
no velocity removed: the energy a swing brings is stored and given back, and damping only takes it away.

Integration (sim/jiggle/solver.py, sim/jiggle/particle_kernels.py: tissue_near, tissue_substeps): a step whose offset stays
below SAFE x ONSET x R (the larger end plus a quarter step at the larger end speed: :func:`bound`) is the exact
linear flow, the same arithmetic as a model without the law. Otherwise the particle's goal part of
the step is split into n = 2^j equal substeps, each a half kick of the stiffening, the exact linear flow over
h / n and another half kick (Strang splitting: symmetric, second order, symplectic without damping); n is
the smallest power of two (at most 2^LEVELS) for which the stiffening's fastest frequency in the particle's
swing, sqrt(kappa (rho phi)'(rho_max)) with rho_max its turning point for the particle's energy, times h / n
is at most SUB_OMEGA (the linear part needs no substeps: its flow is exact; :func:`thresholds`).
The neighbour springs' kicks around it are unchanged.

The rows the kernels read, per particle and step length (:func:`rows`, ROW floats): the exact linear flow over
h (goal_flow.COEFFS); kappa, k and the energies from which each level is needed (:func:`thresholds`); the exact
flow over h / 2^j for j = 1..LEVELS.
"""
from __future__ import annotations

import math

import numpy as np

from jiggle.sim.jiggle.goal_flow import COEFFS, flow_numpy

ONSET = 0.5
"""rho below which the goal spring is exactly linear (the fraction of the reach)."""
GAIN = 64.0
"""A: phi at the reach (the stiffening force there is GAIN x kappa R, against k R of the linear spring)."""
K_FLOOR = (2.0 * math.pi * 3.0) ** 2
"""1/s^2: the smallest stiffening scale kappa, that of a 3 Hz spring: how stiff tissue is near its reach is
the tissue's, not the goal weight's (an artist's choice of how loosely a CV follows), so soft goals still stiffen."""
SAFE = 1.0
"""A step takes the sub-stepped path once its offset bound passes SAFE x ONSET x R."""
SUB_OMEGA = 0.25
"""The largest stiffest-frequency x substep of the sub-stepped path (stability ends at 2)."""
LEVELS = 6
"""The sub-stepped path takes at most 2^LEVELS substeps a step."""
STABLE = 1.0
"""The stiffening's largest frequency x substep at the finest level: a particle stiffer than it resolves (a goal
weight near 1 driven far past its reach) has its kappa lowered to it in those substeps, so the split stays
stable (below the finest level the energy thresholds keep the substeps within SUB_OMEGA)."""
NEAR = 0.9
"""rho from which a particle is "near its limit" (compare's near-limit fraction and the hard stops)."""
FAST = 0.1
"""A hard stop: a substep that ends near the limit in which the outward offset speed falls by more than
half without turning back, from a speed that would have covered FAST x R in the substep."""
BROAD = 1.5
"""Reaches from its goal within which the contacts' broad phase looks for a particle (sim/jiggle/colliders.py):
the law turns a swing that the linear spring would carry to 4 reaches back at 1.0 R; 1.5 R takes a goal
jerked faster still (a teleport, which cut detection glues through)."""
ROW = 2 * COEFFS + COEFFS * LEVELS
"""floats per particle in a tissue row: flow(h); kappa, k, the LEVELS energy thresholds (padded to COEFFS);
flow(h / 2^j) for j = 1..LEVELS."""


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


def thresholds(k: np.ndarray, h) -> np.ndarray:
    """(n, LEVELS) the energies per unit mass and reach^2 (1/s^2) from which the sub-stepped path takes 2^j
    substeps (column j - 1), for stiffness k (n,) 1/s^2 and step h seconds (a number or (n,)): level j is
    needed once the stiffening's frequency at the swing's turning point, sqrt(kappa (rho phi)'(rho_max)),
    times h exceeds SUB_OMEGA 2^(j - 1); rho_max is where the linear and stiffening potentials hold the
    particle's energy. Chosen from the energy, which a free swing keeps, the level holds through a whole
    swing, so the sub-stepped path stays a symplectic map (a level chosen from the position would change
    within a swing and let the energy drift). inf: never needed."""
    k = np.asarray(k, dtype=np.float64).reshape(-1)
    hh = np.broadcast_to(np.asarray(h, dtype=np.float64).reshape(-1), k.shape)
    kap = kappa(k)
    rho = np.linspace(ONSET, 1.0, 4097)
    tan = tangent(rho)                                                  # increasing from 0 to SLOPE
    out = np.full((len(k), LEVELS), np.inf)
    free = np.isfinite(k) & (kap > 0)
    for j in range(1, LEVELS + 1):
        need = np.zeros(len(k))
        with np.errstate(divide="ignore"):                 # h = 0 (knots 1e-12 s apart): no level is needed
            need[free] = (SUB_OMEGA * 2.0 ** (j - 1) / hh[free]) ** 2 / kap[free]   # the tangent that needs level j
        r = np.interp(need, tan, rho)
        e = 0.5 * np.where(free, k, 0.0) * r ** 2 + kap * potential(r)
        out[:, j - 1] = np.where(free & (need <= SLOPE), e, np.inf)
    return out


def level(row: np.ndarray, y: np.ndarray, u: np.ndarray, reach: np.ndarray) -> np.ndarray:
    """(n,) int: the sub-stepped path's j (2^j substeps) of particles at offsets y, u (n, 3), from their
    energy per unit mass and reach^2 against the row's thresholds (the kernels' tissue_level)."""
    row = np.asarray(row, dtype=np.float64)
    kap, k = row[:, COEFFS], row[:, COEFFS + 1]
    rho = np.linalg.norm(y, axis=1) / reach
    e = 0.5 * np.sum(u * u, axis=1) / reach ** 2 + 0.5 * k * rho ** 2 + kap * potential(rho)
    return np.sum(row[:, COEFFS + 2:COEFFS + 2 + LEVELS] <= e[:, None], axis=1)


def rows(k: np.ndarray, c: np.ndarray, h) -> np.ndarray:
    """(n, ROW) float64 tissue rows for stiffness k (n,) 1/s^2 (inf: glued), damping c (n,) 1/s and step h
    seconds, a number or one per row."""
    from jiggle.sim.jiggle.goal_flow import goal_flow_batch
    k = np.asarray(k, dtype=np.float64).reshape(-1)
    c = np.asarray(c, dtype=np.float64).reshape(-1)
    n = len(k)
    out = np.zeros((n, ROW))
    hh = np.broadcast_to(np.asarray(h, dtype=np.float64).reshape(-1), k.shape)
    # every level's flow in one batch: goal_flow_batch computes each distinct (k, c, h) once (a few dozen)
    scales = 2.0 ** np.arange(LEVELS + 1)
    flows = goal_flow_batch(np.tile(k, LEVELS + 1), np.tile(c, LEVELS + 1),
                            (hh[None, :] / scales[:, None]).reshape(-1)).reshape(LEVELS + 1, n, COEFFS)
    out[:, :COEFFS] = flows[0]
    out[:, COEFFS] = kappa(k)
    out[:, COEFFS + 1] = np.where(np.isfinite(k), k, 0.0)
    out[:, COEFFS + 2:COEFFS + 2 + LEVELS] = np.minimum(thresholds(k, hh), np.finfo(np.float32).max)
    out[:, 2 * COEFFS:] = flows[1:].transpose(1, 0, 2).reshape(n, LEVELS * COEFFS)
    return out


def split(rows_: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """What the kernels read of tissue rows (..., n, ROW), float32 in their layout: the exact flows over h
    (..., n, COEFFS) and the levels (..., LEVELS + 1, n, COEFFS), level j the flow over h / 2^j (level 0: kappa,
    k and the LEVELS energy thresholds)."""
    r = np.asarray(rows_, dtype=np.float64)
    lin = r[..., :COEFFS]
    lev = np.moveaxis(r[..., COEFFS:].reshape(r.shape[:-1] + (LEVELS + 1, COEFFS)), -2, -3)
    return np.ascontiguousarray(lin, dtype=np.float32), np.ascontiguousarray(lev, dtype=np.float32)


def bound(y0, u0, y1, u1, h: float) -> np.ndarray:
    """(n,) metres: the largest offset a step (y0, u0) -> (y1, u1) of h seconds may reach, as the kernels'
    tissue_near bounds it: the larger end plus a quarter step at the larger end speed."""
    return np.maximum(np.linalg.norm(y0, axis=1), np.linalg.norm(y1, axis=1)) + \
        0.25 * h * np.maximum(np.linalg.norm(u0, axis=1), np.linalg.norm(u1, axis=1))


# ------------------------------------------------------------------------------ the NumPy reference
def accel_numpy(y: np.ndarray, kap: np.ndarray, reach: np.ndarray) -> np.ndarray:
    """(n, 3) m/s^2: the stiffening's acceleration -kappa phi(|y| / R) y (the kernels' tissue_accel)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        rho = np.where(np.isfinite(reach), np.linalg.norm(y, axis=1) / reach, 0.0)
    return -(kap * phi(rho))[:, None] * y


def step_numpy(row: np.ndarray, y: np.ndarray, u: np.ndarray, b0, b1, b2, h: float, reach: np.ndarray):
    """The kernels' tissue_near and tissue_substeps in float64: (y, u, stops) after the goal part of a step of h seconds from
    offsets y, u (n, 3) under forcing b0 + b1 tau + b2 tau^2 ((n, 3) each); row (n, ROW) tissue rows, reach
    (n,) metres (inf: no limit); stops (n,) int, the hard stops of :func:`hard_stop_numpy`."""
    row = np.asarray(row, dtype=np.float64)
    y, u = np.asarray(y, dtype=np.float64), np.asarray(u, dtype=np.float64)
    b0, b1, b2 = (np.broadcast_to(np.asarray(b, dtype=np.float64), y.shape) for b in (b0, b1, b2))
    y1, u1 = flow_numpy(row[:, :COEFFS], y, u, b0, b1, b2)
    kap = row[:, COEFFS]
    stops = np.zeros(len(y), np.int64)
    big = bound(y, u, y1, u1, h)
    with np.errstate(invalid="ignore"):
        sub = (kap > 0) & np.isfinite(reach) & (big > SAFE * ONSET * reach)
    for i in np.flatnonzero(sub):
        j = int(level(row[i:i + 1], y[i:i + 1], u[i:i + 1], reach[i:i + 1])[0])
        n = 2 ** j
        hs = h / n
        kap_i = np.minimum(kap[i:i + 1], STABLE ** 2 / (hs * hs * SLOPE)) if j == LEVELS else kap[i:i + 1]
        ys, us = y[i:i + 1], u[i:i + 1]
        fl = row[i:i + 1, :COEFFS] if j == 0 else row[i:i + 1, 2 * COEFFS + COEFFS * (j - 1):2 * COEFFS + COEFFS * j]
        for m in range(n):
            tau = hs * m
            c0 = b0[i] + tau * (b1[i] + tau * b2[i])
            c1 = b1[i] + 2.0 * tau * b2[i]
            u_in = us
            us = us + 0.5 * hs * accel_numpy(ys, kap_i, reach[i:i + 1])
            yn, un = flow_numpy(fl, ys, us, c0[None], c1[None], b2[i][None])
            un = un + 0.5 * hs * accel_numpy(yn, kap_i, reach[i:i + 1])
            stops[i] += int(hard_stop_numpy(ys, u_in, yn, un, reach[i:i + 1], hs)[0])
            ys, us = yn, un
        y1[i], u1[i] = ys[0], us[0]
    return y1, u1, stops


def hard_stop_numpy(y0, u0, y1, u1, reach, h) -> np.ndarray:
    """(n,) bool: substeps (y0, u0) -> (y1, u1) of h seconds that end near the limit (|y1| >= NEAR R) with
    the outward offset speed fallen by more than half and not turned back (by more than 1% of it: a wall
    leaves it at 0, to round-off), from a speed that would have
    covered FAST x R in the substep: the signature of a wall (a smooth turn, resolved by the substeps,
    takes many substeps to lose half its speed)."""
    n0, n1 = np.linalg.norm(y0, axis=1), np.linalg.norm(y1, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        v0 = np.where(n0 > 0, np.sum(u0 * y0, axis=1) / n0, 0.0)
        v1 = np.where(n1 > 0, np.sum(u1 * y1, axis=1) / n1, 0.0)
    return (n1 >= NEAR * reach) & (v0 * h > FAST * reach) & (v1 >= -0.01 * v0) & (v1 < 0.5 * v0)


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
