"""The skin's side of the painted maps (rig.character.painted_maps): the jiggle map applied to a
chunk of skins, and the influence maps turned into (vertex, muscle) pairs and weights.

Jiggle map J (V,) in [0, 1], per vertex, on every set but the static one:

    final = static + J (final - static)

Only the vertices with J < 1 are touched (:class:`JiggleMap`: a gather, one multiply-add and a
scatter of those rows per chunk), so a map of ones everywhere (or none) leaves the skin exactly as
it was, bit for bit, and where J = 0 the final skin is the static skin exactly.

Influence maps I (V, M) in [0, 1] (NaN: not painted, the computed weight stays), per (vertex,
muscle) pair, replacing the weight computed at bind (the shell's envelope, or an influence object's
w beta): :func:`painted_pairs` adds the pairs a map paints > 0 outside the culled region (the shell
deformer runs over any CSR list of pairs; a vertex added far beyond the muscle's drop-off shell moves
only when the muscle's shell reaches it, as in Maya Muscle, where painted weights scale a geometric
fall-off), and gives each pair its painted value. :func:`shell_regions` is the computed table a user
starts painting from (`jiggle fit` writes it).
"""
from __future__ import annotations

import numpy as np

from jiggle.rig.base.errors import InputError


class JiggleMap:
    """A jiggle map (V,) ready to apply to chunks of skins.

    rows : (R,) int64, the vertices whose value is < 1. keep : (R,) float32, their values.
    """

    def __init__(self, values: np.ndarray):
        values = np.asarray(values, np.float32).reshape(-1)
        if not np.all((values >= 0.0) & (values <= 1.0)):
            raise InputError("jiggle map values must lie in [0, 1] (and not be NaN)", field="jiggle_map")
        self.values = values
        self.rows = np.nonzero(values < 1.0)[0]
        self.keep = values[self.rows][None, :, None]

    @property
    def identity(self) -> bool:
        return len(self.rows) == 0

    def apply(self, static: np.ndarray, final: np.ndarray) -> np.ndarray:
        """`final` (T, V, 3) float32 with its rows J < 1 set to static + J (final - static), in place
        when it is writable (else on a copy); returned."""
        if self.identity:
            return final
        if not final.flags.writeable:
            final = np.array(final)
        s = np.take(static, self.rows, axis=1)
        d = np.take(final, self.rows, axis=1)
        d -= s
        d *= self.keep
        d += s
        final[:, self.rows] = d
        return final


def painted_pairs(offsets: np.ndarray, muscle: np.ndarray, influence: np.ndarray | None
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """The culled pairs completed by the influence maps.

    offsets : (V + 1,) int CSR of the culled pairs; muscle : (P,) int, sorted by vertex then muscle.
    influence : (V, M) float32 in [0, 1], NaN where not painted, or None.

    Returns offsets (V + 1,) int32 and muscle (P',) int32 of the culled pairs plus every (v, m) with
    influence > 0 (sorted as before), and painted (P',) float32: the influence of each pair, NaN
    where it keeps the computed weight (None without maps).
    """
    if influence is None:
        return offsets, muscle, None
    V, M = influence.shape
    keep = np.zeros((V, M), bool)
    vertex = np.repeat(np.arange(V), np.diff(offsets))
    keep[vertex, muscle] = True
    keep |= np.nan_to_num(influence, nan=0.0) > 0.0
    v, m = np.nonzero(keep)            # row-major: by vertex, then muscle, as cull_pairs
    out = np.zeros(V + 1, np.int64)
    np.cumsum(np.bincount(v, minlength=V), out=out[1:])
    return out.astype(np.int32), m.astype(np.int32), influence[v, m].astype(np.float32)


def shell_regions(character, rig, shells=None, margin: float = 0.25, star: bool = True) -> np.ndarray:
    """(V, M) float32 in [0, 1]: the weight each muscle's shell deformer gets on each vertex when
    nothing is painted (0 outside the culled region, 1 within the drop-off shell, the envelope fading
    between: rig.skin.shell.shells.pair_envelope), as rig.skin.muscle_skin.MuscleSkin computes it for
    "shell" skinning with `margin` and `star`. What a user starts painting influence maps from."""
    from jiggle.rig.muscle.shell_params import default_shell
    from jiggle.rig.skin.shell.frames import MuscleFrames
    from jiggle.rig.skin.shell.shells import cull_pairs, pair_envelope, shell_table
    shells = [default_shell(k) for k in rig.kinds] if shells is None else list(shells)
    frames = MuscleFrames.build(rig, character.bind_world, star=star)
    table = shell_table(shells, star=frames.star if star else None, star_index=frames.star_index if star else None)
    offsets, muscle = cull_pairs(character.vertices, frames.E_rest, table.drop_off, margin, star=table.star,
                                 star_index=table.star_index)
    env = pair_envelope(character.vertices, frames.E_rest, table.drop_off, margin, offsets, muscle,
                        star=table.star, star_index=table.star_index)
    out = np.zeros((character.num_vertices, rig.M), np.float32)
    out[np.repeat(np.arange(character.num_vertices), np.diff(offsets)), muscle] = env
    return out
