"""Drive a user's own MuJoCo model (MJCF) with a clip, through a map from clip joints to bodies.

`sim.drive.skeleton` builds a model from the clip; here the model comes from the user (for example
dm_control's CMU humanoid, a free root and hinge triads named after the ASF bones) and the clip's
motion is transferred onto it by rest-pose alignment:

- Both rest poses are taken as "the same pose": the clip's rest pose (its hierarchy) and the
  model's pose at ``qpos0``. For a mapped clip joint j and body b, the clip's world delta rotation
  ``D_j(t) = W_j(t) W_j,rest^-1`` is applied to the body's world rest rotation:
  ``T_b(t) = D_j(t) R_b(qpos0)``.
- Each target is expressed relative to the body's parent as the parent is actually posed (so that a
  joint that cannot follow exactly does not push its error onto the bones below), and relative to
  the body's own ``quat``; that rotation ``Q_b`` is then put onto the body's joints:

  * free joint: position and ``T_b`` as its quaternion. Its position is the clip joint's world
    position plus the rest offset between the two roots, carried by ``D_j(t)``. The rest offset is
    measured with the two rest skeletons overlaid by the one translation that best matches the
    rest positions of all mapped joints (least squares: the mean difference), so a model standing at
    z = 1 m and a clip whose rest root sits at the origin still land on the same floor.
  * ball joint: ``Q_b`` itself.
  * hinges: angles with ``R(a1, q1) R(a2, q2) R(a3, q3) = Q_b`` (MuJoCo composes a body's joints
    in order, axes in the body frame). Three orthonormal axes: an exact Euler decomposition in the
    hinges' own frame. One or two hinges cannot reach every rotation: the angles are the
    projection, the reachable rotation at the least angle from ``Q_b`` (closed forms: the twist
    about one axis; the top singular pair of a 2x2 matrix for two, see :func:`hinge_angles`).
    Other hinge sets (three non-orthogonal axes, more than three): Gauss-Newton on the
    rotation-vector error.
    Angles are unwrapped over time; hinge ``range`` limits are not applied (kinematics only).
  * slide joints stay at ``qpos0`` (the clip's non-root translations are not transferred).
  Bodies without a mapped clip joint keep their joints at ``qpos0`` and follow their parent; a
  model without a free joint stays where ``qpos0`` puts its root (fixed base), only its joints
  turn.

Both sides must be Z-up (jiggle's readers convert clips; MuJoCo models usually are). The
constructor checks it by numbers: gravity must point down -z when the model has gravity, and the
rotation that best aligns the model's rest bone directions with the clip's (Kabsch, over mapped
bodies with a mapped child) must be small; otherwise the model is probably Y-up, or its qpos0 is
not a rest pose, and an InputError says so.
"""
from __future__ import annotations

import os
import warnings

import mujoco
import numpy as np
from scipy.spatial.transform import Rotation

from jiggle.rig.base.errors import InputError, require_file
from jiggle.rig.motion import quat
from jiggle.rig.motion.clip import Clip
from jiggle.sim.drive.skeleton import body_poses

MAX_REST_MISALIGNMENT_DEG = 45.0  # Kabsch angle above which the two rest poses are not comparable


def _obj_name(m: mujoco.MjModel, kind, i: int) -> str:
    return mujoco.mj_id2name(m, kind, i) or ""


class MjcfDrive:
    """A user MJCF posed from a clip by rest-pose alignment (see the module docstring).

    Parameters
    ----------
    xml_path : the model file; ``<include>`` and asset paths resolve relative to its folder.
    clip : the motion (Z-up, metres).
    joint_map : clip joint name -> MJCF body name. Default (None): every clip joint whose name is
        also a body name maps to that body. Keys must be clip joints and values model bodies, each
        body at most once; otherwise an InputError names the key (field ``joint_map[key]``).

    Attributes
    ----------
    model, data : mujoco.MjModel / MjData.
    body_names : (B,) names of the model's bodies except the world, MuJoCo order (the B of
        :meth:`world`).
    mapping : dict clip joint name -> body name actually used.
    rest_misalignment_deg : float, the Kabsch rotation angle (degrees) between the rest bone
        directions of model and clip; small when both are Z-up and in similar rest poses.
    rest_offset : (3,) float64, metres, world rest offset from the clip's root joint to the model's
        free root (see the module docstring).
    """

    def __init__(self, xml_path: str | os.PathLike, clip: Clip, joint_map: dict[str, str] | None = None):
        p = require_file(xml_path, "MJCF model")
        try:
            self.model = mujoco.MjModel.from_xml_path(p)
        except ValueError as e:  # MuJoCo's parse and compile errors
            raise InputError(f"MuJoCo cannot load the model: {e}".strip(), p) from None
        self.xml_path = p
        self.clip = clip
        m = self.model
        self.data = mujoco.MjData(m)
        body_ids = {_obj_name(m, mujoco.mjtObj.mjOBJ_BODY, b): b for b in range(1, m.nbody)}
        self.body_names = tuple(_obj_name(m, mujoco.mjtObj.mjOBJ_BODY, b) for b in range(1, m.nbody))

        if joint_map is None:
            joint_map = {n: n for n in clip.joint_names if n in body_ids}
            if not joint_map:
                raise InputError("no clip joint has the name of a model body; pass joint_map "
                                 "(clip joint -> body)", p, field="joint_map")
        used: dict[str, str] = {}
        for key, body in joint_map.items():
            fld = f"joint_map[{key!r}]"
            if key not in clip.joint_names:
                raise InputError(f"the clip has no joint {key!r}", p, field=fld)
            if body not in body_ids:
                raise InputError(f"the model has no body {body!r}", p, field=fld)
            if body in used:
                raise InputError(f"body {body!r} is already driven by clip joint {used[body]!r}", p,
                                 field=fld)
            used[body] = key
        self.mapping = dict(joint_map)
        # body id -> clip joint index, for the mapped bodies
        self._src = {body_ids[b]: clip.index(k) for k, b in self.mapping.items()}

        # Rest: the model at qpos0, the clip's hierarchy pose.
        mujoco.mj_kinematics(m, self.data)
        self._rest_xquat = self.data.xquat.copy()  # (nbody, 4)
        self._rest_xpos = self.data.xpos.copy()  # (nbody, 3)
        self._clip_rest_rot, self._clip_rest_pos = clip.rest_world()

        self._plan = self._joint_plan()
        self._check_orientation()
        self.rest_offset = self._root_rest_offset()

    # ------------------------------------------------------------------ setup
    def _joint_plan(self) -> list[tuple[int, str, list[int]]]:
        """Per body with joints: (body id, kind, joint ids), kind in free/ball/hinge/slide-only."""
        m = self.model
        plan = []
        for b in range(1, m.nbody):
            jids = [j for j in range(m.body_jntadr[b], m.body_jntadr[b] + m.body_jntnum[b])] \
                if m.body_jntnum[b] > 0 else []
            types = [int(m.jnt_type[j]) for j in jids]
            if not jids:
                continue
            if mujoco.mjtJoint.mjJNT_FREE in types:
                plan.append((b, "free", jids))
            elif mujoco.mjtJoint.mjJNT_BALL in types:
                rot = [j for j in jids if m.jnt_type[j] != mujoco.mjtJoint.mjJNT_SLIDE]
                if len(rot) != 1:
                    raise InputError(f"body {_obj_name(m, mujoco.mjtObj.mjOBJ_BODY, b)!r} mixes a ball "
                                     f"joint with other rotational joints; expected one ball or hinges",
                                     self.xml_path, field="joints")
                plan.append((b, "ball", rot))
            else:
                plan.append((b, "hinge", [j for j in jids if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE]))
        return plan

    def _bone_pairs(self) -> list[tuple[int, int, int, int]]:
        """(body, child body, clip joint, clip child joint) for mapped bodies whose first mapped
        child body is driven by a clip joint."""
        m = self.model
        pairs = []
        for b, j in self._src.items():
            for c in range(b + 1, m.nbody):
                if m.body_parentid[c] == b and c in self._src:
                    pairs.append((b, c, j, self._src[c]))
                    break
        return pairs

    def _check_orientation(self) -> None:
        m = self.model
        g = np.asarray(m.opt.gravity, float)
        if np.linalg.norm(g) > 0:
            down = np.degrees(np.arccos(np.clip(-g[2] / np.linalg.norm(g), -1.0, 1.0)))
            if down > 1.0:
                raise InputError(f"gravity {g.tolist()} is {down:.1f} degrees off -z; jiggle is Z-up "
                                 f"(rotate the model's worldbody so that z is up)", self.xml_path,
                                 field="option gravity")
        pairs = self._bone_pairs()
        if len(pairs) < 2:
            self.rest_misalignment_deg = 0.0  # too few bones to tell an orientation
            return
        a = np.array([self._rest_xpos[c] - self._rest_xpos[b] for b, c, _, _ in pairs])
        cp = self._clip_rest_pos
        u = np.array([cp[jc] - cp[j] for _, _, j, jc in pairs])
        keep = (np.linalg.norm(a, axis=1) > 1e-6) & (np.linalg.norm(u, axis=1) > 1e-6)
        a = a[keep] / np.linalg.norm(a[keep], axis=1, keepdims=True)
        u = u[keep] / np.linalg.norm(u[keep], axis=1, keepdims=True)
        if len(a) < 2:
            self.rest_misalignment_deg = 0.0
            return
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # SciPy warns on degenerate (collinear) sets
            rot, _ = Rotation.align_vectors(u, a)
        self.rest_misalignment_deg = float(np.degrees(rot.magnitude()))
        if self.rest_misalignment_deg > MAX_REST_MISALIGNMENT_DEG:
            raise InputError(
                f"the model's rest pose (qpos0) is turned {self.rest_misalignment_deg:.0f} degrees "
                f"from the clip's rest pose (best fit over {len(a)} bone directions); both must be "
                f"Z-up and in a similar rest pose (is the model Y-up?)", self.xml_path, field="orientation")

    def _root_rest_offset(self) -> np.ndarray:
        """World offset (3,) metres from the clip joint driving the free root to the root body, with
        the rest skeletons overlaid by the least-squares translation over all mapped joints."""
        free = [b for b, kind, _ in self._plan if kind == "free" and b in self._src]
        if not free:
            return np.zeros(3)
        b = free[0]
        ids = list(self._src)
        shift = np.mean([self._clip_rest_pos[self._src[i]] - self._rest_xpos[i] for i in ids], axis=0)
        return self._rest_xpos[b] + shift - self._clip_rest_pos[self._src[b]]

    # ------------------------------------------------------------------ qpos
    def qpos(self, times: np.ndarray | None = None) -> np.ndarray:
        """(N, nq) float64 qpos at `times` (seconds from the clip's start; the clip is
        interpolated), or at every clip frame when `times` is None."""
        if times is None:
            rot, tra = self.clip.rotations, self.clip.translations
        else:
            rot, tra = self.clip.sample(times)
        wr, wp = self.clip.world(rot, tra)  # (N, J, 4), (N, J, 3)
        delta = quat.mul(wr, quat.conj(self._clip_rest_rot)[None])  # D_j(t), world
        m = self.model
        n = wr.shape[0]
        q = np.tile(m.qpos0, (n, 1))
        # Achieved world rotation of every body, filled parents first (MuJoCo orders bodies so).
        achieved = np.empty((n, m.nbody, 4))
        achieved[:, 0] = quat.IDENTITY
        plan = {b: (kind, jids) for b, kind, jids in self._plan}
        for b in range(1, m.nbody):
            parent_rot = achieved[:, m.body_parentid[b]]
            base = quat.mul(parent_rot, m.body_quat[b])  # the body with its joints at zero
            kind, jids = plan.get(b, (None, []))
            if b not in self._src or kind is None:
                achieved[:, b] = self._pose_joints(base, q, kind, jids)
                continue
            j = self._src[b]
            target = quat.mul(delta[:, j], self._rest_xquat[b])  # T_b(t)
            if kind == "free":
                a = m.jnt_qposadr[jids[0]]
                q[:, a:a + 3] = wp[:, j] + quat.rotate(delta[:, j], self.rest_offset)
                q[:, a + 3:a + 7] = quat.make_continuous(quat.canonical(target))
                achieved[:, b] = target
                continue
            local = quat.mul(quat.conj(base), target)  # Q_b: the joints' rotation
            if kind == "ball":
                a = m.jnt_qposadr[jids[0]]
                q[:, a:a + 4] = quat.make_continuous(quat.canonical(local))
                achieved[:, b] = target
                continue
            if jids:
                axes = np.array([m.jnt_axis[k] for k in jids])
                ang = hinge_angles(local, axes)
                for c, k in enumerate(jids):
                    q[:, m.jnt_qposadr[k]] = m.qpos0[m.jnt_qposadr[k]] + ang[:, c]
            achieved[:, b] = self._pose_joints(base, q, kind, jids)
        return q

    def _pose_joints(self, base: np.ndarray, q: np.ndarray, kind: str | None, jids: list[int]) -> np.ndarray:
        """World rotation (N, 4) of a body whose frame with joints at zero is `base`, for the joint
        values already in q."""
        m = self.model
        if kind == "free":
            a = m.jnt_qposadr[jids[0]]
            return quat.normalize(q[:, a + 3:a + 7])
        if kind == "ball":
            a = m.jnt_qposadr[jids[0]]
            return quat.mul(base, quat.normalize(q[:, a:a + 4]))
        out = base
        for k in jids if kind == "hinge" else []:
            a = m.jnt_qposadr[k]
            out = quat.mul(out, quat.from_axis_angle(m.jnt_axis[k], q[:, a] - m.qpos0[a]))
        return out

    # ------------------------------------------------------------------ kinematics
    def kinematics(self, qpos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World rotations (N, B, 4) w,x,y,z and positions (N, B, 3) metres of every body but the
        world (order of `body_names`) for qpos (N, nq), by mj_kinematics."""
        return body_poses(self.model, self.data, qpos, np.arange(1, self.model.nbody))

    def world(self, times: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Body world rotations (N, B, 4) and positions (N, B, 3) metres at `times` seconds
        (default: every clip frame), through MuJoCo."""
        return self.kinematics(self.qpos(times))


def hinge_angles(q: np.ndarray, axes: np.ndarray, iterations: int = 20) -> np.ndarray:
    """Hinge angles (N, k) radians such that R(a1, t1) ... R(ak, tk) best equals rotations q (N, 4).

    axes : (k, 3) hinge axes in the body frame (normalised here), k >= 1, composed in order
        (intrinsic, as MuJoCo composes a body's joints).

    "Best" is the least rotation angle between the two, i.e. the largest |<q, q(t)>| of the unit
    quaternions. One hinge: the twist of q about its axis (exact optimum). Two hinges: with
    half-angle (c_i, s_i), <q, q1 q2> = (c1, s1) M (c2, s2)^T for a 2x2 M, so the optimum is the
    top singular pair of M (exact, any two axes). Three orthonormal axes: exact Euler decomposition
    in the hinges' frame. Any other set (three non-orthogonal, or more than three): Gauss-Newton on
    the rotation-vector error from the twists about each axis in turn. Angles are wrapped to
    (-pi, pi], then unwrapped along N.
    """
    q = np.asarray(q, float)
    a = np.asarray(axes, float)
    a = a / np.linalg.norm(a, axis=1, keepdims=True)
    k = a.shape[0]
    n = q.shape[0]
    if k == 0:
        return np.zeros((n, 0))
    if k == 1:
        ang = (2.0 * np.arctan2(q[:, 1:] @ a[0], q[:, 0]))[:, None]
    elif k == 2:
        a12 = quat.mul(np.r_[0.0, a[0]], np.r_[0.0, a[1]])  # the product of the two pure axes
        M = np.stack([np.stack([q[:, 0], q[:, 1:] @ a[1]], -1),
                      np.stack([q[:, 1:] @ a[0], q @ a12], -1)], -2)  # (N, 2, 2)
        u, _, vt = np.linalg.svd(M)
        ang = 2.0 * np.stack([np.arctan2(u[:, 1, 0], u[:, 0, 0]), np.arctan2(vt[:, 0, 1], vt[:, 0, 0])], -1)
    elif k == 3 and np.allclose(a @ a.T, np.eye(3), atol=1e-6):
        # Columns a1, a2, a3 (the third flipped if needed to make B a proper rotation):
        # R(ai, t) = B R(ei, t) B^T, so B^T Q B = Rx(t1) Ry(t2) Rz(t3), intrinsic "XYZ".
        third = np.cross(a[0], a[1])
        sign = float(np.sign(third @ a[2]))
        B = np.stack([a[0], a[1], third], axis=1)
        local = B.T[None] @ quat.to_matrix(q) @ B[None]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # gimbal lock: SciPy still returns a valid solution
            ang = Rotation.from_matrix(local).as_euler("XYZ")
        ang[:, 2] *= sign
    else:
        ang = np.zeros((n, k))
        rest = q
        for i in range(k):  # twist about each axis in turn
            ang[:, i] = 2.0 * np.arctan2(rest[:, 1:] @ a[i], rest[:, 0])
            rest = quat.mul(quat.conj(quat.from_axis_angle(a[i], ang[:, i])), rest)
        ang = _gauss_newton(q, a, ang, iterations)
    ang = np.mod(ang + np.pi, 2.0 * np.pi) - np.pi
    return np.unwrap(ang, axis=0)


def _compose(a: np.ndarray, ang: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
    """R(a1, t1) ... R(ak, tk) as (N, 4), and tails (k + 1 of them) with tails[i] = R_i ... R_k
    (0-based; tails[k] is the identity)."""
    n, k = ang.shape
    out = quat.identity((n,))
    tails = [quat.identity((n,))]
    for i in reversed(range(k)):
        out = quat.mul(quat.from_axis_angle(a[i], ang[:, i]), out)
        tails.append(out)
    return out, tails[::-1]


def _gauss_newton(q: np.ndarray, a: np.ndarray, ang: np.ndarray, iterations: int) -> np.ndarray:
    """Minimise |log(R(ang)^T q)| over the angles (N, k), vectorised over N."""
    ang = ang.copy()
    k = a.shape[0]
    for _ in range(iterations):
        r, tails = _compose(a, ang)
        err_q = quat.canonical(quat.mul(quat.conj(r), q))  # in the frame after all joints
        e = quat.to_rotvec(err_q)  # (N, 3)
        # d/dt_i of R: axis a_i seen from the end frame, b_i = (R_{i+1} ... R_k)^T a_i; then
        # de/dt_i = -Jl^-1(e) b_i (the inverse left Jacobian of SO(3)), exact for large errors too.
        B = np.stack([quat.rotate(quat.conj(tails[i + 1]), np.broadcast_to(a[i], e.shape))
                      for i in range(k)], axis=-1)  # (N, 3, k)
        J = _inv_left_jacobian(e) @ B
        step = (np.linalg.pinv(J) @ e[..., None])[..., 0]
        ang += step
        if np.max(np.abs(step)) < 1e-12:
            break
    return ang


def _inv_left_jacobian(phi: np.ndarray) -> np.ndarray:
    """(N, 3, 3) inverse left Jacobian of SO(3) at rotation vectors phi (N, 3):
    I - [phi]/2 + (1/t^2 - (1 + cos t) / (2 t sin t)) [phi]^2, t = |phi| (series for small t)."""
    t = np.linalg.norm(phi, axis=-1)
    K = np.zeros(phi.shape[:-1] + (3, 3))
    K[..., 0, 1], K[..., 0, 2], K[..., 1, 2] = -phi[..., 2], phi[..., 1], -phi[..., 0]
    K[..., 1, 0], K[..., 2, 0], K[..., 2, 1] = phi[..., 2], -phi[..., 1], phi[..., 0]
    small = t < 1e-4
    ts = np.where(small, 1.0, t)
    c = np.where(small, 1.0 / 12.0, 1.0 / ts**2 - (1.0 + np.cos(ts)) / (2.0 * ts * np.sin(ts)))
    return np.eye(3) - 0.5 * K + c[..., None, None] * (K @ K)


def read_body_map(path: str | os.PathLike) -> dict[str, str]:
    """Read a clip-joint -> MJCF-body map from TOML: a ``[joints]`` table of ``clip_joint = "body"``."""
    from jiggle.rig.base.tomlfile import read_toml

    p, doc = read_toml(path, "joint map")
    table = doc.get("joints")
    if not isinstance(table, dict) or not table:
        raise InputError('expected a [joints] table of clip_joint = "body" entries', p, field="joints")
    for k, v in table.items():
        if not isinstance(v, str) or not v:
            raise InputError(f"expected a body name, found {v!r}", p, field=f"joints.{k}")
    return dict(table)
