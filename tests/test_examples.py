"""The runnable examples of examples/ (the documentation's code) run, each as a user runs it, and make what they
say: the five-line bake's plot of the belly, a bake read back and plotted, a folder of clips baked on Dask."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
ASSETS = Path(os.environ.get("JIGGLE_ASSETS", ROOT.parent / "shared" / "assets"))


def run(script: str, *argv, timeout=600) -> str:
    env = {**os.environ, "PYTHONPATH": str(ROOT), "JIGGLE_ASSETS": str(ASSETS)}
    r = subprocess.run([sys.executable, str(ROOT / "examples" / script), *map(str, argv)], capture_output=True,
                       text=True, env=env, cwd=ROOT, timeout=timeout)
    assert r.returncode == 0, f"{script} failed:\n{r.stdout}\n{r.stderr}"
    return r.stdout


def need(*paths: Path):
    missing = [str(p) for p in paths if not p.exists()]
    if missing:
        pytest.skip(f"the shared assets are missing: {', '.join(missing)}")


def png(path: Path) -> None:
    import imageio.v3 as iio
    img = iio.imread(path)
    assert img.ndim == 3 and img.shape[0] > 200 and img[..., :3].std() > 5, f"{path} looks empty"


def test_bake_from_python_plots_the_belly(tmp_path):
    need(ASSETS / "characters" / "CesiumMan.glb", ASSETS / "mocap" / "cmu_bvh" / "02_04.bvh")
    out = run("bake_from_python.py", tmp_path)
    png(tmp_path / "belly.png")
    jiggled = float(out.split("belly jiggle: up to ")[1].split(" mm")[0])
    assert jiggled > 1.0, out                                   # the belly does jiggle, by millimetres


def test_read_a_bake_plots_the_skins_jiggle(tmp_path):
    import jiggle
    bake = jiggle.bake(frames=12, out=tmp_path / "demo", progress=False)
    out = run("read_a_bake.py", bake.folder, tmp_path / "plot.png")
    png(tmp_path / "plot.png")
    assert "largest jiggle" in out and "12 frames" in out


def test_bake_a_folder_with_dask(tmp_path):
    clips = [ASSETS / "mocap" / "cmu_bvh" / f"{c}.bvh" for c in ("02_04", "05_02")]
    need(ASSETS / "characters" / "CesiumMan.glb", *clips)
    folder = tmp_path / "clips"
    folder.mkdir()
    for c in clips:
        (folder / c.name).symlink_to(c)
    out = run("bake_a_folder_with_dask.py", folder, ASSETS / "characters" / "CesiumMan.glb", tmp_path / "out",
              "--workers", 2, "--frames", 8)
    for c in clips:
        assert f"{c.name}: 8 frames" in out, out
        assert (tmp_path / "out" / c.stem / "bake.npz").is_file()
