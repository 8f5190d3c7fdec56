"""Skin over bones and muscles (rig/skin/muscle_skin.py): the thesis's simple arm and CesiumMan.

The simple arm (rig/muscle/simple_arm.py) is a cylinder on two bones with one muscle on the upper bone;
CesiumMan gets the default template fitted and a CMU run retargeted onto it (skipped without the
shared assets).
"""
from __future__ import annotations

import warnings

import numpy as np
import pytest
from conftest import asset

from jiggle.rig.base.errors import InputError, JiggleWarning
from jiggle.rig.muscle.shell_params import ShellParams
from jiggle.rig.muscle.simple_arm import simple_arm
from jiggle.rig.skin.muscle_skin import MuscleSkin


@pytest.fixture(scope="module")
def arm():
    return simple_arm()


@pytest.fixture(scope="module")
def arm_skins(arm):
    return {mode: MuscleSkin(arm.character, arm.rig, skinning=mode) for mode in ("shell", "influence")}


def mid_front(arm):
    """Vertices on the front (+Y, over the muscle) at the middle of the upper bone."""
    v = arm.character.vertices
    return (np.abs(v[:, 2] + 0.15) < 0.01) & (v[:, 1] > 0.05)


@pytest.mark.parametrize("mode", ["shell", "influence"])
def test_bind_pose_gives_the_artists_skin(arm, arm_skins, mode):
    out = arm_skins[mode].pose(arm.world(0.0))
    assert np.abs(out - arm.character.vertices).max() < 1e-6


@pytest.mark.parametrize("mode", ["shell", "influence"])
def test_bending_the_elbow_bulges_the_middle_of_the_upper_arm(arm, arm_skins, mode):
    """Thesis simple example: at 90 deg of flexion the biceps, 30% shorter with its volume kept, is
    ~19% thicker; the skin over the middle of the upper bone moves outward along its normal by
    ~1.4 mm (shells, held below half the drop-off distance so no shell folds the skin where it ends:
    rig/skin/shell/shells.py) / ~1.9 mm (influence objects, held below the drop-off distance: the
    biceps' pull also slides the skin along the arm, and the limit scales the whole pull) compared
    with LBS, more at 90 deg than at 45."""
    sel = mid_front(arm)
    n = arm.character.normals[sel]       # the upper arm is rigid under LBS here: rest normals hold
    out = {}
    for angle in (45.0, 90.0):
        w = arm.world(angle)
        skin = arm_skins[mode]
        move = skin.pose(w) - skin.lbs(w)
        out[angle] = float(np.mean(np.sum(move[sel] * n, axis=1)))
    assert out[90.0] > (1.0e-3 if mode == "shell" else 1.5e-3)
    assert out[90.0] > 1.3 * out[45.0] > 0.0                  # more at 90 than at 45 (the limits saturate)
    print(f"\n{mode}: mid upper arm pushed out by {out[45.0] * 1e3:.2f} mm at 45 deg, {out[90.0] * 1e3:.2f} mm at 90")


def test_continuity_over_an_elbow_sweep(arm, arm_skins):
    """Sweep the elbow 0 -> 120 deg in 0.25 deg steps: the change of each vertex's displacement from
    LBS (skin - LBS) from one step to the next never exceeds C times (the step's largest motion of the
    muscle's CVs relative to its bone + the vertex's own LBS motion). The displacement is a smooth
    function of both (the deformer's field moves with the muscle; a vertex that LBS slides through
    the field, as in the elbow's crease, sees its gradient), so a bounded C says no vertex jumps.
    Measured C ~ 3 (crease vertices near 120 deg); a jump would break it by orders of magnitude."""
    skin = arm_skins["shell"]
    angles = np.arange(0.0, 120.0 + 1e-9, 0.25)
    prev = None
    ratios = []
    for a in angles:
        w = arm.world(a)
        static = arm.rig.static(w)
        lbs = skin.lbs(w)
        delta = skin.pose(w, static.cvs, static.curve) - lbs
        cv = static.cvs - skin.frames.carried_rest_cvs(w)
        if prev is not None:
            step = np.linalg.norm(delta - prev[0], axis=1)
            motion = np.linalg.norm(cv - prev[1], axis=1).max() + np.linalg.norm(lbs - prev[2], axis=1)
            ratios.append((step / np.maximum(motion, 1e-12)).max())
        prev = (delta, cv, lbs)
    assert max(ratios) < 4.0, max(ratios)


def test_zero_painted_weight_gives_lbs_and_half_weight_half_the_move(arm):
    """Painted weights w_i scale each pair: 0 keeps the vertex on LBS; 0.5 halves the displacement
    of a vertex only one muscle moves (stretch: D = w w_i a (E_cur - E_ref) q, linear in w_i)."""
    ch, w = arm.character, arm.world(90.0)
    full = MuscleSkin(ch, arm.rig)
    zero = MuscleSkin(ch, arm.rig, weights=np.zeros((ch.num_vertices, 1)))
    half = MuscleSkin(ch, arm.rig, weights=np.full((ch.num_vertices, 1), 0.5))
    lbs = full.lbs(w)
    np.testing.assert_array_equal(zero.pose(w), lbs)
    d_full, d_half = full.pose(w) - lbs, half.pose(w) - lbs
    assert np.abs(d_full).max() > 1e-2
    np.testing.assert_allclose(d_half, 0.5 * d_full, atol=2e-6)


def test_nan_cvs_skip_the_muscle_with_a_warning_and_no_nan(arm, arm_skins):
    w = arm.world(60.0)
    static = arm.rig.static(w)
    cvs = static.cvs.copy()
    cvs[3] = np.nan
    for mode, skin in arm_skins.items():
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            out = skin.pose(w, cvs, static.curve, frame=17)
        assert np.isfinite(out).all(), mode
        np.testing.assert_allclose(out, skin.lbs(w), atol=1e-6)
        msg = " ".join(str(c.message) for c in caught if issubclass(c.category, JiggleWarning))
        assert "biceps" in msg and "17" in msg, (mode, msg)


def test_collapsed_muscle_is_skipped(arm, arm_skins):
    """A degenerate muscle frame (every CV at one point: zero scale) is skipped, not a NaN."""
    w = arm.world(30.0)
    static = arm.rig.static(w)
    cvs = np.repeat(static.cvs.mean(axis=0, keepdims=True), len(static.cvs), axis=0)
    with pytest.warns(JiggleWarning, match="biceps"):
        out = arm_skins["shell"].pose(w, cvs, static.curve, frame=3)
    np.testing.assert_allclose(out, arm_skins["shell"].lbs(w), atol=1e-6)


def test_bad_parameters_are_named(arm):
    ch, rig = arm.character, arm.rig
    with pytest.raises(InputError, match="skinning"):
        MuscleSkin(ch, rig, skinning="rbf-ish")
    with pytest.raises(InputError, match="weights"):
        MuscleSkin(ch, rig, weights=np.full((ch.num_vertices, 1), 1.5))
    with pytest.raises(InputError, match="shells"):
        MuscleSkin(ch, rig, [ShellParams(), ShellParams()])
    with pytest.raises(InputError, match="margin"):
        MuscleSkin(ch, rig, margin=-1.0)
    for field, kw in (("sticky", dict(sticky=1.5)), ("hard", dict(hard=-0.1)), ("drop_off", dict(drop_off=0.0)),
                      ("slippage", dict(slippage=-1.0)), ("mode", dict(mode="wobble"))):
        with pytest.raises(InputError, match=field):
            ShellParams(**kw)


def test_culling_keeps_only_vertices_near_the_muscle(arm, arm_skins):
    """Pairs are the vertices within (1 + d)(1 + margin) of the rest ellipsoid: the forearm's far
    end and the shoulder cap's back are out; everything the deformer moves at 90 deg is in, or in
    the rings the skin spreads it to (MuscleSkin.spread), and nothing farther moves."""
    skin = arm_skins["shell"]
    v = arm.character.vertices
    kept = np.zeros(len(v), bool)
    kept[np.repeat(np.arange(len(v)), np.diff(skin.pair_offsets))] = True
    assert 0 < kept.sum() < 0.5 * len(v)
    assert not kept[v[:, 2] < -0.45].any()
    w = arm.world(90.0)
    moved = np.linalg.norm(skin.pose(w) - skin.lbs(w), axis=1) > 0
    spread = np.zeros(len(v), bool)
    spread[skin.spread.rows] = True
    assert not (moved & ~spread).any() and (kept & ~spread).sum() == 0
    bare = MuscleSkin(arm.character, arm.rig, spread=0.0)
    assert not ((np.linalg.norm(bare.pose(w) - bare.lbs(w), axis=1) > 0) & ~kept).any()


# ---------------------------------------------------------------------------------- CesiumMan
@pytest.fixture(scope="module")
def cesium():
    from jiggle.rig.character.load import load_character
    from jiggle.rig.motion.bvh import read_bvh
    from jiggle.rig.motion.clip import transforms
    from jiggle.rig.motion.gltf_skeleton import read_gltf_skeleton
    from jiggle.rig.motion.retarget import JointMap, retarget
    from jiggle.rig.muscle.fit import fit_musculature
    path = asset("characters/CesiumMan.glb")
    clip = read_bvh(asset("mocap/cmu_bvh/02_03.bvh"))
    ch = load_character(path)
    run = retarget(clip, JointMap.load("cmu"), read_gltf_skeleton(path), JointMap.load("cesiumman"))
    world = transforms(*run.world())
    return ch, fit_musculature(ch), world


@pytest.mark.parametrize("mode", ["shell", "influence"])
def test_cesiumman_bind_pose_is_the_artists_skin(cesium, mode):
    ch, mus, _ = cesium
    skin = MuscleSkin.from_musculature(mus, skinning=mode)
    assert np.abs(skin.pose(ch.bind_world) - ch.vertices).max() < 1e-6


def test_cesiumman_run_frame_stays_within_the_drop_off(cesium):
    """A frame of the retargeted run (and every 8th frame): no NaN, and no vertex moves farther from
    LBS than the drop-off distance d |L_ref u| of the muscles that may move it (the largest among its
    pairs; the drop-off limit holds each pair below half its own). Measured: the worst vertices, in the
    creases behind the knees where LBS folds the skin into the hamstrings' field, reach 0.49 of that
    distance: without the limit they would go to ~1.9 times the nearest muscle's. The skin's spreading
    of that displacement (a weighted mean of its neighbours') moves no vertex farther than the largest
    of those distances."""
    ch, mus, world = cesium
    skin = MuscleSkin.from_musculature(mus, spread=0.0)
    spread = MuscleSkin.from_musculature(mus)
    vertex = np.repeat(np.arange(ch.num_vertices), np.diff(skin.pair_offsets))
    worst = 0.0
    for f in range(0, len(world), 8):
        w = world[f]
        lbs = skin.lbs(w)
        out = skin.pose(w, frame=f)
        assert np.isfinite(out).all()
        static = mus.rig.static(w)
        fr, _ = skin.frames.frame(w, static.cvs, static.curve)
        m = skin.pair_muscle
        p_l = np.einsum("pij,pj->pi", fr.E_ref_inv[m, :3, :3], lbs[vertex]) + fr.E_ref_inv[m, :3, 3]
        u = p_l / np.linalg.norm(p_l, axis=1, keepdims=True)
        reach = skin.table.drop_off[m] * np.linalg.norm(np.einsum("pij,pj->pi", fr.E_ref[m, :3, :3], u), axis=1)
        bound = np.zeros(ch.num_vertices)
        np.maximum.at(bound, vertex, reach)
        move = np.linalg.norm(out - lbs, axis=1)
        assert np.all(move <= bound + 1e-6), f
        assert np.linalg.norm(spread.pose(w, frame=f) - lbs, axis=1).max() <= bound.max() + 1e-6
        worst = max(worst, float((move[bound > 0] / bound[bound > 0]).max()))
    print(f"\nworst move / drop-off distance over the run: {worst:.2f}")
