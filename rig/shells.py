"""Shell deformer parameters (Pratscher et al. 2005, sections 4.2 and 4.3).

One deformer per muscle. In the muscle's local space (its ellipsoid E is the unit sphere at the
origin, p_l = E^-1 p) there are three shells: the sticky shell of radius 1 + (1 - s) d toward which
points deform, the hard shell 1 + h d and the drop-off shell 1 + d (d in local units: multiples of
the muscle's radius in that direction).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import InputError

STAR_THETA = 17
"""Star table rows: polar angles theta_i = pi i / 16, i = 0..16, about the local +z axis."""
STAR_PHI = 32
"""Star table columns: azimuths phi_j = -pi + 2 pi j / 32, j = 0..31 (periodic)."""
TRAJECTORY_SAMPLES = 9
"""K: samples c(u_k), u_k = k / (K - 1), of a muscle's trajectory curve per frame."""

MODES = ("basic", "stretch", "trajectory")
"""How a deformed local point returns to world space: through the muscle's current ellipsoid alone
(basic), blended from its rest ellipsoid to its current one (stretch), or along a curve between the
two centres (trajectory)."""


@dataclass(frozen=True)
class ShellParams:
    """One muscle's deformer.

    sticky : s in [0, 1]; the sticky shell has radius 1 + (1 - s) d (1: the muscle's surface).
    hard : h in [0, 1]; full deformation inside radius 1 + h d.
    drop_off : d > 0, local units; nothing moves beyond radius 1 + d.
    weight : w in [0, 1], the overall weight (the per-vertex painted weight w_i multiplies it).
    slippage : l >= 0, the exponent on the stretch fall-off alpha(r)^l.
    mode : one of MODES.
    """

    sticky: float = 1.0
    hard: float = 0.5
    drop_off: float = 1.0
    weight: float = 1.0
    slippage: float = 1.0
    mode: str = "stretch"

    def __post_init__(self):
        for k in ("sticky", "hard", "drop_off", "weight", "slippage"):
            v = getattr(self, k)
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise InputError(f"expected a number, got {v!r}", field=k)
            object.__setattr__(self, k, float(v))
        check_params(self.sticky, self.hard, self.drop_off, self.weight, self.slippage, self.mode)


def check_params(sticky, hard, drop_off, weight, slippage, mode, where: str = "") -> None:
    """Raise InputError naming the parameter (prefixed by `where`, e.g. a muscle's name) when a
    value is out of range: s, h, w in [0, 1], d > 0 (and finite), l >= 0 (and finite)."""
    import math

    def bad(field, msg):
        raise InputError(msg, field=f"{where}.{field}" if where else field)

    for field, v in (("sticky", sticky), ("hard", hard), ("weight", weight)):
        if not 0.0 <= v <= 1.0:
            bad(field, f"expected a value in [0, 1], got {v}")
    if not (math.isfinite(drop_off) and drop_off > 0.0):
        bad("drop_off", f"expected a finite value > 0 (local units of the muscle's radius), got {drop_off}")
    if not (math.isfinite(slippage) and slippage >= 0.0):
        bad("slippage", f"expected a finite value >= 0, got {slippage}")
    if mode not in MODES:
        bad("mode", f"expected one of {', '.join(MODES)}, got {mode!r}")


MUSCLE_SHELL = ShellParams()
"""Muscles: the skin rides the muscle surface under it (s = 1), fully within half a radius of it
(h = 0.5), fading out one radius away (d = 1)."""
FAT_SHELL = ShellParams(drop_off=0.75)
"""Fat lies at the skin: its influence fades out sooner."""


def default_shell(kind: str) -> ShellParams:
    """The deformer a muscle of this kind gets when its template gives none."""
    return FAT_SHELL if kind == "fat" else MUSCLE_SHELL


@dataclass(frozen=True)
class ShellFrames:
    """One frame's ellipsoids of all M muscles (the per-frame state of the shell deformer).

    E_ref : (M, 4, 4) float64, the rest ellipsoid carried rigidly by the muscle's bone
        (local unit sphere -> world, column vectors, metres).
    E_ref_inv : (M, 4, 4) float64, its inverse.
    E_cur : (M, 4, 4) float64, the ellipsoid fitted to the muscle's current CVs.
    E_cur_inv : (M, 4, 4) float64, its inverse.
    curve : (M, K, 3) float64, metres: trajectory samples c(u_k), u_k = k / (K - 1), with c(0) the
        centre of E_ref and c(1) the centre of E_cur.
    active : (M,) bool; False: the muscle is skipped this frame (it contributes nothing).

    Arrays are converted (not copied when already of the right dtype) and their shapes checked;
    a mismatch raises InputError naming the field.
    """

    E_ref: np.ndarray
    E_ref_inv: np.ndarray
    E_cur: np.ndarray
    E_cur_inv: np.ndarray
    curve: np.ndarray
    active: np.ndarray

    def __post_init__(self):
        M = None
        for k in ("E_ref", "E_ref_inv", "E_cur", "E_cur_inv"):
            a = np.asarray(getattr(self, k), dtype=np.float64)
            if a.ndim != 3 or a.shape[1:] != (4, 4):
                raise InputError(f"expected shape (M, 4, 4), got {a.shape}", field=k)
            if M is None:
                M = a.shape[0]
            elif a.shape[0] != M:
                raise InputError(f"expected {M} matrices (as E_ref), got {a.shape[0]}", field=k)
            object.__setattr__(self, k, a)
        curve = np.asarray(self.curve, dtype=np.float64)
        if curve.ndim != 3 or curve.shape[0] != M or curve.shape[2] != 3 or curve.shape[1] < 2:
            raise InputError(f"expected shape ({M}, K >= 2, 3), got {curve.shape}", field="curve")
        object.__setattr__(self, "curve", curve)
        active = np.asarray(self.active)
        if active.shape != (M,):
            raise InputError(f"expected shape ({M},), got {active.shape}", field="active")
        object.__setattr__(self, "active", active.astype(bool))

    @property
    def num_muscles(self) -> int:
        return self.E_ref.shape[0]
