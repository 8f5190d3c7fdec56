"""What a muscle's template says about the skin around it: its shell deformer's parameters.

Pratscher et al. 2005, 4.2: each muscle deforms the skin through three shells (sticky, hard, drop-off)
in its local space; :class:`ShellParams` holds one muscle's values, checked on construction
(:func:`check_params`), and :func:`default_shell` gives a muscle or a fat mass the defaults. The
deformer itself (maths, kernels, launcher, painted weights) is rig/skin/shell/.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from jiggle.rig.base.errors import InputError

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
