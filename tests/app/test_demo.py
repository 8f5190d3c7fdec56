import pytest

"""The built-in demo (the README's first command), reduced for CI: it needs no file from outside the
repository, bakes and compares into one folder and prints where the report is."""
import json
import re

import numpy as np

from jiggle.sim.app.cli import main
from jiggle.sim.bake.caches import read_npz


@pytest.mark.slow
def test_demo_bakes_and_compares(capsys, tmp_path):
    code = main(["demo", "--out", str(tmp_path), "--frames", "30", "--resolution", "6000"])
    out, err = capsys.readouterr()
    assert code == 0, err
    report = re.search(r"open the report: (\S+report\.html)", out)
    assert report and (tmp_path / "report.html").samefile(report.group(1))
    for name in ("bake.npz", "bake.usdc", "bake.json", "metrics.json", "displacement.npz", "amplitude.png",
                 "energy.png", "spectrum.png", "displacement.png", "peak.png", "report.html"):
        assert (tmp_path / name).stat().st_size > 0, name
    assert (tmp_path / "clip.mp4").exists() or (tmp_path / "clip.gif").exists()
    assert not (tmp_path / ".partial").exists()
    d = read_npz(tmp_path / "bake.npz")
    assert d.num_frames == 30 and d.fps == 30.0 and "belly_fat" in d.muscle_names
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    belly = metrics["muscles"]["belly_fat"]
    assert belly["peak_mm"] > 5.0                     # the jumping belly visibly jiggles
    move = np.linalg.norm(d.skin_final - d.skin_static, axis=2).max()
    assert move > 2e-3                                 # and moves the skin
    html = (tmp_path / "report.html").read_text()
    assert "belly_fat" in html and "data:image/png;base64," in html
