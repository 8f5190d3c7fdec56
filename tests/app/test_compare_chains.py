"""jiggle compare on a bake with chains: the tissue is measured from the skin that follows the swung chains (a
chain turning rigidly by 60 degrees is neither jiggle nor a tear), metrics.json's "chains" holds each tip's known
swing, frequency and the root check, chains.png and the report show them; a bake without chains keeps the numbers
of the old code path (the static skin as reference); and the Horse's real bake (tail and ears) end to end."""
from __future__ import annotations

import html
import json

import numpy as np
import pytest
from conftest import asset
from test_compare import STRICT, known_bake  # noqa: E402 - tests/app is on the path (rootdir conftest)

from jiggle.rig.skin.quality import SkinQuality
from jiggle.sim.app.report.chains import ROOT_SHARE, chain_joints, root_edges
from jiggle.sim.app.report.compare import compare, reference_skin, skin_displacement
from jiggle.sim.app.report.page import CHAINS_CAPTION
from jiggle.sim.bake.caches import BakeData, read_npz, write_npz
from jiggle.sim.bake.loop import wrap_figures

FPS, T = 30.0, 72
SWING_HZ = 1.25                  # 3 periods in the clip, on an FFT bin (fps / T = 0.4167 Hz)
SWING = np.pi / 3                # the chain turns up to 60 degrees each way
PIVOT = np.array([0.5, 0.0, 1.0])
LENGTH = 0.5                     # metres, pivot to tip
BUMP = 0.005                     # metres, the tissue's own bump on the body
BUMP_FRAME = 50
RISE = np.array([0.0, 0.0, 0.1])  # m/s: the whole body rides up


def rot_y(theta: float) -> np.ndarray:
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def chain_bake():
    """(BakeData, truth): a vertical sheet (x 0..1, z 0.75..1.25 m, 5 cm grid, y = 0) riding up at 0.1 m/s; its half
    x >= 0.5 is a tail hinged at PIVOT that turns rigidly about y by theta(t) = 60 deg sin(2 pi 1.25 t) (a hard
    seam: no weight blend), its tip at x = 1; the body half gets a 5 mm tissue bump along y around (0.2, 1.0) at
    frame 50. theta = +-60 deg at frames 6, 18, ... puts the tip 2 sin(30 deg) 0.5 = 0.5 m from its animated place."""
    xs, zs = np.linspace(0.0, 1.0, 21), np.linspace(0.75, 1.25, 11)
    X, Z = np.meshgrid(xs, zs, indexing="ij")
    verts = np.stack([X.ravel(), np.zeros(X.size), Z.ravel()], axis=1)
    nz = len(zs)
    faces = []
    for i in range(len(xs) - 1):
        for k in range(nz - 1):
            a, b, c, d = i * nz + k, (i + 1) * nz + k, (i + 1) * nz + k + 1, i * nz + k + 1
            faces += [[a, b, c], [a, c, d]]
    faces = np.array(faces)
    t = np.arange(T) / FPS
    theta = SWING * np.sin(2 * np.pi * SWING_HZ * t)
    R = np.stack([rot_y(th) for th in theta])                     # (T, 3, 3)
    static = verts[None] + t[:, None, None] * RISE
    pivot = PIVOT + t[:, None] * RISE                              # (T, 3)
    chain = np.flatnonzero(verts[:, 0] >= 0.5 - 1e-9)
    rel = static[:, chain] - pivot[:, None]
    delta = np.einsum("tij,tvj->tvi", R, rel) - rel                # (T, Vc, 3) what the swing adds
    swung = static.copy()
    swung[:, chain] += delta
    body = verts[:, 0] < 0.45
    s = np.where(body, np.exp(-((verts[:, 0] - 0.2) ** 2 + (verts[:, 2] - 1.0) ** 2) / (2 * 0.08 ** 2)), 0.0)
    s /= s.max()
    g = np.exp(-0.5 * ((t - t[BUMP_FRAME]) / 0.1) ** 2)
    final = swung.copy()
    final[..., 1] += BUMP * g[:, None] * s[None]
    tip_static = np.array([1.0, 0.0, 1.0]) + t[:, None] * RISE
    tip_final = pivot + np.einsum("tij,tj->ti", R, tip_static - pivot)
    # the chain's joints: its root at the pivot and one halfway, both turned by theta (animated: not turned)
    eye = np.tile(np.eye(4), (T, 1, 1))
    anim = np.tile(np.eye(4), (T, 3, 1, 1))
    anim[:, 1, :3, 3] = pivot
    anim[:, 2, :3, 3] = pivot + [0.25, 0.0, 0.0]
    cw = np.tile(np.eye(4), (T, 2, 1, 1))
    cw[:, :, :3, :3] = R[:, None]
    cw[:, 0, :3, 3] = pivot
    cw[:, 1, :3, 3] = pivot + R @ np.array([0.25, 0.0, 0.0])
    anim[:, 0] = eye
    cv = np.array([[0.3, 0.0, 1.0], [0.3, 0.1, 1.0], [0.3, 0.0, 1.1]])
    cvs = cv[None] + t[:, None, None] * RISE
    data = BakeData(skin_static=static, skin_final=final, faces=faces, fps=FPS, times=t,
                    joint_names=("root", "tail", "tail2"), joint_world=anim, muscle_names=("rump",),
                    muscle_cvs_static=cvs, muscle_cvs_dynamic=cvs, muscle_cv_offsets=[0, 3],
                    muscle_faces=np.array([[0, 1, 2]]), params=json.dumps({"character": "a sheet with a tail"}),
                    skin_rest=verts, chain_names=("tail", "tail2"), chain_world=cw, chain_tip_names=("tail",),
                    chain_tips_static=tip_static[:, None], chain_tips_final=tip_final[:, None],
                    chain_vertices=chain, chain_delta=delta)
    offset = 2 * np.sin(np.abs(theta) / 2) * LENGTH                # |tip_final - tip_static| (m), a chord
    return data, {"offset": offset, "chain": chain, "theta": theta, "pivot": PIVOT, "verts": verts}


SUMMARY = {"chains": {"chains": [{"chain": "tail", "joints": 2, "length_m": LENGTH, "tip_peak_m": LENGTH,
                                  "swing_share": 1.0, "penetrations": 0, "deepest_m": 0.0}],
                      "steps": 100, "step_s": 0.001, "warmup": {"cycles": 0}, "joints": ["tail", "tail2"]}}


@pytest.fixture(scope="module")
def chained(tmp_path_factory):
    """The chain bake compared without renders: (folder, data, truth, metrics)."""
    folder = tmp_path_factory.mktemp("chains")
    data, truth = chain_bake()
    write_npz(data, folder / "bake.npz")
    (folder / "bake.json").write_text(json.dumps({"frames": T, **SUMMARY}))
    result = compare(str(folder), render=False)
    return folder, data, truth, json.loads((folder / "metrics.json").read_text(), **STRICT)


def test_the_tissue_is_measured_from_the_swung_skin(chained):
    folder, data, truth, m = chained
    # the old reference (the animated static skin) reads the tail's swing as half a metre of jiggle that tears the
    # seam; from skin_swung the tissue's own 5 mm bump is all there is, and nothing tears
    q = SkinQuality(data.skin_rest, data.faces)
    assert q.jiggle(data.skin_static, data.skin_final)["torn_edges"].max() > 0
    assert skin_displacement(data.skin_static, data.skin_final).max() > 0.4
    assert m["reference"] == "skin_swung"
    assert m["skin"]["max_mm"] == pytest.approx(BUMP * 1e3, abs=1e-3)
    assert m["peak"]["frame"] == BUMP_FRAME and m["skin"]["max_frame"] == BUMP_FRAME
    jig = m["skin_quality"]["worst"]["jiggle"]
    assert jig["torn_edges_max"] == 0 and jig["gradient_max"] < 0.2
    assert m["skin_quality"]["targets"]["torn_edges"]["pass"]
    assert m["loop"]["wrap_mm"] < BUMP * 1e3                       # the bump is gone by the last frame
    with np.load(folder / "displacement.npz") as npz:
        assert npz["max_m"][truth["chain"]].max() < 1e-5             # the tail's skin: no jiggle


def test_chain_tip_swing_frequency_and_settling(chained):
    _, data, truth, m = chained
    c = m["chains"]
    assert c["count"] == 1 and c["names"] == ["tail"]
    tail = c["chains"]["tail"]
    off = truth["offset"]
    assert tail["tip_peak_mm"] == pytest.approx(LENGTH * 1e3, abs=1e-3)     # 60 degrees: a chord of L
    k = tail["tip_peak_frame"]                                               # |theta| = 60 deg every 12 frames
    assert k % 12 == 6 and tail["tip_peak_time_s"] == pytest.approx(k / FPS)
    assert tail["tip_peak_share"] == pytest.approx(1.0, abs=1e-5) and tail["length_from"] == "bake.json"
    assert tail["tip_rms_mm"] == pytest.approx(1e3 * np.sqrt(np.mean(off ** 2)), abs=1e-3)
    assert tail["tip_end_mm"] == pytest.approx(1e3 * off[-1], abs=1e-3)
    assert tail["dominant_hz"] == pytest.approx(SWING_HZ, abs=0.05)
    assert tail["settle_s"] is None                                          # swung to the end: never settles
    assert tail["joints"] == 2 and tail["skin_vertices"] == len(truth["chain"])
    assert tail["penetrations"] == 0 and tail["swing_share"] == 1.0
    assert c["penetrations"] == 0 and c["swing_share_min"] == pytest.approx(1.0, abs=1e-5)
    assert len(c["per_frame"]["tip_offset_mm"]["tail"]) == T


def test_root_check_sees_the_hard_seam(chained):
    _, data, truth, m = chained
    # a hard seam turned by 60 degrees: the seam's edges stretch by the distance from the pivot over their length,
    # up to 5x here: torn at the root, where the check looks; the edges out along the tail turn rigidly (gradient
    # 2 sin(30 deg) = 1 at most) and are not root edges
    root = m["chains"]["chains"]["tail"]["root"]
    assert root["edges"] > 0 and root["torn_edges_max"] > 0 and not root["pass"]
    assert root["gradient_max"] == pytest.approx(0.25 / 0.05, rel=0.02)      # the corner (z = 1.25) over 5 cm
    assert not m["chains"]["targets"]["root_torn_edges"]["pass"]
    q = SkinQuality(data.skin_rest, data.faces)
    E, verts = q.mesh.edges, truth["verts"]
    peak = np.linalg.norm(data.chain_delta, axis=2).max(axis=0)
    (edges,) = root_edges(E, len(verts), data.chain_vertices, np.zeros(len(peak), np.int64), peak, 1)
    seam = np.flatnonzero((verts[E, 0] < 0.5 - 1e-9).any(axis=1) & (verts[E, 0] >= 0.5 - 1e-9).any(axis=1))
    assert set(seam) <= set(edges)                                          # every edge across the seam
    # turned by 60 degrees at most, a tail vertex moves its distance from the pivot; the body's none: an edge of the
    # tail is a root edge when its less moving end moves less than a quarter of the tail's farthest corner
    tail = verts[:, 0] >= 0.5 - 1e-9
    moved = np.where(tail, np.linalg.norm(verts - PIVOT, axis=1), 0.0)[E].min(axis=1)
    want = np.flatnonzero(tail[E].any(axis=1) & (moved < ROOT_SHARE * np.linalg.norm([0.5, 0.0, 0.25])))
    assert set(seam) <= set(edges) and edges.tolist() == want.tolist() and len(edges) == root["edges"]


def test_chain_joints_without_counts():
    data, _ = chain_bake()
    assert [j.tolist() for j in chain_joints(data, None)] == [[0, 1]]
    assert [j.tolist() for j in chain_joints(data, {"chains": [{"chain": "tail", "joints": 1}]})] == [[0]]


def test_length_from_the_joints_without_bake_json(tmp_path):
    data, _ = chain_bake()
    write_npz(data, tmp_path / "bake.npz")
    m = compare(str(tmp_path), render=False)["metrics"]
    tail = m["chains"]["chains"]["tail"]
    assert tail["length_from"] != "bake.json" and tail["length_mm"] == pytest.approx(LENGTH * 1e3, abs=1e-3)
    assert tail["swing_share"] is None and tail["penetrations"] is None and m["chains"]["penetrations"] is None


def test_plot_report_and_record(chained):
    folder, _, _, m = chained
    png = folder / "chains.png"
    assert png.is_file() and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert m["files"]["chains_plot"] == "chains.png"
    assert "chains.png" in json.loads((folder / "compare.json").read_text())["files"]
    page = (folder / "report.html").read_text()
    assert "<h2>Chains</h2>" in page and html.escape(CHAINS_CAPTION) in page
    assert "root_torn_edges" in page and ">tail<" in page


def test_a_bake_without_chains_keeps_the_old_numbers(tmp_path):
    data, _ = known_bake()
    assert data.chain_vertices is None and reference_skin(data)[0] is data.skin_static
    write_npz(data, tmp_path / "bake.npz")
    m = compare(str(tmp_path), render=False)["metrics"]
    # the old code path: d = final - static, measured directly
    old = skin_displacement(data.skin_static, data.skin_final)
    assert m["skin"]["max_mm"] == pytest.approx(1e3 * float(old.max()), rel=1e-7)
    assert m["peak"]["frame"] == int(np.argmax(old.max(axis=1)))
    q = SkinQuality(data.skin_static[0], data.faces).jiggle(data.skin_static, data.skin_final)
    jig = m["skin_quality"]["worst"]["jiggle"]
    assert jig["gradient_p999_max"] == pytest.approx(float(q["gradient_p999"].max()), rel=1e-7)
    assert jig["torn_edges_max"] == int(q["torn_edges"].max())
    assert m["loop"]["wrap_mm"] == pytest.approx(wrap_figures(data.skin_final, data.skin_static, False)["wrap_mm"],
                                                 rel=1e-7)
    assert m["reference"] == "skin_static" and "chains" not in m and "chains_plot" not in m["files"]
    assert not (tmp_path / "chains.png").exists()


@pytest.mark.slow
def test_horse_tail_and_ears(tmp_path):
    """The Horse galloping (12 frames): three chains swing, the tissue's peak is far below the tail's swing, every
    chain's tip figures agree with the bake's own, and the report has the plot."""
    from jiggle.sim.app.cli import main
    horse = asset("characters/zoo/Horse.glb")
    out = tmp_path / "horse"
    assert main(["-q", "bake", "--character", str(horse), "--animation", "Gallop", "--out", str(out),
                 "--formats", "npz", "--frames", "12"]) == 0
    m = compare(str(out), render=False)["metrics"]
    data = read_npz(out / "bake.npz")
    baked = {c["chain"]: c for c in json.loads((out / "bake.json").read_text())["chains"]["chains"]}
    c = m["chains"]
    assert c["count"] == 3 and set(c["names"]) == {"Tail1", "Ear1.L", "Ear1.R"} == set(baked)
    for name, p in c["chains"].items():
        assert p["tip_peak_mm"] == pytest.approx(baked[name]["tip_peak_m"] * 1e3, rel=1e-3, abs=0.01)
        assert p["tip_peak_share"] == pytest.approx(baked[name]["swing_share"], rel=1e-3, abs=1e-4)
        assert p["penetrations"] == baked[name]["penetrations"] and p["root"]["edges"] > 0
        assert p["skin_vertices"] > 0
    assert sum(p["skin_vertices"] for p in c["chains"].values()) == len(data.chain_vertices)
    old = skin_displacement(data.skin_static, data.skin_final).max() * 1e3
    assert m["reference"] == "skin_swung" and m["skin"]["max_mm"] < old
    assert m["skin"]["max_mm"] < 0.5 * c["chains"]["Tail1"]["tip_peak_mm"]
    assert (out / "chains.png").is_file() and "<h2>Chains</h2>" in (out / "report.html").read_text()
