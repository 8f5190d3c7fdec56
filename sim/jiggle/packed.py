"""Many bakes' particles in one model: one launch per stage steps them all (`jiggle batch` on a GPU).

A GPU steps one character's few thousand particles in launches that leave it nearly idle; B characters packed
into one particle array cost about as many launches as one. :func:`pack_models` concatenates B ParticleModels
(particles, springs with their indices shifted, muscles) into one, with the bakes' particle offsets (B + 1,) and
each particle's bake, the batch index (N,) int32 (also on the device: :attr:`PackedModel.wp_batch`);
:class:`PackedBakes` steps a chunk of every bake: the bakes whose chunk has the same step grid (output times,
knots, cuts, the spring limit's splits) run as one pack, a bake alone where none shares its grid.

Why the result is each bake's own, bit for bit: every kernel's arithmetic for a particle reads only that
particle, its springs' neighbours (never in another bake: no spring joins two models) and the step's times, and
the per-particle tables (the tissue rows, sim.jiggle.tissue_law.rows; the knot velocities, goal_track.
knot_velocities) are computed element by element; so a particle's float32 operations are the same in the pack.
What is not per particle is kept per bake: a run's start (sim.jiggle.simulate.restart solves each bake's
equilibrium, a sparse solve whose rounding depends on the system) is done for each bake alone and the packed run
goes on from the packed states; the step grid must be the same (the packed solver's spring limit is the smallest,
and a bake is packed only where its own limit gives the same grid); a cut is found per bake (find_cuts takes the
largest move over a bake's points), so bakes are packed only where their cuts agree. tests/jiggle/test_packed.py
checks three different bakes (CesiumMan on two CMU clips, the generated demo body) chunk by chunk.

Not packed here: capsule and floor contacts (the contact kernels take one floor height and one capsule list per
launch: a pack needs a floor per muscle and the capsules of every bake with the per-muscle candidate lists made
from each bake's own, a change to sim/jiggle/contact_kernels.py), tissue contacts (a hash grid over the pack works
unchanged, the muscle mask becomes block-diagonal), keyed parameters (sim/jiggle/keyed_solver.py), a preroll; a
bake with any of them runs alone (:meth:`PackedBakes.can_pack`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from jiggle.rig.base.errors import InputError
from jiggle.sim.jiggle.goal_track import GoalTrack, build_track
from jiggle.sim.jiggle.particles import ParticleBuilder, ParticleModel
from jiggle.sim.jiggle.simulate import TIME_EPS, restart, run, step_times
from jiggle.sim.jiggle.solver import ParticleSolver


@dataclass(frozen=True, eq=False)
class PackedModel:
    """B particle models as one. model : the packed ParticleModel (muscle names "<bake>/<muscle>").
    offsets : (B + 1,) int64, bake b owns particles offsets[b]:offsets[b + 1]. batch : (N,) int32, each particle's
    bake; wp_batch its device copy. names : (B,) the bakes' names."""

    model: ParticleModel
    offsets: np.ndarray
    batch: np.ndarray
    wp_batch: wp.array
    names: tuple

    @property
    def num_bakes(self) -> int:
        return len(self.offsets) - 1

    def pack(self, arrays) -> np.ndarray:
        """One (N_b, ...) array per bake -> (N, ...) (concatenated on the particle axis)."""
        return np.concatenate([np.asarray(a) for a in arrays], axis=0)

    def unpack(self, a: np.ndarray, axis: int = 0) -> list[np.ndarray]:
        """(..., N, ...) with the particles on `axis` -> one array per bake."""
        return [np.take(a, np.arange(self.offsets[b], self.offsets[b + 1]), axis=axis) for b in range(self.num_bakes)]


def pack_models(models, names=None, device: str | None = None) -> PackedModel:
    """The models (ParticleModel, each with its muscles) as one PackedModel on `device` (None: the first model's).
    They must agree on gravity (the solver's gravity is one vector)."""
    models = list(models)
    if not models:
        raise InputError("nothing to pack: no particle models", field="models")
    gravity = {m.gravity for m in models}
    if len(gravity) > 1:
        raise InputError("packed bakes must all have gravity on or all off", field="gravity")
    names = tuple(names) if names is not None else tuple(f"bake{b}" for b in range(len(models)))
    b = ParticleBuilder()
    offsets = [0]
    for name, m in zip(names, models):
        base = b.num_particles
        go = np.asarray(m.group_offsets)
        for g in range(len(go) - 1):
            if go[g + 1] <= go[g]:
                continue
            b.begin_group(f"{name}/{m.group_names[g]}")
            sl = slice(int(go[g]), int(go[g + 1]))
            b.add_particles(m.rest[sl], m.mass[sl], m.goal_k[sl], m.goal_c[sl], m.drag[sl], m.reach[sl])
        if m.num_springs:
            b.add_springs(np.asarray(m.springs) + base, m.spring_k, m.spring_c)
        offsets.append(b.num_particles)
    device = device or models[0].device
    model = b.finalize(device, gravity=gravity.pop())
    offsets = np.asarray(offsets, np.int64)
    batch = np.repeat(np.arange(len(models), dtype=np.int32), np.diff(offsets))
    return PackedModel(model, offsets, batch, wp.array(batch, dtype=wp.int32, device=device), names)


def pack_tracks(tracks) -> GoalTrack:
    """The bakes' goal tracks (same knots and cuts) as one: positions concatenated on the particle axis, the knot
    velocities computed again (per point: the same numbers)."""
    first = tracks[0]
    for t in tracks[1:]:
        if not (np.array_equal(t.times, first.times) and np.array_equal(t.cut, first.cut)):
            raise InputError("packed goal tracks must have the same knots and cuts", field="tracks")
    return build_track(first.times, np.concatenate([t.pos for t in tracks], axis=1), cuts=first.cut)


class PackedBakes:
    """Steps the chunks of B bakes, packed where their chunks can be (module docstring).

    models : B ParticleModels; names : their names. Each bake keeps a solver of its own (its starts, and its
    chunks that run alone); each set of bakes that runs packed gets a packed model and solver, made once.
    :attr:`packed_runs` and :attr:`alone_runs` count the runs of each kind.
    """

    def __init__(self, models, names=None, device: str | None = None):
        self.models = list(models)
        self.names = tuple(names) if names is not None else tuple(f"bake{b}" for b in range(len(self.models)))
        self.device = device or (self.models[0].device if self.models else "cpu")
        self.solvers = [ParticleSolver(m) for m in self.models]
        self._packs: dict[tuple, tuple[PackedModel, ParticleSolver]] = {}
        self.packed_runs = self.alone_runs = 0

    def pack_of(self, bakes: tuple) -> tuple[PackedModel, ParticleSolver]:
        """The packed model and solver of these bakes (indices), made once."""
        got = self._packs.get(bakes)
        if got is None:
            pm = pack_models([self.models[b] for b in bakes], [self.names[b] for b in bakes], self.device)
            got = self._packs[bakes] = (pm, ParticleSolver(pm.model))
        return got

    def grid_key(self, b: int, track: GoalTrack, times: np.ndarray, substeps: int) -> bytes:
        """What must be equal for bakes to run packed: the output times, knots, cuts and the step grid."""
        grid = step_times(np.asarray(times, np.float64), track.times, substeps, self.solvers[b].max_step)
        return b"|".join(np.ascontiguousarray(a).tobytes() for a in (times, track.times, track.cut, grid))

    def simulate(self, tracks, times, substeps: int, starts) -> list[tuple[np.ndarray, tuple]]:
        """One chunk of every bake: tracks (B,) GoalTracks, times (B,) output times (seconds), starts (B,) each
        (x, v) float32 to go on from, or None (the run starts on its goals, sim.jiggle.simulate.restart).
        Returns per bake (positions (T_b, N_b, 3) float64, (x, v) float32 end state): sim.jiggle.simulate.run's
        ``run(model, track, times, substeps, 0, solver, start=..., return_state=True)`` for each bake, bit for bit.
        """
        B = len(self.models)
        times = [np.asarray(t, np.float64) for t in times]
        groups: dict[bytes, list[int]] = {}
        for b in range(B):
            groups.setdefault(self.grid_key(b, tracks[b], times[b], substeps), []).append(b)
        out: list = [None] * B
        for members in groups.values():
            if len(members) == 1:
                b = members[0]
                out[b] = run(self.models[b], tracks[b], times[b], substeps, 0.0, self.solvers[b], start=starts[b],
                             return_state=True)
                self.alone_runs += 1
                continue
            bakes = tuple(members)
            pm, solver = self.pack_of(bakes)
            given = [starts[b] if starts[b] is not None else self._start(b, tracks[b], times[b][0]) for b in bakes]
            start = (pm.pack([g[0] for g in given]).astype(np.float32), pm.pack([g[1] for g in given]).astype(np.float32))
            x, (ex, ev) = run(pm.model, pack_tracks([tracks[b] for b in bakes]), times[bakes[0]], substeps, 0.0, solver,
                              start=start, return_state=True)
            for b, xb, exb, evb in zip(bakes, pm.unpack(x, axis=1), pm.unpack(ex), pm.unpack(ev)):
                out[b] = (xb, (exb, evb))
            self.packed_runs += 1
        return out

    def _start(self, b: int, track: GoalTrack, t0: float) -> tuple[np.ndarray, np.ndarray]:
        """Bake b's state at a run's start on its goals (sim.jiggle.simulate.restart, its own model alone)."""
        m, solver = self.models[b], self.solvers[b]
        if t0 < track.times[0] - TIME_EPS:
            raise InputError("a start outside the goal track", field="times")
        state = m.state()
        restart(m, solver, state, track.to_device(m.device), t0)
        x, v = state.x.numpy(), state.v.numpy()
        return x.copy(), v.copy()
