"""Loop-aware bakes (`jiggle bake --loop auto|on|off`): a game cycle baked in its periodic steady state.

    judge (prepare, sim/bake/setup.py): is the clip a cycle? -> Loop (period, the times of one cycle, goal
        knots and joint transforms extended periodically past both ends)
    warm_up (the bake, sim/bake/baker.py, before its first chunk): the cycle simulated again and again from
        the state its last run ended in, until the state at the cycle's start stops changing -> the steady
        state, from which the bake's first chunk goes on as any chunk goes on from the one before

**auto** judges the clip a cycle when its pose at the window's end (the clip's last key, or --end) repeats
the one at its start: every joint's world position within CLOSED_TOLERANCE (1%) of the character's height
of where it was, once the root's horizontal travel over the window is taken off (a walk with root motion
moves forward: the cycle repeats shifted by that travel). That cycle is *closed*: its period is the
window's length and the last key is the first pose again. A glTF/FBX animation of the character file
itself is a game's cycle: when its ends do not meet that closely but the jump from its last key to its
first is no larger than its largest key-to-key step, it is judged *open*: the last key is the frame before
the first, and the period is the clip's length plus one key step. Anything else (mocap takes, the
physics drive, a built-in scene) is baked plainly. **on** loops whatever the judge says (a clip whose ends
do not meet pops at the seam in its pose, not only in its jiggle); **off** never.

What a loop writes follows the clip's own convention, over one period [a, a + P] at n = round(P x fps) equal
steps (fps nudged by at most half a frame per period, so a whole number of frames spans it; bake.json
records the rate asked for and the one used). A closed cycle: frames 0..n, the last at a + P, its joints the
first frame's shifted by the root travel, so the last frame repeats the first, pose and (in the steady
state) jiggle, as the clip's last key repeats its first: an engine looping it wraps from a pose to the same
pose. An open cycle: frames 0..n-1, the clip's own frames; a DCC looping them steps from frame n-1 to frame 0
as from any frame to the next; its glb adds the key at the period (frame 0 again, sim/bake/glb.py), so an
engine's keys run from 0 to the period either way.

The physics of one cycle is the physics of the clip repeated with its root offset by the travel each time
(goal knots, capsules and floor all translated alike, and the jiggle is invariant to that translation): the
warm-up simulates the cycle from a state, takes the travel off the state it ends in, and starts the next
cycle there. The goal knots and joint transforms extend periodically past both ends, so the goals'
velocities and cut tests at the seam see the neighbours the repeated clip gives them.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np

from jiggle.rig.base.errors import InputError

LOOP_MODES = ("auto", "on", "off")
CLOSED_TOLERANCE = 0.01
"""The largest joint displacement between the window's end and start (root travel off), as a share of the
character's height, of a closed cycle."""
WARMUP_TOLERANCE_MM = 0.01
"""The warm-up stops when the state at the cycle's start changes by less than this between two cycles (mm at the
character's real size: particle positions, and velocities times one frame step; a file in other units than its real
size is simulated in the file's, so its changes are scaled by the real size's factor)."""
WARMUP_MAX_CYCLES = 16
"""Cycles the warm-up runs at most (the first from the quasi-static start)."""
RELAXATION = 0.3
"""When the start state stops contracting (the change after a cycle above half the one two cycles before, a
tissue driven hard into its stiffening), the next start moves only this share of the way to where the cycle
ended: a fixed point the plain repetition circles (a period-doubling) becomes an attracting one."""
KNOT_MARGIN = 6
"""Goal knots carried past each end of the cycle (the bake's chunks reach MARGIN = 3 past theirs)."""


@dataclass(frozen=True, eq=False)
class Loop:
    """What the judge decided, and a looping bake's time base.

    mode : "auto", "on" or "off" as asked. on : whether the bake loops. kind : "closed" (the last key repeats
    the first pose), "open" (the last key is the frame before the first), "forced" (--loop on, the ends do not
    meet), None (not a loop). why : the reason, in words. start : seconds, the cycle's first frame (a).
    period : seconds (P). fps_asked, fps : the output rate asked for and the one used (n / P). delta : (3,)
    metres, the root's horizontal travel over one period. gap : the largest joint displacement between the
    window's ends (travel off) over the character's height. step : the clip's largest key-to-key joint step
    over the height (open cycles), None when not measured. cycle_times : (n + 1,) seconds, one period's output
    frames, both ends. times, knots : the bake's output times (cycle_times, or their first --frames) and goal
    knots (periodic past both ends). world_at : times -> (k, J, 4, 4), the drive's joint transforms extended
    periodically (the travel added per period). joints_at : the same for the clip's own joints.
    """

    mode: str
    on: bool
    kind: str | None
    why: str
    start: float = 0.0
    period: float = 0.0
    fps_asked: float = 0.0
    fps: float = 0.0
    delta: np.ndarray = field(default_factory=lambda: np.zeros(3))
    gap: float | None = None
    step: float | None = None
    own: bool = False
    cycle_times: np.ndarray | None = None
    times: np.ndarray | None = None
    knots: np.ndarray | None = None
    world_at: Callable | None = None
    joints_at: Callable | None = None

    @property
    def repeats_first(self) -> bool:
        """Whether the frames written end with the first again (closed, forced), else one frame before it (open)."""
        return self.on and self.kind != "open"

    @property
    def frames(self) -> int:
        """Frames one whole period writes: n + 1 (both ends) or n (an open cycle's)."""
        return len(self.cycle_times) - (0 if self.repeats_first else 1)

    def to_json(self) -> dict:
        """bake.json's (and the params') "loop": the decision, the time base."""
        out = {"mode": self.mode, "on": self.on, "kind": self.kind,
               "closed": None if self.gap is None else bool(self.kind == "closed"),
               "why": self.why, "own_animation": self.own,
               "end_gap_pct_of_height": None if self.gap is None else round(100.0 * self.gap, 4),
               "largest_key_step_pct_of_height": None if self.step is None else round(100.0 * self.step, 4)}
        if self.on:
            n = len(self.cycle_times) - 1
            out.update({"start_s": self.start, "period_s": self.period, "fps_asked": self.fps_asked,
                        "fps": self.fps, "cycle_frames": n, "repeats_first": self.repeats_first,
                        "root_travel_m": [round(float(x), 6) + 0.0 for x in self.delta],
                        "frames_written": f"0..{n}: one period, both ends; frame {n} repeats frame 0 (pose moved by "
                                          f"the root travel and, in the steady state, jiggle), as the clip's last key "
                                          f"repeats its first" if self.repeats_first else
                                          f"0..{n - 1}: one period without its end, as the clip's own keys; frame 0 "
                                          f"follows frame {n - 1} as one ordinary step (a glb adds the key at the "
                                          f"period, frame 0 again)"})
        return out


def off(mode: str, why: str, **kw) -> Loop:
    return Loop(mode=mode, on=False, kind=None, why=why, **kw)


def judge(mode: str | None, *, clip, drive: str, world_at: Callable, height: float, times: np.ndarray,
          fps: float, end: float | None, frames: int | None, own: bool, goal_rate: float | None,
          joints_at: Callable | None = None, log: Callable[[str], None] = lambda s: None) -> Loop:
    """The Loop of a bake (module docstring).

    mode : "auto" (None too), "on" or "off". clip : the clip the drive plays (rig.motion.clip.Clip, on the
    character's skeleton). drive : "kinematic" or "physics". world_at : times -> (k, J, 4, 4) joint world
    transforms (the drive's). height : metres, the character's (as simulated). times : (T,) the plain bake's
    output times (their first is the cycle's start). fps : the output rate asked for. end : --end (None: the
    clip's end). frames : --frames (None: all). own : the clip is an animation of the character file itself.
    goal_rate : Hz, the goal knots' rate. joints_at : the clip's own joints (the npz's joint_world), None: none.
    """
    mode = mode or "auto"
    if mode not in LOOP_MODES:
        raise InputError(f"expected one of {', '.join(LOOP_MODES)}, got {mode!r}", field="--loop")
    if mode == "off":
        return off(mode, "--loop off")
    if drive != "kinematic":
        if mode == "on":
            raise InputError("the physics drive simulates the body, so its poses do not repeat a cycle: --loop on "
                             "needs the kinematic drive", field="--loop")
        return off(mode, "the physics drive simulates the body: its poses do not repeat a cycle")
    a = float(times[0])
    b = float(clip.duration if end is None else end)
    if b - a <= 0:
        return off(mode, "a single pose")
    ends = np.asarray(world_at(np.array([a, b])), np.float64)[:, :, :3, 3]           # (2, J, 3)
    travel = (ends[1] - ends[0]).mean(axis=0)
    travel[2] = 0.0
    h = max(float(height), 1e-9)
    gap = float(np.linalg.norm(ends[1] - ends[0] - travel, axis=1).max()) / h
    whole = a <= 1e-9 and abs(b - clip.duration) <= 1e-9
    step = None
    kind, why = None, ""
    if gap <= CLOSED_TOLERANCE:
        kind = "closed"
        why = (f"closed: the pose at {b:.4g} s repeats the one at {a:.4g} s (joints within {100 * gap:.3g}% of the "
               f"height, <= {100 * CLOSED_TOLERANCE:g}%, root travel {np.linalg.norm(travel):.3g} m off)")
    elif own and whole and clip.num_frames >= 3:
        keys = np.asarray(world_at(clip.times), np.float64)[:, :, :3, 3]               # (F, J, 3)
        d = np.diff(keys, axis=0)
        d = d - np.concatenate([d.mean(axis=1)[:, :2], np.zeros((len(d), 1))], axis=1)[:, None]
        step = float(np.linalg.norm(d, axis=2).max()) / h
        if gap <= step * (1.0 + 1e-3):          # a seam as long as the largest step: equal but for round-off
            kind = "open"
            why = (f"open: the character's own animation, its last key {100 * gap:.3g}% of the height from its first "
                   f"(> {100 * CLOSED_TOLERANCE:g}%), no more than its largest key step ({100 * step:.3g}%): the last "
                   f"key is the frame before the first, the period one key step longer than the clip")
    if kind is None:
        why = (f"the pose at {b:.4g} s is {100 * gap:.3g}% of the height from the one at {a:.4g} s "
               f"(> {100 * CLOSED_TOLERANCE:g}%)" + (f" and more than its largest key step ({100 * step:.3g}%)"
                                                      if step is not None else ""))
        if mode == "auto":
            return off(mode, "not a cycle: " + why, gap=gap, step=step, own=own)
        kind, why = "forced", "--loop on: " + why + "; the pose pops at the seam"
    period = b - a
    if kind == "open":
        period += 1.0 / clip.fps
        travel = travel * period / (b - a)
    n = max(1, int(round(period * fps)))
    used = float(fps) if abs(period * fps - n) < 1e-6 else n / period
    cycle = a + period * np.arange(n + 1) / n
    if used != fps:
        log(f"loop: {n} frames a period of {period:.4g} s, at {used:.4g} fps (asked {fps:g})")
    source = world_at
    if kind == "open":
        source = _open_drive(clip, travel)
    from jiggle.sim.jiggle.secondary import DEFAULT_GOAL_RATE, knot_times
    from jiggle.sim.jiggle.simulate import merge_times
    inner = knot_times(cycle, goal_rate or max(DEFAULT_GOAL_RATE, used))
    inner = inner[inner <= a + period + 1e-9]
    eps = 1e-9
    knots = merge_times(inner[inner < a + period - eps][-KNOT_MARGIN:] - period, inner,
                        inner[inner > a + eps][:KNOT_MARGIN] + period)
    full = cycle if kind != "open" else cycle[:-1]      # an open clip's own frames: the period's end not among them
    lp = Loop(mode=mode, on=True, kind=kind, why=why, start=a, period=period, fps_asked=float(fps), fps=used,
              delta=travel, gap=gap, step=step, own=own, cycle_times=cycle,
              times=full if frames is None else full[:frames], knots=knots,
              world_at=periodic(source, a, period, travel))
    if joints_at is not None:                  # the clip's own skeleton travels in its own space
        je = np.asarray(joints_at(np.array([a, b])), np.float64)[:, :, :3, 3]
        jt = (je[1] - je[0]).mean(axis=0) * period / (b - a)
        jt[2] = 0.0
        lp = replace(lp, joints_at=periodic(joints_at, a, period, jt))
    log(f"loop: {why}")
    return lp


def periodic(fn: Callable, a: float, period: float, delta: np.ndarray) -> Callable:
    """times -> fn's (k, J, 4, 4) transforms of the cycle [a, a + period) repeated both ways, each repeat shifted by
    `delta` (3,) metres: at t = a + u + m period (0 <= u < period), fn(a + u) moved by m delta."""
    delta = np.asarray(delta, np.float64)

    def at(ts):
        ts = np.asarray(ts, np.float64).reshape(-1)
        m = np.floor((ts - a) / period + 1e-9)
        u = np.clip(ts - a - m * period, 0.0, period)
        out = np.array(fn(a + u), dtype=np.float64)
        if delta.any():
            out[..., :3, 3] += (m[:, None] * delta[None])[:, None, :]
        return out
    return at


def _open_drive(clip, travel: np.ndarray) -> Callable:
    """The kinematic drive of an open cycle over [0, duration + 1 key]: the clip with its first key appended
    after its last (the roots moved by the travel)."""
    from jiggle.rig.motion.clip import Clip, transforms
    from jiggle.sim.drive.skeleton import Skeleton
    tra0 = np.array(clip.translations[:1])
    tra0[:, clip.parents < 0] += travel
    ext = replace(clip, rotations=np.concatenate([clip.rotations, clip.rotations[:1]]),
                  translations=np.concatenate([clip.translations, tra0]))
    assert isinstance(ext, Clip)
    sk = Skeleton(ext)
    return lambda ts: transforms(*sk.world(np.asarray(ts, dtype=np.float64)))


# ---------------------------------------------------------------------------------------- warm-up
def warm_up(setup, model, solver, colliders=None, tissue=None, margin: int = 3,
            log: Callable[[str], None] = lambda s: None) -> tuple[tuple[np.ndarray, np.ndarray], dict]:
    """The particles' state (x, v) (N, 3) float32 at the cycle's start in its periodic steady state, and the
    record of how it was reached ({"cycles", "change_mm", "changes_mm", "converged", "tolerance_mm"}).

    The cycle (setup.loop's cycle_times, over the bake's goal knots) is simulated from the quasi-static start
    (sim.jiggle.simulate.restart), then again from the state each run ended in with the root travel taken
    off, until the state a cycle ends in equals the one it started from within WARMUP_TOLERANCE_MM (positions;
    velocities times a frame step) or WARMUP_MAX_CYCLES ran (relaxed steps, RELAXATION, once the repetition
    stops contracting); the start of the smallest such change is returned. The step grid and goal track are the bake's own over the cycle, so the
    bake's chunks going on from this state repeat the last cycle's arithmetic.
    """
    from jiggle.sim.jiggle.simulate import goals, simulate
    lp, s, rig = setup.loop, setup, setup.rig
    times = lp.cycle_times
    kt, world_k = cycle_knots(setup, margin)
    static = s.static_at(kt, world_k)
    track = goals(rig, kt, static.cvs, s.settings)
    coll = None if colliders is None else colliders.at(kt, world_k, track.cut)

    def cycle(state):
        solver.stops.zero_()
        _, (x, v) = simulate(model, track, times, s.settings, solver=solver, preroll=0.0, start=state,
                             colliders=coll, contacts={}, tissue=tissue)
        return x, v
    state, rec = steady_state(cycle, lp, log, scale=getattr(setup, "real_scale", 1.0))
    solver.stops.zero_()
    return state, rec


def warm_up_fem(setup, fem, colliders=None, margin: int = 3,
                log: Callable[[str], None] = lambda s: None) -> tuple[tuple[np.ndarray, np.ndarray], dict]:
    """As :func:`warm_up` for the FEM hero mode (sim.fem.tissue.FemTissue): the solid's vertex state (x, v) at the
    cycle's start in its periodic steady state, from the start on the goal moving with it."""
    from jiggle.sim.jiggle.goal_track import find_cuts
    lp, s, rig = setup.loop, setup, setup.rig
    times = lp.cycle_times
    kt, world_k = cycle_knots(setup, margin)
    static = rig.static(world_k, device=s.settings.device).cvs
    cuts = find_cuts(kt, static, s.settings.cut_ratio, s.settings.cut_jump)
    ends = None if colliders is None else colliders.capsules.ends(world_k).reshape(len(kt), -1, 3)

    def cycle(state):
        _, end, _ = fem.run(kt, static, times, start=state, cuts=cuts, capsule_ends=ends)
        return end
    return steady_state(cycle, lp, log, scale=getattr(setup, "real_scale", 1.0))


def cycle_knots(setup, margin: int) -> tuple[np.ndarray, np.ndarray]:
    """The bake's goal knots over one cycle of setup.loop, `margin` more past each end, and the joint world
    transforms (k, J, 4, 4) there: the window a warm-up simulates, as a chunk's."""
    from jiggle.sim.jiggle.simulate import TIME_EPS
    s, times = setup, setup.loop.cycle_times
    ka = max(0, int(np.searchsorted(s.knots, times[0] - TIME_EPS)) - margin)
    kb = min(len(s.knots), int(np.searchsorted(s.knots, times[-1] + TIME_EPS, side="right")) + margin)
    kt = s.knots[ka:kb]
    return kt, np.asarray(s.world_at(kt), dtype=np.float64)


def steady_state(cycle: Callable, lp: Loop, log: Callable[[str], None] = lambda s: None, scale: float = 1.0
                 ) -> tuple[tuple[np.ndarray, np.ndarray], dict]:
    """The fixed point of `cycle` (start state (x, v) or None for the quasi-static start -> the state (x, v) one
    period later) with the loop's root travel lp.delta taken off, and the warm-up's record (see warm_up); scale :
    real metres per simulated metre (the changes are measured at real size)."""
    times = lp.cycle_times
    frame = lp.period / (len(times) - 1)
    shift = np.asarray(lp.delta, np.float32)[None]
    state, residuals, best, relax = None, [], None, 1.0
    for k in range(WARMUP_MAX_CYCLES):
        x, v = cycle(state)
        end = (np.asarray(x - shift, np.float64), np.asarray(v, np.float64))
        if state is None:                   # the quasi-static start: the first cycle only carries it in
            state = tuple(a.astype(np.float32) for a in end)
            continue
        dx = np.abs(end[0] - state[0]).max(initial=0.0)
        dv = np.abs(end[1] - state[1]).max(initial=0.0) * frame
        residuals.append(1000.0 * float(scale) * float(max(dx, dv)))
        if best is None or residuals[-1] < best[0]:
            best = (residuals[-1], state, len(residuals))
        if residuals[-1] < WARMUP_TOLERANCE_MM:
            break
        if relax == 1.0 and len(residuals) >= 4 and residuals[-1] > 0.5 * residuals[-3]:
            relax = RELAXATION             # not contracting (a hard-driven, stiffening tissue): relaxed steps
        state = tuple((s0 + relax * (e - s0)).astype(np.float32) for s0, e in zip(state, end))
    change, state, used = best if best is not None else (0.0, state, 0)
    rec = {"cycles": len(residuals) + 1, "change_mm": change, "changes_mm": [round(c, 5) for c in residuals],
           "start_from_cycle": used + 1, "converged": bool(change < WARMUP_TOLERANCE_MM),
           "relaxation": relax, "tolerance_mm": WARMUP_TOLERANCE_MM, "max_cycles": WARMUP_MAX_CYCLES,
           "rule": "cycle k simulated from start state s_k; change = max over particles of |x_end - travel - x_start| "
                   "and |v_end - v_start| x one frame step (mm at real size); s_(k+1) = s_k + relaxation (end - s_k); the bake "
                   "starts from the s_k of the smallest change"}
    log(f"loop warm-up: {rec['cycles']} cycles, the start state repeats within {change:.3g} mm"
        + ("" if rec["converged"] else f" (not below {WARMUP_TOLERANCE_MM:g} mm: the best start of "
                                       f"{WARMUP_MAX_CYCLES} cycles)"))
    return state, rec


def wrap_figures(skin_final: np.ndarray, skin_static: np.ndarray, repeats_first: bool) -> dict:
    """The loop wrap of a bake's jiggle offset d = skin_final - skin_static (T, V, 3) metres, in mm.

    wrap_mm : max over vertices |d[T-1] - d[0]|: the seam a player shows when it goes from the last frame to the
    first. For a loop whose last frame repeats the first (repeats_first) that is the mismatch of the steady
    state, ideally 0, and `wrap_step_mm`, |d[0] - d[T-2]|, is the step a player looping frames 0..T-2 takes
    across the seam (one ordinary frame step when the loop is right); otherwise (a plain bake, an open cycle's
    frames 0..n-1) wrap_step_mm is wrap_mm, the step from the last frame to the first. step_median_mm, step_max_mm : the median
    and largest over t of max over vertices |d[t+1] - d[t]|. wrap_ratio : wrap_mm / step_median_mm (inf when the
    median step is 0 and the wrap is not, 0 when both are).
    """
    d = np.asarray(skin_final, np.float64) - np.asarray(skin_static, np.float64)
    T = d.shape[0]
    if T < 2:
        return {"wrap_mm": 0.0, "wrap_ratio": 0.0, "step_median_mm": 0.0, "step_max_mm": 0.0}
    steps = np.linalg.norm(np.diff(d, axis=0), axis=-1).max(axis=1) * 1e3
    wrap = float(np.linalg.norm(d[-1] - d[0], axis=-1).max()) * 1e3
    med = float(np.median(steps))
    ratio = (0.0 if wrap == 0.0 else math.inf) if med == 0.0 else wrap / med
    out = {"wrap_mm": wrap, "wrap_ratio": ratio, "step_median_mm": med, "step_max_mm": float(steps.max())}
    if repeats_first and T >= 3:
        out["wrap_step_mm"] = float(np.linalg.norm(d[0] - d[-2], axis=-1).max()) * 1e3
    else:
        out["wrap_step_mm"] = wrap
    return out
