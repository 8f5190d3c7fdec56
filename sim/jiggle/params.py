"""What the animator sets for the secondary motion: per-muscle jiggle parameters and the blend curves.

The particle model (sim/jiggle/particles.py) puts one particle on each of a muscle's 40 CVs. These are the
knobs, all in continuous time so that nothing depends on the frame rate or the substep count:

- Goal springs. Particle i is pulled toward its goal (the static CV) with angular frequency

      omega_i = 2 pi f / sqrt(J) * sqrt(w_i / (1 - w_i))

  and damping ratio zeta, relative to the goal's velocity:
  ``y'' = -omega_i^2 y - 2 zeta omega_i y' + ...`` for the offset y = x - goal.
  f (Hz) is the frequency a particle of goal weight 1/2 has at strength 1. The goal weight w_i in
  [0, 1] scales the stiffness by w / (1 - w), so w = 1 glues the particle (infinitely stiff), w = 0
  frees it and w = 1/2 keeps f.
- Jiggle strength J in [0, 1] replaces Maya's goal smoothness (the thesis's "jiggle strength"). It
  scales the goal springs' compliance: stiffness k = k(J = 1) / J. A quasi-static offset under an
  acceleration a is a / omega^2, so **the jiggle's size grows in proportion to J**, while the damping
  ratio, and so how many wobbles a landing makes, stays put; the wobble gets faster as J drops, by
  1 / sqrt(J). J = 0 glues every particle to its goal. Users who think in frequency and damping give
  ``frequency`` and ``damping`` and leave J at 1.
- Neighbour springs with their own frequency (on the mean particle mass) and damping ratio, and a
  friction: a drag on the world velocity, 1/s.
- Masses: the muscle's rest volume times its density, shared over the sections in proportion to
  their volume and over each section's 8 CVs equally.
- Reach: how far a CV may swing from its static place, ``J x max_offset`` (metres): tissue does
  not stretch without end, and a soft goal driven hard (a fat pad of goal weight 0.1 on a landing)
  would otherwise swing several of its own thicknesses (issue 18 measured glute fat 7.6 cm past a pad
  1.8 cm thick). The default max_offset is MAX_OFFSET_RADII[kind] x the muscle's mean rest radius: 1.5
  radii for a muscle, 2.5 for fat; like the jiggle's size, the reach scales with J. The goal spring is
  linear to half the reach and stiffens smoothly beyond (sim/jiggle/tissue_law.py): the tissue slows
  down as it nears its reach and turns back, as tissue does, instead of stopping dead at a wall.

Goal weights default from the template's tendon and belly values: sections (end, bulge, middle,
bulge, end) get (tendon, mean, belly, mean, tendon); painted weights (one per CV) replace them.

``static_dyn_blend`` (the thesis appendix's blend shape) mixes static and dynamic CVs before the
skin deformers, ``cvs = static + b (dynamic - static)``: a :class:`BlendCurve` per muscle, keyable
(linear between keys, held before the first and after the last), defaulting to the global curve.

Keyable: strength, frequency, damping, goal_scale (a multiplier of the goal weights, clipped to [0, 1]) and
blend are each a number or a curve of keys (sim/jiggle/keyed.py: the syntax, linear or smooth, and how the
solver holds a keyed goal spring per goal-knot interval); a MuscleJiggle's attribute then holds a
sim.jiggle.keyed.Curve, and its particle model is built from :meth:`MuscleJiggle.reference`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Mapping

import numpy as np

from jiggle.rig.base.errors import InputError
from jiggle.rig.base.frozen import frozen_array
from jiggle.sim.jiggle.keyed import PARAMETERS, Curve, muscle_curves, parse_curve, reference_values

CVS = 40
SECTIONS, RING = 5, 8
MAX_OFFSET_RADII = {"muscle": 1.5, "fat": 2.5}
"""A CV's reach at strength 1, in its muscle's mean rest radii, per kind (see the module)."""
KEYABLE = {p.attribute: p.name for p in PARAMETERS.values() if p.attribute not in (None, "blend")}
"""MuscleJiggle attributes that may hold a Curve -> the parameter's documented name."""


@dataclass(frozen=True, eq=False)
class BlendCurve(Curve):
    """A value in [0, 1] over time: keys `times` (K,) seconds ascending, `values` (K,), linear (or smooth)
    between keys and held outside them (sim.jiggle.keyed.Curve). K = 1 is a constant."""

    @classmethod
    def constant(cls, value: float) -> "BlendCurve":
        return cls(np.zeros(1), np.array([float(value)]))

    @classmethod
    def parse(cls, value, where: str) -> "BlendCurve":
        """A number, keys [[t, b], ...] (seconds, blend) or {keys = ..., interpolation = "smooth"} (the syntax of
        every keyable parameter, sim.jiggle.keyed.parse_curve); InputError naming `where` otherwise."""
        if isinstance(value, BlendCurve):
            return value
        if isinstance(value, Curve):
            value = {"keys": np.stack([value.times, value.values], axis=1).tolist(),
                     "interpolation": value.interpolation}
        if isinstance(value, (list, tuple)) and len(value) == 1 and isinstance(value[0], (list, tuple)) \
                and len(value[0]) == 2:
            value = value[0][1]                     # one key: its value (held everywhere), as before
        v = parse_curve(value, "blend", where)
        return cls.constant(v) if not isinstance(v, Curve) else cls(v.times, v.values, v.interpolation)

    @property
    def is_zero(self) -> bool:
        return bool(np.all(self.values == 0.0))


@dataclass(frozen=True, eq=False)
class MuscleJiggle:
    """One muscle's simulation parameters (see the module docstring for the model).

    name : the muscle. frequency_hz : f > 0, Hz. damping_ratio : zeta >= 0 of the goal springs.
    strength : J in [0, 1]. goal_scale : >= 0, multiplies the goal weights (clipped to [0, 1]).
    strength, frequency_hz, damping_ratio and goal_scale may each be a sim.jiggle.keyed.Curve (keys given as
    lists or {keys, interpolation} are parsed; keys all equal become the number).
    density : kg/m^3 > 0. spring_frequency_hz : >= 0, Hz (0: no neighbour
    springs). spring_damping_ratio : >= 0. friction : >= 0, 1/s.
    goal : (40,) goal weights in [0, 1], one per CV (rig.muscle.model order: section-major, 8 per ring).
    blend : the muscle's static_dyn_blend curve, or None for the global one.
    max_offset : metres > 0 (inf: none), the reach at strength 1 (the tissue law stiffens toward it); at
        strength J the reach is J x max_offset (`reach`).
    """

    name: str
    frequency_hz: float
    damping_ratio: float
    goal: np.ndarray
    density: float
    strength: float = 1.0
    spring_frequency_hz: float = 0.0
    spring_damping_ratio: float = 0.0
    friction: float = 0.0
    blend: BlendCurve | None = None
    max_offset: float = math.inf
    goal_scale: float = 1.0

    def __post_init__(self):
        where = f"muscle {self.name!r}"
        for f, name in KEYABLE.items():
            v = getattr(self, f)
            if isinstance(v, (Curve, list, tuple, dict, Mapping)):
                object.__setattr__(self, f, parse_curve(v, name, f))     # a Curve, or the number all keys hold
        for f in ("frequency_hz", "damping_ratio", "density", "strength", "spring_frequency_hz",
                  "spring_damping_ratio", "friction", "max_offset", "goal_scale"):
            if isinstance(getattr(self, f), Curve):
                continue                                                  # checked key by key by parse_curve
            try:
                v = float(getattr(self, f))
            except (TypeError, ValueError):
                raise InputError(f"{where}: {f} must be a number, got {getattr(self, f)!r}", field=f) from None
            if math.isnan(v) or (not math.isfinite(v) and f != "max_offset"):
                raise InputError(f"{where}: {f} is NaN or inf", field=f)
            object.__setattr__(self, f, v)
        g = np.asarray(self.goal, dtype=np.float64).reshape(-1)
        if g.shape != (CVS,):
            raise InputError(f"{where}: goal weights must be {CVS} values (one per CV), got {g.size}", field="goal")
        bad = ~((g >= 0) & (g <= 1))
        if bad.any():
            k = int(np.argmax(bad))
            raise InputError(f"{where}: goal weight of CV {k} must be in [0, 1], got {g[k]:g}", field="goal")
        object.__setattr__(self, "goal", frozen_array(g))
        plain = {f: getattr(self, f) if not isinstance(getattr(self, f), Curve) else None for f in KEYABLE}
        checks = (("frequency_hz", plain["frequency_hz"] is None or plain["frequency_hz"] > 0, "> 0 Hz"),
                  ("damping_ratio", plain["damping_ratio"] is None or plain["damping_ratio"] >= 0, ">= 0"),
                  ("density", self.density > 0, "> 0 kg/m^3"),
                  ("strength", plain["strength"] is None or 0 <= plain["strength"] <= 1, "in [0, 1]"),
                  ("goal_scale", plain["goal_scale"] is None or plain["goal_scale"] >= 0, ">= 0"),
                  ("spring_frequency_hz", self.spring_frequency_hz >= 0, ">= 0 Hz"),
                  ("spring_damping_ratio", self.spring_damping_ratio >= 0, ">= 0"),
                  ("friction", self.friction >= 0, ">= 0 1/s"),
                  ("max_offset", self.max_offset > 0, "> 0 m"))
        for f, ok, expect in checks:
            if not ok:
                raise InputError(f"{where}: {f} must be {expect}, got {getattr(self, f):g}", field=f)
        if self.blend is not None and not isinstance(self.blend, BlendCurve):
            object.__setattr__(self, "blend", BlendCurve.parse(self.blend, f"{where}.blend"))

    @property
    def keyed(self) -> dict:
        """{attribute: Curve} of the keyed goal-spring attributes (strength, frequency_hz, damping_ratio,
        goal_scale); empty for a plain muscle."""
        return muscle_curves(self)

    def reference(self) -> "MuscleJiggle":
        """This muscle with every Curve replaced by the number its particle model is built with
        (sim.jiggle.keyed.reference_values: the largest strength, the smallest goal_scale); itself when
        nothing is keyed."""
        ref = reference_values(self)
        return replace(self, **ref) if ref else self

    @property
    def reach(self) -> float:
        """metres: how far a CV may move from its goal, strength x max_offset (inf: no limit); for a keyed
        strength, at its largest key."""
        if self.keyed:
            return self.reference().reach
        return self.strength * self.max_offset if math.isfinite(self.max_offset) else math.inf

    def goal_weights(self) -> np.ndarray:
        """(40,) the goal weights after goal_scale, clip(goal_scale goal, 0, 1) (the goal itself at 1)."""
        if self.goal_scale == 1.0:
            return self.goal
        return np.clip(self.goal * self.goal_scale, 0.0, 1.0)

    def goal_stiffness(self) -> np.ndarray:
        """(40,) omega_i^2, 1/s^2, per unit mass; inf where the particle is glued (w = 1 or J = 0); for a
        keyed muscle, at its :meth:`reference` values."""
        if self.keyed:
            return self.reference().goal_stiffness()
        w = self.goal_weights()
        if self.strength == 0.0:
            return np.full(CVS, np.inf)
        with np.errstate(divide="ignore"):
            k = (2.0 * math.pi * self.frequency_hz) ** 2 / self.strength * w / (1.0 - w)
        return np.where(w >= 1.0, np.inf, k)


def section_goals(tendon: float, belly: float) -> np.ndarray:
    """(40,) goal weights: sections (end, bulge, middle, bulge, end) get (tendon, mean, belly, mean, tendon)."""
    mid = 0.5 * (tendon + belly)
    return np.repeat(np.array([tendon, mid, belly, mid, tendon], dtype=np.float64), RING)


def from_template(name: str, jiggle) -> MuscleJiggle:
    """A MuscleJiggle from a template's rig.muscle.template.Jiggle."""
    return MuscleJiggle(name=name, frequency_hz=jiggle.frequency_hz, damping_ratio=jiggle.damping_ratio,
                        goal=section_goals(jiggle.goal_tendon, jiggle.goal_belly), density=jiggle.density,
                        strength=jiggle.strength, spring_frequency_hz=jiggle.spring_frequency_hz,
                        spring_damping_ratio=jiggle.spring_damping_ratio, friction=jiggle.friction)


def glued(jiggles, idle) -> list[MuscleJiggle]:
    """`jiggles` with every muscle flagged in `idle` ((M,) bool: it drives no skin, rig.skin.muscle_skin.MuscleSkin.idle)
    at strength 0: its particles glued to their goals (goal_stiffness inf), so the solver moves them with the static
    shape and none ever nears its reach or stops hard; the others as they are."""
    idle = np.zeros(len(jiggles), bool) if idle is None else np.asarray(idle, bool).reshape(-1)
    if len(idle) != len(jiggles):
        raise InputError(f"expected one idle flag per muscle ({len(jiggles)}), got {len(idle)}", field="idle")
    return [replace(j, strength=0.0) if i else j for j, i in zip(jiggles, idle)]


OVERRIDES = ("frequency", "damping", "strength", "goal_scale", "goal", "goal_tendon", "goal_belly", "density",
             "spring_frequency", "spring_damping", "friction", "blend", "max_offset")
ATTRIBUTES = {"frequency": "frequency_hz", "damping": "damping_ratio", "spring_frequency": "spring_frequency_hz",
         "spring_damping": "spring_damping_ratio"}


def override(mj: MuscleJiggle, values: dict, where: str | None = None) -> MuscleJiggle:
    """`mj` with keys of OVERRIDES replaced (a scene's per-muscle table or a CLI option). ``goal`` is
    40 weights, 5 (one per section) or one number; ``goal_tendon``/``goal_belly`` rebuild the section
    defaults; ``blend``, ``strength``, ``frequency``, ``damping`` and ``goal_scale`` are numbers or curves
    (sim.jiggle.keyed.parse_curve)."""
    where = where or f"muscle {mj.name!r}"
    unknown = sorted(set(values) - set(OVERRIDES))
    if unknown:
        raise InputError(f"unknown jiggle key(s) {', '.join(unknown)}; expected {', '.join(OVERRIDES)}", field=where)
    kw = {}
    for k, v in values.items():
        if k == "blend":
            kw["blend"] = BlendCurve.parse(v, f"{where}.blend")
        elif k == "goal":
            g = np.asarray(v, dtype=np.float64).reshape(-1)
            if g.size == 1:
                g = np.full(CVS, g[0])
            elif g.size == SECTIONS:
                g = np.repeat(g, RING)
            elif g.size != CVS:
                raise InputError(f"goal must be one weight, {SECTIONS} (per section) or {CVS} (per CV), got {g.size}",
                                 field=f"{where}.goal")
            kw["goal"] = g
        elif k not in ("goal_tendon", "goal_belly"):
            kw[ATTRIBUTES.get(k, k)] = v
    if "goal_tendon" in values or "goal_belly" in values:
        g = mj.goal
        kw.setdefault("goal", section_goals(values.get("goal_tendon", g[0]), values.get("goal_belly", g[2 * RING])))
    try:
        return replace(mj, **kw)
    except InputError as e:
        # name the key the user wrote (damping), not the attribute (damping_ratio)
        key = {a: k for k, a in ATTRIBUTES.items()}.get(e.field, e.field)
        message = e.message.replace(f"muscle {mj.name!r}", where).replace(f": {e.field} ", f": {key} ")
        raise InputError(message, field=f"{where}.{key}") from None


COLLIDERS = ("bone", "model")
"""JiggleSettings.colliders: the capsules the particles collide with."""


@dataclass(frozen=True)
class JiggleSettings:
    """Settings of one simulation run.

    substeps : >= 1 integration steps per output frame (the solver splits further where the goal
        track's knots or the neighbour springs' stability need it; results do not depend on it).
    goal_rate : Hz, the rate at which static goals are sampled from the motion (the goal track's
        knots); None: max(120, output fps). Output times are always knots too.
    gravity : add g = 9.81 m/s^2 along -Z. Off by default: the static muscle already is the shape the
        artist sees under gravity; on, the muscles also sag below it by g / omega^2.
    preroll : seconds. 0: start settled at the first frame's goals, moving with them (offset and
        relative velocity zero; at the gravity sag when gravity is on). > 0: start at the bind pose,
        at rest, that long before the first frame, the goals blending to the first frame's over the
        first half and holding over the second.
    blend : the global static_dyn_blend curve (muscles without their own use it).
    strength : if given, every muscle's jiggle strength J (the CLI's --strength J, alias --jiggle), a
        number or a sim.jiggle.keyed.Curve.
    cut_ratio, cut_jump : a knot interval is a cut (a teleport) when its largest CV move exceeds
        cut_jump metres and cut_ratio times the largest move in each neighbouring interval; the
        particles are glued through it and restart at their goals.
    collisions : the particles collide with the bone capsules of other body parts and the floor
        (sim/jiggle/colliders.py).
    colliders : which capsules: "bone" (fitted to the character's skin around each bone,
        rig/character/capsules.py) or "model" (the MuJoCo model's own capsule geoms that drives the
        skeleton, kept inside the skin; bones without one keep their bone capsule).
    muscle_collisions : the particles of muscles of different body parts also collide with each other
        (sim/jiggle/tissue_contacts.py; off by default: it steps the particles one launch per step).
    device : Warp device.
    """

    substeps: int = 4
    goal_rate: float | None = None
    gravity: bool = False
    preroll: float = 0.0
    blend: BlendCurve = field(default_factory=lambda: BlendCurve.constant(1.0))
    strength: float | Curve | None = None
    cut_ratio: float = 8.0
    cut_jump: float = 0.1
    collisions: bool = True
    colliders: str = "bone"
    muscle_collisions: bool = False
    device: str = "cpu"

    def __post_init__(self):
        for f in ("collisions", "muscle_collisions"):
            if not isinstance(getattr(self, f), (bool, np.bool_)):
                raise InputError(f"expected true or false, got {getattr(self, f)!r}", field=f)
        if self.colliders not in COLLIDERS:
            raise InputError(f"expected one of {', '.join(map(repr, COLLIDERS))}, got {self.colliders!r}",
                             field="colliders")
        if isinstance(self.substeps, bool) or not isinstance(self.substeps, (int, np.integer)) or self.substeps < 1:
            raise InputError(f"expected an integer >= 1, got {self.substeps!r}", field="substeps")
        for f, lo, strict in (("goal_rate", 0.0, True), ("preroll", 0.0, False), ("cut_ratio", 1.0, True),
                              ("cut_jump", 0.0, True)):
            v = getattr(self, f)
            if v is None:
                continue
            if not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v) or \
                    not (v > lo if strict else v >= lo):
                raise InputError(f"expected a finite number {'>' if strict else '>='} {lo:g}, got {v!r}", field=f)
        if not isinstance(self.blend, BlendCurve):
            object.__setattr__(self, "blend", BlendCurve.parse(self.blend, "blend"))
        if self.strength is not None:
            if isinstance(self.strength, bool) or not isinstance(self.strength, (int, float, Curve, list, tuple, dict)):
                raise InputError(f"jiggle strength must be in [0, 1], got {self.strength!r}", field="strength")
            try:
                object.__setattr__(self, "strength", parse_curve(self.strength, "strength"))
            except InputError as e:
                raise InputError(f"jiggle {e.message}", field="strength") from None



MOTION_RATE = 60.0
"""Hz: the clip is sampled at this rate to measure how a muscle moves (so the result does not depend on the
bake's output rate)."""
