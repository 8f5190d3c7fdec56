"""An independent reference for the chains (sim/chain): the same physical model stepped in NumPy from scratch, in
maximal coordinates, with no MuJoCo call.

Formulation (Lagrange multipliers on maximal coordinates, as Baraff 1996 "Linear-time dynamics using Lagrange
multipliers", here with a dense solve: a chain has at most tens of links). Each link is a free
rigid body: its centre of mass x, its body frame's orientation Q (world from body), linear velocity v and angular
velocity w (both world). A ball joint keeps the link's joint point o = x - Q c (c : the centre of mass in the body
frame) on its parent's attachment point a = o_p + Q_p p (p : the joint's bind position in the parent's frame); a
chain's root hangs from the animated anchor (kinematic: the animation's transform W_A(t), exactly). Per step h, with
y = (v, w) of every link and the constraint impulses mu (three per joint):

    [ M   G^T ] [ y+  ]   [ M y + h f + (armature momentum) ]      M : m I3 and I_w = Q I_body Q^T per link, plus
    [ G   0   ] [ -mu ] = [ b                               ]          (A + h c) on each joint's relative
                                                                       angular velocity (below)
    G y+ = b : o_i's velocity = a_i's:  v_i + w_i x r_i - v_p - w_p x s_i = 0 (r_i = o_i - x_i, s_i = a_i - x_p),
               for a root  v_i + w_i x r_i = da/dt (the anchor point's velocity at t + h)
    x+ = x + h v+,  Q+ = exp(h [w+]x) Q,  then each joint point put back on its parent's attachment (post-
    stabilization, parents first: o_i = a_i, x_i = o_i + Q_i c_i), so bones keep their length with no drift

(semi-implicit Euler: positions from the new velocities, as MuJoCo's Euler integrator). The forces f, all as the
project's model defines them (sim/chain/simulate.py, sim/chain/model.py), per joint i with child frame Q_i and the
joint's relative rotation from bind q_i = q0_i^-1 (Q_p^-1 Q_i) and relative angular velocity in the child frame
u_i = Q_i^T (w_i - w_p):

    spring        tau = -k rotvec(q_target^-1 q_i)                  (MuJoCo's ball spring, child frame)
    damping       tau = -c (u_i - u_target)                         (implicit in u_i: h c on the coupling)
    feed-forward  tau = -R_i*^T sum_{b below i} (x_b* - o_i*) x m_b g s   at the animated pose (*): the torque
                  that holds that pose against gravity (s : the chain's gravity share), applied in the current
                  child frame (it is a generalized force on the joint's dofs, as qfrc_applied)
    a generalized torque tau on joint i acts as +Q_i tau on the child and -Q_i tau on the parent
    gravity       m g s on every centre of mass;  gyroscopic  -w x I_w w on every link
    armature      A on the joint's dofs: the generalized inertia A du_i/dt, which in world terms is the torque pair
                  -/+ A (d(w_i - w_p)/dt - w_i x (w_i - w_p)) on child / parent, i.e. (w_i - w_p) enters the
                  mass matrix with A (the same coupling as the implicit damping's h c) and A w_i x (w_i - w_p)
                  is an explicit velocity-product term (MuJoCo adds A to the joint's diagonal of M in its own
                  child-frame coordinates; this is the same in world coordinates)

Inputs at each step's middle (t + h/2: the targets, their rates and the feed-forward) and the anchor at the step's
ends; the animation between its knots by C2 splines (scipy CubicSpline for the anchor's position, RotationSpline
for rotations), independent of the project's Hermite interpolation.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.spatial.transform import Rotation, RotationSpline


# ------------------------------------------------------------------------------------------ rotations
def skew(a: np.ndarray) -> np.ndarray:
    """(..., 3, 3) the cross-product matrix [a]x of (..., 3)."""
    z = np.zeros(a.shape[:-1])
    return np.stack([np.stack([z, -a[..., 2], a[..., 1]], -1), np.stack([a[..., 2], z, -a[..., 0]], -1),
                     np.stack([-a[..., 1], a[..., 0], z], -1)], -2)


def exp_map(phi: np.ndarray) -> np.ndarray:
    """(..., 3, 3) the rotation by rotation vector phi (..., 3) (Rodrigues)."""
    th = np.linalg.norm(phi, axis=-1)[..., None, None]
    K = skew(phi)
    small = th < 1e-8
    ths = np.where(small, 1.0, th)
    a = np.where(small, 1.0 - th ** 2 / 6.0, np.sin(ths) / ths)
    b = np.where(small, 0.5 - th ** 2 / 24.0, (1.0 - np.cos(ths)) / ths ** 2)
    return np.eye(3) + a * K + b * (K @ K)


def log_map(R: np.ndarray) -> np.ndarray:
    """(..., 3) the rotation vector (angle in [0, pi]) of rotation matrices R (..., 3, 3)."""
    return Rotation.from_matrix(R.reshape(-1, 3, 3)).as_rotvec().reshape(R.shape[:-2] + (3,))


def wxyz_to_matrix(q: np.ndarray) -> np.ndarray:
    q = np.asarray(q, np.float64)
    return Rotation.from_quat(q.reshape(-1, 4)[:, [1, 2, 3, 0]]).as_matrix().reshape(q.shape[:-1] + (3, 3))


def matrix_to_wxyz(R: np.ndarray) -> np.ndarray:
    q = Rotation.from_matrix(R.reshape(-1, 3, 3)).as_quat()[:, [3, 0, 1, 2]]
    q = q * np.where(q[:, :1] < 0, -1.0, 1.0)
    return q.reshape(R.shape[:-2] + (4,))


# ------------------------------------------------------------------------------------------ the links
@dataclass
class Links:
    """n links, parents first. parent : (n,) index of the parent link, -1 for the root (hangs from the anchor).
    pos : (n, 3) m, the joint's bind position in the parent's body frame. rot : (n, 3, 3) the body frame's bind
    rotation in the parent's frame. mass : (n,) kg. com : (n, 3) m, centre of mass in the body frame.
    inertia : (n, 3, 3) kg m^2 about the centre of mass, body frame. k : (n,) N m/rad. c : (n,) N m s/rad.
    armature : (n,) kg m^2. share : (n,) gravity share. gravity : (3,) m/s^2."""

    parent: np.ndarray
    pos: np.ndarray
    rot: np.ndarray
    mass: np.ndarray
    com: np.ndarray
    inertia: np.ndarray
    k: np.ndarray
    c: np.ndarray
    armature: np.ndarray
    share: np.ndarray
    gravity: np.ndarray

    @property
    def count(self) -> int:
        return len(self.parent)


def links_from_model(cm, select=None) -> Links:
    """The links of a sim.chain.model.ChainModel (its compiled MjModel's arrays: masses, inertias, stiffness,
    damping, armature, gravity, as the project set them; read after a ChainSolver was made, which writes the
    stiffness and damping) or of the links `select` (indices of one chain: its root first)."""
    m = cm.model
    idx = np.arange(cm.links.count) if select is None else np.asarray(select)
    dof = np.asarray(cm.ball_v)[idx]
    jnt = np.asarray(m.dof_jntid)[dof]
    body = np.asarray(m.jnt_bodyid)[jnt]
    where = {int(b): i for i, b in enumerate(body)}
    parent = np.array([where.get(int(m.body_parentid[b]), -1) for b in body], np.int64)
    assert np.allclose(m.jnt_pos[jnt], 0.0), "the ball joints sit at their bodies' origins"
    for a in (m.dof_damping, m.dof_armature):       # isotropic per ball joint
        assert np.allclose(a[dof], a[dof + 1]) and np.allclose(a[dof], a[dof + 2])
    assert (m.jnt_stiffness[jnt] > 0).all(), "stiffness unset: read the model after a ChainSolver was made"
    iq = wxyz_to_matrix(m.body_iquat[body])
    inertia = iq @ (np.asarray(m.body_inertia[body])[:, :, None] * np.swapaxes(iq, -1, -2))
    return Links(parent=parent, pos=np.array(m.body_pos[body]), rot=wxyz_to_matrix(m.body_quat[body]),
                 mass=np.array(m.body_mass[body]), com=np.array(m.body_ipos[body]), inertia=inertia,
                 k=np.array(m.jnt_stiffness[jnt]), c=np.array(m.dof_damping[dof]), armature=np.array(
                     m.dof_armature[dof]), share=1.0 - np.array(m.body_gravcomp[body]),
                 gravity=np.array(m.opt.gravity))


# ------------------------------------------------------------------------------------------ the animation
class Drive:
    """The animation at its knots, splined: the anchor's world transform (K, 4, 4) and each link's target rotation
    from bind (K, n, 4) w,x,y,z. RotationSpline's first derivative is the rate in the rotated (body) frame."""

    def __init__(self, knots: np.ndarray, anchor: np.ndarray, targets: np.ndarray):
        knots = np.asarray(knots, np.float64)
        self.pos = CubicSpline(knots, anchor[:, :3, 3])
        self.rot = RotationSpline(knots, Rotation.from_matrix(anchor[:, :3, :3]))
        self.tgt = [RotationSpline(knots, Rotation.from_matrix(wxyz_to_matrix(targets[:, i])))
                    for i in range(targets.shape[1])]

    def anchor(self, t):
        """(S, 3, 3) rotation, (S, 3) position, (S, 3) world angular velocity, (S, 3) velocity at times t (S,)."""
        R = self.rot(t).as_matrix()
        w = np.einsum("sij,sj->si", R, self.rot(t, 1))
        return R, self.pos(t), w, self.pos(t, 1)

    def target(self, t):
        """(S, n, 3, 3) each target rotation, (S, n, 3) its rate in its own frame, at times t (S,)."""
        R = np.stack([s(t).as_matrix() for s in self.tgt], 1)
        u = np.stack([s(t, 1) for s in self.tgt], 1)
        return R, u


def animated(L: Links, RA, pA, RT):
    """The animated pose: body rotations (S, n, 3, 3), joint points (S, n, 3), centres of mass (S, n, 3), from the
    anchor (RA (S, 3, 3), pA (S, 3)) and the targets RT (S, n, 3, 3): R_i = R_p R0_i RT_i, o_i = o_p + R_p p_i."""
    S, n = len(RA), L.count
    R, o = np.zeros((S, n, 3, 3)), np.zeros((S, n, 3))
    for i in range(n):
        p = L.parent[i]
        Rp, op = (RA, pA) if p < 0 else (R[:, p], o[:, p])
        R[:, i] = Rp @ L.rot[i] @ RT[:, i]
        o[:, i] = op + Rp @ L.pos[i]
    x = o + np.einsum("snij,nj->sni", R, L.com)
    return R, o, x


def feed_forward(L: Links, R, o, x) -> np.ndarray:
    """(S, n, 3) N m, child frame: each joint's torque holding the pose (R, o, x from `animated`) against gravity:
    -R_i^T sum_{b in the subtree of i} (x_b - o_i) x m_b g s_b."""
    n = L.count
    below = [[i] for i in range(n)]
    for i in range(n - 1, -1, -1):          # children after parents: gather subtrees bottom up
        if L.parent[i] >= 0:
            below[L.parent[i]] += below[i]
    out = np.zeros(o.shape)
    for i in range(n):
        f = (L.mass * L.share)[below[i], None] * L.gravity
        tau = np.cross(x[:, below[i]] - o[:, i:i + 1], f[None]).sum(1)
        out[:, i] = -np.einsum("sji,sj->si", R[:, i], tau)
    return out


# ------------------------------------------------------------------------------------------ the run
def simulate(L: Links, drive: Drive, t0: float, t1: float, h: float, start=None) -> tuple[np.ndarray, np.ndarray]:
    """Step from t0 (the animated pose, moving with the animation) to t1 by h: (N+1,) step times and (N+1, n, 4)
    each joint's rotation from its bind frame (w,x,y,z), the project's ChainRun.rotations convention. start :
    ((n, 4) rotations from bind, (n, 3) relative angular velocities in the child frames) to start from instead of
    the animated pose."""
    n = L.count
    N = int(np.ceil((t1 - t0) / h - 1e-9))
    t = t0 + h * np.arange(N + 1)
    tm = t[:-1] + 0.5 * h
    RA, pA, wA, vA = drive.anchor(t)
    RAm, pAm, _, _ = drive.anchor(tm)
    RTm, uTm = drive.target(tm)
    RTmT = np.swapaxes(RTm, -1, -2)
    ff = feed_forward(L, *animated(L, RAm, pAm, RTm))
    anchor_vel = vA[:, None] + np.cross(wA[:, None], np.einsum("sij,nj->sni", RA, L.pos))   # (N+1, n, 3)
    root = L.parent < 0
    kid = np.flatnonzero(~root)                 # joints with a parent link
    par = L.parent[kid]
    pp = np.maximum(L.parent, 0)
    # the start: the animated pose at t0 (or `start`), every link moving with it (w_i = w_p + R_i u_i)
    RT0, uT0 = drive.target(t[:1])
    if start is not None:
        RT0, uT0 = wxyz_to_matrix(np.asarray(start[0]))[None], np.asarray(start[1], np.float64)[None]
    Q, o, x = (a[0] for a in animated(L, RA[:1], pA[:1], RT0))
    w, v = np.zeros((n, 3)), np.zeros((n, 3))
    for i in range(n):
        p = L.parent[i]
        wp, vo = (wA[0], anchor_vel[0, i]) if p < 0 else (w[p], v[p] + np.cross(w[p], o[i] - x[p]))
        w[i] = wp + Q[i] @ uT0[0, i]
        v[i] = vo + np.cross(w[i], x[i] - o[i])
    rel = np.zeros((N + 1, n, 3, 3))
    R0T = np.swapaxes(L.rot, -1, -2)

    def parent_frames(Q, RAk):
        return np.where(root[:, None, None], RAk[None], Q[pp])

    rel[0] = R0T @ np.swapaxes(parent_frames(Q, RA[0]), -1, -2) @ Q
    # the KKT matrix as 3x3 blocks: v_i at block i, w_i at n + i, the joint's impulse at 2n + i
    m6, B = 6 * n, 3 * n
    eye = np.eye(3)
    coup = L.armature + h * L.c              # what multiplies each joint's relative angular velocity in M
    base = np.zeros((B, 3, B, 3))
    bb = base.transpose(0, 2, 1, 3)          # a view: bb[I, J] is the (I, J) block
    ii = np.arange(n)
    bb[ii, ii] = L.mass[:, None, None] * eye
    bb[n + ii, n + ii] = coup[:, None, None] * eye
    np.add.at(bb, (n + par, n + par), coup[kid, None, None] * eye)
    bb[n + kid, n + par] = -coup[kid, None, None] * eye
    bb[n + par, n + kid] = -coup[kid, None, None] * eye
    bb[2 * n + ii, ii] = eye                 # G: v_i - [r_i]x w_i - v_p + [s_i]x w_p
    bb[ii, 2 * n + ii] = eye
    bb[2 * n + kid, par] = -eye
    bb[par, 2 * n + kid] = -eye
    base = base.reshape(3 * B, 3 * B)
    rhs = np.zeros((B, 3))
    fg = h * (L.mass * L.share)[:, None] * L.gravity
    for s in range(N):
        Iw = Q @ L.inertia @ np.swapaxes(Q, -1, -2)
        r = o - x
        Qp = parent_frames(Q, RA[s])
        wp = np.where(root[:, None], wA[s][None], w[pp])
        dw = w - wp
        # generalized torques (child frame): spring, feed-forward, the damping's reference
        q_rel = R0T @ np.swapaxes(Qp, -1, -2) @ Q
        tau = -L.k[:, None] * log_map(RTmT[s] @ q_rel) + ff[s] + L.c[:, None] * uTm[s]
        T = np.einsum("nij,nj->ni", Q, tau)                                       # world, on the child
        arm = L.armature[:, None] * (dw + h * np.cross(w, dw))                   # old armature momentum + product
        kkt = base.copy()
        kb = kkt.reshape(B, 3, B, 3).transpose(0, 2, 1, 3)
        kb[n + ii, n + ii] += Iw
        kb[2 * n + ii, n + ii] = -skew(r)
        kb[n + ii, 2 * n + ii] = skew(r)
        sk = skew(o[par] + np.einsum("kij,kj->ki", Qp[kid], L.pos[kid]) - x[par])
        kb[2 * n + kid, n + par] = sk
        kb[n + par, 2 * n + kid] = -sk
        rhs[:n] = L.mass[:, None] * v + fg
        rhs[n:2 * n] = np.einsum("nij,nj->ni", Iw, w) + h * (T - np.cross(w, np.einsum("nij,nj->ni", Iw, w))) + arm
        np.add.at(rhs, n + par, -(h * T[kid] + arm[kid]))
        rhs[n:2 * n][root] += coup[root, None] * wA[s + 1]      # (A + h c)(w_i+ - w_A+): w_A+ is known
        rhs[2 * n:] = 0.0
        rhs[2 * n:][root] = anchor_vel[s + 1, root]
        y = np.linalg.solve(kkt, rhs.ravel())[:m6]
        v, w = y[:3 * n].reshape(n, 3), y[3 * n:].reshape(n, 3)
        # integrate, then put every joint point back on its parent's attachment (parents first)
        Q = exp_map(h * w) @ Q
        if s % 64 == 63:                     # keep the rotations orthonormal against rounding
            U, _, Vt = np.linalg.svd(Q)
            Q = U @ Vt
        x = x + h * v
        for i in range(n):
            p = L.parent[i]
            o[i] = (pA[s + 1] + RA[s + 1] @ L.pos[i]) if p < 0 else (o[p] + Q[p] @ L.pos[i])
            x[i] = o[i] + Q[i] @ L.com[i]
        rel[s + 1] = R0T @ np.swapaxes(parent_frames(Q, RA[s + 1]), -1, -2) @ Q
    return t, matrix_to_wxyz(rel)


def resample(t: np.ndarray, rotations: np.ndarray, times: np.ndarray) -> np.ndarray:
    """(S, n, 4) the rotations (N, n, 4) at step times t, at `times` (normalized lerp between the steps)."""
    k = np.clip(np.searchsorted(t, times, side="right") - 1, 0, len(t) - 2)
    f = ((times - t[k]) / (t[k + 1] - t[k]))[:, None, None]
    a, b = rotations[k], rotations[k + 1]
    b = np.where(np.sum(a * b, -1, keepdims=True) < 0, -b, b)
    q = (1 - f) * a + f * b
    return q / np.linalg.norm(q, axis=-1, keepdims=True)
