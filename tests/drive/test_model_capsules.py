"""--colliders model: the MuJoCo model's own capsule geoms as the particles' colliders (sim.drive.skeleton:
capsule_geoms, model_capsules; rig.character.capsules.model_capsules): the geoms ride their bodies exactly as
MuJoCo places them, they are kept inside the character's skin, and a bake with them reports them."""
import json
from pathlib import Path

import mujoco
import numpy as np

from jiggle.sim.app.cli import main
from jiggle.sim.drive.skeleton import Skeleton, capsule_geoms

ROOT = Path(__file__).resolve().parents[2]


def test_geoms_ride_their_bodies_as_mujoco_places_them():
    """At a moving pose of a CMU clip, each geom's segment from the body's world transform and the geom's
    local ends equals MuJoCo's own geom_xpos +- the geom's z axis x half length (to 1e-9 m)."""
    from conftest import asset

    from jiggle.rig.motion.mocap import load_clip
    clip = load_clip(str(asset("mocap/cmu_bvh/02_04.bvh")))
    sk = Skeleton(clip)
    g = capsule_geoms(sk.model, sk.body_ids)
    kinds = (int(mujoco.mjtGeom.mjGEOM_CAPSULE), int(mujoco.mjtGeom.mjGEOM_SPHERE))
    caps = [k for k in range(sk.model.ngeom) if int(sk.model.geom_type[k]) in kinds]
    assert len(g["joint"]) == len(caps) >= 20
    t = np.array([1.3])
    sk.data.qpos[:] = sk.qpos_at(t)[0]
    mujoco.mj_kinematics(sk.model, sk.data)
    for c, k in enumerate(caps):
        j = g["joint"][c]
        Rj = sk.data.xmat[sk.body_ids[j]].reshape(3, 3)
        ends = (Rj @ g["local"][c].T).T + sk.data.xpos[sk.body_ids[j]]
        axis = sk.data.geom_xmat[k].reshape(3, 3)[:, 2]
        half = sk.model.geom_size[k, 1] if int(sk.model.geom_type[k]) == kinds[0] else 0.0
        want = np.sort(np.stack([sk.data.geom_xpos[k] - half * axis, sk.data.geom_xpos[k] + half * axis]), axis=0)
        np.testing.assert_allclose(np.sort(ends, axis=0), want, atol=1e-9)
        assert g["radius"][c] == sk.model.geom_size[k, 0]


def test_model_capsules_sit_inside_the_skin_and_follow_the_bones():
    """On CesiumMan with the MuJoCo model of its own skeleton: every kept geom's axis lies at least 10% of its
    radius inside the skin (nearest vertex), no radius grows past the geom's, the limb geoms end toward the
    child joint along the bone (their far end nearer the child than the joint), and the joints whose geoms
    were all dropped keep their bone capsules."""
    from conftest import asset
    from scipy.spatial import cKDTree

    from jiggle.rig.character.load import load_character
    from jiggle.sim.drive.skeleton import model_capsules
    ch = load_character(str(asset("characters/CesiumMan.glb")))
    caps, G, kept = model_capsules(ch.skeleton, ch)
    geoms = capsule_geoms(Skeleton(ch.skeleton).model, Skeleton(ch.skeleton).body_ids)
    model = list(range(kept))
    assert all(n.startswith("bone:") for n in caps.names[kept:])
    assert len(model) >= 0.8 * G and G >= 15
    ends = caps.ends(ch.bind_world)
    tree = cKDTree(np.asarray(ch.vertices))
    bind = np.asarray(ch.bind_world)
    with_child = 0
    for c in model:
        pts = ends[c, 0] + np.linspace(0.0, 1.0, 33)[:, None] * (ends[c, 1] - ends[c, 0])
        d, _ = tree.query(pts)
        step = np.linalg.norm(ends[c, 1] - ends[c, 0]) / 16
        assert d.min() + 0.5 * step > caps.radius[c], caps.names[c]
        assert caps.radius[c] <= geoms["radius"][list(geoms["names"]).index(caps.names[c])] + 1e-12
        k = caps.child[c]
        if k >= 0:
            with_child += 1
            j = caps.joint[c]
            assert np.linalg.norm(ends[c, 1] - bind[k, :3, 3]) < np.linalg.norm(ends[c, 1] - bind[j, :3, 3])
    assert with_child >= 10
    covered = set(caps.joint[model])
    fallback = [c for c in range(caps.count) if caps.names[c].startswith("bone:")]
    assert all(caps.joint[c] not in covered for c in fallback)


def test_bake_with_model_colliders_reports_them(tmp_path, capsys):
    """`jiggle bake --colliders model` on the demo's generated body: bake.json says which capsules and how many
    model geoms, the contacts name the geoms, and the final skin is never inside more capsules than the static
    one in any frame; the built-in arm (no MuJoCo model) and a bad scene value are one line, exit 2."""
    out = tmp_path / "m"
    code = main(["bake", str(ROOT / "scenes" / "default.toml"), "--colliders", "model", "--frames", "30",
                 "--formats", "npz", "--out", str(out)])
    assert code == 0, capsys.readouterr().err
    s = json.loads((out / "bake.json").read_text())
    assert s["params"]["collisions"]["capsules"] == "model" and s["params"]["settings"]["colliders"] == "model"
    assert s["params"]["collisions"]["model_geoms"] >= 20
    names = s["contacts"]["colliders"]
    assert names[-1] == "floor" and any(n.endswith("_bone0") for n in names)
    si = s["contacts"]["skin_inside"]
    assert all(f <= st for f, st in zip(si["final"], si["static"]))
    capsys.readouterr()
    assert main(["bake", str(ROOT / "scenes" / "simple_arm.toml"), "--colliders", "model", "--out",
                 str(tmp_path / "arm")]) == 2
    err = capsys.readouterr().err
    assert "no MuJoCo model" in err and err.count("\n") == 1
    bad = ROOT / "scenes" / f".bad_colliders_{tmp_path.name}.toml"     # beside the scene: its relative paths hold
    bad.write_text((ROOT / "scenes" / "default.toml").read_text().replace("[jiggle]", '[jiggle]\ncolliders = "geoms"'))
    try:
        assert main(["bake", str(bad), "--out", str(tmp_path / "b")]) == 2
    finally:
        bad.unlink()
    err = capsys.readouterr().err
    assert "jiggle.colliders" in err and "'bone', 'model'" in err and f"{bad.name}:24:" in err
