"""Seams (rig/skin/seams.py): vertices split at UV seams stay together through the muscles' deformers. CesiumMan
has 1,257 such pairs; before the weld its shells opened them up to 10 mm (static) and 14 mm (final) on a walk."""
from __future__ import annotations

import numpy as np
from conftest import asset
from scipy.spatial import cKDTree

from jiggle.rig.skin.seams import seam_groups, weld
from jiggle.sim.app.cli import main
from jiggle.sim.bake.caches import read_npz


def test_groups_need_the_same_place_and_the_same_weights():
    v = np.array([[0, 0, 0], [0, 0, 0], [1, 0, 0], [1, 0, 0], [2, 0, 0]], float)
    j = np.array([[0, 1], [0, 1], [0, 1], [1, 0], [0, 1]])
    w = np.array([[.7, .3], [.7, .3], [.6, .4], [.6, .4], [1, 0]])
    labels, avg = seam_groups(v, j, w)
    assert labels[0] == labels[1] and labels[2] != labels[3] and len(set(labels)) == 4
    skins = np.arange(2 * 5 * 3, dtype=np.float32).reshape(2, 5, 3)
    out = weld(skins, (labels, avg))
    assert np.allclose(out[:, 0], out[:, 1]) and np.allclose(out[:, 0], skins[:, :2].mean(axis=1))
    assert np.array_equal(out[:, 2:], skins[:, 2:]) and out.dtype == np.float32
    assert seam_groups(v[[0, 2, 4]], j[[0, 2, 4]], w[[0, 2, 4]]) is None


def test_cesiumman_seams_stay_closed_in_the_bake(tmp_path):
    """Every pair of CesiumMan vertices at one rest place stays at one place in skin_static and skin_final."""
    assert main(["-q", "bake", "--character", str(asset("characters/CesiumMan.glb")), "--clip",
                 str(asset("mocap/cmu_bvh/02_03.bvh")), "--out", str(tmp_path), "--formats", "npz"]) == 0
    d = read_npz(tmp_path / "bake.npz")
    pairs = cKDTree(d.skin_rest).query_pairs(1e-6, output_type="ndarray")
    assert len(pairs) > 1000
    for skin in (d.skin_static, d.skin_final):
        assert np.linalg.norm(skin[:, pairs[:, 0]] - skin[:, pairs[:, 1]], axis=2).max() < 1e-6
    assert np.abs(d.skin_final - d.skin_lbs).max() > 1e-3          # and the muscles still move it


def test_compare_measures_open_seams():
    """skin_quality's open_seams: the widest gap between seam pairs plain skinning keeps together; a skin that
    opens a seam by 5 mm at one frame fails it, a closed one passes."""
    from jiggle.sim.app.report.skin_quality import check_targets, seam_gaps
    rest = np.array([[0, 0, 0], [0, 0, 0], [1, 0, 0]], float)
    lbs = np.repeat(rest[None], 3, axis=0)
    final = lbs.copy()
    final[1, 1, 0] += 0.005
    s = seam_gaps(rest, lbs, final)
    assert s["pairs"] == 1 and np.allclose(s["gap_m"], [0, 0.005, 0])
    m = {"final": {"folded_edges": np.zeros(3)}, "jiggle": {"torn_edges": np.zeros(3), "gradient_p999": np.zeros(3)},
         "seams": s}
    t = check_targets(m, 0, 10)["open_seams"]
    assert t["value"] == 5.0 and not t["pass"]
    m["seams"] = seam_gaps(rest, lbs, lbs)
    assert check_targets(m, 0, 10)["open_seams"]["pass"]
