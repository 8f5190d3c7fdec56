"""The viewer's web page: a viser server (scene, GUI panel, websocket) showing a Playback, and tuning it.

Why viser: its GUI is two-way (sliders, buttons and dropdowns call back into this process, which holds the
rebuilt setup and re-simulates), its scene takes NumPy meshes whose vertices are replaced in place each
frame, and its HTTP server serves only its own client build (URL segments ".." refused), never a file of
the bake: the frames travel over the websocket. rerun-sdk's viewer plays logged time series beautifully but
sends nothing back, so it could not drive a re-simulation.

Layout. Scene (world Z-up, metres): the skin (final, static, side by side or overlaid; or the final skin in
heat-map colour bands), the muscles as their loft meshes (click one to select it), the skeleton, the selected
muscle's skin region as a wireframe, a floor grid. Panel: Playback (play/pause, frame slider, loop, speed,
frame and time), Show (skin, heat map and its scale, muscles, skeleton, skin opacity), Muscles (one button
per muscle with its peak jiggle amplitude, the selected one's numbers), Skin quality (the frame's numbers from
metrics.json), Tune (per-muscle strength, frequency, damping ratio, goal weight scale, the global blend; per
chain (tails, ears, hair, wing fingers: sim/chain) its stiffness, damping ratio, gravity and air drag; reset, save
scene).

Playback runs in a thread that advances the frame slider at the bake's fps times the speed; the slider's
callback draws the frame (so a scrub and a tick draw the same way). A slider of the Tune panel records the
value and wakes the re-simulation thread, which runs the latest tuning (moves made while it ran collapse into
one run) and swaps the motion in.

Threads. viser calls a GUI callback in a pool of threads, several at once and in any order, each reading
its slider when it runs. So every edit of the tuning (a knob, the blend, reset, the sliders synced to a
muscle) is one step under one lock (`_wanted`): it reads the slider then, builds on the latest tuning, and
hands the tuning and its number (`generation`, +1 per request that changes a value) to the re-simulation
thread in the same step; a request that changes nothing is no request. The chain sliders are knobs like the
muscles' (`_chain_knob_moved`: the same lock, the same requests). The motion on the page is tagged
with the request it answers (`shown`: ShownMotion, generation, tuning and the arrays drawn); a run's result
is shown when it is done (a slider dragged meanwhile shows each step it reached) and never replaces a newer
one. "save scene" waits until no run is pending, then writes the tuning of the motion shown: the scene
bakes to exactly the frames on the page (`wait_tuned` is the same wait for a caller).
"""
from __future__ import annotations

import contextlib
import html
import io
import os
import threading
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from jiggle.sim.app.view.playback import HEAT_BANDS, Playback, band_colours, compact, heat_bands, skin_regions
from jiggle.sim.app.view.tuning import NotTunable, Tuning

SKIN_COLOUR = (222, 184, 160)
STATIC_COLOUR = (150, 170, 200)
MUSCLE_COLOUR = {"muscle": (190, 70, 60), "fat": (235, 195, 90)}
RELAXED_COLOUR, WORKING_COLOUR = (70, 90, 150), (255, 60, 30)
"""Muscles coloured by activation (--activation on bakes): relaxed blue-grey to working red, in ACTIVATION_LEVELS
steps (a colour is sent to the browser only when a muscle's step changes)."""
ACTIVATION_LEVELS = 10
SELECTED_COLOUR = (40, 200, 255)
BONE_COLOUR = (235, 235, 245)
SKIN_MODES = ("dynamic", "static", "side by side", "overlaid")
MAP_BANDS, MAP_CMAP = 10, "viridis"
"""The painted jiggle map in 10 bands of viridis over [0, 1] (fit.png's map panel uses viridis too)."""
SPEEDS = ("0.25", "0.5", "1", "2")
FREQUENCY_RANGE = (0.5, 20.0)
"""Hz: the frequency slider's range."""
DAMPING_RANGE = (0.0, 2.0)
GOAL_SCALE_RANGE = (0.0, 2.0)
CHAIN_SLIDERS = {"stiffness": ("chain stiffness (Hz)", 0.5, 60.0, 0.1),
                 "damping": ("chain damping ratio", 0.0, 2.0, 0.01),
                 "gravity": ("chain gravity (x g)", 0.0, 3.0, 0.05), "drag": ("chain air drag (x air)", 0.0, 50.0, 0.5)}
"""Per chain knob (view.tuning.CHAIN_KNOBS): the slider's label, range and step (sim.chain.params.CHAIN_PARAMETERS
allows more; `jiggle bake --chain-KNOB` or the scene sets any value in it)."""
SAVE_WAIT_S = 300.0
"""seconds "save scene" waits for a pending re-simulation before it gives up (and says so)."""
CAMERA_FOV = np.radians(40.0)
"""The first view: 40 degrees vertically, from the front (figures face -Y), a little from the right and above."""


def twin(name: str, names) -> str | None:
    """The other side's muscle of a left_/right_ (l_/r_) pair, None when there is none."""
    for a, b in (("left_", "right_"), ("right_", "left_"), ("l_", "r_"), ("r_", "l_")):
        if name.startswith(a) and b + name[len(a):] in names:
            return b + name[len(a):]
    return None


def chain_twin(name: str, names) -> str | None:
    """The other side's chain of a left/right pair (Ear1.L / Ear1.R, Wing_l / Wing_r, LeftEar / RightEar, left_ /
    right_), None when there is none."""
    for a, b in ((".L", ".R"), (".R", ".L"), (".l", ".r"), (".r", ".l"), ("_L", "_R"), ("_R", "_L"), ("_l", "_r"),
                 ("_r", "_l")):
        if name.endswith(a) and name[:-len(a)] + b in names:
            return name[:-len(a)] + b
    for a, b in (("Left", "Right"), ("Right", "Left"), ("left", "right"), ("right", "left")):
        if name.startswith(a) and b + name[len(a):] in names:
            return b + name[len(a):]
    return twin(name, names)


@dataclass(frozen=True, eq=False)
class ShownMotion:
    """The motion on the page and what made it.

    generation : the request it answers (0: the bake's own motion; ViewerPage.generation numbers the
        requests). tuning : the view.tuning.Tuning it was simulated with.
    cvs_dynamic : (T, N, 3) float32 metres, the blended CVs; skin_final : (T, V, 3) float32 metres: the arrays
        the page draws (Playback's), never written once shown.
    """

    generation: int
    tuning: Tuning
    cvs_dynamic: np.ndarray
    skin_final: np.ndarray


class ViewerPage:
    """The page of one bake (see the module).

    playback : the bake's frames. out_dir : its folder (where "save scene" writes by default).
    host, port : where to serve (port 0: any free one). paused : start paused at frame 0.
    tuner_factory : () -> view.tuning.Tuner, run in a background thread (NotTunable: the Tune panel says
        why); None: no tuning. log : progress lines.
    """

    def __init__(self, playback: Playback, out_dir: str, host: str = "127.0.0.1", port: int = 8080,
                 paused: bool = False, tuner_factory: Callable | None = None,
                 log: Callable[[str], None] = lambda s: None, formats=("npz", "usdc")):
        import viser
        self.pb, self.out_dir, self.log, self.formats = playback, os.path.abspath(out_dir), log, tuple(formats)
        with contextlib.redirect_stdout(io.StringIO()):      # viser's own address box: the command prints one
            self.server = viser.ViserServer(host=host, port=port, verbose=False)
        self.tuner = None
        self.tuning = Tuning()
        """The latest Tuning asked for (the sliders'); request number `generation`."""
        self.generation = 0
        """Numbers the requests: 0 the bake's values, +1 per request that changes a value."""
        self.shown = ShownMotion(0, self.tuning, playback.cvs_dynamic, playback.skin_final)
        """The motion on the page, with the request and Tuning it came from."""
        self.saved_motion: ShownMotion | None = None
        """The motion whose values "save scene" wrote last (with `saved`: the path and extra bake arguments)."""
        self.regions = None
        self.base: dict = {}
        """muscle name -> its MuscleJiggle in the bake, once the setup is rebuilt."""
        self.chain_base: dict = {}
        """chain name -> its sim.chain.params.ChainParams in the bake, once the setup is rebuilt."""
        self.selected: int | None = None
        self.motion_version = 0
        """Counts the motions shown: 0 the bake's, +1 per re-simulation swapped in."""
        self.last_run_s: float | None = None
        self.tune_error: str | None = None
        self._draw_lock = threading.RLock()
        self._syncing = False
        self._stop = threading.Event()
        self._tuner_done = threading.Event()
        # the tuning, its generation, the request pending and the run's state change together under this lock
        # (re-entrant: syncing the sliders calls their callbacks in the same thread); never take _draw_lock
        # while holding it (the drawing side takes _draw_lock, then this)
        self._wanted = threading.Condition(threading.RLock())
        self._pending: tuple[int, Tuning] | None = None
        self._busy = False
        self._band_handles: list = []
        self._map_handles: list = []
        self.jiggle_map: np.ndarray | None = None
        """(V,) the character's painted jiggle map (rig.character.painted_maps), once the setup is rebuilt."""
        self._region_handle = None
        self._colours = band_colours(HEAT_BANDS)
        self._map_colours = band_colours(MAP_BANDS, MAP_CMAP)
        self._build_scene()
        self._build_gui(paused)
        self.draw(0)
        self._threads = [threading.Thread(target=self._play_loop, name="jiggle-view-play", daemon=True)]
        if tuner_factory is not None:
            self._threads.append(threading.Thread(target=self._tune_loop, args=(tuner_factory,),
                                                  name="jiggle-view-tune", daemon=True))
        else:
            self.tune_error = "tuning is off (--no-tune)"
            self._set_tune_status(self.tune_error)
            self._tuner_done.set()
        for t in self._threads:
            t.start()

    # ------------------------------------------------------------------ address and lifetime
    @property
    def url(self) -> str:
        host = self.server.get_host()
        return f"http://{'127.0.0.1' if host in ('0.0.0.0', '') else host}:{self.server.get_port()}/"

    def stop(self) -> None:
        self._stop.set()
        with self._wanted:
            self._wanted.notify_all()
        self.server.stop()

    def wait_tuner(self, timeout: float = 120.0) -> bool:
        """Block until the setup is rebuilt and the Tune panel is ready, its sliders showing the bake's values
        (True), or known not to be (False)."""
        self._tuner_done.wait(timeout)
        return self._tuner_done.is_set() and self.tuner is not None

    @property
    def shown_tuning(self) -> Tuning:
        """The Tuning of the motion shown (`tuning` is the latest asked for)."""
        return self.shown.tuning

    def _idle(self) -> bool:
        """No run pending or running (the caller holds _wanted)."""
        return not self._busy and self._pending is None

    def wait_tuned(self, timeout: float = 60.0) -> bool:
        """Block until no run is pending; True when the motion shown is then the one of the latest tuning asked
        for (its generation), False when those values could not re-simulate (the panel says why) or after
        `timeout` seconds."""
        with self._wanted:
            self._wanted.wait_for(lambda: self._idle() or self._stop.is_set(), timeout)
            return self._idle() and self.shown.generation == self.generation

    def wait_motion(self, version: int, timeout: float = 60.0) -> bool:
        """Block until a motion newer than `version` (motion_version) is shown and no run is pending."""
        with self._wanted:
            return self._wanted.wait_for(lambda: self.motion_version > version and self._idle(), timeout)

    # ------------------------------------------------------------------ scene
    def _build_scene(self) -> None:
        pb, sc = self.pb, self.server.scene
        sc.set_up_direction("+z")
        s0 = pb.data.skin_static[0]
        lo, hi = pb.data.skin_static.min(axis=(0, 1)), pb.data.skin_static.max(axis=(0, 1))
        self.centre = 0.5 * (lo + hi)
        self.size = float(max(hi - lo))
        self.side_offset = np.array([-1.15 * float(hi[0] - lo[0]) - 0.1 * self.size, 0.0, 0.0])
        sc.add_grid("/floor", width=3 * self.size, height=3 * self.size, plane="xy",
                    position=(float(self.centre[0]), float(self.centre[1]), float(lo[2])),
                    cell_size=0.25 * self.size / 2, section_size=self.size / 2)
        faces = pb.faces.astype(np.uint32)
        self.h_dynamic = sc.add_mesh_simple("/skin/dynamic", pb.skin(0, "final"), faces, color=SKIN_COLOUR,
                                            side="double")
        self.h_static = sc.add_mesh_simple("/skin/static", s0, faces, color=STATIC_COLOUR, side="double",
                                           visible=False)
        self.h_label_static = sc.add_label("/labels/static", "static", visible=False,
                                           position=tuple(float(x) for x in (self.centre + self.side_offset
                                                                              + [0, 0, 0.55 * (hi[2] - lo[2])])))
        self.h_label_dynamic = sc.add_label("/labels/dynamic", "dynamic", visible=False,
                                            position=tuple(float(x) for x in (self.centre
                                                                               + [0, 0, 0.55 * (hi[2] - lo[2])])))
        surf = pb.muscle_surfaces(0)
        mfaces = np.asarray(pb.data.muscle_faces, np.uint32)
        self.h_muscles = []
        self._muscle_colour = [MUSCLE_COLOUR.get(i.kind, MUSCLE_COLOUR["muscle"]) for i in pb.muscles]
        """The colour last sent for each muscle's mesh (the selection's aside)."""
        for m, info in enumerate(pb.muscles):
            h = sc.add_mesh_simple(f"/muscles/{info.name}", surf[m], mfaces,
                                   color=MUSCLE_COLOUR.get(info.kind, MUSCLE_COLOUR["muscle"]), visible=False)
            h.on_click(lambda event, m=m: self.select(m))
            self.h_muscles.append(h)
        self.bones = None
        """(B, 2) joint index pairs of the skeleton's bones, once the tuner thread knows the parents (from the
        rebuilt character, when its joints are the bake's); joints alone until then."""
        self.h_skeleton = self.h_joints = None
        cam = self.server.initial_camera
        height = float(hi[2] - lo[2])
        cam.look_at = tuple(float(x) for x in self.centre)
        cam.position = tuple(float(x) for x in self.centre + np.array([0.5 * height, -2.4 * height, 0.4 * height]))
        cam.up = (0.0, 0.0, 1.0)
        cam.fov = CAMERA_FOV

    # ------------------------------------------------------------------ GUI
    def _build_gui(self, paused: bool) -> None:
        gui, pb = self.server.gui, self.pb
        gui.configure_theme(control_width="large", dark_mode=True, show_logo=False)
        gui.add_markdown(f"**jiggle view** · {html.escape(pb.name)} · {pb.T} frames at {pb.data.fps:g} fps, "
                         f"{pb.V} vertices, {len(pb.muscles)} muscles")
        with gui.add_folder("Playback"):
            self.g_play = gui.add_button("Play" if paused else "Pause")
            self.g_frame = gui.add_slider("frame", min=0, max=max(pb.T - 1, 1), step=1, initial_value=0)
            self.g_loop = gui.add_checkbox("loop", initial_value=True)
            self.g_speed = gui.add_dropdown("speed", SPEEDS, initial_value="1")
            self.g_time = gui.add_markdown("")
        self.playing = not paused
        self.g_play.on_click(lambda _: self.set_playing(not self.playing))
        self.g_frame.on_update(lambda _: self.draw(int(self.g_frame.value)))

        with gui.add_folder("Show"):
            self.g_mode = gui.add_dropdown("skin", SKIN_MODES, initial_value="dynamic")
            self.g_heat = gui.add_checkbox("heat map", initial_value=False)
            self.g_heat_bar = gui.add_html(self._heat_bar_html(), visible=False)
            self.g_map = gui.add_checkbox("painted jiggle map", initial_value=False, disabled=True)
            self.g_map_note = gui.add_markdown("*the character's painted maps are known once the setup is rebuilt*")
            self.g_muscles = gui.add_checkbox("muscles", initial_value=False)
            has = pb.data.activation is not None
            self.g_activation = gui.add_checkbox(
                "colour muscles by activation", initial_value=False, disabled=not has,
                hint="blue: relaxed; red: working hard (a bake made with --activation on)" if has else
                "this bake has no activation: bake it with --activation on")
            self.g_skeleton = gui.add_checkbox("skeleton", initial_value=False)
            self.g_opacity = gui.add_slider("skin opacity", min=0.1, max=1.0, step=0.05, initial_value=1.0)
        for h in (self.g_mode, self.g_heat, self.g_map, self.g_skeleton, self.g_opacity):
            h.on_update(lambda _: self.redraw())
        self.g_muscles.on_update(self._muscles_toggled)
        self.g_activation.on_update(self._activation_toggled)

        with gui.add_folder("Skin quality"):
            self.g_quality = gui.add_markdown("")

        with gui.add_folder("Tune"):
            self.g_tune_status = gui.add_markdown("rebuilding the setup from bake.json ...")
            names = [m.name for m in pb.muscles]
            self.g_t_muscle = gui.add_dropdown("muscle", names, initial_value=names[0] if names else "")
            self.g_t_both = gui.add_checkbox("both sides", initial_value=True)
            self.g_t_strength = gui.add_slider("strength", min=0.0, max=1.0, step=0.01, initial_value=1.0)
            self.g_t_frequency = gui.add_slider("frequency (Hz)", min=FREQUENCY_RANGE[0], max=FREQUENCY_RANGE[1],
                                                step=0.1, initial_value=5.0)
            self.g_t_damping = gui.add_slider("damping ratio", min=DAMPING_RANGE[0], max=DAMPING_RANGE[1],
                                              step=0.01, initial_value=0.3)
            self.g_t_goal = gui.add_slider("goal weight scale", min=GOAL_SCALE_RANGE[0], max=GOAL_SCALE_RANGE[1],
                                           step=0.01, initial_value=1.0)
            self.g_t_blend = gui.add_slider("blend (all muscles)", min=0.0, max=1.0, step=0.01, initial_value=1.0)
            chains = self._bake_chains()
            with gui.add_folder("Chains (swing)"):
                self.g_c_chain = gui.add_dropdown("chain", chains or ("(none)",),
                                                  initial_value=chains[0] if chains else "(none)")
                self.g_c_knobs = {k: gui.add_slider(label, min=lo, max=hi, step=step, initial_value=lo)
                                  for k, (label, lo, hi, step) in CHAIN_SLIDERS.items()}
                self.g_c_note = gui.add_markdown("" if chains else "*no chain swings in this bake*")
            self.g_t_reset = gui.add_button("reset to the bake")
            self.g_t_path = gui.add_text("scene file", initial_value=os.path.join(self.out_dir, "tuned.toml"))
            self.g_t_save = gui.add_button("save scene")
            self.g_t_result = gui.add_markdown("")
        with gui.add_folder("Muscles (peak jiggle)"):
            self.g_selected = gui.add_markdown("Click a muscle (here or in the view) to highlight it and its skin.")
            order = np.argsort(-pb.original_peak_mm, kind="stable")
            self.g_muscle_buttons = {}
            for m in order:
                b = gui.add_button(self._muscle_label(int(m)))
                b.on_click(lambda _, m=int(m): self.select(m))
                self.g_muscle_buttons[int(m)] = b
            self.g_clear = gui.add_button("clear selection")
            self.g_clear.on_click(lambda _: self.select(None))

        self._tune_controls = (self.g_t_muscle, self.g_t_both, self.g_t_strength, self.g_t_frequency,
                               self.g_t_damping, self.g_t_goal, self.g_t_blend, self.g_t_reset, self.g_t_save,
                               self.g_t_path)
        for h in (*self._tune_controls, self.g_c_chain, *self.g_c_knobs.values()):
            h.disabled = True
        self.g_t_muscle.on_update(lambda _: self._sync_sliders())
        for knob, h in (("strength", self.g_t_strength), ("frequency", self.g_t_frequency),
                        ("damping", self.g_t_damping), ("goal_scale", self.g_t_goal)):
            h.on_update(lambda _, knob=knob, h=h: self._knob_moved(knob, h))
        self.g_t_blend.on_update(lambda _: self._blend_moved())
        self.g_c_chain.on_update(lambda _: self._sync_chain_sliders())
        for knob, h in self.g_c_knobs.items():
            h.on_update(lambda _, knob=knob, h=h: self._chain_knob_moved(knob, h))
        self.g_t_reset.on_click(lambda _: self._reset())
        self.g_t_save.on_click(lambda _: self._save())

    def _bake_chains(self) -> list[str]:
        """The names of the chains the bake swung (bake.json's params), [] when none (or no bake.json)."""
        params = (self.pb.summary or {}).get("params") or {}
        chains = (params.get("chains") or {}).get("chains") or []
        return [str(c["chain"]) for c in chains if isinstance(c, dict) and c.get("chain")]

    def _heat_bar_html(self) -> str:
        top = self.pb.heat_top_mm
        stops = ", ".join(f"rgb({r},{g},{b}) {100 * k / HEAT_BANDS:.1f}%, rgb({r},{g},{b}) "
                          f"{100 * (k + 1) / HEAT_BANDS:.1f}%" for k, (r, g, b) in enumerate(self._colours))
        return (f'<div style="font-size:12px;padding:0 12px">'
                f'<div style="height:12px;border:1px solid #999;background:linear-gradient(to right,{stops})"></div>'
                f'<div style="display:flex;justify-content:space-between"><span>0 mm</span>'
                f'<span>|final - static|</span><span>{top:.1f} mm</span></div></div>')

    def _muscle_label(self, m: int) -> str:
        pb = self.pb
        now, was = pb.peak_mm[m], pb.original_peak_mm[m]
        label = f"{pb.muscles[m].name} · {now:.1f} mm"
        if pb.tuned and abs(now - was) >= 0.05:
            label += f" (bake {was:.1f})"
        return label

    # ------------------------------------------------------------------ drawing
    def redraw(self) -> None:
        self.draw(int(self.g_frame.value))

    def draw(self, k: int) -> None:
        """Show frame k with the current toggles."""
        pb = self.pb
        k = int(np.clip(k, 0, pb.T - 1))
        with self._draw_lock, self.server.atomic():
            mode, heat = self.g_mode.value, bool(self.g_heat.value)
            opacity = float(self.g_opacity.value)
            show_final = mode != "static"
            final = pb.skin(k, "final")
            heat_on = heat and show_final
            map_on = bool(self.g_map.value) and self.jiggle_map is not None and show_final and not heat_on
            self.h_dynamic.visible = show_final and not heat_on and not map_on
            if show_final and not heat_on and not map_on:
                self.h_dynamic.vertices = final
                see_through = min(opacity, 0.6) if mode == "overlaid" else opacity
                self.h_dynamic.opacity = None if see_through >= 1.0 else see_through
            self._draw_heat(k, final if heat_on else None, opacity)
            self._map_handles = self._draw_bands("/skin/map", self.jiggle_map, 1.0, self._map_colours,
                                                 final if map_on else None, opacity, self._map_handles)
            show_static = mode in ("static", "side by side", "overlaid")
            self.h_static.visible = show_static
            if show_static:
                self.h_static.vertices = pb.skin(k, "static")
                self.h_static.position = tuple(float(x) for x in self.side_offset) if mode == "side by side" \
                    else (0.0, 0.0, 0.0)
                self.h_static.opacity = 0.45 if mode == "overlaid" else (None if opacity >= 1.0 else opacity)
            self.h_label_static.visible = self.h_label_dynamic.visible = mode == "side by side"
            self._draw_muscles(k, "static" if mode == "static" else "final")
            self._draw_skeleton(k)
            self._draw_region(k, "static" if mode == "static" else "final")
            self.g_heat_bar.visible = heat
            t = pb.times[k]
            self.g_time.content = f"frame **{k}** / {pb.T - 1} · t = **{t:.3f} s**" + \
                (" · *tuned motion*" if pb.tuned else "")
            self._draw_quality(k)
        self.frame_shown = k

    def _draw_heat(self, k: int, final: np.ndarray | None, opacity: float) -> None:
        self._band_handles = self._draw_bands("/skin/heat", self.pb.displacement_mm[k], self.pb.heat_top_mm,
                                              self._colours, final, opacity, self._band_handles)

    def _draw_bands(self, name: str, values: np.ndarray | None, top: float, colours: np.ndarray,
                    skin: np.ndarray | None, opacity: float, old: list) -> list:
        """The skin (V, 3) coloured by per-vertex `values` (V,) over [0, top] in len(colours) bands, as one
        mesh per band under `name`; hidden (skin None) or redrawn, replacing the handles `old`."""
        if skin is None or values is None:
            for h in old:
                if h is not None:
                    h.visible = False
            return old
        handles = []
        for b, band in enumerate(heat_bands(values, self.pb.faces, top, len(colours))):
            if band is None:
                handles.append(None)
                continue
            ids, local = band
            handles.append(self.server.scene.add_mesh_simple(
                f"{name}/band{b}", skin[ids], local, color=tuple(int(c) for c in colours[b]), side="double",
                opacity=None if opacity >= 1.0 else opacity))
        for b, h in enumerate(old):
            if h is not None and (b >= len(handles) or handles[b] is None):
                h.remove()
        return handles

    def _draw_muscles(self, k: int, which: str) -> None:
        on = bool(self.g_muscles.value)
        surf = self.pb.muscle_surfaces(k, which) if on else None
        colours = self.muscle_colours(k) if on else None
        for m, h in enumerate(self.h_muscles):
            h.visible = on
            if on:
                h.vertices = surf[m]
                if m != self.selected and self._muscle_colour[m] != colours[m]:
                    h.color = colours[m]
                    self._muscle_colour[m] = colours[m]

    def muscle_colours(self, k: int) -> list[tuple]:
        """Each muscle's colour at frame k: its kind's, or with "colour muscles by activation" its activation's
        (RELAXED_COLOUR to WORKING_COLOUR in ACTIVATION_LEVELS steps; fat, never activated, keeps its own)."""
        pb = self.pb
        act = pb.data.activation if bool(self.g_activation.value) else None
        out = []
        for m, info in enumerate(pb.muscles):
            if act is None or info.kind == "fat":
                out.append(MUSCLE_COLOUR.get(info.kind, MUSCLE_COLOUR["muscle"]))
                continue
            t = round(float(np.clip(act[k, m], 0.0, 1.0)) * ACTIVATION_LEVELS) / ACTIVATION_LEVELS
            out.append(tuple(int(round(a + t * (b - a))) for a, b in zip(RELAXED_COLOUR, WORKING_COLOUR)))
        return out

    def _activation_toggled(self, _) -> None:
        if self.g_activation.value and not self.g_muscles.value:
            self.g_muscles.value = True                      # _muscles_toggled redraws
        else:
            self.redraw()

    def _draw_skeleton(self, k: int) -> None:
        """The joints (and the bones, once known) made anew each frame: the browser lost other nodes made in the
        same batch as an update of a point cloud's points (seen: the heat map's first bands), never a node
        made anew."""
        sc = self.server.scene
        if not self.g_skeleton.value:
            for h in (self.h_joints, self.h_skeleton):
                if h is not None:
                    h.remove()
            self.h_joints = self.h_skeleton = None
            return
        j = self.pb.joints(k).astype(np.float32)
        self.h_joints = sc.add_point_cloud("/skeleton/joints", j, colors=np.array(BONE_COLOUR, np.uint8),
                                           point_size=0.012 * self.size, point_shape="circle")
        if self.bones is not None and len(self.bones):
            self.h_skeleton = sc.add_line_segments("/skeleton/bones", j[self.bones], colors=BONE_COLOUR,
                                                   thickness=4.0, thickness_units="screen")

    def _draw_region(self, k: int, which: str) -> None:
        if self._region_handle is not None:
            self._region_handle.vertices = self.pb.skin(k, which)[self._region_faces[0]]

    def _draw_quality(self, k: int) -> None:
        rows = self.pb.quality_rows(k)
        if rows is None:
            self.g_quality.content = "no skin-quality numbers (run `jiggle compare` on the bake)"
        else:
            note = "\n\n*(the bake's motion; the tuned one is not measured)*" if self.pb.tuned else ""
            self.g_quality.content = "| final skin, this frame | |\n|---|---:|\n" + \
                "\n".join(f"| {a} | {b} |" for a, b in rows) + note

    # ------------------------------------------------------------------ interaction
    def set_playing(self, on: bool) -> None:
        self.playing = bool(on)
        self.g_play.label = "Pause" if self.playing else "Play"

    def _play_loop(self) -> None:
        pb = self.pb
        pos, last = float(self.g_frame.value), time.perf_counter()
        while not self._stop.is_set():
            time.sleep(max(0.005, 0.5 / pb.data.fps))
            now = time.perf_counter()
            dt, last = now - last, now
            if not self.playing or pb.T < 2:
                pos = float(self.g_frame.value)
                continue
            if int(round(pos)) != int(self.g_frame.value):
                pos = float(self.g_frame.value)              # scrubbed meanwhile
            pos += dt * pb.data.fps * float(self.g_speed.value)
            if pos > pb.T - 1:
                if self.g_loop.value:
                    pos = pos % pb.T
                else:
                    pos = pb.T - 1
                    self.set_playing(False)
            k = int(pos)
            if k != int(self.g_frame.value):
                self.g_frame.value = k                       # draws (the slider's callback)

    def _muscles_toggled(self, _) -> None:
        if self.g_muscles.value and float(self.g_opacity.value) >= 1.0:
            self.g_opacity.value = 0.4                       # redraws
        else:
            self.redraw()

    def select(self, m: int | None) -> None:
        """Highlight muscle m (its mesh and its skin region), None: none."""
        pb = self.pb
        with self._draw_lock:
            if self.selected is not None:
                info = pb.muscles[self.selected]
                self.h_muscles[self.selected].color = self._muscle_colour[self.selected] = \
                    self.muscle_colours(self.frame_shown)[self.selected]
            if self._region_handle is not None:
                self._region_handle.remove()
                self._region_handle = None
            self.selected = m
            if m is None:
                self.g_selected.content = "Click a muscle (here or in the view) to highlight it and its skin."
                self.redraw()
                return
            info = pb.muscles[m]
            self.h_muscles[m].color = SELECTED_COLOUR
            region = self.regions[m] if self.regions is not None else pb.region_fallback(m)
            faces = pb.faces[region[pb.faces].all(axis=1)]
            if len(faces) == 0:
                faces = pb.faces[region[pb.faces].any(axis=1)]
            self._region_faces = compact(faces) if len(faces) else (np.zeros(0, np.int64), np.zeros((0, 3), np.uint32))
            if len(faces):
                which = "static" if self.g_mode.value == "static" else "final"
                self._region_handle = self.server.scene.add_mesh_simple(
                    "/skin/region", pb.skin(self.frame_shown, which)[self._region_faces[0]], self._region_faces[1],
                    color=SELECTED_COLOUR, wireframe=True)
            k_peak = int(np.argmax(pb.amplitude_mm[:, m])) if pb.T else 0
            self.g_selected.content = (
                f"**{info.name}** ({info.kind}): peak {pb.peak_mm[m]:.1f} mm at {pb.times[k_peak]:.2f} s"
                + (f" (bake: {pb.original_peak_mm[m]:.1f} mm)" if pb.tuned else "")
                + f"; {int(region.sum())} skin vertices in its region"
                + ("" if self.regions is not None else " (nearest-CV estimate until the setup is rebuilt)"))
            if self.tuner is not None and self.g_t_muscle.value != info.name:
                self.g_t_muscle.value = info.name            # the Tune panel follows
        self.redraw()

    def _show_maps(self, maps) -> None:
        """Offer the character's painted jiggle map (rig.character.painted_maps.PaintedMaps or None)."""
        jiggle = None if maps is None else maps.jiggle
        if jiggle is not None and len(jiggle) == self.pb.V:
            self.jiggle_map = np.asarray(jiggle, np.float64)
            self.g_map.disabled = False
            self.g_map_note.content = (f"painted jiggle map ({html.escape(maps.source or 'the character')}): "
                                       "dark 0 shows no jiggle, bright 1 all of it")
        else:
            self.g_map_note.content = ("*no painted jiggle map on this character (`jiggle fit` writes one to "
                                       "paint)*")

    # ------------------------------------------------------------------ tuning
    def _set_tune_status(self, text: str) -> None:
        self.g_tune_status.content = text

    def _tune_loop(self, factory: Callable) -> None:
        try:
            tuner = factory()
        except NotTunable as e:
            self.tune_error = str(e)
            self._set_tune_status(f"tuning is off: {html.escape(str(e))}")
            return
        except Exception as e:  # noqa: BLE001 - the page keeps playing; the panel says what failed
            self.tune_error = f"{type(e).__name__}: {e}"
            self._set_tune_status(f"tuning is off: the setup did not rebuild ({html.escape(self.tune_error)})")
            return
        finally:
            if self.tune_error is not None:
                self._tuner_done.set()
        try:
            self._open_tuning(tuner)
        except Exception as e:  # noqa: BLE001 - as above
            self.tune_error = f"{type(e).__name__}: {e}"
            self._set_tune_status(f"tuning is off: {html.escape(self.tune_error)}")
            return
        finally:
            self._tuner_done.set()
        self._run_requests(tuner)

    def _open_tuning(self, tuner) -> None:
        """The rebuilt setup's skin regions, bones and painted map on the page; the Tune panel's sliders set to the
        bake's values, then opened."""
        pb = self.pb
        self.regions = skin_regions(tuner.setup.skin, pb.V, len(pb.muscles))
        ch = tuner.setup.character
        if tuple(ch.joint_names) == tuple(pb.data.joint_names):
            parents = np.asarray(ch.parents)
            kids = np.flatnonzero(parents >= 0)
            self.bones = np.stack([parents[kids], kids], axis=1)
        self.base = {j.name: j for j in tuner.jiggles}
        chains = tuner.setup.chains
        self.chain_base = {} if chains is None else dict(zip(chains.chains.names, chains.params))
        self._show_maps(getattr(ch, "maps", None))
        with self._wanted:                                   # the sliders show the bake's values before they open
            self.tuner = tuner
            self._sync_sliders()
            for h in self._tune_controls:
                h.disabled = False
            if self.chain_base and list(self.g_c_chain.options) == list(self.chain_base):
                self.g_c_chain.disabled = False
                self._sync_chain_sliders()              # each knob open unless the bake keys it over time
            elif self.chain_base:
                self.g_c_note.content = "*the rebuilt chains are not the ones bake.json lists: not tuned here*"
        self._set_tune_status(f"ready: move a slider to re-simulate (setup rebuilt in {tuner.prepare_s:.1f} s)")
        if self.selected is not None:
            self.select(self.selected)

    def _run_requests(self, tuner) -> None:
        """The re-simulation thread: the latest request, run and shown, until the page stops."""
        while True:
            with self._wanted:
                self._wanted.wait_for(lambda: self._pending is not None or self._stop.is_set())
                if self._stop.is_set():
                    return
                (generation, tuning), self._pending = self._pending, None
                self._busy = True
            motion = None
            try:
                self._set_tune_status("re-simulating ...")
                motion = tuner.run(tuning)
                self._show_motion(generation, tuning, motion)
            except Exception as e:  # noqa: BLE001 - a value that blows up: say so, keep the last motion
                self._set_tune_status(f"could not re-simulate: {html.escape(str(e))}")
                motion = None
            finally:
                with self._wanted:                       # the waiters (wait_tuned, save scene) see it now
                    self._busy = False
                    more = self._pending is not None
                    self._wanted.notify_all()
            if motion is not None:
                self._set_tune_status(("re-simulating ..." if more else "re-simulated") +
                                      f" (last run {motion.seconds:.2f} s: particles, blend, chains, skin)")

    def _show_motion(self, generation: int, tuning: Tuning, motion) -> bool:
        """Swap in the motion (view.tuning.Motion) of request `generation` (its Tuning `tuning`), tagged with
        both, and redraw; False (nothing shown) when the page already shows a newer request's."""
        pb = self.pb
        with self._draw_lock:
            if generation <= self.shown.generation:
                return False
            pb.replace_motion(motion.cvs_dynamic, motion.skin_final)
            self.shown = ShownMotion(generation, tuning, pb.cvs_dynamic, pb.skin_final)
            self.last_run_s = motion.seconds
            self.motion_version += 1
            for m, b in self.g_muscle_buttons.items():
                b.label = self._muscle_label(m)
            if self.selected is not None:
                self.select(self.selected)
            else:
                self.redraw()
        return True

    def _request(self, tuning: Tuning) -> None:
        """Ask for `tuning` as the next generation (the caller holds _wanted); a request not yet started is
        replaced; one that changes nothing is dropped."""
        if tuning == self.tuning:
            return
        self.generation += 1
        self.tuning = tuning
        self._pending = (self.generation, tuning)
        self._wanted.notify_all()

    def _current(self, name: str, knob: str) -> float:
        j = self.base[name]
        v = self.tuning.muscles.get(name, {}).get(knob)
        if v is not None:
            return float(v)
        return {"strength": j.strength, "frequency": j.frequency_hz, "damping": j.damping_ratio,
                "goal_scale": 1.0}[knob]

    def _sync_sliders(self) -> None:
        """The Tune sliders show the chosen muscle's values (without re-simulating)."""
        with self._wanted:
            if self.tuner is None:
                return
            name = self.g_t_muscle.value
            self._syncing = True                            # their callbacks run here, in this thread: ignored
            try:
                self.g_t_strength.value = self._current(name, "strength")
                self.g_t_frequency.value = float(np.clip(self._current(name, "frequency"), *FREQUENCY_RANGE))
                self.g_t_damping.value = float(np.clip(self._current(name, "damping"), *DAMPING_RANGE))
                self.g_t_goal.value = self._current(name, "goal_scale")
                blend = self.tuning.blend
                if blend is None:
                    curve = self.tuner.setup.settings.blend
                    blend = float(curve.values[0]) if len(curve.values) == 1 else 1.0
                self.g_t_blend.value = blend
            finally:
                self._syncing = False
            self._sync_chain_sliders()

    def _chain_current(self, name: str, knob: str) -> float | None:
        """The chain's knob as the latest tuning has it (the bake's value when not tuned); None when the bake keys
        it over time (a slider sets a constant: not tuned here)."""
        from jiggle.sim.jiggle.keyed import Curve
        v = self.tuning.chains.get(name, {}).get(knob)
        if v is not None:
            return float(v)
        v = getattr(self.chain_base[name], knob)
        return None if isinstance(v, Curve) else float(v)

    def _sync_chain_sliders(self) -> None:
        """The chain sliders show the chosen chain's values (without re-simulating); a knob the bake keys over time
        is shown off."""
        with self._wanted:
            if self.tuner is None or not self.chain_base or self.g_c_chain.disabled:
                return
            name = self.g_c_chain.value
            if name not in self.chain_base:
                return
            keyed = []
            was, self._syncing = self._syncing, True        # their callbacks run here, in this thread: ignored
            try:
                for knob, h in self.g_c_knobs.items():
                    _, lo, hi, _ = CHAIN_SLIDERS[knob]
                    v = self._chain_current(name, knob)
                    if v is None:
                        keyed.append(knob)
                    else:
                        h.value = float(np.clip(v, lo, hi))
                    h.disabled = v is None
            finally:
                self._syncing = was
            self.g_c_note.content = (f"*{', '.join(keyed)} keyed over time in the bake: edit the keys in the scene*"
                                     if keyed else "")

    def _chain_knob_moved(self, knob: str, handle) -> None:
        """A chain knob's slider moved: its value (read now, under the lock) on the chosen chain (and its twin with
        "both sides") over the latest tuning, as _knob_moved does for a muscle."""
        with self._wanted:
            if self._syncing or self.tuner is None or self.g_c_chain.disabled:
                return
            value = float(handle.value)
            name = self.g_c_chain.value
            if name not in self.chain_base:
                return
            other = chain_twin(name, self.chain_base) if self.g_t_both.value else None
            tuning = self.tuning
            for n in (name, other):
                if n is None:
                    continue
                now = self._chain_current(n, knob)
                if now is not None and now != value:
                    tuning = tuning.with_chain(n, **{knob: value})
            self._request(tuning)

    def _knob_moved(self, knob: str, handle) -> None:
        """A knob's slider moved: its value (read now, under the lock: the latest the browser sent) on the chosen
        muscle (and its twin with "both sides") over the latest tuning."""
        with self._wanted:
            if self._syncing or self.tuner is None:
                return
            value = float(handle.value)
            name = self.g_t_muscle.value
            other = twin(name, self.base) if self.g_t_both.value else None
            tuning = self.tuning
            for n in (name, other):
                if n is not None and self._current(n, knob) != value:
                    tuning = tuning.with_muscle(n, **{knob: value})
            self._request(tuning)

    def _blend_moved(self) -> None:
        with self._wanted:
            if self._syncing or self.tuner is None:
                return
            self._request(self.tuning.with_blend(float(self.g_t_blend.value)))

    def _reset(self) -> None:
        with self._wanted:
            self._request(Tuning())
            self._sync_sliders()

    def _save(self) -> None:
        """Write the scene of the motion shown: once no run is pending (the one of the latest values is then
        shown, unless those values could not re-simulate: the motion shown is written, and the panel says so)."""
        from jiggle.sim.app.view.scene_file import save_tuned_scene
        if self.tuner is None:
            return
        path = os.path.abspath(os.path.expanduser(self.g_t_path.value.strip() or "tuned.toml"))
        with self._wanted:
            if not self._idle():
                self.g_t_result.content = "waiting for the re-simulation of the latest values to save them ..."
            done = self._wanted.wait_for(lambda: self._idle() or self._stop.is_set(), SAVE_WAIT_S)
            shown, latest = self.shown, self.generation
        if not done or not self._idle():
            self.g_t_result.content = "not saved: a re-simulation is still running; save again when it is done"
            return
        try:
            args = save_tuned_scene(self.tuner, shown.tuning, path, self.formats, source=self.out_dir)
        except Exception as e:  # noqa: BLE001 - a path that cannot be written: the panel says so
            self.g_t_result.content = f"not saved: {html.escape(str(e))}"
            return
        cmd = " ".join(["jiggle bake", path, *args, "--out", "OUT"])
        self.saved_motion = shown
        self.saved = (path, args)
        note = "" if shown.generation == latest else \
            " (the values of the motion shown: the latest ones did not re-simulate)"
        self.g_t_result.content = f"saved **{html.escape(path)}**{note}; bake it with `{html.escape(cmd)}`"
        self.log(f"saved {path}{note}; bake it with: {cmd}")
