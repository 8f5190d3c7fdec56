"""The swung chains in every file a bake writes: the npz's chain arrays agree with each other and with the skin, the
pc2 and USD carry the swung skin, and the glb carries the chains on their own bones, checked by the Khronos
glTF-Validator and played by three.js (the shared Horse on its Gallop: a tail and two ears)."""
from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest
from conftest import asset

from jiggle.sim.app.cli import main
from jiggle.sim.bake.caches import read_npz, read_pc2

pytestmark = pytest.mark.slow
JS = Path(__file__).resolve().parents[1] / "js"


@pytest.fixture(scope="module")
def baked(tmp_path_factory):
    out = tmp_path_factory.mktemp("horse")
    code = main(["-q", "bake", "--character", str(asset("characters/zoo/Horse.glb")), "--animation", "Gallop",
                 "--out", str(out), "--formats", "glb,pc2,usda"])
    assert code == 0
    return out


def test_the_npz_holds_the_swing_and_the_skin_follows_it(baked):
    from jiggle.rig.character.load import load_character
    from jiggle.rig.skin.chain_skin import ChainSkin
    d = read_npz(baked / "bake.npz")
    summary = json.loads((baked / "bake.json").read_text())
    assert d.chain_tip_names == ("Ear1.L", "Ear1.R", "Tail1")
    assert [c["chain"] for c in summary["chains"]["chains"]] == list(d.chain_tip_names)
    # chain_delta is linear skinning's own answer for the swung joints: recomputed from chain_world
    c = load_character(str(asset("characters/zoo/Horse.glb")))
    idx = [c.joint_names.index(n) for n in d.chain_names]
    skin = ChainSkin(c, idx)
    static = np.tile(np.asarray(c.bind_world)[None], (len(d.times), 1, 1, 1))
    names = list(d.joint_names)
    static[:, [c.joint_names.index(n) for n in names if n in c.joint_names]] = \
        np.asarray(d.joint_world, np.float64)[:, [k for k, n in enumerate(names) if n in c.joint_names]]
    swung = static.copy()
    swung[:, idx] = d.chain_world
    assert np.array_equal(np.sort(skin.vertices), np.sort(d.chain_vertices))
    assert np.abs(skin.delta(static, swung) - d.chain_delta).max() < 2e-4
    # the tips: swung beyond the animation, by what bake.json says
    peak = np.linalg.norm(d.chain_tips_final - d.chain_tips_static, axis=2).max(axis=0)
    assert np.allclose(peak, [c["tip_peak_m"] for c in summary["chains"]["chains"]], rtol=1e-3, atol=1e-5)
    # the pc2 is skin_final, the swing in it
    pc2 = read_pc2(baked / "bake.pc2").points
    assert np.array_equal(pc2, d.skin_final)
    tail = d.chain_vertices[np.linalg.norm(d.chain_delta, axis=2).max(axis=0) > 0.05]
    assert len(tail) > 50 and np.linalg.norm(pc2[:, tail] - d.skin_static[:, tail], axis=2).max() > 0.3
    # the USD's final skin too, at the frames' time codes
    from pxr import Usd, UsdGeom
    stage = Usd.Stage.Open(str(baked / "bake.usda"))
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/jiggle/skin_final"))
    codes = mesh.GetPointsAttr().GetTimeSamples()
    assert len(codes) == len(d.times)
    for k in (0, len(codes) // 2, len(codes) - 1):
        assert np.allclose(np.array(mesh.GetPointsAttr().Get(codes[k])), d.skin_final[k], atol=1e-6)


def node():
    import shutil
    if shutil.which("node") is None:
        pytest.skip("Node.js not found (./dev.sh installs nodejs and npm; JIGGLE_JS=0 leaves them out)")
    if not (JS / "node_modules" / "three").is_dir() or not (JS / "node_modules" / "gltf-validator").is_dir():
        pytest.skip("tests/js/node_modules lacks three or gltf-validator (./dev.sh install runs npm ci there)")


def test_the_glb_passes_the_khronos_validator(baked):
    node()
    r = subprocess.run(["node", str(JS / "validate_glb.mjs"), str(baked / "bake.glb")], capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    issues = json.loads(r.stdout)["issues"]
    assert issues["numErrors"] == 0 and issues["numWarnings"] == 0, issues["messages"][:5]


def test_threejs_plays_the_chains_on_their_bones(baked, tmp_path):
    """three.js plays the glb: its skin is the bake's skin_final (RMS 3 mm, p99 15 mm at the Horse's 5.7 m; the
    bake's own figures for the file), and the tail's skin swings as the bake swung it, far from plain skinning."""
    node()
    d = read_npz(baked / "bake.npz")
    frames = [0, len(d.times) // 3, 2 * len(d.times) // 3, len(d.times) - 1]
    out = tmp_path / "three.json"
    r = subprocess.run(["node", str(JS / "play_glb.mjs"), str(baked / "bake.glb"),
                        json.dumps([float(d.times[f] - d.times[0]) for f in frames]), str(out)],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    res = json.loads(out.read_text())
    moved = d.chain_vertices[np.linalg.norm(d.chain_delta, axis=2).max(axis=0) > 0.05]
    for k, f in enumerate(frames):
        v = np.asarray(res["frames"][k], np.float64).reshape(-1, 3)
        played = np.column_stack([v[:, 0], -v[:, 2], v[:, 1]])          # glTF's Y-up -> jiggle's Z-up
        err = np.linalg.norm(played - d.skin_final[f], axis=1) * 1000
        assert np.sqrt((err ** 2).mean()) <= 3.5 and np.percentile(err, 99) <= 16.0, (f, err.mean())
        # on the swung tail and ears: the played skin follows the swing (well within the swing's size)
        swing = np.linalg.norm(d.chain_delta[f], axis=1)
        big = swing > 0.05
        if big.any():
            e = np.linalg.norm(played[d.chain_vertices[big]] - d.skin_final[f, d.chain_vertices[big]], axis=1)
            assert np.median(e) < 0.1 * np.median(swing[big]), (f, np.median(e), np.median(swing[big]))
    assert len(moved) > 50
