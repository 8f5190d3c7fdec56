"""A part's vibration modes and its Rayleigh damping (sim/fem/modes.py): the modes are the solid's (its sway rings
where a ring-down of the simulated solid does; they scale as a linear solid's), the Rayleigh band gives the material's
ratio at both ends, and the simulated solid rings down with it (the goal-relative drag, sim.fem.fem_kernels.goal_drag,
and VBD's tet damping together)."""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

pytest.importorskip("tetgen", reason="tetgen is not installed (pip install tetgen)")
pytest.importorskip("newton", reason="newton is not installed (pip install newton)")

from jiggle.rig.muscle.material import FAT, Material  # noqa: E402
from jiggle.sim.fem import measure  # noqa: E402
from jiggle.sim.fem.experiments import ellipsoid_rig, ringdown_run  # noqa: E402
from jiggle.sim.fem.modes import band, modes, rayleigh  # noqa: E402
from jiggle.sim.fem.solve import DT, NUMERICAL_DAMPING  # noqa: E402
from jiggle.sim.fem.tet_mesh import part_mesh  # noqa: E402


@pytest.fixture(scope="module")
def mesh():
    return part_mesh(ellipsoid_rig(0.2, (0.03, 0.025)).rest_cvs)


def test_modes_scale_as_a_linear_solid(mesh):
    """Four times the modulus doubles every frequency; the same part twice as big rings half as fast; the sway
    carries most of the free mass, and no mode carries more than all of it."""
    base = modes(mesh, FAT)
    assert np.all(np.diff(base.frequencies_hz) >= 0) and base.lowest_hz > 0
    stiff = modes(mesh, replace(FAT, youngs_pa=4 * FAT.youngs_pa))
    assert np.allclose(stiff.frequencies_hz, 2 * base.frequencies_hz, rtol=1e-6)
    big = modes(mesh, FAT, points=2.0 * mesh.points)
    assert np.allclose(big.frequencies_hz, 0.5 * base.frequencies_hz, rtol=1e-6)
    assert 0.3 < base.shares[base.sway] <= 1.0 and (base.shares <= 1.0 + 1e-9).all()


def test_the_sway_is_where_the_solid_rings(mesh):
    """An undamped ring-down of the simulated solid (a stopped goal, sim.fem.experiments) rings at the frequency of
    the mode that sways along the drive within 8% (VBD's backward Euler rings a little low), on either axis across
    the part (its radii differ: so do the two sways)."""
    found = modes(mesh, FAT)
    for d in ((0.0, 0.0, 1.0), (0.0, 1.0, 0.0)):
        f = found.frequencies_hz[found.along(d)]
        _, rd = ringdown_run(mesh, FAT, duration=0.5, fps=1000.0, k_damp=0.0, direction=d, window=3.0 / f)
        assert rd.frequency_hz == pytest.approx(f, rel=0.08)


def test_rayleigh_gives_the_ratio_across_the_band():
    """zeta(omega) = alpha / 2 omega + beta omega / 2 is the asked ratio at both ends of the band and no less than
    2 sqrt(w1 w2) / (w1 + w2) of it between; the solver's numerical part comes off beta."""
    zeta, f1, f2, mu = 0.3, 4.0, 9.0, 1000.0
    alpha, k_damp = rayleigh(zeta, f1, f2, mu)
    beta = 2 * k_damp / mu

    def z(f):
        w = 2 * math.pi * f
        return alpha / (2 * w) + beta * w / 2
    assert z(f1) == pytest.approx(zeta) and z(f2) == pytest.approx(zeta)
    between = [z(f) for f in np.linspace(f1, f2, 20)]
    assert min(between) >= 2 * math.sqrt(f1 * f2) / (f1 + f2) * zeta - 1e-12 and max(between) <= zeta + 1e-12
    a2, k2 = rayleigh(zeta, f1, f2, mu, dt=1e-3, numerical=0.75)
    assert a2 == alpha and 2 * k2 / mu == pytest.approx(beta - 2 * 0.75 * 1e-3)
    assert rayleigh(0.001, f1, f2, mu, dt=1e-3, numerical=0.75)[1] == 0.0     # never negative
    assert band(modes(part_mesh(ellipsoid_rig(0.2, (0.03, 0.025)).rest_cvs), FAT))[1] >= 2 * 0.999 * band(
        modes(part_mesh(ellipsoid_rig(0.2, (0.03, 0.025)).rest_cvs), FAT))[0]


def test_the_solid_rings_down_with_the_material_ratio(mesh):
    """The Rayleigh damping of the band (the drag on the velocity relative to the goal, and VBD's tet damping less its
    own numerical part) makes the solid ring down with the material's ratio (read from successive extrema, as the
    reference reads its cases) within 25%; the drag alone adds alpha / 2 omega to the undamped ring's ratio."""
    mat = Material(FAT.youngs_pa, FAT.poisson, FAT.density, 0.3, "fat")
    found = modes(mesh, mat)
    f1, f2 = band(found)
    alpha, k_damp = rayleigh(mat.damping_ratio, f1, f2, mat.shear_pa, DT, NUMERICAL_DAMPING)
    # the drive along the sway (the mode with the most mass, the band's top): a coarse mesh's modes along the part's
    # axes need not be it (this one's along z is a lighter mode at 0.56 of the sway, where the band's ratio dips)
    sway = np.asarray(found.means[found.sway], np.float64)
    kw = dict(duration=0.6, fps=1000.0, direction=tuple(sway / np.linalg.norm(sway)), window=3.0 / found.sway_hz)

    def zeta(run_rd):
        run, rd = run_rd
        sig = measure.principal_signal(measure.goal_offsets(run.positions[:, :mesh.surface_count],
                                                            run.goals[:, :mesh.surface_count]))
        t_stop = run.times[0] + 0.2
        d, n = measure.decrement(sig, run.times, t_stop)
        assert n >= 2
        return d / math.sqrt(4 * math.pi ** 2 + d * d), rd.frequency_hz
    z, _ = zeta(ringdown_run(mesh, mat, k_damp=k_damp, alpha=alpha, **kw))
    assert z == pytest.approx(0.3, rel=0.25)
    z0, f0 = zeta(ringdown_run(mesh, mat, k_damp=0.0, **kw))
    za, _ = zeta(ringdown_run(mesh, mat, k_damp=0.0, alpha=alpha, **kw))
    assert za - z0 == pytest.approx(alpha / (4 * math.pi * f0), rel=0.3)
