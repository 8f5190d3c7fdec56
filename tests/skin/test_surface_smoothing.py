"""The skin's spreading of the muscles' displacement (rig/skin/surface_smoothing.py)."""
import meshes
import numpy as np
import pytest

from jiggle.rig.base.errors import InputError
from jiggle.rig.character.mesh_graph import mesh_neighbours
from jiggle.rig.skin.quality import SkinQuality
from jiggle.rig.skin.surface_smoothing import BLOCK, SurfaceSmoothing, steps_for_reach


def grid(n=21, size=0.4):
    return meshes.grid(n, size)


def reference(field, faces, steps, step=0.5):
    """Dense NumPy: x <- (1 - step) x + step mean(neighbours)."""
    A = mesh_neighbours(faces, len(field)).toarray()
    mean = A / A.sum(axis=1, keepdims=True)
    x = field.astype(np.float64)
    for _ in range(steps):
        x = (1 - step) * x + step * (mean @ x)
    return x


def test_equals_the_dense_reference_and_keeps_uniform_fields():
    verts, faces = grid()
    rng = np.random.default_rng(0)
    field = rng.normal(size=(3, len(verts), 3)).astype(np.float32)
    s = SurfaceSmoothing(faces, len(verts), 7, step=0.5)
    got = s(field)
    for t in range(3):
        np.testing.assert_allclose(got[t], reference(field[t], faces, 7), atol=1e-5)
    uniform = np.broadcast_to(np.array([0.01, -0.02, 0.03], np.float32), (len(verts), 3))
    np.testing.assert_allclose(s(uniform), uniform, atol=1e-8)
    assert np.array_equal(SurfaceSmoothing(faces, len(verts), 0)(field), field)


def test_restricted_to_the_active_vertices_and_their_rings_is_exact():
    """A field that is 0 off the active vertices smooths the same on the active set and its n rings
    as on the whole mesh; vertices farther away are not even computed."""
    verts, faces = grid()
    active = np.linalg.norm(verts[:, :2] - 0.2, axis=1) < 0.06
    field = np.where(active[:, None], np.float32(0.01), np.float32(0.0)) * np.ones((len(verts), 3), np.float32)
    part = SurfaceSmoothing(faces, len(verts), 5, active)
    whole = SurfaceSmoothing(faces, len(verts), 5)
    np.testing.assert_allclose(part(field), whole(field), atol=1e-9)
    assert len(part.rows) < len(verts)


def test_a_step_in_the_field_stops_tearing_the_skin():
    """A pad's outline as a step of 2 cm in the displacement across one 2 cm edge tears the edges along
    it (gradient 1); spread over 2.3 cm it no longer does, and the pad keeps most of its displacement."""
    verts, faces = grid()
    q = SkinQuality(verts, faces)
    pad = (verts[:, 0] > 0.15) & (verts[:, 0] < 0.25)
    d = np.zeros_like(verts, dtype=np.float32)
    d[pad, 2] = 0.02
    moved = (verts + d)[None].astype(np.float32)
    assert q.jiggle(verts[None], moved)["gradient_max"][0] >= 0.99
    steps = steps_for_reach(verts, faces, 0.023)
    spread = verts + SurfaceSmoothing(faces, len(verts), steps)(d)
    j = q.jiggle(verts[None], spread[None].astype(np.float32))
    assert j["torn_edges"][0] == 0 and j["gradient_max"][0] < 0.6
    assert spread[pad, 2].max() > 0.8 * 0.02


def test_steps_follow_the_reach_not_the_mesh_resolution():
    coarse, cf = grid(21)
    fine, ff = grid(41)                     # edges half as long: four times the steps for one reach
    assert steps_for_reach(coarse, cf, 0.05) * 4 == pytest.approx(steps_for_reach(fine, ff, 0.05), rel=0.1)
    assert steps_for_reach(fine, ff, 0.0) == 0
    with pytest.raises(InputError):
        SurfaceSmoothing(ff, len(fine), -1)


@pytest.mark.parametrize("steps", [0, 1, 5])
def test_spread_front_equals_the_steps_on_all_rows(steps):
    """A field zero beyond the active vertices: the front-restricted steps (each over the rings the
    field has reached, rows by ring) equal smooth_rows over all computed rows bit for bit."""
    vertices, faces = grid()
    V = len(vertices)
    rng = np.random.default_rng(3)
    active = rng.random(V) < 0.15
    sm = SurfaceSmoothing(faces, V, steps, active)
    assert set(sm.order.tolist()) == set(sm.rows.tolist())
    n0 = sm.ring_ends[0]
    np.testing.assert_array_equal(sm.order[:n0], np.nonzero(active)[0])
    x = np.zeros((V, 7), np.float32)
    x[active] = rng.normal(size=(active.sum(), 7))
    want = sm.smooth_rows(x[sm.rows])[np.searchsorted(sm.rows, sm.order)]
    np.testing.assert_array_equal(sm.spread_front(x[sm.order[:n0]]), want)
    # into a kept workspace (the products into it, the last straight into `out`): the same sums
    work = sm.workspace()
    work.fill(np.nan)
    np.testing.assert_array_equal(sm.spread_front(x[sm.order[:n0]], work=work), want)
    out = np.full((len(sm.rows), 7), np.nan, np.float32)
    assert sm.spread_front(x[sm.order[:n0]], out=out, work=work) is out
    np.testing.assert_array_equal(out, want)
    wide = np.zeros((V, 2 * BLOCK + 5), np.float32)   # several column blocks, out wider than one
    wide[active] = rng.normal(size=(active.sum(), wide.shape[1]))
    np.testing.assert_array_equal(sm.spread_front(wide[sm.order[:n0]], work=work),
                                  sm.spread_front(wide[sm.order[:n0]]))
    with pytest.raises(InputError):
        sm.spread_front(x[sm.order[:n0]], work=work[:1])
    whole = SurfaceSmoothing(faces, V, steps)          # every vertex active: ring 0 is all of them
    np.testing.assert_array_equal(whole.spread_front(x), whole.smooth_rows(x))
    np.testing.assert_array_equal(whole.spread_front(x, work=whole.workspace()), whole.smooth_rows(x))


@pytest.mark.parametrize("steps", [0, 1, 5])
def test_the_device_spread_equals_the_host_one(steps):
    """spread_device (the GPU's way, run here on the CPU device): the smooth skin plus the spread of ring 0's
    displacements, on the computed rows, the smooth skin elsewhere; equal to spread_front's sums scattered
    onto the smooth skin (bit for bit on the CPU, where nothing fuses the product and the sum)."""
    import warp as wp
    vertices, faces = grid()
    V, T = len(vertices), 5
    rng = np.random.default_rng(4)
    active = rng.random(V) < 0.2
    sm = SurfaceSmoothing(faces, V, steps, active)
    n0 = int(sm.ring_ends[0])
    smooth = rng.normal(size=(T, V, 3)).astype(np.float32)
    moved = rng.normal(size=(n0, T, 3)).astype(np.float32)
    d = sm.spread_front(moved.reshape(n0, 3 * T)).reshape(-1, T, 3)             # (R, T, 3) rows in order
    want = smooth.copy()
    if steps:
        want[:, sm.order] = smooth[:, sm.order] + d.transpose(1, 0, 2)
    got = sm.spread_device(wp.array(smooth, dtype=wp.vec3, device="cpu"),
                           wp.array(moved, dtype=wp.vec3, device="cpu")).numpy()
    np.testing.assert_array_equal(got, want)
    assert steps == 0 or np.abs(got - smooth).max() > 0.1           # the displacement arrived
