"""Joint torques of a clip (sim/drive/inverse.py): de Leva's segment masses, a held pose standing on the floor with
its weight, and a jump whose flight has no ground and whose landing loads the knees."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from conftest import asset

from jiggle.rig.motion.mocap import load_clip
from jiggle.rig.motion.role_map import resolve_roles
from jiggle.sim.drive.inverse import DE_LEVA_MALE, joint_torques, segment_bodies, segment_masses
from jiggle.sim.drive.skeleton import Skeleton


@pytest.fixture(scope="module")
def jump():
    clip = load_clip(str(asset("mocap/cmu_bvh/02_04.bvh")))
    return clip, resolve_roles(clip)


def test_segment_masses_follow_de_leva(jump):
    """Each segment gets its share of de Leva's table (both sides' limbs each theirs), the trunk the rest of the
    bodies, and the masses sum to the body's."""
    clip, roles = jump
    capsule = Skeleton(clip).model.body_mass[Skeleton(clip).body_ids]
    m = segment_masses(clip.parents, capsule, 70.0, roles)
    assert m.sum() == pytest.approx(70.0)
    seg = segment_bodies(clip.parents, roles)
    assert roles["left_upper_leg"] in seg["upper_leg"] and roles["right_foot"] in seg["foot"]
    for name, bodies in seg.items():
        sides = 1 if name in ("head", "trunk") else 2
        assert m[bodies].sum() == pytest.approx(DE_LEVA_MALE[name] * sides * 70.0, rel=1e-9), name
    # without roles, the capsules' proportions
    plain = segment_masses(clip.parents, capsule, 70.0)
    np.testing.assert_allclose(plain / plain.sum(), capsule / capsule.sum())


def test_a_held_pose_stands_on_its_floor_with_its_weight(jump):
    """The jump's first frame held still for a second: the floor pushes up with the body's weight (within 1%),
    nothing sideways, and nothing is left on the root."""
    clip, roles = jump
    T = 60
    held = replace(clip, rotations=np.repeat(clip.rotations[:1], T, axis=0),
                   translations=np.repeat(clip.translations[:1], T, axis=0))
    loads = joint_torques(held, np.array([0.0, held.duration]), 60.0, roles)
    weight = 60.0 * 9.81
    mid = slice(len(loads.times) // 4, 3 * len(loads.times) // 4)
    np.testing.assert_allclose(loads.ground[mid, 2], weight, rtol=1e-2)
    assert np.abs(loads.ground[mid, :2]).max() < 0.02 * weight
    assert np.linalg.norm(loads.residual[mid, :3], axis=1).max() < 0.02 * weight
    assert loads.contact[mid].any(axis=1).all()


def test_the_flight_has_no_ground_and_the_landing_loads_the_knees(jump):
    """CMU 02_04, a jump: in the air (1.1-1.4 s) the floor gives nothing; in the 0.25 s after the landing (1.45 s)
    the knees carry at least 5 times their mean torque in the air, and the floor pushes with more than the weight."""
    clip, roles = jump
    loads = joint_torques(clip, np.array([0.0, 2.5]), 60.0, roles)
    t = loads.times
    air = (t > 1.1) & (t < 1.4)
    land = (t > 1.45) & (t < 1.7)
    assert np.abs(loads.ground[air]).max() == 0.0 and not loads.contact[air].any()
    assert loads.ground[land, 2].max() > 1.5 * 60.0 * 9.81
    for side in ("left", "right"):
        knee = np.linalg.norm(loads.torques[:, roles[f"{side}_lower_leg"]], axis=1)
        assert knee[land].mean() > 5.0 * knee[air].mean(), (side, knee[land].mean(), knee[air].mean())


def test_the_velocity_filter_is_scipys_zero_phase_butterworth():
    """sim.drive.inverse filters in NumPy (scipy.signal's import cost more than the inverse dynamics): the same
    coefficients as scipy.signal.butter and the same result as its filtfilt, ends included."""
    from scipy.signal import butter, filtfilt

    from jiggle.sim.drive.inverse import _filtered, butterworth2
    for cutoff, rate in ((12.0, 240.0), (6.0, 120.0), (30.0, 100.0)):
        b, a = butter(2, cutoff / (0.5 * rate))
        b2, a2 = butterworth2(cutoff, rate)
        assert np.allclose(b, b2, rtol=1e-12, atol=1e-15) and np.allclose(a, a2, rtol=1e-12, atol=1e-15)
        x = np.random.default_rng(1).normal(size=(97, 5)).cumsum(axis=0)
        assert np.allclose(_filtered(x, rate, cutoff), filtfilt(b, a, x, axis=0), rtol=1e-10, atol=1e-10)
