"""Driving a user MJCF from a clip: dm_control's CMU humanoid from the CMU ASF/AMC, a small model
with free and ball joints, the hinge decomposition, and bad maps/models."""
from __future__ import annotations

import os

import mujoco
import numpy as np
import pytest
from conftest import asset

from jiggle.rig.base.errors import InputError
from jiggle.rig.motion import quat
from jiggle.rig.motion.acclaim import read_amc, read_asf
from jiggle.rig.motion.bvh import read_bvh
from jiggle.rig.motion.clip import Clip
from jiggle.sim.drive.mjcf_drive import MjcfDrive, hinge_angles

HUMANOID = "mjcf/humanoid_CMU.xml"
ASF = "mocap/cmu_amc/01.asf"
AMC = "mocap/cmu_amc/01_01.amc"


@pytest.fixture(scope="module")
def cmu():
    clip = read_amc(asset(AMC), read_asf(asset(ASF)))
    drive = MjcfDrive(asset(HUMANOID), clip)
    q = drive.qpos()
    rot, pos = drive.kinematics(q)
    return clip, drive, q, rot, pos


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _angle_deg(a, b):
    return np.degrees(np.arccos(np.clip(np.sum(_unit(a) * _unit(b), axis=-1), -1.0, 1.0)))


def test_default_map_and_orientation(cmu):
    clip, drive, q, rot, pos = cmu
    # Every body of the humanoid is named after an ASF bone (and "root"): all 31 map by name.
    assert len(drive.mapping) == 31 and drive.mapping["lfemur"] == "lfemur"
    assert q.shape == (clip.num_frames, drive.model.nq) and rot.shape == (clip.num_frames, 31, 4)
    # Both Z-up and both in the same T-pose at rest: the best-fit rotation between the rest bone
    # directions is about a degree (the model is a generic body, not subject 01).
    assert drive.rest_misalignment_deg < 3.0


def test_bone_directions_follow_the_clip(cmu):
    """For every mapped bone with a mapped child, on every frame, the model's bone direction (body
    to child body) is within its REST difference + 1 degree of the clip's.

    Rest-pose alignment transfers rotations, so the rest difference between the two skeletons (up
    to 11.2 degrees at the hip joints, which have no joint to correct it, 8-10 degrees at the
    clavicles, 5 at the upper neck) is carried along; anything beyond it is tracking error of the
    joints (measured: under 0.4 degrees). Bones whose rest directions agree within 3 degrees stay
    within 3 degrees on every frame."""
    clip, drive, _, _, pos = cmu
    _, cpos = clip.world()
    _, crest = clip.rest_world()
    _, mrest = drive.kinematics(drive.model.qpos0[None])
    names = drive.body_names
    parent = {names[b - 1]: names[drive.model.body_parentid[b] - 1]
              for b in range(1, drive.model.nbody) if drive.model.body_parentid[b] > 0}
    by_body = {v: k for k, v in drive.mapping.items()}
    checked, worst = 0, 0.0
    for child, body in parent.items():
        if child not in by_body or body not in by_body:
            continue
        ib, ic = names.index(body), names.index(child)
        jb, jc = clip.index(by_body[body]), clip.index(by_body[child])
        rest_mj, rest_clip = mrest[0, ic] - mrest[0, ib], crest[jc] - crest[jb]
        if np.linalg.norm(rest_mj) < 1e-6 or np.linalg.norm(rest_clip) < 1e-6:
            # root -> lhipjoint, rhipjoint, lowerback start at the root in both skeletons; the
            # model hangs the thumbs on the hand, but in the ASF lthumb starts where lhand does.
            continue
        rest = _angle_deg(rest_mj, rest_clip)
        err = _angle_deg(pos[:, ic] - pos[:, ib], cpos[:, jc] - cpos[:, jb])
        assert err.max() <= rest + 1.0, (body, child, err.max(), rest)
        if rest < 3.0:
            assert err.max() < 3.0, (body, child, err.max())
        worst = max(worst, float(err.max()))
        checked += 1
    assert checked == 25  # 30 parent-child pairs less those five
    assert worst < 12.0


def _key(drive, body):
    return next(k for k, v in drive.mapping.items() if v == body)


def test_hinges_carry_the_amc_angles(cmu):
    """dm_control built the humanoid from the CMU ASF (hinges rz, ry, rx in the bone's axis frame),
    so the decomposed hinge angles are the AMC's own dof values: exactly where the model's body
    frames equal the ASF axes, within 1 degree where the model rounds them (e.g. quat "1 0 0
    0.17365" for 20 degrees). The thumbs are the exception: their model frame differs from the
    ASF's, two hinges cannot follow, and the projection differs by up to ~45 degrees."""
    clip, drive, q, _, _ = cmu
    asf = read_asf(asset(ASF))
    values: dict[str, list[list[float]]] = {}
    for ln in open(asset(AMC)).read().splitlines():
        t = ln.split()
        if t and not ln.startswith((":", "#")) and not t[0].isdigit():
            values.setdefault(t[0], []).append([float(x) for x in t[1:]])
    m = drive.model
    exact = {"lowerback", "upperback", "thorax", "lowerneck", "upperneck", "head", "lclavicle",
             "rclavicle"}
    compared = 0
    for b in asf.bones:
        if not b.dof or b.name in ("lthumb", "rthumb"):
            continue
        amc = np.radians(np.array(values[b.name]))
        for c, dof in enumerate(b.dof):
            jid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, b.name + dof)
            d = q[:, m.jnt_qposadr[jid]] - amc[:, c]
            d = np.degrees(np.abs((d + np.pi) % (2 * np.pi) - np.pi))
            assert d.max() < (1e-6 if b.name in exact else 1.0), (b.name, dof, d.max())
            compared += 1
    assert compared == 56 - 4  # every hinge but the thumbs' four


def test_root_follows_the_clip(cmu):
    clip, drive, q, rot, pos = cmu
    wr, wp = clip.world()
    d_root = quat.mul(wr[:, 0], quat.conj(clip.rest_world()[0][0]))
    expect = wp[:, 0] + quat.rotate(d_root, drive.rest_offset)
    np.testing.assert_allclose(pos[:, drive.body_names.index("root")], expect, atol=1e-9)
    # Rest offset: both roots are the pelvis; only the overlay of two different skeletons is left.
    assert np.linalg.norm(drive.rest_offset) < 0.05
    # The root's world rotation is the clip's delta applied to the model's rest rotation.
    rest_rot, _ = drive.kinematics(drive.model.qpos0[None])
    target = quat.mul(d_root, rest_rot[0, drive.body_names.index("root")])
    assert np.degrees(quat.angle(quat.mul(quat.conj(target), rot[:, 0]))).max() < 1e-6
    # The model stands on the floor like the clip: the lowest body z over the take is near 0.
    assert -0.05 < pos[..., 2].min() < 0.1


def test_times_interpolate_and_match_frames(cmu):
    clip, drive, q, rot, pos = cmu
    r, p = drive.world(clip.times[[0, 10, 500]])
    np.testing.assert_allclose(p, pos[[0, 10, 500]], atol=1e-9)
    r2, p2 = drive.world(np.array([10.5 / clip.fps]))
    assert r2.shape == (1, 31, 4) and p2.shape == (1, 31, 3)
    # Half way between frames 10 and 11 lies between them.
    assert np.all(np.linalg.norm(p2[0] - 0.5 * (pos[10] + pos[11]), axis=-1) < 0.01)


def test_joint_map_from_bvh_names(cmu):
    """The BVH of the same take, mapped by joint_map (BVH name -> body), poses the model with the
    same world rotations (BVH and AMC rotations agree to 0.0003 degrees, see test_acclaim)."""
    clip, drive, _, rot, _ = cmu
    bvh = read_bvh(asset("mocap/cmu_bvh/01_01.bvh")).frames(0, 200)
    from bvh_reference import BVH_TO_ASF
    d2 = MjcfDrive(asset(HUMANOID), bvh, joint_map=BVH_TO_ASF)
    r2, _ = d2.world()
    err = np.degrees(quat.angle(quat.mul(quat.conj(rot[:200]), r2)))
    assert err.max() < 0.01


def test_bad_maps_name_the_key(cmu):
    clip = cmu[0]
    with pytest.raises(InputError, match="no body 'left_thigh'") as e:
        MjcfDrive(asset(HUMANOID), clip, joint_map={"lfemur": "left_thigh"})
    assert e.value.field == "joint_map['lfemur']" and e.value.path == str(asset(HUMANOID))
    with pytest.raises(InputError, match="no joint 'LeftUpLeg'") as e:
        MjcfDrive(asset(HUMANOID), clip, joint_map={"LeftUpLeg": "lfemur"})
    assert e.value.field == "joint_map['LeftUpLeg']"
    with pytest.raises(InputError, match="already driven by clip joint 'lfemur'") as e:
        MjcfDrive(asset(HUMANOID), clip, joint_map={"lfemur": "lfemur", "rfemur": "lfemur"})
    assert e.value.field == "joint_map['rfemur']"
    renamed = Clip(["hips"], [-1], np.zeros((1, 3)), quat.identity((1,)), quat.identity((1, 1)),
                   np.zeros((1, 1, 3)), 30.0)
    with pytest.raises(InputError, match="pass joint_map"):
        MjcfDrive(asset(HUMANOID), renamed)


def _variant(tmp_path, old: str, new: str) -> str:
    """A copy of the humanoid with one edit, beside a link to its common/ folder."""
    src = asset(HUMANOID)
    text = open(src).read()
    assert old in text
    os.symlink(os.path.join(os.path.dirname(src), "common"), tmp_path / "common")
    p = tmp_path / "humanoid.xml"
    p.write_text(text.replace(old, new))
    return str(p)


def test_y_up_model_is_refused(tmp_path, cmu):
    p = _variant(tmp_path, 'pos="0 0 1" euler="90 0 0"', 'pos="0 1 0" euler="0 0 0"')
    with pytest.raises(InputError, match=r"turned (8[5-9]|9[0-5]) degrees") as e:
        MjcfDrive(p, cmu[0])
    assert e.value.field == "orientation" and e.value.path == p


def test_sideways_gravity_is_refused(tmp_path, cmu):
    p = _variant(tmp_path, '<statistic', '<option gravity="0 -9.81 0"/>\n  <statistic')
    with pytest.raises(InputError, match="off -z") as e:
        MjcfDrive(p, cmu[0])
    assert e.value.field == "option gravity"


def test_missing_and_broken_models(tmp_path, cmu):
    with pytest.raises(InputError, match="not found"):
        MjcfDrive(tmp_path / "none.xml", cmu[0])
    bad = tmp_path / "bad.xml"
    bad.write_text("<mujoco><worldbody><body name='a'><joint type='bogus'/></body></worldbody></mujoco>")
    with pytest.raises(InputError, match="MuJoCo cannot load") as e:
        MjcfDrive(bad, cmu[0])
    assert e.value.path == str(bad)


# ---------------------------------------------------------------------------------------- no assets
def _chain_clip(T: int = 40, seed: int = 0) -> Clip:
    """root -> a -> b, random smooth rotations, root moving."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 1, T)[:, None, None]
    rv = rng.normal(size=(1, 3, 3)) * t * 1.5
    from scipy.spatial.transform import Rotation
    rot = quat.from_xyzw(Rotation.from_rotvec(rv.reshape(-1, 3)).as_quat()).reshape(T, 3, 4)
    offsets = np.array([[0, 0, 1.0], [0, 0, 0.3], [0.2, 0, 0.1]])
    tra = np.broadcast_to(offsets, (T, 3, 3)).copy()
    tra[:, 0] += np.linspace(0, 1, T)[:, None] * [0.5, 0.2, 0]
    return Clip(["root", "a", "b"], [-1, 0, 1], offsets, quat.identity((3,)), rot, tra, 30.0,
                end_parents=[2], end_offsets=[[0.0, 0.0, 0.25]])


def test_free_ball_and_hinges_small_model(tmp_path):
    """A model whose rest pose equals the clip's: free root, ball joint and an orthonormal hinge
    triad (axes permuted and one flipped) reproduce the clip's world rotations exactly."""
    xml = """<mujoco><worldbody>
      <body name="root" pos="0 0 1"><freejoint/><geom size="0.05"/>
        <body name="a" pos="0 0 0.3"><joint type="ball"/><geom size="0.05"/>
          <body name="b" pos="0.2 0 0.1">
            <joint type="hinge" axis="0 1 0"/><joint type="hinge" axis="0 0 -1"/>
            <joint type="hinge" axis="1 0 0"/><geom size="0.05"/>
            <body name="tip" pos="0 0 0.25"><geom size="0.02"/></body>
          </body></body></body></worldbody></mujoco>"""
    p = tmp_path / "chain.xml"
    p.write_text(xml)
    clip = _chain_clip()
    drive = MjcfDrive(p, clip)
    assert drive.mapping == {"root": "root", "a": "a", "b": "b"}
    np.testing.assert_allclose(drive.rest_offset, 0.0, atol=1e-12)
    r, pos = drive.world()
    wr, wp = clip.world()
    for name in ("root", "a", "b"):
        err = quat.angle(quat.mul(quat.conj(wr[:, clip.index(name)]), r[:, drive.body_names.index(name)]))
        assert err.max() < 1e-8, name
        np.testing.assert_allclose(pos[:, drive.body_names.index(name)], wp[:, clip.index(name)], atol=1e-9)
    np.testing.assert_allclose(pos[:, drive.body_names.index("tip")], clip.end_world(wr, wp)[:, 0], atol=1e-9)


def _hinge_product(axes, ang):
    q = quat.identity((ang.shape[0],))
    for k in range(len(axes)):
        q = quat.mul(q, quat.from_axis_angle(axes[k] / np.linalg.norm(axes[k]), ang[:, k]))
    return q


def test_hinge_angles_exact_for_reachable_rotations():
    rng = np.random.default_rng(3)
    cases = [np.eye(3), np.eye(3)[[2, 1, 0]], np.array([[0, 0, 1.0], [0, -1, 0], [1, 0, 0]]),
             np.array([[1, 0, 0.0], [0, 1, 0]]), np.array([[0, 0, 1.0]]),
             np.array([[1, 0, 0.0], [1, 1, 0], [0, 1, 1]]),  # non-orthogonal
             np.array([[1, 0, 0.0], [0, 1, 0], [0, 0, 1], [1, 0, 0]])]  # four (angles not unique)
    for axes in cases:
        ang = rng.uniform(-1.2, 1.2, size=(200, len(axes)))
        q = _hinge_product(axes, ang)
        got = hinge_angles(q, axes)
        back = _hinge_product(axes, got)
        assert np.degrees(quat.angle(quat.mul(quat.conj(q), back))).max() < 1e-6, axes
        if len(axes) < 3 or (len(axes) == 3 and np.allclose(axes @ axes.T, np.eye(3))):
            np.testing.assert_allclose(got, ang, atol=1e-8)


def test_hinge_angles_project_unreachable_rotations():
    """One or two hinges: the angles give the reachable rotation nearest to the target, checked
    against a brute-force grid of angles (2 degree steps) and against small perturbations."""
    rng = np.random.default_rng(4)
    from scipy.spatial.transform import Rotation
    q = quat.from_xyzw(Rotation.from_rotvec(rng.normal(size=(200, 3)) * 1.0).as_quat())
    grid = np.radians(np.arange(-180.0, 180.0, 2.0))
    for axes in (np.array([[0, 0, 1.0]]), np.array([[1, 0, 0.0], [0, 1, 0]]),
                 np.array([[1, 0, 0.0], [1, 1, 0]])):
        k = len(axes)
        got = hinge_angles(q, axes)
        err = quat.angle(quat.mul(quat.conj(q), _hinge_product(axes, got)))
        G = np.stack(np.meshgrid(*[grid] * k, indexing="ij"), -1).reshape(-1, k)
        brute = 2.0 * np.arccos(np.clip(np.abs(q @ _hinge_product(axes, G).T).max(axis=1), 0.0, 1.0))
        assert np.all(err <= brute + 1e-9), axes
        for i in range(k):
            for delta in (-1e-3, 1e-3):
                g = got.copy()
                g[:, i] += delta
                assert np.all(err <= quat.angle(quat.mul(quat.conj(q), _hinge_product(axes, g))) + 1e-12)
