"""The bake's device (`--device`, BakeRequest.device): every kernel of the bake runs where it says. This
machine has no GPU: a CUDA device is refused with one line naming the devices there (exit 2), and the
CUDA bake, compared with the CPU one, runs only where a GPU exists (skipped here, saying so)."""
import numpy as np
import pytest
import warp as wp

from jiggle.sim.app.cli import main

ARGS = ["--frames", "12", "--formats", "npz", "--resolution", "3000", "--chunk", "4"]


def has_cuda() -> bool:
    wp.init()
    return wp.is_cuda_available()


def test_a_device_that_is_not_here_is_exit_2(capsys, tmp_path):
    if has_cuda():
        pytest.skip("this machine has a CUDA device")
    assert main(["bake", "--out", str(tmp_path / "x"), "--device", "cuda", *ARGS]) == 2
    err = capsys.readouterr().err.strip()
    assert "--device: no Warp device 'cuda' here" in err and "this machine has: cpu" in err and "\n" not in err, err
    assert main(["bake", "--out", str(tmp_path / "y"), "--device", "gpu7", *ARGS]) == 2
    assert "no Warp device 'gpu7'" in capsys.readouterr().err


@pytest.mark.slow
def test_an_explicit_cpu_is_the_default_bit_for_bit(tmp_path):
    from jiggle.sim.bake.caches import read_npz
    assert main(["-q", "bake", "--out", str(tmp_path / "a"), *ARGS]) == 0
    assert main(["-q", "bake", "--out", str(tmp_path / "b"), "--device", "cpu", *ARGS]) == 0
    a, b = read_npz(tmp_path / "a" / "bake.npz"), read_npz(tmp_path / "b" / "bake.npz")
    assert np.array_equal(a.skin_final, b.skin_final) and str(a.params) == str(b.params)


@pytest.mark.slow
def test_the_cuda_bake_agrees_with_the_cpu_one(tmp_path):
    if not has_cuda():
        pytest.skip("no CUDA device on this machine: the GPU path runs where one exists")
    from jiggle.sim.bake.caches import read_npz
    assert main(["-q", "bake", "--out", str(tmp_path / "cpu"), *ARGS]) == 0
    assert main(["-q", "bake", "--out", str(tmp_path / "gpu"), "--device", "cuda", *ARGS]) == 0
    a, b = read_npz(tmp_path / "cpu" / "bake.npz"), read_npz(tmp_path / "gpu" / "bake.npz")
    # float32 on another device: sums in another order; 0.1 mm on a body of ~1.8 m
    assert np.abs(a.skin_final - b.skin_final).max() < 1e-4
    assert np.abs(a.muscle_cvs_dynamic - b.muscle_cvs_dynamic).max() < 1e-4


# ---------------------------------------------------------------------------------------- on the device
# The bake's promises, on whatever device runs it: the CPU here, and CUDA where a GPU exists
# (benchmarks/gpu_check.py runs this file on a lent GPU machine).
def device_or_skip(device: str) -> str:
    if device != "cpu" and not has_cuda():
        pytest.skip("no CUDA device on this machine: the GPU path runs where one exists")
    return device


class Stop(Exception):
    """Raised by a progress callback to stop a bake between chunks (as a crash would)."""


@pytest.mark.slow
@pytest.mark.parametrize("device", ["cpu", "cuda"])
def test_a_bake_interrupted_on_the_device_resumes_bit_for_bit(device, tmp_path):
    """The simple arm at 60 fps in chunks of 16, stopped after its second chunk and resumed, on the device:
    every cache equals the unbroken bake's on the same device bit for bit (the particle state is stored
    with each chunk, sim/bake/baker.py)."""
    from pathlib import Path

    from jiggle.sim.bake.baker import PARTIAL, bake
    from jiggle.sim.bake.caches import read_npz, read_pc2
    from jiggle.sim.bake.setup import BakeRequest, prepare
    device = device_or_skip(device)
    arm = str(Path(__file__).resolve().parents[2] / "scenes" / "simple_arm.toml")
    req = BakeRequest(scene=arm, fps=60, chunk=16, formats=("npz", "pc2"), device=device)
    bake(prepare(req), str(tmp_path / "whole"))
    seen = []

    def stop_after_two(n):
        seen.append(n)
        if len(seen) == 2:
            raise Stop
    with pytest.raises(Stop):
        bake(prepare(req), str(tmp_path / "cut"), progress=stop_after_two)
    assert (tmp_path / "cut" / PARTIAL).is_dir() and not (tmp_path / "cut" / "bake.npz").exists()
    summary = bake(prepare(req), str(tmp_path / "cut"), resume=True)
    assert summary["resumed_after_chunks"] >= 2
    a, b = read_npz(tmp_path / "whole" / "bake.npz"), read_npz(tmp_path / "cut" / "bake.npz")
    for k in ("skin_static", "skin_final", "muscle_cvs_dynamic"):
        assert np.array_equal(getattr(a, k), getattr(b, k)), k
    assert np.array_equal(read_pc2(tmp_path / "whole" / "bake.pc2").points, read_pc2(tmp_path / "cut" / "bake.pc2").points)


@pytest.mark.slow
@pytest.mark.parametrize("device", ["cpu", "cuda"])
def test_the_jiggle_on_the_device_is_independent_of_the_frame_rate(device):
    """The simple arm's flex (tests/jiggle/test_jiggle_clips.py) at 24, 30 and 60 fps against 120 fps x 16
    substeps, on the device: every CV at every frame within 2% of the reference's peak amplitude (the
    CPU's own bound), and the device's reference within 0.1 mm of the CPU's."""
    import importlib.util
    from pathlib import Path
    spec = importlib.util.spec_from_file_location(
        "jiggle_clips", Path(__file__).resolve().parents[1] / "jiggle" / "test_jiggle_clips.py")
    clips = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(clips)
    CLIP_S, RATE_TOL, flex_angle, frames = clips.CLIP_S, clips.RATE_TOL, clips.flex_angle, clips.frames
    from jiggle.rig.muscle.simple_arm import arm_world, simple_arm
    from jiggle.sim.jiggle.params import JiggleSettings
    from jiggle.sim.jiggle.materials import default_jiggles
    from jiggle.sim.jiggle.secondary import jiggle_rig
    device = device_or_skip(device)
    arm = simple_arm()
    jiggles = default_jiggles(arm.rig)

    def world_at(t):
        return arm_world(flex_angle(t))

    def run(fps, sub, dev=device):
        return jiggle_rig(arm.rig, jiggles, world_at, frames(fps, CLIP_S), JiggleSettings(substeps=sub, device=dev))
    ref = run(120, 16)
    peak = np.linalg.norm(ref.dynamic - ref.static, axis=2).max()
    assert peak > 1e-3
    for fps, sub in ((24, 2), (30, 4), (60, 4)):
        r = run(fps, sub)
        k = np.round(r.times * 120).astype(int)
        err = np.linalg.norm(r.dynamic - ref.dynamic[k], axis=2).max()
        assert err <= RATE_TOL * peak, (fps, sub, err / peak)
    if device != "cpu":
        assert np.abs(ref.dynamic - run(120, 16, "cpu").dynamic).max() < 1e-4
