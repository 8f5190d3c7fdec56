"""A chain's parameters: its swing frequency, damping ratio, gravity and air drag, each a number or a keyed curve
(sim.jiggle.keyed.Curve), per chain or glob ("Tail*"), with defaults from the chain's length.

Defaults (nothing needs tuning):

- frequency: FREQUENCY_PER_PENDULUM times a pendulum's of the chain's length measured on a body REFERENCE_SIZE
  big, f = k sqrt(g / (REFERENCE_SIZE L / S)) / (2 pi), L the chain's length and S the body's size (its rest
  skin's largest extent): a long tail swings slower than a short ear, and a chain swings the same share of its
  length whatever the file's unit (game files come in any unit, and the animation's timing does not change
  with it; sim.chain.model scales gravity alike). A joint's spring is set for this frequency over the inertia of
  everything below it, less TAPER toward the tip: stiff at the root, looser toward the tip.
- damping: DAMPING, the ratio of each joint's spring (0 rings forever, 1 returns without overshoot).
- gravity: 1, the share of g the chain feels. The spring holds the animated pose under that gravity (the pose is
  what the animator drew: a still character's chains stay on it), so gravity shapes how the chain swings (a
  hanging tail swings back faster, an upright ear slower), not where it rests.
- drag: 1, quadratic air drag on every link, -1/2 rho C_D A |v| v with air's density (1.2 kg/m^3) times it,
  C_D = DRAG_COEFFICIENT and A the link capsule's side: real air barely slows a tail; hair and capes take more.
"""
from __future__ import annotations

import fnmatch
import math
from dataclasses import dataclass

from jiggle.rig.base.errors import InputError
from jiggle.sim.jiggle.keyed import Curve, Parameter, is_glob, jsonable_value, parse_curve

G = 9.81
"""m/s^2."""
FREQUENCY_PER_PENDULUM = 12.0
"""A chain's default frequency over a pendulum's of its (reduced) length: the zoo's most vigorous cycles (a
galloping horse's head and hips accelerate at 3 to 7 g at REFERENCE_SIZE) swing tails and ears by 20 to 45% of
their length, calmer cycles less."""
KIND_STIFFNESS = {"wing": 2.5, "fin": 1.5, "feather": 1.5, "ear": 1.0, "antenna": 1.0, "antennae": 1.0, "horn": 2.0,
                  "hair": 0.7, "ponytail": 0.7, "pony": 0.7, "braid": 0.7, "mane": 0.7, "cape": 0.6, "cloak": 0.6,
                  "skirt": 0.6, "scarf": 0.6, "ribbon": 0.6, "tassel": 0.6, "streamer": 0.6}
"""A chain's default frequency times this by the word its root's name holds (rig.character.chains.APPENDAGE_WORDS):
a wing's fingers carry a flight surface and swing little, cloth and hair more; 1 for the rest."""
TAPER = 0.15
"""The frequency falls by this share from the root to the tip."""
DAMPING = 0.35
"""The default damping ratio: a swing decays to 1% in about two of its periods."""
AIR_DENSITY = 1.2
"""kg/m^3 at drag 1."""
DRAG_COEFFICIENT = 1.0
"""A link's drag coefficient across its capsule (a cylinder in cross-flow)."""
LIMIT_DEG = 35.0
"""Degrees past the animated pose's largest bend from bind where a joint's soft limit starts."""


CHAIN_PARAMETERS = {p.name: p for p in (
    Parameter("stiffness", "Hz", 0.0, 100.0, lo_open=True, keyable=True, default="2 x a pendulum's of the chain's "
              "length", what="swing frequency of the chain's root (looser toward the tip)"),
    Parameter("damping", "", 0.0, 5.0, keyable=True, default=str(DAMPING), what="damping ratio of every joint's spring"),
    Parameter("gravity", "", 0.0, 10.0, keyable=True, default="1", what="share of g the chain feels"),
    Parameter("drag", "", 0.0, 10000.0, keyable=True, default="1", what="air density times this on every link"),
)}
"""The keyable chain parameters (--chain-stiffness, --chain-damping, --chain-gravity, --chain-drag; a scene's
[chains.NAME] keys)."""


@dataclass(frozen=True)
class ChainParams:
    """One chain's parameters: stiffness (Hz), damping (ratio), gravity (share of g), drag (share of air); each a
    float or a Curve over the clip's seconds. `given` : the names the user set (the rest are defaults)."""

    stiffness: float | Curve
    damping: float | Curve
    gravity: float | Curve
    drag: float | Curve
    given: tuple = ()

    def to_json(self) -> dict:
        return {k: jsonable_value(getattr(self, k)) for k in CHAIN_PARAMETERS} | {"set_by_user": list(self.given)}

    def keyed(self) -> tuple:
        return tuple(k for k in CHAIN_PARAMETERS if isinstance(getattr(self, k), Curve))


REFERENCE_SIZE = 2.0
"""metres: the body size at which the chains' defaults are physical (g is g, a pendulum a pendulum); a body of
another size swings as this one would (sim.chain.model.gravity_at)."""


def default_frequency(length: float, size: float) -> float:
    """Hz: the default swing frequency of a chain `length` metres long on a body `size` metres big."""
    reduced = REFERENCE_SIZE * max(length, 1e-9) / max(size, 1e-9)
    return FREQUENCY_PER_PENDULUM * math.sqrt(G / reduced) / (2.0 * math.pi)


def check_value(name: str, value, where: str):
    """A parameter's value (number, keys or Curve) checked for its range: float or Curve; InputError naming
    `where`."""
    if name not in CHAIN_PARAMETERS:
        raise InputError(f"unknown chain parameter {name!r}; the parameters are {', '.join(CHAIN_PARAMETERS)}",
                         field=where)
    return parse_curve(value, name, where, CHAIN_PARAMETERS)


def kind_factor(name: str) -> float:
    """KIND_STIFFNESS of a chain named `name` (its root joint's name)."""
    from jiggle.rig.character.chains import name_words
    return next((KIND_STIFFNESS[w] for w in name_words(name) if w in KIND_STIFFNESS), 1.0)


def from_spring(spring: dict, frequency: float) -> dict:
    """A file's own spring settings (VRM spring bones, rig.character.vrm_springs) as this chain's defaults: VRM's
    stiffness scales the default frequency by its square root (its force is linear in it: VRM 1 is jiggle's
    default), its drag force (0..1, the share of velocity lost per frame at 60 fps) sets the damping ratio, its gravity
    power the gravity share."""
    out = {}
    if "stiffness" in spring:
        out["stiffness"] = round(frequency * math.sqrt(max(float(spring["stiffness"]), 0.01)), 4)
    if "drag" in spring:
        out["damping"] = round(min(5.0, DAMPING + 2.0 * float(spring["drag"])), 4)
    if "gravity_power" in spring:
        out["gravity"] = float(min(10.0, max(0.0, float(spring["gravity_power"]))))
    return out


def chain_params(names, lengths, size: float, entries=(), springs=None) -> list[ChainParams]:
    """Every chain's parameters: defaults from its length (metres) on a body `size` metres big (or from the file's
    own spring settings, `springs`: one dict or None per chain, from_spring), then `entries` (pattern, {name: value},
    where) in order, an exact chain name beating a glob and a later glob an earlier one. InputError naming the
    entry for a pattern that matches no chain or a value out of range."""
    names = list(names)
    ranked = []
    for order, (pattern, table, where) in enumerate(entries):
        path = line = None
        if isinstance(where, tuple):            # a scene's table: (where, file, line)
            where, path, line = where
        hit = [n for n in names if fnmatch.fnmatchcase(n, pattern)] if is_glob(pattern) else \
            [n for n in names if n == pattern]
        if not hit:
            raise InputError(f"{pattern!r} matches no chain; the chains are {', '.join(names) or '(none)'}",
                             path, line, field=where)
        ranked.append((0 if is_glob(pattern) else 1, order, hit, table, (where, path, line)))
    chosen: dict = {n: {} for n in names}
    for _, _, hit, table, (where, path, line) in sorted(ranked, key=lambda r: (r[0], r[1])):
        for k, v in table.items():
            try:
                value = check_value(k, v, where if path is None else f"{where}.{k}")
            except InputError as e:
                raise InputError(e.message, path, line, field=e.field) from None
            for n in hit:
                chosen[n][k] = value
    out = []
    springs = list(springs) if springs is not None else [None] * len(names)
    for n, L, spring in zip(names, lengths, springs):
        mine = chosen[n]
        f = round(kind_factor(n) * default_frequency(L, size), 4)
        base = {"stiffness": f, "damping": DAMPING, "gravity": 1.0, "drag": 1.0, **(from_spring(spring, f) if spring
                                                                                       else {})}
        out.append(ChainParams(given=tuple(sorted(mine)), **{k: mine.get(k, v) for k, v in base.items()}))
    return out
