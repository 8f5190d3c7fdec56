"""The bake's device (`--device`, BakeRequest.device): every kernel of the bake runs where it says. This
machine has no GPU: a CUDA device is refused with one line naming the devices there (exit 2), and the
CUDA bake, compared with the CPU one, runs only where a GPU exists (skipped here, saying so)."""
import numpy as np
import pytest
import warp as wp

from sim.app.cli import main

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
    from sim.bake.caches import read_npz
    assert main(["-q", "bake", "--out", str(tmp_path / "a"), *ARGS]) == 0
    assert main(["-q", "bake", "--out", str(tmp_path / "b"), "--device", "cpu", *ARGS]) == 0
    a, b = read_npz(tmp_path / "a" / "bake.npz"), read_npz(tmp_path / "b" / "bake.npz")
    assert np.array_equal(a.skin_final, b.skin_final) and str(a.params) == str(b.params)


@pytest.mark.slow
def test_the_cuda_bake_agrees_with_the_cpu_one(tmp_path):
    if not has_cuda():
        pytest.skip("no CUDA device on this machine: the GPU path runs where one exists")
    from sim.bake.caches import read_npz
    assert main(["-q", "bake", "--out", str(tmp_path / "cpu"), *ARGS]) == 0
    assert main(["-q", "bake", "--out", str(tmp_path / "gpu"), "--device", "cuda", *ARGS]) == 0
    a, b = read_npz(tmp_path / "cpu" / "bake.npz"), read_npz(tmp_path / "gpu" / "bake.npz")
    # float32 on another device: sums in another order; 0.1 mm on a body of ~1.8 m
    assert np.abs(a.skin_final - b.skin_final).max() < 1e-4
    assert np.abs(a.muscle_cvs_dynamic - b.muscle_cvs_dynamic).max() < 1e-4
