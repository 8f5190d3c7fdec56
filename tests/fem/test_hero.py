"""The FEM hero mode (`jiggle bake --tissue fem`, sim/fem/tissue.py): the structured mesh of a part's loft coordinates
(conforming, positive, its own goal, the fallback of a folded loft), its ring-down against the materials' rule, and
bakes of CesiumMan on CMU 09_11: no inverted tet, the embedded CVs through blend/skin/caches, the record in bake.json,
an interrupted bake resumed equal to an unbroken one bit for bit, a bad --tissue refused."""
from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("newton", reason="newton is not installed (pip install newton)")

from jiggle.rig.muscle.material import FAT  # noqa: E402
from jiggle.sim.fem.experiments import ellipsoid_rig, ringdown_run  # noqa: E402
from jiggle.sim.fem.solve import STIFFENING  # noqa: E402
from jiggle.sim.fem.tet_mesh import boundary_faces, structured_part_mesh, tet_volumes  # noqa: E402
from jiggle.sim.fem.tissue import HERO_MESH  # noqa: E402
from jiggle.sim.jiggle.materials import fem_frequency  # noqa: E402

from conftest import ASSETS  # noqa: E402

CESIUM = ASSETS / "characters/CesiumMan.glb"
RUN = ASSETS / "mocap/cmu_bvh/09_11.bvh"


@pytest.fixture(scope="module")
def ellipsoid():
    rig = ellipsoid_rig(0.2, (0.03, 0.03))
    return rig, structured_part_mesh(rig.rest_cvs, **HERO_MESH)


def test_structured_mesh_is_conforming_positive_and_its_own_goal(ellipsoid):
    rig, mesh = ellipsoid
    assert len(mesh.tets) == 6 * 12 * 9 and mesh.mesher == "structured"
    assert (tet_volumes(mesh.points, mesh.tets) > 0).all()
    # every interior face is shared by exactly two tets: the boundary is a closed 2-manifold (each edge in 2 faces)
    faces = boundary_faces(mesh.tets)
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert (counts == 2).all()
    assert mesh.volume == pytest.approx(rig.volumes(rig.rest_cvs)[0], rel=0.06)
    np.testing.assert_allclose(mesh.goals(rig.rest_cvs), mesh.points, atol=1e-12)
    np.testing.assert_allclose(mesh.cvs(mesh.points), rig.rest_cvs, atol=1e-12)
    # the axis and the end rows ride the bone, the rest is free
    assert 0 < mesh.attached.sum() < 0.4 * len(mesh.points)


def test_hero_mesh_rings_at_the_materials_rule(ellipsoid):
    """The fat ellipsoid's undamped small-strain fundamental on the hero mesh, with the hero's stiffening, is within
    15% of sim.jiggle.materials' rule (the rule the particles' goal springs follow): the hero and the particles stand
    for the same tissue. Swung five times as hard, the stiffening tissue rings faster (strain stiffening)."""
    rig, mesh = ellipsoid
    f = fem_frequency(FAT, float(rig.mean_radii(rig.rest_cvs)[0]))
    run, rd = ringdown_run(mesh, FAT, duration=3.0 / f, window=3.0 / f, stiffening=STIFFENING, speed=0.1)
    assert rd.frequency_hz == pytest.approx(f, rel=0.15)
    assert run.min_det.min() > 0
    _, hard = ringdown_run(mesh, FAT, duration=3.0 / f, window=3.0 / f, stiffening=STIFFENING, speed=0.5)
    _, linear = ringdown_run(mesh, FAT, duration=3.0 / f, window=3.0 / f, stiffening=0.0, speed=0.5)
    assert hard.frequency_hz > 1.04 * linear.frequency_hz
    assert linear.frequency_hz == pytest.approx(rd.frequency_hz, rel=0.02)


needs_assets = pytest.mark.skipif(not (CESIUM.exists() and RUN.exists()), reason="CesiumMan or CMU 09_11 is absent")


def bake(out, *extra):
    from jiggle.sim.app.cli import main
    return main(["bake", "--clip", str(RUN), "--character", str(CESIUM), "--tissue", "fem", "--formats", "npz",
                 "--out", str(out), "-q", *extra])


@needs_assets
def test_a_folded_part_meshes_by_its_loft_coordinates():
    """CesiumMan's pectorals loft into themselves (TetGen refuses the surface): part_mesh falls back to the structured
    mesh, whose tets across the fold are left out; what stays is positive and holds ~all the volume."""
    import warnings

    from jiggle.rig.character.load import load_character
    from jiggle.rig.muscle.fit import fit_musculature
    from jiggle.sim.fem.tet_mesh import part_mesh
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rig = fit_musculature(load_character(str(CESIUM)), "auto").rig
    m = rig.names.index("left_pectoral")
    mesh = part_mesh(rig.rest_cvs[rig.cv_offsets[m]:rig.cv_offsets[m + 1]])
    assert mesh.mesher == "structured"
    assert (tet_volumes(mesh.points, mesh.tets) > 0).all()
    assert mesh.volume == pytest.approx(rig.volumes(rig.rest_cvs)[m], rel=0.1)


@pytest.fixture(scope="module")
def hero(tmp_path_factory):
    if not (CESIUM.exists() and RUN.exists()):
        pytest.skip("CesiumMan or CMU 09_11 is absent")
    out = tmp_path_factory.mktemp("hero")
    assert bake(out, "--frames", "12", "--chunk", "6") == 0
    return out


@needs_assets
def test_hero_bake_runs_the_solid_with_no_inverted_tet(hero):
    from jiggle.sim.bake.caches import read_npz
    summary = json.loads((hero / "bake.json").read_text())
    fem = summary["fem"]
    assert summary["params"]["tissue"]["solver"] == "fem"
    assert fem["inverted_max"] == 0 and fem["frames_with_inverted"] == 0 and 0 < fem["min_det"] < 1
    assert len(fem["parts"]) == summary["muscles"] and fem["tets"] > 1000
    assert fem["contacts"] and fem["stiffening"]["b"] > 0
    belly = fem["parts"]["belly_fat"]
    assert belly["material"]["name"] in ("fat", "custom") and belly["frequency_hz"] > 0
    # each part's smallest det F over the output frames, the whole bake's the smallest of them; every kept step at
    # the check's floor or above (sim.fem.step)
    per = [p["min_det"] for p in fem["parts"].values()]
    assert min(per) == pytest.approx(fem["min_det"], abs=1e-6) and all(0 < d <= 1.0 + 1e-6 for d in per)
    check = fem["step_check"]
    assert check["steps"] == fem["steps"] > 0 and check["steps_redone"] >= 0
    assert check["step_min_det"] >= check["det_floor"] - 1e-6
    d = read_npz(hero / "bake.npz")
    assert np.isfinite(d.skin_final).all()
    # the embedded CVs move off the static ones (the solid jiggles), the first frame starts on them
    off = np.linalg.norm(d.muscle_cvs_dynamic - d.muscle_cvs_static, axis=-1)
    assert off[0].max() < 1e-5 and off[1:].max() > 1e-3


@needs_assets
def test_an_interrupted_hero_bake_resumes_bit_for_bit(hero, tmp_path, monkeypatch):
    from jiggle.sim.bake import baker as bake_mod
    from jiggle.sim.bake.caches import read_npz
    real = bake_mod.Baker.chunk

    def chunk(self, c, state):
        if c == 1:
            raise KeyboardInterrupt
        return real(self, c, state)
    monkeypatch.setattr(bake_mod.Baker, "chunk", chunk)
    assert bake(tmp_path, "--frames", "12", "--chunk", "6") == 130
    monkeypatch.setattr(bake_mod.Baker, "chunk", real)
    assert bake(tmp_path, "--frames", "12", "--chunk", "6", "--resume") == 0
    a, b = read_npz(hero / "bake.npz"), read_npz(tmp_path / "bake.npz")
    for k in ("muscle_cvs_dynamic", "skin_final"):
        np.testing.assert_array_equal(getattr(a, k), getattr(b, k), err_msg=k)
    assert json.loads((tmp_path / "bake.json").read_text())["fem"]["inverted_max"] == 0


def test_a_bad_tissue_solver_exits_2(capsys):
    from jiggle.sim.app.cli import main
    with pytest.raises(SystemExit) as e:
        main(["bake", "--tissue", "jelly", "--out", "/tmp/never"])
    assert e.value.code == 2 and "--tissue" in capsys.readouterr().err


def test_the_request_refuses_an_unknown_solver():
    from jiggle.rig.base.errors import InputError
    from jiggle.sim.bake.setup import BakeRequest, tissue_solver
    assert tissue_solver(BakeRequest()) == "particles" and tissue_solver(BakeRequest(tissue="fem")) == "fem"
    with pytest.raises(InputError, match="--tissue"):
        tissue_solver(BakeRequest(tissue="jelly"))


@pytest.mark.slow
def test_a_hero_loop_warms_up_to_its_steady_state(tmp_path):
    """The Cat's Walk, a closed cycle, with --tissue fem: the solid is warmed up to its periodic steady state (the
    start state repeats within the tolerance) and the baked loop's last frame repeats its first."""
    cat = ASSETS / "characters/zoo/Cat.glb"
    if not cat.exists():
        pytest.skip("the shared Cat is absent")
    from jiggle.sim.app.cli import main
    assert main(["bake", "--character", str(cat), "--animation", "Walk", "--tissue", "fem", "--formats", "npz",
                 "--out", str(tmp_path), "-q"]) == 0
    summary = json.loads((tmp_path / "bake.json").read_text())
    loop = summary["loop"]
    assert loop["on"] and loop["warmup"]["converged"] and loop["warmup"]["cycles"] >= 3
    assert loop["seam"]["wrap_mm"] < 0.05 * loop["seam"]["wrap_step_mm"]
    assert summary["fem"]["inverted_max"] == 0


def test_an_inverted_solid_is_never_written_silently():
    """The bake warns (a JiggleWarning, the CLI's `jiggle: warning:` line) when the hero solid inverted tets at an
    output frame, naming how many, on how many frames and the smallest det F; nothing when none did or with no
    solid."""
    import warnings

    from jiggle.rig.base.errors import JiggleWarning
    from jiggle.sim.bake.baker import _warn_inverted
    with pytest.warns(JiggleWarning, match=r"up to 142 tets on 24 of 60 output frames \(smallest det F -2.23\)"):
        _warn_inverted({"inverted_max": 142, "frames_with_inverted": 24, "min_det": -2.23}, 60)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _warn_inverted({"inverted_max": 0, "frames_with_inverted": 0, "min_det": 0.3}, 60)
        _warn_inverted(None, 60)
