"""Muscle activation against a musculoskeletal model: jiggle's fitted muscles beside MyoSuite's myolegs26, on the
same clip and the same joint torques, and beside published running EMG timing.

    python benchmarks/activation_reference.py [--out benchmarks/results]

The reference is MyoSuite's leg model (PyPI `myo-sim`, `myolegs26`: Rajagopal et al. 2016's lower limbs in MuJoCo, 13
muscles a leg with their real paths, via points that follow the knee and hip, and force-length-velocity curves).
For CMU 02_03 (a run) and 02_04 (a jump), on the generated body and on CesiumMan:

1. the clip's joint torques, as the bake computes them (sim.drive.inverse.joint_torques: inverse dynamics with the
   ground's push, the body's mass from its skin's volume), scaled to the reference's body (torque ~ mass x length);
2. jiggle's activations, as the bake computes them (sim.jiggle.activation.activations: moment arms from the fitted
   muscles' paths, strengths from their volumes);
3. the reference's: myolegs26 posed in the clip's leg angles each sample (the pelvis turned as the clip's hips,
   then per leg the hip's three angles, the knee and the ankle fitted so that the thigh and the shank point where
   the clip's do and the ankle bends as much from its rest), its muscles' moment arms about the hip, knee and
   ankle (MuJoCo's actuator_moment, with the knee's and hip's coupled coordinates chained in: dL/dq + dL/dq_dep
   dq_dep/dq), their strongest force at their length and speed (F0 FL FV, mju_muscleGain), then the same least-effort
   static optimization (static_optimization) and activation dynamics (activation_dynamics) as jiggle's.

Compared per group and side (quadriceps: vasti + rectus femoris; hamstrings: hamstrings + biceps femoris short
head; gluteus: gluteus maximus; calf: gastrocnemius + soleus; a group's activation the force-weighted mean of its
muscles'): the correlation of the two activations over the clip, and where in the stride each is active against
published running EMG (Novacheck 1998, Cappellini et al. 2006): quadriceps from late swing through loading,
hamstrings in late swing, calf in stance (a stance is a foot on the floor, sim.drive.inverse's contacts). A group's
timing score is the share of its activation inside its window over the share of time the window takes (1: no
preference; above 1: active where the EMG is). Writes activation_reference.md / .json and activation_reference/*.png.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from activation_landings import ASSETS, CHARACTERS, CLIPS, RATE, fit_for, save_figure  # noqa: E402

GROUPS = {"quadriceps": ("vasti", "rectfem"), "hamstrings": ("hamstrings", "bifemsh"), "glute": ("glutmax",),
          "calf": ("gastroc", "soleus")}
"""jiggle's group (the template's muscle names hold it) -> the reference's muscles (myolegs26 names less _l/_r)."""
REFERENCE_MASS_KG, REFERENCE_HEIGHT_M = 75.3, 1.70
"""Rajagopal et al. 2016's subject, the body myolegs26 is built for: torques scale by mass x length."""
LEG_DOFS = ("hip_flexion", "hip_adduction", "hip_rotation", "knee_angle", "ankle_angle")
EMG_WINDOWS = {"quadriceps": (("swing", 0.8, 1.0), ("stance", 0.0, 0.3)),
               "hamstrings": (("swing", 0.5, 1.0),),
               "calf": (("stance", 0.0, 1.0),)}
"""Published running EMG (Novacheck 1998, Gait & Posture 7; Cappellini et al. 2006, J Neurophysiol 95): where in a
leg's stride each group is on, as (phase, from, to) fractions of that phase: quadriceps the last fifth of swing and
the first 30% of stance (the loading), hamstrings the second half of swing, the calf through stance."""
WEIGHTS = {"thigh": 1.0, "shank": 1.0, "ankle": 1.0, "foot": 0.3, "rest": 0.02}
"""The pose fit's residuals: thigh and shank directions (unit vectors), the ankle's bend (radians), the foot's
direction (weak: it settles the hip's twist when the knee is straight), a pull toward the last sample's angles."""
RESTART_DEG = 3.0
"""A leg whose fit from the last sample's angles still misses its thigh or shank by more is fitted again from
several starts."""


# ---------------------------------------------------------------------------------------------- the reference model
class Reference:
    """myolegs26 (myo_sim.load) with what posing it needs: its joints' and muscles' indices, its joint couplings."""

    def __init__(self):
        import mujoco
        import myo_sim
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            self.model, self.data = myo_sim.load("myolegs26")
        m = self.model
        self.mj = mujoco
        jid = lambda n: mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, n)  # noqa: E731
        bid = lambda n: mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, n)  # noqa: E731
        self.names = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_ACTUATOR, a) for a in range(m.nu)]
        self.legs = {}
        for s in ("l", "r"):
            joints = [jid(f"{d}_{s}") for d in LEG_DOFS]
            self.legs[s] = {"joints": joints, "qadr": [int(m.jnt_qposadr[j]) for j in joints],
                            "dofs": [int(m.jnt_dofadr[j]) for j in joints],
                            "range": np.array([m.jnt_range[j] for j in joints]),
                            "bodies": [bid(f"{b}_{s}") for b in ("femur", "tibia", "talus", "toes")]}
        # the coupled coordinates (knee translations, moving via points): q_dep = q0_dep + sum c_i (q - q0)^i
        self.couplings = []
        for e in range(m.neq):
            if m.eq_type[e] == mujoco.mjtEq.mjEQ_JOINT and m.eq_obj2id[e] >= 0:
                dep, ind = int(m.eq_obj1id[e]), int(m.eq_obj2id[e])
                self.couplings.append((int(m.jnt_qposadr[dep]), int(m.jnt_dofadr[dep]), int(m.jnt_qposadr[ind]),
                                       int(m.jnt_dofadr[ind]), np.array(m.eq_data[e, :5], np.float64)))
        self.qpos0 = np.array(m.qpos0)
        mujoco.mj_forward(m, self.data)
        self.rest_frame = self.frame(self.data)           # the pelvis's anatomical frame at rest, world
        self.rest_bend = {s: self.ankle_bend(s) for s in self.legs}

    def frame(self, d) -> np.ndarray:
        """(3, 3) columns right, up, forward of the pelvis (from its hip centres and the world's up at rest)."""
        L, R = d.xpos[self.legs["l"]["bodies"][0]], d.xpos[self.legs["r"]["bodies"][0]]
        return anatomical_frame(R - L, np.array([0.0, 0.0, 1.0]))

    def pose(self, root_rot: np.ndarray, q: dict) -> None:
        """Pose the model: the root turned by root_rot (3, 3), each leg's LEG_DOFS angles q[side] (5,), the coupled
        coordinates from them; kinematics only."""
        mj, m, d = self.mj, self.model, self.data
        qpos = self.qpos0.copy()
        quat = np.zeros(4)
        mj.mju_mat2Quat(quat, np.ascontiguousarray(root_rot).ravel())
        qpos[3:7] = quat
        for s, leg in self.legs.items():
            qpos[leg["qadr"]] = q[s]
        for dep, _, ind, _, c in self.couplings:
            x = qpos[ind] - self.qpos0[ind]
            qpos[dep] = self.qpos0[dep] + sum(c[i] * x ** i for i in range(5))
        d.qpos[:] = qpos
        mj.mj_kinematics(m, d)

    def ankle_bend(self, s: str) -> float:
        """radians: the angle between the shank (knee to ankle) and the foot (ankle to toes) as posed."""
        b = self.legs[s]["bodies"]
        x = self.data.xpos
        return angle(x[b[2]] - x[b[1]], x[b[3]] - x[b[2]])

    def directions(self, s: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        b = self.legs[s]["bodies"]
        x = self.data.xpos
        return unit(x[b[1]] - x[b[0]]), unit(x[b[2]] - x[b[1]]), unit(x[b[3]] - x[b[2]])

    def arms_at(self, s: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """At the current pose: (arms (nu, 3, 3): per muscle the torque vector about the hip, knee and ankle (world)
        per newton of tension; lengths (nu,) m; the hinge axes (5, 3)). The hip's three hinges' generalized forces
        g = -dL/dq are turned into the torque vector t with t . n_i = g_i; the knee's and ankle's lie on their
        axis."""
        mj, m, d = self.mj, self.model, self.data
        mj.mj_comPos(m, d)
        mj.mj_tendon(m, d)
        mj.mj_transmission(m, d)
        dense = np.zeros((m.nu, m.nv))
        mj.mju_sparse2dense(dense, d.actuator_moment, d.moment_rownnz, d.moment_rowadr, d.moment_colind)
        eff = dense.copy()
        for _, dep_dof, ind_qadr, ind_dof, c in self.couplings:    # chain rule through the coupled coordinates
            x = d.qpos[ind_qadr] - self.qpos0[ind_qadr]
            eff[:, ind_dof] += dense[:, dep_dof] * sum(i * c[i] * x ** (i - 1) for i in range(1, 5))
        leg = self.legs[s]
        axes = np.array([d.xaxis[j] for j in leg["joints"]])          # (5, 3)
        g = -eff[:, leg["dofs"]]                                       # (nu, 5) N m per N
        arms = np.zeros((m.nu, 3, 3))
        arms[:, 0] = np.linalg.solve(axes[:3], g[:, :3].T).T          # t . n_i = g_i for the hip's three hinges
        arms[:, 1] = g[:, 3:4] * axes[3]
        arms[:, 2] = g[:, 4:5] * axes[4]
        return arms, np.array(d.actuator_length), axes

    def strongest(self, lengths: np.ndarray, speeds: np.ndarray) -> np.ndarray:
        """(K, nu) N: each muscle's largest active force at its length and speed (K, nu) m, m/s: F0 FL FV."""
        m = self.model
        out = np.zeros_like(lengths)
        for a in range(m.nu):
            prm = np.array(m.actuator_gainprm[a, :9])
            for k in range(len(lengths)):
                out[k, a] = -self.mj.mju_muscleGain(lengths[k, a], speeds[k, a], m.actuator_lengthrange[a],
                                                    m.actuator_acc0[a], prm)
        return np.maximum(out, 0.0)


def unit(v: np.ndarray) -> np.ndarray:
    return v / max(float(np.linalg.norm(v)), 1e-12)


def angle(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.arccos(np.clip(np.dot(unit(a), unit(b)), -1.0, 1.0)))


def anatomical_frame(right: np.ndarray, up: np.ndarray) -> np.ndarray:
    """(3, 3) columns right, up, forward: `right` (3,) as given, `up` (3,) made square to it, forward = up x right."""
    r = unit(right)
    u = unit(up - np.dot(up, r) * r)
    return np.stack([r, u, np.cross(u, r)], axis=1)


# ---------------------------------------------------------------------------------------------- the clip's pose
def clip_legs(world: np.ndarray, rest: np.ndarray, roles: dict) -> dict:
    """The clip's leg geometry per sample: world (K, J, 4, 4) and the rest pose (J, 4, 4). Returns the pelvis's
    anatomical frame (K, 3, 3) (its rest frame, right from hip to hip and up the world's, carried by the hips
    joint's rotation) and per side (l, r) the thigh's and shank's unit directions (K, 3) and the ankle's bend from
    its rest (K,) radians."""
    p = world[:, :, :3, 3]
    hips = roles["hips"]
    rest_frame = anatomical_frame(rest[roles["right_upper_leg"], :3, 3] - rest[roles["left_upper_leg"], :3, 3],
                                  np.array([0.0, 0.0, 1.0]))
    turn = np.einsum("kab,cb->kac", world[:, hips, :3, :3], rest[hips, :3, :3])      # R(t) R_rest^T
    out = {"pelvis": np.einsum("kab,bc->kac", turn, rest_frame)}
    for s, side in (("l", "left"), ("r", "right")):
        hip, knee, ankle, toe = (roles[f"{side}_{r}"] for r in ("upper_leg", "lower_leg", "foot", "toe"))
        thigh, shank, foot = p[:, knee] - p[:, hip], p[:, ankle] - p[:, knee], p[:, toe] - p[:, ankle]
        rest_bend = angle(rest[ankle, :3, 3] - rest[knee, :3, 3], rest[toe, :3, 3] - rest[ankle, :3, 3])
        bend = np.array([angle(a, b) for a, b in zip(shank, foot)]) - rest_bend
        out[s] = {"thigh": thigh / np.linalg.norm(thigh, axis=1, keepdims=True),
                  "shank": shank / np.linalg.norm(shank, axis=1, keepdims=True),
                  "foot": foot / np.linalg.norm(foot, axis=1, keepdims=True), "bend": bend}
    return out


def fit_pose(ref: Reference, legs: dict) -> tuple[np.ndarray, dict, np.ndarray]:
    """The reference posed in the clip's leg geometry (clip_legs) sample by sample: (root rotations (K, 3, 3), the
    legs' angles {side: (K, 5)} radians, the fit's worst direction miss (K,) degrees)."""
    from scipy.optimize import least_squares
    K = len(legs["pelvis"])
    roots = np.einsum("kab,cb->kac", legs["pelvis"], ref.rest_frame)            # the model's rest frame onto the clip's
    q = {s: np.zeros((K, 5)) for s in ref.legs}
    miss = np.zeros(K)
    last = {s: np.zeros(5) for s in ref.legs}
    for k in range(K):
        for s, leg in ref.legs.items():
            target = legs[s]

            def resid(x, s=s, k=k):
                qq = {o: (x if o == s else last[o]) for o in ref.legs}
                ref.pose(roots[k], qq)
                th, sh, ft = ref.directions(s)
                return np.concatenate([WEIGHTS["thigh"] * (th - target["thigh"][k]),
                                       WEIGHTS["shank"] * (sh - target["shank"][k]),
                                       [WEIGHTS["ankle"] * (ref.ankle_bend(s) - ref.rest_bend[s] - target["bend"][k])],
                                       WEIGHTS["foot"] * (ft - target["foot"][k]),
                                       WEIGHTS["rest"] * (x - last[s])])
            lo, hi = leg["range"][:, 0], leg["range"][:, 1]
            r = least_squares(resid, np.clip(last[s], lo, hi), bounds=(lo, hi), xtol=1e-8)
            resid(r.x)                                          # posed at the fit (not its last probe)
            if _worst_miss(ref, s, target, k) > RESTART_DEG:
                # a local minimum (the first sample, a fast swing): restart from the knee's known bend, the hip
                # flexed and twisted a few ways, and keep the best
                knee = -angle(target["thigh"][k], target["shank"][k])
                for flex in (-0.3, 0.4, 1.2):
                    for twist in (-0.5, 0.0, 0.5):
                        x0 = np.clip([flex, 0.0, twist, knee, last[s][4]], lo, hi)
                        t = least_squares(resid, x0, bounds=(lo, hi), xtol=1e-8)
                        if t.cost < r.cost:
                            r = t
            q[s][k] = last[s] = r.x
        ref.pose(roots[k], {s: q[s][k] for s in ref.legs})
        miss[k] = max(math.degrees(angle(a, b)) for s in ref.legs
                      for a, b in zip(ref.directions(s)[:2], (legs[s]["thigh"][k], legs[s]["shank"][k])))
    return roots, q, miss


def _worst_miss(ref: Reference, s: str, target: dict, k: int) -> float:
    """degrees: the larger of the thigh's and the shank's miss of leg `s` as last posed, against sample k."""
    th, sh, _ = ref.directions(s)
    return math.degrees(max(angle(th, target["thigh"][k]), angle(sh, target["shank"][k])))


# ---------------------------------------------------------------------------------------------- the comparison
def reference_activations(ref: Reference, roots: np.ndarray, q: dict, torques: np.ndarray, times: np.ndarray,
                          joints: dict) -> np.ndarray:
    """(K, nu) the activations of the reference's muscles for the clip's torques (K, J, 3) N m
    (world; at the reference's size) at the clip's joints `joints` {side: (hip, knee, ankle) indices}: the posed
    model's arms and strengths, sim.jiggle.activation's static optimization and activation dynamics."""
    from jiggle.sim.jiggle.activation import activation_dynamics, static_optimization
    K, nu = len(times), ref.model.nu
    arms = np.zeros((K, nu, 6, 3))
    lengths = np.zeros((K, nu))
    for k in range(K):
        ref.pose(roots[k], {s: q[s][k] for s in ref.legs})
        for i, s in enumerate(("l", "r")):
            a, lengths[k], _ = ref.arms_at(s)
            side = np.array([n.endswith(f"_{s}") for n in ref.names])
            arms[k, side, 3 * i:3 * i + 3] = a[side]
    speeds = np.gradient(lengths, times, axis=0)
    strength = ref.strongest(lengths, speeds)                                 # (K, nu)
    tq = np.concatenate([torques[:, list(joints["l"])], torques[:, list(joints["r"])]], axis=1)   # (K, 6, 3)
    # static_optimization takes one strength per muscle: its arms carry the sample's F / F0 instead
    f0 = np.maximum(strength.max(axis=0), 1e-9)
    exc, _ = static_optimization(arms * (strength / f0)[:, :, None, None], tq, f0)
    return activation_dynamics(exc, times)


def group_series(names, activation: np.ndarray, weights: np.ndarray | None, keys, side: str) -> np.ndarray:
    """(K,) the weighted mean activation of the muscles named with one of `keys` on `side` ('left'/'right' prefix
    or '_l'/'_r' suffix)."""
    pick = [i for i, n in enumerate(names) if any(k in n for k in keys) and
            (n.startswith(f"{side}_") or n.endswith("_" + side[0]))]
    if not pick:
        return np.full(len(activation), np.nan)
    w = np.ones(len(pick)) if weights is None else np.asarray(weights)[pick]
    return activation[:, pick] @ w / w.sum()


def phases(contact: np.ndarray) -> np.ndarray:
    """(K,) each sample's phase as (0: stance, 1: swing) + its fraction through that bout, nan in a bout cut by the
    clip's ends. contact : (K,) bool, the foot on the floor."""
    out = np.full(len(contact), np.nan)
    k = 0
    while k < len(contact):
        j = k
        while j < len(contact) and contact[j] == contact[k]:
            j += 1
        if k > 0 and j < len(contact):                     # a whole bout
            out[k:j] = (0.0 if contact[k] else 1.0) + np.arange(j - k) / (j - k)
        k = j
    return out


def timing_score(series: np.ndarray, phase: np.ndarray, windows) -> float:
    """The share of `series`' activation inside `windows` over the share of time they take (whole bouts only)."""
    ok = np.isfinite(phase) & np.isfinite(series)
    if ok.sum() < 4 or series[ok].sum() <= 0:
        return float("nan")
    inside = np.zeros(len(phase), bool)
    for name, a, b in windows:
        base = 0.0 if name == "stance" else 1.0
        inside |= (phase >= base + a) & (phase < base + b - 1e-12 if b < 1.0 else phase < base + 1.0)
    share_time = inside[ok].mean()
    if share_time <= 0:
        return float("nan")
    return float(series[ok & inside].sum() / series[ok].sum() / share_time)


def case(clip: str, character: str, ref: Reference, out: Path) -> dict:
    from jiggle.sim.drive.inverse import joint_torques
    from jiggle.sim.jiggle.activation import activations
    path = str(ASSETS / "mocap" / "cmu_bvh" / f"{clip}.bvh")
    fit, world_at, mass, times = fit_for(path, str(ASSETS / CHARACTERS[character]) if CHARACTERS[character] else None)
    roles = fit.mus.roles
    loads = joint_torques(fit.clip.scaled(fit.size.scale), times, mass, roles=roles)
    ours = activations(fit.mus.rig, world_at, loads, fit.clip.parents, fit.character.bind_world, times,
                       scale=fit.size.scale, roles=fit.mus.roles)
    world = np.asarray(world_at(times), np.float64)
    rest = np.asarray(fit.character.bind_world, np.float64)
    t0 = time.perf_counter()
    legs = clip_legs(world, rest, roles)
    roots, q, miss = fit_pose(ref, legs)
    height = float(np.ptp(rest[:, 2, 3])) * fit.size.scale
    gain = (REFERENCE_MASS_KG / mass) * (REFERENCE_HEIGHT_M / max(height, 1e-6))
    joints = {s: tuple(roles[f"{side}_{r}"] for r in ("upper_leg", "lower_leg", "foot"))
              for s, side in (("l", "left"), ("r", "right"))}
    act_ref = reference_activations(ref, roots, q, gain * loads.at(times), times, joints)
    t_ref = time.perf_counter() - t0
    f0 = np.array(ref.model.actuator_gainprm[:, 2])
    foot = {s: loads.contact[:, list({roles[f"{side}_foot"], roles[f"{side}_toe"]})].any(axis=1)
            for s, side in (("l", "left"), ("r", "right"))}
    foot = {s: np.interp(times, loads.times, v.astype(float)) > 0.5 for s, v in foot.items()}
    rows, series = [], {}
    names = list(fit.mus.rig.names)
    for g, keys in GROUPS.items():
        for s, side in (("l", "left"), ("r", "right")):
            a = group_series(names, ours.activation, None, (g,), side)
            b = group_series(ref.names, act_ref, f0, keys, side)
            ok = np.isfinite(a) & np.isfinite(b)
            corr = float(np.corrcoef(a[ok], b[ok])[0, 1]) if ok.sum() > 3 and a[ok].std() > 0 and b[ok].std() > 0 \
                else float("nan")
            ph = phases(foot[s])
            win = EMG_WINDOWS.get(g)
            rows.append({"group": g, "side": side, "correlation": corr, "mean_ours": float(np.nanmean(a)),
                         "mean_reference": float(np.nanmean(b)), "peak_ours": float(np.nanmax(a)),
                         "peak_reference": float(np.nanmax(b)),
                         "timing_ours": timing_score(a, ph, win) if win else None,
                         "timing_reference": timing_score(b, ph, win) if win else None})
            series[(g, side)] = (a, b)
    plot(out / f"{clip}_{character}.png", times, series, foot,
         f"CMU {clip} ({CLIPS[clip]}) on the {character} body: jiggle (solid) and MyoSuite myolegs26 (dashed)")
    return {"clip": clip, "character": character, "mass_kg": mass, "height_m": height, "torque_gain": gain,
            "pose_miss_deg_median": float(np.median(miss)), "pose_miss_deg_max": float(miss.max()),
            "groups": rows, "reference_s": t_ref, "samples": int(len(times)),
            "stance_share": {s: float(v.mean()) for s, v in foot.items()}}


def plot(path: Path, times, series, foot, title) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(len(GROUPS), 2, figsize=(12, 8), sharex=True, sharey=True)
    for i, g in enumerate(GROUPS):
        for j, side in enumerate(("left", "right")):
            ax = axes[i, j]
            a, b = series[(g, side)]
            on = foot[side[0]]
            ax.fill_between(times, 0, 1.02, where=on, color="0.9", step="mid", lw=0)
            ax.plot(times, a, color="C0", label="jiggle")
            ax.plot(times, b, color="C3", ls="--", label="myolegs26")
            ax.set_ylim(0, 1.02)
            ax.set_title(f"{side} {g}", fontsize=9)
            ax.grid(alpha=0.3)
            if i == len(GROUPS) - 1:
                ax.set_xlabel("time (s); grey: that foot on the floor")
    axes[0, 0].legend(loc="upper right", fontsize=8)
    fig.suptitle(title, fontsize=10)
    save_figure(fig, path, 80)


def write(results: list[dict], out: Path, seconds: float) -> None:
    lines = ["# Muscle activation against MyoSuite (benchmarks/activation_reference.py)", "",
             f"`python benchmarks/activation_reference.py`: {len(results)} cases in {seconds:.0f} s. The same clip's "
             "joint torques (scaled to the reference's 75 kg, 1.70 m) drive jiggle's fitted muscles and MyoSuite's "
             "myolegs26, posed in the clip's leg angles, through the same least-effort static optimization and "
             "activation dynamics. Correlation: of the two activations over the clip. Timing: the share of the "
             "group's activation inside its published running-EMG window (quadriceps late swing through loading, "
             "hamstrings late swing, calf stance) over the window's share of the time (1: none; above: on where "
             "the EMG is), jiggle / reference.", "",
             "| clip | body | group | side | correlation | mean jiggle / ref | peak jiggle / ref | timing jiggle / ref |",
             "|---|---|---|---|---|---|---|---|"]
    fmt = lambda v: "-" if v is None or not np.isfinite(v) else f"{v:.2f}"  # noqa: E731
    for r in results:
        for g in r["groups"]:
            c = g["correlation"]
            cs = fmt(c) if not (np.isfinite(c) and c < 0.7) else f"**{c:.2f}**"
            lines.append(f"| {r['clip']} | {r['character']} | {g['group']} | {g['side']} | {cs} | "
                         f"{fmt(g['mean_ours'])} / {fmt(g['mean_reference'])} | {fmt(g['peak_ours'])} / "
                         f"{fmt(g['peak_reference'])} | {fmt(g['timing_ours'])} / {fmt(g['timing_reference'])} |")
    corr = np.array([g["correlation"] for r in results for g in r["groups"]], float)
    lines += ["", f"Correlation at least 0.7: {int(np.sum(corr >= 0.7))} of {int(np.isfinite(corr).sum())}; median "
              f"{np.nanmedian(corr):.2f}, worst {np.nanmin(corr):.2f}.", "",
              "The pose fit (the reference's thigh and shank against the clip's, worst per sample): " + ", ".join(
                  f"{r['clip']} {r['character']} median {r['pose_miss_deg_median']:.1f} deg, worst "
                  f"{r['pose_miss_deg_max']:.1f} deg" for r in results) + ".", ""]
    lines += [f"![{r['clip']} {r['character']}](activation_reference/{r['clip']}_{r['character']}.png)" for r in results]
    (out / "activation_reference.md").write_text("\n".join(lines) + "\n")
    (out / "activation_reference.json").write_text(json.dumps(results, indent=1))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(HERE / "results"))
    ap.add_argument("--clips", nargs="*", default=list(CLIPS))
    ap.add_argument("--characters", nargs="*", default=list(CHARACTERS))
    args = ap.parse_args(argv)
    if not (ASSETS / "mocap" / "cmu_bvh").is_dir():
        print(f"skipped: no shared CMU clips at {ASSETS / 'mocap' / 'cmu_bvh'}")
        return 0
    try:
        ref = Reference()
    except ImportError as e:
        print(f"skipped: MyoSuite's models are not installed ({e}); ./dev.sh install brings myo-sim")
        return 0
    out = Path(args.out)
    t = time.perf_counter()
    results = []
    for clip in args.clips:
        for character in args.characters:
            if CHARACTERS[character] and not (ASSETS / CHARACTERS[character]).is_file():
                continue
            r = case(clip, character, ref, out / "activation_reference")
            results.append(r)
            print(clip, character, [(g["group"], g["side"], round(g["correlation"], 2)) for g in r["groups"]],
                  flush=True)
    write(results, out, time.perf_counter() - t)
    return 0


if __name__ == "__main__":
    sys.exit(main())
