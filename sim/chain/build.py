"""A character's chains made ready to swing: links measured, parameters resolved, the MuJoCo model built with its
soft limits and the contacts the animation itself keeps (sim.chain.model), from the animated pose at the knots."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from jiggle.sim.jiggle.keyed import Curve

SAMPLE_KNOTS = 400
"""Knots the animated pose is sampled at (evenly) for the soft limits and the contacts it keeps."""


@dataclass(frozen=True, eq=False)
class ChainSetup:
    """chains : rig.character.chains.Chains. links : ChainLinks. params : one ChainParams per chain. model :
    sim.chain.model.ChainModel. apart : (n, C) the link / body capsule pairs the animation keeps apart. riders :
    ((joint, chain joint carrying it), ...) the joints below chain joints that are not (sim.chain.simulate.riders_of).
    moved : (m,) every joint the swing moves (the chain joints, then the riders). skin : rig.skin.chain_skin.ChainSkin
    of `moved` (what they move of the skin), or None."""

    chains: object
    links: object
    params: tuple
    model: object
    apart: np.ndarray
    riders: tuple = ()
    moved: np.ndarray | None = None
    skin: object = None

    def to_json(self, names) -> list:
        out = []
        for c, p in zip(self.chains.chains, self.params):
            idx = np.flatnonzero(self.links.chain == len(out))
            out.append({**c.to_json(names), **p.to_json(), "length_m": round(float(self.links.length[len(out)]), 5),
                        "mass_kg": round(float(self.links.mass[idx].sum()), 5),
                        "soft_limit_deg": [round(float(np.degrees(v)), 2) for v in self.model.limit[idx]]})
        return out


def make(character, chains, capsules, floor, entries, knots: np.ndarray, world_at) -> ChainSetup | None:
    """The ChainSetup of `chains` on `character` (None when there is none). capsules : the body's BoneCapsules or
    None; floor : metres or None; entries : the per-chain parameter entries (sim.chain.params.chain_params); knots,
    world_at : the bake's goal knots and drive."""
    from jiggle.rig.character.chains import chain_links
    from jiggle.rig.skin.chain_skin import ChainSkin
    from jiggle.sim.chain.measure import kept_apart
    from jiggle.sim.chain.model import build
    from jiggle.sim.chain.params import chain_params
    from jiggle.sim.chain.simulate import riders_of, soft_limits, targets_from_world
    if not len(chains):
        return None
    links = chain_links(character, chains)
    size = float(np.ptp(np.asarray(character.vertices), axis=0).max())
    params = chain_params(chains.names, links.length, size, entries, [c.spring for c in chains.chains])
    hi = max(p.stiffness.hi if isinstance(p.stiffness, Curve) else float(p.stiffness) for p in params)
    pick = np.unique(np.linspace(0, len(knots) - 1, min(len(knots), SAMPLE_KNOTS)).round().astype(int))
    world = np.asarray(world_at(np.asarray(knots)[pick]), np.float64)
    limits = soft_limits(links, targets_from_world(links, world))
    own = set(int(j) for j in links.joints)
    apart = kept_apart(world, links, capsules, own) if capsules is not None else np.zeros((links.count, 0), bool)
    exclude = []
    if capsules is not None and capsules.count:
        for i in range(links.count):
            for j in np.unique(capsules.joint):
                if int(j) in own:
                    continue
                if not apart[i, capsules.joint == j].all():
                    exclude.append((i, int(j)))
    model = build(links, capsules, floor, frequency_hi=hi, exclude=exclude, limits=limits, size=size,
                  bind_world=np.asarray(character.bind_world))
    riders = tuple(riders_of(model, character.parents))
    moved = np.array([int(j) for j in links.joints] + [j for j, _ in riders], np.int64)
    return ChainSetup(chains=chains, links=links, params=tuple(params), model=model, apart=apart, riders=riders,
                      moved=moved, skin=ChainSkin(character, moved))
