"""Delta Mush (rig/skin/delta_mush.py): the Warp kernels against a float64 NumPy reference, the rest
pose and rigid motions kept exactly, a crease taken out, and the option reaching the bake."""
import numpy as np
import pytest

from jiggle.rig.base.errors import InputError
from jiggle.rig.character.mesh_graph import mesh_edges
from jiggle.rig.skin.delta_mush import DeltaMush
from jiggle.rig.skin.quality import SkinQuality


def tube(rings=24, around=16, length=0.6, radius=0.05):
    """A capped-less tube along z: vertices (V, 3), faces (F, 3)."""
    z = np.linspace(0.0, length, rings)
    a = np.linspace(0.0, 2 * np.pi, around, endpoint=False)
    verts = np.stack([np.repeat(radius * np.cos(a)[None], rings, 0).ravel(),
                      np.repeat(radius * np.sin(a)[None], rings, 0).ravel(), np.repeat(z, around)], axis=1)
    faces = []
    for i in range(rings - 1):
        for j in range(around):
            p, q = i * around + j, i * around + (j + 1) % around
            faces += [(p, q, p + around), (q, q + around, p + around)]
    return verts, np.array(faces)


def reference(rest, faces, points, steps, step=0.5):
    """Delta Mush in float64 NumPy, written from the paper's definition with the module's frames."""
    V = len(rest)
    edges, _ = mesh_edges(faces)
    nb = [[] for _ in range(V)]
    for a, b in edges:
        nb[a].append(b)
        nb[b].append(a)
    nb = [sorted(n) for n in nb]

    def smooth(p):
        for _ in range(steps):
            p = np.stack([p[i] + step * (p[n].mean(axis=0) - p[i]) for i, n in enumerate(nb)])
        return p

    def frames(s):
        tri = s[faces]
        fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        n = np.zeros((V, 3))
        np.add.at(n, faces.ravel(), np.repeat(fn, 3, axis=0))
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        e = s[[k[0] for k in nb]] - s
        e -= np.sum(e * n, axis=1, keepdims=True) * n
        e /= np.linalg.norm(e, axis=1, keepdims=True)
        return np.stack([e, np.cross(n, e), n], axis=2)              # columns t, b, n

    s0 = smooth(rest.astype(np.float64))
    delta = np.einsum("vji,vj->vi", frames(s0), rest - s0)
    s = smooth(points.astype(np.float64))
    return s + np.einsum("vij,vj->vi", frames(s), delta)


def bend(verts, degrees):
    """The tube's upper half turned about x at its middle, as two rigid bones with a hard seam: LBS
    at its worst (a crease ring at the seam)."""
    out = verts.copy()
    top = verts[:, 2] > 0.3
    a = np.radians(degrees)
    R = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    out[top] = (verts[top] - [0, 0, 0.3]) @ R.T + [0, 0, 0.3]
    return out


def test_kernels_equal_the_numpy_reference():
    verts, faces = tube(10, 8)
    posed = bend(verts, 50) + np.random.default_rng(1).normal(0, 0.002, verts.shape)
    mush = DeltaMush(verts, faces, iterations=4)
    np.testing.assert_allclose(mush.apply(posed), reference(verts, faces, posed, 4), atol=2e-6)


def test_rest_and_rigid_motions_are_kept():
    verts, faces = tube()
    mush = DeltaMush(verts, faces, iterations=6)
    np.testing.assert_allclose(mush.apply(verts), verts, atol=1e-6)
    a = 0.7
    R = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    moved = verts @ R.T + [0.3, -1.0, 0.5]
    batch = mush.apply(np.stack([verts, moved]))
    np.testing.assert_allclose(batch[1], moved, atol=2e-6)


def test_crumples_are_taken_out_and_the_rest_detail_kept():
    """A bent tube whose skin crumples near the joint (ripples of 3 mm, two edges long, as LBS makes
    where weights crowd): mushed, the ripples shrink to a fraction and their sharp edges go, while
    vertices far from the joint keep their skinned place."""
    verts, faces = tube()
    q = SkinQuality(verts, faces)
    posed = bend(verts, 40)
    band = np.abs(verts[:, 2] - 0.3) < 0.08
    ring = np.round(verts[:, 2] / (0.6 / 23)).astype(int)
    radial = verts[:, :2] / np.linalg.norm(verts[:, :2], axis=1, keepdims=True)
    crumpled = posed.copy()
    crumpled[band, :2] += 0.003 * np.where(ring[band] % 2, 1.0, -1.0)[:, None] * radial[band]
    mush = DeltaMush(verts, faces, iterations=8)
    out, smooth = mush.apply(crumpled), mush.apply(posed)
    ripple_before = np.abs(crumpled[band] - posed[band]).max()
    ripple_after = np.abs(out[band] - smooth[band]).max()
    assert ripple_after < 0.5 * ripple_before
    assert q.skin(out[None])["sharp_edges"][0] < q.skin(crumpled[None])["sharp_edges"][0]
    far = np.abs(verts[:, 2] - 0.3) > 0.25
    assert np.abs(out[far] - posed[far]).max() < 1e-4


def test_bad_input():
    verts, faces = tube(4, 6)
    with pytest.raises(InputError, match="whole number"):
        DeltaMush(verts, faces, iterations=0)
    with pytest.raises(InputError, match="weights"):
        DeltaMush(verts, faces, weights=np.full(len(verts), 2.0))
    with pytest.raises(InputError):
        DeltaMush(verts, faces).apply(verts[:-1])
