"""Skin driven by the bones and the muscles: LBS (or DQS), then every muscle's deformer.

    joint world transforms --Skinner (Warp)--------------------------> smooth-skinned positions
    muscle CVs (static now; jiggled and blended later)
        --MuscleFrames--> per muscle E_ref (rest ellipsoid riding its bone), E_cur (fitted to the CVs)
        --ShellDeformer (Warp)--> shells in series on the culled (vertex, muscle) pairs    "shell"
        --InfluenceDeformer (Warp)--> the muscle surface carries its bound vertices         "influence"
    or, with no smooth skinning at all, feature points anchored to the bones and muscles drive a
    zoned RBF interpolation of the whole skin (rig.skin.rbf_skin.RBFSkin, Simmons et al. 2002)    "rbf"

The artist's skin is kept: both deformers act on the change of each muscle relative to the bone it
rides (rig/skin/shell/shells.py says how the paper's absolute shells became relative), so at the bind pose with
the muscles at rest the result is the smooth-skinned skin, which at bind is the artist's skin.

The skin spreads what the deformers do to it: their displacement from the smooth skin, static and
jiggling alike, is smoothed over the surface (rig/skin/surface_smoothing.py, a reach of JIGGLE_REACH of
the character's size), so a muscle's or a fat pad's outline never shows as a crease, a step or a tear
(issue 18: on the generated body this took the shells' added folds on the dance clip from +4 to 0 per
frame on average and every jiggle tear out of the run and jump clips). At bind the displacement is 0,
so the artist's skin is still kept exactly.

Built once (`MuscleSkin(...)`): the Skinner's rest mesh and weights, the muscle frames, the pair list
culled at bind, the painted weights and the deformer's device arrays. Per frame (`pose`): one launch
for the skinning, a few NumPy operations over all muscles at once for their frames, one launch for the
deformer; nothing loops in Python over muscles, pairs or vertices.

Per chunk of T frames (`pose_batch`, `lbs_batch`: the bake), for S sets of muscle states (e.g. the
static and the blended CVs): one LBS/DQS launch for the T frames, shared by the sets, the frames of
all sets and frames in a few NumPy operations (the bones' part once), one upload and one launch of
the shells (or the influence objects) for all sets and frames over the vertices that have pairs,
handing the spread their displacements, then the sparse spread of each set over the rings the
displacement reaches (two threads). `launches` counts pose_batch's Warp launches. On the CPU the
kernels write straight into the host arrays returned (no device-to-host copy) and the spread works in
kept workspaces a block of frames at a time; with `reuse` (the bake) the returned arrays themselves
are two generations of kept buffers, so a chunk makes no new array of its size: with the bake's
mallopt every such array is a fresh mapping whose pages fault in, which had doubled the stage's time.
"""
from __future__ import annotations

import threading
import warnings
from dataclasses import dataclass
from typing import Sequence

import numpy as np
import warp as wp

from jiggle.rig.base.errors import InputError, JiggleWarning
from jiggle.rig.character.character import Character
from jiggle.rig.muscle.loft_attach import bind_influence
from jiggle.rig.muscle.model import MuscleRig
from jiggle.rig.muscle.shell_params import MODES, ShellParams, default_shell
from jiggle.rig.skin.delta_mush import DeltaMush
from jiggle.rig.skin.influence import InfluenceDeformer
from jiggle.rig.skin.painted_maps import JiggleMap, painted_pairs
from jiggle.rig.skin.shell.deformer import ShellBatch, ShellDeformer
from jiggle.rig.skin.shell.frames import MuscleFrames
from jiggle.rig.skin.shell.shells import beta, cull_pairs, pair_envelope, shell_table
from jiggle.rig.skin.skinning import character_skinner
from jiggle.rig.skin.surface_smoothing import BLOCK, JIGGLE_REACH, SurfaceSmoothing, pool, steps_for_reach

SKINNING = ("shell", "influence", "rbf")
"""How the muscles move the skin: the shell deformers (Pratscher et al.), influence objects (the
thesis's Maya setup), or anatomy-driven RBF interpolation (Simmons et al.; no LBS underneath)."""


class MuscleSkin:
    """A character's skin over its bones and muscles.

    Parameters
    ----------
    character : the skinned character (rest skin, weights, bind transforms).
    rig : its muscles (rig.muscle.model.MuscleRig), in the character's joint order.
    shells : one ShellParams per muscle, or None for each kind's default (rig.muscle.shell_params.default_shell).
    skinning : "shell" (default), "influence" or "rbf" (`method`, `weights`, `margin` and `star` do not
        apply to it; `rbf` takes rig.skin.rbf_skin.RBFSkinOptions, `segmentation` and `roles` save their
        recomputation).
    method : "lbs" (default) or "dqs", the smooth skinning underneath.
    weights : (V, M) painted per-vertex weights w_i in [0, 1] (rig.skin.shell.weights), or None for 1.
        Influence objects multiply them by the muscle's overall weight w and the shell fall-off beta
        at bind, so a muscle's pull fades out smoothly at the edge of the region it binds.
    margin : culling margin: a (vertex, muscle) pair is kept when the vertex lies within
        (1 + d)(1 + margin) of the muscle's rest ellipsoid (local units) at bind; a shell's pull fades
        to 0 across that margin (rig.skin.shell.shells.pair_envelope), so the culling line leaves no step.
    star : give each deformer its muscle's star-shaped offsets (Pratscher et al. 4.3.2).
    device : Warp device.
    mush : Delta Mush smoothing steps on the smooth skin (rig.skin.delta_mush; on the RBF skin for
        "rbf"): 0 (default) off; a clean-up for skins whose weights crease under LBS.
    rigid : rig.character.gear.RigidParts, the gear and hard shells (shell and influence skinning), or
        None (default: all tissue). No deformer acts on them and the spread cannot reach them; each
        rigid piece follows plain skinning (its bone, for a shell bound to one joint) plus one
        translation, the mean displacement of the soft skin under it (rig.character.gear.Ride), in
        the static and the jiggling skin alike: it rides the body beneath without being stretched.
    spread : how far the skin spreads what the muscles do to it (shell and influence: their
        displacement from the smooth skin, static and jiggling alike, rig.skin.surface_smoothing), a
        fraction of the character's largest extent (default JIGGLE_REACH; 0: not at all).
    """

    def __init__(self, character: Character, rig: MuscleRig, shells: Sequence[ShellParams] | None = None, *,
                 skinning: str = "shell", method: str = "lbs", weights: np.ndarray | None = None,
                 margin: float = 0.25, star: bool = True, device: str = "cpu", rbf=None, segmentation=None,
                 roles=None, spread: float = JIGGLE_REACH, mush: int = 0, rigid=None):
        shells, painted = _checked_inputs(character, rig, shells, weights, skinning=skinning, method=method,
                                          margin=margin, spread=spread)
        M, V = rig.M, character.num_vertices

        self.character, self.rig, self.shells = character, rig, tuple(shells)
        self.skinning, self.method, self.device = skinning, method, wp.get_device(device)
        self.jiggle_mask = None
        """(V,) float32 in [0, 1] or None: how much of the jiggle each vertex shows (skin_frames)."""
        maps = character.maps
        jm = JiggleMap(maps.jiggle) if maps is not None and maps.jiggle is not None else None
        self.jiggle_map = None if jm is None or jm.identity else jm
        """rig.skin.painted_maps.JiggleMap of the character's painted jiggle map (skin_frames: the final
        skin's jiggle scaled by it, applied last), or None (none, or 1 everywhere)."""
        self.rigid = rigid if rigid is not None and rigid.any and skinning != "rbf" else None
        """rig.character.gear.RigidParts of the gear and hard shells the deformers leave alone, or None."""
        self.gear = rigid
        """rig.character.gear.RigidParts as given (the rule that decided each rigidly bound piece, hard or flesh,
        even when none is hard), or None."""
        self.ride = None
        """rig.character.gear.Ride of the rigid pieces on the tissue under them, or None."""
        self.idle = np.zeros(M, bool)
        """(M,) bool: the muscles that drive nothing because none of their skin is soft (no (vertex, muscle)
        pair of theirs lies on a soft vertex: all lay on gear or hard shells): the bake does not simulate them
        (sim.bake.setup). All False without rigid parts and for "rbf"."""
        self.launches = 0
        """Warp launches pose_batch has made so far (skinning, Delta Mush, shells, influence objects, RBF)."""
        self._slots, self._turn = ({}, {}), 0          # pose_batch(reuse=True)'s kept host buffers
        self._work_free, self._work_lock = [], threading.Lock()     # _spread_moved's workspaces
        self.jiggle_spread = None
        """SurfaceSmoothing of the jiggle (skin_frames), or None: the deformers' displacement is spread
        instead, inside pose / pose_batch (shell, influence)."""
        from jiggle.rig.skin.creases import Creases
        self.creases = Creases(character.vertices, character.faces,
                               fixed=None if self.rigid is None else self.rigid.mask)
        """rig.skin.creases.Creases: skin_frames holds the jiggle together across the edges the smooth skin squeezes."""
        self.frames = MuscleFrames.build(rig, character.bind_world, star=star)
        self.table = shell_table(shells, star=self.frames.star if star else None,
                                 star_index=self.frames.star_index if star else None)
        self.skinner = character_skinner(character, device)
        self.mush = _delta_mush(character, mush, device)
        """rig.skin.delta_mush.DeltaMush over the smooth skin (or the RBF skin), or None."""
        if skinning == "rbf":  # the feature points carry the muscles: no (vertex, muscle) pairs to cull
            self._bind_rbf(rbf, segmentation, roles, spread, device)
            return
        offsets, muscle = cull_pairs(character.vertices, self.frames.E_rest, self.table.drop_off, margin,
                                     star=self.table.star, star_index=self.table.star_index)
        # painted influence maps add the pairs they paint > 0 and replace the computed fall-off of each
        # pair they cover (NaN where they keep it)
        offsets, muscle, influence = painted_pairs(offsets, muscle, self._influence_table())
        vertex = np.repeat(np.arange(V), np.diff(offsets))
        if self.rigid is not None:      # gear and hard shells: no pair, so no deformer and no spread moves them
            from jiggle.rig.character.gear import ride
            offsets, muscle, vertex, influence = _soft_pairs(self.rigid.mask, offsets, muscle, vertex, influence)
            self.idle = np.bincount(muscle, minlength=M) == 0
            self.ride = ride(character, self.rigid)
        pair_w = painted[vertex, muscle]
        self.pair_offsets, self.pair_muscle = offsets, muscle
        if skinning == "shell":
            self.pair_weight, self.deformer = self._shell_deformer(offsets, muscle, pair_w, influence, margin,
                                                                   device)
        else:
            self.pair_weight, self.deformer = self._influence_deformer(vertex, offsets, muscle, pair_w, influence,
                                                                       device)
        # the muscles' displacement of the skin, spread over its surface (rig/skin/surface_smoothing.py)
        self.spread = self._surface(spread, np.diff(offsets) > 0)
        # the batched deformers hand the spread their paired vertices' displacements: its ring 0
        paired = np.nonzero(np.diff(offsets) > 0)[0]
        assert self.spread.steps == 0 or np.array_equal(self.spread.order[:self.spread.ring_ends[0]], paired)
        self.spread_on_device = not self.device.is_cpu
        """pose_batch spreads on the device (SurfaceSmoothing.spread_device) and copies back finished skins:
        a GPU's way; on the CPU the host spread (SciPy, blocks kept in the cache) is several times faster."""

    def _bind_rbf(self, rbf, segmentation, roles, spread: float, device) -> None:
        """Binds the "rbf" skin: no (vertex, muscle) pairs, the RBF skin (rig.skin.rbf_skin.RBFSkin) as the
        deformer, its jiggle mask, and the spread of the jiggle over `spread` x the character's size."""
        from jiggle.rig.skin.rbf_skin import RBFSkin, RBFSkinOptions
        V = self.character.num_vertices
        self.pair_offsets, self.pair_muscle = np.zeros(V + 1, np.int64), np.zeros(0, np.int64)
        self.pair_weight = np.zeros(0, np.float32)
        self.deformer = RBFSkin(self.character, self.rig, segmentation=segmentation, roles=roles,
                                options=rbf or RBFSkinOptions(), device=device)
        self.jiggle_mask = self.deformer.jiggle_mask
        # no deformer displacement to spread here: the skin's jiggle is spread instead (skin_frames)
        self.jiggle_spread = self._surface(spread, None)

    def _shell_deformer(self, offsets: np.ndarray, muscle: np.ndarray, pair_w: np.ndarray, influence, margin: float,
                        device) -> tuple[np.ndarray, ShellDeformer]:
        """The pairs' weights (P,) float32 (painted weight x fall-off, or x the painted influence `influence`
        (P,) where it is not NaN) and the ShellDeformer over the pairs (CSR `offsets` (V + 1,), `muscle` (P,))."""
        # every pull fades out before the culling line (shells.pair_envelope)
        fall = pair_envelope(self.character.vertices, self.frames.E_rest, self.table.drop_off, margin,
                             offsets, muscle, star=self.table.star, star_index=self.table.star_index)
        if influence is not None:
            fall = np.where(np.isnan(influence), fall, influence)
        pair_weight = (pair_w * fall).astype(np.float32)
        return pair_weight, ShellDeformer(self.table, offsets, muscle, pair_weight, device=device)

    def _influence_deformer(self, vertex: np.ndarray, offsets: np.ndarray, muscle: np.ndarray, pair_w: np.ndarray,
                            influence, device) -> tuple[np.ndarray, InfluenceDeformer]:
        """The pairs' weights (P,) float32 (painted weight x the muscle's weight x its fall-off at bind, the
        painted influence `influence` (P,) standing for the fall-off where it is not NaN) and the
        InfluenceDeformer binding each pair's vertex (`vertex` (P,), CSR `offsets` (V + 1,), `muscle` (P,))."""
        fall = self._bind_falloff(vertex, muscle)
        if influence is not None:   # the map stands for the fall-off beta, the muscle's weight w stays
            fall = np.where(np.isnan(influence), fall, self.table.weight[muscle] * influence)
        pair_weight = (pair_w * fall).astype(np.float32)
        binding = bind_influence(self.character.vertices, offsets, muscle, self.rig.rest_cvs)
        # like the shells' limit: a pair moves its vertex by at most the muscle's drop-off distance
        # (d x its mean rest radius), so no large pull folds the skin where it fades
        reach = self.table.drop_off * self.rig.mean_radii(self.rig.rest_cvs)
        return pair_weight, InfluenceDeformer(binding, offsets, muscle, pair_weight, self.rig.M, device=device,
                                              reach=np.maximum(reach, 1e-9))

    def _influence_table(self) -> np.ndarray | None:
        """(V, M) float32 influence maps of the character in rig order (NaN: not painted), or None;
        maps naming no muscle of the rig are left out with a JiggleWarning."""
        maps = self.character.maps
        if maps is None or not maps.influence:
            return None
        names = [n.lower() for n in self.rig.names]
        extra = [n for n in maps.influence if n not in names]
        if extra:
            warnings.warn(f"{maps.source}: influence map(s) of no muscle of the rig ignored: {', '.join(extra[:8])}"
                          f"{' ...' if len(extra) > 8 else ''}", JiggleWarning, stacklevel=3)
        return maps.influence_table(self.rig.names)

    def _surface(self, reach: float, active) -> SurfaceSmoothing:
        """The skin's surface smoothing over `reach` x its rest size, on the `active` vertices (None: all)."""
        v, faces = self.character.vertices, self.character.faces
        size = float(np.ptp(v, axis=0).max()) if len(v) else 0.0
        return SurfaceSmoothing(faces, len(v), steps_for_reach(v, faces, reach * size), active)

    def _spread(self, smooth: np.ndarray, skins: list, threads: bool = True) -> list:
        """Skins (T, V, 3) each smooth + spread(skin - smooth), for the smooth skin (T, V, 3) beneath,
        new arrays: the rows the spread reaches gathered, smoothed with the frames side by side as
        columns and scattered back; one set per worker thread (NumPy and SciPy run without the GIL),
        or one after the other without `threads`."""
        if self.spread.steps == 0 or not skins or len(self.spread.rows) == 0:
            return [np.array(k, dtype=np.float32) for k in skins]
        rows = self.spread.rows
        T, V = smooth.shape[:2]
        R = len(rows)
        base = np.take(smooth, rows, axis=1)                                       # (T, R, 3)
        vec = np.dtype((np.void, 12))          # a vertex's xyz as one item: a scatter 3x faster than [:, rows]

        def one(k):
            d = np.ascontiguousarray((np.take(k, rows, axis=1) - base).transpose(1, 0, 2)).reshape(R, 3 * T)
            d = self.spread.smooth_rows(d, copy=False, threads=False).reshape(R, T, 3)
            out = np.array(k, dtype=np.float32)
            moved = base + d.transpose(1, 0, 2)                                     # (T, R, 3), a new array
            out.view(vec).reshape(T, V)[:, rows] = moved.view(vec).reshape(T, R)
            return out
        return list(pool().map(one, skins)) if threads and len(skins) > 1 else [one(k) for k in skins]

    @classmethod
    def from_musculature(cls, mus, *, weights=None, character_path=None, rigid="auto", **kw) -> "MuscleSkin":
        """The skin of a fitted musculature (rig.muscle.fit), each muscle's deformer from its template
        entry. `weights`: a painted weights file (.npz, rig.skin.shell.weights), an array (V, M), or None for
        the file beside `character_path` when there is one, else 1. `rigid`: the gear and hard shells,
        "auto" (default: found from the skin, rig.character.gear.find_rigid), "none", a --rigid list
        (rig.character.gear.parse_rigid) or a RigidParts. Other keywords as the constructor."""
        from jiggle.rig.character.gear import parse_rigid
        from jiggle.rig.skin.shell.weights import find_weights, load_weights
        if kw.get("skinning", "shell") != "rbf":
            kw["rigid"] = parse_rigid(mus.character, rigid)
        names = mus.rig.names
        if weights is None and character_path is not None:
            weights = find_weights(character_path)
        if weights is not None and not isinstance(weights, np.ndarray):
            weights = load_weights(weights, names, mus.character.num_vertices)
        shells = [m.spec.shell for m in mus.muscles]
        if kw.get("skinning") == "rbf":
            kw = {"segmentation": mus.segmentation, "roles": mus.roles, **kw}
        return cls(mus.character, mus.rig, shells, weights=weights, **kw)

    # ------------------------------------------------------------------ facts
    @property
    def num_pairs(self) -> int:
        """The (vertex, muscle) pairs kept at bind."""
        return len(self.pair_muscle)

    def pairs_per_muscle(self) -> np.ndarray:
        """(M,) number of vertices each muscle may move."""
        return np.bincount(self.pair_muscle, minlength=self.rig.M)

    def _bind_falloff(self, vertex: np.ndarray, muscle: np.ndarray) -> np.ndarray:
        """(P,) the shell attenuation beta of each pair's vertex at bind (influence weights fade with it)."""
        E_inv = np.linalg.inv(self.frames.E_rest)[muscle]
        p = np.einsum("pij,pj->pi", E_inv[:, :3, :3], self.character.vertices[vertex]) + E_inv[:, :3, 3]
        r = np.linalg.norm(p, axis=1)
        t = self.table
        return t.weight[muscle] * beta(r, t.hard[muscle], t.drop_off[muscle])

    # ------------------------------------------------------------------ per frame
    def lbs(self, world: np.ndarray) -> np.ndarray:
        """Smooth skinning alone (mushed, with `mush`), (V, 3) float32 metres, for joint world
        transforms (J, 4, 4)."""
        out = self.skinner.skin(self.character.skin_matrices(world), self.method)
        return out if self.mush is None else self.mush.apply(out)

    def _smooth_points(self, points):
        """The smooth skin on the device, (V,) or (T, V) vec3, through the Delta Mush when there is one."""
        if self.mush is None:
            return points
        if points.ndim == 1:
            return self.mush.launch(points.reshape((1, points.shape[0]))).reshape((points.shape[0],))
        return self.mush.launch(points)

    def pose(self, world: np.ndarray, cvs: np.ndarray | None = None, curve: np.ndarray | None = None,
             frame: int | None = None) -> np.ndarray:
        """Deformed skin (V, 3) float32 metres.

        world : (J, 4, 4) rigid joint world transforms, metres, the character's joint order.
        cvs : (N, 3) the muscles' section CVs this frame (static, jiggled or blended), metres; None:
            the static shape for `world` (MuscleRig.static).
        curve : (M, 5, 3) the action-curve CVs; None: the static ones for `world`.
        frame : the frame's index, only for the warning that names a muscle skipped this frame.
        """
        world = np.asarray(world, dtype=np.float64)
        if self.skinning == "rbf":  # the features ride the CVs; the action curve is not needed
            cvs = self.rig.static(world).cvs if cvs is None else cvs
            out = self.deformer.pose(world, self._finite_cvs(cvs, world, frame))
            return out if self.mush is None else self.mush.apply(out)
        if cvs is None or curve is None:
            static = self.rig.static(world)
            cvs = static.cvs if cvs is None else cvs
            curve = static.curve if curve is None else curve
        points = self._smooth_points(self.skinner.launch(self.character.skin_matrices(world), self.method))
        if self.skinning == "shell":
            fr, skipped = self.frames.frame(world, cvs, curve, frame=frame or 0)
            for s in skipped:
                warnings.warn(f"{s.message}; the skin there follows the bones only", JiggleWarning, stacklevel=2)
            out = self.deformer.launch(points, fr)
        else:
            cvs = np.asarray(cvs, dtype=np.float64)
            ref = self.frames.carried_rest_cvs(world)
            bad = ~np.isfinite(cvs.reshape(self.rig.M, -1)).all(axis=1)
            if bad.any():
                self._warn(np.nonzero(bad)[0], frame, "its CVs hold NaN or inf")
                cvs = np.where(np.repeat(bad, self.rig.CVS_PER_MUSCLE)[:, None], ref, cvs)
            out = self.deformer.launch(points, cvs, ref)
        base = points.numpy()
        skin = self._spread(base[None], [out.numpy()[None]])[0]
        if self.ride is not None:
            self.ride.apply(base[None], [skin])
        return skin[0].copy()

    def lbs_batch(self, world: np.ndarray) -> np.ndarray:
        """Smooth skinning alone of T frames, (T, V, 3) float32 metres, for joint world transforms
        (T, J, 4, 4): `lbs` frame by frame, in one upload and one launch."""
        world = self._check_world_batch(world)
        out = self.skinner.skin_batch(self.character.skin_matrices(world), self.method)
        return out if self.mush is None else self.mush.apply(out)

    def pose_batch(self, world: np.ndarray, cvs_sets, curves, first_frame: int = 0, defer: bool = False,
                   smooth: bool = False, reuse: bool = False):
        """Deformed skins of T frames for S sets of muscle states: S arrays (T, V, 3) float32 metres
        (defer: a function returning them that finishes the skins' spread; the device work is done and
        every array it needs copied, so it may run in another thread while the caller goes on).

        world : (T, J, 4, 4) rigid joint world transforms, metres, the character's joint order.
        cvs_sets : S arrays (T, N, 3) of section CVs, metres (e.g. the static and the blended CVs);
            None: the static CVs for `world`.
        curves : S arrays (T, M, 5, 3) of action-curve CVs, metres; None: the static ones.
        first_frame : index of world[0], for the warnings naming a muscle skipped at a frame.
        smooth : also return the smooth skin alone (what :meth:`lbs_batch` returns: LBS / DQS, through
            the Delta Mush when there is one), (T, V, 3) float32, as one more array after the S sets;
            it is the skin the deformers start from, so it costs no launch ("rbf": lbs_batch's).
        reuse : the arrays returned (and what a deferred function reads) live in buffers this skin
            keeps and hands out in turn, two generations of them (shell and influence skins on the CPU;
            otherwise new arrays as without it): call n's arrays stay valid until call n + 2 with
            `reuse` overwrites them, and call n's deferred function must have run by then. The bake
            (at most two chunks in flight) saves allocating and faulting in ~(S + 1) x T x V x 12 bytes
            per chunk. Without it (default) every call returns new arrays.

        Set s at frame t equals ``pose(world[t], cvs_sets[s][t], curves[s][t], frame=first_frame + t)``
        to float32 rounding. The smooth skin is computed once for all sets (one launch for the T
        frames), the muscle frames of every set and frame in a few NumPy operations (the bones' part
        and the reference centres' curve parameters shared by sets over one curve), then one upload
        and one launch of the shells or the influence objects for all sets and frames, over the
        vertices that have pairs only: with a spread, it returns their displacements in the layout the
        spread smooths (rig.skin.surface_smoothing.SurfaceSmoothing.spread_front), which computes
        each step on the rings the displacement has reached. `launches` counts the Warp launches.
        """
        world = self._check_world_batch(world)
        S = len(cvs_sets)
        if S == 0 or len(curves) != S:
            raise InputError(f"expected as many curves as CVs sets (at least one), got {len(curves)} and {S}",
                             field="curves")
        T, V = len(world), self.character.num_vertices
        if T == 0:
            empty = [np.zeros((0, V, 3), np.float32) for _ in range(S + bool(smooth))]
            return (lambda: empty) if defer else empty
        if any(c is None for c in cvs_sets) or any(k is None for k in curves):
            static = self.rig.static(world)
            cvs_sets = [static.cvs if c is None else c for c in cvs_sets]
            curves = [static.curve if k is None else k for k in curves]
        before = self._launch_count()
        if self.skinning == "rbf":
            return self._pose_batch_rbf(world, cvs_sets, first_frame, defer, smooth, before)
        chunk = self._chunk(S, T, V, defer, smooth, reuse)
        points, base = self._smooth_batch(world, chunk)
        out = self._deform_batch(world, points, cvs_sets, curves, first_frame, chunk)
        if chunk.spread and self.spread_on_device:
            return self._finish_on_device(points, out, base, chunk, before)
        return self._finish_on_host(out, base, chunk, before)

    def _pose_batch_rbf(self, world: np.ndarray, cvs_sets: list, first_frame: int, defer: bool, smooth: bool,
                        before: int):
        """pose_batch of the "rbf" skin: the RBF skin of each CV set (T, N, 3) (one launch per set), mushed
        when the skin mushes, plus lbs_batch's smooth skin with `smooth`; `before`: _launch_count() at the start."""
        S = len(cvs_sets)
        out = self.deformer.pose_batch(world, [self._finite_cvs(c, world, first_frame) for c in cvs_sets])
        out = [o if self.mush is None else self.mush.apply(o) for o in out]
        extra = S                                     # the RBF skinner: one launch per set
        if smooth:
            out.append(self.lbs_batch(world))
        self.launches += self._launch_count() - before + extra
        return (lambda: out) if defer else out

    def _chunk(self, S: int, T: int, V: int, defer: bool, smooth: bool, reuse: bool) -> _Chunk:
        """How pose_batch runs a chunk of T frames for S sets (shell and influence skins): where its
        arrays live and whether the deformers' displacement is spread."""
        cpu = self.device.is_cpu
        # reuse: this call's generation of kept buffers; None: new arrays where they outlive the call
        slot = self._next_slot() if reuse and cpu else None
        keep = (defer or smooth or slot is not None) and cpu      # base outlives this call
        spread = self.spread.steps > 0 and len(self.spread.rows) > 0
        # where the displacements go: a host array that outlives the call (defer), else the deformer's buffer
        hold = spread and cpu and (defer or slot is not None)
        return _Chunk(S, T, V, cpu, slot, keep, spread, hold, smooth, defer)

    def _smooth_batch(self, world: np.ndarray, chunk: _Chunk):
        """The smooth skin of the chunk's T frames, one launch (and the Delta Mush's): the device's (T, V) vec3
        points and the host's (T, V, 3) float32 array `base` (the kept buffer "smooth" when it outlives the
        call, `chunk.keep`)."""
        T, V, slot = chunk.T, chunk.V, chunk.slot
        matrices = self.character.skin_matrices(world)
        if chunk.keep and self.mush is None:      # skinned straight into the host array returned: no copy
            base = self._host(slot, "smooth", (T, V, 3))
            points = self.skinner.launch_batch(matrices, self.method, out=_on_device(base, self.device))
        else:
            points = self._smooth_points(self.skinner.launch_batch(matrices, self.method))
            base = points.numpy()
            if chunk.keep:                        # the device buffers are reused by the next call
                base = _copy_into(self._host(slot, "smooth", (T, V, 3)), base)
        return points, base

    def _deform_batch(self, world: np.ndarray, points, cvs_sets: list, curves: list, first_frame: int,
                      chunk: _Chunk):
        """The shells' (or the influence objects') one launch over the smooth skin `points` (T, V) vec3 for
        all sets and frames: a Warp array, (S, P, T, 3) the paired vertices' displacements with a spread
        (in the kept buffer "moved" with `chunk.hold`, shells), else (S, T, V, 3) the skins."""
        if self.skinning == "shell":
            # only "trajectory" muscles read the paths along the action curves
            paths = bool(np.any(self.table.mode == MODES.index("trajectory")))
            arrays, skipped = self.frames.frame_sets(world, cvs_sets, curves, first_frame, paths=paths)
            for sk in skipped:
                for s in sk:        # stacklevel 3: pose_batch's caller
                    warnings.warn(f"{s.message}; the skin there follows the bones only", JiggleWarning,
                                  stacklevel=3)
            batch = ShellBatch(*arrays)
            if chunk.spread:
                shape = (chunk.S, self.deformer.model.num_paired, chunk.T, 3)
                held = self._host(chunk.slot, "moved", shape) if chunk.hold else None
                return self.deformer.launch_displace(points, batch, out=_on_device(held, self.device))
            return self.deformer.launch_batch(points, batch)
        cur, ref = self._influence_cvs(world, cvs_sets, first_frame)
        return self.deformer.launch_batch(points, cur, ref, displace=chunk.spread)

    def _finish_on_device(self, points, out, base: np.ndarray, chunk: _Chunk, before: int):
        """pose_batch's end on a GPU: each set's displacements `out` (S, P, T, 3) spread on the device
        over the smooth skin `points` (T, V) vec3; `before`: _launch_count() at the start."""
        S = chunk.S
        # a GPU spreads on the device and hands back the finished skins (new arrays, copied in `finish`,
        # which may run in another thread: the device keeps the order of the work)
        skins = [self.spread.spread_device(points, out[s]) for s in range(S)]
        self.launches += self._launch_count() - before + len(self.spread.front) * S + S

        def finish():
            return [sk.numpy() for sk in skins] + ([base] if chunk.smooth else [])
        return self._finish(finish, base, S, chunk.defer)

    def _finish_on_host(self, out, base: np.ndarray, chunk: _Chunk, before: int):
        """pose_batch's end on the host: the deformers' Warp array `out` copied back, then each set's
        displacements (S, P, T, 3) spread over the smooth skin `base` (T, V, 3) (`_spread_moved`), or the
        skins (S, T, V, 3) as they are; `before`: _launch_count() at the start."""
        S, T, V, slot = chunk.S, chunk.T, chunk.V, chunk.slot
        out = out.numpy()
        if chunk.hold and self.skinning != "shell":
            out = _copy_into(self._host(slot, "moved", out.shape), out)
        # out: (S, P, T, 3) displacements with a spread, else (S, T, V, 3)
        self.launches += self._launch_count() - before
        if chunk.spread:
            moved = out            # a host array of its own when it outlives the call (hold), or the GPU's copy
            sets = [self._host(slot, f"set{s}", (T, V, 3)) for s in range(S)] if slot is not None else None

            def finish():
                return self._spread_moved(base, moved, threads=not chunk.defer, out=sets) + (
                    [base] if chunk.smooth else [])
        else:
            sets = ([_copy_into(self._host(slot, f"set{s}", (T, V, 3)), out[s]) for s in range(S)] if chunk.cpu
                    else [out[s] for s in range(S)]) + ([base] if chunk.smooth else [])

            def finish():
                return sets
        return self._finish(finish, base, S, chunk.defer)

    def _finish(self, finish, base: np.ndarray, S: int, defer: bool):
        """pose_batch's end: `finish` (or a function doing it, `defer`), with the rigid pieces set on
        the smooth skin `base` (T, V, 3) plus their ride (rig.character.gear.Ride) in its S sets."""
        if self.ride is None:
            return finish if defer else finish()

        def done():
            out = finish()
            self.ride.apply(base, out[:S])
            return out
        return done if defer else done()

    def _launch_count(self) -> int:
        """Warp launches made so far by the skinner, the Delta Mush and the deformer."""
        return sum(getattr(x, "launches", 0) for x in (self.skinner, self.mush, self.deformer) if x is not None)

    def _influence_cvs(self, world: np.ndarray, cvs_sets, first_frame: int) -> tuple[np.ndarray, np.ndarray]:
        """Influence objects' CVs: (S, T, N, 3) each set's, every muscle holding NaN or inf put back on
        its carried rest shape at that frame (with the warning naming it and the frame), and the carried
        rest CVs (T, N, 3)."""
        ref = self.frames.carried_rest_cvs(world)                                          # (T, N, 3)
        T = len(ref)
        cur = np.empty((len(cvs_sets),) + ref.shape)
        for s, cvs in enumerate(cvs_sets):
            cvs = np.asarray(cvs, dtype=np.float64)
            if cvs.shape != ref.shape:
                raise InputError(f"expected CVs {ref.shape}, got {cvs.shape}", field="cvs_sets")
            bad = ~np.isfinite(cvs.reshape(T, self.rig.M, -1)).all(axis=2)                 # (T, M)
            for t in np.nonzero(bad.any(axis=1))[0]:
                self._warn(np.nonzero(bad[t])[0], first_frame + int(t), "its CVs hold NaN or inf")
            cur[s] = np.where(np.repeat(bad, self.rig.CVS_PER_MUSCLE, axis=1)[..., None], ref, cvs)
        return cur, ref

    def _spread_moved(self, smooth: np.ndarray, moved: np.ndarray, threads: bool = True, out=None) -> list:
        """Skins (T, V, 3) each smooth + spread(displacement), for the smooth skin (T, V, 3) and the
        deformers' displacements of the paired vertices (S, P, T, 3) (ring 0 of the spread): each set's
        spread over the rings it reaches (SurfaceSmoothing.spread_front), added to the smooth skin
        there and scattered into a copy of it, written into out[s] (S arrays (T, V, 3) float32) or new
        arrays; one set per worker thread (NumPy and SciPy run without the GIL), or one after the
        other without `threads`. Equal to :meth:`_spread` of the full skins bit for bit.

        A block of 16 frames at a time, everything in a kept workspace (`_workspace`) of a few MB that
        stays in the cache: no array the size of the chunk is made besides the outputs, each of whose
        pages is written by one copy and one scatter."""
        sm = self.spread
        order = sm.order
        T, V = smooth.shape[:2]
        R, n0 = len(order), int(sm.ring_ends[0])
        vec = np.dtype((np.void, 12))          # a vertex's xyz as one item: a scatter 3x faster than [:, rows]
        smooth_v = smooth.view(vec).reshape(T, V)
        step = max(BLOCK // 3, 1)

        def one(s):
            x = moved[s].reshape(n0, 3 * T)
            dst = np.empty_like(smooth) if out is None else out[s]
            dst_v = dst.view(vec).reshape(T, V)
            work, d_flat, rows_all, d_frames = self._workspace()
            try:
                # a few frames at a time, each block's spread added, scattered and copied while in the cache
                for a in range(0, T, step):
                    b = min(a + step, T)
                    n = b - a
                    d = d_flat[:R * 3 * n].reshape(R, 3 * n)
                    sm.spread_front(x[:, 3 * a:3 * b], out=d, work=work)              # (R, 3 n)
                    rows, dt = rows_all[:n], d_frames[:n]                            # (n, R, 3)
                    rows_v = rows.view(vec).reshape(n, R)
                    # frames first: the smooth skin's rows and the spread transposed as 12-byte items
                    # (plain copies), then added as floats (the same sums as base + d); per frame, a
                    # gather and a scatter of R items stay in the cache
                    np.copyto(dt.view(vec).reshape(n, R), d.view(vec).reshape(R, n).T)
                    for t in range(n):
                        np.take(smooth_v[a + t], order, out=rows_v[t], mode="clip")
                    np.add(rows, dt, out=rows)
                    dst[a:b] = smooth[a:b]
                    for t in range(n):
                        np.put(dst_v[a + t], order, rows_v[t], mode="clip")
            finally:
                self._workspace(release=(work, d_flat, rows_all, d_frames))
            return dst
        S = len(moved)
        return list(pool().map(one, range(S))) if threads and S > 1 else [one(s) for s in range(S)]

    def _workspace(self, release=None):
        """A spread workspace (spread_front's `work`, (R * BLOCK,) and twice (BLOCK // 3, R, 3) float32) for one
        set in one thread, kept between calls (one per thread that ever spread at the same time), or
        `release` one."""
        with self._work_lock:
            if release is not None:
                self._work_free.append(release)
                return None
            if self._work_free:
                return self._work_free.pop()
        R = len(self.spread.order)
        F = max(BLOCK // 3, 1)
        return (self.spread.workspace(), np.empty(R * BLOCK, np.float32), np.empty((F, R, 3), np.float32),
                np.empty((F, R, 3), np.float32))

    def _next_slot(self) -> dict:
        """The next generation of kept host buffers (pose_batch's `reuse`: two, in turn)."""
        self._turn = (self._turn + 1) % len(self._slots)
        return self._slots[self._turn]

    def _host(self, slot, name: str, shape: tuple) -> np.ndarray:
        """A C-contiguous float32 array `shape`: slot None a new one; else the slot's buffer `name`,
        grown when it is too small (the last, shorter chunk of a bake takes a prefix of it)."""
        n = int(np.prod(shape))
        if slot is None:
            return np.empty(shape, np.float32)
        buf = slot.get(name)
        if buf is None or buf.size < n:
            buf = slot[name] = np.empty(n, np.float32)
        return buf[:n].reshape(shape)

    def _finite_cvs(self, cvs, world: np.ndarray, first_frame: int | None) -> np.ndarray:
        """CVs (N, 3) or (T, N, 3) with every muscle holding NaN or inf put back on its rest shape carried
        by its bone (with the warning that names it), so the RBF skin stays finite."""
        cvs = np.asarray(cvs, dtype=np.float64)
        bad = ~np.isfinite(cvs.reshape(cvs.shape[:-2] + (self.rig.M, -1))).all(axis=-1)
        if not bad.any():
            return cvs
        ref = self.frames.carried_rest_cvs(world)
        rows = np.repeat(bad, self.rig.CVS_PER_MUSCLE, axis=-1)[..., None]
        for t, m in zip(*np.nonzero(bad.reshape(-1, self.rig.M))):
            self._warn([m], None if first_frame is None else first_frame + int(t), "its CVs hold NaN or inf")
        return np.where(rows, ref, cvs)

    def _check_world_batch(self, world) -> np.ndarray:
        world = np.asarray(world, dtype=np.float64)
        J = self.character.num_joints
        if world.ndim != 4 or world.shape[1:] != (J, 4, 4):
            raise InputError(f"expected (T, {J}, 4, 4) joint world transforms, got {world.shape}", field="world")
        return world

    def _warn(self, muscles, frame, why: str) -> None:
        names = ", ".join(repr(self.rig.names[m]) for m in muscles)
        at = "" if frame is None else f" at frame {frame}"
        warnings.warn(f"muscle {names} skipped{at}: {why}; the skin there follows the bones only",
                      JiggleWarning, stacklevel=3)


@dataclass(frozen=True)
class _Chunk:
    """How MuscleSkin.pose_batch runs one chunk of T frames for S sets over V vertices (shell and
    influence skins): set once per call by MuscleSkin._chunk, read by its steps."""
    S: int
    T: int
    V: int
    cpu: bool           # the skin's device is the CPU
    slot: dict | None   # reuse: this call's generation of kept host buffers; None: new arrays where they outlive it
    keep: bool          # the smooth skin `base` outlives this call (a host buffer of its own)
    spread: bool        # the deformers' displacement is spread over the surface
    hold: bool          # the displacements go to a host buffer that outlives the call, not the deformer's
    smooth: bool        # the smooth skin is returned too, after the S sets
    defer: bool         # a function finishing the skins is returned


def _checked_inputs(character: Character, rig: MuscleRig, shells, weights, *, skinning: str, method: str,
                    margin: float, spread: float) -> tuple[list[ShellParams], np.ndarray]:
    """MuscleSkin's arguments checked (InputError naming the one at fault): the shells, one ShellParams
    per muscle (each kind's default for None), and the painted weights (V, M) float32 in [0, 1]."""
    if skinning not in SKINNING:
        raise InputError(f"expected one of {', '.join(SKINNING)}, got {skinning!r}", field="skinning")
    if method not in ("lbs", "dqs"):
        raise InputError(f"expected 'lbs' or 'dqs', got {method!r}", field="method")
    if rig.num_joints != character.num_joints:
        raise InputError(f"the muscle rig has {rig.num_joints} joints, the character {character.num_joints}",
                         field="rig")
    if not (np.isfinite(margin) and margin >= 0.0):
        raise InputError(f"expected a number >= 0, got {margin}", field="margin")
    if not (np.isfinite(spread) and spread >= 0.0):
        raise InputError(f"expected a number >= 0, got {spread}", field="spread")
    M, V = rig.M, character.num_vertices
    shells = [default_shell(k) for k in rig.kinds] if shells is None else list(shells)
    if len(shells) != M or not all(isinstance(s, ShellParams) for s in shells):
        raise InputError(f"expected {M} ShellParams, one per muscle, got {len(shells)}", field="shells")
    painted = np.ones((V, M), np.float32) if weights is None else np.asarray(weights, np.float32)
    if painted.shape != (V, M):
        raise InputError(f"expected ({V}, {M}) weights (vertices, muscles), got {painted.shape}",
                         field="weights")
    if not np.all((painted >= 0.0) & (painted <= 1.0)):
        raise InputError("painted weights must lie in [0, 1] (and not be NaN)", field="weights")
    return shells, painted


def _delta_mush(character: Character, mush, device) -> DeltaMush | None:
    """The Delta Mush of `mush` steps (a whole number >= 0, else InputError) over the character's skin,
    or None for 0."""
    if isinstance(mush, bool) or int(mush) != mush or mush < 0:
        raise InputError(f"expected a whole number >= 0, got {mush!r}", field="mush")
    return (DeltaMush(character.vertices, character.faces, iterations=int(mush), device=device)
            if mush else None)


def _soft_pairs(rigid: np.ndarray, offsets: np.ndarray, muscle: np.ndarray, vertex: np.ndarray, influence):
    """The (vertex, muscle) pairs on soft vertices only, for the rigid vertices `rigid` (V,) bool: CSR
    `offsets` (V + 1,) recounted, `muscle`, `vertex` and `influence` (P,) (or None) kept where soft."""
    keep = ~rigid[vertex]
    muscle, vertex = muscle[keep], vertex[keep]
    influence = None if influence is None else influence[keep]
    offsets = np.concatenate([[0], np.cumsum(np.bincount(vertex, minlength=len(rigid)))]).astype(offsets.dtype)
    return offsets, muscle, vertex, influence


def _on_device(a: np.ndarray | None, device):
    """A host float32 array (..., 3) as a Warp vec3 array over the same memory (the CPU device), or None."""
    return None if a is None else wp.array(a, dtype=wp.vec3, device=device, copy=False)


def _copy_into(dst: np.ndarray, src: np.ndarray) -> np.ndarray:
    np.copyto(dst, src)
    return dst


def skin_frames(skin, world: np.ndarray, cvs_sets, curve: np.ndarray, frames: np.ndarray, defer: bool = False,
                smooth: bool = False, reuse: bool = False):
    """The pipeline's skin stage: skins (T, V, 3) float32 metres, one per CV set (T, N, 3), over joint
    world transforms (T, J, 4, 4) and action curves (T, M, 5, 3).

    frames : (T,) the frame numbers, for warnings naming a muscle skipped at a frame. Batched over
    the frames in one launch per set (MuscleSkin.pose_batch, equal to posing frame by frame) when the
    frames are consecutive and the skin can; frame by frame otherwise.
    With several sets the first is the static one: where the skin has a `jiggle_mask` or a
    `jiggle_spread` (the RBF skin), every other set's difference from it (its jiggle) is scaled by the
    mask (zones without muscles show none) and spread over the surface; then, where the character has
    a painted jiggle map (MuscleSkin.jiggle_map), scaled by it per vertex (rig.skin.painted_maps); then every
    other set's jiggle is held together across the edges the static skin squeezes (MuscleSkin.creases,
    rig/skin/creases.py), so a crease or an abrupt seam of the weights does not tear it.
    defer : return a function that finishes the skins instead (the surface spread, no device work:
    the bake runs it in a worker thread while the next chunk is simulated; sim/bake/baker.py).
    smooth : also return the smooth skin alone (MuscleSkin.lbs_batch's: LBS / DQS, mushed when the skin
    mushes), (T, V, 3) float32, as one more array after the sets (pose_batch's, at no extra launch).
    reuse : MuscleSkin.pose_batch's: the arrays live in buffers the skin keeps, two generations in turn
    (valid until the second batched call after this one; a deferred function must run before it); the
    bake's two chunks in flight. Ignored frame by frame (new arrays).
    """
    frames = np.asarray(frames, dtype=np.int64).reshape(-1)
    n = len(cvs_sets)
    if hasattr(skin, "pose_batch") and (len(frames) < 2 or np.all(np.diff(frames) == 1)):
        first = int(frames[0]) if len(frames) else 0
        kw = {"reuse": True} if reuse else {}       # only asked of skins that take it
        done = skin.pose_batch(world, list(cvs_sets), [curve] * n, first_frame=first, defer=defer, smooth=smooth,
                               **kw)
        pending = done if defer else (lambda: done)
    else:
        out = [np.stack([skin.pose(world[k], cvs[k], curve[k], frame=int(frames[k])) for k in range(len(world))])
               for cvs in cvs_sets]
        if smooth:
            out.append(skin.lbs_batch(world) if hasattr(skin, "lbs_batch")
                       else np.stack([skin.lbs(w) for w in world]).astype(np.float32))
        pending = lambda: out  # noqa: E731

    def finish() -> list[np.ndarray]:
        out = list(pending())
        mask, spread = getattr(skin, "jiggle_mask", None), getattr(skin, "jiggle_spread", None)
        painted = getattr(skin, "jiggle_map", None)
        for s in range(1, n):
            if mask is not None or spread is not None:
                d = out[s] - out[0]
                d = d if mask is None else np.asarray(mask, np.float32)[:, None] * d
                out[s] = out[0] + (d if spread is None else spread(d))
            if painted is not None:     # where the map is 0 the final skin is the static one exactly
                out[s] = painted.apply(out[0], out[s])
        creases = getattr(skin, "creases", None)
        if creases is not None and n > 1:   # the jiggle held together where the smooth skin squeezes the surface
            creases.hold(out[0], out[1:n])
        character = getattr(skin, "character", None)
        if character is not None:       # the seams closed on every set (rig/skin/seams.py); LBS needs none
            from jiggle.rig.skin.seams import for_character, weld
            groups = for_character(character)
            out[:n] = [weld(o, groups) for o in out[:n]]
        return out
    return finish if defer else finish()
