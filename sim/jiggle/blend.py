"""The blend stage: static and dynamic CVs mixed by each muscle's static_dyn_blend curve.

    cvs = static + b (dynamic - static)        b = the muscle's curve at the frame (the global one
                                               for muscles without their own), per CV of the muscle

b = 0 gives the static CVs bit for bit (a caller skips the simulation when every weight is 0,
:func:`needs_simulation`); b = 1 the dynamic ones. The thesis's appendix calls this the blend shape
between the static and the dynamic muscle. Called alike by the bake's chunk loop and `jiggle simulate`.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from jiggle.sim.jiggle.params import CVS, JiggleSettings, MuscleJiggle


def blend_weights(jiggles: Sequence[MuscleJiggle], settings: JiggleSettings, times: np.ndarray) -> np.ndarray:
    """(T, M) blend weights in [0, 1] at times (T,) seconds, one column per muscle."""
    if not jiggles:
        return np.zeros((len(times), 0))
    return np.stack([(j.blend or settings.blend)(times) for j in jiggles], axis=1)


def needs_simulation(weights: np.ndarray) -> bool:
    """False when every weight is 0: the final CVs are then the static ones and nothing is simulated."""
    return bool(np.any(weights != 0))


def blend(static: np.ndarray, dynamic: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Final CVs (T, N, 3) from static and dynamic CVs (T, N, 3) metres and weights (T, M), each
    muscle's weight applied to its CVS control points."""
    b = np.repeat(weights, CVS, axis=1)[:, :, None]
    return static + b * (dynamic - static)
