"""Off-screen pictures of a triangle mesh (a generated body, later a character), with PyVista.

Set ``VTK_DEFAULT_OPENGL_WINDOW=vtkEGLRenderWindow`` before VTK loads (done here when unset): without
a GL library VTK crashes the process instead of raising, which is why the tests keep a render smoke
test. Views assume the project's convention that figures face -Y with Z up.
"""
from __future__ import annotations

import os

import numpy as np

from jiggle.rig.base.atomic import atomic_path

os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")

SKIN = (0.87, 0.70, 0.60)
# direction from the mesh towards the camera, for a figure facing -Y, Z up
VIEWS = {
    "front": (0.0, -1.0, 0.0),
    "back": (0.0, 1.0, 0.0),
    "side": (1.0, 0.0, 0.0),   # from the figure's left (+X), its front to the image's left
    "left": (1.0, 0.0, 0.0),
    "right": (-1.0, 0.0, 0.0),
    "top": (0.0, 0.0, 1.0),
    "iso": (0.8, -1.0, 0.45),
}


def render_mesh(vertices: np.ndarray, faces: np.ndarray, path: str | os.PathLike, *,
                scalars: np.ndarray | None = None, views=("front", "side"), title: str | None = None,
                size: tuple[int, int] = (1200, 900), overlay_lines: np.ndarray | None = None) -> str:
    """Write a PNG of the mesh seen from each view, side by side, and return its path.

    vertices : (V, 3) metres. faces : (F, 3) int vertex indices.
    scalars : (V,) per-vertex values to colour by (integers: one colour per label, e.g. the dominant
        joint; floats: a colour map), or None for a plain skin colour.
    views : names from :data:`VIEWS` ("front", "side", "back", "left", "right", "top", "iso") or
        (3,) directions from the mesh towards the camera.
    overlay_lines : (B, 2, 3) metres, segments drawn over the mesh (e.g. the skeleton's bones, with a
        sphere at each end); the mesh is then drawn half transparent.
    size : (width, height) of the whole picture in pixels.
    The file is written atomically (a temporary file beside it, then renamed).
    """
    import pyvista as pv

    v = np.asarray(vertices, float)
    f = np.asarray(faces, np.int64)
    mesh = pv.PolyData(v, np.hstack([np.full((len(f), 1), 3), f]).ravel())
    kwargs = {"color": SKIN}
    if scalars is not None:
        s = np.asarray(scalars)
        labels = np.issubdtype(s.dtype, np.integer)
        # labels (joint indices) cycle through 20 distinct colours, so neighbouring joints differ
        mesh.point_data["scalars"] = (s - s.min()) % 20 if labels else s
        kwargs = {"scalars": "scalars", "cmap": "tab20" if labels else "viridis", "show_scalar_bar": not labels}
        if labels:
            kwargs.update(clim=(-0.5, 19.5), n_colors=20)
    bones = None
    if overlay_lines is not None and len(overlay_lines):
        seg = np.asarray(overlay_lines, float).reshape(-1, 2, 3)
        pts = seg.reshape(-1, 3)
        lines = np.hstack([np.full((len(seg), 1), 2), np.arange(2 * len(seg)).reshape(-1, 2)]).ravel()
        scale = float(np.ptp(v, axis=0).max()) if len(v) else 1.0
        bones = (pv.PolyData(pts, lines=lines).tube(radius=0.004 * scale),
                 pv.PolyData(pts).glyph(geom=pv.Sphere(radius=0.008 * scale), scale=False, orient=False))

    views = list(views)
    pl = pv.Plotter(off_screen=True, shape=(1, len(views)), window_size=list(size), border=False)
    for i, view in enumerate(views):
        pl.subplot(0, i)
        pl.set_background("white")
        pl.add_mesh(mesh.copy(deep=False), smooth_shading=True, specular=0.2,
                    opacity=0.45 if bones else 1.0, **kwargs)
        if bones:
            pl.add_mesh(bones[0], color=(0.15, 0.25, 0.75))
            pl.add_mesh(bones[1], color=(0.8, 0.15, 0.15))
        direction = VIEWS[view] if isinstance(view, str) else tuple(float(x) for x in view)
        up = (0.0, 1.0, 0.0) if isinstance(view, str) and view == "top" else (0.0, 0.0, 1.0)
        frame_camera(pl, v if len(v) else np.zeros((1, 3)), np.asarray(direction, float), np.asarray(up),
                      size[0] / len(views) / size[1])
        pl.add_text(view if isinstance(view, str) else "view", position="lower_left", font_size=10,
                    color="black")
        if i == 0 and title:
            pl.add_text(title, position="upper_left", font_size=12, color="black")
    with atomic_path(path) as tmp:
        pl.screenshot(tmp)
    pl.close()
    return os.fspath(path)


def frame_camera(pl, points: np.ndarray, direction: np.ndarray, up: np.ndarray, aspect: float) -> None:
    """Parallel projection looking along -direction, framing the points tightly (5% margin).
    aspect : width / height of the viewport."""
    d = direction / np.linalg.norm(direction)
    up = up - up @ d * d
    up /= np.linalg.norm(up)
    right = np.cross(up, d)
    lo, hi = points.min(0), points.max(0)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    centre = 0.5 * (lo + hi)
    half_w = np.abs((corners - centre) @ right).max()
    half_h = np.abs((corners - centre) @ up).max()
    radius = float(np.linalg.norm(hi - lo)) or 1.0
    pl.camera.focal_point = tuple(centre)
    pl.camera.position = tuple(centre + 3.0 * radius * d)
    pl.camera.up = tuple(up)
    pl.enable_parallel_projection()
    pl.camera.parallel_scale = 1.05 * max(half_h, half_w / aspect, 1e-6)
    pl.reset_camera_clipping_range()
