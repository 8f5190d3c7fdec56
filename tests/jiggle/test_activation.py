"""Muscle activation from the motion's loads (sim/jiggle/activation.py): moment arms are the path length's
derivative, the least-effort sharing, activation dynamics, and on a real jump the quadriceps work at the landing and
rest in the air."""
from __future__ import annotations

import numpy as np
import pytest

from jiggle.sim.jiggle.activation import (FALL_S, RISE_S, activation_dynamics, below, moment_arms, path_points,
                                          static_optimization)


def _rotate_below(world, parents, j, axis, angle):
    """world (J, 4, 4) with joint j's subtree rotated by `angle` about world `axis` through joint j."""
    from scipy.spatial.transform import Rotation
    R = Rotation.from_rotvec(np.asarray(axis) * angle).as_matrix()
    p = world[j, :3, 3]
    out = world.copy()
    for i in np.flatnonzero(below(parents)[j]):
        out[i, :3, :3] = R @ world[i, :3, :3]
        out[i, :3, 3] = R @ (world[i, :3, 3] - p) + p
    return out


def test_moment_arms_are_the_path_lengths_derivative(arm_rig):
    """R_mj . a = -dL/dtheta for every joint and axis, against central differences of the path's length."""
    rig, world, parents = arm_rig
    arms = moment_arms(rig, world[None], parents)[0]                    # (M, J, 3)

    def length(w):
        P = path_points(rig, w[None])[0]
        return np.linalg.norm(np.diff(P, axis=1), axis=2).sum(axis=1)
    h = 1e-6
    checked = 0
    for j in range(len(parents)):
        for a in np.eye(3):
            d = (length(_rotate_below(world, parents, j, a, h)) - length(_rotate_below(world, parents, j, a, -h))) / (2 * h)
            np.testing.assert_allclose(arms[:, j] @ a, -d, atol=1e-7)
            checked += np.abs(d).max() > 1e-4
    assert checked >= 1                    # the elbow moves the biceps' path


@pytest.fixture
def arm_rig():
    from jiggle.rig.muscle.simple_arm import simple_arm
    arm = simple_arm(rings=8, around=8)
    world = np.asarray(arm.world(70.0), np.float64)
    parents = np.asarray(arm.character.parents)
    return arm.rig, world, parents


def test_least_effort_takes_the_muscle_that_pulls_the_right_way():
    """Two muscles at one joint, a flexor and an extensor (moment arms +-3 cm, 1000 N): a flexing torque of 12 N m
    is the flexor's alone at 12 / 30 = 0.4; twice the flexor's reach saturates it at 1 with the rest unmet."""
    arms = np.zeros((2, 2, 1, 3))
    arms[:, 0, 0] = [0.03, 0.0, 0.0]
    arms[:, 1, 0] = [-0.03, 0.0, 0.0]
    force = np.array([1000.0, 1000.0])
    torques = np.array([[[12.0, 0.0, 0.0]], [[60.0, 0.0, 0.0]]])
    exc, unmet = static_optimization(arms, torques, force)
    np.testing.assert_allclose(exc[0], [0.4, 0.0], atol=2e-3)
    np.testing.assert_allclose(exc[1], [1.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(unmet[1, 0], [30.0, 0.0, 0.0], atol=0.1)


def test_activation_rises_fast_and_falls_slower():
    """A step of excitation 0 -> 1 -> 0: activation reaches 1 - 1/e after RISE_S and falls to 1/e of its value
    FALL_S after the excitation stops."""
    dt = 0.001
    t = np.arange(400) * dt
    on, off = 100, 200                                                  # the samples the excitation steps at
    u = ((np.arange(400) >= on) & (np.arange(400) < off)).astype(float)[:, None]
    a = activation_dynamics(u, t)[:, 0]
    # n steps after a step the gap to the excitation is exp(-n dt / tau) of what it was
    assert a[on - 1 + round(RISE_S / dt)] == pytest.approx(1 - np.exp(-1), abs=1e-9)
    assert a[off - 1 + round(FALL_S / dt)] == pytest.approx(a[off - 1] * np.exp(-1), abs=1e-9)
    assert FALL_S > RISE_S


@pytest.mark.slow
def test_the_quadriceps_work_at_the_landing_and_rest_in_the_air(tmp_path):
    """The generated body on CMU 02_04 (a jump; landing at 1.45 s): both quadriceps' mean activation in the 0.2 s
    after the landing is at least 3 times their mean in the air (1.1-1.4 s); fat is never activated."""
    from conftest import asset

    from jiggle.sim.bake.setup import BakeRequest, _character, _drive, _fit, _inputs, _scene
    from jiggle.sim.drive.inverse import joint_torques
    from jiggle.sim.jiggle.activation import activations
    req = BakeRequest(clip=str(asset("mocap/cmu_bvh/02_04.bvh")))
    log = lambda s: None  # noqa: E731
    scene = _scene(req, None)
    inputs = _inputs(req, scene, None, "particles")
    fit = _fit(req, inputs, _character(req, inputs, None, None, log), None, None, log)
    times = np.arange(0.0, 2.0, 1.0 / 60.0)
    loads = joint_torques(fit.clip, times, 60.0, roles=fit.mus.roles)
    act = activations(fit.mus.rig, _drive(fit.clip, "kinematic", times, log), loads, fit.clip.parents,
                      fit.character.bind_world, times)
    names = list(fit.mus.rig.names)
    air, land = (times > 1.1) & (times < 1.4), (times > 1.45) & (times < 1.65)
    for side in ("left", "right"):
        q = act.activation[:, names.index(f"{side}_quadriceps")]
        assert q[land].mean() >= 3.0 * q[air].mean() and q[land].mean() > 0.02, (side, q[land].mean(), q[air].mean())
    fat = [i for i, k in enumerate(fit.mus.rig.kinds) if k == "fat"]
    assert fat and np.abs(act.activation[:, fat]).max() == 0.0


@pytest.mark.slow
def test_a_bake_with_activation_on_writes_it_and_off_writes_none(tmp_path):
    """jiggle bake --activation on: bake.npz's activation (frames x muscles, in [0, 1], fat 0) and bake.json's
    record (the body's mass, each muscle's peak and mean); the legs work hardest on the jump, and stiffened the
    quadriceps jiggle at most 0.8 of their jiggle without it at the landing while every fat part stays within 20%;
    a bake with --activation off has neither, the default is the bake with it on, and the built-in simple arm (no
    clip skeleton) refuses it (exit 2)."""
    import json
    import os

    from conftest import asset

    from jiggle.sim.app.cli import main
    from jiggle.sim.bake.caches import read_npz
    clip = str(asset("mocap/cmu_bvh/02_04.bvh"))
    on, off = tmp_path / "on", tmp_path / "off"
    args = ["-q", "bake", "--clip", clip, "--end", "2.0", "--formats", "npz"]
    assert main([*args, "--out", str(on), "--activation", "on"]) == 0
    assert main([*args, "--out", str(off), "--activation", "off"]) == 0
    assert main([*args, "--out", str(tmp_path / "default")]) == 0
    a, b = read_npz(on / "bake.npz"), read_npz(off / "bake.npz")
    assert np.array_equal(read_npz(tmp_path / "default" / "bake.npz").skin_final, a.skin_final)   # on by default
    import jiggle
    np.testing.assert_array_equal(jiggle.Bake.open(on).activation, a.activation)     # the API reads it too
    assert b.activation is None and a.activation.shape == (len(a.times), len(a.muscle_names))
    assert a.activation.min() >= 0.0 and a.activation.max() <= 1.0
    rec = json.loads((on / "bake.json").read_text())["params"]["activation"]
    assert "activation" not in json.loads((off / "bake.json").read_text())["params"]
    kinds = {n: m["kind"] for n, m in json.loads((on / "bake.json").read_text())["params"]["muscles"].items()}
    fat = [i for i, n in enumerate(a.muscle_names) if kinds[n] == "fat"]
    assert fat and np.abs(a.activation[:, fat]).max() == 0.0 and set(rec["muscles"]) == {
        n for n, k in kinds.items() if k != "fat"}
    assert 40.0 < rec["body_mass_kg"] < 90.0 and "closed skin" in rec["body_mass_from"]
    legs = max(rec["muscles"][n]["mean"] for n in rec["muscles"] if "quadriceps" in n or "calf" in n or "glute" in n)
    arms = max(rec["muscles"][n]["mean"] for n in rec["muscles"] if "biceps" in n or "triceps" in n)
    assert legs > 3.0 * arms, (legs, arms)
    from dataclasses import replace

    from jiggle.rig.base.errors import InputError
    with pytest.raises(InputError, match="activations must lie in"):
        replace(a, activation=a.activation + 1.5)
    with pytest.raises(InputError, match="expected shape"):
        replace(a, activation=a.activation[:, :3])
    # compare plots it beside the jiggle and reports the hardest-working muscles
    from jiggle.sim.app.commands.compare import compare_bake
    res = compare_bake(str(on), render=False, video=False)
    assert os.path.getsize(res["files"]["activation_plot"]) > 0 and "activation_plot" not in compare_bake(
        str(off), render=False, video=False)["files"]
    top = next(iter(res["metrics"]["activation"]["muscles"]))
    assert kinds[top] == "muscle" and "Activation" in open(res["files"]["report"], encoding="utf-8").read()
    # a working muscle is stiffer: the quadriceps hold at the landing (1.45 s), the fat over them jiggles as before
    off_ = a.muscle_cv_offsets
    land = (a.times >= 1.45) & (a.times < 1.75)

    def peak(d, m):
        sl = slice(off_[m], off_[m + 1])
        return np.linalg.norm(d.muscle_cvs_dynamic[land, sl] - d.muscle_cvs_static[land, sl], axis=2).max()
    for m, n in enumerate(a.muscle_names):
        if "quadriceps" in n:
            assert peak(a, m) <= 0.8 * peak(b, m), (n, peak(a, m), peak(b, m))
            assert rec["muscles"][n]["stiffening_peak"] > 1.5
        if kinds[n] == "fat":
            assert abs(peak(a, m) / peak(b, m) - 1.0) <= 0.2, (n, peak(a, m), peak(b, m))
    # and it bulges: the static belly of a working muscle is thicker at the landing, its volume kept; fat never
    from jiggle.rig.muscle import loft

    def belly(d, m):
        c = d.muscle_cvs_static[:, off_[m]:off_[m + 1]].astype(np.float64).reshape(-1, 5, 8, 3)
        return np.linalg.norm(c[:, 2] - c[:, 2].mean(axis=1, keepdims=True), axis=2).mean(axis=1), loft.volume(c)
    for m, n in enumerate(a.muscle_names):
        (ra, va), (rb, vb) = belly(a, m), belly(b, m)
        if kinds[n] == "fat":
            np.testing.assert_array_equal(a.muscle_cvs_static[:, off_[m]:off_[m + 1]],
                                          b.muscle_cvs_static[:, off_[m]:off_[m + 1]])
        elif "quadriceps" in n:
            k = int(np.argmax(a.activation[:, m]))
            assert ra[k] / rb[k] > 1.0 + 0.05 * a.activation[k, m], (n, ra[k] / rb[k], a.activation[k, m])
            np.testing.assert_allclose(va, vb, rtol=1e-4)                     # float32 caches
    from pathlib import Path
    arm = Path(__file__).resolve().parents[2] / "scenes" / "simple_arm.toml"
    assert main(["-q", "bake", str(arm), "--out", str(tmp_path / "arm"), "--activation", "on"]) == 2
