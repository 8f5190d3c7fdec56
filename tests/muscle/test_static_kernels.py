"""The static muscle shape on a Warp device (rig/muscle/static_kernels.py, `MuscleRig.static(world,
device="cpu")`, the default) against the NumPy reference (`device=None`), for every volume rule.

Both run in float64; the bound is the issue's 1e-9 m (measured: ~1e-16 m on the arm, ~1e-14 m on
the human rigs). Rigs: the two-bone arm's muscles (tests/arm_muscles.py), including a belly pushed
below MIN_BELLY x its rest chord and a section whose tangent runs along the up vector (the side-vector
fallback); the default human template fitted to the generated jumping-jacks body driven by its clip
and by random joint turns, and to CesiumMan (shared asset) turned at random.
"""
from __future__ import annotations

import pickle
import warnings

import numpy as np
import pytest
from arm_muscles import ARM_BIND, arm_world, biceps, brachio, spec_from_ellipsoid
from conftest import asset
from scipy.spatial.transform import Rotation

from jiggle.rig.muscle import model
from jiggle.rig.muscle.model import MIN_BELLY, VOLUME_RULES, build_muscle_rig

TOL = 1e-9   # metres


def differences(rig, world, rule) -> tuple[float, float]:
    """Max |device - NumPy| (metres) of the section CVs and of the curve CVs."""
    dev = rig.static(world, volume=rule, device="cpu")
    ref = rig.static(world, volume=rule, device=None)
    assert dev.cvs.shape == ref.cvs.shape and dev.curve.shape == ref.curve.shape
    assert dev.cvs.dtype == np.float64 and dev.curve.dtype == np.float64
    return float(np.abs(dev.cvs - ref.cvs).max(initial=0.0)), float(np.abs(dev.curve - ref.curve).max(initial=0.0))


def assert_equal(rig, world, label: str):
    for rule in VOLUME_RULES:
        d_cvs, d_curve = differences(rig, world, rule)
        print(f"\n{label}, {rule}: max |warp - numpy| cvs {d_cvs:.1e} m, curve {d_curve:.1e} m")
        assert d_cvs < TOL and d_curve < TOL, (label, rule)


def turned(world: np.ndarray, rng, max_deg: float) -> np.ndarray:
    """world (T, J, 4, 4) with every joint of every frame turned at random (up to max_deg) about its own
    origin: rigid per joint, though the bones no longer meet (the static shape takes any rigid transforms)."""
    T, J = world.shape[:2]
    vec = Rotation.random(T * J, random_state=int(rng.integers(1 << 31))).as_rotvec()
    vec *= np.radians(max_deg) * rng.uniform(0.0, 1.0, (T * J, 1)) / np.maximum(np.linalg.norm(vec, axis=1,
                                                                                              keepdims=True), 1e-12)
    out = world.copy()
    out[..., :3, :3] = Rotation.from_rotvec(vec).as_matrix().reshape(T, J, 3, 3) @ world[..., :3, :3]
    return out


def world_point(rig, world, m: int, slot: int) -> np.ndarray:
    """(T, 3) slot `slot` of muscle m in world coordinates, world (T, J, 4, 4)."""
    return (world[:, rig.joints[m, slot]] @ rig.local[m, slot])[:, :3]


# ---------------------------------------------------------------------------------- the arm
def test_arm_muscles_over_elbow_sweeps_and_moves():
    specs = [biceps(), brachio(bulge_position=0.3, tone=0.7, middle_offset=(0.004, 0.01, 0.0)),
             biceps(rim_scale=0.8, main_scale=1.2, bone=1), biceps(hinges=[(0, 0.02, -0.04), (0, 0.025, -0.27)])]
    rig = build_muscle_rig(specs, ARM_BIND)
    g = np.eye(4)
    g[:3, :3] = Rotation.from_rotvec([0.3, -1.1, 0.7]).as_matrix()
    g[:3, 3] = (0.4, -2.0, 1.1)
    world = np.stack([arm_world(a, root=r) for a in np.arange(0.0, 141.0, 5.0) for r in (None, g)])
    assert_equal(rig, world, "arm sweep")
    # the rest pose is reproduced on the device too
    assert np.abs(rig.static(ARM_BIND, device="cpu").cvs - rig.rest_cvs).max() < TOL


def test_a_collapsed_belly_is_clamped_alike():
    """The elbow joint pushed up the arm brings the brachio's hinges within MIN_BELLY x its rest chord:
    both paths push the belly ends apart to exactly that extent along the hinge axis."""
    rig = build_muscle_rig([brachio(), biceps()], ARM_BIND)
    world, collapsed = [], []
    for lift in (0.10, 0.15, 0.17, 0.20):
        for angle in (0.0, 10.0, 30.0, 100.0):
            w = arm_world(angle)
            w[1:, 2, 3] += lift
            world.append(w)
            collapsed.append(lift > 0.12 and angle < 20.0)     # hinges 3 cm apart or less, 5.4 cm kept
    world = np.stack(world)
    assert_equal(rig, world, "collapsed brachio")
    curve = rig.static(world, device="cpu").curve[:, 0]                           # (T, 5, 3) brachio
    u = world_point(rig, world, 0, model._I_HINGE) - world_point(rig, world, 0, model._O_HINGE)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    extent = np.einsum("ti,ti->t", curve[:, 4] - curve[:, 0], u)
    assert np.allclose(extent[collapsed], MIN_BELLY * rig.rest_chord[0], rtol=1e-9)
    assert np.all(extent >= MIN_BELLY * rig.rest_chord[0] * (1 - 1e-9))


def test_a_section_along_the_up_vector_takes_the_side_vector_alike():
    """A belly straight down the arm spanning the elbow: at 90 deg flexion its insertion tangent (riding
    the forearm) points along its up vector (riding the upper arm), and the end section's frame comes
    from the side vector; at 90.02 deg still (within ~0.06 deg), at 90.2 deg no longer."""
    spec = spec_from_ellipsoid("along", [(0, 0.03, -0.2), (0, 0.03, -0.4)], (0, 1, 0), (0.02, 0.015),
                               bones=(0, 0, 1, 1), origin=(0, 0.02, -0.15), insertion=(0, 0.015, -0.5))
    rig = build_muscle_rig([spec, brachio()], ARM_BIND)
    angles = np.array([89.8, 89.98, 90.0, 90.02, 90.2])
    world = np.stack([arm_world(a) for a in angles])
    assert_equal(rig, world, "tangent along up")
    curve = rig.static(world, device="cpu").curve[:, 0]
    tangent = curve[:, 4] - curve[:, 3]
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    up = world_point(rig, world, 0, model._UP)
    sine = np.linalg.norm(np.cross(tangent, up / np.linalg.norm(up, axis=1, keepdims=True)), axis=1)
    assert np.all((sine < 1e-3) == (np.abs(angles - 90.0) < 0.05)), sine


# ---------------------------------------------------------------------------------- human rigs
def fitted_human(character):
    from jiggle.rig.muscle.fit import FitOptions, fit_musculature
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return fit_musculature(character, "human", FitOptions()).rig


@pytest.fixture(scope="module")
def jumping_jacks():
    """(rig, world (T, J, 4, 4)): the human template on the body generated for the jumping-jacks clip."""
    from jiggle.rig.character.load import body_character
    from jiggle.rig.motion.clip import transforms
    from jiggle.rig.motion.mocap import load_clip
    clip = load_clip("scenes/motions/jumping_jacks.toml")
    return fitted_human(body_character(clip)), transforms(*clip.world())


def test_human_rig_over_its_clip(jumping_jacks):
    rig, world = jumping_jacks
    assert rig.M == 28
    assert_equal(rig, world, f"generated body, {len(world)} clip frames")


def test_human_rig_turned_at_random(jumping_jacks):
    """Every joint turned up to 120 deg at random: bellies collapse, sections turn far from rest."""
    rig, world = jumping_jacks
    assert_equal(rig, turned(world[::6], np.random.default_rng(3), 120.0), "generated body, random turns")


def test_cesium_man_turned_at_random():
    from jiggle.rig.character.load import load_character
    c = load_character(asset("characters/CesiumMan.glb"))
    rig = fitted_human(c)
    bind = np.asarray(c.bind_world, dtype=np.float64)
    assert np.abs(rig.static(bind, device="cpu").cvs - rig.rest_cvs).max() < TOL
    assert_equal(rig, turned(np.stack([bind] * 24), np.random.default_rng(5), 90.0), "CesiumMan, random turns")


# ---------------------------------------------------------------------------------- the entry point
def test_the_default_is_the_device_path_and_shapes_follow_the_input():
    rig = build_muscle_rig([biceps(), brachio()], ARM_BIND)
    world = np.stack([arm_world(a) for a in (0, 45, 90, 135)])
    default, dev = rig.static(world), rig.static(world, device="cpu")
    assert np.array_equal(default.cvs, dev.cvs) and np.array_equal(default.curve, dev.curve)
    one = rig.static(world[2], device="cpu")
    assert one.cvs.shape == (80, 3) and one.curve.shape == (2, 5, 3)
    assert np.array_equal(one.cvs, dev.cvs[2]) and np.array_equal(one.curve, dev.curve[2])
    empty = rig.static(world[:0], device="cpu")
    assert empty.cvs.shape == (0, 80, 3) and empty.curve.shape == (0, 2, 5, 3)
    none = build_muscle_rig([], ARM_BIND)
    assert none.static(world, device="cpu").cvs.shape == (4, 0, 3)
    assert none.static(ARM_BIND, device="cpu").curve.shape == (0, 5, 3)
    # the constants are uploaded once per device and kept off the rig, which still pickles
    assert list(model._ON_DEVICE[rig]) == ["cpu"]
    again = pickle.loads(pickle.dumps(rig))
    assert np.array_equal(again.static(world).cvs, dev.cvs)
