"""Gear and hard surfaces (rig/character/gear.py, applied by rig/skin/muscle_skin.py).

Reference: a piece (welded component) bound rigidly to one joint follows plain skinning plus one
translation, the mean displacement (deformed - plain) of the soft skin within reach of it, in every
set: its edges keep their plain-skinned lengths exactly (to float32 rounding) and the jiggle
gradient |d_a - d_b| / |s_a - s_b| across its edges is 0. The soft skin is what it was without the
piece's deformers; a character with no rigid piece is today's skin bit for bit.
"""
from __future__ import annotations

import os
from dataclasses import replace

import numpy as np
import pytest

from jiggle.rig.base.errors import InputError
from jiggle.rig.character.gear import RIGID_WEIGHT, find_rigid, parse_rigid, pieces, ride
from jiggle.rig.muscle.simple_arm import simple_arm
from jiggle.rig.skin.muscle_skin import MuscleSkin, skin_frames

ASSETS = os.path.join(os.path.dirname(__file__), "..", "..", "..", "shared", "assets", "characters")


@pytest.fixture(scope="module")
def arm():
    return simple_arm(rings=32, around=24)


def box(centre, half):
    """A closed box: 8 corners (8, 3) and 12 outward triangles (12, 3)."""
    c = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float) * half + centre
    f = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                  [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    return c, f


def with_piece(character, name="Pouch", joint=0, blend=None, centre=(0.0, 0.07, -0.12), half=0.015):
    """`character` with a box added as part `name`, bound rigidly to `joint` (or blended half and half
    with joint `blend`), the parts listed in meta["parts"]."""
    V = character.num_vertices
    c, f = box(np.array(centre), half)
    k = character.joints.shape[1]
    joints = np.zeros((8, k), np.int64)
    weights = np.zeros((8, k))
    joints[:, 0], weights[:, 0] = joint, 1.0
    if blend is not None:
        joints[:, 1], weights[:, :2] = blend, 0.5
    normals = (c - c.mean(0)) / np.linalg.norm(c - c.mean(0), axis=1, keepdims=True)
    return replace(character, vertices=np.vstack([character.vertices, c]), faces=np.vstack([character.faces, f + V]),
                   normals=np.vstack([character.normals, normals]), joints=np.vstack([character.joints, joints]),
                   weights=np.vstack([character.weights, weights]),
                   meta={**character.meta, "parts": [["Arm", 0, V], [name, V, 8]]})


def frames_of(arm, skin, T=4):
    """Static and jiggled skins (T, V, 3) of a bent elbow and the plain skin, the jiggle a made-up wobble."""
    world = arm.world(np.linspace(30.0, 90.0, T))
    st = arm.rig.static(world)
    rng = np.random.default_rng(0)
    jig = st.cvs + 0.004 * rng.standard_normal(st.cvs.shape)
    return skin_frames(skin, world, (st.cvs, jig), st.curve, np.arange(T), smooth=True)


def edge_lengths(x, faces):
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    return np.linalg.norm(x[..., e[:, 0], :] - x[..., e[:, 1], :], axis=-1)


# ---------------------------------------------------------------------------------- detection
def test_a_piece_bound_to_one_joint_is_rigid_the_skinned_body_is_not(arm):
    ch = with_piece(arm.character)
    r = find_rigid(ch)
    V = arm.character.num_vertices
    assert r.mask[V:].all() and not r.mask[:V].any()
    assert r.parts == ("Pouch",) and r.pieces == 1 and r.joints == ("shoulder",)
    assert "Pouch" in r.describe() and r.to_json()["vertices"] == 8
    assert not find_rigid(arm.character).any


def test_a_skin_wholly_on_one_joint_is_a_body_not_a_shell(arm):
    ch = arm.character
    k = ch.joints.shape[1]
    w = np.zeros((ch.num_vertices, k))
    w[:, 0] = 1.0
    blob = replace(ch, joints=np.zeros_like(ch.joints), weights=w)
    assert not find_rigid(blob).any


def test_a_part_named_like_gear_is_rigid_unless_it_is_most_of_the_skin(arm):
    named = with_piece(arm.character, name="Belt_Pouch.001", blend=1)       # skinned over two joints
    assert find_rigid(named).parts == ("Belt_Pouch.001",)
    assert not find_rigid(with_piece(arm.character, name="Bag", blend=1)).any
    big = replace(named, meta={**named.meta, "parts": [["Vest", 0, named.num_vertices]]})
    assert not find_rigid(big).any


def test_welded_pieces_ignore_uv_seams(arm):
    ch = with_piece(arm.character)
    V = ch.num_vertices
    # split the box's first corner as a UV seam does: a copy at the same place takes two of its faces
    split = replace(ch, vertices=np.vstack([ch.vertices, ch.vertices[V - 8]]),
                    normals=np.vstack([ch.normals, ch.normals[V - 8]]),
                    joints=np.vstack([ch.joints, ch.joints[V - 8]]), weights=np.vstack([ch.weights, ch.weights[V - 8]]),
                    faces=np.where(np.arange(len(ch.faces))[:, None] >= len(ch.faces) - 2,
                                   np.where(ch.faces == V - 8, V, ch.faces), ch.faces))
    lab = pieces(split)
    assert lab[V] == lab[V - 8] and len(np.unique(lab)) == 2
    assert find_rigid(split).mask[V - 8:].all()


def test_the_user_overrides_by_part_or_joint(arm):
    ch = with_piece(arm.character)
    V = arm.character.num_vertices
    assert not parse_rigid(ch, "none").any and not parse_rigid(ch, "-Pouch").any
    assert parse_rigid(ch, "auto").mask[V:].all() and parse_rigid(ch, None).count == 8
    assert parse_rigid(ch, "none,pouch").count == 8                          # names match without case
    by_joint = parse_rigid(ch, "none,shoulder")
    rigid_v = ch.weights.max(1) >= RIGID_WEIGHT
    assert np.array_equal(by_joint.mask, rigid_v & (ch.joints[np.arange(len(ch.joints)), ch.weights.argmax(1)] == 0))
    assert parse_rigid(ch, "Arm").count == ch.num_vertices
    assert parse_rigid(ch, ["-shoulder"]).count == 0
    with pytest.raises(InputError, match="Helmet"):
        parse_rigid(ch, "Helmet")


# ---------------------------------------------------------------------------------- the skin
def test_a_rigid_piece_rides_the_body_without_stretching(arm):
    ch = with_piece(arm.character)
    V = arm.character.num_vertices
    soft = frames_of(arm, MuscleSkin(ch, arm.rig))
    r = find_rigid(ch)
    skin = MuscleSkin(ch, arm.rig, rigid=r)
    static, final, lbs = frames_of(arm, skin)
    f = ch.faces[-12:] - V
    # without it, the deformers stretch the pouch; with it, its edges keep their plain-skinned lengths
    assert np.abs(edge_lengths(soft[1][:, V:], f) - edge_lengths(soft[2][:, V:], f)).max() > 1e-5
    for s in (static, final):
        assert np.abs(edge_lengths(s[:, V:], f) - edge_lengths(lbs[:, V:], f)).max() < 1e-6
        move = s[:, V:] - lbs[:, V:]                                        # one translation per frame
        assert np.abs(move - move[:, :1]).max() < 1e-6
    # it rides the soft skin under it: the mean displacement of its anchors, which move
    rd = skin.ride
    assert len(rd.anchors) and not r.mask[rd.anchors].any()
    w = np.asarray(rd.weights.todense())[0]
    want = np.einsum("a,tak->tk", w, final[:, rd.anchors] - lbs[:, rd.anchors])
    assert np.abs(final[:, V] - lbs[:, V] - want).max() < 1e-6 and np.abs(want).max() > 1e-4
    # the jiggle gradient across its edges is 0; the body's skin is what it was
    d = final - static
    assert np.abs(edge_lengths(d[:, V:], f)).max() < 1e-6
    assert np.allclose(static[:, :V], soft[0][:, :V], atol=1e-6) and np.allclose(final[:, :V], soft[1][:, :V], atol=1e-6)
    assert np.abs(final[:, :V] - static[:, :V]).max() > 1e-4, "the body under it still jiggles"


def test_pose_frame_by_frame_equals_the_batch(arm):
    ch = with_piece(arm.character)
    skin = MuscleSkin(ch, arm.rig, rigid=find_rigid(ch))
    world = arm.world(np.array([40.0, 80.0]))
    st = arm.rig.static(world)
    batch = skin.pose_batch(world, [st.cvs], [st.curve])[0]
    for t in range(2):
        assert np.abs(skin.pose(world[t], st.cvs[t], st.curve[t]) - batch[t]).max() < 1e-6


def test_a_piece_out_of_reach_follows_its_bone_exactly(arm):
    ch = with_piece(arm.character, centre=(0.0, 0.4, -0.12), half=0.02)     # far off the arm
    r = find_rigid(ch)
    assert len(ride(ch, r).anchors) == 0
    V = arm.character.num_vertices
    static, final, lbs = frames_of(arm, MuscleSkin(ch, arm.rig, rigid=r))
    assert np.array_equal(final[:, V:], lbs[:, V:]) and np.array_equal(static[:, V:], lbs[:, V:])


@pytest.mark.parametrize("mode", ["shell", "influence"])
def test_no_rigid_piece_is_todays_skin_bit_for_bit(arm, mode):
    ref = frames_of(arm, MuscleSkin(arm.character, arm.rig, skinning=mode))
    skin = MuscleSkin(arm.character, arm.rig, skinning=mode, rigid=find_rigid(arm.character))
    assert skin.rigid is None and skin.ride is None
    out = frames_of(arm, skin)
    assert all(np.array_equal(a, b) for a, b in zip(ref, out))


# ---------------------------------------------------------------------------------- real files
def _load(name):
    import warnings

    from jiggle.rig.character.load import load_character
    path = os.path.join(ASSETS, name)
    if not os.path.isfile(path):
        pytest.skip(f"{name} is not in ../shared/assets")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return load_character(path)


def test_robot_expressive_is_hard_shells_but_its_hand():
    ch = _load("RobotExpressive.glb")
    r = find_rigid(ch)
    parts = {p[0]: (p[1], p[2]) for p in ch.meta["parts"]}
    assert {"Torso.0", "Torso.1", "Head_13.0", "Leg.L", "Foot.R_68"} <= set(r.parts)
    for hand in ("Hand.R.0", "Hand.R.1"):
        a, n = parts[hand]
        assert not r.mask[a:a + n].any()
    assert r.pieces == 60 and r.count == ch.num_vertices - 554


@pytest.mark.parametrize("name", ["CesiumMan.glb", "RiggedFigure.glb", "zoo/Horse.glb", "zoo/Cow.glb"])
def test_one_piece_bodies_have_no_rigid_part(name):
    assert not find_rigid(_load(name)).any


def test_the_frogs_eyes_are_rigid_its_body_is_not():
    ch = _load("zoo/Frog.glb")
    r = find_rigid(ch)
    assert r.parts == ("Frog.2", "Frog.3") and r.joints == ("Head",) and not r.partly
