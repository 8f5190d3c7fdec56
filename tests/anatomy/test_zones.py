"""Geodesic zones (rig.anatomy.zones): body parts from roles, neighbours from the skeleton, a blend that is a
partition of unity mixing only neighbouring zones near their boundary."""
from __future__ import annotations

import numpy as np
import pytest
from conftest import asset

from jiggle.rig.anatomy.zones import blend_weights, body_zones, edge_graph, segment_zones, skeleton_neighbours
from jiggle.rig.base.errors import InputError
from jiggle.rig.character.bone_heat import weld


@pytest.fixture(scope="module")
def cesium():
    from jiggle.rig.character.load import load_character
    from jiggle.rig.motion.role_map import resolve_roles
    from jiggle.rig.muscle.segmentation import segment_skin
    c = load_character(asset("characters/CesiumMan.glb"))
    seg = segment_skin(c)
    roles = resolve_roles(c.skeleton)
    z = body_zones(c.vertices, c.faces, seg.region, seg.segments, c.parents, c.joint_names, roles, 0.04 * c.height)
    return c, seg, roles, z


def test_cesium_zones_are_body_parts(cesium):
    c, seg, roles, z = cesium
    assert set(z.names) == {"torso", "head"} | {f"{s}_{p}" for s in ("left", "right") for p in (
        "upper_arm", "lower_arm", "hand", "upper_leg", "lower_leg", "foot")}
    assert (z.counts() > 0).all()
    nb = lambda a, b: bool(z.neighbours[z.index(a), z.index(b)])  # noqa: E731
    assert nb("left_upper_leg", "torso") and nb("left_upper_leg", "left_lower_leg")
    # the thighs touch at the crotch on the mesh but share no joint: one leg never moves the other
    assert not nb("left_upper_leg", "right_upper_leg")
    assert not nb("left_hand", "torso") and not nb("head", "left_upper_arm")
    assert (z.neighbours == z.neighbours.T).all() and z.neighbours.diagonal().all()
    # the left thigh's vertices sit on the left (+X for CesiumMan), the right's on the right
    assert c.vertices[z.vertex_zone == z.index("left_upper_leg"), 0].min() > 0
    assert c.vertices[z.vertex_zone == z.index("right_upper_leg"), 0].max() < 0


def test_blend_is_a_partition_of_unity_over_neighbours(cesium):
    c, _, _, z = cesium
    b = z.blend.tocoo()
    rows = np.asarray(z.blend.sum(axis=1)).ravel()
    np.testing.assert_allclose(rows, 1.0, atol=1e-12)
    assert (b.data > 0).all()
    assert z.neighbours[z.vertex_zone[b.row], b.col].all()
    mixed = z.blend.getnnz(axis=1) > 1
    assert 0 < mixed.sum() < 0.5 * len(mixed)           # only near boundaries
    dense = z.blend.toarray()
    own = dense[np.arange(len(dense)), z.vertex_zone]
    assert (own[:, None] >= dense - 1e-12).all()         # a vertex's own zone weighs the most


def test_blend_falls_off_with_geodesic_distance():
    # a strip of 11 x 2 vertices along x, split at x = 0.5 into two neighbouring zones
    x = np.linspace(0.0, 1.0, 11)
    v = np.r_[np.c_[x, np.zeros(11), np.zeros(11)], np.c_[x, np.ones(11) * 0.1, np.zeros(11)]]
    f = []
    for i in range(10):
        f += [[i, i + 1, 11 + i + 1], [i, 11 + i + 1, 11 + i]]
    zone = (v[:, 0] > 0.5).astype(np.int32)
    nb = np.ones((2, 2), bool)
    w = blend_weights(v, np.array(f), zone, nb, band=0.25).toarray()
    other = w[np.arange(len(v)), 1 - zone]
    # weight of the other zone: 0 beyond the band, growing toward the boundary, below a half
    assert (other[np.abs(v[:, 0] - 0.5) > 0.3] == 0).all()
    left = other[:6][::-1]  # x = 0.5, 0.4, ..., 0.0 (zone 0), distance to zone 1 grows
    assert (np.diff(left) <= 1e-15).all() and left[0] > 0.25 and (other < 0.5 + 1e-12).all()
    # not neighbours: no mixing at all
    w0 = blend_weights(v, np.array(f), zone, np.eye(2, dtype=bool), band=0.25).toarray()
    assert (w0[np.arange(len(v)), zone] == 1).all()


def test_weld_joins_seam_copies():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 0, 0.0]])
    ids = weld(v, np.array([[0, 1, 2]]))[2]
    assert ids[1] == ids[3] and len(set(ids)) == 3
    ids, g = edge_graph(v, np.array([[0, 1, 2], [3, 2, 0]]))
    assert g.shape == (3, 3) and g.nnz == 6


def test_without_roles_every_segment_is_a_zone(cesium):
    c, seg, _, _ = cesium
    names, sz = segment_zones(seg.segments, c.parents, c.joint_names, None)
    assert names == seg.segments.labels and (sz == np.arange(len(names))).all()
    nb = skeleton_neighbours(seg.segments, sz, len(names))
    assert (nb == nb.T).all() and nb.sum() > len(names)


def test_bad_input(cesium):
    c, seg, roles, _ = cesium
    with pytest.raises(InputError, match="band"):
        body_zones(c.vertices, c.faces, seg.region, seg.segments, c.parents, c.joint_names, roles, -1.0)
    with pytest.raises(InputError, match="vertex_segment"):
        body_zones(c.vertices, c.faces, seg.region[:-1], seg.segments, c.parents, c.joint_names, roles, 0.0)
    _, _, _, z = cesium
    with pytest.raises(InputError, match="no zone"):
        z.index("tail")
