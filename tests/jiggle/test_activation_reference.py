"""The MyoSuite reference of benchmarks/activation_reference.py: myolegs26 posed from a clip's leg geometry, its
muscles' arms as torque vectors, and the timing measure against published EMG."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("myo_sim", reason="MyoSuite's models (myo-sim) are not installed; ./dev.sh install brings them")
sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
import activation_reference as ar  # noqa: E402


@pytest.fixture(scope="module")
def ref():
    return ar.Reference()


def _turn(axis, deg):
    from scipy.spatial.transform import Rotation
    return Rotation.from_rotvec(np.radians(deg) * np.asarray(axis, float)).as_matrix()


def _legs_of(ref, root, q):
    """The leg geometry clip_legs reads from a clip, read off the reference posed at root (3, 3) and angles q."""
    ref.pose(root, q)
    out = {"pelvis": (root @ ref.rest_frame)[None]}
    for s in ref.legs:
        th, sh, ft = ref.directions(s)
        out[s] = {"thigh": th[None], "shank": sh[None], "foot": ft[None],
                  "bend": np.array([ref.ankle_bend(s) - ref.rest_bend[s]])}
    return out


def test_the_pose_fit_finds_the_angles_that_made_the_legs(ref):
    root = _turn([0, 0, 1], 40) @ _turn([1, 0, 0], 15)       # turned and leaning
    q = {"l": np.array([0.9, -0.1, 0.2, -1.2, 0.25]), "r": np.array([-0.2, 0.15, -0.1, -0.3, -0.5])}
    roots, fitted, miss = ar.fit_pose(ref, _legs_of(ref, root, q))
    assert np.allclose(roots[0], root, atol=1e-9)
    assert miss[0] < 0.5
    for s in q:
        # flexion, knee and ankle to a degree; the hip's twist is set by the bent knee and the foot
        assert np.degrees(np.abs(fitted[s][0] - q[s])).max() < 2.0, (s, fitted[s][0], q[s])


def _one_joint(ref, side, joint, torque):
    """The reference's excitations (nu,) for `torque` (3,) N m at one of the leg's joints (0 hip, 1 knee, 2 ankle)
    standing (K = 1)."""
    from jiggle.sim.jiggle.activation import static_optimization
    ref.pose(np.eye(3), {"l": np.zeros(5), "r": np.zeros(5)})
    arms, _, axes = ref.arms_at(side)
    f0 = np.array(ref.model.actuator_gainprm[:, 2])
    tq = np.zeros((1, 3, 3))
    tq[0, joint] = torque
    mine = np.array([n.endswith(f"_{side}") for n in ref.names])
    exc, unmet = static_optimization((arms * mine[:, None, None])[None], tq, f0)
    return dict(zip(ref.names, exc[0])), axes, unmet


def test_the_reference_arms_turn_the_knee_and_ankle_the_right_way(ref):
    axes = _one_joint(ref, "r", 1, np.zeros(3))[1]
    knee, ankle = axes[3], axes[4]           # knee_angle: flexion negative; ankle_angle: dorsiflexion positive
    ext, _, unmet = _one_joint(ref, "r", 1, 60.0 * knee)
    assert ext["vasti_r"] > 0.05 and ext["hamstrings_r"] < 0.01 and ext["bifemsh_r"] < 0.01
    assert np.linalg.norm(unmet) < 1.0
    flex, _, _ = _one_joint(ref, "r", 1, -40.0 * knee)
    assert flex["hamstrings_r"] + flex["bifemsh_r"] + flex["gastroc_r"] > 0.05 and flex["vasti_r"] < 0.01
    push, _, _ = _one_joint(ref, "r", 2, -80.0 * ankle)      # plantarflexion: the calf, not the shin's front
    assert push["soleus_r"] > 0.05 and push["tibant_r"] < 0.01
    lift, _, _ = _one_joint(ref, "r", 2, 10.0 * ankle)
    assert lift["tibant_r"] > 0.01 and lift["soleus_r"] < 0.01
    # the other leg's muscles never answer this leg's torque
    assert max(v for n, v in ext.items() if n.endswith("_l")) == 0.0


def test_the_knee_arms_include_the_moving_via_points(ref):
    """The quadriceps' via points slide with the knee (equality-coupled coordinates): the arm about the knee is the
    length's whole derivative, which a finite difference of the posed length confirms."""
    q = {"l": np.zeros(5), "r": np.array([0.3, 0.0, 0.0, -1.0, 0.0])}
    ref.pose(np.eye(3), q)
    arms, L0, axes = ref.arms_at("r")
    h = 1e-5
    q2 = {"l": q["l"], "r": q["r"] + np.array([0, 0, 0, h, 0])}
    ref.pose(np.eye(3), q2)
    _, L1, _ = ref.arms_at("r")
    dLdq = (L1 - L0) / h
    i = ref.names.index("rectfem_r")
    assert np.isclose(arms[i, 1] @ axes[3], -dLdq[i], rtol=1e-3, atol=1e-6)


def test_the_timing_score_is_the_share_in_the_window_over_its_time():
    contact = np.array([0] * 5 + [1] * 10 + [0] * 10 + [1] * 10 + [0] * 5, bool)
    ph = ar.phases(contact)
    assert np.isnan(ph[:5]).all() and np.isnan(ph[-5:]).all()          # bouts cut by the clip's ends
    assert ph[5] == 0.0 and ph[15] == 1.0 and np.isclose(ph[14], 0.9)
    on_stance = contact.astype(float)
    # whole bouts: two stances, one swing, 10 samples each: all of it in the 2/3 of the time stance takes
    assert ar.timing_score(on_stance, ph, (("stance", 0.0, 1.0),)) == pytest.approx(1.5)
    assert ar.timing_score(np.where(ph >= 1.5, 1.0, 0.0), ph, (("swing", 0.5, 1.0),)) == pytest.approx(6.0)
    assert ar.timing_score(np.ones(len(ph)), ph, (("stance", 0.0, 1.0),)) == pytest.approx(1.0)
    assert ar.timing_score(1.0 - on_stance, ph, (("stance", 0.0, 1.0),)) == pytest.approx(0.0)


def test_the_deep_muscles_on_the_reference_skeleton_have_its_arms(ref):
    """sim.jiggle.deep_muscles placed on a skeleton with myolegs26's own joint centres (standing) turn the hip and
    ankle as its muscles do: the frontal-plane ones exactly, the iliopsoas within 5% (its via point that slides
    with the hip is fixed), the tibialis anterior's flexion arm exactly (the reference's ankle is a hinge)."""
    import mujoco

    from jiggle.sim.jiggle.activation import path_arms
    from jiggle.sim.jiggle.deep_muscles import deep_paths
    ref.pose(np.eye(3), {"l": np.zeros(5), "r": np.zeros(5)})
    arms, _, axes = ref.arms_at("r")
    bodies = ["pelvis", "femur_l", "tibia_l", "talus_l", "toes_l", "femur_r", "tibia_r", "talus_r", "toes_r"]
    parents = np.array([-1, 0, 1, 2, 3, 0, 5, 6, 7])
    world = np.tile(np.eye(4), (len(bodies), 1, 1))
    for i, b in enumerate(bodies):
        world[i, :3, 3] = ref.data.xpos[mujoco.mj_name2id(ref.model, mujoco.mjtObj.mjOBJ_BODY, b)]
    roles = {"hips": 0}
    for s, o in (("left", 1), ("right", 5)):
        roles.update({f"{s}_upper_leg": o, f"{s}_lower_leg": o + 1, f"{s}_foot": o + 2, f"{s}_toe": o + 3})
    names, points, joints, _ = deep_paths(world, roles)
    ours = path_arms(points[None], joints, parents, world[None])[0]
    for mine, theirs, j, k, tol in (("right_hip_adductors", "add_r", 5, 0, 1e-3), ("right_hip_abductors", "abd_r", 5, 0, 1e-3),
                                    ("right_iliopsoas", "iliopsoas_r", 5, 0, 0.05)):
        a, b = ours[names.index(mine), j], arms[ref.names.index(theirs), k]
        assert np.linalg.norm(a - b) <= tol * np.linalg.norm(b) + 1e-5, (mine, a, b)
    ta = ours[names.index("right_tibialis_anterior"), 7] @ axes[4]
    assert ta == pytest.approx(arms[ref.names.index("tibant_r"), 2] @ axes[4], rel=1e-2)   # the table's 0.1 mm
    assert ta > 0.02                                           # a dorsiflexor, 2.5 cm
    # the left side is the right one mirrored (x -> -x: a torque, an axial vector, keeps x and turns y and z)
    assert np.allclose(ours[names.index("left_hip_abductors"), 1],
                       ours[names.index("right_hip_abductors"), 5] * [1, -1, -1], atol=2e-3)
