"""jiggle compare on a bake with collisions: bake.json's "contacts" reach metrics.json ("collisions"), a
per-frame plot (contacts.png) and the report (a table of which muscle hit what); a bake without them gets
none of it."""
from __future__ import annotations

import json

import numpy as np
import pytest
from test_compare import STRICT, T, known_bake  # noqa: E402 - tests/app is on the path (rootdir conftest)

from jiggle.sim.app.report.compare import collision_metrics, compare
from jiggle.sim.bake.caches import write_npz

DEPTH_FRAME = 20
"""The frame of the synthetic bake's deepest contact."""


def contacts(frames: int = T) -> dict:
    """bake.json's "contacts" as sim.bake.baker writes them: belly_fat hits a thigh capsule for frames 18..22
    (deepest 3.5 mm at DEPTH_FRAME), biceps_l the floor at frame 40; the static skin has 4 vertices inside
    a capsule per frame, the final 4 except 2 frames with 3."""
    depth = np.zeros(frames)
    depth[18:23] = [1.0, 2.5, 3.5, 2.0, 0.5]
    depth[40] = 0.25
    muscle = [None] * frames
    hit = [None] * frames
    for f in range(18, 23):
        muscle[f], hit[f] = "belly_fat", "LeftHip>LeftKnee"
    muscle[40], hit[40] = "biceps_l", "floor"
    final = [4] * frames
    final[30] = final[31] = 3
    return {"method": "projection with Coulomb friction", "friction": 0.5, "floor_m": -0.9,
            "colliders": ["LeftHip>LeftKnee", "floor"], "capsule_radius_mm": [50.0], "pairs_checked": 3,
            "pairs_touching_at_rest": 0, "frames_in_contact": 6, "max_penetration_mm": 3.5,
            "pairs": [{"muscle": "belly_fat", "hit": "LeftHip>LeftKnee", "frames": 5, "max_penetration_mm": 3.5,
                       "impulse_Ns": 0.02},
                      {"muscle": "biceps_l", "hit": "floor", "frames": 1, "max_penetration_mm": 0.25,
                       "impulse_Ns": 0.001}],
            "per_frame": {"time_s": list(np.arange(frames) / 30.0), "max_penetration_mm": depth.tolist(),
                          "muscle": muscle, "hit": hit, "impulse_Ns": (depth * 0.004).tolist()},
            "skin_inside": {"static": [4] * frames, "final": final, "max_static": 4, "max_final": 4,
                            "frames_final_above_static": 0, "kept_out": [0] * 20 + [2] + [0] * (frames - 21),
                            "max_kept_out": 2, "max_pull_mm": 0.8, "method": "pulled back"}}


def test_collisions_reach_metrics_plot_and_report(tmp_path):
    data, _ = known_bake()
    write_npz(data, tmp_path / "bake.npz")
    (tmp_path / "bake.json").write_text(json.dumps({"frames": T, "contacts": contacts()}))
    result = compare(str(tmp_path), render=False)
    c = json.loads((tmp_path / "metrics.json").read_text(), **STRICT)["collisions"]
    assert c["frames_in_contact"] == 6 and c["max_penetration_mm"] == pytest.approx(3.5)
    pf = c["per_frame"]
    assert len(pf["max_penetration_mm"]) == T and int(np.argmax(pf["max_penetration_mm"])) == DEPTH_FRAME
    assert pf["muscle"][DEPTH_FRAME] == "belly_fat" and pf["hit"][40] == "floor"
    si = c["skin_inside"]
    assert si["max_static"] == si["max_final"] == 4 and si["frames_final_above_static"] == 0
    assert si["mean_final"] == pytest.approx(4 - 2 / T) and pf["skin_inside_final"][30] == 3
    assert [p["muscle"] for p in c["pairs"]] == ["belly_fat", "biceps_l"]
    assert si["pulled_back_frames"] == 1 and si["max_pulled_back"] == 2 and si["max_pull_mm"] == 0.8
    assert pf["skin_pulled_back"][20] == 2 and len(pf["skin_pulled_back"]) == T
    with open(result["files"]["contacts_plot"], "rb") as fh:
        assert fh.read(8) == b"\x89PNG\r\n\x1a\n"
    page = (tmp_path / "report.html").read_text()
    assert "<h2>Collisions</h2>" in page and "LeftHip&gt;LeftKnee" in page and "frames in contact" in page
    assert "pulled back out of a capsule" in page and "by at most 0.8 mm" in page
    assert json.loads((tmp_path / "compare.json").read_text())["files"].count("contacts.png") == 1


def test_no_collisions_no_section(tmp_path):
    """A bake without collisions (bake.json without "contacts", or no bake.json): nothing changes."""
    data, _ = known_bake()
    write_npz(data, tmp_path / "bake.npz")
    (tmp_path / "bake.json").write_text(json.dumps({"frames": T}))
    result = compare(str(tmp_path), render=False)
    assert "collisions" not in result["metrics"] and "contacts_plot" not in result["files"]
    assert not (tmp_path / "contacts.png").exists()
    assert "Collisions" not in (tmp_path / "report.html").read_text()


def test_a_later_compare_without_contacts_removes_the_plot(tmp_path):
    data, _ = known_bake()
    write_npz(data, tmp_path / "bake.npz")
    (tmp_path / "bake.json").write_text(json.dumps({"contacts": contacts()}))
    compare(str(tmp_path), render=False)
    assert (tmp_path / "contacts.png").is_file()
    (tmp_path / "bake.json").write_text(json.dumps({}))
    compare(str(tmp_path), render=False)
    assert not (tmp_path / "contacts.png").exists()


def test_per_frame_lists_of_another_length_are_left_out():
    c = collision_metrics(contacts(T), np.arange(T - 5) / 30.0)
    assert c["per_frame"] == {} and "skin_inside" not in c and c["max_penetration_mm"] == 3.5
