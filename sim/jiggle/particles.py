"""The particle model of the secondary motion: built once, frozen, then stepped by the solver.

One particle per muscle CV, all muscles flattened into one array (muscle m owns particles
``group_offsets[m]:group_offsets[m + 1]``). :class:`ParticleBuilder` collects particles and springs
in Python lists; :meth:`ParticleBuilder.finalize` checks them and returns a :class:`ParticleModel`
of read-only NumPy arrays and their Warp copies on one device. ``model.state()`` gives a
:class:`ParticleState` (positions and velocities, world metres, float32), the only thing a step
changes.

Forces (per particle i, offset y_i = x_i - g_i from the goal g_i, u_i = y_i'):

- goal spring: -m_i k_i y_i - m_i c_i u_i (k_i = omega_i^2, c_i = 2 zeta omega_i; see
  sim/jiggle/params.py); k_i = inf glues the particle to its goal;
- friction: -m_i mu_i v_i on the world velocity;
- neighbour spring (i, j): -k_ij (y_i - y_j) - c_ij (u_i - u_j), with k_ij = mu_ij omega_s^2 and
  c_ij = 2 zeta_s mu_ij omega_s on the pair's reduced mass mu_ij = m_i m_j / (m_i + m_j), so each spring
  alone rings at the muscle's spring frequency whatever the two masses. The springs act on the offsets: a
  zero-length spring between the two offsets, that is, a spring whose rest vector is the goal
  shape's current edge. A spring with a scalar rest length would fight the static shape whenever the
  muscle contracts and bulges; this one only resists the jiggle's differential motion, keeps the
  model linear, and conserves momentum (equal and opposite forces);
- gravity m_i g (when on).

Reach: `reach` (metres; inf: no limit) is where the tissue law (sim/jiggle/tissue_law.py) makes the goal
spring very stiff: linear to half of it, stiffening smoothly beyond, so a particle slows down and turns
back before it; no projection, no velocity removed. sim/jiggle/params.py says how far tissue may go.

Springs of a muscle (built by :meth:`ParticleBuilder.add_muscles`): each CV to its two nearest
neighbours at rest (the thesis), plus the structural ones the two nearest alone miss: around every
ring (each CV to the next in its section: keeps a section round) and along the muscle (CV r of
section s to CV r of section s + 1: carries a wave from the tendons along the belly). Each pair once.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np
import warp as wp

from jiggle.rig.base.errors import InputError
from jiggle.rig.base.frozen import frozen_array
from jiggle.sim.jiggle.params import CVS, RING, SECTIONS, MuscleJiggle

GRAVITY = 9.81
"""m/s^2, along -Z."""


@dataclass
class ParticleState:
    """Positions x and velocities v (N,) wp.vec3 float32, world metres and m/s."""

    x: wp.array
    v: wp.array

    def numpy(self) -> tuple[np.ndarray, np.ndarray]:
        """(x, v) as (N, 3) float64 copies."""
        return self.x.numpy().astype(np.float64), self.v.numpy().astype(np.float64)

    def assign(self, x: np.ndarray, v: np.ndarray) -> None:
        """Set the state from (N, 3) arrays."""
        self.x.assign(np.asarray(x, dtype=np.float32))
        self.v.assign(np.asarray(v, dtype=np.float32))


@dataclass(frozen=True, eq=False)
class ParticleModel:
    """The frozen particle model (NumPy arrays read-only; `wp_*` their float32/int32 device copies).

    mass : (N,) kg. goal_k : (N,) 1/s^2 (inf: glued). goal_c : (N,) 1/s. drag : (N,) 1/s.
    reach : (N,) metres (inf: no limit), where the tissue law (sim/jiggle/tissue_law.py) has stiffened the goal
        spring to GAIN times its linear force.
    glued : (N,) bool. rest : (N, 3) metres, positions at bind.
    springs : (E, 2) int64 particle pairs i < j. spring_k : (E,) N/m. spring_c : (E,) N s/m.
    adj_offsets : (N + 1,) CSR rows of each particle's springs; adj_index : (2E,) the other particle;
    adj_k, adj_c : (2E,) that spring's stiffness and damping.
    group_offsets : (G + 1,) particles of group g are group_offsets[g]:group_offsets[g + 1].
    group_names : (G,) names (the muscles), for messages.
    gravity : bool.
    """

    mass: np.ndarray
    goal_k: np.ndarray
    goal_c: np.ndarray
    drag: np.ndarray
    reach: np.ndarray
    glued: np.ndarray
    rest: np.ndarray
    springs: np.ndarray
    spring_k: np.ndarray
    spring_c: np.ndarray
    adj_offsets: np.ndarray
    adj_index: np.ndarray
    adj_k: np.ndarray
    adj_c: np.ndarray
    group_offsets: np.ndarray
    group_names: tuple
    gravity: bool
    device: str
    wp_inv_mass: wp.array
    wp_drag: wp.array
    wp_reach: wp.array
    wp_adj_offsets: wp.array
    wp_adj_index: wp.array
    wp_adj_k: wp.array
    wp_adj_c: wp.array

    @property
    def num_particles(self) -> int:
        return len(self.mass)

    @property
    def num_springs(self) -> int:
        return len(self.springs)

    @property
    def gravity_vector(self) -> np.ndarray:
        return np.array([0.0, 0.0, -GRAVITY if self.gravity else 0.0])

    def group_of(self, particle: int) -> str:
        """The name of the group (muscle) that owns `particle`."""
        g = int(np.searchsorted(self.group_offsets, particle, side="right")) - 1
        return self.group_names[g] if 0 <= g < len(self.group_names) else f"particle {particle}"

    def state(self) -> ParticleState:
        """A new state at the rest positions, at rest."""
        return ParticleState(wp.array(self.rest.astype(np.float32), dtype=wp.vec3, device=self.device),
                             wp.zeros(self.num_particles, dtype=wp.vec3, device=self.device))

    def spring_rate_bound(self) -> tuple[float, float]:
        """(omega, gamma): upper bounds of the neighbour springs' angular frequency (rad/s) and damping
        rate (1/s), the largest eigenvalues of M^-1/2 K M^-1/2 and M^-1/2 C M^-1/2 bounded by their
        Gershgorin row sums (glued particles are held and drop out). The step's explicit spring kicks
        are stable for omega h < 2 and gamma h < 2."""
        free = ~self.glued
        if self.num_springs == 0 or not free.any():
            return 0.0, 0.0
        rows = np.repeat(np.arange(self.num_particles), np.diff(self.adj_offsets))
        cols = self.adj_index
        scale = 1.0 / np.sqrt(self.mass[rows] * self.mass[cols])
        other = free[cols]
        bound = []
        for a in (self.adj_k, self.adj_c):
            diag = np.bincount(rows, weights=a, minlength=self.num_particles) / self.mass
            off = np.bincount(rows, weights=a * scale * other, minlength=self.num_particles)
            bound.append(float(np.max((diag + off)[free])))
        return math.sqrt(bound[0]), bound[1]

    def energy(self, x: np.ndarray, v: np.ndarray, goal: np.ndarray, goal_vel: np.ndarray) -> float:
        """Joules in the goal frame: kinetic of the offsets' velocities, goal-spring potential under the tissue
        law (sim.jiggle.tissue_law.energy_numpy) and neighbour-spring potential (glued particles and gravity
        excluded). x, v, goal, goal_vel : (N, 3)."""
        from jiggle.sim.jiggle.tissue_law import energy_numpy
        y, u = x - goal, v - goal_vel
        free = ~self.glued
        e = float(np.sum((self.mass * energy_numpy(y, u, self.goal_k, np.asarray(self.reach, dtype=np.float64)))[free]))
        if self.num_springs:
            d = y[self.springs[:, 0]] - y[self.springs[:, 1]]
            e += 0.5 * np.sum(self.spring_k * np.sum(d * d, axis=1))
        return float(e)


class ParticleBuilder:
    """Collects particles, springs and groups, then :meth:`finalize` freezes them. Particles and springs
    come one at a time or in bulk (arrays, checked at once): a muscle's 40 particles and ~90 springs are
    one call each."""

    _FIELDS = ("rest", "mass", "k", "c", "drag", "reach")

    def __init__(self):
        self._parts = {f: [] for f in self._FIELDS}
        self._spring_parts = {f: [] for f in ("ij", "k", "c")}
        self._n = 0
        self._groups, self._group_start = [], []

    @property
    def num_particles(self) -> int:
        return self._n

    def begin_group(self, name: str) -> None:
        """Particles added from now on belong to group `name` (a muscle), for messages."""
        self._groups.append(str(name))
        self._group_start.append(self.num_particles)

    def _where(self) -> str:
        return f"muscle {self._groups[-1]!r}" if self._groups else "particle"

    def add_particle(self, position, mass: float, goal_stiffness: float = math.inf, goal_damping: float = 0.0,
                     drag: float = 0.0, reach: float = math.inf) -> int:
        """Add a particle; returns its index.

        position : (3,) metres at rest. mass : kg > 0. goal_stiffness : k = omega^2 >= 0, 1/s^2 per unit
        mass (inf: glued to its goal). goal_damping : c >= 0, 1/s per unit mass. drag : mu >= 0, 1/s.
        reach : metres > 0 (inf: no limit), how far it may move from its goal.
        """
        p = np.asarray(position, dtype=np.float64).reshape(-1)
        if p.shape != (3,) or not np.isfinite(p).all():
            raise InputError(f"{self._where()}, particle {self.num_particles}: position must be 3 finite numbers, "
                             f"got {position!r}", field="position")
        return int(self.add_particles(p[None], [mass], [goal_stiffness], [goal_damping], [drag], [reach])[0])

    def add_particles(self, positions, mass, goal_stiffness, goal_damping, drag, reach) -> np.ndarray:
        """Add n particles at once (as :meth:`add_particle` each): positions (n, 3) metres, the rest (n,)
        arrays or scalars; returns their indices (n,). The first bad value is named as add_particle does."""
        p = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
        n = len(p)
        values = {f: np.broadcast_to(np.asarray(v, dtype=np.float64), (n,)).copy()
                  for f, v in (("mass", mass), ("goal_stiffness", goal_stiffness), ("goal_damping", goal_damping),
                               ("drag", drag), ("reach", reach))}
        bad_p = ~np.isfinite(p).all(axis=1)
        if bad_p.any():
            i = int(np.argmax(bad_p))
            raise InputError(f"{self._where()}, particle {self._n + i}: position must be 3 finite numbers, got "
                             f"{p[i].tolist()!r}", field="position")
        for f, expect in (("mass", "> 0 kg"), ("goal_stiffness", ">= 0 1/s^2"), ("goal_damping", ">= 0 1/s"),
                          ("drag", ">= 0 1/s"), ("reach", "> 0 m")):
            v = values[f]
            ok = (v > 0) if f in ("mass", "reach") else (v >= 0)
            if f not in ("goal_stiffness", "reach"):
                ok &= np.isfinite(v)
            if not ok.all():
                i = int(np.argmax(~ok))
                raise InputError(f"{self._where()}, particle {self._n + i}: {f} must be {expect}, "
                                 f"got {float(v[i])!r}", field=f)
        for f, v in zip(self._FIELDS, (p, values["mass"], values["goal_stiffness"], values["goal_damping"],
                                       values["drag"], values["reach"])):
            self._parts[f].append(v)
        self._n += n
        return np.arange(self._n - n, self._n)

    def add_spring(self, i: int, j: int, stiffness: float, damping: float = 0.0) -> None:
        """A neighbour spring between particles i != j: stiffness N/m >= 0, damping N s/m >= 0."""
        self.add_springs([[i, j]], [stiffness], [damping])

    def add_springs(self, pairs, stiffness, damping=0.0) -> None:
        """Add E springs at once (as :meth:`add_spring` each): pairs (E, 2) particle indices, stiffness and
        damping (E,) arrays or scalars."""
        ij = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
        E, n = len(ij), self.num_particles
        k = np.broadcast_to(np.asarray(stiffness, dtype=np.float64), (E,)).copy()
        c = np.broadcast_to(np.asarray(damping, dtype=np.float64), (E,)).copy()
        bad = (ij < 0).any(axis=1) | (ij >= n).any(axis=1) | (ij[:, 0] == ij[:, 1])
        if bad.any():
            e = int(np.argmax(bad))
            raise InputError(f"{self._where()}, spring ({ij[e, 0]}, {ij[e, 1]}): expected two different particles in "
                             f"[0, {n})", field="spring")
        for f, v in (("stiffness", k), ("damping", c)):
            ok = np.isfinite(v) & (v >= 0)
            if not ok.all():
                e = int(np.argmax(~ok))
                raise InputError(f"{self._where()}, spring ({ij[e, 0]}, {ij[e, 1]}): {f} must be a finite number >= 0, "
                                 f"got {float(v[e])!r}", field=f)
        self._spring_parts["ij"].append(np.sort(ij, axis=1))
        self._spring_parts["k"].append(k)
        self._spring_parts["c"].append(c)

    def add_muscles(self, rest_cvs: np.ndarray, rest_volume: np.ndarray, jiggles: Sequence[MuscleJiggle]) -> None:
        """One group of 40 particles per muscle, with the springs of the module docstring.

        rest_cvs : (40 M, 3) metres (rig.muscle.model.MuscleRig.rest_cvs). rest_volume : (M,) m^3.
        jiggles : M MuscleJiggle, in rig order.
        """
        rest_cvs = np.asarray(rest_cvs, dtype=np.float64).reshape(-1, SECTIONS, RING, 3)
        if len(rest_cvs) != len(jiggles) or len(rest_volume) != len(jiggles):
            raise InputError(f"expected one jiggle entry per muscle ({len(rest_cvs)}), got {len(jiggles)}",
                             field="jiggle")
        for cvs, volume, mj in zip(rest_cvs, rest_volume, jiggles):
            mj = mj.reference()          # keyed parameters: built at their reference values (sim/jiggle/keyed.py)
            self.begin_group(mj.name)
            if not (np.isfinite(volume) and volume > 0):
                raise InputError(f"muscle {mj.name!r}: rest volume must be > 0 m^3, got {volume!r}", field="volume")
            mass, k, c, ij, spring_k, spring_c = muscle_terms(cvs, float(volume) * mj.density, mj)
            base = self.num_particles
            self.add_particles(cvs.reshape(CVS, 3), mass, k, c, mj.friction, mj.reach if mj.reach > 0 else math.inf)
            if len(ij):
                self.add_springs(base + ij, spring_k, spring_c)

    def finalize(self, device: str = "cpu", gravity: bool = False) -> ParticleModel:
        """Freeze into a ParticleModel on `device` (CPU default; CUDA works unchanged)."""
        n = self.num_particles

        def cat(parts, shape=(0,)):
            return np.concatenate(parts) if parts else np.zeros(shape)
        rest, mass, k, goal_c, drag, reach = (cat(self._parts[f], (0, 3) if f == "rest" else (0,))
                                              for f in self._FIELDS)
        springs = cat(self._spring_parts["ij"], (0, 2)).astype(np.int64).reshape(-1, 2)
        sk, sc = cat(self._spring_parts["k"]), cat(self._spring_parts["c"])
        # CSR adjacency: each spring listed from both ends, rows in particle order
        ends = np.concatenate([springs, springs[:, ::-1]])
        order = np.lexsort((ends[:, 1], ends[:, 0]))
        ends = ends[order]
        adj_k, adj_c = np.concatenate([sk, sk])[order], np.concatenate([sc, sc])[order]
        offsets = np.zeros(n + 1, dtype=np.int64)
        np.cumsum(np.bincount(ends[:, 0], minlength=n), out=offsets[1:])
        glued = ~np.isfinite(k)
        groups = self._group_start or [0]
        names = tuple(self._groups) or ("particles",)
        inv_mass = np.where(glued, 0.0, 1.0 / np.maximum(mass, 1e-300)) if n else np.zeros(0)

        def dev(a, dtype):
            return wp.array(np.ascontiguousarray(a), dtype=dtype, device=device)

        return ParticleModel(
            mass=frozen_array(mass), goal_k=frozen_array(k), goal_c=frozen_array(goal_c),
            drag=frozen_array(drag), reach=frozen_array(reach),
            glued=frozen_array(glued, bool),
            rest=frozen_array(rest.reshape(n, 3)), springs=frozen_array(springs, np.int64),
            spring_k=frozen_array(sk), spring_c=frozen_array(sc), adj_offsets=frozen_array(offsets, np.int64),
            adj_index=frozen_array(ends[:, 1], np.int64), adj_k=frozen_array(adj_k), adj_c=frozen_array(adj_c),
            group_offsets=frozen_array(np.append(groups, n), np.int64), group_names=names, gravity=bool(gravity),
            device=str(device),
            wp_inv_mass=dev(inv_mass.astype(np.float32), wp.float32),
            wp_drag=dev(drag.astype(np.float32), wp.float32),
            # inf reaches as the largest float32: no offset ever reaches it
            wp_reach=dev(np.minimum(reach, np.finfo(np.float32).max).astype(np.float32), wp.float32),
            wp_adj_offsets=dev(offsets.astype(np.int32), wp.int32),
            wp_adj_index=dev(ends[:, 1].astype(np.int32), wp.int32),
            wp_adj_k=dev(adj_k.astype(np.float32), wp.float32),
            wp_adj_c=dev(adj_c.astype(np.float32), wp.float32))


def section_masses(cvs: np.ndarray, total: float) -> np.ndarray:
    """(40,) kg: `total` shared over the 5 sections in proportion to area x the arc spacing around
    each section's station, then equally over each ring's 8 CVs. cvs : (5, 8, 3) metres."""
    centre = cvs.mean(axis=1)                                             # (5, 3)
    rel = cvs - centre[:, None]
    area = 0.5 * np.linalg.norm(np.cross(rel, np.roll(rel, -1, axis=1)).sum(axis=1), axis=1)
    seg = np.linalg.norm(np.diff(centre, axis=0), axis=1)                 # (4,)
    spacing = 0.5 * (np.concatenate([[0.0], seg]) + np.concatenate([seg, [0.0]]))
    share = area * spacing
    if not share.sum() > 0:
        share = np.ones(SECTIONS)
    return np.repeat(total * share / share.sum() / RING, RING)


def muscle_terms(cvs: np.ndarray, total: float, jiggle: MuscleJiggle):
    """One muscle's particle terms: (mass (40,) kg, goal stiffness (40,) 1/s^2 (inf: glued), goal damping (40,)
    1/s, spring pairs (E, 2) (none without neighbour springs), their stiffness (E,) N/m and damping (E,) N s/m) for
    rest CVs (5, 8, 3) metres, `total` kg and `jiggle` (a MuscleJiggle at its reference values)."""
    mass = section_masses(np.asarray(cvs, np.float64).reshape(SECTIONS, RING, 3), total)
    k = jiggle.goal_stiffness()
    with np.errstate(invalid="ignore"):
        c = np.where(np.isfinite(k), 2.0 * jiggle.damping_ratio * np.sqrt(k), 0.0)
    if not jiggle.spring_frequency_hz > 0:
        return mass, k, c, np.zeros((0, 2), np.int64), np.zeros(0), np.zeros(0)
    w = 2.0 * math.pi * jiggle.spring_frequency_hz
    ij = muscle_springs(np.asarray(cvs, np.float64).reshape(CVS, 3))
    m_ = mass[ij[:, 0]] * mass[ij[:, 1]] / (mass[ij[:, 0]] + mass[ij[:, 1]])   # reduced mass: a light end CV stays slow
    return mass, k, c, ij, m_ * w * w, 2.0 * jiggle.spring_damping_ratio * m_ * w


def muscle_springs(cvs: np.ndarray) -> np.ndarray:
    """(E, 2) particle pairs i < j of one muscle's 40 CVs (rest positions (40, 3)): two nearest
    neighbours of each, every ring edge and every edge along the muscle, each pair once."""
    d = np.linalg.norm(cvs[:, None] - cvs[None], axis=2)
    np.fill_diagonal(d, np.inf)
    nearest = np.argsort(d, axis=1, kind="stable")[:, :2]
    pairs = [(i, int(j)) for i in range(CVS) for j in nearest[i]]
    idx = np.arange(CVS).reshape(SECTIONS, RING)
    pairs += list(zip(idx.reshape(-1), np.roll(idx, -1, axis=1).reshape(-1)))
    pairs += list(zip(idx[:-1].reshape(-1), idx[1:].reshape(-1)))
    return np.unique(np.sort(np.array(pairs, dtype=np.int64), axis=1), axis=0)


def muscle_model(rig, jiggles: Sequence[MuscleJiggle], device: str = "cpu", gravity: bool = False) -> ParticleModel:
    """The particle model of every muscle of `rig` (rig.muscle.model.MuscleRig)."""
    b = ParticleBuilder()
    b.add_muscles(rig.rest_cvs, rig.rest_volume, jiggles)
    return b.finalize(device, gravity=gravity)
