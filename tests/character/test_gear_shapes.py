"""Hard or soft from the mesh, not the weights alone (rig/character/gear.py find_rigid, issue 50), and no work for
muscles that drive nothing (rig/skin/muscle_skin.py MuscleSkin.idle, sim/bake).

Reference: a rigidly bound piece is hard when its part or material is named like gear or its shape says so (an
open sheet, a plate thinner than PLATE of its width, a tapered spike, a shell lying close over a bigger piece);
the bulky, rounded piece holding most of the skin's volume and of the skeleton's bone length is the body's own
volume, flesh however it is weighted; any other rigidly bound piece stays hard. A muscle none of whose (vertex,
muscle) pairs lies on soft skin drives nothing: glued to its static shape, or with every muscle so, nothing is
simulated; bake.json says "simulated": false with no reach, and compare's near-reach count leaves it out.
"""
from __future__ import annotations

import json
import os
import warnings
from dataclasses import replace

import numpy as np
import pytest

from gear_builds import cone, plated, rebound_rigidly, slab
from jiggle.rig.character.gear import (PLATE, RULE_BODY, RULE_MATERIAL, RULE_NAMED, RULE_PIECE, RULE_PLATE,
                                       RULE_SHEET, RULE_SHELL, RULE_SPIKE, find_rigid, parse_rigid, pieces)
from jiggle.rig.muscle.simple_arm import simple_arm

ASSETS = os.path.join(os.path.dirname(__file__), "..", "..", "..", "shared", "assets", "characters")


def _asset(name):
    path = os.path.join(ASSETS, name)
    if not os.path.isfile(path):
        pytest.skip(f"{name} is not in ../shared/assets")
    return path


def _load(name):
    from jiggle.rig.character.load import load_character
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return load_character(_asset(name))


def _ball(centre, radius, n=12):
    """A closed UV sphere (vertices, outward faces)."""
    import trimesh
    m = trimesh.creation.uv_sphere(radius=radius, count=[n, n])
    return np.asarray(m.vertices) + centre, np.asarray(m.faces)


def with_pieces(character, pieces_, joint=0, materials=None):
    """`character` with closed pieces [(name, vertices, faces)] added, each bound with weight 1 to `joint`; the
    character's own skin becomes part "Body"."""
    from jiggle.rig.character.normals import vertex_normals
    V, k = character.num_vertices, character.joints.shape[1]
    verts, faces, parts = [np.asarray(character.vertices)], [np.asarray(character.faces)], [["Body", 0, V]]
    n = V
    for name, v, f in pieces_:
        verts.append(v), faces.append(f + n), parts.append([name, n, len(v)])
        n += len(v)
    vertices, faces_ = np.vstack(verts), np.vstack(faces)
    joints = np.vstack([character.joints, np.zeros((n - V, k), np.int64)])
    weights = np.vstack([character.weights, np.zeros((n - V, k))])
    joints[V:, 0], weights[V:, 0] = joint, 1.0
    return replace(character, vertices=vertices, faces=faces_, normals=vertex_normals(vertices, faces_),
                   joints=joints, weights=weights,
                   meta={**character.meta, "parts": parts, **({"materials": materials} if materials else {})})


@pytest.fixture(scope="module")
def arm():
    return simple_arm(rings=32, around=24)


def _rules(r):
    return {(d["part"], d["rule"], d["hard"]) for d in r.decided}


# ---------------------------------------------------------------------------------- the rules, one by one
def test_shapes_say_hard_plate_sheet_spike_shell(arm):
    from gear_builds import offset_shell
    ch = arm.character
    eye = np.eye(3)
    far = np.array([1.0, 0.0, 0.0])                                          # each piece well apart
    plate = slab(far * 1, eye, (0.05, 0.04, 0.002))                           # 4 mm thick, 80 mm wide
    spike = cone(far * 2, far * 2 + [0.0, 0.0, 0.15], 0.02)
    tri = np.array([[0.0, 0.0, 0.0], [0.05, 0.0, 0.0], [0.0, 0.05, 0.0], [0.05, 0.05, 0.02]]) + far * 3
    sheet = (tri, np.array([[0, 1, 2], [1, 3, 2]]))                           # one open layer
    head = _ball(far * 4, 0.05)
    top = head[1][(head[0][head[1]][:, :, 2] > far[2] * 4 + 0.01).all(axis=1)]
    helmet = offset_shell(head[0], (head[0] - far * 4) / 0.05, top, 0.004, 0.006)   # a helmet over the ball's top
    added = with_pieces(ch, [("P", *plate), ("S", *spike), ("O", *sheet), ("Head", *head), ("Cover", *helmet)])
    r = find_rigid(added)
    got = {d["part"]: d["rule"] for d in r.decided}
    assert got["P"] == RULE_PLATE and got["S"] == RULE_SPIKE and got["O"] == RULE_SHEET
    assert got["Cover"] == RULE_SHELL and got["Head"] == RULE_PIECE
    assert all(d["hard"] for d in r.decided) and not r.mask[:ch.num_vertices].any()
    assert r.why[RULE_PLATE] == 8 and sum(r.why.values()) == r.count
    assert 2 * 0.002 / 0.08 < PLATE


def test_names_and_materials_say_hard(arm):
    ch = arm.character
    ball = _ball(np.array([0.0, 0.3, 0.0]), 0.03)
    named = with_pieces(ch, [("Helmet.001", *ball)])
    assert {(d["part"], d["rule"]) for d in find_rigid(named).decided} == {("Helmet.001", RULE_NAMED)}
    V = ch.num_vertices
    metal = with_pieces(ch, [("Cap", *ball)], materials=[["Skin", 0, V], ["Steel_Dark", V, len(ball[0])]])
    r = find_rigid(metal)
    assert [d["rule"] for d in r.decided] == [RULE_MATERIAL] and r.mask[V:].all()


def test_a_rigidly_bound_body_is_flesh_its_eyes_are_not(arm):
    """The arm bound wholly to one joint with two eyes on another: the arm is the body's own volume."""
    ch = arm.character
    k = ch.joints.shape[1]
    w = np.zeros((ch.num_vertices, k))
    w[:, 0] = 1.0
    body = replace(ch, joints=np.zeros_like(ch.joints), weights=w)
    top = np.asarray(ch.vertices)[np.argmax(np.asarray(ch.vertices)[:, 2])]
    eyes = [(f"Eye.{s}", *_ball(top + [0.0, s * 0.02, 0.0], 0.01, 8)) for s in (-1, 1)]
    blob = with_pieces(body, eyes, joint=1)
    r = find_rigid(blob)
    assert not r.mask[:ch.num_vertices].any() and r.mask[ch.num_vertices:].all()
    assert ("Body", RULE_BODY, False) in _rules(r) and r.soft == {RULE_BODY: ch.num_vertices}
    assert {d["rule"] for d in r.decided if d["hard"]} == {RULE_PIECE}
    assert "flesh though bound rigidly" in r.describe() and r.to_json()["soft"] == {RULE_BODY: ch.num_vertices}
    # the user still decides
    assert parse_rigid(blob, "Body").mask[:ch.num_vertices].all()


# ---------------------------------------------------------------------------------- built characters
@pytest.fixture(scope="module")
def cat():
    return _load("zoo/Cat.glb")


def rigid_cat(cat):
    """The shared Cat rebound rigidly to two joints: its body and ears to Head, its eyes (the two 202-vertex
    balls) to Head2."""
    label = pieces(cat)
    sizes = np.bincount(label)
    eyes = [int(k) for k in np.nonzero(sizes == 202)[0]]
    assert len(eyes) == 2
    return rebound_rigidly(cat, "Head", {k: "Head2" for k in eyes})


def test_the_cat_rebound_rigidly_keeps_its_body_soft(cat):
    blob = rigid_cat(cat)
    assert (np.asarray(blob.weights)[:, 0] == 1.0).all()
    r, before = find_rigid(blob), find_rigid(cat)
    assert np.array_equal(r.mask, before.mask), "the same pieces hard as in the Cat: eyes and ears"
    body = [d for d in r.decided if not d["hard"]]
    assert len(body) == 1 and body[0]["rule"] == RULE_BODY and body[0]["vertices"] == 595


def test_shared_characters_are_decided_as_before():
    """The zoo's and the robot's hard vertices are those of the weights-alone rule (tests/character/test_gear.py
    holds the counts): the eyes and head pieces, the robot's every piece but the hand."""
    for name, count in (("zoo/Orc.glb", 1471), ("zoo/Goleling.glb", 682), ("zoo/Frog.glb", 404),
                        ("zoo/Cat.glb", 675), ("RobotExpressive.glb", 6106)):
        r = find_rigid(_load(name))
        assert r.count == count and not r.soft, name
        assert sum(d["vertices"] for d in r.decided if d["hard"]) == count


def test_a_character_of_plates_and_shards_is_all_hard_and_drives_no_muscle():
    from jiggle.rig.muscle.fit import fit_musculature
    from jiggle.rig.skin.muscle_skin import MuscleSkin
    knight = plated(_load("CesiumMan.glb"))
    r = find_rigid(knight)
    assert r.all and set(r.why) == {RULE_PLATE, RULE_SPIKE}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        mus = fit_musculature(knight, "auto")
    skin = MuscleSkin.from_musculature(mus, rigid=r)
    assert skin.idle.all() and skin.num_pairs == 0


def test_robot_muscles_under_metal_are_idle_the_hand_is_not():
    from jiggle.rig.muscle.fit import fit_musculature
    from jiggle.rig.skin.muscle_skin import MuscleSkin
    robot = _load("RobotExpressive.glb")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        mus = fit_musculature(robot, "auto")
    skin = MuscleSkin.from_musculature(mus)
    soft = np.nonzero(~skin.rigid.mask)[0]
    driving = set(skin.pair_muscle[np.isin(np.repeat(np.arange(robot.num_vertices), np.diff(skin.pair_offsets)),
                                           soft)].tolist())
    assert 0 < len(driving) < mus.rig.M
    assert set(np.nonzero(~skin.idle)[0].tolist()) == driving
    assert not MuscleSkin.from_musculature(mus, rigid="none").idle.any()


# ---------------------------------------------------------------------------------- bakes
def _bake(tmp_path, glb, name, *extra):
    from jiggle.sim.app.cli import main
    from jiggle.sim.app.commands.compare import compare_bake
    out = tmp_path / name
    assert main(["bake", "--character", str(glb), "--out", str(out), "--formats", "npz", "-q", *extra]) == 0
    compare_bake(str(out), render=False, video=False)
    return json.loads((out / "bake.json").read_text()), json.loads((out / "metrics.json").read_text())


@pytest.mark.slow
def test_the_rigidly_bound_cat_jiggles_as_the_cat_does(tmp_path, cat):
    """Done when: a rigidly bound blob body jiggles like the same body skinned smoothly, its peak within 20% on
    the cycle each one's tissue is held on (their Dance, the one that jiggles most: the Cat's peaks at 18 mm; 0.0 mm
    under the weights-alone rule). Their calmer Walk need not agree as closely: the hold matches the worst cycle, and
    the two bindings answer the Walk differently (7.4 and 5.6 mm)."""
    from jiggle.rig.character.gltf_write import write_character
    from jiggle.rig.motion.mocap import load_clip
    src = _asset("zoo/Cat.glb")
    glb = tmp_path / "rigid_cat.glb"
    # the Cat's cycles, so its tissue is held on the same ones (one tissue per character)
    write_character(rigid_cat(cat), glb, source=src,
                    animations={n: load_clip(src, animation=n) for n in ("Walk", "Dance", "Idle")})
    _, smooth = _bake(tmp_path, src, "cat", "--animation", "Dance")
    info, rigid = _bake(tmp_path, glb, "rigid", "--animation", "Dance")
    assert smooth["skin"]["max_mm"] > 10.0
    assert rigid["skin"]["max_mm"] == pytest.approx(smooth["skin"]["max_mm"], rel=0.2)
    assert RULE_BODY in info["params"]["rigid"]["parts"]["soft"]
    assert rigid["skin_quality"]["worst"]["jiggle"]["torn_edges_max"] == 0


@pytest.mark.slow
def test_a_knight_in_plate_simulates_no_muscle(tmp_path):
    """Done when: a character whose every piece is plate or shard bakes with no simulated muscle and the
    near-reach count is 0."""
    from jiggle.rig.character.gltf_write import write_character
    from jiggle.rig.motion.mocap import load_clip
    from jiggle.sim.app.outputs.inspect import inspect_file
    src = _asset("CesiumMan.glb")
    glb = tmp_path / "knight.glb"
    write_character(plated(_load("CesiumMan.glb")), glb, animations={"walk": load_clip(src)})
    info, metrics = _bake(tmp_path, glb, "knight", "--frames", "20")
    muscles = info["params"]["muscles"]
    assert muscles and all(m["simulated"] is False and m["reach_m"] is None for m in muscles.values())
    assert sorted(info["params"]["rigid"]["not_simulated"]) == sorted(muscles)
    assert "tissue" not in info                                  # no particle model: nothing simulated
    lim = metrics["limits"]
    assert lim["muscles_near_limit"] == 0 and lim["muscles_with_reach"] == 0 and not lim["flags"]
    assert metrics["skin"]["max_mm"] == 0.0
    rep = inspect_file(str(glb))["rigid"]
    assert rep["simulated"].startswith("none") and any(k.startswith("hard, a thin plate") for k in rep["rules"])
