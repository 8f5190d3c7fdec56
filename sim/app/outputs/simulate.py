"""What `jiggle simulate` writes: static against dynamic muscles, as figures, pictures and facts.

jiggle.json     per muscle the jiggle amplitude (largest CV distance dynamic - static): peak (mm) and
                when, the value at the end, a settle time; the skin's largest move from the static
                skin over the rendered frames; the frames written; the settings and sources
amplitude.png   per-muscle amplitude over time (the largest few), the blend curves when keyed, cuts
frames/frame_NNNN.png   (NNNN: the output frame; frames of an earlier run in the folder are removed)
                every K-th output frame side by side: static skin over the static focus muscles | the
                skin from the blended CVs coloured by its distance from the static skin (mm, one scale
                for all frames), the focus muscles jiggled (solid) and static (wireframe), so a muscle
                swinging past its static shape shows as a gap between the two

The pictures show the jiggling part: the focus muscles (by default those whose blended peak is at least
half the largest), seen from the character's side (its +X at bind, turned with the root), with a fixed frame
when they stay in place (the arm) and following them otherwise (a runner).
"""
from __future__ import annotations

import json
import os
import re
import time
from typing import Sequence

import numpy as np

from jiggle.rig.base.atomic import atomic_path
from jiggle.rig.base.errors import InputError
from jiggle.rig.skin.muscle_skin import skin_frames
from jiggle.sim.app.report.mesh_render import SKIN, frame_camera
from jiggle.sim.jiggle.keyed import jsonable_value
from jiggle.sim.jiggle.secondary import JiggleResult

os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")

SETTLE_FRACTION = 0.1
"""A muscle has settled once its amplitude stays below this fraction of its peak ..."""
SETTLE_WINDOW = 0.25
"""... for this many seconds (or until the clip ends)."""
SETTLED = 1e-6
"""metres: a muscle whose amplitude never exceeds this (a micrometre) counts as settled throughout."""
PANEL = (640, 360)
"""Pixels (width, height) of one panel of a frame picture."""
MUSCLE = (0.78, 0.18, 0.16)
GHOST = (0.15, 0.3, 0.75)


# ---------------------------------------------------------------------------------------- facts
def settle_time(times: np.ndarray, amp: np.ndarray, peak: int, fraction: float = SETTLE_FRACTION,
                window: float = SETTLE_WINDOW) -> float | None:
    """Seconds from frame `peak` until `amp` (T,) stays below fraction * amp[peak] for `window`
    seconds (or to the end of the clip); None when it never does (a jiggle kept going by the motion)."""
    thr = fraction * amp[peak]
    below = amp < thr
    for i in range(peak + 1, len(times)):
        if below[i]:
            e = int(np.searchsorted(times, times[i] + window, side="right"))
            if below[i:e].all():
                return float(times[i] - times[peak])
    return None


def _curve(c) -> list:
    return [[round(float(t), 6), round(float(v), 6)] for t, v in zip(c.times, c.values)]


def shown_amplitude(result: JiggleResult) -> np.ndarray:
    """(T, M) metres: each muscle's largest CV distance between the blended CVs (what the skin gets) and
    the static ones, blend x amplitude (cvs = static + b (dynamic - static))."""
    return result.blend * result.amplitude()


def jiggle_facts(result: JiggleResult) -> dict:
    """JSON-ready facts of a simulation: per muscle its amplitude figures and parameters, and the settings."""
    amp = result.amplitude()
    shown = shown_amplitude(result)
    t = result.times
    muscles = {}
    for m, name in enumerate(result.names):
        a = amp[:, m]
        k = int(np.argmax(a)) if len(a) else 0
        mj = result.jiggles[m]
        settle = settle_time(t, a, k) if a[k] > SETTLED else 0.0
        muscles[name] = {
            "peak_mm": round(float(a[k]) * 1e3, 3), "peak_time_s": round(float(t[k]), 4),
            "end_mm": round(float(a[-1]) * 1e3, 3),
            "settle_s": None if settle is None else round(settle, 4),
            "blended_peak_mm": round(float(shown[:, m].max(initial=0.0)) * 1e3, 3),
            "frequency_hz": jsonable_value(mj.frequency_hz), "damping_ratio": jsonable_value(mj.damping_ratio),
            "strength": jsonable_value(mj.strength), "goal_scale": jsonable_value(mj.goal_scale),
            "density_kg_m3": mj.density, "goal_min": float(mj.goal.min()), "goal_max": float(mj.goal.max()),
            "blend": None if mj.blend is None else _curve(mj.blend),
        }
    s = result.settings
    return {
        "frames": int(len(t)), "start_s": float(t[0]), "end_s": float(t[-1]),
        "fps": round(float(1.0 / np.min(np.diff(t))), 6) if len(t) > 1 else None,
        "particles": int(result.cv_offsets[-1]), "cuts_s": [round(float(c), 4) for c in result.cuts],
        "amplitude": "largest CV distance dynamic - static (blended: blend x that, what the skin gets)",
        "settle_rule": f"amplitude below {SETTLE_FRACTION:g} x its peak for {SETTLE_WINDOW:g} s (or to the end); "
                       "null: never",
        "settings": {"substeps": s.substeps, "goal_rate_hz": s.goal_rate, "gravity": s.gravity,
                     "preroll_s": s.preroll, "strength": jsonable_value(s.strength), "blend": _curve(s.blend),
                     "cut_ratio": s.cut_ratio, "cut_jump_m": s.cut_jump, "device": s.device},
        "muscles": muscles,
    }


def top_muscles(result: JiggleResult, n: int, blended: bool = True) -> list[int]:
    """Indices of the n muscles with the largest peak amplitude (blended: as the skin gets it), largest first."""
    dyn = result.amplitude().max(axis=0, initial=0.0)
    if not blended:
        return [int(i) for i in np.argsort(-dyn, kind="stable")[:n]]
    shown = shown_amplitude(result).max(axis=0, initial=0.0)
    return [int(i) for i in np.lexsort((-dyn, -shown))[:n]]      # blended peak first, then the dynamic one


# ---------------------------------------------------------------------------------------- plot
def plot_amplitude(result: JiggleResult, path: str, top: int = 8, title: str = "") -> str:
    """amplitude.png: the `top` muscles' amplitude (mm) over time (dashed: blended out, never reaching the
    skin), cuts as grey lines, and below it their blend curves when any of them is keyed. Written atomically."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    amp = 1e3 * result.amplitude()
    idx = top_muscles(result, top)
    keyed = result.blend.size and np.ptp(result.blend[:, idx], axis=0).max(initial=0.0) > 0
    fig, axes = plt.subplots(2 if keyed else 1, 1, figsize=(9, 5.5 if keyed else 4), sharex=True, squeeze=False,
                             gridspec_kw={"height_ratios": [3, 1]} if keyed else None)
    ax = axes[0, 0]
    for m in idx:
        out = not result.blend[:, m].any()
        ax.plot(result.times, amp[:, m], lw=1.0 if out else 1.4, ls="--" if out else "-",
                label=result.names[m] + (" (blend 0)" if out else ""))
    for c in result.cuts:
        ax.axvline(c, color="0.5", ls=":", lw=0.8)
    ax.set_ylabel("jiggle amplitude (mm)\nmax |dynamic - static| CV")
    ax.grid(alpha=0.3)
    ax.legend(loc="upper right", fontsize=8, ncol=2 if len(idx) > 4 else 1)
    if keyed:
        b = axes[1, 0]
        for m in idx:
            b.plot(result.times, result.blend[:, m], lw=1.2)
        b.set_ylabel("blend")
        b.set_ylim(-0.05, 1.05)
        b.grid(alpha=0.3)
    axes[-1, 0].set_xlabel("time (s)")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=100)
    plt.close(fig)
    return path


# ---------------------------------------------------------------------------------------- camera
def side_direction(world: np.ndarray, bind_world: np.ndarray) -> np.ndarray:
    """(3,) unit horizontal direction toward the camera: the root's +X at bind (the figure's left side,
    as mesh_render.VIEWS["side"]) turned with the root over the clip, averaged."""
    rel = world[:, 0, :3, :3] @ bind_world[0, :3, :3].T                 # (T, 3, 3) root turn since bind
    d = rel[:, :, 0].mean(axis=0)
    d[2] = 0.0
    n = np.linalg.norm(d)
    return d / n if n > 1e-6 else np.array([1.0, 0.0, 0.0])


def focus_boxes(points: np.ndarray, pad: float = 0.35, least: float = 0.0) -> np.ndarray:
    """(T, 2, 3) per-frame boxes (lo, hi) framing `points` (T, P, 3) with `pad` (a fraction of their
    size) around them and at least `least` metres across: one fixed box over all frames when the points
    stay in place (their centre travels less than their size), else a box of fixed size following
    their centre."""
    centre = points.mean(axis=1)                                          # (T, 3)
    half = np.abs(points - centre[:, None]).max(axis=(0, 1))              # (3,) largest half-extent
    lo, hi = points.min(axis=(0, 1)), points.max(axis=(0, 1))
    travel = float(np.linalg.norm(np.ptp(centre, axis=0)))
    if travel <= 2.0 * float(half.max()):
        c, h = 0.5 * (lo + hi), np.maximum(0.5 * (hi - lo) * (1.0 + pad), 0.5 * least)
        return np.broadcast_to(np.stack([c - h, c + h]), (len(points), 2, 3)).copy()
    h = np.maximum(half * (1.0 + pad), 0.5 * least)
    return np.stack([centre - h, centre + h], axis=1)


# ---------------------------------------------------------------------------------------- frames
def _poly(points, faces):
    import pyvista as pv
    f = np.asarray(faces, np.int64)
    return pv.PolyData(np.asarray(points, np.float64), np.hstack([np.full((len(f), 1), 3), f]).ravel())


class FrameRenderer:
    """One off-screen plotter, two panels, drawn again for each frame (meshes updated in place, so a
    frame costs a render and a screenshot, not a new window).

    faces : (F, 3) skin triangles. muscle_faces : (Fm, 3) triangles of all muscles' surfaces merged.
    direction : (3,) toward the camera. clim : (lo, hi) mm of the heat map.
    """

    def __init__(self, faces: np.ndarray, vertices: int, muscle_faces: np.ndarray, muscle_points: int, *,
                 direction: np.ndarray, clim: tuple[float, float], panel: tuple[int, int] = PANEL):
        import pyvista as pv
        self.direction = np.asarray(direction, float)
        self.panel = panel
        z = np.zeros((vertices, 3))
        zm = np.zeros((muscle_points, 3))
        self.static_skin, self.dyn_skin = _poly(z, faces), _poly(z, faces)
        self.dyn_skin.point_data["mm"] = np.zeros(vertices)
        self.static_mus, self.dyn_mus, self.ghost = _poly(zm, muscle_faces), _poly(zm, muscle_faces), _poly(zm, muscle_faces)
        pl = pv.Plotter(off_screen=True, shape=(1, 2), window_size=[2 * panel[0], panel[1]], border=False)
        pl.subplot(0, 0)
        pl.set_background("white")
        pl.add_mesh(self.static_mus, color=MUSCLE, smooth_shading=True)
        pl.add_mesh(self.static_skin, color=SKIN, opacity=0.35, smooth_shading=True)
        pl.subplot(0, 1)
        pl.set_background("white")
        pl.add_mesh(self.dyn_mus, color=MUSCLE, smooth_shading=True)
        pl.add_mesh(self.ghost, color=GHOST, style="wireframe", line_width=1, opacity=0.6)
        pl.add_mesh(self.dyn_skin, scalars="mm", cmap="YlOrRd", clim=clim, opacity=0.55, smooth_shading=True,
                    scalar_bar_args={"title": "skin moved (mm)", "color": "black", "title_font_size": 11,
                                     "label_font_size": 10, "vertical": True, "position_x": 0.86,
                                     "position_y": 0.1, "height": 0.8, "width": 0.06})
        # corner annotations made once and re-texted per frame: adding an actor to a shown plotter renders it
        self.labels = []
        for i in range(2):
            pl.subplot(0, i)
            self.labels.append(pl.add_text(" ", position="lower_left", font_size=9, color="black"))
        pl.subplot(0, 0)
        self.title = pl.add_text(" ", position="upper_left", font_size=9, color="black")
        self.pl = pl

    def draw(self, path: str, static_skin, dyn_skin, static_mus, dyn_mus, box: np.ndarray,
             left: str, right: str, title: str = "") -> str:
        """Write one frame: skins (V, 3), merged muscle points (P, 3) static and dynamic, box (2, 3)."""
        self.static_skin.points = np.asarray(static_skin, np.float64)
        self.dyn_skin.points = np.asarray(dyn_skin, np.float64)
        self.dyn_skin.point_data["mm"] = 1e3 * np.linalg.norm(np.asarray(dyn_skin, np.float64) - static_skin, axis=1)
        self.static_mus.points = np.asarray(static_mus, np.float64)
        self.ghost.points = np.asarray(static_mus, np.float64)
        self.dyn_mus.points = np.asarray(dyn_mus, np.float64)
        corners = np.asarray(box, float)
        for i, text in enumerate((left, right)):
            self.pl.subplot(0, i)
            frame_camera(self.pl, corners, self.direction, np.array([0.0, 0.0, 1.0]), self.panel[0] / self.panel[1])
            self.labels[i].SetText(0, text)           # corner 0: lower left
        self.title.SetText(2, title)                  # corner 2: upper left
        self.pl.render()                              # the screenshot alone would reuse the last image
        with atomic_path(path) as tmp:
            self.pl.screenshot(tmp)
        return path

    def close(self) -> None:
        self.pl.close()


# ---------------------------------------------------------------------------------------- all
def write_jiggle_outputs(result: JiggleResult, skin, world: np.ndarray, out_dir: str, *, every: int = 1,
                         render: bool = True, source: dict | None = None, focus: Sequence[str] | None = None,
                         title: str = "", top: int = 8) -> dict:
    """Write jiggle.json, amplitude.png and (unless render is False) frames/frame_NNNN.png into out_dir.

    result : the simulation. skin : rig.skin.muscle_skin.MuscleSkin of the same rig (None: no skin figures,
        no frames). world : (T, J, 4, 4) joint world transforms at result.times.
    every : render every K-th output frame (the first and, when it falls on the step, the last).
    focus : muscles the camera frames and draws (default: those whose blended peak is at least half the
        largest).
    Returns {"facts": ..., "files": {kind: path}, "timings": {stage: seconds}}.
    """
    if every < 1:
        raise InputError(f"expected a whole number >= 1, got {every}", field="every")
    world = np.asarray(world, np.float64)
    T = len(result.times)
    if world.shape[0] != T:
        raise InputError(f"expected {T} world transforms (one per output frame), got {world.shape[0]}", field="world")
    os.makedirs(out_dir, exist_ok=True)
    facts = {"source": source or {}, **jiggle_facts(result)}
    files, timings = {}, {}
    names = list(result.names)
    if focus:
        unknown = [f for f in focus if f not in names]
        if unknown:
            raise InputError(f"no muscle {', '.join(map(repr, unknown))}; the muscles are {', '.join(names)}",
                             field="focus")
        focus_idx = [names.index(f) for f in focus]
    else:
        peak = shown_amplitude(result).max(axis=0)
        focus_idx = [int(i) for i in np.nonzero(peak >= 0.5 * peak.max(initial=0.0))[0]] or [0]
    facts["focus"] = [names[i] for i in focus_idx]

    t0 = time.perf_counter()
    files["plot"] = plot_amplitude(result, os.path.join(out_dir, "amplitude.png"), top=top, title=title)
    timings["plot_s"] = time.perf_counter() - t0

    frames = list(range(0, T, every))
    if skin is not None and render and T:
        t0 = time.perf_counter()
        sel = np.asarray(frames)
        static_skin, dyn_skin = skin_frames(skin, world[sel], (result.static[sel], result.cvs[sel]),
                                            result.curve[sel], sel)
        move = 1e3 * np.linalg.norm(dyn_skin.astype(np.float64) - static_skin, axis=2)       # (F, V) mm
        kk = int(np.argmax(move.max(axis=1)))
        facts["skin"] = {"vertices": int(move.shape[1]), "peak_move_mm": round(float(move.max()), 3),
                         "peak_time_s": round(float(result.times[frames[kk]]), 4),
                         "over": "rendered frames"}
        timings["skin_s"] = time.perf_counter() - t0

        t0 = time.perf_counter()
        rig = skin.rig
        sm = rig.surface(result.static[sel])[:, focus_idx]                  # (F, m, P, 3)
        dm = rig.surface(result.cvs[sel])[:, focus_idx]
        P = sm.shape[2]
        mf = np.concatenate([rig.surface_faces + i * P for i in range(len(focus_idx))])
        sm, dm = sm.reshape(len(sel), -1, 3), dm.reshape(len(sel), -1, 3)
        # the camera keeps the static and the jiggled focus muscles in view, with a quarter of the
        # character's height across at least (a belly alone is too small to read)
        both = np.concatenate([result.static[sel], result.cvs[sel]], axis=1).reshape(len(sel), 2, rig.M, -1, 3)
        boxes = focus_boxes(both[:, :, focus_idx].reshape(len(sel), -1, 3), least=skin.character.height / 4.0)
        direction = side_direction(world, skin.character.bind_world)
        amp = 1e3 * result.amplitude()
        renderer = FrameRenderer(skin.character.faces, skin.character.num_vertices, mf, sm.shape[1],
                                 direction=direction, clim=(0.0, max(float(move.max()), 1.0)))
        written = []
        fdir = os.path.join(out_dir, "frames")
        os.makedirs(fdir, exist_ok=True)
        try:
            for i, k in enumerate(frames):
                tt = float(result.times[k])
                f0 = focus_idx[0]
                left = f"static   t = {tt:.3f} s"
                right = (f"dynamic (blend {result.blend[k, f0]:.2f})   {names[f0]} {amp[k, f0]:.1f} mm, "
                         f"skin {move[i].max():.1f} mm")
                path = os.path.join(fdir, f"frame_{k:04d}.png")
                renderer.draw(path, static_skin[i], dyn_skin[i], sm[i], dm[i], boxes[i], left, right,
                              title=f"{title}  frame {k}")
                written.append(os.path.relpath(path, out_dir))
        finally:
            renderer.close()
        # frames of an earlier run into the same folder would read as part of this one
        keep = {os.path.basename(w) for w in written}
        for name in os.listdir(fdir):
            if re.fullmatch(r"frame_\d{4,}\.png", name) and name not in keep:
                os.remove(os.path.join(fdir, name))
        timings["render_s"] = time.perf_counter() - t0
        files["frames"] = fdir
        facts["frames_written"] = {"every": every, "count": len(written), "panel_px": list(PANEL),
                                   "files": written}
    else:
        facts["frames_written"] = {"every": every, "count": 0, "files": []}
    facts["timings_s"] = {k: round(v, 3) for k, v in timings.items()}
    js = os.path.join(out_dir, "jiggle.json")
    with atomic_path(js) as tmp, open(tmp, "w") as fh:
        json.dump(facts, fh, indent=2)
    files["facts"] = js
    return {"facts": facts, "files": files, "timings": timings}
