"""The public Python API (jiggle/api.py): a bake through `jiggle.bake` is the command's bake bit for bit; mistakes
are InputError with the command's message; a Bake reads its folder read-only and exports; the stages one at a
time (load_character, load_clip, fit, simulate) give the same skin as the bake; the package installs as the one
name `jiggle` with its console script."""
from __future__ import annotations

import gc
import json
import os
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

import jiggle

ROOT = Path(__file__).resolve().parents[1]
ASSETS = Path(os.environ.get("JIGGLE_ASSETS", ROOT.parent / "shared" / "assets"))
CESIUM = ASSETS / "characters" / "CesiumMan.glb"
CLIP = ASSETS / "mocap" / "cmu_bvh" / "02_04.bvh"
FRAMES = 24


def need_assets():
    if not (CESIUM.is_file() and CLIP.is_file()):
        pytest.skip(f"the shared assets are not at {ASSETS} (CesiumMan.glb, cmu_bvh/02_04.bvh)")


def cli(*argv, check=True):
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    r = subprocess.run([sys.executable, "-m", "jiggle", *map(str, argv)], capture_output=True, text=True, env=env)
    if check and r.returncode != 0:
        raise AssertionError(r.stderr)
    return r


@pytest.fixture(scope="module")
def both(tmp_path_factory):
    """CesiumMan on 02_04, the first 24 frames, a per-muscle strength and a global blend: through the command
    line and through the API."""
    need_assets()
    tmp = tmp_path_factory.mktemp("api")
    cli("bake", "--clip", CLIP, "--character", CESIUM, "--frames", FRAMES, "--strength", "belly_fat=0.8",
        "--blend", "0.7", "--formats", "npz,pc2", "--out", tmp / "cli", "-q")
    bake = jiggle.bake(CLIP, CESIUM, frames=FRAMES, muscles={"belly_fat": {"strength": 0.8}}, blend=0.7,
                       formats=["pc2"], out=tmp / "api", progress=False)
    return tmp / "cli", bake


def test_a_bake_through_python_is_the_commands_bit_for_bit(both):
    folder, bake = both
    with np.load(folder / "bake.npz") as z:
        assert set(bake.ARRAYS) <= set(z.files) | {"skin_rest", "activation"}     # optional ones
        for k in bake.ARRAYS:
            if k in z.files:
                assert np.array_equal(z[k], getattr(bake, k)), k
    ours = json.loads((folder / "bake.json").read_text())
    assert ours["key"] == bake.summary["key"] and ours["params"] == bake.params
    assert (folder / "bake.pc2").read_bytes() == (bake.folder / "bake.pc2").read_bytes()


def test_a_bake_is_read_only_and_exports(both, tmp_path):
    _, bake = both
    assert bake.skin_final.shape == (FRAMES, bake.summary["vertices"], 3) and bake.skin_final.dtype == np.float32
    with pytest.raises(ValueError):
        bake.skin_final[0, 0, 0] = 1.0
    belly = bake.muscle("belly_fat")
    assert belly.shape[0] == FRAMES and np.abs(belly - bake.muscle("belly_fat", "static")).max() > 1e-4
    with pytest.raises(jiggle.InputError, match="no muscle 'tail'"):
        bake.muscle("tail")
    pc2 = bake.to_pc2(tmp_path / "x.pc2")
    from jiggle.sim.bake.caches import read_pc2
    assert np.array_equal(read_pc2(pc2).points, bake.skin_final)
    usd = bake.to_usd(tmp_path / "x.usda")
    from pxr import Usd, UsdGeom
    stage = Usd.Stage.Open(str(usd))
    pts = UsdGeom.Mesh(stage.GetPrimAtPath("/jiggle/skin_final")).GetPointsAttr().Get(3)
    assert np.allclose(np.asarray(pts), bake.skin_final[3])
    with pytest.raises(jiggle.InputError, match="ending in .glb"):
        bake.to_glb(tmp_path / "x.gltf")


def test_mistakes_are_input_errors_with_the_commands_message(tmp_path):
    with pytest.raises(jiggle.InputError) as e:
        jiggle.bake(fps=-1, out=tmp_path / "a", progress=False)
    r = cli("bake", "--fps", "-1", "--out", tmp_path / "b", check=False)
    assert r.returncode == 2 and f"jiggle: error: {e.value}" in r.stderr
    missing = tmp_path / "nowhere.bvh"
    with pytest.raises(jiggle.InputError) as e:
        jiggle.bake(missing, out=tmp_path / "c", progress=False)
    r = cli("bake", "--clip", missing, "--out", tmp_path / "d", check=False)
    assert r.returncode == 2 and str(missing) in str(e.value) and f"jiggle: error: {e.value}" in r.stderr
    with pytest.raises(jiggle.InputError, match="unknown parameter 'stiffness'; a muscle takes blend, damping"):
        jiggle.bake(muscles={"belly_fat": {"stiffness": 2}}, progress=False)
    with pytest.raises(TypeError, match="unexpected keyword argument 'speed'"):
        jiggle.bake(speed=2)
    with pytest.raises(jiggle.InputError, match="no bake.json"):
        jiggle.Bake.open(tmp_path)
    assert not (tmp_path / "a" / "bake.json").exists()


def test_a_bake_without_out_lives_as_long_as_its_object():
    bake = jiggle.bake(frames=3, progress=False)
    folder = bake.folder
    assert (folder / "bake.npz").is_file() and len(bake.times) == 3
    del bake
    gc.collect()
    assert not folder.exists()


def test_the_stages_one_at_a_time_give_the_bakes_skin(both):
    _, bake = both
    character = jiggle.load_character(CESIUM)
    clip = jiggle.load_clip(CLIP)
    muscles = jiggle.fit(character)
    assert isinstance(character, jiggle.Character) and isinstance(muscles, jiggle.Muscles)
    assert muscles.rig.M == len(bake.muscle_names)
    sim = jiggle.simulate(clip, character, muscles, frames=FRAMES, blend=0.7)
    assert sim.skin_final.shape == bake.skin_final.shape and not sim.skin_final.flags.writeable
    assert np.array_equal(sim.skin_static, bake.skin_static)
    # the bake has belly_fat at strength 0.8: everything else moves as this one does
    far = np.abs(sim.skin_final - bake.skin_final).max(axis=(0, 2))
    assert far.max() > 0 and np.median(far) < 1e-6


def test_the_version_is_in_one_place():
    r = cli("--version")
    assert r.stdout.strip() == f"jiggle {jiggle.__version__}"
    assert "dynamic" in (ROOT / "pyproject.toml").read_text() and jiggle.__version__.count(".") == 2


def test_the_package_installs_as_one_name_with_its_script(tmp_path):
    """The wheel holds `jiggle` alone (rig, sim and scenes under it, their data too), and its entry point."""
    r = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(tmp_path), str(ROOT)],
                       capture_output=True, text=True)
    if r.returncode != 0 and "satisfies the requirement setuptools" in r.stderr:
        pytest.skip("pip cannot fetch setuptools to build the wheel (no package index here)")
    assert r.returncode == 0, r.stderr
    wheel = next(tmp_path.glob("jiggle-*.whl"))
    names = zipfile.ZipFile(wheel).namelist()
    tops = {n.split("/")[0] for n in names}
    assert tops == {"jiggle", f"jiggle-{jiggle.__version__}.dist-info"}, tops
    for must in ("jiggle/api.py", "jiggle/rig/skin/jiggle_bones.py", "jiggle/sim/app/cli.py", "jiggle/scenes/default.toml",
                 "jiggle/rig/muscle/templates/human.toml"):
        assert must in names, must
    meta = zipfile.ZipFile(wheel).read(f"jiggle-{jiggle.__version__}.dist-info/entry_points.txt").decode()
    assert "jiggle = jiggle.sim.app.cli:main" in meta
    top_level = zipfile.ZipFile(wheel).read(f"jiggle-{jiggle.__version__}.dist-info/top_level.txt").decode().split()
    assert top_level == ["jiggle"]
