"""Secondary motion of a whole clip: static goals, particles, blend (`jiggle simulate`).

:func:`jiggle_rig` takes a muscle rig, its jiggle parameters and the motion (a function from times to
joint world transforms) and runs the pipeline's stages over the clip, the same ones the bake runs
chunk by chunk:

1. Goal knots (:func:`knot_times`): the output times plus a grid at ``goal_rate`` (default
   max(120 Hz, output fps)), so the goal path the particles see is the same whatever the output frame
   rate (24, 30, 60 and 120 fps all divide 120 Hz); static CVs at the knots (``MuscleRig.static``,
   rig/muscle/model.py).
2. :func:`sim.jiggle.simulate.goals` and :func:`sim.jiggle.simulate.simulate`: the particles.
3. :func:`sim.jiggle.blend.blend`: ``cvs = static + b (dynamic - static)``; b = 0 everywhere gives the
   static CVs bit for bit and skips the simulation.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Callable, Sequence

import numpy as np

from jiggle.rig.base.errors import InputError
from jiggle.rig.base.frozen import frozen_array
from jiggle.sim.jiggle.blend import blend, blend_weights, needs_simulation
from jiggle.sim.jiggle.colliders import muscle_contacts
from jiggle.sim.jiggle.keyed_solver import make_solver
from jiggle.sim.jiggle.params import CVS, JiggleSettings, MuscleJiggle
from jiggle.sim.jiggle.particles import muscle_model
from jiggle.sim.jiggle.simulate import TIME_EPS, goals, merge_times, simulate
from jiggle.sim.jiggle.tissue_contacts import tissue_contact_model

DEFAULT_GOAL_RATE = 120.0


@dataclass(frozen=True, eq=False)
class JiggleResult:
    """A simulated clip, at the output times.

    times : (T,) seconds. static, dynamic, cvs : (T, N, 3) float64 metres (cvs = the blend of the two,
    what the skin deformers get). curve : (T, M, 5, 3) static action curves. blend : (T, M).
    knots : (S,) goal knot times. cuts : (C,) seconds, the starts of cut intervals.
    names : (M,) muscles. cv_offsets : (M + 1,). jiggles : the MuscleJiggle used. settings.
    contacts : with colliders or tissue contacts, {"depth", "hit", "impulse"} (T, M) each
        (sim.jiggle.colliders.muscle_contacts).
    """

    times: np.ndarray
    static: np.ndarray
    dynamic: np.ndarray
    cvs: np.ndarray
    curve: np.ndarray
    blend: np.ndarray
    knots: np.ndarray
    cuts: np.ndarray
    names: tuple
    cv_offsets: np.ndarray
    jiggles: tuple
    settings: JiggleSettings
    contacts: dict | None = None

    def amplitude(self) -> np.ndarray:
        """(T, M) metres: each muscle's largest CV distance between dynamic and static per frame."""
        d = np.linalg.norm(self.dynamic - self.static, axis=2)
        return d.reshape(len(self.times), -1, CVS).max(axis=2)


KNOTS_AFTER = 2
"""Goal knots past the last output frame: the last frames then see the same goal path (and its
velocity from both sides) whatever the output rate; world_at must accept those times (a clip holds
its last pose there)."""


def knot_times(out_times: np.ndarray, goal_rate: float) -> np.ndarray:
    """Goal knots: a grid at goal_rate Hz from out_times[0] to KNOTS_AFTER grid points past
    out_times[-1], plus every output time."""
    t0, t1 = float(out_times[0]), float(out_times[-1])
    n = int(math.ceil((t1 - t0) * goal_rate - 1e-6)) + KNOTS_AFTER
    grid = t0 + np.arange(n + 1) / goal_rate
    return merge_times(grid, out_times)


def jiggle_rig(rig, jiggles: Sequence[MuscleJiggle], world_at: Callable[[np.ndarray], np.ndarray],
               times: np.ndarray, settings: JiggleSettings = JiggleSettings(), *, cuts=None,
               colliders=None, tissue=None) -> JiggleResult:
    """Simulate every muscle of `rig` (rig.muscle.model.MuscleRig) over a motion.

    world_at : times (K,) seconds -> joint world transforms (K, J, 4, 4) in the rig's joint order,
        asked from times[0] to a few goal knots past times[-1] (KNOTS_AFTER).
    times : (T,) output times, seconds, increasing (T >= 1).
    cuts : None to detect cuts from the goals, or (S - 1,) bool over the knot intervals.
    colliders : None, or a sim.jiggle.colliders.ColliderModel of the rig's muscles: the particles collide
        with its capsules (moving with world_at's joints) and floor; the result's `contacts` then holds
        the per-frame, per-muscle contacts (sim.jiggle.colliders.muscle_contacts).
    tissue : None; True, or a sim.jiggle.tissue_contacts.TissueContactModel of the rig's muscles: the muscles
        of different body parts also collide with each other's particles (True: the model
        sim.jiggle.tissue_contacts.tissue_contact_model builds); `contacts` then holds those too (hit ids
        C + 1 + muscle, C the capsules; TissueContactModel.hit_names).
    """
    times = np.asarray(times, dtype=np.float64).reshape(-1)
    if len(times) == 0 or not np.isfinite(times).all() or np.any(np.diff(times) <= 0):
        raise InputError("output times must be finite and increasing", field="times")
    jiggles = list(jiggles)
    if len(jiggles) != rig.M:
        raise InputError(f"expected {rig.M} jiggle entries (one per muscle), got {len(jiggles)}", field="jiggle")
    if settings.strength is not None:
        jiggles = [replace(j, strength=settings.strength) for j in jiggles]
    fps = 1.0 / float(np.min(np.diff(times))) if len(times) > 1 else DEFAULT_GOAL_RATE
    rate = settings.goal_rate or max(DEFAULT_GOAL_RATE, fps)
    knots = knot_times(times, rate)
    out = np.searchsorted(knots, times - TIME_EPS)
    world = np.asarray(world_at(knots), dtype=np.float64)
    static = rig.static(world)                                                     # rig.muscle: static CVs
    st = static.cvs[out]
    track = goals(rig, knots, static.cvs, settings, cuts=cuts)                   # sim.jiggle: goals
    weights = blend_weights(jiggles, settings, times)
    contacts = None
    if needs_simulation(weights):                                                 # sim.jiggle: particles
        model = muscle_model(rig, jiggles, settings.device, gravity=settings.gravity)
        moving = None if colliders is None else colliders.at(knots, world, track.cut)
        if tissue is True:
            tissue = tissue_contact_model(rig, model)
        sink = {}
        solver = make_solver(model, jiggles)             # keyed: sim/jiggle/keyed_solver.py
        dyn, _ = simulate(model, track, times, settings, solver=solver, colliders=moving, contacts=sink,
                          tissue=tissue or None)
        if "records" in sink:
            contacts = muscle_contacts(sink["records"], rig.cv_offsets)
    else:
        dyn = st.copy()
    cvs = blend(st, dyn, weights)                                                 # sim.jiggle: blend
    return JiggleResult(times=frozen_array(times), static=frozen_array(st), dynamic=frozen_array(dyn),
                        cvs=frozen_array(cvs), curve=frozen_array(static.curve[out]), blend=frozen_array(weights),
                        knots=frozen_array(knots), cuts=frozen_array(knots[:-1][track.cut]),
                        names=tuple(rig.names), cv_offsets=frozen_array(rig.cv_offsets), jiggles=tuple(jiggles),
                        settings=settings, contacts=contacts)
