"""The quadruped's neck muscles on a neck that bends through a chain of joints.

Their belly is one straight loft whose hinges ride the chest, and the model keeps the tendon's length
(rig/muscle/model.py): an insertion riding the head turned the head's swing through the neck's joints into
a slide of the belly's far end along the chest's axis. The Quaternius horse lowering its head to graze
(Idle_Headlow) stretched its 1.07 m neck muscles to 1.24x, 27 cm straight on past the lowered neck, and
the shell deformer carried 17 cm of it onto the skin at Neck2: 34 folded edge-frames where plain skinning
has none (rig/muscle/templates/quadruped.toml says why the insertion now rides the neck's first joint)."""
from __future__ import annotations

import os
import warnings

import numpy as np
import pytest

from jiggle.rig.muscle.template import load_template

HORSE = os.path.join(os.path.dirname(__file__), "..", "..", "..", "shared", "assets", "characters", "zoo",
                     "Horse.glb")


def test_neck_muscles_ride_the_necks_first_joint_and_the_fat_needs_no_neck():
    tpl = load_template("quadruped")
    riding = {m.name: (p, p.riding(m)) for p in tpl.pairs for m in p.muscles}
    for name in ("left_neck", "right_neck"):
        pair, (origin, o_hinge, i_hinge, insertion) = riding[name]
        assert (pair.parent, pair.child) == ("chest", "head")
        assert (origin, o_hinge, i_hinge, insertion) == ("chest", "chest", "chest", "neck")
    # a skeleton without a neck joint (rig.muscle.fit leaves out the pairs needing a missing optional
    # role) keeps the neck fat: it is in a pair of its own that needs no neck
    pair, ride = riding["neck_fat"]
    assert "neck" not in {pair.parent, pair.child, *ride}
    assert all(m.name not in ("left_neck", "right_neck") for m in pair.muscles)


def _folds(x: np.ndarray, faces: np.ndarray, pairs: np.ndarray) -> int:
    """Interior edges whose two faces' normals are more than 90 degrees apart."""
    n = np.cross(x[faces[:, 1]] - x[faces[:, 0]], x[faces[:, 2]] - x[faces[:, 0]])
    n /= np.linalg.norm(n, axis=1, keepdims=True) + 1e-30
    return int(((n[pairs[:, 0]] * n[pairs[:, 1]]).sum(axis=1) < 0).sum())


def _face_pairs(faces: np.ndarray) -> np.ndarray:
    by_edge = {}
    for f, tri in enumerate(faces):
        for a, b in ((tri[0], tri[1]), (tri[1], tri[2]), (tri[2], tri[0])):
            by_edge.setdefault((min(a, b), max(a, b)), []).append(f)
    return np.array([fs for fs in by_edge.values() if len(fs) == 2])


@pytest.mark.slow
@pytest.mark.skipif(not os.path.exists(HORSE), reason="shared asset Horse.glb is absent")
def test_horse_grazing_static_skin_folds_no_more_than_lbs():
    from jiggle.rig.muscle.model import _pose
    from jiggle.sim.bake.setup import BakeRequest, prepare
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        setup = prepare(BakeRequest(character=HORSE, animation="Idle_Headlow"))
    skin, rig = setup.skin, setup.rig
    frames = np.arange(56, 92, 4)             # the head down (68 was the worst frame: 2 folds, LBS 0)
    world = setup.world_at(setup.times[frames])
    static = rig.static(world)
    # the neck muscles stretch with the neck's base only: no longer the head's 1.24x
    neck = [rig.names.index(n) for n in ("left_neck", "right_neck")]
    stretch = _pose(rig, world).length[:, neck] / rig.rest_length[neck]
    assert stretch.max() < 1.1
    faces = np.asarray(setup.character.faces)
    pairs = _face_pairs(faces)
    for t in range(len(frames)):
        lbs = skin.lbs(world[t])
        out = skin.pose(world[t], static.cvs[t], static.curve[t])
        assert _folds(out, faces, pairs) <= _folds(lbs, faces, pairs), f"frame {frames[t]}"
        # the muscles still shape the neck (a few mm), but never carry it 17 cm off its skinned place
        assert np.linalg.norm(out - lbs, axis=1).max() < 0.1
