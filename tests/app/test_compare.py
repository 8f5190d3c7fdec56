"""jiggle compare: metrics against a synthetic bake whose answers are known, strict JSON, a
self-contained report, errors for missing or unfinished bakes, and one render smoke test."""
from __future__ import annotations

import json
import os
import re

import numpy as np
import pytest

from jiggle.rig.base.errors import InputError
from jiggle.sim.app.report import compare_render
from jiggle.sim.app.report.compare import compare, muscle_energy, muscle_offsets
from jiggle.sim.bake.caches import BakeData, write_npz

FPS, T = 30.0, 60
PEAK_FRAME = 37
SKIN_AMP = 0.012                 # metres, the skin bump's largest displacement
MUSCLES = {"biceps_l": (3.0, 0.004, 0.25), "belly_fat": (5.0, 0.010, 1.5)}   # Hz, metres, kg
CVS = 40
STRICT = dict(parse_constant=lambda c: pytest.fail(f"metrics.json holds {c}"))


def external(text: str) -> list[str]:
    """URLs and non-data sources a page would fetch (base64 has no ':', so no "http:" hides in it)."""
    return (re.findall(r"(?:https?|ftp):", text, flags=re.I)
            + [s for s in re.findall(r"(?:src|href)\s*=\s*[\"']?([^\"' >]*)", text, flags=re.I)
               if not s.startswith("data:")] + re.findall(r"url\(|@import", text))


def sphere(rows: int = 12, cols: int = 24):
    """A UV sphere (radius 0.2 m, centre 1 m up): vertices (V, 3) float64, faces (F, 3)."""
    import trimesh
    m = trimesh.creation.uv_sphere(radius=0.2, count=[rows, cols])
    return np.asarray(m.vertices) + [0.0, 0.0, 1.0], np.asarray(m.faces)


def known_bake(rows=12, cols=24, frames=T, still=False):
    """(BakeData, truth): a sphere riding up at 0.1 m/s; its skin bulges outward around +X by
    SKIN_AMP * g(t) * s(v) with g a Gaussian in time equal to 1 at PEAK_FRAME and s in [0, 1], 1 at the
    vertex nearest +X; two muscles of 40 CVs each swinging A_c sin(2 pi f t) along one direction per
    muscle, A_c spread over [0.5, 1] x the muscle's amplitude. still: dynamic == static everywhere."""
    verts, faces = sphere(rows, cols)
    t = np.arange(frames) / FPS
    rise = np.array([0.0, 0.0, 0.1])
    static = verts[None] + t[:, None, None] * rise
    normal = (verts - [0.0, 0.0, 1.0]) / 0.2
    s = np.clip(normal[:, 0], 0.0, None) ** 4
    s /= s.max()                                          # exactly 1 at the vertex nearest +X
    g = np.exp(-0.5 * ((t - t[min(PEAK_FRAME, frames - 1)]) / 0.15) ** 2)
    disp = SKIN_AMP * g[:, None] * s[None]                # (T, V) metres
    final = static if still else static + disp[:, :, None] * normal[None]

    rng = np.random.default_rng(0)
    cv_static, cv_dyn, amps = [], [], []
    for m, (f, a, _) in enumerate(MUSCLES.values()):
        base = rng.normal(scale=0.05, size=(CVS, 3)) + [0.1 * m, 0.0, 1.0]
        st = base[None] + t[:, None, None] * rise
        amp_c = a * np.linspace(0.5, 1.0, CVS)            # (CVS,) metres
        e = np.array([1.0, 2.0 * m - 1.0, 0.5]) / np.linalg.norm([1.0, 2.0 * m - 1.0, 0.5])
        off = amp_c[None, :, None] * np.sin(2 * np.pi * f * t)[:, None, None] * e
        cv_static.append(st)
        cv_dyn.append(st if still else st + off)
        amps.append(amp_c)
    params = {"muscles": {n: {"mass_kg": kg, "frequency_hz": f, "damping_ratio": 0.2,
                              "kind": "fat" if "fat" in n else "muscle"} for n, (f, _, kg) in MUSCLES.items()},
              "clip": {"file": "/data/synthetic_bounce.bvh"}, "character": "test sphere",
              "settings": {"substeps": 4, "gravity": False}}
    data = BakeData(skin_static=static, skin_final=final, faces=faces, fps=FPS, times=t,
                    joint_names=("root",), joint_world=np.tile(np.eye(4), (frames, 1, 1, 1)),
                    muscle_names=tuple(MUSCLES), muscle_cvs_static=np.concatenate(cv_static, axis=1),
                    muscle_cvs_dynamic=np.concatenate(cv_dyn, axis=1),
                    muscle_cv_offsets=[0, CVS, 2 * CVS], muscle_faces=np.array([[0, 1, 2]]),
                    params=json.dumps(params))
    return data, {"disp": disp, "s": s, "g": g}


@pytest.fixture(scope="module")
def baked(tmp_path_factory):
    """One synthetic bake compared without renders: (folder, data, truth, result)."""
    folder = tmp_path_factory.mktemp("bake")
    data, truth = known_bake()
    write_npz(data, folder / "bake.npz")
    return folder, data, truth, compare(str(folder), render=False)


def test_files_exist_and_have_headers(baked):
    folder, _, _, result = baked
    for name in ("metrics.json", "displacement.npz", "amplitude.png", "energy.png", "spectrum.png",
                 "displacement.png", "report.html"):
        p = folder / name
        assert p.is_file() and p.stat().st_size > 0, name
    for key in ("amplitude", "energy", "spectrum", "displacement_plot"):
        with open(result["files"][key], "rb") as fh:
            assert fh.read(8) == b"\x89PNG\r\n\x1a\n", key
    assert not (folder / "peak.png").exists() and not (folder / "clip.mp4").exists()
    on_disk = json.loads((folder / "metrics.json").read_text(), **STRICT)
    assert on_disk["files"]["report"] == "report.html" and on_disk["muscles"].keys() == result["metrics"]["muscles"].keys()
    assert not [n for n in os.listdir(folder) if n.startswith(".")]          # no temporary files left


def test_skin_metrics_match_the_known_field(baked):
    folder, data, truth, result = baked
    skin, peak = result["metrics"]["skin"], result["metrics"]["peak"]
    disp = truth["disp"]
    assert peak["frame"] == PEAK_FRAME and skin["max_frame"] == PEAK_FRAME
    assert peak["time_s"] == pytest.approx(PEAK_FRAME / FPS)
    assert truth["s"][skin["max_vertex"]] == pytest.approx(1.0)             # a vertex on the bump's top (seams repeat it)
    assert skin["max_mm"] == pytest.approx(SKIN_AMP * 1e3, abs=1e-3)            # 1e-6 m
    with np.load(folder / "displacement.npz") as npz:
        max_m, rms_m = npz["max_m"], npz["rms_m"]
    assert max_m.dtype == np.float32 and max_m.shape == (data.skin_static.shape[1],)
    np.testing.assert_allclose(max_m, SKIN_AMP * truth["s"], atol=1e-6)          # g = 1 at the peak frame
    # RMS over time of SKIN_AMP g(t) s(v) is SKIN_AMP s(v) sqrt(mean g^2)
    np.testing.assert_allclose(rms_m, SKIN_AMP * truth["s"] * np.sqrt(np.mean(truth["g"] ** 2)), atol=1e-6)
    vmax = disp.max(axis=0)
    assert skin["per_vertex_max"]["p95_mm"] == pytest.approx(1e3 * np.percentile(vmax, 95), abs=1e-3)
    assert skin["per_vertex_max"]["mean_mm"] == pytest.approx(1e3 * vmax.mean(), abs=1e-3)


def test_muscle_amplitude_and_frequency(baked):
    _, data, _, result = baked
    m = result["metrics"]
    bin_hz = FPS / T
    assert m["frequency_resolution_hz"] == pytest.approx(bin_hz)
    t = data.times
    assert list(m["muscles"]) == ["belly_fat", "biceps_l"]                    # largest peak first
    for name, (f, a, _) in MUSCLES.items():
        mm = m["muscles"][name]
        # within one bin (the contract); these sit on bin centres, where the parabola is closer still
        assert abs(mm["dominant_hz"] - f) <= bin_hz / 4, name
        # the largest CV has amplitude a: its offset a |sin(2 pi f t)| sampled at the frames
        wave = a * np.abs(np.sin(2 * np.pi * f * t))
        assert mm["peak_mm"] == pytest.approx(1e3 * wave.max(), abs=1e-3)
        k = int(round(mm["peak_time_s"] * FPS))          # the wave peaks every period: any of them
        assert mm["peak_frame"] == k and wave[k] == pytest.approx(wave.max(), abs=1e-6)
        assert mm["rms_mm"] == pytest.approx(1e3 * np.sqrt(np.mean(wave ** 2)), abs=1e-3)
        assert mm["kind"] == ("fat" if "fat" in name else "muscle") and mm["cvs"] == CVS
    assert m["energy_unit"] == "J"


def test_energy_against_a_hand_computation(baked):
    _, data, _, result = baked
    d = muscle_offsets(data)
    masses = np.array([kg for _, _, kg in MUSCLES.values()])
    omegas = np.array([2 * np.pi * f for f, _, _ in MUSCLES.values()])
    energy = muscle_energy(d, data.times, data.muscle_cv_offsets, masses, omegas)
    k = 21
    dt2 = data.times[k + 1] - data.times[k - 1]
    for m, name in enumerate(MUSCLES):
        sl = slice(m * CVS, (m + 1) * CVS)
        # E = sum over CVs of 0.5 (mass / 40) (|v|^2 + w^2 |d|^2), v by a central difference
        v = (d[k + 1, sl] - d[k - 1, sl]) / dt2
        hand = sum(0.5 * masses[m] / CVS * (v[c] @ v[c] + omegas[m] ** 2 * d[k, sl][c] @ d[k, sl][c])
                   for c in range(CVS))
        assert energy[k, m] == pytest.approx(hand, rel=1e-12)
        mm = result["metrics"]["muscles"][name]
        assert mm["peak_energy_j"] == pytest.approx(energy[:, m].max(), rel=1e-5)
        assert mm["mean_energy_j"] == pytest.approx(energy[:, m].mean(), rel=1e-5)
        # an oscillation at the spring's own frequency keeps its energy: 0.5 m_c w^2 sum A_c^2,
        # less what the central difference misses of the speed (sin(w dt) / (w dt) of it)
        a = MUSCLES[name][1] * np.linspace(0.5, 1.0, CVS)
        full = 0.5 * masses[m] / CVS * omegas[m] ** 2 * (a ** 2).sum()
        assert full * 0.7 < energy[1:-1, m].mean() <= full * 1.01


def test_per_kg_energy_without_masses(tmp_path):
    data, _ = known_bake(rows=6, cols=8)
    params = json.loads(data.params)
    params["muscles"]["biceps_l"].pop("mass_kg")
    params["muscles"]["belly_fat"] = "not a table"                 # tolerated: no params for it at all
    fields = {f: getattr(data, f) for f in data.__dataclass_fields__}
    write_npz(BakeData(**{**fields, "params": json.dumps(params)}), tmp_path / "bake.npz")
    m = compare(str(tmp_path), render=False)["metrics"]
    assert m["energy_unit"] == "J/kg" and "per kg" in m["energy"]
    fat = m["muscles"]["belly_fat"]
    assert fat["mass_kg"] is None and fat["energy_frequency_from"] == "measured"
    assert fat["energy_frequency_hz"] == pytest.approx(fat["dominant_hz"])
    assert m["muscles"]["biceps_l"]["energy_frequency_from"] == "params"


def test_report_is_self_contained(baked):
    folder, _, _, _ = baked
    text = (folder / "report.html").read_text()
    assert not external(text)
    assert text.count('src="data:image/png;base64,') == 5                     # the five plots
    for name in MUSCLES:
        assert name in text
    assert "synthetic_bounce.bvh" in text and "test sphere" in text and "substeps" in text
    assert text.index("belly_fat") < text.index("biceps_l")                  # sorted by peak


def test_still_bake_gives_zeros_and_no_frequency(tmp_path):
    """Blend 0: dynamic == static. The fat's CVs alone carry float32 round-off (a few ulps, well
    under STILL), which must not make up a frequency."""
    data, _ = known_bake(rows=6, cols=8, still=True)
    dyn = np.array(data.muscle_cvs_dynamic)
    dyn[::2, CVS:] = np.nextafter(np.nextafter(dyn[::2, CVS:], np.float32(2)), np.float32(2))  # 2 ulps up
    fields = {f: getattr(data, f) for f in data.__dataclass_fields__}
    write_npz(BakeData(**{**fields, "muscle_cvs_dynamic": dyn}), tmp_path / "bake.npz")
    compare(str(tmp_path), render=False)
    m = json.loads((tmp_path / "metrics.json").read_text(), **STRICT)
    assert m["skin"]["max_mm"] == 0.0 and m["skin"]["per_vertex_rms"]["p99_mm"] == 0.0
    assert m["peak"]["frame"] == 0
    still, noisy = m["muscles"]["biceps_l"], m["muscles"]["belly_fat"]
    assert still["peak_mm"] == 0.0 and still["peak_energy_j"] == 0.0 and still["settle_s"] == 0.0
    assert 0.0 < noisy["peak_mm"] < 1e-3
    assert still["dominant_hz"] is None and noisy["dominant_hz"] is None
    with np.load(tmp_path / "displacement.npz") as npz:
        assert not npz["max_m"].any() and not npz["rms_m"].any()


def test_short_clip_has_no_frequency(tmp_path):
    data, _ = known_bake(rows=6, cols=8, frames=5)
    write_npz(data, tmp_path / "bake.npz")
    m = compare(str(tmp_path), render=False)["metrics"]
    assert all(mm["dominant_hz"] is None for mm in m["muscles"].values())
    assert all(mm["peak_mm"] > 0 for mm in m["muscles"].values())


def test_missing_or_unfinished_bake_names_the_path(tmp_path):
    missing = tmp_path / "nope"
    with pytest.raises(InputError, match="jiggle bake") as e:
        compare(str(missing), render=False)
    assert str(missing) in str(e.value)
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(InputError, match="bake.npz") as e:
        compare(str(empty), render=False)
    assert str(empty) in str(e.value) and "--out" in str(e.value)
    partial = tmp_path / "partial"
    (partial / ".partial").mkdir(parents=True)
    with pytest.raises(InputError, match="unfinished") as e:
        compare(str(partial), render=False)
    assert str(partial) in str(e.value) and "--resume" in str(e.value)
    assert os.listdir(empty) == [] and os.listdir(partial) == [".partial"]   # nothing written


def test_video_falls_back_to_gif_when_ffmpeg_fails(tmp_path, monkeypatch):
    import imageio.v2

    def broken(*args, **kwargs):
        raise RuntimeError("no ffmpeg here")
    monkeypatch.setattr(imageio.v2, "get_writer", broken)
    frames = [np.full((16, 24, 3), 40 * i, np.uint8) for i in range(4)]
    path, how = compare_render.write_video(frames, str(tmp_path), fps=10.0)
    assert path.endswith("clip.gif") and how.startswith("gif") and "no ffmpeg here" in how
    assert open(path, "rb").read(6) in (b"GIF89a", b"GIF87a")
    assert os.listdir(tmp_path) == ["clip.gif"]


def test_video_frames_spread_evenly():
    assert compare_render.video_frames(50).tolist() == list(range(50))
    sel = compare_render.video_frames(300)
    assert len(sel) == compare_render.MAX_VIDEO_FRAMES and sel[0] == 0 and sel[-1] == 299
    assert np.ptp(np.diff(sel)) <= 1


def test_view_looks_across_the_motion():
    verts, _ = sphere(6, 8)
    moved = verts.copy()
    moved[verts[:, 0] > 0.1] += [0.01, 0.0, 0.0]          # the +X side swings along X
    d = compare_render.view_direction(verts, moved)
    assert abs(d[0]) < 1e-9 and d[2] > 0                  # seen from +-Y, slightly above


@pytest.mark.slow
def test_render_smoke(tmp_path):
    """peak.png and the video from a real off-screen render (PyVista, EGL); a second run without
    renders removes them, so no picture of an earlier run stays beside new numbers."""
    data, _ = known_bake(rows=16, cols=32)
    write_npz(data, tmp_path / "bake.npz")
    calls = []
    result = compare(str(tmp_path), progress=calls.append)
    files = result["files"]
    with open(files["peak"], "rb") as fh:
        assert fh.read(8) == b"\x89PNG\r\n\x1a\n"
    import imageio.v3 as iio
    img = iio.imread(files["peak"])
    assert img.shape[0] * img.shape[1] == pytest.approx(2 * compare_render.PEAK_PIXELS, rel=0.05)
    left, right = img[:, : img.shape[1] // 2], img[:, img.shape[1] // 2:]
    assert (left < 250).any() and (right < 250).any()                        # something drawn in both
    with open(files["video"], "rb") as fh:
        head = fh.read(12)
    assert head[4:8] == b"ftyp" or head[:6] in (b"GIF89a", b"GIF87a")
    video = result["metrics"]["video"]
    assert video["frames"] == T and sum(calls) == 1 + T
    text = open(files["report"]).read()
    assert "data:video/mp4;base64," in text or "data:image/gif;base64," in text
    # five plots, the peak and the skin-quality close-ups
    assert text.count("data:image/png;base64,") == 7 and not external(text)
    closeups = iio.imread(files["quality_closeups"])
    assert closeups.shape[0] >= 2 * 300 and (closeups < 250).any()            # a row per worst frame

    compare(str(tmp_path), render=False)
    assert not (tmp_path / "peak.png").exists() and not (tmp_path / "clip.mp4").exists()
    assert not (tmp_path / "quality_closeups.png").exists()
    assert not (tmp_path / "clip.gif").exists()


def test_skin_quality_finds_a_planted_dent(tmp_path):
    """A vertex of the final skin pushed through the sphere at one frame: compare's skin quality counts
    its folds and tears at that frame only, fails the targets, picks that frame as the worst, and
    reports the LBS and rest counts from the bake's own skin_lbs and skin_rest."""
    import dataclasses
    data, _ = known_bake()
    final = data.skin_final.copy()
    verts, _ = sphere()
    v, k = 100, 20
    final[k, v] -= 0.3 * (verts[v] - [0.0, 0.0, 1.0]) / 0.2        # 0.3 m inward: through the middle
    data = dataclasses.replace(data, skin_final=final, skin_lbs=data.skin_static, skin_rest=verts)
    write_npz(data, tmp_path / "bake.npz")
    q = compare(str(tmp_path), render=False)["metrics"]["skin_quality"]
    assert q["rest_from"] == "skin_rest" and q["rest"]["folded_edges"] == 0
    per = q["per_frame"]
    assert per["lbs"]["folded_edges"] == per["static"]["folded_edges"] == [0] * T
    folds = np.array(per["final"]["folded_edges"])
    torn = np.array(per["jiggle"]["torn_edges"])
    assert folds[k] >= 4 and torn[k] >= 4 and folds.sum() == folds[k] and torn.sum() == torn[k]
    assert k in q["worst_frames"]
    t = q["targets"]
    assert not t["torn_edges"]["pass"] and not t["folds_added_over_lbs"]["pass"]
    assert t["folds_added_over_lbs"]["worst_frame"] == k and t["folds_added_over_lbs"]["value"] > 1.1
    assert (tmp_path / "quality.png").is_file()
    assert "Skin quality" in (tmp_path / "report.html").read_text() and "FAIL" in (tmp_path / "report.html").read_text()


def test_near_limit_fraction_hard_stops_and_the_flag(tmp_path):
    """The synthetic muscles given reaches: biceps_l (4 mm swing) with a reach of 4.2 mm sits at >= 90% of
    it exactly where |sin| >= 0.9 / (4 / 4.2) (its largest CV carries the whole amplitude); belly_fat (10 mm)
    with a 50 mm reach never comes near. bake.json's tissue hard stops reach metrics.json; the report flags
    biceps_l (more than 5% of frames) with advice naming its scene table, and not belly_fat."""
    data, _ = known_bake()
    params = json.loads(data.params)
    params["muscles"]["biceps_l"].update(reach_m=0.0042, strength=0.5)
    params["muscles"]["belly_fat"].update(reach_m=0.05, strength=0.5)
    from dataclasses import replace
    data = replace(data, params=json.dumps(params))
    write_npz(data, tmp_path / "bake.npz")
    (tmp_path / "bake.json").write_text(json.dumps({"tissue": {"hard_stops": {"biceps_l": 3, "belly_fat": 0},
                                                               "hard_stop_rule": "test rule"}}))
    m = compare(str(tmp_path), render=False)["metrics"]
    t = np.arange(T) / FPS
    expect = float((0.004 * np.abs(np.sin(2 * np.pi * MUSCLES["biceps_l"][0] * t)) >= 0.9 * 0.0042).mean())
    bic, fat = m["muscles"]["biceps_l"], m["muscles"]["belly_fat"]
    assert expect > 0.05
    assert bic["near_limit_fraction"] == pytest.approx(expect, abs=1.5 / T)
    sampled = 0.004 * np.abs(np.sin(2 * np.pi * MUSCLES["biceps_l"][0] * t)).max()
    assert bic["peak_reach_fraction"] == pytest.approx(sampled / 0.0042, rel=1e-5)
    assert fat["near_limit_fraction"] == 0.0 and fat["peak_reach_fraction"] < 0.25
    assert bic["hard_stops"] == 3 and fat["hard_stops"] == 0
    lim = m["limits"]
    assert lim["hard_stops_total"] == 3 and lim["hard_stop_rule"] == "test rule"
    assert lim["near_limit_fraction_all"] == pytest.approx(bic["near_limit_fraction"] / 2)
    assert [f["muscle"] for f in lim["flags"]] == ["biceps_l"]
    assert "jiggle.muscles.biceps_l" in lim["flags"][0]["advice"] and "damping" in lim["flags"][0]["advice"]
    html = (tmp_path / "report.html").read_text()
    assert "Near the limit" in html and "FLAG" in html and "biceps_l is near its limit" in html
    assert (tmp_path / "limits.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and "Offset over reach" in html


def test_a_bake_without_reaches_has_no_limit_flags(baked):
    m = baked[3]["metrics"]
    assert not (baked[0] / "limits.png").exists()
    assert m["limits"]["muscles_with_reach"] == 0 and m["limits"]["flags"] == []
    assert all(x["near_limit_fraction"] is None and x["hard_stops"] is None for x in m["muscles"].values())


def test_an_inverted_hero_solid_fails_a_skin_target(tmp_path):
    """A hero-mode bake whose solid inverted tets (bake.json "fem") fails compare's fem_inverted_tets target, in
    metrics.json and in the report, however clean its skin; one with none passes it; a particle bake has no such
    target."""
    data, _ = known_bake()
    write_npz(data, tmp_path / "bake.npz")
    fem = {"inverted_max": 3, "frames_with_inverted": 2, "min_det": -0.4}
    (tmp_path / "bake.json").write_text(json.dumps({"fem": fem}))
    targets = compare(str(tmp_path), render=False)["metrics"]["skin_quality"]["targets"]
    t = targets["fem_inverted_tets"]
    assert t["value"] == 3 and t["limit"] == 0 and t["pass"] is False
    assert t["frames"] == 2 and t["min_det"] == -0.4
    assert targets["torn_edges"]["pass"]                   # the skin itself scores clean
    html = (tmp_path / "report.html").read_text()
    assert re.search(r"fem_inverted_tets</th><td>3 \(limit 0\) <b[^>]*>FAIL", html), "the report shows the failure"
    (tmp_path / "bake.json").write_text(json.dumps({"fem": {**fem, "inverted_max": 0, "frames_with_inverted": 0,
                                                            "min_det": 0.3}}))
    assert compare(str(tmp_path), render=False)["metrics"]["skin_quality"]["targets"]["fem_inverted_tets"]["pass"]
    (tmp_path / "bake.json").write_text(json.dumps({"fem": None}))
    assert "fem_inverted_tets" not in compare(str(tmp_path), render=False)["metrics"]["skin_quality"]["targets"]
