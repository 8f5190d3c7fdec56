"""A working muscle's bulge (rig/muscle/bulge.py): the belly shortens and thickens, its volume kept."""
from __future__ import annotations

import numpy as np
import pytest

from jiggle.rig.muscle.bulge import BULGE_STRAIN, bulged
from jiggle.rig.muscle.simple_arm import simple_arm


@pytest.fixture(scope="module")
def arm():
    return simple_arm(rings=16, around=12)


def _posed(arm, T=3):
    s = arm.rig.static(np.repeat(np.asarray(arm.character.bind_world)[None], T, axis=0))
    return np.asarray(s.cvs), np.asarray(s.curve)


def test_a_muscle_at_rest_is_left_bit_for_bit(arm):
    cvs, curve = _posed(arm)
    out, c2 = bulged(cvs, curve, np.zeros((3, arm.rig.M)))
    np.testing.assert_array_equal(out, cvs)
    np.testing.assert_array_equal(c2, curve)
    act = np.zeros((3, arm.rig.M))
    act[1] = 1.0
    out, _ = bulged(cvs, curve, act)
    np.testing.assert_array_equal(out[[0, 2]], cvs[[0, 2]])                  # only the working frame moves
    assert not np.array_equal(out[1], cvs[1])


def test_the_belly_thickens_and_shortens_with_its_volume_kept(arm):
    cvs, curve = _posed(arm, 1)
    act = np.ones((1, arm.rig.M))
    out, c2 = bulged(cvs, curve, act)
    ring = lambda x: x.reshape(5, 8, 3)                                       # noqa: E731
    before, after = ring(cvs[0, :40]), ring(out[0, :40])
    r = lambda s, k: np.linalg.norm(s[k] - s[k].mean(axis=0), axis=1).mean()  # noqa: E731
    assert 1.05 < r(after, 2) / r(before, 2) < 1.0 / np.sqrt(1.0 - BULGE_STRAIN)    # thicker, as a cylinder at most
    for k in (0, 4):                                                          # the tendon ends stay
        np.testing.assert_array_equal(after[k], before[k])
    belly = lambda s: np.linalg.norm(s[3].mean(axis=0) - s[1].mean(axis=0))   # noqa: E731
    assert belly(after) / belly(before) == pytest.approx(1.0 - BULGE_STRAIN, rel=1e-9)
    # the action curve's belly points move with their sections
    np.testing.assert_allclose(c2[0, 0, 1] - curve[0, 0, 1], after[1].mean(axis=0) - before[1].mean(axis=0),
                               atol=1e-12)
    # the lofted muscle's volume is kept
    v0, v1 = arm.rig.volumes(cvs[0]), arm.rig.volumes(out[0])
    assert v1[0] / v0[0] == pytest.approx(1.0, abs=1e-6)
    # half the activation, half the strain
    half, _ = bulged(cvs, curve, 0.5 * act)
    assert belly(ring(half[0, :40])) / belly(before) == pytest.approx(1.0 - 0.5 * BULGE_STRAIN, rel=1e-9)


def test_the_rest_shapes_table_keeps_a_posed_muscles_volume(arm):
    """The bake reads each muscle's growth from a table made once on its rest shape (growth_table) instead of
    solving it frame after frame: on the arm flexed through its motion the volume still holds within 0.2%, and the
    growth is the exact one's within 0.5%."""
    from jiggle.rig.muscle.bulge import growth_table, growths
    from jiggle.rig.muscle.simple_arm import arm_world
    T = 6
    s = arm.rig.static(np.stack([arm_world(d) for d in np.linspace(0.0, 130.0, T)]))
    cvs, curve = np.asarray(s.cvs), np.asarray(s.curve)
    act = np.linspace(0.1, 1.0, T)[:, None] * np.ones((1, arm.rig.M))
    table = growth_table(arm.rig.rest_cvs)
    fast, _ = bulged(cvs, curve, act, table=table)
    exact, _ = bulged(cvs, curve, act)
    v0, v1 = arm.rig.volumes(cvs), arm.rig.volumes(fast)
    np.testing.assert_allclose(v1, v0, rtol=2e-3)
    np.testing.assert_allclose(fast, exact, atol=5e-3 * float(np.ptp(cvs, axis=(0, 1)).max()))
    assert table.shape == (arm.rig.M, 11) and table[:, 0] == pytest.approx(1.0) and (np.diff(table, axis=1) > 0).all()
    rings = np.asarray(arm.rig.rest_cvs).reshape(-1, 5, 8, 3)
    assert growths(rings, np.array([BULGE_STRAIN]))[0] == pytest.approx(table[0, -1], rel=1e-12)
