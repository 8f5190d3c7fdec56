"""A character's real size (rig/character/real_size.py): the user's height, its own walk by dynamic similarity, or
the file's unit."""
from __future__ import annotations

import os
import warnings
from types import SimpleNamespace

import numpy as np
import pytest

from jiggle.rig.character.real_size import G, K_WALK, centre_height, leg_height, real_size

ASSETS = os.path.join(os.path.dirname(__file__), "..", "..", "..", "shared", "assets")


def _skeleton(hip=1.0, legs=2, ik=False):
    """A root at the hips' height with `legs` legs (hip, knee, foot on the floor) and a spine up; optional IK
    targets on the floor under the root."""
    pos, par, names = [[0, 0, hip]], [-1], ["Root"]
    pos.append([0, 0, hip + 0.5]), par.append(0), names.append("Spine")
    for k in range(legs):
        x = 0.2 * (k - (legs - 1) / 2)
        for z, n in ((hip, "Hip"), (hip / 2, "Knee"), (0.0, "Foot")):
            par.append(len(pos) - 1 if n != "Hip" else 0)
            pos.append([x, 0, z]), names.append(f"{n}{k}")
    if ik:
        pos.append([0, 0, 0.0]), par.append(0), names.append("IK_Foot")
    world = np.repeat(np.eye(4)[None], len(pos), axis=0)
    world[:, :3, 3] = pos
    return world, np.array(par), names


def test_leg_height_reads_the_hips():
    world, par, names = _skeleton(hip=0.9)
    assert leg_height(world, par, 0.0, 1.6, names) == pytest.approx(0.9)
    world, par, names = _skeleton(hip=0.5, legs=4, ik=True)          # a quadruped, an IK target on the floor
    assert leg_height(world, par, 0.0, 0.9, names) == pytest.approx(0.5)
    world, par, names = _skeleton(legs=1)
    assert leg_height(world, par, 0.0, 1.6, names) is None            # one leg is no gait


def _character(hip=0.9, scale=1.0):
    world, par, names = _skeleton(hip=hip)
    world[:, :3, 3] *= scale
    v = np.array([[0, 0, 0], [0, 0, (hip + 0.8) * scale], [0.3 * scale, 0, 0]], float)
    return SimpleNamespace(vertices=v, bind_world=world, parents=par, joint_names=names)


def test_a_walk_gives_the_size_by_dynamic_similarity():
    # a human's stride, 1.06 s, is a 0.9 m hip's: T = K sqrt(h / g); the same walk on a file 10 x too big
    T = K_WALK * np.sqrt(0.9 / G)
    human = real_size(_character(), walk=("Walk", T))
    assert human.source == "walk" and human.scale == pytest.approx(1.0)
    big = real_size(_character(scale=10.0), walk=("Walk_Loop", T))
    assert big.scale == pytest.approx(0.1) and big.height_m == pytest.approx(1.7)
    # a cat's quicker walk says a smaller body: the period goes as the square root of the size
    cat = real_size(_character(scale=10.0), walk=("walk", T / 2))
    assert cat.height_m == pytest.approx(1.7 / 4)


def test_height_beats_the_walk_and_nothing_is_the_file():
    ch = _character(scale=3.0)
    given = real_size(ch, height_m=0.5, walk=("Walk", 1.0))
    assert given.source == "height" and given.height_m == 0.5 and given.scale == pytest.approx(0.5 / 5.1)
    plain = real_size(ch)
    assert plain.source == "file" and plain.scale == 1.0 and "file's unit" in plain.why


def test_the_shared_horse_is_horse_sized():
    """The zoo's Horse is 4.8 units tall in its file; its own Walk (1.17 s) says a 2 m horse (a real one stands
    1.6-2.4 m at the head)."""
    path = os.path.join(ASSETS, "characters", "zoo", "Horse.glb")
    if not os.path.isfile(path):
        pytest.skip("characters/zoo/Horse.glb is not in ../shared/assets")
    from jiggle.rig.character.load import load_character
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        horse = load_character(path)
    size = real_size(horse, walk=("Walk", 1.1667))
    assert size.source == "walk" and 1.6 <= size.height_m <= 2.4, size.why


def test_a_legless_walker_vaults_over_its_centre_of_mass():
    """A blob without legs (one root joint, a box skin 2 m tall) that walks: its centre of mass height (1 m, the
    skin's area-weighted centroid, not its vertices' mean) stands for the hip; a stride of a 0.25 m hip's makes it
    a quarter of its file's size."""
    import trimesh
    box = trimesh.creation.box(extents=(1.0, 1.0, 2.0))
    v = np.asarray(box.vertices) + (0, 0, 1.0)
    v = np.concatenate([v, np.tile([[0.4, 0.4, 2.0]], (50, 1))])       # many vertices at the top: not the mean
    f = np.asarray(box.faces)
    assert centre_height(v, f) == pytest.approx(1.0) and v[:, 2].mean() > 1.5
    blob = SimpleNamespace(vertices=v, faces=f, bind_world=np.eye(4)[None], parents=np.array([-1]),
                           joint_names=["Body"])
    size = real_size(blob, walk=("Walk", K_WALK * np.sqrt(0.25 / G)))
    assert size.source == "walk" and size.scale == pytest.approx(0.25) and "no legs" in size.why
    assert real_size(blob).source == "file"                            # no walk: the file's unit
