"""The bone capsules in `jiggle fit`'s outputs (a panel of fit.png, a list in muscles.json), and the capsules
built from a real character sitting inside its skin (rig/character/capsules.py)."""
from __future__ import annotations

import numpy as np

from jiggle.rig.character.capsules import BoneCapsules
from jiggle.sim.app.outputs.fit import capsule_facts, capsule_meshes


def two_capsules() -> BoneCapsules:
    ends = np.array([[[0.0, 0.0, 0.0], [0.0, 0.0, 0.4]], [[0.1, 0.0, 0.0], [0.4, 0.0, 0.0]]])
    return BoneCapsules(joint=[0, 0], child=[-1, -1], local=ends, radius=[0.05, 0.02], names=["a>b", "a>c"],
                        parents=np.array([-1]))


def test_capsule_facts_and_meshes():
    """Facts: radius and axis length in mm; meshes: each spans its axis plus the radius at both ends (a
    cylinder with hemispherical caps), within a facet's sag."""
    caps = two_capsules()
    bind = np.eye(4)[None]
    assert capsule_facts(caps, bind) == [{"bone": "a>b", "radius_mm": 50.0, "length_mm": 400.0},
                                         {"bone": "a>c", "radius_mm": 20.0, "length_mm": 300.0}]
    meshes = capsule_meshes(caps, bind)
    lo, hi = np.asarray(meshes[0].bounds).reshape(3, 2).T
    np.testing.assert_allclose(lo, [-0.05, -0.05, -0.05], atol=2e-3)
    np.testing.assert_allclose(hi, [0.05, 0.05, 0.45], atol=2e-3)
    lo, hi = np.asarray(meshes[1].bounds).reshape(3, 2).T
    np.testing.assert_allclose([lo[0], hi[0]], [0.08, 0.42], atol=1e-3)


def test_capsules_sit_inside_the_skin():
    """On CesiumMan (skinned glTF): every point of every capsule's axis lies at least 10% of its radius
    inside the skin (nearest skin vertex, sampled densely: rig/character/capsules.py INSIDE_FRACTION), and a
    leaf's capsule stops inside the skin its joint dominates."""
    from conftest import asset
    from scipy.spatial import cKDTree

    from jiggle.rig.character.capsules import bone_capsules
    from jiggle.rig.character.load import load_character
    ch = load_character(str(asset("characters/CesiumMan.glb")))
    caps = bone_capsules(ch)
    assert caps.count >= 10
    ends = caps.ends(ch.bind_world)
    tree = cKDTree(np.asarray(ch.vertices))
    for c in range(caps.count):
        pts = ends[c, 0] + np.linspace(0.0, 1.0, 33)[:, None] * (ends[c, 1] - ends[c, 0])
        d, _ = tree.query(pts)
        # between two samples of the check (17 along the axis) the distance may dip by half a sample step
        step = np.linalg.norm(ends[c, 1] - ends[c, 0]) / 16
        assert d.min() + 0.5 * step > caps.radius[c], caps.names[c]
