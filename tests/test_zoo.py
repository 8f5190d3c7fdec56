"""benchmarks/zoo.py, the zoo as a benchmark: its loop-wrap measure on arrays whose answer is known, its choice of
cycles, a refusal kept as a row, and its quick subset (Horse on Gallop and CesiumMan on its walk, 12 frames each)
run end to end through `jiggle bake` and `jiggle compare`: a table with a row per bake and every column, finite
figures for the bakes, the gallery page and its pictures."""
from __future__ import annotations

import importlib.util
import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def zoo():
    path = ROOT / "benchmarks" / "zoo.py"
    spec = importlib.util.spec_from_file_location("_bench_zoo", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module                  # dataclasses look their module up there
    try:
        spec.loader.exec_module(module)
        yield module
    finally:
        sys.modules.pop(spec.name, None)


def test_loop_wrap_on_a_known_offset(zoo):
    # d[t] = A sin(2 pi t / T) on one vertex, zero elsewhere, sampled t = 0..n-1 with the last frame short of a
    # full period: the wrap |d[n-1] - d[0]| and every step |d[t+1] - d[t]| are known in closed form.
    n, period, amp = 20, 25.0, 0.010                      # frames, frames per period, metres
    t = np.arange(n)
    static = np.zeros((n, 3, 3))
    final = static.copy()
    final[:, 1, 2] = amp * np.sin(2 * np.pi * t / period)
    wrap_mm, ratio = zoo.loop_wrap(final, static)
    want_wrap = abs(amp * np.sin(2 * np.pi * (n - 1) / period)) * 1e3
    steps = np.abs(np.diff(amp * np.sin(2 * np.pi * t / period))) * 1e3
    assert wrap_mm == pytest.approx(want_wrap, rel=1e-9)
    assert ratio == pytest.approx(want_wrap / np.median(steps), rel=1e-9)
    # a static skin moved by a constant offset never pops; a still clip with a jump at the end: ratio inf
    assert zoo.loop_wrap(static + 0.003, static) == (0.0, 0.0)
    jump = final * 0
    jump[-1, 0, 0] = 0.002
    w, r = zoo.loop_wrap(jump, static)
    assert w == pytest.approx(2.0) and r == math.inf


def test_sustained_jiggle_and_the_idle_order(zoo):
    # one vertex of two: per-frame max a, 0, b, a (the last frame repeats the first in a closed loop)
    a, b = 0.004, 0.002
    diff = np.array([[a, 0.0], [0.0, 0.0], [0.0, b], [a, 0.0]])
    assert zoo.sustained(diff, True, 2.0) == pytest.approx(100 * math.sqrt((a * a + b * b) / 3) / 2.0)
    assert zoo.sustained(diff, False, 2.0) == pytest.approx(100 * math.sqrt((2 * a * a + b * b) / 4) / 2.0)
    # an Idle with one stroke peaks above the Walk but sustains below it; a mocap clip is not the character's cycle
    R = zoo.Row
    rows = [R("Horse", "Walk", "baked", peak_pct=0.98, sustained_pct=0.60),
            R("Horse", "Idle_2", "baked", peak_pct=1.01, sustained_pct=0.30),
            R("Horse", "Idle", "baked", peak_pct=0.09, sustained_pct=0.02),
            R("Horse", "CMU 09_11 (run)", "baked", peak_pct=0.05, sustained_pct=0.01),
            R("Cat", "Walk", "baked", peak_pct=0.5, sustained_pct=0.3)]
    order = zoo.idle_order(rows)
    assert [o["character"] for o in order] == ["Horse"]
    o = order[0]
    # its Idle is below every other cycle, Idle_2 included, both ways
    assert o["idle"] == "Idle" and o["peak_pct"]["other"] == "Walk" and o["peak_pct"]["below"]
    assert o["sustained_pct"]["below"] and o["sustained_pct"]["other_pct"] == 0.30
    # its variant's one stroke peaks above the Walk, and sustains below it
    v, w = o["variants_peak_pct"], o["variants_sustained_pct"]
    assert v["idle"] == "Idle_2" and v["other"] == "Walk" and not v["below"] and w["below"]
    text = "\n".join(zoo.idle_lines(order))
    assert "**no**" in text and "Idle variants" in text
    # an Idle above a calmer cycle is reported
    calm = rows + [R("Horse", "Sleep", "baked", peak_pct=0.05, sustained_pct=0.01)]
    assert not zoo.idle_order(calm)[0]["peak_pct"]["below"]


def test_cycles_are_the_looping_animations(zoo):
    horse = ["Attack_Kick", "Death", "Eating", "Gallop", "Gallop_Jump", "Idle", "Idle_2", "Idle_Headlow",
             "Idle_HitReact_Left", "Walk"]
    assert zoo.cycles_of(horse) == ["Gallop", "Walk", "Idle", "Idle_2", "Idle_Headlow"]
    robot = ["Dance", "Death", "Idle", "Jump", "Running", "Sitting", "Walking", "WalkJump", "Wave"]
    assert zoo.cycles_of(robot) == ["Running", "Walking", "Dance", "Idle"]
    # an FBX's shape-key actions repeat the armature's; a file's only animation is its cycle
    barbarian = ["Armature|Armature|idle", "Key.001|Armature|idle", "Key|Armature|idle"]
    assert zoo.cycles_of(barbarian) == ["Armature|Armature|idle"]
    assert zoo.cycles_of(["animation0"]) == ["animation0"]


def test_a_refusal_is_a_row(zoo, tmp_path):
    bad = tmp_path / "not_a_character.glb"
    bad.write_bytes(b"this is not a glTF file")
    row = zoo.run_job(zoo.Job("Bad", str(bad), "Walk", animation="Walk"), tmp_path / "out", zoo.jiggle_command(), 4)
    assert row.status == "refused" and row.message.startswith("jiggle: error:") and "\n" not in row.message
    assert not row.passed and zoo.md_row(row).count("|") == len(zoo.HEAD) + 1


@pytest.mark.slow
def test_quick_zoo_writes_one_table(zoo, tmp_path):
    for rel in ("characters/zoo/Horse.glb", "characters/CesiumMan.glb"):
        if not (zoo.ASSETS / rel).is_file():
            pytest.skip(f"shared asset {rel} not found under {zoo.ASSETS} (../shared/assets is absent)")
    docs = tmp_path / "docs"
    assert zoo.main(["--quick", "--out", str(tmp_path / "bakes"), "--results", str(tmp_path / "zoo"),
                     "--gallery", str(docs)]) == 0
    data = json.loads((tmp_path / "zoo.json").read_text())
    rows = data["rows"]
    assert [(r["character"], r["clip"]) for r in rows] == [("Horse", "Gallop"), ("CesiumMan", "animation0")]
    md = (tmp_path / "zoo.md").read_text()
    head = next(ln for ln in md.splitlines() if ln.startswith("| character"))
    assert [c.strip() for c in head.strip("|").split("|")] == zoo.HEAD
    body = [ln for ln in md.splitlines() if ln.startswith("| ") and not ln.startswith(("| character", "| ---"))]
    assert len(body) == len(rows) and all(ln.count("|") == len(zoo.HEAD) + 1 for ln in body)
    assert "bakes pass" in md
    for r in rows:
        assert r["status"] == "baked", r
        assert r["frames"] == 12
        for k in ("size_m", "peak_mm", "peak_pct", "sustained_pct", "gradient_p999", "folds_over_lbs", "near_limit_pct", "wrap_mm",
                  "wrap_ratio", "bake_s", "compare_s"):
            assert r[k] is not None and math.isfinite(r[k]), (r["character"], k, r[k])
        assert r["torn_edges"] >= 0 and r["hard_stops"] >= 0
        assert 0 < r["peak_pct"] < 100 and r["size_m"] > 0.5
        # the wrap the table reports is the one loop_wrap finds in the bake's own arrays: the tissue's, from the
        # skin that follows the swung chains
        with np.load(Path(r["out"]) / "bake.npz") as z:
            static = np.array(z["skin_static"])
            if "chain_vertices" in z.files:
                static[:, z["chain_vertices"]] += z["chain_delta"]
            wrap, ratio = zoo.loop_wrap(z["skin_final"], static)
        if r["wrap_from"] == "bake.npz":
            assert r["wrap_mm"] == pytest.approx(wrap) and r["wrap_ratio"] == pytest.approx(ratio)
    assert rows[0]["vigorous"] and not rows[1]["vigorous"]
    # the Horse's tail and ears swing, and never into its body; CesiumMan has no chain
    assert rows[0]["chains"] == 3 and rows[0]["chain_penetrations"] == 0 and rows[0]["chain_swing_min_pct"] > 0
    assert rows[1]["chains"] == 0
    page = (docs / "gallery.md").read_text()
    import imageio.v2 as iio
    for name in ("Horse", "CesiumMan"):        # each plays its cycle: a video of its frames at its rate, not a still
        for ext in ("webm", "mp4"):
            video = docs / "images" / "gallery" / f"{name}.{ext}"
            assert video.is_file() and video.stat().st_size < 600_000, video
            assert f"../images/gallery/{name}.{ext}" in page
            with iio.get_reader(str(video)) as reader:            # read back by ffmpeg
                fps = float(reader.get_meta_data()["fps"])
                frames = np.stack([f for f in reader])        # list() would ask its length: inf
            assert frames.shape[0] >= 6 and frames.shape[1:3] == (400, 1056), frames.shape   # twice 520 x 200
            assert 24.0 <= fps <= 30.0, fps
            assert np.abs(frames[1:].astype(float) - frames[:-1]).mean() > 0.1        # it moves
        poster = docs / "images" / "gallery" / f"{name}.png"
        assert poster.is_file() and f'poster="../images/gallery/{name}.png"' in page
        assert not (docs / "images" / "gallery" / f"{name}.gif").exists()
    assert page.index("<video") < page.index("## The numbers")
