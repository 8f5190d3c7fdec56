"""Anatomy-driven RBF skinning for animation (Simmons et al. 2002, sections 2 and 4; `skinning = "rbf"`).

    bind:      feature vertices (rig.anatomy.features, snapped to existing vertices so the mesh keeps its
               topology and the caches match the character) anchored to bones and muscles;
               geodesic zones (rig.anatomy.zones); per vertex the cardinal RBF weights of its zone's
               interpolant over the features of the zone and its neighbours (rig.anatomy.rbf.build_zone_rbf),
               kept to `support` non-zeros with affine reproduction restored
    per frame: feature positions ride their components: bone anchors with the joint transforms,
               muscle anchors on the loft of the current CVs (static, jiggling or blended)
               --> skin = W @ features, one sparse product (a Warp launch, rig.anatomy.rbf.RBFSkinner)

The jiggle stays where muscles are: `jiggle_mask` (V,) is 1 in the zones that hold a muscle's feature
points and 0 in the others (head, hands, feet), blended across zone boundaries, and the pipeline's
skin stage scales the skin's jiggle (final - static) by it (rig.skin.muscle_skin.skin_frames). Without
it the head, whose zone borrows the torso's feature points near the neck, nodded with the pectorals'
jiggle (issue 18: 30-40 mm).

No smooth skinning runs underneath: the feature points carry the bones and the muscles, the RBF
interpolates the rest ("the skin follows the underlying components closely at selected locations
... but can smoothly interpolate to avoid most of the artifacts that can occur when the surface
buckles at joints"). At the bind pose with the muscles at rest the skin is the artist's skin: the
weights reproduce affine maps exactly, and the identity is one.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from jiggle.rig.base.errors import InputError


@dataclass(frozen=True)
class RBFSkinOptions:
    """kernel, scale (fraction of the height), support (non-zeros per vertex), band (fraction of the
    height), features (rig.anatomy.features.FeatureOptions or None: the defaults, snapping)."""

    kernel: str = "soliton"
    scale: float = 0.1
    support: int = 32
    band: float = 0.04
    features: object = None


class RBFSkin:
    """The RBF skin of a character over its bones and muscles.

    character : rig.character.character.Character; rig : rig.muscle.model.MuscleRig (None: bones only);
    segmentation : rig.muscle.segmentation.Segmentation of the character's skin, or None to compute it;
    roles : {role: joint} or None to resolve them. device : Warp device.
    """

    def __init__(self, character, rig=None, *, segmentation=None, roles=None,
                 options: RBFSkinOptions = RBFSkinOptions(), device: str = "cpu"):
        from dataclasses import replace

        from jiggle.rig.anatomy.features import FeatureOptions, find_features
        from jiggle.rig.anatomy.rbf import RBFOptions, RBFSkinner, build_zone_rbf
        from jiggle.rig.anatomy.zones import body_zones
        from jiggle.rig.motion.role_map import resolve_roles
        from jiggle.rig.muscle.segmentation import segment_skin

        if segmentation is None:
            segmentation = segment_skin(character)
        if roles is None:
            try:
                roles = resolve_roles(character.skeleton)
            except InputError:
                roles = None  # not a humanoid: a zone per bone segment
        fo = replace(options.features or FeatureOptions(), insert=False)
        self.features = fs = find_features(character, segmentation.segments, rig, fo)
        H = character.height
        self.zones = body_zones(character.vertices, character.faces, segmentation.region, segmentation.segments,
                                character.parents, character.joint_names, roles, options.band * H)
        vertex = np.asarray(fs.vertex, np.int64)
        rbf = RBFOptions(kernel=options.kernel, scale=options.scale * H, support=options.support)
        self.weights = build_zone_rbf(character.vertices, fs.anchors.rest, self.zones.vertex_zone[vertex],
                                      self.zones, rbf, feature_vertex=vertex)
        self.skinner = RBFSkinner(self.weights, device=device)
        self.character, self.rig, self.options = character, rig, options
        # zones that hold a muscle's features show the jiggle, the others (head, hands, feet) do not,
        # blended across the zone boundaries like the interpolants themselves
        from jiggle.rig.anatomy.features import MUSCLE
        holds = np.zeros(self.zones.num_zones)
        holds[self.zones.vertex_zone[vertex[np.asarray(fs.anchors.kind) == MUSCLE]]] = 1.0
        self.jiggle_mask = np.clip(np.asarray(self.zones.blend @ holds).ravel(), 0.0, 1.0).astype(np.float32)
        self.num_cvs = 0 if rig is None else len(rig.rest_cvs)

    @property
    def num_features(self) -> int:
        return len(self.features.vertex)

    def feature_positions(self, world: np.ndarray, cvs: np.ndarray | None) -> np.ndarray:
        """(F, 3) or (T, F, 3) float64 metres: the feature points on their components for joint world
        transforms (J, 4, 4) or (T, J, 4, 4) and muscle CVs (N, 3) or (T, N, 3) (None: rest CVs)."""
        world = np.asarray(world, np.float64)
        if cvs is None and self.rig is not None:
            cvs = np.broadcast_to(self.rig.rest_cvs, world.shape[:-3] + self.rig.rest_cvs.shape)
        return self.features.anchors.positions(world, cvs)

    def pose(self, world: np.ndarray, cvs: np.ndarray | None = None) -> np.ndarray:
        """Skin (V, 3) float32 metres for one frame."""
        return self.skinner.apply(self.feature_positions(world, cvs))

    def pose_batch(self, world: np.ndarray, cvs_sets) -> list[np.ndarray]:
        """S skins (T, V, 3) float32 metres for joint transforms (T, J, 4, 4) and S CV arrays (T, N, 3)."""
        world = np.asarray(world, np.float64)
        return [self.skinner.apply_batch(self.feature_positions(world, cvs)) for cvs in cvs_sets]
