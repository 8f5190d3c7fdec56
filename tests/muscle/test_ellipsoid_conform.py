"""Ellipsoid fitting from surface moments and conforming to the skin (paper 000, 3.2-3.3)."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

from jiggle.rig.muscle.conform import conform
from jiggle.rig.muscle.ellipsoid import Ellipsoid, fit_ellipsoid, surface_moments


def tube(radius=0.05, length=0.3, sections=64, rings=60, capped=True):
    """A closed cylinder along +x from 0 to `length` (a limb)."""
    m = trimesh.creation.cylinder(radius=radius, height=length, sections=sections)
    m = m.subdivide_to_size(length / rings)
    m.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0]))
    m.apply_translation([length / 2, 0, 0])
    if not capped:
        side = np.abs(m.face_normals[:, 0]) < 0.5
        m = trimesh.Trimesh(m.vertices, m.faces[side], process=False)
    return m


def test_sphere_moments_are_isotropic():
    s = trimesh.creation.icosphere(subdivisions=4, radius=0.1)
    area, mean, cov = surface_moments(s.vertices, s.faces)
    # a uniform distribution on a sphere of radius r has covariance r^2/3 I
    assert area == pytest.approx(4 * np.pi * 0.01, rel=1e-2)
    assert np.allclose(mean, 0, atol=1e-6)
    assert np.allclose(cov, np.eye(3) * 0.01 / 3, rtol=2e-2, atol=1e-6)


def test_moments_do_not_depend_on_tessellation():
    coarse = tube(rings=4, capped=False)
    fine = tube(rings=60, capped=False)
    _, m1, c1 = surface_moments(coarse.vertices, coarse.faces)
    _, m2, c2 = surface_moments(fine.vertices, fine.faces)
    assert np.allclose(m1, m2, atol=1e-9) and np.allclose(c1, c2, atol=1e-9)


def test_cylinder_fit_follows_the_paper():
    r, L = 0.05, 0.3
    m = tube(r, L, capped=False)
    e = fit_ellipsoid(m.vertices, m.faces, along=np.array([1.0, 0, 0]))
    # uniform along the length: std L / sqrt(12); on the circle: r / sqrt(2)
    assert e.radii == pytest.approx([L / np.sqrt(12), r / np.sqrt(2), r / np.sqrt(2)], rel=1e-2)
    assert e.axes[0] @ [1, 0, 0] > 0.999
    assert np.allclose(e.centre, [L / 2, 0, 0], atol=1e-6)
    assert np.linalg.det(e.axes) == pytest.approx(1.0)
    E = e.matrix
    assert np.allclose(E[:3, :3] @ [1, 0, 0] + E[:3, 3], e.centre + e.axes[0] * e.radii[0])


def test_flat_patch_gets_minimum_thickness_and_moves_inward():
    # a flat square of skin facing +z: the fit has no thickness
    v = np.array([[0, 0, 0], [0.2, 0, 0], [0.2, 0.1, 0], [0, 0.1, 0]], float)
    f = np.array([[0, 1, 2], [0, 2, 3]])
    e = fit_ellipsoid(v, f, along=np.array([1.0, 0, 0]), outward=np.array([0, 0, 1.0]), thickness_min=0.01)
    assert e.radii[2] == pytest.approx(0.01)
    assert e.axes[2] @ [0, 0, 1] == pytest.approx(1.0)
    assert e.centre[2] == pytest.approx(-0.01)  # outer side stays on the patch
    assert np.all(np.diff(e.radii) <= 0)


def test_conform_reaches_toward_the_skin_and_keeps_the_tips():
    r, L, nu = 0.05, 0.3, 3.0
    skin = tube(r, L)
    side = tube(r, L, capped=False)
    e = fit_ellipsoid(side.vertices, side.faces, along=np.array([1.0, 0, 0]))
    pts, _ = e.mesh(3)
    out, report = conform(e, pts, skin, nu=nu)
    assert report.misses <= 2  # only the two tips, which lie on the axis
    s = (pts - e.centre) @ e.axes[0]
    d = np.abs(s) / e.radii[0]
    radial = np.linalg.norm(out[:, 1:], axis=1)
    # p_r = p' + (1 - e^{(d-1) nu}) (p_i - p'), with |p_i - p'| = r on a cylinder
    expect = (1 - np.exp((d - 1) * nu)) * r
    assert np.allclose(radial, expect, atol=2e-3 * r + 1e-3)
    assert np.all(radial <= r + 1e-9)
    assert np.allclose(out[:, 0], pts[:, 0])  # the shape moves only across the axis


def test_pair_conform_stays_on_its_side_of_the_plane():
    r, L = 0.05, 0.3
    skin = tube(r, L)
    side = tube(r, L, capped=False)
    front = side.triangles_center[:, 1] >= 0
    e = fit_ellipsoid(side.vertices, side.faces[front], along=np.array([1.0, 0, 0]))
    assert e.centre[1] > 0.01
    pts, _ = e.mesh(3)
    theta = np.array([0, 1.0, 0])
    out, _ = conform(e, pts, skin, nu=3.0, plane=(np.array([L / 2, 0, 0]), theta))
    assert np.min(out @ theta) >= min(0.0, np.min(pts @ theta)) - 1e-9
    # rays pointing away from the plane still reach toward the skin
    top = np.argmax(pts[:, 1])
    assert out[top, 1] > pts[top, 1] + 0.001 and out[top, 1] < r


def test_rays_that_miss_keep_the_ellipsoid():
    e = Ellipsoid(centre=np.array([5.0, 5, 5]), axes=np.eye(3), radii=np.array([0.1, 0.05, 0.04]))
    pts, _ = e.mesh(2)
    out, report = conform(e, pts, tube())
    assert report.hits == 0 and np.array_equal(out, pts)
