"""The pictures of `jiggle compare`: static | dynamic skin side by side, off screen with PyVista.

peak.png    the peak frame, two panels of about PEAK_PIXELS pixels each
clip.mp4    the whole clip, at most MAX_VIDEO_FRAMES frames taken evenly, two panels of about
            VIDEO_PIXELS pixels (480 x 360 for a square-ish view), played in real time (its frame rate
            is frames / duration); clip.gif when ffmpeg fails

Both panels share one camera; the dynamic skin is coloured by its displacement from the static skin
(mm), on one scale for the peak picture and every video frame (0 to the largest displacement of the
bake). The camera looks horizontally across the skin's main motion at the peak (so the jiggle moves in
the picture plane, not towards the viewer), from the side where the moving skin is, a little from
above. It frames the whole skin: one fixed box when the body stays in place, else a box of fixed size
following it (sim.app.outputs.simulate.focus_boxes). A panel takes the shape of that box as seen (a
standing figure from the side gets a tall panel, not a wide one with empty sides), within
ASPECT, widened by BAR_ROOM for the colour bar.

One Plotter draws every frame: the meshes' points, normals and scalars are replaced in place, so a
frame costs a render and a read-back, not a new window. Two choices keep a frame near 40 ms for a
20k-vertex skin on a 2-core software GL (llvmpipe): vertex normals come from rig.character.normals (NumPy, ~4
ms a skin) with Gouraud shading instead of PyVista's smooth_shading, whose VTK normals filter re-runs
on every update (~80 ms a frame), and multisampling is off (8x MSAA more than doubles a frame).
"""
from __future__ import annotations

import os
import time
from typing import Callable

import numpy as np

from jiggle.rig.base.atomic import atomic_path
from jiggle.rig.character.normals import VertexNormals
from jiggle.sim.app.outputs.simulate import focus_boxes
from jiggle.sim.app.report.mesh_render import SKIN, frame_camera

os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")

VIDEO_PIXELS = 480 * 360
"""Pixels of one video panel (its sides are multiples of 8, as H.264 wants)."""
PEAK_PIXELS = 800 * 600
"""Pixels of one panel of peak.png."""
ASPECT = (0.6, 1.8)
"""Least and largest width / height of a panel."""
BAR_ROOM = 1.25
"""A panel is this much wider than its view's box, so the colour bar at its right leaves the skin free."""
MAX_VIDEO_FRAMES = 90
CMAP = "YlOrRd"
ELEVATION = 0.3
"""Upward component of the (unit, before normalising) horizontal view direction."""


def video_frames(T: int, max_frames: int = MAX_VIDEO_FRAMES) -> np.ndarray:
    """(K,) int frame indices of the video: all T frames, or max_frames spread evenly over them
    (first and last included)."""
    if T <= max_frames:
        return np.arange(T)
    return np.unique(np.round(np.linspace(0, T - 1, max_frames)).astype(int))


def view_direction(static: np.ndarray, final: np.ndarray) -> np.ndarray:
    """(3,) unit direction from the skin towards the camera, from one frame's skins (V, 3) metres.

    Horizontal and perpendicular to the main horizontal direction of the displacement (the
    displacement-weighted principal axis of its xy parts), on the side of the moving vertices, raised
    by ELEVATION. With no displacement: the project's front view (figures face -Y)."""
    u = (final.astype(np.float64) - static)[:, :2]
    w = np.linalg.norm(u, axis=1)
    if not np.any(w > 0):
        d = np.array([0.0, -1.0])
    else:
        cov = (u * w[:, None]).T @ u                       # weighted by size: the big moves decide
        evals, evecs = np.linalg.eigh(cov)
        e = evecs[:, -1]
        d = np.array([-e[1], e[0]])                        # horizontal, across the motion
        moving = (static[:, :2] * w[:, None]).sum(axis=0) / w.sum() - static[:, :2].mean(axis=0)
        if moving @ d < 0:
            d = -d                                         # look from the side the jiggle is on
    v = np.array([d[0], d[1], ELEVATION])
    return v / np.linalg.norm(v)


def panel_size(box: np.ndarray, direction: np.ndarray, pixels: int, step: int = 8) -> tuple[int, int]:
    """(width, height) of a panel of about `pixels` pixels shaped like `box` (2, 3) metres seen along
    -direction (Z up), widened by BAR_ROOM, width / height within ASPECT, sides multiples of `step`."""
    d = np.asarray(direction, float) / np.linalg.norm(direction)
    up = np.array([0.0, 0.0, 1.0]) - d[2] * d
    up /= np.linalg.norm(up)
    right = np.cross(up, d)
    lo, hi = np.asarray(box, float)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    c = corners - 0.5 * (lo + hi)
    w, h = np.abs(c @ right).max(), np.abs(c @ up).max()
    aspect = float(np.clip(BAR_ROOM * w / h if h > 0 else ASPECT[1], *ASPECT))
    height = np.sqrt(pixels / aspect)
    return (int(max(step, step * round(aspect * height / step))), int(max(step, step * round(height / step))))


def _poly(points: np.ndarray, faces: np.ndarray):
    import pyvista as pv
    f = np.asarray(faces, np.int64)
    return pv.PolyData(np.asarray(points, np.float64), np.hstack([np.full((len(f), 1), 3), f]).ravel())


class SideBySide:
    """One off-screen plotter, two panels with one camera: static skin | dynamic skin coloured by its
    displacement (mm). faces : (F, 3) skin triangles; vertices : V; clim : (lo, hi) mm;
    panel : (width, height) pixels of one panel."""

    def __init__(self, faces: np.ndarray, vertices: int, clim: tuple[float, float],
                 panel: tuple[int, int] = (480, 360)):
        import pyvista as pv
        z = np.zeros((vertices, 3))
        self.normals = VertexNormals(faces, vertices)
        self.static, self.dynamic = _poly(z, faces), _poly(z, faces)
        self.dynamic.point_data["mm"] = np.zeros(vertices)
        for mesh in (self.static, self.dynamic):
            mesh.point_data["Normals"] = np.zeros((vertices, 3), np.float32)
            mesh.point_data.active_normals_name = "Normals"
        self.panel = panel
        pl = pv.Plotter(off_screen=True, shape=(1, 2), window_size=[2 * panel[0], panel[1]], border=False)
        pl.ren_win.SetMultiSamples(0)
        pl.subplot(0, 0)
        pl.set_background("white")
        actors = [pl.add_mesh(self.static, color=SKIN, specular=0.2)]
        pl.subplot(0, 1)
        pl.set_background("white")
        actors.append(pl.add_mesh(
            self.dynamic, scalars="mm", cmap=CMAP, clim=clim, specular=0.2,
            scalar_bar_args={"title": "moved (mm)", "color": "black", "title_font_size": 12,
                             "label_font_size": 11, "vertical": True, "position_x": 0.83,
                             "position_y": 0.1, "height": 0.8, "width": 0.07, "fmt": "%.1f"}))
        for actor in actors:
            actor.prop.interpolation = "gouraud"          # shade with our normals (add_mesh set flat)
        pl.link_views()                                   # one camera for both panels
        # annotations made once and re-texted per frame: adding an actor to a shown plotter renders it
        self.labels = []
        for i in range(2):
            pl.subplot(0, i)
            self.labels.append(pl.add_text(" ", position="lower_left", font_size=9, color="black"))
        self.pl = pl

    def resize(self, panel: tuple[int, int]) -> None:
        self.panel = panel
        self.pl.window_size = [2 * panel[0], panel[1]]

    def draw(self, static: np.ndarray, final: np.ndarray, box: np.ndarray, direction: np.ndarray,
             left: str, right: str) -> np.ndarray:
        """(H, W, 3) uint8 image of one frame: skins (V, 3) metres, box (2, 3) to frame, direction (3,)
        towards the camera, corner texts."""
        s = np.asarray(static, np.float64)
        f = np.asarray(final, np.float64)
        normals = self.normals(np.stack([s, f])).astype(np.float32)
        self.static.points = s
        self.dynamic.points = f
        self.static.point_data["Normals"] = normals[0]
        self.dynamic.point_data["Normals"] = normals[1]
        self.dynamic.point_data["mm"] = 1e3 * np.linalg.norm(f - s, axis=1)
        self.pl.subplot(0, 0)
        frame_camera(self.pl, np.asarray(box, float), direction, np.array([0.0, 0.0, 1.0]),
                     self.panel[0] / self.panel[1])
        for i, text in enumerate((left, right)):
            self.labels[i].SetText(0, text)               # corner 0: lower left
        self.pl.render()                                  # the read-back alone would reuse the last image
        return self.pl.screenshot(return_img=True)

    def close(self) -> None:
        self.pl.close()


def write_png(image: np.ndarray, path: str) -> str:
    """Write an (H, W, 3) uint8 image as PNG, atomically."""
    import imageio.v3 as iio
    with atomic_path(path) as tmp:
        iio.imwrite(tmp, image, extension=".png")
    return path


def write_video(images: list, out_dir: str, fps: float, name: Callable[[str], str] = str) -> tuple[str, str]:
    """Write (H, W, 3) uint8 images as out_dir/clip.mp4 (H.264, yuv420p) at `fps`, or as
    out_dir/clip.gif when ffmpeg fails; return (path, how: "mp4" or "gif (ffmpeg failed: ...)").
    name : maps those file names to the ones to write (compare keeps a user's own clip.mp4)."""
    import imageio.v2 as iio2
    import imageio.v3 as iio

    path = os.path.join(out_dir, name("clip.mp4"))
    try:
        with atomic_path(path) as tmp:
            writer = iio2.get_writer(tmp, format="FFMPEG", mode="I", fps=fps, codec="libx264",
                                     pixelformat="yuv420p", quality=6, macro_block_size=8,
                                     ffmpeg_log_level="error")
            try:
                for im in images:
                    writer.append_data(im)
            finally:
                writer.close()
            if not os.path.getsize(tmp):
                raise OSError("ffmpeg wrote an empty file")
        return path, "mp4"
    except Exception as e:          # no ffmpeg binary, a codec missing, a crash: the GIF still shows it
        reason = f"{type(e).__name__}: {e}".splitlines()[0][:200]
    path = os.path.join(out_dir, name("clip.gif"))
    with atomic_path(path) as tmp:
        iio.imwrite(tmp, np.stack(images), extension=".gif", duration=1000.0 / fps, loop=0)
    return path, f"gif (ffmpeg failed: {reason})"


def render_outputs(data, peak_frame: int, disp: np.ndarray, out_dir: str, *, video: bool = True,
                   progress=None, name: Callable[[str], str] = str, reference: np.ndarray | None = None) -> dict:
    """Write peak.png and (with video) clip.mp4 or clip.gif into out_dir (name: as write_video's).

    data : sim.bake.caches.BakeData. peak_frame : the frame of peak.png. disp : (T, V) metres, the skin
    displacement per frame (its maximum fixes the colour scale). progress(1) after each frame.
    reference : (T, V, 3) metres, the left panel and what the colour measures from: default data.skin_static;
    compare passes skin_swung for a bake with chains (the swung tail on both sides, coloured by the tissue alone).
    Returns {"files": {"peak": path, "video": path}, "video": facts or None, "timings": {stage: s}}.
    """
    timings, files = {}, {}
    t0 = time.perf_counter()
    static = data.skin_static if reference is None else reference
    label = "static" if static is data.skin_static else "static + chains"
    T = data.num_frames
    times = data.times
    top = float(disp.max()) * 1e3 if disp.size else 0.0
    clim = (0.0, top if top > 1e-3 else 1.0)              # a still skin gets a 0..1 mm scale, not 0..0
    direction = view_direction(static[peak_frame], data.skin_final[peak_frame])
    sel = video_frames(T) if video else np.zeros(0, int)
    k = peak_frame
    box_frames = np.unique(np.append(sel, k))
    boxes = focus_boxes(np.concatenate([static[box_frames], data.skin_final[box_frames]], axis=1),
                        pad=0.02)
    box_of = {int(f): boxes[i] for i, f in enumerate(box_frames)}
    peak_box = focus_boxes(np.concatenate([static[k:k + 1], data.skin_final[k:k + 1]], axis=1),
                           pad=0.02)[0]
    r = SideBySide(data.faces, data.skin_static.shape[1], clim,
                   panel=panel_size(peak_box, direction, PEAK_PIXELS))
    timings["render_setup_s"] = time.perf_counter() - t0
    try:
        t0 = time.perf_counter()
        image = r.draw(static[k], data.skin_final[k], peak_box, direction,
                       f"{label}   frame {k}, t = {times[k]:.3f} s",
                       f"dynamic   coloured by how far the skin moved, up to {disp[k].max() * 1e3:.2f} mm")
        files["peak"] = write_png(image, os.path.join(out_dir, name("peak.png")))
        if progress is not None:
            progress(1)
        timings["peak_s"] = time.perf_counter() - t0
        if len(sel):
            t0 = time.perf_counter()
            r.resize(panel_size(box_of[int(sel[0])], direction, VIDEO_PIXELS))     # boxes: one size
            images = []
            for f in sel:
                images.append(r.draw(static[f], data.skin_final[f], box_of[int(f)], direction,
                                     f"{label}   t = {times[f]:.3f} s",
                                     f"dynamic   moved up to {disp[f].max() * 1e3:.2f} mm"))
                if progress is not None:
                    progress(1)
            timings["video_render_s"] = time.perf_counter() - t0
    finally:
        r.close()
    info = None
    if len(sel):
        t0 = time.perf_counter()
        duration = float(times[sel[-1]] - times[sel[0]])
        fps = (len(sel) - 1) / duration if len(sel) > 1 and duration > 0 else data.fps
        fps = float(min(max(fps, 1.0), max(data.fps, 1.0)))
        files["video"], how = write_video(images, out_dir, fps, name)
        timings["video_encode_s"] = time.perf_counter() - t0
        info = {"file": os.path.basename(files["video"]), "format": how, "frames": int(len(sel)),
                "every": float(T - 1) / max(len(sel) - 1, 1), "fps": fps,
                "size_px": [int(images[0].shape[1]), int(images[0].shape[0])],
                "colour_scale_mm": list(clim)}
    return {"files": files, "video": info, "timings": timings}
