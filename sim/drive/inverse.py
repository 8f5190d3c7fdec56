"""Joint torques of a clip: inverse dynamics of the driven skeleton in MuJoCo, the ground pushing where feet touch.

The skeleton is the drive's own model (sim.drive.skeleton: a body per clip joint, capsules along the bones) with its
masses set from a published segment table: de Leva 1996 (J Biomech 29:1223, adjusted Zatsiorsky-Seluyanov
parameters, male: head and neck 6.94% of the body's mass, trunk 43.46%, upper arm 2.71%, forearm 1.62%, hand
0.61%, thigh 14.16%, shank 4.33%, foot 1.37%) where the skeleton's roles are known (the human template's), each
segment's share spread over its bodies as their capsules' masses are and their inertias scaled alike; without roles
(a quadruped, a creature), the capsules' own proportions. The body's mass is the caller's (a bake: its skin's volume
at tissue density and real size).

Per sample (RATE samples a second): qpos from the clip (Skeleton.qpos_at), qvel by MuJoCo's differentiatePos
between neighbours, low-pass filtered (a 2nd-order Butterworth forward and back at CUTOFF_HZ: mocap markers' noise
grows as f^2 through two derivatives; Winter 2009, Biomechanics and Motor Control of Human Movement, ch. 2, filters
gait at ~6 Hz and impacts want more), qacc its derivative, then `mj_inverse`: the generalized forces (qfrc_inverse)
that make the model move so, gravity included. On a free-floating skeleton the root's 6 of them are a force and a
torque from nowhere; where the feet touch the floor, the ground gives them: the contact forces at the touching foot
bodies' lowest points (within CONTACT_GAP of the floor, moving slower than CONTACT_SPEED) that best produce the root's six (least squares, pushing
only, friction kept small by a light penalty) are taken off every joint's load through the contact Jacobians, so a
landing's load runs up through the ankles, knees and hips. What the ground cannot give stays on the root
(`residual`: the clip's own inconsistency, or a push in flight).

Each ball joint's torque is returned in world axes: the torque the parent side applies to the child side about the
joint, the load its muscles must carry (sim.jiggle.activation).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from jiggle.rig.base.frozen import frozen_array
from jiggle.rig.motion.clip import Clip
from jiggle.sim.drive.skeleton import Skeleton

DE_LEVA_MALE = {"head": 0.0694, "trunk": 0.4346, "upper_arm": 0.0271, "lower_arm": 0.0162, "hand": 0.0061,
                "upper_leg": 0.1416, "lower_leg": 0.0433, "foot": 0.0137}
"""Segment masses over the body's (de Leva 1996, Table 4, males); both sides' limbs each, summing to 1."""
BODY_DENSITY = 1010.0
"""kg/m^3: a whole human body's mean density (Clauser et al. 1969), for a mass from a skin's volume."""
RATE = 120.0
"""Hz: the samples inverse dynamics runs on: ten to the low-pass's one (CUTOFF_HZ), as gait labs sample their
filtered kinematics (Winter 2009). 240 Hz cost twice as much for the same activations: a median 2-5% of each
muscle's peak apart on the shared jump and run (correlation 0.99 or more), the largest difference 0.15, at an
impact."""
CUTOFF_HZ = 12.0
"""Hz: the low-pass of the joint velocities (see the module)."""
CONTACT_GAP = 0.05
"""Of the body's height: a foot body whose lowest point is this near the floor (and slow: CONTACT_SPEED) may be
pushed by it. Mocap feet do not come back to one height (a run's CMU 02_03 touches down 2-6 cm above its lowest
step), so the gap is generous and the speed tells a planted foot from a swinging one."""
CONTACT_SPEED = 1.0
"""m/s: the largest vertical speed of a foot body's lowest point the floor may push (a swinging foot passes low
and fast; a landing foot slows within a few samples)."""
FRICTION_PENALTY = 0.05
"""Weight of the contact forces' tangential parts against their vertical ones in the least squares."""


@dataclass(frozen=True, eq=False)
class Loads:
    """A clip's joint loads (arrays read-only).

    times : (K,) seconds. torques : (K, J, 3) N m, world axes: at each clip joint the torque its parent side
    applies to its child side (zero at a root and at a joint with no ball). ground : (K, 3) N, the floor's total
    push. residual : (K, 6) the root's force (N, world) and torque (N m, root frame) left unexplained. masses : (J,)
    kg of each joint's body. mass_kg : their sum. contact : (K, J) bool, the bodies the floor pushes."""

    times: np.ndarray
    torques: np.ndarray
    ground: np.ndarray
    residual: np.ndarray
    masses: np.ndarray
    contact: np.ndarray
    mass_kg: float

    def __post_init__(self):
        for k in ("times", "torques", "ground", "residual", "masses", "contact"):
            object.__setattr__(self, k, frozen_array(getattr(self, k)))

    def at(self, times: np.ndarray) -> np.ndarray:
        """(T, J, 3) torques at `times` (seconds), linear between samples, held past the ends."""
        t = np.asarray(times, np.float64)
        flat = self.torques.reshape(len(self.times), -1)
        out = np.stack([np.interp(t, self.times, flat[:, i]) for i in range(flat.shape[1])], axis=1)
        return out.reshape(len(t), *self.torques.shape[1:])


def subtree(parents: np.ndarray, j: int) -> list[int]:
    """Joint j and every joint below it (parents come before children)."""
    out = [j]
    for c in range(j + 1, len(parents)):
        if parents[c] in out:
            out.append(c)
    return out


def segment_bodies(parents: np.ndarray, roles: dict) -> dict[str, list[int]]:
    """{de Leva segment: clip joints whose bodies make it} from role -> joint index (the human roles of
    rig.motion.retarget); joints in no limb or head segment are the trunk's."""
    seg: dict[str, list[int]] = {}
    taken: set[int] = set()
    for side in ("left", "right"):
        for role, name, whole in (("hand", "hand", True), ("foot", "foot", True), ("lower_arm", "lower_arm", False),
                                  ("upper_arm", "upper_arm", False), ("lower_leg", "lower_leg", False),
                                  ("upper_leg", "upper_leg", False)):
            j = roles.get(f"{side}_{role}")
            if j is None:
                continue
            bodies = [b for b in (subtree(parents, j) if whole else [j]) if b not in taken]
            seg.setdefault(name, []).extend(bodies)
            taken.update(bodies)
    for role in ("neck", "head"):
        j = roles.get(role)
        if j is not None:
            bodies = [b for b in subtree(parents, j) if b not in taken]
            seg.setdefault("head", []).extend(bodies)
            taken.update(bodies)
    seg["trunk"] = [b for b in range(len(parents)) if b not in taken]
    return seg


def segment_masses(parents: np.ndarray, capsule: np.ndarray, mass_kg: float, roles: dict | None = None) -> np.ndarray:
    """(J,) kg: each joint's body's mass, the body's `mass_kg` spread by de Leva's table over the segments `roles`
    give (segment_bodies; within a segment as the capsule masses (J,) are), else as the capsules are."""
    capsule = np.maximum(np.asarray(capsule, np.float64), 1e-9)
    if not roles:
        return capsule * (mass_kg / capsule.sum())
    out = np.zeros_like(capsule)
    seg = segment_bodies(np.asarray(parents), roles)
    share = {k: v for k, v in DE_LEVA_MALE.items() if seg.get(k)}
    scale = 1.0 / sum(share[k] * (2 if k not in ("head", "trunk") else 1) for k in share) if share else 1.0
    for name, bodies in seg.items():
        if not bodies:
            continue
        sides = 2 if name not in ("head", "trunk") else 1
        # the segment's bodies for both sides together: each side's share of the table
        total = DE_LEVA_MALE.get(name, 0.0) * sides * scale * mass_kg
        out[bodies] = capsule[bodies] * (total / capsule[bodies].sum())
    return out


def butterworth2(cutoff: float, rate: float) -> tuple[np.ndarray, np.ndarray]:
    """(b (3,), a (3,)): the 2nd-order Butterworth low-pass at `cutoff` Hz for samples at `rate` Hz, by the bilinear
    transform with the cutoff prewarped (scipy.signal.butter(2, cutoff / (rate / 2)) exactly)."""
    k = math.tan(math.pi * cutoff / rate)
    norm = 1.0 / (1.0 + math.sqrt(2.0) * k + k * k)
    b0 = k * k * norm
    return (np.array([b0, 2.0 * b0, b0]),
            np.array([1.0, 2.0 * (k * k - 1.0) * norm, (1.0 - math.sqrt(2.0) * k + k * k) * norm]))


def _lfilter(b: np.ndarray, a: np.ndarray, x: np.ndarray, z: np.ndarray) -> np.ndarray:
    """The 2nd-order filter (b, a) over x (n, d) along its first axis, from state z (2, d) (transposed direct form
    II, as scipy.signal.lfilter)."""
    y = np.empty_like(x)
    z0, z1 = z[0].copy(), z[1].copy()
    for i in range(len(x)):
        y[i] = b[0] * x[i] + z0
        z0 = b[1] * x[i] - a[1] * y[i] + z1
        z1 = b[2] * x[i] - a[2] * y[i]
    return y


def _filtered(x: np.ndarray, rate: float, cutoff: float) -> np.ndarray:
    """x (n, d) low-passed forward and back (zero phase): scipy.signal.filtfilt(b, a, x, axis=0) of
    butterworth2's filter, its odd extension of 9 samples at either end and its steady-state start, in NumPy (the
    import of scipy.signal alone took 0.4-0.6 s of an activation bake)."""
    if len(x) <= 12 or cutoff >= 0.5 * rate:
        return x
    b, a = butterworth2(cutoff, rate)
    pad = 9                                         # filtfilt's 3 x max(len(a), len(b))
    x = np.asarray(x, np.float64)
    ext = np.concatenate([2.0 * x[:1] - x[pad:0:-1], x, 2.0 * x[-1:] - x[-2:-pad - 2:-1]])
    # lfilter_zi: the state that a step of 1 leaves the filter in, scaled by the first sample
    zi = np.linalg.solve(np.eye(2) - np.array([[-a[1], 1.0], [-a[2], 0.0]]), b[1:] - a[1:] * b[0])
    y = _lfilter(b, a, ext, zi[:, None] * ext[:1])
    y = _lfilter(b, a, y[::-1], zi[:, None] * y[-1:])[::-1]
    return y[pad:len(y) - pad]


def joint_torques(clip: Clip, times: np.ndarray, mass_kg: float, roles: dict | None = None,
                  floor_z: float | None = None, rate: float = RATE, cutoff: float = CUTOFF_HZ) -> Loads:
    """The clip's joint loads (Loads) sampled at `rate` over [times[0], times[-1]] (seconds; within the clip), for a
    body of `mass_kg` kg (segment_masses with `roles`), the floor at `floor_z` metres (None: the lowest a foot body's
    capsule reaches over those times; no feet found: no floor)."""
    from jiggle.sim.drive.physics_drive import _geom_lowest, find_feet
    times = np.asarray(times, np.float64)
    t0, t1 = float(times[0]), float(times[-1])
    n = max(int(math.ceil((t1 - t0) * rate)) + 1, 3)
    ts = np.linspace(t0, max(t1, t0 + 2.0 / rate), n)
    dt = float(ts[1] - ts[0])
    sk = Skeleton(clip)
    m, d = sk.model, sk.data
    J = clip.num_joints
    bodies = sk.body_ids
    capsule = np.array(m.body_mass[bodies])
    masses = segment_masses(clip.parents, capsule, mass_kg, roles)
    m.body_inertia[bodies] *= (masses / np.maximum(capsule, 1e-12))[:, None]
    m.body_mass[bodies] = masses
    q = np.clip(ts, 0.0, clip.duration)
    qpos = sk.qpos_at(q)
    # velocities between neighbours, at the samples (the mean of the two sides), filtered; accelerations from them
    mid = np.zeros((n - 1, m.nv))
    for i in range(n - 1):
        mujoco.mj_differentiatePos(m, mid[i], dt, qpos[i], qpos[i + 1])
    qvel = np.concatenate([mid[:1], 0.5 * (mid[1:] + mid[:-1]), mid[-1:]])
    qvel = _filtered(qvel, 1.0 / dt, cutoff)
    qacc = np.gradient(qvel, dt, axis=0)
    feet = find_feet(clip)
    foot_bodies = sorted({b for f in feet for b in subtree(clip.parents, f)})
    geoms = {j: np.flatnonzero(m.geom_bodyid == bodies[j]) for j in foot_bodies}
    lowest = {}
    for i in range(n):
        d.qpos[:] = qpos[i]
        mujoco.mj_kinematics(m, d)
        for j, g in geoms.items():
            if len(g):
                low = _geom_lowest(m, d, g)
                lowest.setdefault(j, []).append(low[np.argmin(low[:, 2])])
    low_pts = {j: np.array(v) for j, v in lowest.items()}
    slow = {j: np.abs(np.gradient(v[:, 2], dt)) <= CONTACT_SPEED for j, v in low_pts.items()}
    if floor_z is None and low_pts:
        floor_z = float(min(v[:, 2].min() for v in low_pts.values()))
    height = float(np.ptp(clip.rest_world()[1][:, 2])) or 1.0
    gap = CONTACT_GAP * height
    torques = np.zeros((n, J, 3))
    ground = np.zeros((n, 3))
    residual = np.zeros((n, 6))
    contact = np.zeros((n, J), bool)
    root_dofs = [int(m.jnt_dofadr[k]) for k in range(m.njnt) if m.jnt_type[k] == mujoco.mjtJoint.mjJNT_FREE]
    root = np.concatenate([np.arange(a, a + 6) for a in root_dofs]) if root_dofs else np.zeros(0, int)
    balls = [(j, int(m.jnt_dofadr[k]), bodies[j]) for j in range(J) for k in range(m.njnt)
             if m.jnt_bodyid[k] == bodies[j] and m.jnt_type[k] == mujoco.mjtJoint.mjJNT_BALL]
    jacp = np.zeros((3, m.nv))
    for i in range(n):
        d.qpos[:], d.qvel[:], d.qacc[:] = qpos[i], qvel[i], qacc[i]
        mujoco.mj_inverse(m, d)
        f_gen = np.array(d.qfrc_inverse)
        touching = [j for j in low_pts if floor_z is not None and low_pts[j][i, 2] - floor_z <= gap and slow[j][i]]
        if touching and len(root):
            cols = []
            for j in touching:
                mujoco.mj_jac(m, d, jacp, None, low_pts[j][i], bodies[j])
                cols.append(jacp.copy())
            Jc = np.concatenate(cols)                                   # (3c, nv)
            f = _ground_forces(Jc[:, root], f_gen[root])
            f_gen = f_gen - Jc.T @ f
            ground[i] = f.reshape(-1, 3).sum(axis=0)
            contact[i, touching] = True
        if len(root):
            residual[i] = f_gen[root[:6]]
        for j, adr, b in balls:
            torques[i, j] = d.xmat[b].reshape(3, 3) @ f_gen[adr:adr + 3]
    return Loads(ts, torques, ground, residual, masses, contact, float(masses.sum()))


def _ground_forces(Jr: np.ndarray, wrench: np.ndarray) -> np.ndarray:
    """(3c,) contact forces whose generalized forces on the root's dofs, Jr^T f (Jr: (3c, 6)), are the root's
    `wrench` (6,) as nearly as pushing-only forces give it; tangential parts penalized by FRICTION_PENALTY."""
    from scipy.optimize import nnls
    c = Jr.shape[0] // 3
    scale = max(float(np.abs(wrench).max()), 1.0)
    pen = np.zeros((3 * c, 3 * c))
    for k in range(c):
        pen[3 * k, 3 * k] = pen[3 * k + 1, 3 * k + 1] = FRICTION_PENALTY
    A = np.concatenate([Jr.T / scale, pen])
    b = np.concatenate([wrench / scale, np.zeros(3 * c)])
    # the tangential parts are free, the normal ones pushing only: a non-negative least squares with each free
    # part split into its positive and negative halves (scipy's nnls, 6x faster than a bounded lsq_linear here)
    free = np.tile([True, True, False], c)
    z, _ = nnls(np.concatenate([A[:, free], -A[:, free], A[:, ~free]], axis=1), b)
    n = int(free.sum())
    f = np.empty(3 * c)
    f[free] = z[:n] - z[n:2 * n]
    f[~free] = z[2 * n:]
    return f


__all__ = ["Loads", "DE_LEVA_MALE", "BODY_DENSITY", "RATE", "CUTOFF_HZ", "CONTACT_GAP", "CONTACT_SPEED", "segment_bodies",
           "segment_masses", "joint_torques", "subtree"]
