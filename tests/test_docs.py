"""The documentation site: `mkdocs build --strict` passes (no broken link, no missing reference), the generated
pages say what the code does (every command, every public name, the parameters, bake.json's keys), and headless
Chromium shows the home page and the API page."""
from __future__ import annotations

import html
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    pytest.importorskip("mkdocs", reason="mkdocs is not installed (the test extras: pip install -e '.[test]')")
    out = tmp_path_factory.mktemp("site")
    r = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-q", "-f", str(ROOT / "mkdocs.yml"),
                        "-d", str(out)], capture_output=True, text=True, cwd=ROOT,
                       env={**__import__("os").environ, "NO_MKDOCS_2_WARNING": "1"})
    assert r.returncode == 0, f"mkdocs build --strict failed:\n{r.stderr}"
    return out


def test_the_command_line_page_has_every_command(site):
    from jiggle.sim.app.cli import build_parser
    top = build_parser()
    sub = next(a for a in top._actions if getattr(a, "choices", None) and "bake" in a.choices)
    page = (site / "reference" / "cli" / "index.html").read_text()
    for name, parser in sub.choices.items():
        assert f"jiggle {name}" in page, name
        for action in parser._actions:
            for flag in action.option_strings:
                assert flag in page, f"jiggle {name} {flag}"


def test_the_api_page_documents_every_public_name(site):
    import jiggle
    page = (site / "reference" / "python" / "index.html").read_text()
    for name in ("bake", "Bake", "Metrics", "load_character", "load_clip", "fit", "simulate", "Simulation"):
        assert f'id="jiggle.api.{name}"' in page, name
    assert "InputError" in page and "(T, V, 3)" in page
    assert set(jiggle.__all__) >= {"bake", "Bake", "InputError", "load_character", "load_clip", "fit", "simulate"}


def test_the_parameters_page_is_the_codes_table(site):
    from jiggle.sim.jiggle.keyed import PARAMETERS
    page = (site / "reference" / "parameters" / "index.html").read_text()
    for name, p in PARAMETERS.items():
        assert f"<code>{name}</code>" in page and html.escape(p.what.split(";")[0], quote=False) in page


def test_the_bake_json_keys_documented_are_a_bakes(tmp_path):
    import jiggle
    bake = jiggle.bake(frames=3, formats=["glb"], out=tmp_path / "b", progress=False)
    text = (ROOT / "docs" / "reference" / "files.md").read_text()
    table = text.split("## bake.json")[1].split("## bake.npz")[0]
    documented = {k.strip("`") for row in table.splitlines() if row.startswith("| `")
                  for k in row.split("|")[1].replace(",", " ").split()}
    actual = set(json.loads((bake.folder / "bake.json").read_text()))
    assert documented == actual, f"documented but absent: {documented - actual}; absent from the page: {actual - documented}"


def test_the_readme_is_a_landing_page():
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 200
    assert text.count("./dev.sh demo") == 1 and text.count("./dev.sh test") == 1
    for link in [s.split(")")[0] for s in text.split("](")[1:]]:
        if not link.startswith("http"):
            assert (ROOT / link).exists(), f"README links to a missing {link}"


@pytest.fixture(scope="module")
def browser():
    from browser import headless_chromium
    drv = headless_chromium(1280, 900)
    yield drv
    drv.quit()


@pytest.mark.parametrize("page, must", [("index.html", "Two commands"), ("reference/python/index.html", "jiggle.api.bake")])
def test_chromium_shows_the_pages(site, browser, page, must, tmp_path):
    """The page renders with the theme (its stylesheet applied: a coloured header bar) and its content."""
    import imageio.v3 as iio
    from selenium.webdriver.common.by import By
    browser.get((site / page).as_uri())
    assert must in browser.page_source
    header = browser.find_element(By.CSS_SELECTOR, "header.md-header")
    assert header.value_of_css_property("background-color") not in ("rgba(0, 0, 0, 0)", "transparent")
    shot = tmp_path / (page.replace("/", "_") + ".png")
    browser.save_screenshot(str(shot))
    img = iio.imread(shot)[..., :3].astype(float)
    top, body = img[:40], img[100:]
    assert top.std(axis=(0, 1)).max() < 30 and np.abs(top.mean(axis=(0, 1)) - 255).max() > 40   # the bar
    assert body.std() > 20                                                                  # text drawn


def test_the_gallery_leads_with_animations_that_play(site, browser, tmp_path):
    """The Gallery's videos come before its numbers, at twice the old GIFs' size, and its first character's video
    plays in a real browser: it loads, its time runs, and two screenshots of it 0.4 s apart differ."""
    import io
    import time

    import imageio.v3 as iio
    from selenium.webdriver.common.by import By
    text = (ROOT / "docs" / "gallery.md").read_text()
    folder = ROOT / "docs" / "images" / "gallery"
    videos = sorted(folder.glob("*.webm"))
    if not videos:
        pytest.skip("docs/images/gallery has no animation (benchmarks/zoo.py writes them)")
    assert text.index("<video") < text.index("## The numbers")
    assert sum(f.stat().st_size for f in folder.iterdir()) < 12_000_000       # a few MB for the whole page
    for v in videos:                                                          # each with its MP4 and its poster
        assert v.with_suffix(".mp4").is_file() and v.with_suffix(".png").is_file(), v
    browser.get((site / "gallery" / "index.html").as_uri())
    video = browser.find_element(By.CSS_SELECTOR, "figure video")
    browser.execute_script("arguments[0].scrollIntoView()", video)
    for _ in range(100):
        if browser.execute_script("return arguments[0].readyState >= 3 && arguments[0].currentTime > 0.05", video):
            break
        time.sleep(0.1)
    assert browser.execute_script("return arguments[0].videoWidth", video) >= 1040
    t0 = browser.execute_script("return arguments[0].currentTime", video)
    a = iio.imread(io.BytesIO(video.screenshot_as_png))[..., :3].astype(float)
    time.sleep(0.4)
    b = iio.imread(io.BytesIO(video.screenshot_as_png))[..., :3].astype(float)
    assert browser.execute_script("return arguments[0].currentTime", video) != t0, "the video does not play"
    assert a.shape == b.shape and a.std() > 5
    assert np.abs(a - b).mean() > 0.5, "the gallery's animation does not advance"