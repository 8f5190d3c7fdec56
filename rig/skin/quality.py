"""Skin quality: what the eye sees as a torn, creased or crumpled skin, measured per frame.

For a triangle mesh with a fixed topology (a character's skin) over T frames:

- folded edges: interior edges whose two faces turn more than 90 degrees against each other
  (the dot product of their unit normals below 0): creases, slivers, a surface folding over itself;
- sharp edges: more than 60 degrees (dot below 0.5); a smooth skin at rest has few, so the count is
  read against the rest mesh's own (``rest_sharp``, ``rest_folded``);
- edge strain: |length / rest length - 1|, its 99th percentile and maximum;
- face area ratio: area / rest area, its minimum (a collapsed face) and maximum;
- the jiggle displacement gradient of an edge (a, b): |d_a - d_b| / max(|s_a - s_b|, GRADIENT_FLOOR
  x rest length) with s the static skin and d = final - static, i.e. how much the jiggle alone
  stretches or squeezes the edge relative to its own length; above 1 the jiggle tears it
  (``torn_edges``); its 99th and 99.9th percentiles and maximum per frame. The floor keeps an edge
  that the skinning squashed to nothing (LBS collapsing an elbow's inside: 10 mm to 0.1 mm) from
  counting a tenth of a millimetre of jiggle as a tear; that collapse is the skinning's, and the fold
  measures see it.

`SkinQuality` is built once per mesh (edges, their faces, rest lengths and areas) and measures many
frames in one Warp launch per measure (rig/skin/quality_kernels.py); the reductions run in NumPy.
The bake measures every chunk with it (sim/bake/baker.py), `jiggle compare` reports it, and the
tests and benchmarks hold the skin to it.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from jiggle.rig.base.errors import InputError
from jiggle.rig.base.frozen import frozen_array
from jiggle.rig.character.mesh_graph import mesh_edges

FOLDED_COS = 0.0
"""An edge folds when its faces' normals are more than 90 degrees apart (cosine below this)."""
SHARP_COS = 0.5
"""An edge is sharp when its faces' normals are more than 60 degrees apart (cosine below this)."""
TORN = 1.0
"""The jiggle tears an edge when it stretches or squeezes it by more than its own length."""

SKIN_MEASURES = ("folded_edges", "sharp_edges", "edge_strain_p99", "edge_strain_max", "area_ratio_min",
                 "area_ratio_max")
"""Per frame, of one skin (see the module)."""
JIGGLE_MEASURES = ("gradient_p99", "gradient_p999", "gradient_max", "torn_edges")
GRADIENT_FLOOR = 0.1
"""An edge's length in the gradient is at least this share of its rest length (see the module)."""
"""Per frame, of the jiggle between a static and a final skin (see the module)."""


@dataclass(frozen=True, eq=False)
class MeshTopology:
    """One mesh's edges and rest measures. E edges, F faces.

    faces : (F, 3) int32. edges : (E, 2) int32. edge_faces : (E, 2) int32 (-1: boundary).
    rest_length : (E,) float64 metres. rest_area : (F,) float64 m^2. rest_cos : (E,) float64, the
    cosine between each edge's face normals at rest (1 on a boundary edge).
    """
    num_vertices: int
    faces: np.ndarray
    edges: np.ndarray
    edge_faces: np.ndarray
    rest_length: np.ndarray
    rest_area: np.ndarray
    rest_cos: np.ndarray

    @classmethod
    def of(cls, rest: np.ndarray, faces: np.ndarray) -> "MeshTopology":
        """From the rest vertices (V, 3) metres and faces (F, 3)."""
        rest = np.asarray(rest, dtype=np.float64)
        faces = np.asarray(faces)
        if rest.ndim != 2 or rest.shape[1] != 3:
            raise InputError(f"expected (V, 3) rest vertices, got {rest.shape}", field="rest")
        if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0:
            raise InputError(f"expected (F >= 1, 3) faces, got {faces.shape}", field="faces")
        if faces.min() < 0 or faces.max() >= len(rest):
            raise InputError(f"face indices must lie in [0, {len(rest)})", field="faces")
        edges, edge_faces = mesh_edges(faces)
        # floors keep the ratios finite on a degenerate rest edge or face (they then read as large)
        length = np.maximum(np.linalg.norm(rest[edges[:, 1]] - rest[edges[:, 0]], axis=1), 1e-9)
        n = _face_normals(rest[None], faces)[0]
        area = np.maximum(0.5 * np.linalg.norm(_face_cross(rest[None], faces)[0], axis=1), 1e-12)
        cos = np.where(edge_faces[:, 1] >= 0,
                       np.einsum("ij,ij->i", n[edge_faces[:, 0]], n[np.maximum(edge_faces[:, 1], 0)]), 1.0)
        return cls(len(rest), frozen_array(faces, np.int32), frozen_array(edges, np.int32),
                   frozen_array(edge_faces, np.int32), frozen_array(length), frozen_array(area), frozen_array(cos))

    @property
    def num_edges(self) -> int:
        return len(self.edges)

    @property
    def rest_folded(self) -> int:
        """Folded edges of the rest mesh itself."""
        return int(np.count_nonzero(self.rest_cos < FOLDED_COS))

    @property
    def rest_sharp(self) -> int:
        """Sharp edges of the rest mesh itself."""
        return int(np.count_nonzero(self.rest_cos < SHARP_COS))


def _face_cross(points: np.ndarray, faces: np.ndarray) -> np.ndarray:
    tri = points[:, faces]
    return np.cross(tri[:, :, 1] - tri[:, :, 0], tri[:, :, 2] - tri[:, :, 0])


def _face_normals(points: np.ndarray, faces: np.ndarray) -> np.ndarray:
    c = _face_cross(points, faces)
    length = np.linalg.norm(c, axis=-1, keepdims=True)
    return np.where(length > 0, c / np.where(length > 0, length, 1.0), 0.0)


class SkinQuality:
    """Measures frames of one mesh (see the module). Built once: the topology and its device arrays.

    rest : (V, 3) metres, the rest skin. faces : (F, 3). device : Warp device.
    """

    def __init__(self, rest: np.ndarray, faces: np.ndarray, device: str = "cpu"):
        self.mesh = MeshTopology.of(rest, faces)
        self.device = wp.get_device(device)
        m = self.mesh
        self._faces = wp.array(m.faces, dtype=wp.vec3i, device=self.device)
        self._edges = wp.array(m.edges, dtype=wp.vec2i, device=self.device)
        self._edge_faces = wp.array(m.edge_faces, dtype=wp.vec2i, device=self.device)
        self._rest_length = wp.array(m.rest_length, dtype=wp.float32, device=self.device)
        self._rest_area = wp.array(m.rest_area, dtype=wp.float32, device=self.device)

    def _points(self, skins, name: str) -> wp.array:
        p = np.ascontiguousarray(skins, dtype=np.float32)
        if p.ndim != 3 or p.shape[1:] != (self.mesh.num_vertices, 3):
            raise InputError(f"expected (T, {self.mesh.num_vertices}, 3) skins, got {p.shape}", field=name)
        return wp.array(p, dtype=wp.vec3, device=self.device)

    def edges(self, skins: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per frame (T, V, 3) metres: cos (T, E), strain (T, E) and face area ratio (T, F), float32
        (see quality_kernels)."""
        from jiggle.rig.skin import quality_kernels as k
        pts = self._points(skins, "skins")
        T, E, F = pts.shape[0], self.mesh.num_edges, len(self.mesh.faces)
        normals = wp.empty((T, F), dtype=wp.vec3, device=self.device)
        area = wp.empty((T, F), dtype=wp.float32, device=self.device)
        cos = wp.empty((T, E), dtype=wp.float32, device=self.device)
        strain = wp.empty((T, E), dtype=wp.float32, device=self.device)
        if T:
            wp.launch(k.face_measures, dim=(T, F), device=self.device, inputs=[pts, self._faces, self._rest_area],
                      outputs=[normals, area])
            wp.launch(k.edge_measures, dim=(T, E), device=self.device,
                      inputs=[pts, normals, self._edges, self._edge_faces, self._rest_length],
                      outputs=[cos, strain])
        return cos.numpy(), strain.numpy(), area.numpy()

    def skin(self, skins: np.ndarray) -> dict[str, np.ndarray]:
        """The SKIN_MEASURES of T frames (T, V, 3) metres: name -> (T,) float64."""
        cos, strain, area = self.edges(skins)
        strain = np.abs(strain)
        out = {"folded_edges": np.count_nonzero(cos < FOLDED_COS, axis=1),
               "sharp_edges": np.count_nonzero(cos < SHARP_COS, axis=1),
               "edge_strain_p99": _percentile(strain, 99.0), "edge_strain_max": _max(strain),
               "area_ratio_min": _min(area), "area_ratio_max": _max(area)}
        return {name: np.asarray(out[name], dtype=np.float64) for name in SKIN_MEASURES}

    def gradient(self, static: np.ndarray, final: np.ndarray) -> np.ndarray:
        """The jiggle displacement gradient (T, E) float32 of each edge (see the module)."""
        from jiggle.rig.skin import quality_kernels as k
        s, f = self._points(static, "static"), self._points(final, "final")
        if s.shape != f.shape:
            raise InputError(f"static and final skins differ in shape: {s.shape} and {f.shape}", field="final")
        out = wp.empty((s.shape[0], self.mesh.num_edges), dtype=wp.float32, device=self.device)
        if s.shape[0]:
            wp.launch(k.jiggle_gradient, dim=out.shape, device=self.device,
                      inputs=[s, f, self._edges, self._rest_length, GRADIENT_FLOOR], outputs=[out])
        return out.numpy()

    def jiggle(self, static: np.ndarray, final: np.ndarray) -> dict[str, np.ndarray]:
        """The JIGGLE_MEASURES of T frames: name -> (T,) float64."""
        g = self.gradient(static, final)
        out = {"gradient_p99": _percentile(g, 99.0), "gradient_p999": _percentile(g, 99.9),
               "gradient_max": _max(g), "torn_edges": np.count_nonzero(g > TORN, axis=1)}
        return {name: np.asarray(out[name], dtype=np.float64) for name in JIGGLE_MEASURES}

    def worst_vertex(self, skin: np.ndarray, static: np.ndarray | None = None) -> int:
        """The vertex of one frame (V, 3) with the most folded (and, given the static skin, torn) edges
        around it, weighted by how far past the threshold each is: where a close-up should look."""
        cos = self.edges(np.asarray(skin)[None])[0][0]
        bad = np.maximum(FOLDED_COS - cos, 0.0) + np.maximum(SHARP_COS - cos, 0.0) * 0.1
        if static is not None:
            bad = bad + np.maximum(self.gradient(np.asarray(static)[None], np.asarray(skin)[None])[0] - TORN, 0.0)
        score = np.zeros(self.mesh.num_vertices)
        np.add.at(score, self.mesh.edges[:, 0], bad)
        np.add.at(score, self.mesh.edges[:, 1], bad)
        # spread over the 1-ring once, so a cluster of bad edges outweighs a single one
        spread = score.copy()
        np.add.at(spread, self.mesh.edges[:, 0], score[self.mesh.edges[:, 1]])
        np.add.at(spread, self.mesh.edges[:, 1], score[self.mesh.edges[:, 0]])
        return int(np.argmax(spread))


def _percentile(x: np.ndarray, q: float) -> np.ndarray:
    return np.percentile(x, q, axis=1) if x.shape[1] else np.zeros(len(x))


def _max(x: np.ndarray) -> np.ndarray:
    return x.max(axis=1) if x.shape[1] else np.zeros(len(x))


def _min(x: np.ndarray) -> np.ndarray:
    return x.min(axis=1) if x.shape[1] else np.zeros(len(x))
