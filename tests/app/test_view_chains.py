"""`jiggle view` on bakes with chains (sim/chain: tails, ears, wing fingers that swing): the setup rebuilds from
bake.json with the bake's key (the glTF animation it read, its loop, its chains' mode and the values set per chain);
the re-simulation of the untouched values replays the bake's final skin, chains included, bit for bit; a chain
knob tuned in the viewer (the Tuner, or the page's chain sliders) equals `jiggle bake --chain-KNOB NAME=V` bit for
bit, and the scene "save scene" writes bakes to exactly that motion.

Two characters of the shared zoo: the Goleling (2,250 vertices, two wing chains; its second animation, a looping
cycle, baked without collisions: the Tuner's cached path) and the Horse's Gallop (a tail and two ears, with
collisions: Baker's own path) that `jiggle bake --character Horse.glb --animation Gallop` bakes."""
from __future__ import annotations

import json
import tomllib
from types import SimpleNamespace

import numpy as np
import pytest
from conftest import asset

from jiggle.rig.base.errors import InputError
from jiggle.sim.app.cli import main
from jiggle.sim.app.view.page import chain_twin
from jiggle.sim.app.view.tuning import Tuning, chain_entries
from jiggle.sim.bake.caches import read_npz


# ---------------------------------------------------------------------------------------- quick
def test_chain_twins():
    names = {"Ear1.L", "Ear1.R", "Tail1", "Wing_l", "Wing_r", "LeftEar", "RightEar", "left_ear", "right_ear"}
    assert chain_twin("Ear1.L", names) == "Ear1.R" and chain_twin("Ear1.R", names) == "Ear1.L"
    assert chain_twin("Wing_r", names) == "Wing_l" and chain_twin("LeftEar", names) == "RightEar"
    assert chain_twin("left_ear", names) == "right_ear" and chain_twin("Tail1", names) is None


def test_chain_entries_are_the_bakes_values_then_the_tuned_ones():
    """A chain's values the user set come back by exact name (a Curve as it is), the tuned ones after them (an
    exact name: the later entry wins); an unknown chain or knob, a keyed knob or a value out of range is refused."""
    from jiggle.sim.chain.params import ChainParams
    from jiggle.sim.jiggle.keyed import parse_curve
    from jiggle.sim.chain.params import CHAIN_PARAMETERS
    curve = parse_curve([[0.0, 4.0], [0.2, 8.0]], "stiffness", table=CHAIN_PARAMETERS)
    chains = SimpleNamespace(chains=SimpleNamespace(names=["Tail1", "Ear1.L"]), params=(
        ChainParams(stiffness=curve, damping=0.5, gravity=1.0, drag=1.0, given=("damping", "stiffness")),
        ChainParams(stiffness=9.0, damping=0.35, gravity=1.0, drag=1.0)))
    assert chain_entries(chains, Tuning()) == [("Tail1", {"damping": 0.5, "stiffness": curve}, "the bake's Tail1")]
    got = chain_entries(chains, Tuning().with_chain("Ear1.L", damping=0.6).with_chain("Ear1.L", gravity=2.0))
    assert got[-1] == ("Ear1.L", {"damping": 0.6, "gravity": 2.0}, "tuned Ear1.L")
    assert chain_entries(chains, Tuning().with_chain("Tail1", damping=0.7))[-1][1] == {"damping": 0.7}
    for tuning, message in ((Tuning().with_chain("Tail9", damping=0.5), "no chain 'Tail9'"),
                            (Tuning().with_chain("Tail1", spring=0.5), "unknown chain knob spring"),
                            (Tuning().with_chain("Tail1", stiffness=5.0), "keys stiffness of chain 'Tail1'"),
                            (Tuning().with_chain("Ear1.L", damping=9.0), r"damping must be in \[0, 5\]")):
        with pytest.raises(InputError, match=message):
            chain_entries(chains, tuning)


# ---------------------------------------------------------------------------------------- the Goleling
def _bake(out, character, *args) -> None:
    assert main(["-q", "bake", "--character", str(asset(f"characters/zoo/{character}.glb")), "--out", str(out),
                 "--formats", "npz", *args]) == 0


def _tuner(folder):
    from jiggle.sim.app.view.tuning import Tuner
    summary = json.loads((folder / "bake.json").read_text())
    return Tuner(summary, read_npz(folder / "bake.npz").muscle_cvs_static)


GOLELING = ("Goleling", "--animation", "Fast_Flying", "--no-collisions")


@pytest.fixture(scope="module")
def goleling(tmp_path_factory):
    out = tmp_path_factory.mktemp("view_chains") / "goleling"
    _bake(out, *GOLELING)
    return out


@pytest.fixture(scope="module")
def goleling_damped(tmp_path_factory):
    """The same bake with `--chain-damping Wing1.L=0.6`."""
    out = tmp_path_factory.mktemp("view_chains") / "goleling_damped"
    _bake(out, *GOLELING, "--chain-damping", "Wing1.L=0.6")
    return out


@pytest.fixture(scope="module")
def goleling_tuner(goleling):
    return _tuner(goleling)


@pytest.mark.slow
def test_a_chain_bake_rebuilds_with_its_key_and_replays(goleling, goleling_tuner):
    """Its second animation (bake.json does not name it: the one of the clip's duration whose key is the bake's), a
    looping cycle (the particles go on from the warm-up's state) and two swinging wings: the rebuilt key is the
    bake's, and the untouched values replay the final skin, the chains' swing included, bit for bit."""
    t = goleling_tuner
    summary = json.loads((goleling / "bake.json").read_text())
    assert t.setup.key == summary["key"] and t.request.animation == "Fast_Flying"
    assert t.setup.loop is not None and list(t.setup.chains.chains.names) == ["Wing1.L", "Wing1.R"]
    assert t.tuned_chains(Tuning()) is t.setup.chains
    baked = read_npz(goleling / "bake.npz")
    motion = t.run(Tuning())
    assert np.array_equal(motion.cvs_dynamic, baked.muscle_cvs_dynamic)
    assert np.array_equal(motion.skin_final, baked.skin_final)
    swing = t.chain_swing(t.tuned_setup(Tuning()))
    assert swing is t.chain_swing(t.tuned_setup(Tuning().with_muscle(t.jiggles[0].name, strength=0.5)))  # swung once
    moved = np.abs(baked.chain_delta).max()
    assert moved > 1e-3                                       # the wings swing the skin (metres)


@pytest.mark.slow
def test_a_tuned_chain_damping_is_the_bake_of_it_and_its_saved_scene_bakes_it(goleling_tuner, goleling_damped,
                                                                               tmp_path):
    from jiggle.sim.app.view.scene_file import save_tuned_scene
    t = goleling_tuner
    tuning = Tuning().with_chain("Wing1.L", damping=0.6)
    motion = t.run(tuning)
    ref = read_npz(goleling_damped / "bake.npz")
    assert np.array_equal(motion.skin_final, ref.skin_final)            # bit for bit: --chain-damping Wing1.L=0.6
    assert np.array_equal(motion.cvs_dynamic, ref.muscle_cvs_dynamic)
    assert t.tuned_chains(tuning) is t.tuned_chains(Tuning().with_chain("Wing1.L", damping=0.6))     # cached
    assert t.tuned_chains(Tuning().with_chain("Wing1.L", damping=0.35)) is t.setup.chains   # the bake's value
    scene = tmp_path / "tuned.toml"
    args = save_tuned_scene(t, tuning, str(scene), ("npz",))
    doc = tomllib.loads(scene.read_text())
    assert doc["chains"] == {"Wing1.L": {"damping": 0.6}} and doc["motion"]["animation"] == "Fast_Flying"
    out = tmp_path / "rebake"
    assert main(["-q", "bake", str(scene), *args, "--out", str(out), "--formats", "npz"]) == 0
    again = read_npz(out / "bake.npz")
    assert np.array_equal(again.skin_final, motion.skin_final)           # bit for bit: the viewer's motion
    assert np.array_equal(again.chain_delta, ref.chain_delta)


@pytest.mark.slow
def test_the_chain_sliders_tune_the_chosen_chain(goleling, goleling_tuner, goleling_damped, tmp_path):
    """The page's chain sliders: they show the chosen chain's bake values; a move (as the browser sends it: the value
    set, then the callbacks) asks for the chain's knob, with "both sides" its twin's too; the motion shown is then
    the bake of those values, and "save scene" writes them."""
    from jiggle.sim.app.view.page import ViewerPage
    from jiggle.sim.app.view.playback import Playback, open_bake
    t = goleling_tuner
    page = ViewerPage(Playback(*open_bake(str(goleling))), str(goleling), port=0, paused=True,
                      tuner_factory=lambda: t, formats=("npz",))
    try:
        assert page.wait_tuner(), page.tune_error
        assert tuple(page.g_c_chain.options) == ("Wing1.L", "Wing1.R") and not page.g_c_chain.disabled
        base = t.setup.chains.params[0]
        knobs = page.g_c_knobs
        assert knobs["damping"].value == base.damping and knobs["stiffness"].value == base.stiffness
        assert not any(h.disabled for h in knobs.values())

        def browser_sends(handle, value):
            handle._impl.value = value
            for cb in handle._impl.update_cb:
                cb(None)
        page.g_t_both.value = False
        page.g_c_chain.value = "Wing1.L"
        browser_sends(knobs["damping"], 0.6)
        assert page.tuning.chains == {"Wing1.L": {"damping": 0.6}} and page.tuning.muscles == {}
        assert page.wait_tuned(120), page.g_tune_status.content
        ref = read_npz(goleling_damped / "bake.npz")
        assert np.array_equal(page.shown.skin_final, ref.skin_final)
        page.g_c_chain.value = "Wing1.R"                     # the other wing's own values
        assert knobs["damping"].value == base.damping and page.tuning.chains == {"Wing1.L": {"damping": 0.6}}
        page.g_t_both.value = True
        browser_sends(knobs["gravity"], 0.5)
        assert page.tuning.chains == {"Wing1.L": {"damping": 0.6, "gravity": 0.5}, "Wing1.R": {"gravity": 0.5}}
        assert page.wait_tuned(120), page.g_tune_status.content
        scene = tmp_path / "page.toml"
        page.g_t_path.value = str(scene)
        page._save()
        assert page.saved_motion is page.shown, page.g_t_result.content
        assert tomllib.loads(scene.read_text())["chains"] == {"Wing1.L": {"damping": 0.6, "gravity": 0.5},
                                                              "Wing1.R": {"gravity": 0.5}}
        page._reset()
        assert page.tuning == Tuning() and knobs["gravity"].value == base.gravity
    finally:
        page.stop()


# ---------------------------------------------------------------------------------------- the Horse's Gallop
HORSE = ("Horse", "--animation", "Gallop")


@pytest.fixture(scope="module")
def horse(tmp_path_factory):
    out = tmp_path_factory.mktemp("view_chains") / "horse"
    _bake(out, *HORSE)
    return out


@pytest.fixture(scope="module")
def horse_ears(tmp_path_factory):
    """The Gallop with `--chain-damping "Ear*=0.6"` (a glob: bake.json records the value per chain)."""
    out = tmp_path_factory.mktemp("view_chains") / "horse_ears"
    _bake(out, *HORSE, "--chain-damping", "Ear*=0.6")
    return out


@pytest.fixture(scope="module")
def horse_tuner(horse):
    return _tuner(horse)


@pytest.mark.slow
def test_the_horse_gallop_rebuilds_and_replays(horse, horse_tuner):
    t = horse_tuner
    assert t.setup.key == json.loads((horse / "bake.json").read_text())["key"]
    assert t.request.animation == "Gallop" and t.setup.settings.collisions      # Baker's own path
    motion = t.run(Tuning())
    baked = read_npz(horse / "bake.npz")
    assert np.array_equal(motion.skin_final, baked.skin_final) and np.array_equal(motion.cvs_dynamic,
                                                                                  baked.muscle_cvs_dynamic)


@pytest.mark.slow
def test_a_bake_with_chain_values_set_rebuilds_with_its_key(horse_ears):
    t = _tuner(horse_ears)
    assert t.setup.key == json.loads((horse_ears / "bake.json").read_text())["key"]
    assert {n: dict(table) for n, table, _ in t.request.chain_params} == {"Ear1.L": {"damping": 0.6},
                                                                         "Ear1.R": {"damping": 0.6}}


@pytest.mark.slow
def test_the_horses_ears_tuned_are_the_bake_of_them(horse_tuner, horse_ears, horse):
    motion = horse_tuner.run(Tuning().with_chain("Ear1.L", damping=0.6).with_chain("Ear1.R", damping=0.6))
    ref = read_npz(horse_ears / "bake.npz")
    assert np.array_equal(motion.skin_final, ref.skin_final) and np.array_equal(motion.cvs_dynamic,
                                                                                ref.muscle_cvs_dynamic)
    assert not np.array_equal(motion.skin_final, read_npz(horse / "bake.npz").skin_final)


@pytest.mark.slow
def test_a_chain_knob_keyed_in_the_bake_is_kept(tmp_path):
    """A chain whose stiffness the bake keys over time: the page shows that slider off (a slider sets a constant),
    the other knobs tune, and the saved scene keeps the keys (and bakes to the motion shown)."""
    from jiggle.sim.app.view.page import ViewerPage
    from jiggle.sim.app.view.playback import Playback, open_bake
    out = tmp_path / "keyed"
    _bake(out, *GOLELING, "--chain-stiffness", "Wing1.L=[[0, 10], [0.5, 20]]")
    t = _tuner(out)
    assert t.request.chain_params[0][0] == "Wing1.L"
    page = ViewerPage(Playback(*open_bake(str(out))), str(out), port=0, paused=True, tuner_factory=lambda: t,
                      formats=("npz",))
    try:
        assert page.wait_tuner(), page.tune_error
        page.g_t_both.value = False
        page.g_c_chain.value = "Wing1.L"
        knobs = page.g_c_knobs
        assert knobs["stiffness"].disabled and not knobs["damping"].disabled and "keyed" in page.g_c_note.content
        page.g_c_chain.value = "Wing1.R"
        assert not knobs["stiffness"].disabled
        page.g_c_chain.value = "Wing1.L"
        knobs["drag"]._impl.value = 5.0
        for cb in knobs["drag"]._impl.update_cb:
            cb(None)
        assert page.tuning.chains == {"Wing1.L": {"drag": 5.0}} and page.wait_tuned(120), page.g_tune_status.content
        scene = tmp_path / "keyed.toml"
        page.g_t_path.value = str(scene)
        page._save()
        assert page.saved_motion is page.shown, page.g_t_result.content
        assert tomllib.loads(scene.read_text())["chains"] == {"Wing1.L": {"drag": 5.0,
                                                                          "stiffness": [[0.0, 10.0], [0.5, 20.0]]}}
        again = tmp_path / "rebake"
        assert main(["-q", "bake", str(scene), *page.saved[1], "--out", str(again), "--formats", "npz"]) == 0
        assert np.array_equal(read_npz(again / "bake.npz").skin_final, page.shown.skin_final)
    finally:
        page.stop()
