"""Keyable jiggle parameters: curves of keys, muscle globs, and the goal springs of keyed muscles per knot
interval (issue 23: a shot often wants the belly loose in the run and still in the close-up).

A parameter is a number or a **curve** of keys ``[[t, value], ...]`` (seconds of the motion as played,
times increasing), ``"linear"`` between keys (the default) or ``"smooth"`` (monotone cubic, Fritsch-Carlson,
as SciPy's PCHIP: it never overshoots its keys, so a curve stays inside the range its keys were checked
against), held before the first key and after the last. A curve whose keys are all one value is that
number (:func:`parse_curve` returns the float), so a keyed constant is the plain number bit for bit.

Keyable per muscle (PARAMETERS): ``strength`` J, ``frequency`` f, ``damping`` zeta, ``goal_scale`` s (the
goal weights become clip(s w, 0, 1)) and ``blend``; globally ``strength`` and ``blend``.

**Sampling: held per knot interval.** The particles' goals are sampled at fixed knots (120 Hz by default,
whatever the output rate; sim/jiggle/secondary.py: knot_times) and the solver's steps break at knots. A keyed
goal spring is held constant on each knot interval at its curve's value at the interval's midpoint, so each
step still has the exact flow of a linear spring (sim/jiggle/goal_flow.py) and the parameters a particle sees
do not depend on the output rate or the substeps at all (sampling on the substep grid would: a different
grid, different values). The error against the continuous curve is that of the midpoint rule on 1/120 s
intervals, far below the jiggle's own time scales. The blend is applied per output frame (sim/jiggle/blend.py).

Per knot interval j and particle i of a keyed muscle (the model of sim/jiggle/params.py at the interval's
values; particles.py: add_muscles)::

    w = clip(s goal_i, 0, 1)       k = (2 pi f)^2 / J * w / (1 - w)   (inf: glued, when w = 1 or J = 0)
    c = 2 zeta sqrt(k) + friction  reach = J max_offset               (inf when max_offset is)

and a step of length h in interval j uses the goal flow of (k, c, h): one 5x5 matrix exponential per
distinct (k, c, h). :func:`sim.jiggle.goal_flow.expm_batch` computes them all at once (vectorised scaling and squaring with
a degree 13 Pade approximant, Higham 2005): SciPy's ``expm`` loops in Python over a batch (~100 us a
matrix), which would cost a keyed chunk a second.

**Globs.** A per-muscle table is named by a muscle's name or an fnmatch glob (``"*_fat"``, ``"left_*"``).
For every key, the most specific entry wins: an exact name beats any glob, and among globs the later
entry beats the earlier (scene tables in file order, flags in the order given). The command line's entries
are a layer over the scene's (sim/bake/setup.py: _settings), so there a glob beats the scene's exact name. An
unknown exact name or a glob that matches no muscle is an error naming the entry (:func:`resolve_tables`).

**The model of a keyed muscle** is built once at reference values (:func:`reference_values`: the largest
strength key, the smallest goal_scale key), so a particle is glued in it (inverse mass 0, no spring kicks)
only if it is glued at every time; a particle glued on some intervals only has a zero goal flow there, which
holds its offset at exactly 0 (sim/jiggle/keyed_solver.py, sim/jiggle/keyed_kernels.py).
"""
from __future__ import annotations

import fnmatch
import json
import math
from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

from jiggle.rig.base.errors import InputError
from jiggle.rig.base.frozen import frozen_array
from jiggle.sim.jiggle import tissue_law

INTERPOLATIONS = ("linear", "smooth", "step")


@dataclass(frozen=True)
class Parameter:
    """One jiggle parameter as the user sets it: its one documented name (scene key, CLI flag, bake.json
    name), other accepted spellings, unit, range [lo, hi] (lo excluded when lo_open), default (text),
    whether it is keyable, and the MuscleJiggle attribute it sets (None: a global setting)."""

    name: str
    unit: str
    lo: float
    hi: float
    lo_open: bool = False
    keyable: bool = False
    attribute: str | None = None
    aliases: tuple = ()
    default: str = ""
    what: str = ""

    def check(self, v: float) -> bool:
        return (v > self.lo if self.lo_open else v >= self.lo) and v <= self.hi

    @property
    def range_text(self) -> str:
        lo = "(" if self.lo_open else "["
        hi = "inf)" if math.isinf(self.hi) else f"{self.hi:g}]"
        return f"{lo}{self.lo:g}, {hi}"


PARAMETERS = {p.name: p for p in (
    Parameter("strength", "", 0.0, 1.0, keyable=True, attribute="strength", aliases=("jiggle",), default="1",
              what="jiggle strength J: goal stiffness / J, reach x J; 0 glues the muscle to its static shape"),
    Parameter("frequency", "Hz", 0.0, math.inf, lo_open=True, keyable=True, attribute="frequency_hz",
              default="7 (muscle), 4 (fat)", what="goal-spring frequency of a particle of goal weight 1/2 at J = 1"),
    Parameter("damping", "", 0.0, math.inf, keyable=True, attribute="damping_ratio", default="0.5 (muscle), 0.3 (fat)",
              what="goal-spring damping ratio zeta"),
    Parameter("goal_scale", "", 0.0, math.inf, keyable=True, attribute="goal_scale", default="1",
              what="multiplies the goal weights (clipped to [0, 1]): > 1 stiffer, < 1 looser"),
    Parameter("blend", "", 0.0, 1.0, keyable=True, attribute="blend", default="1",
              what="static_dyn_blend: cvs = static + b (dynamic - static)"),
)}
"""The keyable parameters, by their documented name."""


# ---------------------------------------------------------------------------------------------- curves
@dataclass(frozen=True, eq=False)
class Curve:
    """A parameter over time: keys `times` (K,) seconds increasing, `values` (K,), linear, smooth (monotone
    cubic) or step (each key's value held until the next key) between keys, held outside them. Build with
    :func:`parse_curve`."""

    times: np.ndarray
    values: np.ndarray
    interpolation: str = "linear"

    def __post_init__(self):
        object.__setattr__(self, "times", frozen_array(np.atleast_1d(np.asarray(self.times, dtype=np.float64))))
        object.__setattr__(self, "values", frozen_array(np.atleast_1d(np.asarray(self.values, dtype=np.float64))))
        if self.interpolation not in INTERPOLATIONS:
            raise InputError(f"interpolation must be one of {', '.join(INTERPOLATIONS)}, got {self.interpolation!r}",
                             field="interpolation")

    def __call__(self, t) -> np.ndarray:
        """Values at times `t` (seconds, any shape), float64, same shape."""
        t = np.asarray(t, dtype=np.float64)
        if len(self.times) == 1:
            return np.full(t.shape, self.values[0])
        if self.interpolation == "linear":
            return np.interp(t, self.times, self.values)
        if self.interpolation == "step":
            return self.values[np.clip(np.searchsorted(self.times, t, side="right") - 1, 0, len(self.times) - 1)]
        from scipy.interpolate import PchipInterpolator
        return PchipInterpolator(self.times, self.values)(np.clip(t, self.times[0], self.times[-1]))

    @property
    def lo(self) -> float:
        """The smallest value the curve takes (a key's: every interpolation stays within its keys)."""
        return float(self.values.min())

    @property
    def hi(self) -> float:
        return float(self.values.max())

    def to_json(self):
        """{"times": [...], "values": [...], "interpolation": ...}: what bake.json and jiggle.json record
        (parse_curve reads it back)."""
        return {"times": [float(t) for t in self.times], "values": [float(v) for v in self.values],
                "interpolation": self.interpolation}

    def __repr__(self) -> str:
        return f"Curve({json.dumps(self.to_json())})"

    def __eq__(self, other) -> bool:
        return isinstance(other, Curve) and self.interpolation == other.interpolation and \
            np.array_equal(self.times, other.times) and np.array_equal(self.values, other.values)

    __hash__ = None


def _number(v) -> bool:
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))


def parse_curve(value, name: str, where: str | None = None, table: Mapping | None = None) -> "float | Curve":
    """A parameter's value: a number, keys [[t, v], ...] (linear), or a table {keys = [[t, v], ...],
    interpolation = "linear" | "smooth" | "step"}; a Curve or float passes through checked. Returns a float when the
    value is a number or every key holds the same value, else a Curve. InputError naming `where` (default
    the parameter's name) for a value outside the parameter's range, key times that do not increase, or a
    malformed value.

    name : a key of `table` (default PARAMETERS; sim.chain.params.CHAIN_PARAMETERS for a chain's), whose range
    is checked.
    """
    p = (PARAMETERS if table is None else table)[name]
    where = where or name
    expect = f"a number in {p.range_text} or keys [[time_s, value], ...] (optionally {{keys = ..., interpolation = " \
             f"\"smooth\"}})"
    interpolation = "linear"
    if isinstance(value, Curve):
        keys = np.stack([value.times, value.values], axis=1)
        interpolation = value.interpolation
    elif _number(value):
        keys = np.array([[0.0, float(value)]])
    else:
        if isinstance(value, Mapping) and "times" in value and "keys" not in value:     # a to_json record
            value = {"keys": [list(k) for k in zip(value.get("times", []), value.get("values", []))]
                     if len(value.get("times", [])) == len(value.get("values", ())) else None,
                     **{k: v for k, v in value.items() if k not in ("times", "values")}}
        if isinstance(value, Mapping):
            extra = sorted(set(value) - {"keys", "interpolation"})
            if extra or "keys" not in value:
                raise InputError(f"expected {expect}, got {value!r}", field=where)
            interpolation = value.get("interpolation", "linear")
            if interpolation not in INTERPOLATIONS:
                raise InputError(f"interpolation must be one of {', '.join(INTERPOLATIONS)}, got {interpolation!r}",
                                 field=where)
            value = value["keys"]
        ok = isinstance(value, (list, tuple, np.ndarray)) and len(value) > 0 and all(
            isinstance(k, (list, tuple, np.ndarray)) and len(k) == 2 and all(_number(x) for x in k) for k in value)
        if not ok:
            raise InputError(f"expected {expect}, got {value!r}", field=where)
        keys = np.asarray(value, dtype=np.float64).reshape(-1, 2)
    if not np.isfinite(keys[:, 0]).all() or np.isnan(keys[:, 1]).any() or \
            (np.isinf(keys[:, 1]) & np.isinf(p.hi) & (keys[:, 1] > 0)).any():
        raise InputError(f"{name} keys hold NaN or inf", field=where)
    d = np.diff(keys[:, 0])
    if np.any(d <= 0):
        k = int(np.argmax(d <= 0)) + 1
        raise InputError(f"{name} key times must increase: key {k + 1} at t = {keys[k, 0]:g} s follows "
                         f"t = {keys[k - 1, 0]:g} s",
                         field=where)
    bad = [i for i, v in enumerate(keys[:, 1]) if not p.check(float(v))]
    if bad:
        i = bad[0]
        at = "" if len(keys) == 1 and not isinstance(value, (list, tuple, np.ndarray, Curve)) else \
            f" at t = {keys[i, 0]:g} s (key {i + 1})"
        unit = f" {p.unit}" if p.unit else ""
        raise InputError(f"{name} must be in {p.range_text}{unit}, got {keys[i, 1]:g}{at}", field=where)
    if np.all(keys[:, 1] == keys[0, 1]):
        return float(keys[0, 1])
    return Curve(keys[:, 0], keys[:, 1], interpolation)


def parse_text(text: str, name: str, where: str, table: Mapping | None = None) -> "float | Curve":
    """A command-line value: a number, keys ``[[0,1],[2,0.2]]`` (linear) or ``smooth:[[0,1],[2,0.2]]`` or
    ``step:[[0,1],[2,0.2]]`` (JSON or TOML lists). InputError naming `where` (the flag) otherwise."""
    s = text.strip()
    interpolation = None
    for mode in INTERPOLATIONS:
        if s.lower().startswith(mode + ":"):
            interpolation, s = mode, s[len(mode) + 1:].strip()
    try:
        value = float(s) if not s.startswith("[") else json.loads(s)
    except ValueError:
        raise InputError(f"expected a number or keys [[time_s, value], ...] (smooth:[[...]] or step:[[...]] for "
                         f"smooth or held keys), got {text!r}",
                         field=where) from None
    if interpolation is not None:
        if not isinstance(value, list):
            raise InputError(f"{interpolation}: takes keys [[time_s, value], ...], got {s!r}", field=where)
        value = {"keys": value, "interpolation": interpolation}
    return parse_curve(value, name, where, table)


def parse_assignment(text: str, name: str, flag: str, global_ok: bool = True, table: Mapping | None = None):
    """A repeatable flag's value ``[NAME=]VALUE|CURVE``: (pattern or None for the global value, value).
    NAME is a muscle or a glob; without it the value is every muscle's (global_ok) or pattern "*"."""
    s = text.strip()
    pattern = None
    head, sep, tail = s.partition("=")
    if sep and head.strip() and not head.strip()[0].isdigit() and not head.strip().startswith(("[", "-", ".")) \
            and not head.strip().lower().startswith(tuple(m + ":" for m in INTERPOLATIONS)):
        pattern, s = head.strip(), tail
    where = f"{flag} {text.strip()}"
    value = parse_text(s, name, where, table)
    if pattern is None and not global_ok:
        pattern = "*"
    return pattern, value


def value_at(v, t) -> np.ndarray:
    """A number or Curve at times t (seconds): float64 array of t's shape."""
    return v(t) if isinstance(v, Curve) else np.full(np.shape(t), float(v))


def jsonable_value(v):
    """A number, or a Curve as {"keys": ..., "interpolation": ...}."""
    return v.to_json() if isinstance(v, Curve) else v


# ----------------------------------------------------------------------------------------------- globs
def is_glob(name: str) -> bool:
    return any(ch in name for ch in "*?[")


def resolve_tables(entries: Sequence[tuple], names: Sequence[str]) -> dict:
    """Per muscle, the merged table of the entries that name it.

    entries : (pattern, table, where) in order: pattern a muscle name or an fnmatch glob, table
        {key: value}, where the entry's place for messages (e.g. "jiggle.muscles.*_fat" or "--jiggle
        *_fat=..."), or an InputError-ready tuple (where, path, line).
    names : the rig's muscles.
    Returns {name: {key: (value, where)}}; for each key the most specific entry: an exact name beats a
    glob, a later glob beats an earlier one (an exact name given twice: the later). InputError naming the
    entry for an unknown name or a glob that matches no muscle.
    """
    names = list(names)
    known = set(names)
    ranked = []                          # (specificity, order, names matched, table, where)
    for order, (pattern, table, where) in enumerate(entries):
        path = line = None
        if isinstance(where, tuple):
            where, path, line = where
        if is_glob(pattern):
            hit = [n for n in names if fnmatch.fnmatchcase(n, pattern)]
            if not hit:
                raise InputError(f"the glob {pattern!r} matches no muscle; the muscles are "
                                 f"{', '.join(names) or '(none)'}",
                                 path, line, field=where)
            ranked.append((0, order, hit, table, where))
        else:
            if pattern not in known:
                raise InputError(f"the rig has no muscle {pattern!r}; its muscles are {', '.join(names) or '(none)'}",
                                 path, line, field=where)
            ranked.append((1, order, [pattern], table, where))
    out: dict = {}
    for _, _, hit, table, where in sorted(ranked, key=lambda r: (r[0], r[1])):
        for n in hit:
            for k, v in table.items():
                out.setdefault(n, {})[k] = (v, where)
    return out


# ------------------------------------------------------------------------------- keyed goal springs
KEYED_ATTRIBUTES = ("strength", "frequency_hz", "damping_ratio", "goal_scale")
"""The MuscleJiggle attributes that shape the goal springs and may hold a Curve (blend is applied apart)."""


def muscle_curves(mj) -> dict:
    """{attribute: Curve} of a MuscleJiggle's keyed goal-spring attributes (KEYED_ATTRIBUTES)."""
    return {a: getattr(mj, a) for a in KEYED_ATTRIBUTES if isinstance(getattr(mj, a, None), Curve)}


def reference_values(mj) -> dict:
    """The values a keyed MuscleJiggle's particle model is built with: each Curve replaced by the bound
    that never glues a particle the curve frees (strength: its largest key; goal_scale: its smallest;
    frequency, damping: their first key, any value would do). A particle glued in that model (w = 1 at
    the smallest scale, or J = 0 throughout) is glued at every time."""
    out = {}
    for a, cv in muscle_curves(mj).items():
        out[a] = cv.hi if a == "strength" else cv.lo if a == "goal_scale" else float(cv.values[0])
    return out


def goal_springs(goal: np.ndarray, strength, frequency_hz, damping_ratio, goal_scale, max_offset: float,
                 t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A muscle's goal springs at times t (S,) seconds, each parameter a number or a Curve:
    k (S, 40) 1/s^2 (inf: glued), c (S, 40) 1/s goal damping (without the friction) and reach (S, 40)
    metres (inf: none); the arithmetic of MuscleJiggle.goal_stiffness, ParticleBuilder.add_muscles and
    MuscleJiggle.reach, per time.

    goal : (40,) goal weights in [0, 1]. max_offset : metres at strength 1 (inf: none).
    """
    t = np.asarray(t, dtype=np.float64).reshape(-1)
    J, f, z, s = (value_at(v, t)[:, None] for v in (strength, frequency_hz, damping_ratio, goal_scale))
    w = np.asarray(goal, dtype=np.float64)[None]
    w = np.where(s == 1.0, w, np.clip(w * s, 0.0, 1.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        k = (2.0 * math.pi * f) ** 2 / J * w / (1.0 - w)
    k = np.where((w >= 1.0) | (J == 0.0), np.inf, k)
    with np.errstate(invalid="ignore"):
        c = np.where(np.isfinite(k), 2.0 * z * np.sqrt(k), 0.0)
    reach = np.broadcast_to(J * max_offset if math.isfinite(max_offset) else np.full_like(J, np.inf), k.shape)
    reach = np.where(reach > 0, reach, np.inf)
    return k, c, np.ascontiguousarray(reach)


class Schedule:
    """The keyed goal springs of a particle model: which particles are keyed, and their stiffness,
    damping and reach on any knot interval (held at its midpoint, see the module).

    model : the sim.jiggle.particles.ParticleModel (built with :func:`reference_values`).
    jiggles : the MuscleJiggle of each of the model's groups, in order (those with Curves are keyed).
    thread_offsets : (T + 1,) particle offsets of the solver's thread groups (sim.jiggle.solver.thread_groups);
        a thread group with a keyed muscle is keyed whole.
    """

    def __init__(self, model, jiggles: Sequence, thread_offsets: np.ndarray):
        self.model = model
        self.jiggles = list(jiggles)
        g = np.asarray(model.group_offsets, dtype=np.int64)
        if len(self.jiggles) != len(g) - 1:
            raise InputError(f"expected {len(g) - 1} jiggle entries (one per muscle), got {len(self.jiggles)}",
                             field="jiggle")
        self.keyed_muscles = np.array([m for m, j in enumerate(self.jiggles) if muscle_curves(j)], dtype=np.int64)
        """(Mk,) indices of the keyed muscles."""
        to = np.asarray(thread_offsets, dtype=np.int64)
        keyed = np.zeros(model.num_particles, bool)
        for m in self.keyed_muscles:
            keyed[g[m]:g[m + 1]] = True
        hit = np.array([keyed[to[i]:to[i + 1]].any() for i in range(len(to) - 1)], dtype=bool)
        self.thread_offsets = to
        self.keyed_threads = np.flatnonzero(hit)
        """(Tk,) the thread groups holding a keyed muscle."""
        self.particles = np.concatenate([np.arange(to[i], to[i + 1]) for i in self.keyed_threads]) \
            if len(self.keyed_threads) else np.zeros(0, np.int64)
        """(P,) the particles of the keyed thread groups, in order: the columns of :meth:`at`."""
        starts = np.concatenate([[0], np.cumsum(np.diff(to)[self.keyed_threads])])
        self.thread_start = starts[:-1]
        """(Tk,) where each keyed thread group's particles start among `particles`."""

    @property
    def empty(self) -> bool:
        return len(self.keyed_muscles) == 0

    def at(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(k, c, reach), each (S, P): the keyed thread groups' particles' goal stiffness (1/s^2, inf glued),
        goal damping plus friction (1/s) and reach (metres, inf none) at times t (S,) seconds (unkeyed
        muscles in those groups at their model values)."""
        t = np.asarray(t, dtype=np.float64).reshape(-1)
        m = self.model
        p = self.particles
        k = np.broadcast_to(m.goal_k[p], (len(t), len(p))).copy()
        c = np.broadcast_to(m.goal_c[p], (len(t), len(p))).copy()
        reach = np.broadcast_to(m.reach[p], (len(t), len(p))).copy()
        col = np.full(m.num_particles, -1, np.int64)
        col[p] = np.arange(len(p))
        g = m.group_offsets
        for mm in self.keyed_muscles:
            j = self.jiggles[mm]
            cols = col[g[mm]:g[mm + 1]]
            kk, cc, rr = goal_springs(j.goal, j.strength, j.frequency_hz, j.damping_ratio,
                                      getattr(j, "goal_scale", 1.0), j.max_offset, t)
            k[:, cols], c[:, cols], reach[:, cols] = kk, cc, rr
        return k, c + m.drag[p][None], reach

    def model_at(self, t: float):
        """The particle model with the keyed muscles' goal springs at time t (host arrays goal_k, goal_c,
        reach, glued; what sim.jiggle.simulate.restart reads for a start's equilibrium)."""
        from dataclasses import replace
        if self.empty:
            return self.model
        m = self.model
        k, c, reach = self.at(np.array([t]))
        gk, gc, rr = (np.array(a, dtype=np.float64) for a in (m.goal_k, m.goal_c, m.reach))
        gk[self.particles], gc[self.particles], rr[self.particles] = k[0], c[0] - m.drag[self.particles], reach[0]
        return replace(m, goal_k=frozen_array(gk), goal_c=frozen_array(gc), reach=frozen_array(rr),
                       glued=frozen_array(~np.isfinite(gk), bool))

    def flows(self, times: np.ndarray, seg: np.ndarray, dts: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The keyed rows of a run of steps: step k in knot interval seg[k] (of the track's `times`) of length
        dts[k] seconds. Returns (coeffs (U, tissue_law.ROW) float64, one tissue flow row per distinct (stiffness,
        damping, step length); index (B, P) int64, the row of each keyed particle in each block; reach (B, P)
        float64; block (K,) int64, each step's block): one block per distinct (interval, step length) (lengths
        equal to 1e-12 s share one)."""
        times = np.asarray(times, dtype=np.float64)
        hkey = np.round(np.asarray(dts, dtype=np.float64), 12)
        pairs, block = np.unique(np.stack([np.asarray(seg, dtype=np.float64), hkey], axis=1), axis=0,
                                 return_inverse=True)
        segs, inv_seg = np.unique(pairs[:, 0].astype(np.int64), return_inverse=True)
        mid = 0.5 * (times[segs] + times[segs + 1])
        k, c, reach = self.at(mid)                                   # (S, P)
        P = len(self.particles)
        hh = np.repeat(pairs[:, 1], P)
        kk, cc = k[inv_seg].reshape(-1), c[inv_seg].reshape(-1)
        # a row is a function of its (k, c, h) alone: each distinct triple once (a stiffness keyed on every interval
        # repeats across particles of one section and across intervals whose keys step, sim.jiggle.activation)
        if len(np.unique(pairs[:, 1])) == 1:                        # one step length: (k, c) as one sort key
            key = kk + 1j * cc
        else:
            codes = [np.unique(x, return_inverse=True) for x in (kk, cc, hh)]
            key = (codes[0][1].reshape(-1) * len(codes[1][0]) + codes[1][1].reshape(-1)) * len(codes[2][0]) + \
                codes[2][1].reshape(-1)
        _, first, inverse = np.unique(key, return_index=True, return_inverse=True)
        coeffs = tissue_law.rows(kk[first], cc[first], hh[first])
        return coeffs, inverse.reshape(len(pairs), P), reach[inv_seg], block.reshape(-1)
