"""Physics drive: MuJoCo simulates the skeleton's body on a floor while it follows the clip.

The model is :func:`sim.drive.skeleton.build_mjcf`'s (capsules with tissue density, ~67 kg for a CMU
skeleton) plus a floor plane. Two things make it follow the clip:

- **joint welds**, one weld equality per non-root joint, between the parent body and the child
  body. Their relative pose (``eq_data`` relpose) is set every substep to the clip's local transform
  of that joint, so each weld is a stiff, implicitly integrated joint servo. Its forces are
  internal (equal and opposite on parent and child, like muscles): they hold the pose but cannot
  carry the body's weight.
- **a root servo**, a PD acceleration towards the clip's root pose, applied as forces on every
  body of the root's subtree (``xfrc_applied``, each body its mass times the acceleration of a
  rigid motion). It is the only external force besides gravity and the floor ("hand of god"), and
  soft on purpose: with time constant tau it holds the whole weight at a sag of ``g tau**2``
  (3 cm for the default 55 ms), so where the clip's planted foot floats a little above the floor
  the body settles onto it and the contacts carry the weight, while the root still follows the
  clip within centimetres. Its force is in the result: what the clip asks that the feet do not give.

Why not weld every body to a mocap body (the common recipe): those welds are external forces on
every bone; stiff enough to track, they hold the body in the air and the feet carry almost nothing;
soft enough to let the feet carry the weight, the limbs lag by decimetres. Why not a soft weld to a
mocap body for the root: a soft weld's give under load depends on MuJoCo's approximate constraint
mass, not on its solref alone; an explicit PD force has a sag set by one number and is stable
(omega dt = 0.03 at the default step). Why welds and not PD torques at the joints: MuJoCo has no
position actuator for a ball joint, and explicit PD torques are unstable on light bodies (finger
bones weigh ~30 g) unless gains follow every body's inertia; welds are solved implicitly together
with the contacts and stay stable at any mass ratio.

How the constraints are tuned, and why (each found by a failure on CMU 09_11, a run):

- MuJoCo regularises a constraint by ``R = (1 - d)/d * A``, A approximated from the bodies'
  ``body_invweight0``. For a 30 g root sphere or a 60 g toe that approximation is ~1e3-1e5 while
  the body, held by stiff welds, moves like the whole 67 kg skeleton: the rotation rows of the welds
  at the root got R ~ 19 (their position rows 1e-5) and gave way (a hip drifted 60 degrees in half
  a second), and toe contacts let landing feet sink 1.5 cm. The
  drive sets every body's ``body_invweight0`` to the whole body's (1/mass, 1/mean inertia about the
  centre of mass at the first frame), which is what a contact or weld on a welded skeleton moves.
- Joint welds: ``solimp`` dmin = dmax = 0.9999, so a weld follows its reference acceleration
  ``-b v - k r`` almost exactly; ``solref`` (20 ms, critical). On 09_11, 10 / 20 / 30 ms gave
  RMS error 1.2 / 1.5 / 2.0 cm and feet carrying 0.80 / 0.88 / 1.02 of the body weight: stiffer
  welds track closer but hold the body off the floor where the clip's feet float.
- A weld has no velocity target: its damping pulls the relative velocity to zero, which lags a
  moving target by ``b/k = 2 timeconst dampratio**2`` seconds (``b = 2/(dmax timeconst)``,
  ``k = d/(dmax timeconst dampratio)**2``, d = dmax). So each weld's relpose is the clip that far
  ahead in time: ``-k (x - x_clip(t + b/k)) - b v`` is, to first order, ``-k (x - x_clip(t)) - b
  (v - v_clip)``. On 09_11: without the lead RMS error 5.7 cm (max 20 cm); with it 1.5 cm. Linear
  extrapolation with the clip's velocity instead of the clip ahead tracked as well (1.4 cm) but
  pushed landing toes (3 m/s, then stopped by the floor) on into it: 5.4 mm instead of 3.1 mm
  deep, and the feet carried 0.68 of the weight instead of 0.88.
- Floor contacts: ``solref`` 5 ms (three substeps), ``solimp`` 0.9999: a landing foot stops within
  a few millimetres instead of sinking while the welds push it on.

Targets are sampled at every physics substep by interpolating the clip in time
(:meth:`rig.motion.clip.Clip.sample`), never by holding frames. The state starts at the clip's pose at the
first output time, lifted by as much as a foot geom is below the floor there, with velocities
from a central finite difference of the clip over one frame (one-sided at its ends).

Floor: unless given, :func:`estimate_floor`: the median height of the feet's lowest points over
the frames where a foot is planted (its lowest point slower than 0.3 m/s, near its lowest); a clip
without planted frames falls back to a low percentile of the lowest foot point.
"""
from __future__ import annotations

import time as _time
from dataclasses import dataclass
from typing import Callable, Sequence

import mujoco
import numpy as np

from jiggle.rig.base.errors import InputError
from jiggle.rig.base.frozen import frozen_array
from jiggle.rig.motion import quat
from jiggle.rig.motion.clip import Clip
from jiggle.sim.drive.skeleton import BodyShape, Skeleton, build_mjcf, mjcf_names

GRAVITY = 9.81  # m/s^2, as in build_mjcf

# Joint welds, see the module docs: 20 ms critically damped, impedance pinned at MuJoCo's maximum.
JOINT_SOLREF = (0.02, 1.0)
JOINT_SOLIMP = (0.9999, 0.9999, 0.001, 0.5, 2.0)
# Root servo: stiffness m/tau^2, damping 2 zeta m/tau, spread over the bodies by mass. Sag under
# the whole weight g tau^2 = 3.0 cm.
ROOT_TIMECONST = 0.055
ROOT_DAMPRATIO = 1.0
# Floor contacts: 5 ms is three substeps of 1/600 s (MuJoCo clamps to two); critical damping.
FLOOR_SOLREF = (0.005, 1.0)
FLOOR_SOLIMP = (0.9999, 0.9999, 0.001, 0.5, 2.0)
FLOOR_FRICTION = 1.0  # sliding friction coefficient of a shoe on a floor (0.6-1.0)
MAX_CONTACT_POINTS = 8  # contact points kept per foot and frame in the result


class PhysicsDivergedError(RuntimeError):
    """The simulation blew up (MuJoCo warning, non-finite state, or a body far off the clip)."""


# ---------------------------------------------------------------------------------------- feet
def find_feet(clip: Clip) -> list[int]:
    """Joint indices of the feet (ankles), found in the rest pose without joint names.

    A foot is the joint chain above one of the lowest tips of the rest pose (end sites, or joints
    without children, within 5 % of the rest height of the lowest one): walking up from the tip
    while the joint stays within 20 % of the rest height above the lowest point (an ankle sits at
    ~5 %, a knee at ~28 %). The foot is the highest joint reached; its subtree is the foot's bodies.
    Returns sorted indices; empty if the rest pose has no low tips (then pass `feet` by name).
    """
    rest_rot, rest_pos = clip.rest_world()
    tips = [(float(p[2]), int(e)) for p, e in
            zip(clip.end_world(rest_rot[None], rest_pos[None])[0], clip.end_parents)]
    has_kids = np.zeros(clip.num_joints, bool)
    has_kids[clip.parents[clip.parents >= 0]] = True
    tips += [(float(rest_pos[j, 2]), j) for j in range(clip.num_joints) if not has_kids[j]]
    zs = np.array([z for z, _ in tips] + list(rest_pos[:, 2]))
    low, height = zs.min(), zs.max() - zs.min()
    if height <= 0:
        return []
    feet = set()
    for z, j in tips:
        if z - low > 0.05 * height:
            continue
        while clip.parents[j] >= 0 and rest_pos[clip.parents[j], 2] - low < 0.2 * height:
            j = int(clip.parents[j])
        if rest_pos[j, 2] - low < 0.2 * height:
            feet.add(j)
    # a foot inside another foot's subtree (a toe reached from a lower tip) is the same foot
    out = []
    for f in sorted(feet):
        a, inside = clip.parents[f], False
        while a >= 0:
            inside |= a in feet
            a = clip.parents[a]
        if not inside:
            out.append(f)
    return out


def _subtree(clip: Clip, j: int) -> list[int]:
    out = [j]
    for c in range(j + 1, clip.num_joints):
        if clip.parents[c] in out:
            out.append(c)
    return out


def _resolve_feet(clip: Clip, feet: Sequence[str] | None) -> list[int]:
    if feet is not None:
        idx = [clip.index(n) for n in feet]
        if not idx:
            raise InputError("feet must name at least one joint", field="feet")
        return idx
    idx = find_feet(clip)
    if not idx:
        raise InputError("could not find the feet in the clip's rest pose (no low bone tips); "
                         "name the ankle joints (feet=...) or give the floor height", clip.source or None,
                         field="feet")
    return idx


def _geom_lowest(model: mujoco.MjModel, data: mujoco.MjData, geoms: np.ndarray) -> np.ndarray:
    """(G, 3) world lowest point (metres) of capsule or sphere geoms at the current kinematics."""
    r = model.geom_size[geoms, 0]
    half = np.where(model.geom_type[geoms] == mujoco.mjtGeom.mjGEOM_CAPSULE, model.geom_size[geoms, 1], 0.0)
    axis = data.geom_xmat[geoms].reshape(-1, 3, 3)[:, :, 2]  # the geom's local z axis in world
    end = data.geom_xpos[geoms] - (half * np.sign(axis[:, 2]))[:, None] * axis  # lower end of the segment
    end[:, 2] -= r
    return end


PLANTED_SPEED = 0.3  # m/s: a foot whose lowest point moves slower than this is planted
PLANTED_BAND = 0.05  # m: ... and lies within this of that foot's low-percentile height


def estimate_floor(clip: Clip, shape: BodyShape = BodyShape(), feet: Sequence[str] | None = None,
                   percentile: float = 5.0) -> float:
    """Floor height (metres, world z) from the clip.

    Per foot and frame, the lowest point of the foot's geoms (the capsules of the foot joint's
    subtree, as :func:`sim.drive.skeleton.build_mjcf` makes them). A foot is planted in a frame where
    that point moves slower than PLANTED_SPEED and lies within PLANTED_BAND of the foot's
    `percentile` height. The floor is the median height of the planted points: where the clip puts
    its standing feet, half a little above, half a little below. Without at least 3 planted frames
    (a clip that never stands), the `percentile` of the lowest point over all frames.
    """
    if not 0.0 <= percentile <= 100.0:
        raise InputError(f"floor percentile must be within 0..100, got {percentile}", field="floor_percentile")
    foot_idx = _resolve_feet(clip, feet)
    skel = Skeleton(clip, shape)
    model, data = skel.model, skel.data
    geoms = [np.nonzero(np.isin(model.geom_bodyid, skel.body_ids[_subtree(clip, f)]))[0] for f in foot_idx]
    qpos = skel.qpos(clip.rotations, clip.translations)
    low = np.empty((clip.num_frames, len(foot_idx), 3))
    for i in range(clip.num_frames):
        data.qpos[:] = qpos[i]
        mujoco.mj_kinematics(model, data)
        for f, g in enumerate(geoms):
            pts = _geom_lowest(model, data, g)
            low[i, f] = pts[np.argmin(pts[:, 2])]
    z = low[..., 2]
    if clip.num_frames >= 2:
        speed = np.linalg.norm(np.gradient(low, axis=0), axis=-1) * clip.fps
    else:
        speed = np.zeros_like(z)
    planted = (speed < PLANTED_SPEED) & (z - np.percentile(z, percentile, axis=0) < PLANTED_BAND)
    if np.count_nonzero(planted) >= 3:
        return float(np.median(z[planted]))
    return float(np.percentile(z.min(axis=1), percentile))


# ---------------------------------------------------------------------------------------- result
@dataclass(frozen=True, eq=False)
class PhysicsResult:
    """What the physics drive produced at the output times. Arrays are read-only.

    times : (N,) float64, seconds from the clip's start.
    rotations : (N, J, 4) float64, w,x,y,z, simulated world rotation of every clip joint
        (the layout of :meth:`sim.drive.skeleton.Skeleton.world`).
    positions : (N, J, 3) float64, metres, simulated world position of every clip joint.
    reference_positions : (N, J, 3) float64, metres, the kinematic clip at the same times.
    joint_error : (N, J) float64, metres, distance between simulated and kinematic joint positions.
    foot_joints : (F,) names of the foot (ankle) joints; a foot is that joint's subtree.
    foot_force : (N, F) float64, newtons, total normal contact force between each foot and the floor,
        averaged over the physics steps since the previous output time (the impulse over the
        interval divided by its length; the first frame: the force at that instant). Averaged, not
        sampled, because landing impacts last a few milliseconds.
    foot_contact_points : (N, F, K, 3) float64, metres, world contact points of each foot at the
        output time (K = MAX_CONTACT_POINTS), NaN past `foot_contact_count`.
    foot_contact_count : (N, F) int32, contacts of each foot at the output time (those beyond K
        are left out of the points).
    foot_lowest : (N, F) float64, metres, lowest point of each foot's geoms above the floor over the
        states since the previous output time (every physics step's), negative for penetration.
        Measured from the geoms' positions (capsule segment end minus radius), not contact depth.
    root_assist_force : (N, 3) float64, newtons, world force of the root servo (summed over the
        bodies it pushes), averaged like `foot_force`: what holds the body where the feet do not.
    floor_height : metres, world z of the floor plane.
    total_mass : kg.
    timestep : the largest physics substep used, seconds.
    wall_time : seconds spent simulating (model building excluded).
    """

    times: np.ndarray
    rotations: np.ndarray
    positions: np.ndarray
    reference_positions: np.ndarray
    joint_error: np.ndarray
    foot_joints: tuple[str, ...]
    foot_force: np.ndarray
    foot_contact_points: np.ndarray
    foot_contact_count: np.ndarray
    foot_lowest: np.ndarray
    root_assist_force: np.ndarray
    floor_height: float
    total_mass: float
    timestep: float
    wall_time: float

    def __post_init__(self):
        for k in ("times", "rotations", "positions", "reference_positions", "joint_error", "foot_force",
                  "foot_contact_points", "foot_lowest", "root_assist_force"):
            object.__setattr__(self, k, frozen_array(getattr(self, k)))
        object.__setattr__(self, "foot_contact_count", frozen_array(self.foot_contact_count, np.int32))
        object.__setattr__(self, "foot_joints", tuple(self.foot_joints))

    @property
    def rms_error(self) -> float:
        """Metres, RMS over frames and joints of the joint position error."""
        return float(np.sqrt(np.mean(self.joint_error ** 2)))

    @property
    def frame_rms_error(self) -> np.ndarray:
        """(N,) metres, RMS over joints per frame."""
        return np.sqrt(np.mean(self.joint_error ** 2, axis=1))

    @property
    def max_penetration(self) -> float:
        """Metres (>= 0), deepest any foot geom went below the floor over every physics step."""
        return float(max(0.0, -np.min(self.foot_lowest)))

    @property
    def weight(self) -> float:
        """Newtons, the body's weight."""
        return self.total_mass * GRAVITY

    def summary(self) -> dict:
        """The run's figures as plain JSON-ready values (units in the keys), for reports."""
        return {
            "body_mass_kg": round(self.total_mass, 3),
            "floor_height_m": round(self.floor_height, 5),
            "foot_joints": list(self.foot_joints),
            "rms_joint_error_m": round(self.rms_error, 5),
            "max_joint_error_m": round(float(np.max(self.joint_error)), 5),
            "max_foot_penetration_m": round(self.max_penetration, 5),
            "mean_foot_force_over_weight": round(self.mean_foot_force_ratio, 4),
            "mean_root_assist_z_over_weight": round(float(np.mean(self.root_assist_force[:, 2]) / self.weight), 4),
            "physics_timestep_s": round(self.timestep, 6),
            "simulation_wall_s": round(self.wall_time, 3),
        }

    @property
    def mean_foot_force_ratio(self) -> float:
        """Mean over frames of the feet's total normal force divided by the body's weight (over a
        whole stride, 1 if the feet carry the body and the root servo nothing)."""
        return float(np.mean(np.sum(self.foot_force, axis=1)) / self.weight)


# ---------------------------------------------------------------------------------------- drive
class PhysicsDrive:
    """MuJoCo follows a clip with its skeleton's body standing on a floor.

    Parameters
    ----------
    clip : the motion.
    shape : capsule sizes and density of the body (sets its mass).
    floor_height : world z of the floor in metres; None estimates it (:func:`estimate_floor`).
    feet : names of the foot (ankle) joints; None finds them (:func:`find_feet`).
    max_timestep : largest physics substep, seconds; output times are reached exactly by splitting
        each interval into equal substeps no longer than this.
    joint_solref, joint_solimp : MuJoCo solref/solimp of the joint welds (see the module docs).
    root_timeconst : seconds, time constant of the root servo (sag under the whole weight is
        ``9.81 * root_timeconst**2`` metres).
    root_dampratio : damping ratio of the root servo (1: critical).
    floor_percentile : the percentile :func:`estimate_floor` uses (planted band and fallback).

    Step-level use: :meth:`reset` to a time, then :meth:`step` / :meth:`advance`; read the current
    state with :meth:`pose` and :meth:`foot_contacts`. :meth:`run` does all that for many times.
    """

    def __init__(self, clip: Clip, shape: BodyShape = BodyShape(), floor_height: float | None = None,
                 feet: Sequence[str] | None = None, max_timestep: float = 1.0 / 600.0,
                 joint_solref: tuple[float, float] = JOINT_SOLREF,
                 joint_solimp: tuple[float, ...] = JOINT_SOLIMP,
                 root_timeconst: float = ROOT_TIMECONST, root_dampratio: float = ROOT_DAMPRATIO,
                 floor_percentile: float = 5.0):
        if not (np.isfinite(max_timestep) and 0.0 < max_timestep <= 0.01):
            raise InputError(f"physics timestep must be within (0, 0.01] s, got {max_timestep}",
                             field="max_timestep")
        if floor_height is not None and not np.isfinite(floor_height):
            raise InputError(f"floor height must be a finite number of metres, got {floor_height}",
                             field="floor_height")
        if not (len(joint_solref) == 2 and joint_solref[0] >= 2 * max_timestep and joint_solref[1] > 0):
            raise InputError(f"joint_solref must be (timeconst >= 2 timesteps = {2 * max_timestep:.4g} s, "
                             f"dampratio > 0), got {tuple(joint_solref)}", field="joint_solref")
        # explicit PD: keep omega dt well inside the stable range
        if not (np.isfinite(root_timeconst) and root_timeconst >= 10 * max_timestep and root_dampratio > 0):
            raise InputError(f"root servo needs timeconst >= 10 timesteps ({10 * max_timestep:.4g} s) and "
                             f"dampratio > 0, got {root_timeconst}, {root_dampratio}", field="root_timeconst")
        self.clip = clip
        self.shape = shape
        self.max_timestep = float(max_timestep)
        self.foot_idx = _resolve_feet(clip, feet)
        self.floor_height = float(floor_height) if floor_height is not None else \
            estimate_floor(clip, shape, [clip.joint_names[f] for f in self.foot_idx], floor_percentile)
        # target lead: b/k of a weld with constant impedance, see the module docs
        self._joint_lead = 2.0 * joint_solref[0] * joint_solref[1] ** 2
        self._root_kp = 1.0 / root_timeconst ** 2  # per unit mass (or inertia), 1/s^2
        self._root_kd = 2.0 * root_dampratio / root_timeconst  # 1/s

        names = mjcf_names(clip)
        spec = mujoco.MjSpec.from_string(build_mjcf(clip, shape, self.floor_height, max_timestep))
        spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
        floor = spec.geom("floor")
        floor.solref = list(FLOOR_SOLREF)
        floor.solimp = list(FLOOR_SOLIMP)
        floor.friction = [FLOOR_FRICTION, 0.005, 0.0001]
        self.roots = [int(j) for j in np.nonzero(clip.parents < 0)[0]]
        self.children = [j for j in range(clip.num_joints) if clip.parents[j] >= 0]
        for j in self.children:
            self._add_weld(spec, names[clip.parents[j]], names[j], joint_solref, joint_solimp,
                           f"{names[j]}_joint_weld")
        self.model = spec.compile()
        self.data = mujoco.MjData(self.model)
        m = self.model
        self.body_ids = np.array([mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, n) for n in names])
        # root servo: each root's body, free joint addresses and subtree bodies
        self._root_bodies = self.body_ids[self.roots]
        self._root_dof = np.array([m.jnt_dofadr[m.body_jntadr[b]] for b in self._root_bodies])
        self._root_qpos = np.array([m.jnt_qposadr[m.body_jntadr[b]] for b in self._root_bodies])
        self._root_target = np.zeros((len(self.roots), 13))  # pos, quat, lin vel, ang vel (world)
        self._root_subtree = [self.body_ids[_subtree(clip, j)] for j in self.roots]
        eq = lambda n: mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_EQUALITY, n)  # noqa: E731
        self._joint_eq = np.array([eq(f"{names[j]}_joint_weld") for j in self.children], dtype=int)
        self.floor_geom = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "floor")
        # foot geoms: the capsules of each foot joint's subtree
        self.foot_geoms = []
        self._geom_foot = np.full(m.ngeom, -1)
        for f, j in enumerate(self.foot_idx):
            bodies = self.body_ids[_subtree(clip, j)]
            g = np.nonzero(np.isin(m.geom_bodyid, bodies))[0]
            self.foot_geoms.append(g)
            self._geom_foot[g] = f
        self._kin = Skeleton(clip, shape)
        if self._kin.model.nq != m.nq:
            raise RuntimeError("physics model and kinematic skeleton disagree on qpos size")
        self._set_invweights()
        self.time = 0.0
        self._h = 0.5 / clip.fps  # finite-difference half step for clip velocities, seconds
        self._warnings = np.zeros(mujoco.mjtWarning.mjNWARNING.value, int)

    def _set_invweights(self) -> None:
        """Every body's body_invweight0 := the whole skeleton's, at the clip's first frame (module
        docs). Used by MuJoCo only to regularise constraints; mj_setConst would undo it."""
        m, d = self.model, self.data
        d.qpos[:] = self._kin.qpos_at(np.zeros(1))[0]
        mujoco.mj_kinematics(m, d)
        mass = m.body_mass[1:]
        com = mass @ d.xipos[1:] / mass.sum()
        # mean of the three principal moments of the bodies as point masses about the centre of mass
        inertia = (2.0 / 3.0) * float(mass @ np.sum((d.xipos[1:] - com) ** 2, axis=1)) \
            + float(np.sum(m.body_inertia[1:])) / 3.0
        m.body_invweight0[1:, 0] = 1.0 / mass.sum()
        m.body_invweight0[1:, 1] = 1.0 / inertia
        mujoco.mj_resetData(m, d)

    @staticmethod
    def _add_weld(spec, body1: str, body2: str, solref, solimp, name: str) -> None:
        e = spec.add_equality()
        e.name = name
        e.type = mujoco.mjtEq.mjEQ_WELD
        e.objtype = mujoco.mjtObj.mjOBJ_BODY
        e.name1, e.name2 = body1, body2
        data = np.zeros(len(e.data))
        data[6] = 1.0   # relpose quat, replaced every substep
        data[10] = 1.0  # torquescale: radians weigh like metres
        e.data = data
        e.solref = list(solref)
        e.solimp = list(solimp)

    @property
    def total_mass(self) -> float:
        """kg."""
        return float(np.sum(self.model.body_mass))

    @property
    def foot_joints(self) -> tuple[str, ...]:
        """Names of the foot (ankle) joints, in the order of the per-foot arrays."""
        return tuple(self.clip.joint_names[j] for j in self.foot_idx)

    # ------------------------------------------------------------------ targets
    def _set_targets(self, t: float, weld_time: float) -> None:
        """Root servo target: the clip's root pose at `t` and its velocity (central difference);
        joint weld relposes: the clip's local transforms at ``weld_time`` plus the weld lead b/k."""
        c = self.clip
        ta, tb = max(t - self._h, 0.0), min(t + self._h, c.duration)
        if tb <= ta:  # a one-frame clip stands still
            ta, tb = t, t + 1.0
        rot, tra = c.sample(np.array([t, ta, tb, weld_time + self._joint_lead]))
        ch, r = self.children, self.roots
        self.model.eq_data[self._joint_eq, 3:6] = tra[3, ch]
        self.model.eq_data[self._joint_eq, 6:10] = rot[3, ch]
        # a root's local transform is its world transform; angular velocity in the world frame
        w = quat.to_rotvec(quat.mul(rot[2, r], quat.conj(rot[1, r]))) / (tb - ta)
        v = (tra[2, r] - tra[1, r]) / (tb - ta)
        self._root_target[:] = np.concatenate([tra[0, r], rot[0, r], v, w], axis=1)

    def _apply_root_servo(self) -> None:
        """PD servo of each root towards its target, as forces at the centres of mass of every body
        of its subtree (xfrc_applied, world), each body's share being its mass times the
        acceleration of a rigid motion: ``m_b (a + alpha x (c_b - p_root))``.

        Spread over the bodies, not as one wrench on the root body: a CMU root is a 30 g sphere
        holding its children by the joint welds, whose impedance lets 1e-4 of a body's
        unconstrained acceleration through; a torque of the whole body's size on those 30 g blew
        the simulation up within 10 ms. Spread by mass it acts like a gravity field on the body.
        """
        d = self.data
        d.xfrc_applied[:] = 0.0
        for i, b in enumerate(self._root_bodies):
            tp, tq, tv, tw = np.split(self._root_target[i], [3, 7, 10])
            a = self._root_dof[i]
            v = d.qvel[a:a + 3]  # free joint: world linear velocity of the body origin
            w = d.xmat[b].reshape(3, 3) @ d.qvel[a + 3:a + 6]  # free joint: angular velocity, body frame
            acc = self._root_kp * (tp - d.xpos[b]) + self._root_kd * (tv - v)
            err = quat.to_rotvec(quat.mul(tq, quat.conj(d.xquat[b])))  # world rotation vector
            alpha = self._root_kp * err + self._root_kd * (tw - w)
            bodies = self._root_subtree[i]
            arm = d.xipos[bodies] - d.xpos[b]
            d.xfrc_applied[bodies, :3] = self.model.body_mass[bodies, None] * (acc + np.cross(alpha, arm))

    # ------------------------------------------------------------------ stepping
    def reset(self, time: float = 0.0) -> None:
        """State at the clip's pose at `time` (seconds), lifted as much as a foot is below the
        floor, velocities from the clip's central difference over one frame; clears the
        accumulated statistics (:meth:`take_interval`)."""
        if not np.isfinite(time):
            raise InputError(f"start time must be finite, got {time}", field="time")
        c, m, d = self.clip, self.model, self.data
        mujoco.mj_resetData(m, d)
        ta, tb = max(time - self._h, 0.0), min(time + self._h, c.duration)
        q = self._kin.qpos_at(np.array([time, ta, tb]))
        d.qpos[:] = q[0]
        if tb > ta:
            mujoco.mj_differentiatePos(m, d.qvel, tb - ta, q[1], q[2])
        # a clip's foot may start below the floor (CMU 02_03 by 2 cm): lift the body onto it, or
        # the first contact would kick it up
        mujoco.mj_kinematics(m, d)
        sink = -min(0.0, float(np.min(self._lowest())))
        for a in self._root_qpos:
            d.qpos[a + 2] += sink
        self.time = float(time)
        self._set_targets(self.time, self.time)
        mujoco.mj_forward(m, d)
        self._stale = False
        self._warnings[:] = [w.number for w in d.warning]
        self._clear_interval()

    def step(self, dt: float) -> None:
        """Advance by one MuJoCo step of `dt` seconds.

        The joint welds aim at the clip at the step's end (solved implicitly); the root servo acts
        on the state at the step's start. Raises PhysicsDivergedError naming the time if MuJoCo
        warns, the state goes non-finite, or the root drifts more than 1 m from the clip.
        """
        m, d = self.model, self.data
        m.opt.timestep = dt
        self._set_targets(self.time, self.time + dt)
        mujoco.mj_step1(m, d)  # kinematics, contacts, constraints of the current state
        self._apply_root_servo()
        mujoco.mj_step2(m, d)  # forces, constraint solve, integration
        # statistics of the state at the step's start, whose contacts were just solved
        force, _ = self._contacts(points=False)
        self._acc_force += force * dt
        self._acc_assist += np.sum(d.xfrc_applied[:, :3], axis=0) * dt
        self._acc_time += dt
        self._acc_lowest = np.minimum(self._acc_lowest, self._lowest())
        self.time += dt
        self._stale = True
        self._check()

    def advance(self, to_time: float) -> int:
        """Step to `to_time` seconds in equal substeps no longer than max_timestep; returns how many."""
        span = to_time - self.time
        if span < -1e-12:
            raise InputError(f"times must not decrease: at {self.time:.6g} s, asked for {to_time:.6g} s",
                             field="times")
        n = int(np.ceil(span / self.max_timestep - 1e-9))
        start = self.time
        for k in range(n):
            self.step(start + (k + 1) * span / n - self.time)  # no drift from summing substeps
        self.time = float(to_time)
        return n

    def _check(self) -> None:
        d = self.data
        numbers = np.array([w.number for w in d.warning])
        bad = [mujoco.mjtWarning(i).name for i in np.nonzero(numbers > self._warnings)[0]]
        self._warnings = numbers
        reason = None
        if bad:
            reason = "MuJoCo warned " + ", ".join(bad)
        elif not (np.all(np.isfinite(d.qpos)) and np.all(np.isfinite(d.qvel))):
            reason = "the state holds NaN or inf"
        else:
            off = np.linalg.norm(d.xpos[self._root_bodies] - self._root_target[:, :3], axis=-1)
            if np.max(off) > 1.0:
                reason = f"the root is {np.max(off):.2f} m away from the clip's"
            elif np.max(np.abs(d.qvel)) > 1e3:
                reason = f"a velocity reached {np.max(np.abs(d.qvel)):.3g} (m/s or rad/s)"
        if reason:
            raise PhysicsDivergedError(f"physics drive diverged at t = {self.time:.4f} s of clip "
                                       f"{self.clip.name or '<unnamed>'}: {reason}")

    # ------------------------------------------------------------------ reading the state
    def _refresh(self) -> None:
        """After mj_step the kinematics and contacts describe the step's start; recompute them
        (and the constraint forces) for the current state."""
        if self._stale:
            mujoco.mj_forward(self.model, self.data)
            self._stale = False

    def pose(self) -> tuple[np.ndarray, np.ndarray]:
        """Current world rotations (J, 4) w,x,y,z and positions (J, 3) metres of the clip joints."""
        self._refresh()
        return self.data.xquat[self.body_ids].copy(), self.data.xpos[self.body_ids].copy()

    def foot_contacts(self) -> tuple[np.ndarray, list[np.ndarray]]:
        """Current normal force per foot (F,) newtons, and each foot's contact points, a list of
        F arrays (k, 3) metres."""
        self._refresh()
        return self._contacts(points=True)

    def foot_lowest(self) -> np.ndarray:
        """(F,) metres, current lowest point of each foot's geoms above the floor (negative: below)."""
        self._refresh()
        return self._lowest()

    def take_interval(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Statistics over the steps since the last call (or reset), then cleared:
        mean normal force per foot (F,) N, mean root servo force (3,) N (world; the sum over the
        bodies it acts on), and the lowest point of each foot (F,) metres above the floor over those
        steps' states and the current one. With no step since, the current values."""
        if self._acc_time > 0.0:
            force, assist = self._acc_force / self._acc_time, self._acc_assist / self._acc_time
        else:
            self._refresh()
            force, assist = self._contacts(points=False)[0], np.sum(self.data.xfrc_applied[:, :3], axis=0)
        lowest = np.minimum(self._acc_lowest, self.foot_lowest())
        self._clear_interval()
        return force, assist, lowest

    def _clear_interval(self) -> None:
        F = len(self.foot_idx)
        self._acc_force, self._acc_assist = np.zeros(F), np.zeros(3)
        self._acc_time, self._acc_lowest = 0.0, np.full(F, np.inf)

    def _contacts(self, points: bool) -> tuple[np.ndarray, list[np.ndarray]]:
        m, d = self.model, self.data
        F = len(self.foot_idx)
        force = np.zeros(F)
        pts: list[list[np.ndarray]] = [[] for _ in range(F)]
        f6 = np.zeros(6)
        for i in range(d.ncon):
            con = d.contact[i]
            g1, g2 = con.geom[0], con.geom[1]
            if self.floor_geom not in (g1, g2) or con.efc_address < 0:
                continue
            foot = self._geom_foot[g2 if g1 == self.floor_geom else g1]
            if foot < 0:
                continue
            mujoco.mj_contactForce(m, d, i, f6)  # in the contact frame: f6[0] is the normal force
            force[foot] += f6[0]
            if points:
                pts[foot].append(con.pos.copy())
        return force, [np.array(p).reshape(-1, 3) for p in pts]

    def _lowest(self) -> np.ndarray:
        return np.array([_geom_lowest(self.model, self.data, g)[:, 2].min() for g in self.foot_geoms]) \
            - self.floor_height

    # ------------------------------------------------------------------ whole runs
    def run(self, times: np.ndarray | None = None,
            progress: Callable[[int, int], None] | None = None) -> PhysicsResult:
        """Simulate from times[0] to times[-1] and record every output time.

        times : (N,) seconds, non-decreasing; default the clip's frame times.
        progress : called as progress(done, total) after each output frame.
        """
        times = self.clip.times if times is None else np.atleast_1d(np.asarray(times, dtype=float))
        if times.size == 0 or not np.all(np.isfinite(times)):
            raise InputError("output times must be finite and at least one", field="times")
        if np.any(np.diff(times) < 0):
            raise InputError("output times must not decrease", field="times")
        N, J, F, K = len(times), self.clip.num_joints, len(self.foot_idx), MAX_CONTACT_POINTS
        rot, pos = np.empty((N, J, 4)), np.empty((N, J, 3))
        force, lowest, assist = np.zeros((N, F)), np.zeros((N, F)), np.zeros((N, 3))
        pts, count = np.full((N, F, K, 3), np.nan), np.zeros((N, F), np.int32)
        start = _time.perf_counter()
        self.reset(times[0])
        for i, t in enumerate(times):
            self.advance(t)
            rot[i], pos[i] = self.pose()
            _, p = self.foot_contacts()
            force[i], assist[i], lowest[i] = self.take_interval()
            for f in range(F):
                count[i, f] = len(p[f])
                pts[i, f, :min(K, len(p[f]))] = p[f][:K]
            if progress is not None:
                progress(i + 1, N)
        wall = _time.perf_counter() - start
        _, ref = self.clip.world(*self.clip.sample(times))
        return PhysicsResult(
            times=times, rotations=rot, positions=pos, reference_positions=ref,
            joint_error=np.linalg.norm(pos - ref, axis=-1), foot_joints=self.foot_joints,
            foot_force=force, foot_contact_points=pts, foot_contact_count=count, foot_lowest=lowest,
            root_assist_force=assist, floor_height=self.floor_height, total_mass=self.total_mass,
            timestep=self.max_timestep, wall_time=wall)
