"""`jiggle view`: bad folders refused with exit 2, only the page's own files served, Ctrl-C exits 130; in
headless Chromium (Debian's chromium + chromium-driver, driven by selenium; skipped without them) the page
draws the skin and a scrub changes it; a slider typed into the page re-simulates, and the scene its "save
scene" button writes bakes (`jiggle bake`) to exactly that motion. The re-simulation of the untouched
values replays the bake bit for bit.

One small bake (the demo, 0.4 s, a 3,000-vertex body, chunks of 8 frames so the re-simulation carries the
particle state across chunks as the bake does) and one viewer serve the whole module."""
from __future__ import annotations

import http.client
import io
import os
import signal
import subprocess
import sys
import time
import tomllib

import numpy as np
import pytest

from jiggle.sim.app.cli import main
from jiggle.sim.app.view.page import SKIN_COLOUR, twin
from jiggle.sim.app.view.playback import heat_bands
from jiggle.sim.app.view.scene_file import toml_text
from jiggle.sim.app.view.tuning import Tuning, apply_tuning
from jiggle.sim.bake.caches import read_npz

BROWSER_TIMEOUT = 40.0
"""seconds a browser waits for the page to show what a test expects (software WebGL on 2 busy cores)."""


# ---------------------------------------------------------------------------------------- quick
def test_heat_bands_split_every_face_once():
    rng = np.random.default_rng(0)
    faces = rng.integers(0, 50, size=(200, 3))
    values = rng.uniform(-1, 12, size=50)
    bands = heat_bands(values, faces, top=10.0, bands=5)
    got = [ids[local] for ids, local in (b for b in bands if b is not None)]
    assert sum(len(g) for g in got) == len(faces)
    assert sorted(map(tuple, np.concatenate(got))) == sorted(map(tuple, faces))
    mean = values[faces].mean(axis=1)                       # a face lands in the band of its mean, clipped
    ids, local = bands[0]
    assert np.all(values[ids[local]].mean(axis=1) < 2.0)
    assert bands[4] is not None and (mean >= 8.0).sum() == len(bands[4][1])


def test_twin_and_toml_round_trip():
    names = {"left_biceps", "right_biceps", "belly_fat", "l_x", "r_x"}
    assert twin("left_biceps", names) == "right_biceps" and twin("r_x", names) == "l_x"
    assert twin("belly_fat", names) is None
    doc = {"name": 'a "b"', "motion": {"file": "/x/y z.toml"},
           "jiggle": {"blend": [[0.0, 0.25], [1.5, 1.0]], "muscles": {"left biceps": {"goal": [0.1, 0.2]},
                                                                     "belly_fat": {"strength": 1e-05}}}}
    assert tomllib.loads(toml_text(doc, "header\nline two")) == doc


def test_tuning_applies_to_the_named_muscles():
    from jiggle.sim.jiggle.params import JiggleSettings, MuscleJiggle, section_goals
    js = [MuscleJiggle(name=n, frequency_hz=4.0, damping_ratio=0.3, goal=section_goals(0.9, 0.4), density=1000.0)
          for n in ("a", "b")]
    out, settings = apply_tuning(js, JiggleSettings(), Tuning().with_muscle("a", strength=0.25, goal_scale=2.0,
                                                                            frequency=6.0).with_blend(0.5))
    assert out[0].strength == 0.25 and out[0].frequency_hz == 6.0
    assert np.array_equal(out[0].goal, np.clip(js[0].goal * 2.0, 0, 1)) and out[1].strength == 1.0
    assert settings.blend.values.tolist() == [0.5] and all(j.blend is None for j in out)
    with pytest.raises(Exception, match="no muscle 'c'"):
        apply_tuning(js, JiggleSettings(), Tuning().with_muscle("c", strength=0.5))


def _old_bake(folder):
    folder.mkdir()
    np.savez(folder / "bake.npz", format=np.array("jiggle.bake/0"), skin=np.zeros((1, 3, 3)))
    return folder


@pytest.mark.parametrize("case, message", [
    ("missing", "no such folder"), ("file", "found a file"), ("empty", "no bake.npz here"),
    ("partial", "unfinished"), ("old", "unsupported format 'jiggle.bake/0'")])
def test_not_a_bake_is_refused(tmp_path, capsys, case, message):
    path = tmp_path / case
    if case == "file":
        path.write_text("x")
    elif case in ("empty", "partial"):
        (path / ".partial").mkdir(parents=True) if case == "partial" else path.mkdir()
    elif case == "old":
        _old_bake(path)
    assert main(["view", str(path), "--port", "0"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith("jiggle: error:") and message in err, err


# ---------------------------------------------------------------------------------------- one bake
@pytest.fixture(scope="module")
def bake_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("view") / "bake"
    code = main(["-q", "demo", "--out", str(out), "--end", "0.4", "--formats", "npz", "--resolution", "3000",
                 "--chunk", "8", "--no-render"])
    assert code == 0
    return out


@pytest.fixture(scope="module")
def viewer(bake_dir):
    from jiggle.sim.app.commands.view import open_viewer
    page = open_viewer(str(bake_dir), port=0, paused=True, tune=True, log=lambda s: None)
    yield page
    page.stop()


def _get(page, path: str) -> tuple[int, bytes]:
    c = http.client.HTTPConnection("127.0.0.1", page.server.get_port(), timeout=10)
    c.putrequest("GET", path, skip_host=False, skip_accept_encoding=True)
    c.endheaders()
    r = c.getresponse()
    return r.status, r.read()


@pytest.mark.slow
def test_serves_only_the_page(viewer, bake_dir):
    assert viewer.server.get_host() == "127.0.0.1"
    status, body = _get(viewer, "/")
    assert status == 200 and b"<html" in body.lower()
    secret = str(bake_dir / "bake.json")
    for path in ("/bake.npz", "/bake.json", "/../bake.json", "/../../../../etc/passwd", "/%2e%2e/%2e%2e/etc/passwd",
                 "/..%2f..%2f..%2fetc%2fpasswd", "/etc/passwd", "//etc/passwd", secret, "/" + secret,
                 "/assets/../../../" + secret):
        status, body = _get(viewer, path)
        assert status == 404, (path, status)
        assert b"root:" not in body and b"jiggle_bake" not in body


@pytest.mark.slow
def test_rebuilt_setup_replays_the_bake(viewer, bake_dir):
    assert viewer.wait_tuner(), viewer.tune_error
    d = read_npz(bake_dir / "bake.npz")
    motion = viewer.tuner.run(Tuning())
    assert np.array_equal(motion.cvs_dynamic, d.muscle_cvs_dynamic)        # bit for bit
    assert np.array_equal(motion.skin_final, d.skin_final)
    assert (d.activation is None) == viewer.g_activation.disabled          # colour by activation: only with it


@pytest.mark.slow
def test_bakers_own_path_replays_the_bake_too(viewer, bake_dir):
    """The path a bake with collisions takes (Baker.chunk itself, no cache) gives the same frames."""
    assert viewer.wait_tuner(), viewer.tune_error
    d = read_npz(bake_dir / "bake.npz")
    setup = viewer.tuner.tuned_setup(Tuning())
    cvs, skin = np.empty_like(d.muscle_cvs_dynamic), np.empty_like(d.skin_final)
    viewer.tuner._run_baker(setup, cvs, skin)
    assert np.array_equal(cvs, d.muscle_cvs_dynamic) and np.array_equal(skin, d.skin_final)


@pytest.mark.slow
def test_ctrl_c_stops_with_130(bake_dir):
    p = subprocess.Popen([sys.executable, "-m", "jiggle", "view", str(bake_dir), "--port", "0", "--no-tune",
                          "--paused"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         env={**os.environ, "PYTHONFAULTHANDLER": "1"},
                         # a suite started as a background job ignores SIGINT, and its children would inherit that
                         preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        lines = []
        while not (lines and lines[-1].startswith("jiggle view: http://127.0.0.1:")):
            line = p.stdout.readline()
            if not line:
                p.wait(timeout=30)
                pytest.fail(f"the viewer ended ({p.returncode}) before serving: {''.join(lines)}{p.stderr.read()}")
            lines.append(line)
        p.send_signal(signal.SIGINT)
        try:
            code = p.wait(timeout=30)
        except subprocess.TimeoutExpired:
            p.send_signal(signal.SIGABRT)              # faulthandler: every thread's stack into stderr
            p.wait(timeout=30)
            pytest.fail(f"the viewer did not stop on Ctrl-C within 30 s:\n{p.stderr.read()[-6000:]}")
        assert code == 130 and "interrupted" in p.stderr.read()
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()


# ---------------------------------------------------------------------------------------- the browser
@pytest.fixture(scope="module")
def browser():
    from browser import headless_chromium
    drv = headless_chromium()
    yield drv
    drv.quit()


def _pixels(drv) -> np.ndarray:
    import imageio.v3 as iio
    return iio.imread(io.BytesIO(drv.get_screenshot_as_png()))[..., :3].astype(np.int16)


def _skin_mask(img: np.ndarray) -> np.ndarray:
    """Pixels of the 3D view (left of the panel, below the notices) that are skin-coloured (warm: red well
    above blue), unlike the white background and the grey grid."""
    h, w = img.shape[:2]
    view = img[int(0.25 * h):, int(0.2 * w):int(0.7 * w)]
    r, b = view[..., 0], view[..., 2]
    return (r - b > 0.4 * (SKIN_COLOUR[0] - SKIN_COLOUR[2])) & (r > 100)


def _until(fn, timeout=BROWSER_TIMEOUT, every=0.5):
    """fn()'s first answer that is not None or False within `timeout` seconds, else None (an element not
    on the page yet counts as None)."""
    from selenium.common.exceptions import NoSuchElementException, StaleElementReferenceException
    end = time.time() + timeout
    while True:
        try:
            got = fn()
        except (NoSuchElementException, StaleElementReferenceException):
            got = None
        if got is not None and got is not False:
            return got
        if time.time() > end:
            return None
        time.sleep(every)


def _number_input(drv, label: str):
    """The number box of the GUI slider labelled `label`."""
    from selenium.webdriver.common.by import By
    xp = (f"//*[normalize-space(text())='{label}']/ancestor::*[.//input[contains(@class,'NumberInput-input')]][1]"
          "//input[contains(@class,'NumberInput-input')]")
    return drv.find_element(By.XPATH, xp)


def _type(el, text: str) -> None:
    from selenium.webdriver.common.keys import Keys
    el.parent.execute_script("arguments[0].scrollIntoView({block: 'center'})", el)   # the panel scrolls
    el.click()
    el.send_keys(Keys.CONTROL, "a")
    el.send_keys(text)
    el.send_keys(Keys.ENTER)


@pytest.mark.slow
def test_page_draws_the_skin_and_scrubbing_changes_it(viewer, browser, bake_dir, tmp_path):
    browser.get(viewer.url)
    first = _until(lambda: img if _skin_mask(img := _pixels(browser)).sum() > 300 else None)
    assert first is not None, "the skin never showed"
    browser.save_screenshot(str(tmp_path / "frame0.png"))
    mask0 = _skin_mask(first)
    assert mask0.sum() > 300                                   # skin-coloured pixels: not the blank background
    last = viewer.pb.T - 1
    _type(_until(lambda: _number_input(browser, "frame")), str(last))
    assert _until(lambda: viewer.frame_shown == last), "the frame box did not reach the server"

    def changed():
        img = _pixels(browser)
        return img if (_skin_mask(img) != mask0).sum() > 100 else None
    later = _until(changed)
    assert later is not None, "scrubbing to the last frame did not change the picture"
    browser.save_screenshot(str(tmp_path / "frame_last.png"))


@pytest.mark.slow
def test_slider_resimulates_and_the_saved_scene_bakes_the_same(viewer, browser, bake_dir, tmp_path):
    from selenium.webdriver.common.by import By
    assert viewer.wait_tuner(), viewer.tune_error
    if browser.current_url != viewer.url:
        browser.get(viewer.url)
    baked = read_npz(bake_dir / "bake.npz")
    name = viewer.g_t_muscle.value
    box = _until(lambda: el if (el := _number_input(browser, "strength")).is_enabled() else None)
    _type(box, "0.5")                                          # the bake's strength is 1 (the demo scene's)
    # the slider's callback has run once the tuning asked for holds the value (the handle's value is set first)
    assert _until(lambda: viewer.tuning.muscles.get(name, {}).get("strength") == 0.5), "the slider did not reach " \
        "the server"
    assert viewer.wait_tuned() and viewer.motion_version > 0, "the slider did not re-simulate"
    assert viewer.tuning.muscles[name]["strength"] == 0.5
    assert np.abs(viewer.pb.skin_final - baked.skin_final).max() > 1e-5      # the motion changed
    for label, value, asked in (("damping ratio", 0.2, lambda: viewer.tuning.muscles[name].get("damping")),
                                ("goal weight scale", 0.8, lambda: viewer.tuning.muscles[name].get("goal_scale")),
                                ("blend (all muscles)", 0.9, lambda: viewer.tuning.blend)):
        _type(_until(lambda label=label: _number_input(browser, label)), str(value))
        assert _until(lambda asked=asked, value=value: asked() == value), f"{label} did not reach the server"
    assert viewer.wait_tuned(), "the last values did not re-simulate"
    assert viewer.tuning.blend == 0.9 and viewer.tuning.muscles[name]["goal_scale"] == 0.8
    assert viewer.tuning.muscles[name]["damping"] == 0.2
    shown = viewer.shown                                        # the motion on the page, tagged with its values
    assert shown.generation == viewer.generation and shown.tuning == viewer.tuning
    assert viewer.pb.skin_final is shown.skin_final and viewer.pb.cvs_dynamic is shown.cvs_dynamic
    scene = tmp_path / "tuned.toml"
    _type(_until(lambda: browser.find_element(By.XPATH, "//*[normalize-space(text())='scene file']"
                                                        "/ancestor::*[.//input][1]//input")), str(scene))
    assert _until(lambda: viewer.g_t_path.value == str(scene))
    save = browser.find_element(By.XPATH, "//button[normalize-space(.)='save scene']")
    browser.execute_script("arguments[0].scrollIntoView({block: 'center'})", save)
    save.click()
    assert _until(lambda: scene.exists() and getattr(viewer, "saved", None)), viewer.g_t_result.content
    _, args = viewer.saved
    assert viewer.saved_motion is shown                         # the scene holds the values of the motion shown
    out = tmp_path / "rebake"
    assert main(["-q", "bake", str(scene), *args, "--out", str(out), "--formats", "npz"]) == 0
    again = read_npz(out / "bake.npz")
    assert np.array_equal(again.skin_final, shown.skin_final)   # bit for bit: the bake of the tuned value
    assert np.array_equal(again.muscle_cvs_dynamic, shown.cvs_dynamic)
    assert viewer.shown is shown and viewer.pb.skin_final is shown.skin_final, "the page re-simulated meanwhile"
    os.remove(scene)


@pytest.mark.slow
def test_slider_moves_at_once_all_reach_the_motion_shown_and_the_saved_scene(viewer, bake_dir, tmp_path,
                                                                            monkeypatch):
    """viser runs each GUI callback in a pool of threads, several at once and in any order, each reading its
    slider when it runs. Moves of several sliders sent together (each box typed key by key: "0", then the
    value), while building a tuning is slow (a thread preempted mid-edit), all reach the tuning asked for,
    the motion then shown is that tuning's and tagged with it, and no run is left over; "save scene" asked
    while a run is pending waits for it and writes the values of the motion shown."""
    import random
    from concurrent.futures import ThreadPoolExecutor

    from jiggle.sim.app.view.page import ViewerPage
    from jiggle.sim.app.view.playback import Playback, open_bake
    assert viewer.wait_tuner(), viewer.tune_error
    page = ViewerPage(Playback(*open_bake(str(bake_dir))), str(bake_dir), port=0, paused=True,
                      tuner_factory=lambda: viewer.tuner, formats=("npz",))    # the module's rebuilt setup
    try:
        assert page.wait_tuner(), page.tune_error
        name = page.g_t_muscle.value
        slow_muscle, slow_blend = Tuning.with_muscle, Tuning.with_blend
        monkeypatch.setattr(Tuning, "with_muscle", lambda self, *a, **k: (time.sleep(random.uniform(0, 0.004)),
                                                                          slow_muscle(self, *a, **k))[1])
        monkeypatch.setattr(Tuning, "with_blend", lambda self, v: (time.sleep(random.uniform(0, 0.004)),
                                                                   slow_blend(self, v))[1])
        random.seed(0)
        pool = ThreadPoolExecutor(max_workers=32)

        def browser_sends(handle, value):               # as viser's event loop: the value set, then the callbacks
            handle._impl.value = value
            for cb in handle._impl.update_cb:
                pool.submit(cb, None)
        moves = ((page.g_t_strength, "strength", 0.7), (page.g_t_damping, "damping", 0.25),
                 (page.g_t_goal, "goal_scale", 0.6), (page.g_t_blend, None, 0.85))
        for handle, _, value in moves:
            browser_sends(handle, 0.0)
            browser_sends(handle, value)
        pool.shutdown(wait=True)
        assert page.wait_tuned(), "the last values did not re-simulate"
        knobs = page.tuning.muscles[name]
        assert [knobs.get(k) if k else page.tuning.blend for _, k, _ in moves] == [v for *_, v in moves]
        shown = page.shown
        assert shown.generation == page.generation and shown.tuning == page.tuning
        assert page.pb.skin_final is shown.skin_final
        motion = page.tuner.run(page.tuning)
        assert np.array_equal(motion.skin_final, shown.skin_final)
        assert np.array_equal(motion.cvs_dynamic, shown.cvs_dynamic)

        page.g_t_damping.value = 0.4                    # as the browser would, and "save scene" at once
        scene = tmp_path / "pending.toml"
        page.g_t_path.value = str(scene)
        page._save()
        assert page.saved_motion is page.shown and page.shown.generation == page.generation, page.g_t_result.content
        assert page.saved_motion.tuning.muscles[name]["damping"] == 0.4
        assert tomllib.loads(scene.read_text())["jiggle"]["muscles"][name]["damping"] == 0.4
    finally:
        page.stop()


@pytest.mark.slow
def test_a_bake_with_keyed_parameters_plays_but_is_not_tuned(tmp_path):
    """A slider sets one number per muscle: a bake whose strength is keyed over time plays, and the Tune
    panel says why it is off, rather than flattening the keys."""
    import json

    from jiggle.sim.app.view.tuning import NotTunable, Tuner
    out = tmp_path / "keyed"
    assert main(["-q", "demo", "--out", str(out), "--end", "0.3", "--formats", "npz", "--resolution", "3000",
                 "--no-render", "--strength", "belly_fat=[[0, 1], [0.2, 0.3]]"]) == 0
    with pytest.raises(NotTunable, match="keys jiggle parameters over time \\(belly_fat\\)"):
        Tuner(json.loads((out / "bake.json").read_text()))


@pytest.mark.slow
def test_the_painted_jiggle_map_is_shown_on_the_skin(tmp_path):
    """A character with a painted jiggle map (a sidecar beside it): once the setup is rebuilt, the page
    offers the map, and with it on the skin is drawn in bands of the map's values."""
    import shutil

    from conftest import asset

    from jiggle.rig.character.load import load_character
    from jiggle.rig.character.painted_maps import PaintedMaps, save_maps
    from jiggle.sim.app.commands.view import open_viewer
    glb = tmp_path / "hero.glb"
    shutil.copy(asset("characters/CesiumMan.glb"), glb)
    V = load_character(str(glb)).num_vertices
    painted = np.linspace(0.0, 1.0, V).astype(np.float32)               # every band has vertices
    save_maps(tmp_path / "hero.jiggle_map.npz", PaintedMaps(jiggle=painted), V)
    out = tmp_path / "bake"
    assert main(["-q", "bake", "--character", str(glb), "--clip", str(asset("mocap/cmu_bvh/02_03.bvh")),
                 "--out", str(out), "--end", "0.3", "--formats", "npz"]) == 0
    page = open_viewer(str(out), port=0, paused=True, tune=True, log=lambda s: None)
    try:
        assert page.wait_tuner(), page.tune_error
        assert np.array_equal(page.jiggle_map, painted) and not page.g_map.disabled
        assert "painted jiggle map" in page.g_map_note.content
        page.g_map.value = True
        page.draw(3)
        assert sum(h is not None for h in page._map_handles) >= 8 and not page.h_dynamic.visible
        page.g_map.value = False
        page.draw(3)
        assert page.h_dynamic.visible and all(h is None or not h.visible for h in page._map_handles)
    finally:
        page.stop()


@pytest.mark.slow
def test_an_activation_bake_colours_its_muscles_and_tunes_as_jiggle_bake_does(tmp_path):
    """--activation on: the page colours the muscles by activation (a working quadriceps red at the landing, the fat
    its own colour; a bake without activation offers no such colouring), the viewer replays the bake bit for bit,
    and a tuned frequency is the bake of its saved scene (the stiffening applied again over the tuned springs)."""
    import json

    from conftest import asset

    from jiggle.sim.app.view.page import MUSCLE_COLOUR, RELAXED_COLOUR, ViewerPage
    from jiggle.sim.app.view.playback import Playback, open_bake
    from jiggle.sim.app.view.scene_file import save_tuned_scene
    from jiggle.sim.app.view.tuning import Tuner
    out = tmp_path / "bake"
    args = ["--clip", str(asset("mocap/cmu_bvh/02_04.bvh")), "--start", "1.2", "--end", "1.8", "--formats", "npz",
            "--resolution", "3000", "--activation", "on"]
    assert main(["-q", "bake", *args, "--out", str(out)]) == 0
    baked = read_npz(out / "bake.npz")
    t = Tuner(json.loads((out / "bake.json").read_text()), baked.muscle_cvs_static)
    motion = t.run(Tuning())
    assert np.array_equal(motion.skin_final, baked.skin_final) and np.array_equal(motion.cvs_dynamic,
                                                                                 baked.muscle_cvs_dynamic)
    names = list(baked.muscle_names)
    q = names.index("left_quadriceps")
    assert isinstance(t.jiggles[q].frequency_hz, float)          # the sliders' springs: before the stiffening
    tuning = Tuning().with_muscle("left_quadriceps", frequency=9.0)
    tuned = t.run(tuning)
    scene = tmp_path / "tuned.toml"
    extra = save_tuned_scene(t, tuning, str(scene), ("npz",))
    assert "--activation" in extra and tomllib.loads(scene.read_text())["jiggle"]["muscles"]["left_quadriceps"][
        "frequency"] == 9.0
    again = tmp_path / "rebake"
    assert main(["-q", "bake", str(scene), *extra, "--out", str(again), "--formats", "npz"]) == 0
    assert np.array_equal(read_npz(again / "bake.npz").skin_final, tuned.skin_final)
    page = ViewerPage(Playback(*open_bake(str(out))), str(out), port=0, paused=True, tuner_factory=lambda: t,
                      formats=("npz",))
    try:
        assert not page.g_activation.disabled
        page.g_muscles.value = True
        page.g_activation.value = True
        k = int(np.argmax(baked.activation[:, q]))
        page.draw(k)
        colours = page.muscle_colours(k)
        assert colours[q][0] > 150 and colours[q][2] < RELAXED_COLOUR[2] and page._muscle_colour[q] == colours[q]
        fat = [m for m, info in enumerate(page.pb.muscles) if info.kind == "fat"]
        assert fat and all(colours[m] == MUSCLE_COLOUR["fat"] for m in fat)
        page.g_activation.value = False
        page.draw(k)
        assert page._muscle_colour[q] == MUSCLE_COLOUR["muscle"]
    finally:
        page.stop()
