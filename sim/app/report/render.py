"""Off-screen pictures with PyVista (Mesa EGL on a headless machine).

Set ``VTK_DEFAULT_OPENGL_WINDOW=vtkEGLRenderWindow`` before VTK loads (done here when unset): without
a GL library VTK crashes the process instead of raising, which is why the tests keep a render smoke
test.
"""
from __future__ import annotations

import os

import numpy as np

os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")


def _bones(parents: np.ndarray, end_parents: np.ndarray) -> np.ndarray:
    """(B, 2) index pairs into the stacked [joints, end sites] points."""
    J = len(parents)
    pairs = [(p, j) for j, p in enumerate(parents) if p >= 0]
    pairs += [(e, J + k) for k, e in enumerate(end_parents)]
    return np.array(pairs, dtype=np.int64).reshape(-1, 2)


def render_skeleton_over_time(points: np.ndarray, parents: np.ndarray, end_parents: np.ndarray,
                              times: np.ndarray, path: str, poses: int = 8, spacing: float | None = None,
                              size: tuple[int, int] = (1600, 600), title: str = "") -> str:
    """A film strip of the skeleton: `poses` evenly spaced frames side by side, coloured by time.

    points : (N, J + E, 3) metres, world joint positions then end sites, per frame.
    parents : (J,) parent index per joint, -1 for roots; end_parents : (E,) joint of each end site.
    times : (N,) seconds.
    spacing : metres between poses along the strip (default: the widest pose plus 30%).
    Writes a PNG to `path` and returns it.
    """
    import pyvista as pv

    n = points.shape[0]
    frames = np.unique(np.linspace(0, n - 1, min(poses, n)).round().astype(int))
    bones = _bones(parents, end_parents)
    centred = points[frames] - points[frames, :1] * np.array([1.0, 1.0, 0.0])  # root over the origin
    if spacing is None:
        spacing = 1.3 * max(float(np.ptp(centred[..., 0], axis=1).max()), 0.5)
    pl = pv.Plotter(off_screen=True, window_size=list(size))
    pl.set_background("white")
    cmap_t = (times[frames] - times[0]) / max(times[-1] - times[0], 1e-9)
    floor_z = float(points[..., 2].min())
    for k, (f, c) in enumerate(zip(frames, cmap_t)):
        pts = centred[k] + np.array([k * spacing, 0.0, 0.0])
        lines = np.hstack([np.full((len(bones), 1), 2), bones]).ravel()
        poly = pv.PolyData(pts, lines=lines)
        colour = (0.15 + 0.7 * c, 0.35, 0.85 - 0.7 * c)
        pl.add_mesh(poly.tube(radius=0.018), color=colour, smooth_shading=True)
        pl.add_mesh(pv.PolyData(pts).glyph(geom=pv.Sphere(radius=0.028), scale=False, orient=False), color=colour)
        pl.add_point_labels([pts[:, :].max(0) * [0, 0, 1] + [k * spacing, 0, 0.12]], [f"{times[f]:.2f} s"],
                            font_size=14, text_color="black", shape=None, show_points=False)
    width = spacing * (len(frames) - 1)
    floor = pv.Plane(center=(width / 2, 0, floor_z), direction=(0, 0, 1), i_size=width + 1.2 * spacing, j_size=1.0)
    pl.add_mesh(floor, color=(0.85, 0.85, 0.85))
    # Look from the front (figures face -Y) and a little above, framing the whole strip.
    pl.view_vector((0.0, -1.0, 0.25), viewup=(0.0, 0.0, 1.0))
    pl.reset_camera()
    pl.camera.zoom(1.9)
    if title:
        pl.add_title(title, font_size=12, color="black")
    pl.screenshot(path)
    pl.close()
    return path


def render_skin_over_time(positions: np.ndarray, faces: np.ndarray, times: np.ndarray, path: str,
                          spacing: float | None = None, size: tuple[int, int] = (1600, 600),
                          title: str = "") -> str:
    """A film strip of a skinned character: one posed mesh per frame side by side, coloured by time.

    positions : (P, V, 3) metres, the skinned vertices of the P poses to show.
    faces : (F, 3) vertex indices.
    times : (P,) seconds of each pose, for the labels and colours.
    Writes a PNG to `path` and returns it.
    """
    import pyvista as pv

    P = len(positions)
    centre = positions.mean(axis=1) * np.array([1.0, 1.0, 0.0])
    centred = positions - centre[:, None]
    if spacing is None:
        spacing = 1.2 * max(float(np.ptp(centred[..., 0], axis=1).max()), 0.5)
    cells = np.hstack([np.full((len(faces), 1), 3), faces]).ravel()
    pl = pv.Plotter(off_screen=True, window_size=list(size))
    pl.set_background("white")
    span = max(float(times[-1] - times[0]), 1e-9) if P else 1.0
    for k in range(P):
        c = (times[k] - times[0]) / span
        mesh = pv.PolyData(centred[k] + np.array([k * spacing, 0.0, 0.0]), cells)
        pl.add_mesh(mesh, color=(0.55 + 0.35 * c, 0.62, 0.85 - 0.35 * c), smooth_shading=True)
        top = float(centred[k][:, 2].max())
        pl.add_point_labels([[k * spacing, 0.0, top + 0.12]], [f"{times[k]:.2f} s"], font_size=14,
                            text_color="black", shape=None, show_points=False)
    width = spacing * max(P - 1, 0)
    floor_z = float(positions[..., 2].min())
    pl.add_mesh(pv.Plane(center=(width / 2, 0, floor_z), direction=(0, 0, 1), i_size=width + 1.2 * spacing,
                         j_size=1.0), color=(0.85, 0.85, 0.85))
    pl.view_vector((0.0, -1.0, 0.25), viewup=(0.0, 0.0, 1.0))
    pl.reset_camera()
    pl.camera.zoom(2.5)  # reset_camera frames the bounding sphere of a long strip: too far
    if title:
        pl.add_title(title, font_size=12, color="black")
    pl.screenshot(path)
    pl.close()
    return path
