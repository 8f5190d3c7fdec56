"""Secondary motion of a clip: static goals, particles, blend (the thesis's section 6.5 and appendix).

:func:`jiggle_rig` takes a muscle rig, its jiggle parameters and the motion (a function from times to
joint world transforms) and returns static, dynamic and blended CVs at the output times:

1. Goal knots: the output times plus a grid at ``goal_rate`` (default max(120 Hz, output fps)), so
   the goal path the particles see is the same whatever the output frame rate (24, 30, 60 and 120
   fps all divide 120 Hz). Static CVs at the knots (rig.muscle.model), cuts found (sim/jiggle/goal_track.py).
2. :func:`run`: steps between knots, output times and ``substeps`` per frame, split further to the
   solver's spring limit; the exact goal flow makes the result independent of those choices up to
   the splitting error of the springs (benchmarks/bench_jiggle.py measures it).
3. Blend: ``cvs = static + b (dynamic - static)`` with each muscle's static_dyn_blend curve; b = 0
   gives the static CVs bit for bit (the simulation is skipped when every curve is 0).

Starting: with ``preroll`` 0 the particles start on their goals, moving with them (and, with
gravity, at their sag), so the first frame shows no jolt; with preroll P > 0 they start at the bind
pose, at rest, P seconds early, and the goals blend to the first frame over P/2 and hold for P/2.
Cuts: through a cut interval the particles are glued to the (linearly moving) goals, so they restart
from the far side at rest relative to it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Callable, Sequence

import numpy as np

from rig.base.errors import InputError
from rig.base.frozen import frozen_array
from sim.jiggle.goal_track import GoalTrack, build_track
from sim.jiggle.params import CVS, JiggleSettings, MuscleJiggle
from sim.jiggle.particles import GRAVITY, ParticleModel, muscle_model
from sim.jiggle.solver import ParticleSolver

DEFAULT_GOAL_RATE = 120.0
TIME_EPS = 1e-9


def merge_times(*groups, eps: float = TIME_EPS) -> np.ndarray:
    """Sorted union of time arrays with points closer than eps merged."""
    t = np.sort(np.concatenate([np.asarray(g, dtype=np.float64).reshape(-1) for g in groups]))
    if len(t) == 0:
        return t
    keep = np.concatenate([[True], np.diff(t) > eps])
    return t[keep]


def step_times(out_times: np.ndarray, knots: np.ndarray, substeps: int, max_step: float) -> np.ndarray:
    """The solver's step boundaries from out_times[0] to out_times[-1]: every output time, `substeps`
    even steps per output interval, every knot inside, and each step longer than max_step split evenly."""
    out_times = np.asarray(out_times, dtype=np.float64)
    a, b = out_times[:-1], out_times[1:]
    subs = (a[:, None] + (b - a)[:, None] * (np.arange(substeps) / substeps)[None]).reshape(-1)
    inner = knots[(knots > out_times[0]) & (knots < out_times[-1])]
    grid = merge_times(out_times, subs, inner)
    if math.isfinite(max_step) and len(grid) > 1:
        h = np.diff(grid)
        n = np.maximum(1, np.ceil(h / max_step - 1e-9)).astype(np.int64)
        if (n > 1).any():
            k = np.arange(n.max())
            points = grid[:-1, None] + h[:, None] * (k[None] / n[:, None])     # interval i split in n[i]
            grid = np.concatenate([points[k[None] < n[:, None]], grid[-1:]])
    return grid


def equilibrium(model: ParticleModel) -> np.ndarray:
    """(N, 3) metres: the offsets from the goals at which gravity balances the goal and neighbour
    springs (zero without gravity; zero in a group that nothing holds, which falls freely)."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components
    from scipy.sparse.linalg import spsolve
    n = model.num_particles
    y = np.zeros((n, 3))
    if not model.gravity or n == 0:
        return y
    i, j = (model.springs[:, 0], model.springs[:, 1]) if model.num_springs else (np.zeros(0, int), np.zeros(0, int))
    graph = sp.coo_matrix((np.ones(len(i)), (i, j)), shape=(n, n))
    _, comp = connected_components(graph, directed=False)
    held = np.bincount(comp, weights=(model.glued | (model.goal_k > 0)).astype(float)) > 0
    free = ~model.glued & held[comp]
    if not free.any():
        return y
    k = np.where(model.glued, 0.0, model.mass * model.goal_k)
    lap = sp.coo_matrix((np.concatenate([-model.spring_k, -model.spring_k]),
                         (np.concatenate([i, j]), np.concatenate([j, i]))), shape=(n, n)).tocsr()
    deg = np.bincount(np.concatenate([i, j]), weights=np.concatenate([model.spring_k, model.spring_k]), minlength=n)
    a = (lap + sp.diags(deg + k)).tocsr()[free][:, free]
    y[free, 2] = spsolve(a.tocsc(), -GRAVITY * model.mass[free])
    return y


def run(model: ParticleModel, track: GoalTrack, out_times: np.ndarray, substeps: int = 4,
        preroll: float = 0.0, solver: ParticleSolver | None = None, *, start=None,
        return_state: bool = False):
    """Particle positions (T, N, 3) float64 at out_times (T,) seconds, increasing, inside the track.

    substeps : steps per output interval (more where knots or the spring limit need them).
    preroll : seconds (see the module docstring); 0 starts on the goals.
    start : None, or (x, v) (N, 3) float32 positions (m) and velocities (m/s) at out_times[0], to go on
        from an earlier run that ended there (a chunked bake); out[0] is then start's x and preroll must
        be 0. Going on from the state a run returned, with the same step grid, repeats the steps an
        unbroken run would take, so the chunks of a bake do not depend on where it was interrupted.
    return_state : also return the (x, v) float32 state at out_times[-1]: ``(positions, (x, v))``.
    """
    out_times = np.asarray(out_times, dtype=np.float64)
    if out_times.ndim != 1 or len(out_times) == 0 or np.any(np.diff(out_times) <= 0):
        raise InputError("output times must be a non-empty increasing array", field="times")
    if out_times[0] < track.times[0] - TIME_EPS or out_times[-1] > track.times[-1] + TIME_EPS:
        raise InputError(f"output times [{out_times[0]:.4f}, {out_times[-1]:.4f}] s run outside the goal track "
                         f"[{track.times[0]:.4f}, {track.times[-1]:.4f}] s", field="times")
    if start is not None and preroll > 0:
        raise InputError("a run that goes on from a given state has no preroll", field="preroll")
    solver = solver or ParticleSolver(model)
    t0 = out_times[0]
    given, start = start, np.array([t0])
    if preroll > 0:
        # bind pose -> first frame over preroll / 2, then hold; knots at the track's first spacing
        g0 = track.sample(t0)[0]
        dt_k = float(np.min(np.diff(track.times))) if track.num_knots > 1 else preroll / 8
        n = max(4, int(math.ceil(preroll / dt_k)))
        pre = t0 - preroll + preroll * np.arange(n) / n
        a = np.clip((pre - pre[0]) / (0.5 * preroll), 0.0, 1.0)
        a = a * a * (3.0 - 2.0 * a)
        pre_pos = model.rest[None] + a[:, None, None] * (g0 - model.rest)[None]
        keep = track.times >= t0 - TIME_EPS
        times = np.concatenate([pre, track.times[keep]])
        pos = np.concatenate([pre_pos, track.pos[keep]])
        track = build_track(times, pos, cuts=np.concatenate([np.zeros(n, bool), track.cut[keep[:-1]]]))
        start = np.array([pre[0]])
    control = track.to_device(model.device)
    grid = step_times(np.concatenate([start, out_times]) if preroll > 0 else out_times, track.times, substeps,
                      solver.max_step)
    state, nxt = model.state(), model.state()
    if given is not None:
        x, v = (np.asarray(a, dtype=np.float32) for a in given)
        if x.shape != (model.num_particles, 3) or v.shape != x.shape:
            raise InputError(f"a start state must be two ({model.num_particles}, 3) arrays, got {x.shape} and "
                             f"{v.shape}", field="start")
        state.assign(x, v)
    elif preroll > 0:
        state.assign(model.rest, np.zeros_like(model.rest))
    else:
        solver.glue(state, control, t0)
        if model.gravity:
            x, v = state.numpy()
            state.assign(x + equilibrium(model), v)
    out = np.empty((len(out_times), model.num_particles, 3))
    wanted = np.searchsorted(out_times, grid - TIME_EPS)
    is_out = (wanted < len(out_times)) & (np.abs(out_times[np.minimum(wanted, len(out_times) - 1)] - grid) <= TIME_EPS)

    def record(g: int, x) -> None:
        if is_out[g]:
            k = int(wanted[g])
            out[k] = x.numpy()
            if not np.isfinite(out[k]).all():
                p = int(np.argwhere(~np.isfinite(out[k]))[0, 0])
                raise FloatingPointError(f"{model.group_of(p)}: the simulation produced NaN at frame {k} "
                                         f"(t = {out_times[k]:.4f} s)")

    record(0, state.x)
    cut = track.cut[[track.interval(0.5 * (a + b)) for a, b in zip(grid[:-1], grid[1:])]]
    g = 0
    while g < len(grid) - 1:
        if cut[g]:
            solver.glue(state, control, grid[g + 1])
            g += 1
            record(g, state.x)
            continue
        e = g + 1
        while e < len(grid) - 1 and not cut[e]:
            e += 1
        solver.integrate(state, nxt, control, grid[g:e + 1], on_step=lambda k, x, g=g: record(g + k, x))
        state, nxt = nxt, state
        g = e
    if return_state:
        x, v = state.numpy()
        return out, (np.array(x, dtype=np.float32), np.array(v, dtype=np.float32))
    return out


@dataclass(frozen=True, eq=False)
class JiggleResult:
    """A simulated clip, at the output times.

    times : (T,) seconds. static, dynamic, cvs : (T, N, 3) float64 metres (cvs = the blend of the two,
    what the skin deformers get). curve : (T, M, 5, 3) static action curves. blend : (T, M).
    knots : (S,) goal knot times. cuts : (C,) seconds, the starts of cut intervals.
    names : (M,) muscles. cv_offsets : (M + 1,). jiggles : the MuscleJiggle used. settings.
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
               times: np.ndarray, settings: JiggleSettings = JiggleSettings(), *, cuts=None) -> JiggleResult:
    """Simulate every muscle of `rig` (rig.muscle.model.MuscleRig) over a motion.

    world_at : times (K,) seconds -> joint world transforms (K, J, 4, 4) in the rig's joint order,
        asked from times[0] to a few goal knots past times[-1] (KNOTS_AFTER).
    times : (T,) output times, seconds, increasing (T >= 1).
    cuts : None to detect cuts from the goals, or (S - 1,) bool over the knot intervals.
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
    static = rig.static(np.asarray(world_at(knots), dtype=np.float64))
    out = np.searchsorted(knots, times - TIME_EPS)
    blend = np.stack([(j.blend or settings.blend)(times) for j in jiggles], axis=1) if jiggles else np.zeros((len(times), 0))
    st = static.cvs[out]
    track = build_track(knots, static.cvs, cuts=cuts, ratio=settings.cut_ratio, jump=settings.cut_jump,
                        names=rig.names, offsets=rig.cv_offsets)
    if np.all(blend == 0):
        dyn = st.copy()
    else:
        model = muscle_model(rig, jiggles, settings.device, gravity=settings.gravity)
        dyn = run(model, track, times, settings.substeps, settings.preroll)
    b = np.repeat(blend, CVS, axis=1)[:, :, None]
    cvs = st + b * (dyn - st)
    return JiggleResult(times=frozen_array(times), static=frozen_array(st), dynamic=frozen_array(dyn),
                        cvs=frozen_array(cvs), curve=frozen_array(static.curve[out]), blend=frozen_array(blend),
                        knots=frozen_array(knots), cuts=frozen_array(knots[:-1][track.cut]),
                        names=tuple(rig.names), cv_offsets=frozen_array(rig.cv_offsets), jiggles=tuple(jiggles),
                        settings=settings)
