"""Painted maps on the skin (rig/skin/painted_maps.py, applied by rig/skin/muscle_skin.py).

Jiggle map J: final = static + J (final - static) per vertex, on every set but the static one.
Reference equalities: J = 1 everywhere is today's skin bit for bit; J = 0 on a region makes the final
skin the static skin there exactly and changes nothing elsewhere (bit for bit). Influence maps: the
computed shell regions painted back give the same pairs and weights bit for bit; 0 removes a
muscle's pull; a value > 0 outside the culled region adds pairs; a value < 1 softens.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from jiggle.rig.base.errors import InputError
from jiggle.rig.character.painted_maps import PaintedMaps
from jiggle.rig.muscle.simple_arm import simple_arm
from jiggle.rig.skin.muscle_skin import MuscleSkin, skin_frames
from jiggle.rig.skin.painted_maps import JiggleMap, painted_pairs, shell_regions


@pytest.fixture(scope="module")
def arm():
    return simple_arm(rings=32, around=24)


def frames_of(arm, skin, T=4):
    """Static and jiggled skins (T, V, 3) of a bent elbow, the jiggle a made-up wobble of the CVs."""
    world = arm.world(np.linspace(30.0, 90.0, T))
    st = arm.rig.static(world)
    rng = np.random.default_rng(0)
    jig = st.cvs + 0.004 * rng.standard_normal(st.cvs.shape)
    return skin_frames(skin, world, (st.cvs, jig), st.curve, np.arange(T))


def with_maps(arm, **kw):
    return replace(arm.character, maps=PaintedMaps(**kw))


@pytest.mark.parametrize("mode", ["shell", "influence"])
def test_jiggle_map_of_ones_is_todays_skin_bit_for_bit(arm, mode):
    ref = frames_of(arm, MuscleSkin(arm.character, arm.rig, skinning=mode))
    V = arm.character.num_vertices
    skin = MuscleSkin(with_maps(arm, jiggle=np.ones(V)), arm.rig, skinning=mode)
    assert skin.jiggle_map is None
    out = frames_of(arm, skin)
    assert np.array_equal(ref[1], out[1]) and np.array_equal(ref[0], out[0])
    assert np.abs(ref[1] - ref[0]).max() > 1e-4, "the made-up jiggle must move the skin"


@pytest.mark.parametrize("mode", ["shell", "influence"])
def test_jiggle_map_zero_on_a_region_shows_no_jiggle_there_only(arm, mode):
    ref_static, ref_final = frames_of(arm, MuscleSkin(arm.character, arm.rig, skinning=mode))
    v = arm.character.vertices
    zero = v[:, 1] > 0.0                        # the front half of the arm, over the muscle
    jmap = np.where(zero, 0.0, 1.0)
    half = (v[:, 1] <= 0.0) & (v[:, 0] > 0.0)   # a quarter of the arm shows half its jiggle
    jmap[half] = 0.5
    static, final = frames_of(arm, MuscleSkin(with_maps(arm, jiggle=jmap), arm.rig, skinning=mode))
    assert np.array_equal(static, ref_static)
    assert np.array_equal(final[:, zero], static[:, zero])                     # J = 0: no jiggle at all
    rest = ~zero & ~half
    assert np.array_equal(final[:, rest], ref_final[:, rest])                  # J = 1: untouched
    # J = 0.5: half the jiggle (float32 rounding)
    want = ref_static[:, half] + 0.5 * (ref_final[:, half] - ref_static[:, half])
    assert np.abs(final[:, half] - want).max() < 1e-6
    assert np.abs(ref_final[:, zero] - ref_static[:, zero]).max() > 1e-4, "there was jiggle to remove"


def test_jiggle_map_applies_in_the_deferred_and_reused_bake_path(arm):
    V = arm.character.num_vertices
    jmap = np.where(arm.character.vertices[:, 1] > 0.0, 0.0, 1.0)
    skin = MuscleSkin(with_maps(arm, jiggle=jmap), arm.rig)
    world = arm.world(np.linspace(30.0, 90.0, 3))
    st = arm.rig.static(world)
    jig = st.cvs + 0.003
    static, final, smooth = skin_frames(skin, world, (st.cvs, jig), st.curve, np.arange(3), defer=True,
                                        smooth=True, reuse=True)()
    zero = jmap == 0.0
    assert np.array_equal(final[:, zero], static[:, zero]) and smooth.shape == (3, V, 3)


def test_jiggle_map_class_checks_and_identity():
    assert JiggleMap(np.ones(5)).identity
    with pytest.raises(InputError, match="jiggle_map"):
        JiggleMap(np.array([0.0, 1.5]))
    with pytest.raises(InputError):
        JiggleMap(np.array([0.0, np.nan]))
    s = np.zeros((2, 3, 3), np.float32)
    f = np.ones((2, 3, 3), np.float32)
    out = JiggleMap(np.array([1.0, 0.0, 0.25])).apply(s, f)
    assert np.array_equal(out[:, 0], f[:, 0]) and np.all(out[:, 1] == 0.0) and np.allclose(out[:, 2], 0.25)


@pytest.mark.parametrize("mode", ["shell", "influence"])
def test_computed_regions_painted_back_change_nothing(arm, mode):
    """The starting point `jiggle fit` writes (shell_regions), read back as influence maps, gives the
    same pairs; in shell skinning the same weights bit for bit, so the same skin."""
    table = shell_regions(arm.character, arm.rig)
    plain = MuscleSkin(arm.character, arm.rig, skinning=mode)
    painted = MuscleSkin(with_maps(arm, influence={"BICEPS": table[:, 0]}), arm.rig, skinning=mode)
    assert np.array_equal(plain.pair_offsets, painted.pair_offsets)
    assert np.array_equal(plain.pair_muscle, painted.pair_muscle)
    if mode == "shell":
        assert np.array_equal(plain.pair_weight, painted.pair_weight)
        w = arm.world(90.0)
        assert np.array_equal(plain.pose(w), painted.pose(w))
    assert table.min() >= 0.0 and table.max() == 1.0 and (table[:, 0] > 0).sum() == plain.num_pairs


def test_influence_map_removes_softens_and_adds(arm):
    v = arm.character.vertices
    plain = MuscleSkin(arm.character, arm.rig)
    table = shell_regions(arm.character, arm.rig)[:, 0]
    w = arm.world(90.0)
    lbs = plain.lbs(w)
    # removed everywhere: the skin is the smooth skin
    none = MuscleSkin(with_maps(arm, influence={"biceps": np.zeros(len(v))}), arm.rig)
    assert np.abs(none.pose(w) - lbs).max() < 1e-7 and np.all(none.pair_weight == 0.0)
    # softened to half: half the pull where the computed weight is 1 (the limit keeps it about linear)
    soft = MuscleSkin(with_maps(arm, influence={"biceps": 0.5 * table}), arm.rig)
    assert np.allclose(soft.pair_weight, 0.5 * plain.pair_weight)
    full, half = np.abs(plain.pose(w) - lbs).max(), np.abs(soft.pose(w) - lbs).max()
    assert 0.3 * full < half < 0.7 * full
    # added: vertices outside the culled region painted > 0 get pairs with their painted weight
    outside = table == 0.0
    assert outside.any()
    add = np.where(outside, 0.2, table)
    more = MuscleSkin(with_maps(arm, influence={"biceps": add}), arm.rig)
    assert more.num_pairs == len(v) > plain.num_pairs
    assert np.allclose(more.pair_weight[outside], 0.2)


def test_painted_pairs_merges_sorted():
    offsets, muscle = np.array([0, 1, 1, 2]), np.array([1, 0])
    inf = np.full((3, 2), np.nan, np.float32)
    inf[1, 0], inf[0, 1] = 0.3, 0.0     # vertex 1 gains muscle 0; vertex 0 keeps its pair with weight 0
    o, m, p = painted_pairs(offsets, muscle, inf)
    assert o.tolist() == [0, 1, 2, 3] and m.tolist() == [1, 0, 0]
    assert p[0] == 0.0 and p[1] == pytest.approx(0.3) and np.isnan(p[2])
