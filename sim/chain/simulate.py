"""Chains swung over a clip: the animated pose at the goal knots in, each chain joint's simulated rotation at the
output times out.

    drive's joint transforms at the knots --targets--> per knot: each anchor's and body capsule's world pose, each
        chain joint's animated rotation from bind (the spring's rest), the gravity torque that pose needs held
    per step of a fixed grid (dt from the model, the same whatever the output rate, so the bake is frame-rate
        independent): the knots' values between knots (cubic Hermite, C1: no kicks at the knots), set as the
        mocap poses, the springs' rests (qpos_spring), the applied torques (the pose held against gravity, the
        damping's reference: the target's own velocity) and the anchors' driving forces (ChainSolver._window);
        mujoco.mj_step
    output times --> each joint's rotation between the two steps around it (normalized lerp of quaternions)

A joint's spring: k = I (2 pi f)^2 over the inertia I it turns, f the chain's stiffness (Hz) less TAPER toward the
tip; damping c = 2 zeta sqrt(k I) toward the target's velocity; the gravity torque at the animated pose applied,
times the chain's gravity, so a still pose stays where the animator put it and gravity shapes the swing.

A looping bake (sim/bake/loop.py) swings its chains in their periodic steady state: the cycle run from the state
its last run ended in until the state at its start repeats (as the particles' warm-up), on a step that divides the
period, so the last frame's chains meet the first's.

`chain_world` puts the simulated rotations back on the animated skeleton: a chain root hangs from its animated
parent, each joint's translation from its parent is the animation's, its rotation the simulation's.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from jiggle.rig.motion import quat
from jiggle.sim.chain.params import AIR_DENSITY, DRAG_COEFFICIENT, LIMIT_DEG, TAPER
from jiggle.sim.jiggle.keyed import Curve, value_at

WINDOW = 4096
"""Steps whose inputs are made at once (memory is bounded by a window, not the clip)."""
DRAG_EVERY = 4
"""Steps between updates of the air drag (a slow force: each link's velocity over those steps, the force held)."""
KNOT_BLOCK = 512
"""Knots the drive is asked for at once."""
WARMUP_TOLERANCE = 5e-4
"""A looping bake's warm-up stops when the chains' state at the cycle's start changes by less than this (radians
of any joint, and its angular velocity times a step of 1/60 s)."""
WARMUP_MAX_CYCLES = 24


@dataclass
class ChainRun:
    """What a run gives: rotations (T, n, 4) float64, each chain joint's simulated rotation from its bind frame
    (w, x, y, z) at the output times; warmup : a looping bake's record, else
    None; steps : the steps of the frames written, steps_all : with the warm-up's; seconds : the time it took."""

    rotations: np.ndarray
    steps: int = 0
    steps_all: int = 0
    seconds: float = 0.0
    warmup: dict | None = None
    dt: float = 0.0


# ------------------------------------------------------------------------------------------ the drive
@dataclass
class KnotInputs:
    """Per knot (K): the drivers' world poses (K, D, 3) and (K, D, 4), the chain joints' animated rotations from
    bind (K, n, 4), each made continuous over the knots; gravity (K, n, 3) the torque holding the pose."""

    knots: np.ndarray
    driver_pos: np.ndarray
    driver_quat: np.ndarray
    target: np.ndarray
    gravity: np.ndarray | None = None


def rest_rotations(links) -> np.ndarray:
    """(n, 4) each link's bind rotation in its parent's frame."""
    return quat.normalize(quat.from_matrix(links.local[:, :3, :3]))


def targets_from_world(links, world: np.ndarray) -> np.ndarray:
    """(T, n, 4) each chain joint's (rig.character.chains.ChainLinks) animated rotation from its bind frame, from
    joint world transforms (T, J, 4, 4): R0^-1 (R_parent^-1 R_joint), R0 the bind rotation in the parent's frame."""
    par = np.asarray(links.joints)[np.where(links.parent >= 0, links.parent, 0)]
    par = np.where(links.parent >= 0, par, links.anchor)
    Rp = world[:, par, :3, :3]
    Rj = world[:, links.joints, :3, :3]
    local = np.swapaxes(Rp, -1, -2) @ Rj
    rel = np.swapaxes(links.local[None, :, :3, :3], -1, -2) @ local
    return quat.normalize(quat.from_matrix(rel))


def knot_inputs(cm, knots: np.ndarray, world_at: Callable) -> KnotInputs:
    """The animation at the knots (KnotInputs), the drive asked KNOT_BLOCK knots at a time."""
    parts = {k: [] for k in ("p", "q", "t")}
    for a in range(0, len(knots), KNOT_BLOCK):
        w = np.asarray(world_at(knots[a:a + KNOT_BLOCK]), np.float64)
        m = w[:, cm.drivers]
        parts["p"].append(m[..., :3, 3])
        parts["q"].append(quat.from_matrix(m[..., :3, :3]))
        parts["t"].append(targets_from_world(cm.links, w))
    cat = {k: np.concatenate(v) for k, v in parts.items()}
    return KnotInputs(knots=np.asarray(knots, np.float64), driver_pos=cat["p"],
                      driver_quat=quat.make_continuous(cat["q"]), target=quat.make_continuous(cat["t"]))


def gravity_torques(cm, inp: KnotInputs) -> np.ndarray:
    """(K, n, 3) N m: the generalized gravity force on each ball joint with the chains at their animated pose
    (full gravity; MuJoCo's inverse dynamics at zero velocity and acceleration)."""
    import mujoco
    m = cm.model
    d = mujoco.MjData(m)
    out = np.zeros((len(inp.knots), cm.links.count, 3))
    res = np.zeros(m.nv)
    qs = (cm.ball_q[:, None] + np.arange(4)).ravel()
    dv = (cm.ball_v[:, None] + np.arange(3)).ravel()
    for k in range(len(inp.knots)):
        for a in range(len(cm.driver_q)):
            d.qpos[cm.driver_q[a]:cm.driver_q[a] + 3] = inp.driver_pos[k, a]
            d.qpos[cm.driver_q[a] + 3:cm.driver_q[a] + 7] = inp.driver_quat[k, a]
        d.qpos[qs] = inp.target[k].ravel()
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        mujoco.mj_rne(m, d, 0, res)
        out[k] = res[dv].reshape(-1, 3)
    return out


def _hermite(t_knots: np.ndarray, values: np.ndarray, slopes: np.ndarray, t: np.ndarray):
    """values (K, ...) with slopes (K, ...) at t (S,): the cubic Hermite value and derivative (S, ...)."""
    K = len(t_knots)
    if K == 1:
        return np.repeat(values[:1], len(t), 0), np.zeros((len(t),) + values.shape[1:])
    k = np.clip(np.searchsorted(t_knots, t, side="right") - 1, 0, K - 2)
    h = (t_knots[k + 1] - t_knots[k])
    s = np.clip((t - t_knots[k]) / h, 0.0, 1.0)
    shape = (-1,) + (1,) * (values.ndim - 1)
    s, h = s.reshape(shape), h.reshape(shape)
    s2, s3 = s * s, s * s * s
    p0, p1, m0, m1 = values[k], values[k + 1], slopes[k] * h, slopes[k + 1] * h
    val = (2 * s3 - 3 * s2 + 1) * p0 + (s3 - 2 * s2 + s) * m0 + (-2 * s3 + 3 * s2) * p1 + (s3 - s2) * m1
    der = ((6 * s2 - 6 * s) * p0 + (3 * s2 - 4 * s + 1) * m0 + (-6 * s2 + 6 * s) * p1 + (3 * s2 - 2 * s) * m1) / h
    return val, der


def _slopes(t: np.ndarray, v: np.ndarray) -> np.ndarray:
    return np.gradient(v, t, axis=0) if len(t) > 1 else np.zeros_like(v)


def _rows(x: dict, sl: slice) -> dict:
    """ChainSolver.inputs' dict `x` at the rows `sl` (its "values" too)."""
    return {k: ({kk: vv[sl] for kk, vv in v.items()} if k == "values" else v[sl]) for k, v in x.items()}


def _local_omega(q: np.ndarray, dq: np.ndarray) -> np.ndarray:
    """Angular velocity in the rotated (local) frame of a unit quaternion path q with derivative dq: 2 vec(q* dq)."""
    return 2.0 * quat.mul(quat.conj(q), dq)[..., 1:]


# ------------------------------------------------------------------------------------------ the run
class ChainSolver:
    """Steps a ChainModel over the animation (module docstring). params : one ChainParams per chain."""

    def __init__(self, cm, params, inp: KnotInputs, dt: float | None = None):
        import mujoco
        self.cm, self.params, self.inp = cm, list(params), inp
        self.m = cm.model
        self.d = mujoco.MjData(self.m)
        self.dt = float(dt or cm.dt)
        self.m.opt.timestep = self.dt
        links = cm.links
        n = links.count
        self.qs = (cm.ball_q[:, None] + np.arange(4)).ravel()
        self.dv = (cm.ball_v[:, None] + np.arange(3)).ravel()
        length = np.asarray(links.length)[links.chain]
        self.taper = 1.0 - TAPER * np.clip(links.arc / np.maximum(length, 1e-9), 0.0, 1.0)
        self.keyed = any(p.keyed() for p in self.params)
        if inp.gravity is None:
            inp.gravity = gravity_torques(cm, inp)
        self.slopes = {k: _slopes(inp.knots, getattr(inp, k)) for k in
                       ("driver_pos", "driver_quat", "target", "gravity")}
        self.ball_jnt = np.array([self.m.dof_jntid[v] for v in cm.ball_v], np.int64)
        self.link_body = np.array([self.m.jnt_bodyid[j] for j in self.ball_jnt], np.int64)
        # quadratic air drag on each link's centre: F = -1/2 rho C_D A |v| v, A its capsule's side (2 r L)
        length = np.linalg.norm(links.tip, axis=1)
        self.drag_coef = 0.5 * AIR_DENSITY * DRAG_COEFFICIENT * 2.0 * links.radius * np.maximum(length, links.radius)
        self._drag_cap = 0.5 * links.mass / (DRAG_EVERY * self.dt)
        self._set(np.array([0.0]) + (inp.knots[0] if len(inp.knots) else 0.0), 0)
        self.n = n
        self._windows = {}

    def values(self, t: np.ndarray) -> dict:
        """Per link (S, n): stiffness N m/rad, damping N m s/rad, gravity share, drag share at times t (S,)."""
        ch = self.cm.links.chain
        out = {}
        for key in ("stiffness", "damping", "gravity", "drag"):
            per = np.stack([value_at(getattr(p, key), t) for p in self.params], axis=1) if self.params else \
                np.zeros((len(t), 0))
            out[key] = per[:, ch]
        w = 2.0 * math.pi * out["stiffness"] * self.taper[None]
        k = self.cm.inertia[None] * w * w
        out["k"], out["c"] = k, 2.0 * out["damping"] * np.sqrt(k * self.cm.inertia[None])
        return out

    def _set(self, t: np.ndarray, row: int) -> None:
        """The model's springs, damping, gravity and drag at time t[row]."""
        v = self.values(t[row:row + 1])
        m = self.m
        m.jnt_stiffness[self.ball_jnt] = v["k"][0]
        m.dof_damping[self.dv] = np.repeat(v["c"][0], 3)
        m.body_gravcomp[self.link_body] = 1.0 - v["gravity"][0]
        self._drag = self.drag_coef * v["drag"][0]
        self._gravity_share = v["gravity"][0]
        self._damping_c = v["c"][0]

    def inputs(self, t: np.ndarray) -> dict:
        """Everything each step at times t (S,) sets (module docstring)."""
        inp, sl = self.inp, self.slopes
        h = lambda k: _hermite(inp.knots, getattr(inp, k), sl[k], t)    # noqa: E731
        ap, av = h("driver_pos")
        aq, adq = h("driver_quat")
        tq, tdq = h("target")
        g, _ = h("gravity")
        n_aq = np.linalg.norm(aq, axis=-1, keepdims=True)
        n_tq = np.linalg.norm(tq, axis=-1, keepdims=True)
        aq, adq = aq / n_aq, adq / n_aq
        tq, tdq = tq / n_tq, tdq / n_tq
        out = {"driver_pos": ap, "driver_vel": av, "driver_quat": aq, "driver_omega": _local_omega(aq, adq),
               "target": tq, "target_omega": _local_omega(tq, tdq), "gravity": g}
        if self.keyed:
            out["values"] = self.values(t)
        return out

    def start(self, t0: float, balls: tuple[np.ndarray, np.ndarray] | None = None) -> None:
        """The state at t0: drivers on the animation moving with it; the chains at their animated pose moving with
        it, or at `balls` (qpos (n, 4), qvel (n, 3)) when given."""
        import mujoco
        d, cm = self.d, self.cm
        self._blowups = self.unstable()         # the count so far survives the reset
        mujoco.mj_resetData(self.m, d)
        x = self.inputs(np.array([t0]))
        for a in range(len(cm.driver_q)):
            qa, va = cm.driver_q[a], cm.driver_v[a]
            d.qpos[qa:qa + 3], d.qpos[qa + 3:qa + 7] = x["driver_pos"][0, a], x["driver_quat"][0, a]
            d.qvel[va:va + 3], d.qvel[va + 3:va + 6] = x["driver_vel"][0, a], x["driver_omega"][0, a]
        if balls is None:
            d.qpos[self.qs], d.qvel[self.dv] = x["target"][0].ravel(), x["target_omega"][0].ravel()
        else:
            d.qpos[self.qs], d.qvel[self.dv] = np.ravel(balls[0]), np.ravel(balls[1])
        A = len(cm.driver_q)
        if len(cm.mocap):
            d.mocap_pos[cm.mocap], d.mocap_quat[cm.mocap] = x["driver_pos"][0, A:], x["driver_quat"][0, A:]
        d.time = t0
        self._set(np.array([t0]), 0)
        mujoco.mj_forward(self.m, d)

    def unstable(self) -> int:
        """How many times MuJoCo found the state blowing up (and reset it) since the solver was made."""
        import mujoco
        return getattr(self, "_blowups", 0) + int(self.d.warning[mujoco.mjtWarning.mjWARN_BADQACC].number)

    def state(self) -> tuple[np.ndarray, np.ndarray]:
        return self.d.qpos[self.qs].reshape(-1, 4).copy(), self.d.qvel[self.dv].reshape(-1, 3).copy()

    def run(self, t0: float, steps: int, out_times: np.ndarray | None = None) -> np.ndarray:
        """Step `steps` times from the current state at t0; the joints' rotations (len(out_times), n, 4) at
        out_times (seconds in [t0, t0 + steps dt]), or (0, n, 4) when None."""
        import mujoco
        m, d, cm = self.m, self.d, self.cm
        n, dt = self.n, self.dt
        out_times = np.zeros(0) if out_times is None else np.asarray(out_times, np.float64)
        u = (out_times - t0) / dt
        out = np.zeros((len(out_times), n, 4))
        out[u <= 0.0] = d.qpos[self.qs].reshape(n, 4)
        # the step each output time lands in: (k, k + 1] in steps from t0
        land = np.ceil(u - 1e-9).astype(np.int64) - 1
        lands = {}
        for i in np.flatnonzero(u > 0.0):
            lands.setdefault(int(min(land[i], max(steps - 1, 0))), []).append(int(i))
        qs, has_mocap, keyed = self.qs, bool(len(cm.mocap)), self.keyed
        bodies = self.link_body
        centre = d.xipos[bodies].copy()
        drag = bool(self._drag.any()) or self.keyed
        # MuJoCo's arrays as views, made once: each attribute access makes a new one, a good share of a step's cost
        qpos, qpos_spring, qfrc, xipos, xfrc = d.qpos, m.qpos_spring, d.qfrc_applied, d.xipos, d.xfrc_applied
        mocap_pos, mocap_quat, step = d.mocap_pos, d.mocap_quat, mujoco.mj_step
        for w0 in range(0, steps, WINDOW):
            w1 = min(steps, w0 + WINDOW)
            key = (t0, dt, w0, w1)
            if key not in self._windows:                # a looping bake's warm-up runs the same window again
                self._windows = {key: self._window(t0 + dt * np.arange(w0 + 1, w1 + 1))}
            x, spring, force, mpos, mquat = self._windows[key]
            for i in range(w1 - w0):
                k = w0 + i
                if keyed:
                    self._set_row(x["values"], i)
                qpos_spring[:] = spring[i]
                qfrc[:] = force[i]
                if has_mocap:
                    mocap_pos[:] = mpos[i]
                    mocap_quat[:] = mquat[i]
                if drag and k % DRAG_EVERY == 0:   # each link's centre's velocity over the last steps, held
                    now_c = xipos[bodies]
                    vel = (now_c - centre) / (dt * (DRAG_EVERY if k else 1))
                    speed = np.sqrt(np.einsum("ij,ij->i", vel, vel))
                    # never more than half the link's momentum over the interval the force is held: drag slows a
                    # link, it cannot reverse it (explicit, it would at a large drag)
                    coef = np.minimum(self._drag * speed, self._drag_cap)
                    xfrc[bodies, :3] = -coef[:, None] * vel
                    centre = now_c
                sel = lands.get(k)
                if sel is not None:
                    prev = qpos[qs].reshape(n, 4)
                step(m, d)
                if sel is not None:
                    now = qpos[qs].reshape(n, 4)
                    f = (u[sel] - k)[:, None, None]
                    b = np.where(np.sum(prev * now, axis=-1, keepdims=True) < 0, -now, now)
                    out[sel] = quat.normalize((1.0 - f) * prev[None] + f * b[None])
        return out

    def _window(self, t_end: np.ndarray) -> tuple:
        """Everything the steps ending at t_end (S,) set, whole vectors per step (one copy each into MuJoCo):
        the inputs at each step's middle, qpos_spring (S, nq), qfrc_applied (S, nv), the mocap poses (S, M, 3),
        (S, M, 4).

        A ball joint's spring rests at the animated pose at the step's middle; its applied torque holds that pose
        against gravity and refers the damping to the animation's own angular velocity. An anchor's springs rest
        at the animated pose at the step's start (where the step finds it), and it is pushed with the force that
        takes its velocity from the animation's at the step's start to the animation's at its end (its mass or
        inertia times the change, over dt: the semi-implicit Euler step then lands it there) plus what its damping
        takes away at that velocity: it follows the animation exactly up to the step's O(dt^2), which its springs
        hold. The mocap bodies are posed at the step's start."""
        m, cm, dt = self.m, self.cm, self.dt
        A, S = len(cm.driver_q), len(t_end)
        # one evaluation on the half-step grid: each step's start, middle and end
        grid = np.r_[t_end[0] - dt, np.stack([t_end - 0.5 * dt, t_end], axis=1).ravel()]
        half = self.inputs(grid)
        xs, x, xe = (_rows(half, slice(a, a + 2 * S - 1, 2)) for a in (0, 1, 2))
        spring = np.repeat(np.asarray(m.qpos_spring)[None], S, axis=0)
        spring[:, self.qs] = x["target"].reshape(S, -1)
        force = np.zeros((S, m.nv))
        force[:, self.dv] = (x["gravity"] * self._gravity_or(x)[..., None] +
                             self._damping_or(x)[..., None] * x["target_omega"]).reshape(S, -1)
        for a in range(A):
            qa, va = cm.driver_q[a], cm.driver_v[a]
            spring[:, qa:qa + 3], spring[:, qa + 3:qa + 7] = xs["driver_pos"][:, a], xs["driver_quat"][:, a]
            for lo, key, inertia in ((va, "driver_vel", cm.anchor_mass), (va + 3, "driver_omega", cm.anchor_inertia)):
                damping = np.asarray(m.dof_damping[lo:lo + 3])
                force[:, lo:lo + 3] = inertia * (xe[key][:, a] - xs[key][:, a]) / dt + damping * xe[key][:, a]
        mpos, mquat = (xs["driver_pos"][:, A:], xs["driver_quat"][:, A:]) if len(cm.mocap) else (None, None)
        return x, spring, force, mpos, mquat

    def _gravity_or(self, x) -> np.ndarray:
        return x["values"]["gravity"] if "values" in x else np.broadcast_to(self._gravity_share, (len(x["target"]),
                                                                                                   self.n))

    def _damping_or(self, x) -> np.ndarray:
        return x["values"]["c"] if "values" in x else np.broadcast_to(self._damping_c, (len(x["target"]), self.n))

    def _set_row(self, v: dict, i: int) -> None:
        m = self.m
        m.jnt_stiffness[self.ball_jnt] = v["k"][i]
        m.dof_damping[self.dv] = np.repeat(v["c"][i], 3)
        m.body_gravcomp[self.link_body] = 1.0 - v["gravity"][i]
        self._drag = self.drag_coef * v["drag"][i]


def soft_limits(links, targets: np.ndarray) -> np.ndarray:
    """(n,) radians: each joint's soft limit from bind, LIMIT_DEG past the largest bend the animation gives it
    (targets (K, n, 4)), at most just under pi."""
    bend = quat.angle(targets).max(axis=0) if len(targets) else np.zeros(links.count)
    return np.minimum(bend + np.radians(LIMIT_DEG), np.pi - 1e-3)


def swing(cm, params, times: np.ndarray, knots: np.ndarray, world_at: Callable, loop=None,
          log: Callable[[str], None] = lambda s: None) -> ChainRun:
    """Each chain joint's rotation at `times` (seconds, increasing) over the animation `world_at` (times ->
    (k, J, 4, 4)) sampled at `knots` (they cover times), with `params` (one ChainParams per chain). loop : a
    looping bake's sim.bake.loop.Loop (times one period from loop.start), swung in its steady state."""
    import time as _time
    t_start = _time.perf_counter()
    times = np.asarray(times, np.float64)
    inp = knot_inputs(cm, np.asarray(knots, np.float64), world_at)
    t0 = float(times[0])
    warm = None
    if loop is not None:
        P = float(loop.period)
        steps = max(1, int(math.ceil(P / cm.dt - 1e-9)))
        solver = ChainSolver(cm, params, inp, dt=P / steps)
        t0 = float(loop.start)
        balls, changes, best = None, [], None
        frame = 1.0 / 60.0
        # every cycle records the output frames as it goes: the cycle whose end state repeats its start within the
        # tolerance is the bake's (no replay of it)
        for c in range(WARMUP_MAX_CYCLES):
            solver.start(t0, balls)
            s0 = solver.state()
            run = solver.run(t0, steps, times)
            s1 = solver.state()
            balls = s1
            if c == 0:                              # from the animated pose at rest: it only carries the state in
                continue
            dq = quat.angle(quat.mul(quat.conj(s0[0]), s1[0])).max(initial=0.0)
            dw = np.abs(s1[1] - s0[1]).max(initial=0.0) * frame
            changes.append(float(max(dq, dw)))
            if best is None or changes[-1] < best[0]:
                best = (changes[-1], run)
            if changes[-1] < WARMUP_TOLERANCE:
                break
        change, rot = best if best is not None else (0.0, run)
        total = steps
        warm_steps = len(changes) * steps
        warm = {"cycles": len(changes) + 1, "change_rad": change, "converged": bool(change < WARMUP_TOLERANCE),
                "tolerance_rad": WARMUP_TOLERANCE,
                "rule": "cycle k runs from the state cycle k - 1 ended in (the first from the animated pose); change "
                        "= the largest joint rotation between a cycle's start and end states (radians), or angular "
                        "velocity change times 1/60 s; the bake's frames are the cycle of the smallest change"}
        log(f"chains: loop warm-up {warm['cycles']} cycles, the start repeats within {change:.2g} rad")
    else:
        warm_steps = 0
        solver = ChainSolver(cm, params, inp)
        solver.start(t0)
        total = int(math.ceil((float(times[-1]) - t0) / solver.dt - 1e-9))
        rot = solver.run(t0, max(total, 0), times)
    if solver.unstable():
        raise RuntimeError(f"the chains' simulation blew up {solver.unstable()} time(s) at step {solver.dt:.3g} s: a "
                           "setting outside what sim.chain.model's step was chosen for")
    return ChainRun(rotations=rot, steps=int(total), steps_all=int(total + warm_steps),
                    seconds=_time.perf_counter() - t_start, warmup=warm, dt=solver.dt)


# ------------------------------------------------------------------------------------------ the skeleton
def chain_world(world: np.ndarray, cm, rotations: np.ndarray, riders: np.ndarray | None = None) -> np.ndarray:
    """Joint world transforms (T, J, 4, 4) with the chains swung: a copy of the animated `world` (T, J, 4, 4)
    where each chain joint's rotation in its parent's frame is R0 q (bind rotation R0, simulated rotation
    `rotations` (T, n, 4) from it), its translation in its parent's frame the animation's. riders : joints
    below a chain joint that are not chain joints (end bones), carried rigidly by it (None: found here)."""
    links = cm.links
    out = np.array(world, dtype=np.float64, copy=True)
    R = quat.to_matrix(rotations)                                  # (T, n, 3, 3)
    for i in range(links.count):                                  # parents first
        j = int(links.joints[i])
        p = int(links.anchor[i]) if links.parent[i] < 0 else int(links.joints[links.parent[i]])
        anim_local = np.linalg.inv(world[:, p]) @ world[:, j]
        local = anim_local.copy()
        local[:, :3, :3] = links.local[i, :3, :3] @ R[:, i]
        out[:, j] = out[:, p] @ local
    if riders is not None:
        for j, host in riders:
            out[:, j] = out[:, host] @ np.linalg.inv(world[:, host]) @ world[:, j]
    return out


def riders_of(cm, parents: np.ndarray) -> list[tuple[int, int]]:
    """(joint, its nearest chain ancestor) for every joint below a chain joint that is not one, parents first."""
    chain = set(int(j) for j in cm.links.joints)
    out = []
    for j in range(len(parents)):
        if j in chain:
            continue
        k = int(parents[j])
        while k >= 0 and k not in chain:
            k = int(parents[k])
        if k >= 0:
            out.append((j, k))
    return out
