"""The particle stage: static CVs as moving goals in, dynamic CVs out (the thesis's 6.5 and appendix).

Two named stage functions, called alike by the bake's chunk loop (sim/bake/baker.py) and by
:func:`sim.jiggle.secondary.jiggle_rig` (`jiggle simulate`):

- :func:`goals`: the static CVs at the goal knots as a GoalTrack, with cuts found (sim/jiggle/goal_track.py);
- :func:`simulate`: the particles stepped along that track to the output times (:func:`run`).

:func:`run` steps between knots, output times and ``substeps`` per frame, split further to the
solver's spring limit; the exact goal flow makes the result independent of those choices up to the
splitting error of the springs (benchmarks/bench_jiggle.py measures it).

Starting: with ``preroll`` 0 the particles start on their goals, moving with them (and, with
gravity, at their sag), so the first frame shows no jolt; with preroll P > 0 they start at the bind
pose, at rest, P seconds early, and the goals blend to the first frame over P/2 and hold for P/2.
Going on from a given state (a chunked bake) repeats the steps an unbroken run would take.
Cuts: through a cut interval the particles are glued to the (linearly moving) goals, so they restart
from the far side at rest relative to it.
"""
from __future__ import annotations

import math

import numpy as np

from rig.base.errors import InputError
from sim.jiggle.goal_track import GoalTrack, build_track
from sim.jiggle.params import JiggleSettings
from sim.jiggle.particles import GRAVITY, ParticleModel
from sim.jiggle.solver import ParticleSolver

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


def goals(rig, knots: np.ndarray, static_cvs: np.ndarray, settings: JiggleSettings, cuts=None) -> GoalTrack:
    """The goal track of the static CVs (S, N, 3) metres at knots (S,) seconds: cut intervals found
    from the goals' jumps (settings.cut_ratio, settings.cut_jump) unless `cuts` ((S - 1,) bool) says."""
    return build_track(knots, static_cvs, cuts=cuts, ratio=settings.cut_ratio, jump=settings.cut_jump,
                       names=rig.names, offsets=rig.cv_offsets)


def simulate(model: ParticleModel, track: GoalTrack, times: np.ndarray, settings: JiggleSettings, *,
             solver: ParticleSolver | None = None, preroll: float | None = None, start=None):
    """Dynamic CVs (T, N, 3) float64 metres at times (T,) seconds, and the (x, v) float32 particle
    state at times[-1]: :func:`run` with the settings' substeps and preroll (`preroll` overrides it;
    a run going on from `start` has none)."""
    preroll = settings.preroll if preroll is None else preroll
    return run(model, track, times, settings.substeps, preroll, solver, start=start, return_state=True)
