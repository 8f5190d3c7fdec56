"""A working muscle's bulge: contraction shortens the belly and keeps its volume, so the belly thickens.

At a joint angle the pose sets, a muscle-tendon unit has a length; a contracting muscle pulls on its tendons, which
stretch, and its fibres shorten by as much: the belly shortens at a fixed origin-to-insertion length and, its volume
kept, grows thicker (the biceps' bulge as the arm holds a weight; the quadriceps' at a landing). Ultrasound of
contracting muscle finds the fascicles shortening by a tenth or more under a strong isometric effort, as the
tendon stretches (Ito et al. 1998, J Physiol 507:2: the tibialis anterior's fascicles 13% shorter at its greatest
voluntary effort; Narici et al. 1996, J Physiol 496:1: the gastrocnemius' up to a third).

The rule, on a fitted muscle's 5 sections of 8 CVs (rig.muscle.model: section 0 and 4 its tendon ends, 1-3 its
belly), with a belly strain eps = BULGE_STRAIN x activation (0 to 1):

- sections 1 and 3 move toward section 2 along the belly by eps of their distance to it: the belly (1 to 3)
  shortens by eps, the tendon ends (0 to 1, 3 to 4) lengthen by as much;
- sections 1, 2 and 3 grow about their centres by the factor that keeps the lofted muscle's volume (loft.volume:
  a few secant steps from 1 / sqrt(1 - eps), the factor of a cylinder's belly; the loft's smooth surface through
  all five sections makes it less: the tendon ends that lengthen hold some of the volume).

The action curve's points 1 and 3 move with their sections. A muscle at rest (activation 0) is left as it is, bit
for bit. Fat is never activated and never bulges.
"""
from __future__ import annotations

import numpy as np

from jiggle.rig.muscle import loft

BULGE_STRAIN = 0.2
"""The belly's shortening at full activation, between the tibialis anterior's 13% and the gastrocnemius' third
(see the module): a lofted belly ~7% wider at the middle."""
GROWTH_STEPS = 3
"""Secant steps on the belly's growth: the lofted volume kept within ~1e-6 of the muscle's."""
TABLE_LEVELS = 11
"""growth_table's strains: every 10% of BULGE_STRAIN (the growth is smooth in the strain: read linearly between
them, a posed muscle's volume holds within 0.2%)."""
SECTIONS, RING = 5, 8


def growths(rings: np.ndarray, eps: np.ndarray) -> np.ndarray:
    """(n,) the growth of sections 1-3 that keeps the lofted volume of each muscle's rings (n, 5, 8, 3) metres when
    its belly shortens by eps (n,) (see the module: secant steps from a cylinder's 1 / sqrt(1 - eps))."""
    centres = rings.mean(axis=2)
    target = loft.volume(rings)
    shift = _shift(centres, eps)

    def volume(grow):
        return loft.volume(_shaped(rings, centres, shift, grow)) - target
    g0, g1 = np.ones_like(eps), 1.0 / np.sqrt(1.0 - eps)
    v0, v1 = volume(g0), volume(g1)
    for _ in range(GROWTH_STEPS):
        slope = np.where(np.abs(v1 - v0) > 1e-300, (v1 - v0) / np.where(g1 != g0, g1 - g0, 1.0), 1.0)
        g2 = np.where(np.abs(v1) > 0.0, g1 - v1 / slope, g1)
        g0, v0, g1 = g1, v1, np.clip(g2, 1.0, 2.0)
        v1 = volume(g1)
    return g1


def growth_table(rest_cvs: np.ndarray, strain: float = BULGE_STRAIN, levels: int = TABLE_LEVELS,
                 working: np.ndarray | None = None) -> np.ndarray:
    """(M, levels) each muscle's growth (growths) on its rest shape (rest CVs (M * 40, 3) metres) at belly strains
    strain x linspace(0, 1, levels): what bulged reads for a posed shape instead of solving it again, frame after
    frame (a posed muscle keeps its volume: its growth for a strain is its rest shape's within ~1e-3). working :
    (M,) bool, the muscles to solve for (None: all); the others' rows are 1."""
    rings = np.asarray(rest_cvs, np.float64).reshape(-1, SECTIONS, RING, 3)
    M = len(rings)
    out = np.ones((M, levels))
    use = np.arange(M) if working is None else np.flatnonzero(working)
    if len(use):
        eps = strain * np.linspace(0.0, 1.0, levels)
        out[use] = growths(np.repeat(rings[use], levels, axis=0), np.tile(eps, len(use))).reshape(len(use), levels)
    return out


def _shift(centres: np.ndarray, eps: np.ndarray) -> np.ndarray:
    """(n, 5, 3): sections 1-3 moved toward the belly's middle by eps (n,) of their distance to it; the ends stay."""
    shift = -eps[:, None, None] * (centres - centres[:, 2:3])
    shift[:, [0, 4]] = 0.0
    return shift


def _shaped(rings: np.ndarray, centres: np.ndarray, shift: np.ndarray, grow: np.ndarray) -> np.ndarray:
    out = rings.copy()
    for k in (1, 2, 3):
        out[:, k] = (centres[:, k] + shift[:, k])[:, None] + grow[:, None, None] * (rings[:, k] - centres[:, k][:, None])
    return out


def bulged(cvs: np.ndarray, curve: np.ndarray, activation: np.ndarray, strain: float = BULGE_STRAIN,
           table: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(cvs, curve) of static shapes with each muscle bulged by its activation (see the module): cvs (T, M * 40, 3)
    and curve (T, M, 5, 3) metres, activation (T, M) in [0, 1]. table : growth_table of the rig's rest shapes (the
    growth read from it, linear between its levels), or None (solved for each frame's shape). New arrays; frames and
    muscles at 0 unchanged."""
    cvs = np.array(cvs, dtype=np.float64, copy=True)
    curve = np.array(curve, dtype=np.float64, copy=True)
    a = np.clip(np.asarray(activation, np.float64), 0.0, 1.0)
    T, M = a.shape
    c = cvs.reshape(T, M, SECTIONS, RING, 3)
    t, m = np.nonzero(a > 0.0)
    if not len(t):
        return cvs, curve
    eps = strain * a[t, m]                                               # (n,)
    rings = c[t, m]                                                      # (n, 5, 8, 3)
    if table is None:
        grow = growths(rings, eps)
    else:
        x = a[t, m] * (table.shape[1] - 1)
        i = np.minimum(x.astype(np.int64), table.shape[1] - 2)
        grow = table[m, i] + (x - i) * (table[m, i + 1] - table[m, i])
    centres = rings.mean(axis=2)
    shift = _shift(centres, eps)
    c[t, m] = _shaped(rings, centres, shift, grow)
    curve[t, m, 1] += shift[:, 1]
    curve[t, m, 3] += shift[:, 3]
    return c.reshape(cvs.shape), curve


__all__ = ["BULGE_STRAIN", "bulged", "growths", "growth_table"]
