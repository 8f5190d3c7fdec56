"""What the viewer shows of a bake, frame by frame: the skins, the displacement heat map in colour bands,
the muscles' surfaces, the skeleton, the muscles' jiggle amplitude and the skin-quality numbers.

`open_bake(out_dir)` reads and checks the folder (InputError for anything that is not a finished bake of
this jiggle's format); `Playback` holds its arrays and, after a re-simulation, the new motion
(`replace_motion`): the static skin never changes, the final skin and the blended CVs do.

The heat map is the report's (sim.app.report.compare_render): the final skin coloured by its displacement from
the static skin, YlOrRd from 0 to the largest displacement of the bake as loaded (kept when the motion is
re-simulated, so a softer or stronger jiggle shows on the same scale), here in HEAT_BANDS bands of that
scale (the browser's mesh takes one colour per mesh, so a band is a mesh of the faces whose mean
displacement falls in it).
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass

import numpy as np

from jiggle.rig.base.errors import InputError
from jiggle.sim.app.report.compare import load_bake, muscle_amplitude, skin_displacement
from jiggle.sim.bake.caches import BakeData

HEAT_BANDS = 9
"""Colour bands of the heat map (ColorBrewer's YlOrRd has nine classes)."""
CMAP = "YlOrRd"
"""The report's colour map (sim.app.report.compare_render.CMAP)."""
SUMMARY = "bake.json"
QUALITY_ROWS = (("final", "folded_edges", "folded edges", "{:.0f}"), ("final", "sharp_edges", "sharp edges", "{:.0f}"),
                ("final", "edge_strain_p99", "edge strain p99", "{:.3f}"),
                ("final", "area_ratio_min", "area ratio min", "{:.3f}"),
                ("jiggle", "gradient_p999", "jiggle gradient p99.9", "{:.3f}"),
                ("jiggle", "torn_edges", "torn edges", "{:.0f}"))
"""(skin, measure, label, format) of the per-frame skin-quality numbers shown (metrics.json, `jiggle compare`)."""


def band_colours(bands: int = HEAT_BANDS, cmap: str = CMAP) -> np.ndarray:
    """(bands, 3) uint8 RGB: the colour map `cmap` (default the report's, CMAP) at the middle of each band."""
    from matplotlib import colormaps
    rgba = colormaps[cmap]((np.arange(bands) + 0.5) / bands)
    return np.round(255 * rgba[:, :3]).astype(np.uint8)


def heat_bands(values: np.ndarray, faces: np.ndarray, top: float, bands: int = HEAT_BANDS) -> list:
    """The faces (F, 3) split by the mean of their vertices' values (V,) over [0, top] into `bands` equal
    bands (below 0: the first, above top: the last): per band (vertex ids (n,) int64, faces (f, 3) into
    them) or None when no face falls in it."""
    per_face = values[faces].mean(axis=1)
    k = np.clip((per_face / top * bands).astype(np.int64) if top > 0 else np.zeros(len(faces), np.int64),
                0, bands - 1)
    out = []
    for b in range(bands):
        f = faces[k == b]
        if len(f) == 0:
            out.append(None)
            continue
        ids, local = np.unique(f, return_inverse=True)
        out.append((ids, local.reshape(-1, 3).astype(np.uint32)))
    return out


def compact(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(vertex ids (n,), faces (f, 3) uint32 into them) of a subset of faces."""
    ids, local = np.unique(faces, return_inverse=True)
    return ids, local.reshape(-1, 3).astype(np.uint32)


def read_summary(out_dir: str) -> dict | None:
    """bake.json as a dict, None when missing or unreadable."""
    try:
        with open(os.path.join(out_dir, SUMMARY), encoding="utf-8") as fh:
            d = json.load(fh)
    except (OSError, ValueError):
        return None
    return d if isinstance(d, dict) else None


def read_quality(out_dir: str, frames: int) -> dict | None:
    """metrics.json's skin_quality.per_frame ({skin: {measure: (T,) float}}) when `jiggle compare` wrote it
    for this bake (the same number of frames), else None."""
    try:
        with open(os.path.join(out_dir, "metrics.json"), encoding="utf-8") as fh:
            m = json.load(fh)
        per = m["skin_quality"]["per_frame"]
        out = {skin: {k: np.asarray([np.nan if v is None else v for v in vals], float) for k, vals in d.items()}
               for skin, d in per.items()}
    except (OSError, ValueError, KeyError, TypeError):
        return None
    if any(len(v) != frames for d in out.values() for v in d.values()):
        return None
    return out


def open_bake(out_dir: str) -> tuple[BakeData, dict | None]:
    """(bake.npz read back, bake.json or None); InputError naming the folder for a missing folder, a
    file, a folder without bake.npz, an unfinished bake, or a cache of another format."""
    data = load_bake(out_dir)                       # InputError with the folder or file named
    if len(data.muscle_cv_offsets) > 1 and np.any(np.diff(data.muscle_cv_offsets) != 40):
        raise InputError("expected 40 CVs per muscle (5 sections x 8); this bake is of another format",
                         os.path.join(out_dir, "bake.npz"), field="muscle_cv_offsets")
    return data, read_summary(out_dir)


@dataclass(frozen=True)
class MuscleInfo:
    """A muscle of the bake: its name, kind ("muscle", "fat") and CV rows [a, b)."""

    name: str
    kind: str
    a: int
    b: int


class Playback:
    """A bake's frames for the viewer (see the module).

    data : the bake (sim.bake.caches.BakeData). summary : bake.json or None. quality : metrics.json's
    per-frame skin quality or None.
    """

    def __init__(self, data: BakeData, summary: dict | None = None, quality: dict | None = None):
        self.data, self.summary, self.quality = data, summary, quality
        self.T, self.V = data.skin_static.shape[:2]
        self.times = data.times
        self.faces = np.asarray(data.faces, np.int64)
        params = (summary or {}).get("params") or {}
        try:
            table = json.loads(data.params).get("muscles", {}) or params.get("muscles", {})
        except (ValueError, AttributeError):
            table = params.get("muscles", {})
        off = data.muscle_cv_offsets
        self.muscles = [MuscleInfo(n, str((table.get(n) or {}).get("kind", "muscle")), int(off[m]), int(off[m + 1]))
                        for m, n in enumerate(data.muscle_names)]
        self.name = str((summary or {}).get("name") or (params.get("clip") or {}).get("name") or "bake")
        self.replace_motion(data.muscle_cvs_dynamic, data.skin_final, original=True)

    # ---------------------------------------------------------------- the motion
    def replace_motion(self, cvs_dynamic: np.ndarray, skin_final: np.ndarray, original: bool = False) -> None:
        """Show another final skin (T, V, 3) and blended CVs (T, N, 3) (a re-simulation); the heat map's
        scale stays the bake's."""
        self.cvs_dynamic, self.skin_final = cvs_dynamic, skin_final
        self.displacement_mm = 1e3 * skin_displacement(self.data.skin_static, skin_final)     # (T, V)
        d = cvs_dynamic.astype(np.float64) - self.data.muscle_cvs_static
        self.amplitude_mm = 1e3 * muscle_amplitude(d, self.data.muscle_cv_offsets)            # (T, M)
        self.peak_mm = self.amplitude_mm.max(axis=0) if self.T else np.zeros(len(self.muscles))
        if original:
            self.heat_top_mm = float(self.displacement_mm.max()) if self.displacement_mm.size else 0.0
            self.original_peak_mm = self.peak_mm.copy()
            self.original_skin_final = skin_final

    @property
    def tuned(self) -> bool:
        return self.skin_final is not self.original_skin_final

    # ---------------------------------------------------------------- per frame
    def skin(self, k: int, which: str) -> np.ndarray:
        """(V, 3) float32 metres: the "static" or "final" skin at frame k."""
        return (self.data.skin_static if which == "static" else self.skin_final)[k]

    def muscle_surfaces(self, k: int, which: str = "final") -> np.ndarray:
        """(M, P, 3) float32 metres: every muscle's loft surface at frame k, from its static or blended
        CVs (triangles: data.muscle_faces)."""
        from jiggle.rig.muscle import loft
        cvs = (self.data.muscle_cvs_static if which == "static" else self.cvs_dynamic)[k]
        M = len(self.muscles)
        return loft.points(cvs.reshape(M, loft.SECTIONS, loft.RING, 3).astype(np.float64)).astype(np.float32)

    def joints(self, k: int) -> np.ndarray:
        """(J, 3) float32 metres: the clip's joint positions at frame k."""
        return self.data.joint_world[k][:, :3, 3]

    def quality_rows(self, k: int) -> list[tuple[str, str]] | None:
        """[(label, value)] of the frame's skin quality (metrics.json), None when the bake has none or the
        motion shown is a re-simulation (its numbers are the baked motion's)."""
        if self.quality is None:
            return None
        rows = []
        for skin, key, label, fmt in QUALITY_ROWS:
            v = self.quality.get(skin, {}).get(key)
            if v is not None and np.isfinite(v[k]):
                rows.append((label, fmt.format(v[k])))
        return rows or None

    def region_fallback(self, m: int, reach: float = 0.05) -> np.ndarray:
        """(V,) bool: the skin region of muscle m without the bound skin: vertices whose nearest CV at the
        first frame is one of m's and lies within `reach` metres (the skin's pairs, when the setup is
        rebuilt, replace it: Tuner.skin)."""
        from scipy.spatial import cKDTree
        cvs = self.data.muscle_cvs_static[0]
        dist, idx = cKDTree(cvs).query(self.data.skin_static[0])
        mi = self.muscles[m]
        return (idx >= mi.a) & (idx < mi.b) & (dist <= reach)


def skin_regions(skin, V: int, M: int) -> list[np.ndarray] | None:
    """Per muscle, (V,) bool: the vertices the bound skin pairs with it (rig.skin.muscle_skin.MuscleSkin's
    culled (vertex, muscle) pairs), None when the skin has none (RBF skinning)."""
    off, mus = getattr(skin, "pair_offsets", None), getattr(skin, "pair_muscle", None)
    if off is None or mus is None or len(mus) == 0 or len(off) != V + 1:
        return None
    vertex = np.repeat(np.arange(V), np.diff(off))
    out = []
    for m in range(M):
        r = np.zeros(V, bool)
        r[vertex[mus == m]] = True
        out.append(r)
    return out
