"""The particle stage: static CVs as moving goals in, dynamic CVs out (the thesis's 6.5 and appendix).

Two named stage functions, called alike by the bake's chunk loop (sim/bake/baker.py) and by
:func:`sim.jiggle.secondary.jiggle_rig` (`jiggle simulate`):

- :func:`goals`: the static CVs at the goal knots as a GoalTrack, with cuts found (sim/jiggle/goal_track.py);
- :func:`simulate`: the particles stepped along that track to the output times (:func:`run`).

:func:`run` steps between knots, output times and ``substeps`` per frame, split further to the
solver's spring limit; the exact goal flow makes the result independent of those choices up to the
splitting error of the springs (benchmarks/bench_jiggle.py measures it).

Starting: with ``preroll`` 0 the particles start moving with their goals at the offset where the
springs balance the goals' acceleration at the first frame (and gravity, with it), within their reach:
the quasi-static offset a driven spring settles to, so a clip cut mid-motion shows no jolt
(:func:`restart`); with preroll P > 0 they start at the bind pose, at rest, P seconds early, and the
goals blend to the first frame over P/2 and hold for P/2.
Going on from a given state (a chunked bake) repeats the steps an unbroken run would take.
Cuts: through a cut interval the particles are glued to the (linearly moving) goals, and on its far
side they restart as a run starts there (:func:`restart`).
"""
from __future__ import annotations

import math

import numpy as np

from jiggle.rig.base.errors import InputError
from jiggle.sim.jiggle import tissue_law
from jiggle.sim.jiggle.goal_track import GoalTrack, build_track
from jiggle.sim.jiggle.graph import ChunkGraph
from jiggle.sim.jiggle.params import JiggleSettings
from jiggle.sim.jiggle.particles import GRAVITY, ParticleModel
from jiggle.sim.jiggle.solver import ParticleSolver
from jiggle.sim.jiggle.step_sequence import step_sequence
from jiggle.sim.jiggle.tissue_contacts import integrate_tissue

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


def equilibrium(model: ParticleModel, accel: np.ndarray | None = None) -> np.ndarray:
    """(N, 3) metres: the offsets from the goals at which the goal and neighbour springs balance
    gravity (when the model has it) and the inertia of goals accelerating at `accel` (N, 3) m/s^2
    (None: still goals): m (g - a) = k y, the quasi-static offset a driven spring settles to. Zero for
    glued particles and in a group that nothing holds (it falls freely)."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components
    from scipy.sparse.linalg import spsolve
    n = model.num_particles
    y = np.zeros((n, 3))
    body = np.zeros((n, 3)) if accel is None else -np.asarray(accel, dtype=np.float64).reshape(n, 3)
    if model.gravity:
        body[:, 2] -= GRAVITY
    if n == 0 or not body.any():
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
    a = (lap + sp.diags(deg + k)).tocsr()[free][:, free].tocsc()
    rhs = model.mass[free, None] * body[free]
    y[free] = np.stack([spsolve(a, rhs[:, c]) if rhs[:, c].any() else np.zeros(len(rhs)) for c in range(3)], axis=1)
    return y


START_WINDOW = 0.1
"""seconds: the goals' velocity and acceleration at a run's start are fitted over this much of the track."""


def start_motion(track: GoalTrack, t0: float, window: float = START_WINDOW) -> tuple[np.ndarray, np.ndarray]:
    """The goals' velocity (N, 3) m/s and acceleration (N, 3) m/s^2 at t0: a least-squares quadratic
    in time through the track's knots in [t0, t0 + window] (at least three, the track's first ones
    after t0 when the window holds fewer; the goal at t0 itself included). Fitted rather than read
    off one knot interval: mocap's frame-to-frame noise makes a single interval's second difference
    tens of m/s^2 off, and the start offset follows it (equilibrium)."""
    times = track.times
    first = int(np.searchsorted(times, t0 - TIME_EPS))
    last = max(int(np.searchsorted(times, t0 + window + TIME_EPS, side="right")), first + 3)
    pick = times[first:min(last, len(times))]
    if len(pick) < 3:                                   # a track of two knots: its own velocity, no acceleration
        _, vel, _ = track.sample(t0)
        return vel, np.zeros_like(vel)
    t = np.concatenate([[t0], pick[pick > t0 + TIME_EPS]]) - t0
    pos = np.stack([track.sample(t0 + dt)[0] for dt in t])              # (K, N, 3)
    basis = np.stack([np.ones_like(t), t, 0.5 * t * t], axis=1)           # p(t) = p0 + v t + a t^2 / 2
    coef, *_ = np.linalg.lstsq(basis, pos.reshape(len(t), -1), rcond=None)
    n = pos.shape[1]
    return coef[1].reshape(n, 3), coef[2].reshape(n, 3)


def restart(model: ParticleModel, solver: ParticleSolver, state, control, t: float) -> None:
    """Put the particles on their goals at time t as a run starts (and restarts after a cut): at the
    quasi-static offset of the goals' fitted acceleration (and gravity) under the tissue law, with their
    fitted velocity (start_motion); glued particles exactly on their goals, moving with them. A solver of
    keyed parameters (sim/jiggle/keyed_solver.py) gives the model's goal springs at t (`model_at`)."""
    if hasattr(solver, "model_at"):
        model = solver.model_at(t)
    solver.glue(state, control, t)
    x, v = state.numpy()
    y, vel = start_offsets(model, control.track, t)
    state.assign(x + y, np.where(model.glued[:, None], v, vel))


def start_offsets(model: ParticleModel, track: GoalTrack, t: float) -> tuple[np.ndarray, np.ndarray]:
    """(y, vel) (N, 3) float64: :func:`restart`'s offsets from the goals (m) and velocities (m/s) at time t, from the
    model and the track alone (the chunk graph adds them on the device, sim/jiggle/graph.py)."""
    vel, acc = start_motion(track, t)
    y = tissue_law.equilibrium_numpy(equilibrium(model, acc), model.goal_k, np.asarray(model.reach, dtype=np.float64))
    return y, vel


def run(model: ParticleModel, track: GoalTrack, out_times: np.ndarray, substeps: int = 4,
        preroll: float = 0.0, solver: ParticleSolver | None = None, *, start=None,
        return_state: bool = False, colliders=None, contacts: dict | None = None, tissue=None):
    """Particle positions (T, N, 3) float64 at out_times (T,) seconds, increasing, inside the track.

    substeps : steps per output interval (more where knots or the spring limit need them).
    preroll : seconds (see the module docstring); 0 starts on the goals.
    start : None, or (x, v) (N, 3) float32 positions (m) and velocities (m/s) at out_times[0], to go on
        from an earlier run that ended there (a chunked bake); out[0] is then start's x and preroll must
        be 0. Going on from the state a run returned, with the same step grid, repeats the steps an
        unbroken run would take, so the chunks of a bake do not depend on where it was interrupted.
    return_state : also return the (x, v) float32 state at out_times[-1]: ``(positions, (x, v))``.
    colliders : None, or sim.jiggle.colliders.Colliders on the track's knots: the particles collide with
        its capsules and floor (during a preroll the capsules hold the first knot's pose).
    contacts : a dict that, with colliders (or tissue), receives "records": (T, N, 3) float32 contact records
        per output frame (depth m, impulse N s, hit id; zeros and -1 at the first frame and through cuts).
    tissue : None, or a sim.jiggle.tissue_contacts.TissueContactModel of the model's particles: the muscles of
        different body parts collide with each other's particles, a contact pass after every step
        (sim.jiggle.tissue_contacts.integrate_tissue; hit ids C + 1 + muscle in the records, which `contacts`
        then receives with or without colliders). None: the one-launch run, as before.
    """
    out_times = _check_run(track, out_times, preroll, start)
    solver = solver or ParticleSolver(model)
    t0 = out_times[0]
    given, start = start, np.array([t0])
    if preroll > 0:
        track, start, colliders = _preroll_track(model, track, t0, preroll, colliders)
    control = track.to_device(model.device)
    grid = step_times(np.concatenate([start, out_times]) if preroll > 0 else out_times, track.times, substeps,
                      solver.max_step)
    if given is not None:
        given = _start_state(model, given)
    output = _Output(model, out_times, grid, colliders is not None or tissue is not None, contacts)
    how = ("given", given) if given is not None else ("rest",) if preroll > 0 else ("restart", t0)
    if getattr(solver, "use_graph", False) and solver.graph is None:
        solver.graph = ChunkGraph(solver)
    graph = getattr(solver, "graph", None)
    if graph is not None and graph.supports(solver):
        end = _run_graph(graph, model, track, control, grid, output, how, colliders, tissue)
        if return_state:
            return output.out, end
        return output.out

    state = _run_steps(model, solver, track, control, grid, output, how, colliders, tissue)
    if return_state:
        x, v = state.numpy()
        return output.out, (np.array(x, dtype=np.float32), np.array(v, dtype=np.float32))
    return output.out


def _check_run(track: GoalTrack, out_times, preroll: float, start) -> np.ndarray:
    """out_times as a float64 array (T,) seconds, checked: increasing, inside the track, and no preroll for a
    run that goes on from a given state (InputError otherwise)."""
    out_times = np.asarray(out_times, dtype=np.float64)
    if out_times.ndim != 1 or len(out_times) == 0 or np.any(np.diff(out_times) <= 0):
        raise InputError("output times must be a non-empty increasing array", field="times")
    if out_times[0] < track.times[0] - TIME_EPS or out_times[-1] > track.times[-1] + TIME_EPS:
        raise InputError(f"output times [{out_times[0]:.4f}, {out_times[-1]:.4f}] s run outside the goal track "
                         f"[{track.times[0]:.4f}, {track.times[-1]:.4f}] s", field="times")
    if start is not None and preroll > 0:
        raise InputError("a run that goes on from a given state has no preroll", field="preroll")
    return out_times


def _preroll_track(model: ParticleModel, track: GoalTrack, t0: float, preroll: float, colliders):
    """(track, start, colliders) of a run with a preroll: the goal track from `preroll` seconds before t0, the bind
    pose blended to the first frame over preroll / 2 and held (knots at the track's first spacing), then the
    track from t0 on; start (1,) its first time (s); the colliders on its knots, the capsules holding their
    first pose through the preroll (None stays None)."""
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
    cuts = np.concatenate([np.zeros(n, bool), track.cut[keep[:-1]]])
    track = build_track(times, pos, cuts=cuts)
    start = np.array([pre[0]])
    if colliders is not None:
        ends = colliders.control.track.pos
        colliders = colliders.model.on_track(times, np.concatenate([np.repeat(ends[:1], n, axis=0), ends[keep]]),
                                             cuts)
    return track, start, colliders


def _start_state(model: ParticleModel, given) -> tuple[np.ndarray, np.ndarray]:
    """A run's given start (x, v) as two (N, 3) float32 arrays (m, m/s); InputError for other shapes."""
    x, v = (np.asarray(a, dtype=np.float32) for a in given)
    if x.shape != (model.num_particles, 3) or v.shape != x.shape:
        raise InputError(f"a start state must be two ({model.num_particles}, 3) arrays, got {x.shape} and "
                         f"{v.shape}", field="start")
    return x, v


class _Output:
    """A run's output frames: `out` (T, N, 3) float64 positions (m), `records` (T, N, 3) float32 contact records
    (None without colliders or tissue; handed to `contacts` as "records"), and where the step grid (G,) meets
    the output times: `wanted` (G,) the output frame at or after each grid time, `is_out` (G,) bool whether
    it is that frame."""

    def __init__(self, model: ParticleModel, out_times: np.ndarray, grid: np.ndarray, recording: bool,
                 contacts: dict | None):
        self.model, self.out_times = model, out_times
        self.out = np.empty((len(out_times), model.num_particles, 3))
        self.records = None
        if recording:
            self.records = np.zeros((len(out_times), model.num_particles, 3), np.float32)
            self.records[..., 2] = -1.0
            if contacts is not None:
                contacts["records"] = self.records
        self.wanted = np.searchsorted(out_times, grid - TIME_EPS)
        self.is_out = (self.wanted < len(out_times)) & (
            np.abs(out_times[np.minimum(self.wanted, len(out_times) - 1)] - grid) <= TIME_EPS)

    def save(self, ks: np.ndarray, frames: np.ndarray) -> None:
        """Output frames ks (R,) from positions (R, N, 3); the first that is not finite names its muscle."""
        self.out[ks] = frames
        if not np.isfinite(frames).all():
            r, p = np.argwhere(~np.isfinite(frames).all(axis=2))[0]
            k = int(ks[r])
            raise FloatingPointError(f"{self.model.group_of(int(p))}: the simulation produced NaN at frame {k} "
                                     f"(t = {self.out_times[k]:.4f} s)")


def _run_graph(graph: ChunkGraph, model: ParticleModel, track: GoalTrack, control, grid: np.ndarray,
               output: _Output, how: tuple, colliders, tissue):
    """The run as one device program (sim/jiggle/graph.py), nothing read back until its end: the output frames
    and records saved into `output`; the (x, v) state at the end."""
    if tissue is not None:
        from jiggle.sim.jiggle.tissue_contacts import _check
        _check(model, tissue)
    frames, recs, end = graph.run(track, control, grid, output.out_times, output.wanted, output.is_out, how,
                                  colliders, tissue, lambda t: start_offsets(model, track, t))
    output.save(np.arange(len(output.out_times)), frames)
    if output.records is not None:
        output.records[...] = recs
    return end


def _run_steps(model: ParticleModel, solver: ParticleSolver, track: GoalTrack, control, grid: np.ndarray,
               output: _Output, how: tuple, colliders, tissue):
    """The run step by step from the host (sim/jiggle/step_sequence.py): cut-free stretches in one launch each,
    glued cut intervals, restarts past the cuts; the output frames and records saved into `output`. The
    particles' state at the end (on the device)."""
    wanted = output.wanted
    state, nxt = model.state(), model.state()
    for step in step_sequence(track, grid, output.is_out):        # the graph walks it too
        kind, g, e, ks = step
        if kind == "stretch":
            # the cut-free stretch grid[g..e] in one launch, its output frames read back once
            if tissue is None:
                frames = solver.integrate(state, nxt, control, grid[g:e + 1], record=ks, colliders=colliders)
            else:
                frames = integrate_tissue(solver, state, nxt, control, grid[g:e + 1], record=ks,
                                          colliders=colliders, tissue=tissue)
            if len(ks):
                output.save(wanted[g + ks], frames)
                if output.records is not None:
                    output.records[wanted[g + ks]] = solver.contact_records
            state, nxt = nxt, state
            continue
        if kind == "glue":
            solver.glue(state, control, grid[e])
        elif kind == "restart":                     # the cut's far side: a fresh start there
            restart(model, solver, state, control, grid[e])
        elif how[0] == "given":                     # the start
            state.assign(*how[1])
        elif how[0] == "rest":
            state.assign(model.rest, np.zeros_like(model.rest))
        else:
            restart(model, solver, state, control, how[1])
        if len(ks):
            output.save(wanted[e:e + 1], state.x.numpy()[None])
    return state


def goals(rig, knots: np.ndarray, static_cvs: np.ndarray, settings: JiggleSettings, cuts=None) -> GoalTrack:
    """The goal track of the static CVs (S, N, 3) metres at knots (S,) seconds: cut intervals found
    from the goals' jumps (settings.cut_ratio, settings.cut_jump) unless `cuts` ((S - 1,) bool) says."""
    return build_track(knots, static_cvs, cuts=cuts, ratio=settings.cut_ratio, jump=settings.cut_jump,
                       names=rig.names, offsets=rig.cv_offsets)


def simulate(model: ParticleModel, track: GoalTrack, times: np.ndarray, settings: JiggleSettings, *,
             solver: ParticleSolver | None = None, preroll: float | None = None, start=None, colliders=None,
             contacts: dict | None = None, tissue=None):
    """Dynamic CVs (T, N, 3) float64 metres at times (T,) seconds, and the (x, v) float32 particle
    state at times[-1]: :func:`run` with the settings' substeps and preroll (`preroll` overrides it;
    a run going on from `start` has none). colliders, contacts, tissue : as :func:`run`."""
    preroll = settings.preroll if preroll is None else preroll
    return run(model, track, times, settings.substeps, preroll, solver, start=start, return_state=True,
               colliders=colliders, contacts=contacts, tissue=tissue)
