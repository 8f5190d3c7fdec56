"""Bake caches: one baked clip written as `.npz`, USD (`.usdc` / `.usda`) or `.pc2`.

`BakeData` is everything a bake produces, frozen and checked on construction (shapes agree,
every number finite, fps > 0, times strictly increasing), so no writer can put a NaN in a cache.
Every writer goes through `rig.base.atomic.atomic_path`: the file appears under its final name only
once it is complete; a failed or interrupted write leaves no file (or the previous one) there.

Axes and units are jiggle's own everywhere: metres, seconds, Z-up. USD stages say so
(metersPerUnit 1, upAxis Z); Blender is Z-up metres too, so `.pc2` points are written as they are.

The `.npz` layout (format key ``format = "jiggle.bake/1"``, T frames, V skin vertices, J joints,
M muscles, N muscle CVs in all):

=====================  ==========================  ============================================
key                    shape, dtype                meaning
=====================  ==========================  ============================================
format                 () str                      "jiggle.bake/1"
skin_static            (T, V, 3) float32           skin from skinning alone, static muscles; m
skin_final             (T, V, 3) float32           skin with the jiggled muscles; metres
skin_lbs               (T, V, 3) float32           the smooth skin underneath (LBS/DQS, no muscles);
                                                   metres; optional (bakes before it lack it)
skin_rest              (V, 3) float32              the character's rest (bind) skin; metres; optional
faces                  (F, 3) int32                skin triangles (indices into V)
part_names             (P,) str                    the meshes the skin was merged from (a glTF's
                                                   skinned meshes); optional
part_offsets           (P + 1,) int64              part p owns vertices offsets[p]:offsets[p+1]; optional
fps                    () float64                  output frames per second
times                  (T,) float64                seconds from the clip's start, increasing
joint_names            (J,) str                    the clip's own joint names
joint_world            (T, J, 4, 4) float32        joint world transforms, metres, Z-up
muscle_names           (M,) str                    muscle names
muscle_cvs_static      (T, N, 3) float32           static (goal) muscle CVs, metres
muscle_cvs_dynamic     (T, N, 3) float32           blended jiggled muscle CVs, metres
muscle_cv_offsets      (M + 1,) int64              muscle m owns CV rows offsets[m]:offsets[m+1]
muscle_faces           (F_m, 3) int32              one muscle's loft triangles (shared by all)
params                 () str                      the full parameter set as JSON text
=====================  ==========================  ============================================
"""
from __future__ import annotations

import contextlib
import json
import os
import struct
import zipfile
from dataclasses import dataclass, fields

import numpy as np

from rig.base.atomic import atomic_path
from rig.base.errors import InputError
from rig.base.frozen import frozen_array
from rig.character.normals import VertexNormals

FORMAT = "jiggle.bake/1"
PC2_MAGIC = b"POINTCACHE2\0"
PC2_VERSION = 1
_PC2_HEADER = struct.Struct("<12siiffi")  # magic, version, numPoints, startFrame, sampleRate, numSamples


@dataclass(frozen=True, eq=False)
class BakeData:
    """One baked clip (see the module for the npz keys). T frames, V skin vertices, J joints,
    M muscles, N muscle CVs in all. Arrays are read-only copies in the dtypes below.

    skin_static : (T, V, 3) float32 metres, the skin with static muscles.
    skin_final : (T, V, 3) float32 metres, the skin with the jiggled muscles.
    skin_lbs : (T, V, 3) float32 metres, the smooth skin underneath (LBS or DQS, no muscles), or None.
    skin_rest : (V, 3) float32 metres, the character's rest (bind) skin, or None.
    faces : (F, 3) int32, skin triangles.
    fps : output frames per second, > 0.
    times : (T,) float64 seconds from the clip's start, strictly increasing.
    joint_names : (J,) the clip's own joint names.
    joint_world : (T, J, 4, 4) float32, joint world transforms (metres, Z-up).
    muscle_names : (M,) muscle names.
    muscle_cvs_static : (T, N, 3) float32 metres, static (goal) CVs of all muscles.
    muscle_cvs_dynamic : (T, N, 3) float32 metres, the blended jiggled CVs.
    muscle_cv_offsets : (M + 1,) int64, muscle m owns CV rows offsets[m]:offsets[m + 1].
    muscle_faces : (F_m, 3) int32, one muscle's loft triangles (MuscleRig.surface_faces).
    params : the full parameter set as JSON text.
    part_names, part_offsets : the meshes the skin was merged from, (P,) names and (P + 1,) int64
        vertex offsets (part p owns vertices offsets[p]:offsets[p + 1], 0 to V), or None.
    """

    skin_static: np.ndarray
    skin_final: np.ndarray
    faces: np.ndarray
    fps: float
    times: np.ndarray
    joint_names: tuple
    joint_world: np.ndarray
    muscle_names: tuple
    muscle_cvs_static: np.ndarray
    muscle_cvs_dynamic: np.ndarray
    muscle_cv_offsets: np.ndarray
    muscle_faces: np.ndarray
    params: str
    skin_lbs: np.ndarray | None = None
    skin_rest: np.ndarray | None = None
    part_names: tuple | None = None
    part_offsets: np.ndarray | None = None

    def __post_init__(self):
        def put(name, value):
            object.__setattr__(self, name, value)

        def array(name, dtype, ndim):
            try:
                a = frozen_array(getattr(self, name), dtype)
            except (TypeError, ValueError) as e:
                raise InputError(f"not a {dtype.__name__} array: {e}", field=name) from None
            if a.ndim != ndim:
                raise InputError(f"expected {ndim} dimensions, got shape {a.shape}", field=name)
            put(name, a)
            return a

        skin = array("skin_static", np.float32, 3)
        T, V = skin.shape[:2]
        if T < 1 or skin.shape[2] != 3:
            raise InputError(f"expected shape (T >= 1, V, 3), got {skin.shape}", field="skin_static")
        self._shape("skin_final", array("skin_final", np.float32, 3), (T, V, 3))
        if self.skin_lbs is not None:
            self._shape("skin_lbs", array("skin_lbs", np.float32, 3), (T, V, 3))
        if self.skin_rest is not None:
            self._shape("skin_rest", array("skin_rest", np.float32, 2), (V, 3))
            require_finite("skin_rest", self.skin_rest[None], "vertex")
        faces = array("faces", np.int32, 2)
        self._indices("faces", faces, V)
        if (self.part_names is None) != (self.part_offsets is None):
            raise InputError("part_names and part_offsets come together", field="part_names")
        if self.part_names is not None:
            put("part_names", self._names("part_names"))
            po = array("part_offsets", np.int64, 1)
            self._shape("part_offsets", po, (len(self.part_names) + 1,))
            if po[0] != 0 or po[-1] != V or np.any(np.diff(po) < 0):
                raise InputError(f"must run from 0 to {V} (the vertices) without decreasing, got {po.tolist()}",
                                 field="part_offsets")
        try:
            fps = float(self.fps)
        except (TypeError, ValueError):
            raise InputError(f"expected a number, got {self.fps!r}", field="fps") from None
        if not np.isfinite(fps) or fps <= 0:
            raise InputError(f"must be a finite number > 0, got {fps}", field="fps")
        put("fps", fps)
        times = array("times", np.float64, 1)
        self._shape("times", times, (T,))
        if T > 1 and not np.all(np.diff(times) > 0):
            k = int(np.argmax(~(np.diff(times) > 0))) + 1
            raise InputError(f"must increase strictly; frame {k} is at {times[k]} s after "
                             f"{times[k - 1]} s", field="times")
        put("joint_names", self._names("joint_names"))
        J = len(self.joint_names)
        self._shape("joint_world", array("joint_world", np.float32, 4), (T, J, 4, 4))
        put("muscle_names", self._names("muscle_names"))
        M = len(self.muscle_names)
        offsets = array("muscle_cv_offsets", np.int64, 1)
        self._shape("muscle_cv_offsets", offsets, (M + 1,))
        if offsets[0] != 0 or np.any(np.diff(offsets) < 0):
            raise InputError(f"must start at 0 and not decrease, got {offsets.tolist()}",
                             field="muscle_cv_offsets")
        N = int(offsets[-1])
        for name in ("muscle_cvs_static", "muscle_cvs_dynamic"):
            self._shape(name, array(name, np.float32, 3), (T, N, 3))
        mfaces = array("muscle_faces", np.int32, 2)
        self._indices("muscle_faces", mfaces, None)
        if not isinstance(self.params, str):
            raise InputError(f"expected JSON text, got {type(self.params).__name__}", field="params")
        try:
            json.loads(self.params)
        except ValueError as e:
            raise InputError(f"not valid JSON: {e}", field="params") from None
        for name, item in (("skin_static", "vertex"), ("skin_final", "vertex"), ("skin_lbs", "vertex"),
                           ("times", None), ("joint_world", "joint"),
                           ("muscle_cvs_static", "CV"), ("muscle_cvs_dynamic", "CV")):
            require_finite(name, getattr(self, name), item)

    @property
    def num_frames(self) -> int:
        """T, the number of frames."""
        return self.skin_static.shape[0]

    def _shape(self, name, a, shape):
        if a.shape != shape:
            raise InputError(f"expected shape {shape}, got {a.shape}", field=name)

    def _indices(self, name, faces, count):
        if faces.shape[1] != 3:
            raise InputError(f"expected shape (F, 3), got {faces.shape}", field=name)
        if faces.size and (faces.min() < 0 or (count is not None and faces.max() >= count)):
            raise InputError(f"indices must lie in [0, {count}), found [{faces.min()}, "
                             f"{faces.max()}]", field=name)

    def _names(self, name) -> tuple:
        value = getattr(self, name)
        names = tuple(np.asarray(value, dtype=object).ravel().tolist()) if not isinstance(
            value, (list, tuple)) else tuple(value)
        if not all(isinstance(n, str) for n in names):
            raise InputError("expected a list of strings", field=name)
        return names


def require_finite(name: str, a: np.ndarray | None, item: str | None) -> None:
    """Raise InputError naming `name`, the frame and the `item` (vertex, joint, CV) of the first
    non-finite number in `a` (frame-major: axis 0 is the frame, axis 1 the item); None passes."""
    if a is None:
        return
    bad = ~np.isfinite(a)
    if not bad.any():
        return
    where = np.argwhere(bad)[0]
    value = a[tuple(where)]
    at = f"frame {where[0]}" + (f", {item} {where[1]}" if item and len(where) > 1 else "")
    raise InputError(f"not finite ({value}) at {at}; nothing was written", field=name)


# ---------------------------------------------------------------------------------------- npz
_NPZ_KEYS = tuple(f.name for f in fields(BakeData))
_OPTIONAL_KEYS = ("skin_lbs", "skin_rest", "part_names", "part_offsets")


def write_npz(data: BakeData, path: str | os.PathLike, compress: bool = True) -> None:
    """Write `data` to `path` as a `.npz` (the keys in the module docstring), atomically; compress
    False stores the arrays as they are (faster to write and read; skin positions shrink only ~10%)."""
    arrays = {"format": np.array(FORMAT)}
    for name in _NPZ_KEYS:
        value = getattr(data, name)
        if value is None:
            continue
        if name in ("joint_names", "muscle_names", "part_names"):
            value = np.array(value, dtype=str).reshape(-1)
        elif name in ("fps", "params"):
            value = np.array(value)
        arrays[name] = value
    with _writing(path) as tmp:
        with open(tmp, "wb") as fh:  # a file object: savez would append ".npz" to other names
            (np.savez_compressed if compress else np.savez)(fh, **arrays)


def read_npz(path: str | os.PathLike) -> BakeData:
    """Read a `.npz` written by `write_npz`; InputError names the file and the key for a wrong
    format, a missing key or bad contents."""
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise InputError("bake cache not found", path)
    try:
        with np.load(path, allow_pickle=False) as npz:
            stored = {k: npz[k] for k in npz.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as e:
        raise InputError(f"not a readable .npz file: {e}", path) from None
    if "format" not in stored:
        raise InputError(f"missing key; expected a jiggle bake cache ({FORMAT})", path, field="format")
    fmt = str(stored["format"])
    if fmt != FORMAT:
        raise InputError(f"unsupported format {fmt!r}, expected {FORMAT!r}", path, field="format")
    missing = [k for k in _NPZ_KEYS if k not in stored and k not in _OPTIONAL_KEYS]
    if missing:
        raise InputError(f"missing key (the file lacks {', '.join(missing)})", path, field=missing[0])
    values = {k: stored[k] for k in _NPZ_KEYS if k in stored}
    values["fps"] = values["fps"].item() if values["fps"].shape == () else values["fps"]
    values["params"] = str(values["params"]) if values["params"].shape == () else values["params"]
    for k in ("joint_names", "muscle_names", "part_names"):
        if k not in values:
            continue
        if values[k].dtype.kind != "U":
            raise InputError(f"expected strings, got dtype {values[k].dtype}", path, field=k)
        values[k] = tuple(values[k].tolist())
    try:
        return BakeData(**values)
    except InputError as e:
        raise InputError(e.message, path, field=e.field) from None


# ---------------------------------------------------------------------------------------- pc2
@dataclass(frozen=True, eq=False)
class PointCache:
    """A `.pc2` point cache as read back.

    points : (T, V, 3) float32 metres, Z-up.
    start_frame : the first sample's frame (start_time * fps).
    sample_rate : frames between samples (1.0 as jiggle writes them).
    """

    points: np.ndarray
    start_frame: float
    sample_rate: float


def write_pc2(points, path: str | os.PathLike, fps: float, start_time: float = 0.0) -> None:
    """Write points (T, V, 3) float32 metres as a `.pc2` point cache (Blender / 3ds Max), atomically.

    Layout (little-endian): b"POINTCACHE2\\0" (12 bytes), int32 version 1, int32 numPoints V,
    float32 startFrame = start_time * fps, float32 sampleRate = 1.0 (one sample every frame at fps),
    int32 numSamples T, then T * V * 3 float32, frame-major. Axes are written as they are: jiggle
    and Blender are both Z-up metres (3ds Max too, in its system units set to metres).
    """
    p = np.asarray(points)
    if p.ndim != 3 or p.shape[2] != 3 or p.shape[0] < 1:
        raise InputError(f"expected shape (T >= 1, V, 3), got {p.shape}", field="points")
    p = np.ascontiguousarray(p, dtype="<f4")
    require_finite("points", p, "vertex")
    fps, start_time = float(fps), float(start_time)
    if not np.isfinite(fps) or fps <= 0:
        raise InputError(f"must be a finite number > 0, got {fps}", field="fps")
    if not np.isfinite(start_time):
        raise InputError(f"must be finite, got {start_time}", field="start_time")
    header = _PC2_HEADER.pack(PC2_MAGIC, PC2_VERSION, p.shape[1], start_time * fps, 1.0, p.shape[0])
    with _writing(path) as tmp:
        with open(tmp, "wb") as fh:
            fh.write(header)
            _write_frames(fh, p)


def _write_frames(fh, p: np.ndarray) -> None:
    """Write the (T, V, 3) little-endian float32 samples frame by frame (frame-major)."""
    for frame in p:
        fh.write(frame.tobytes())


def read_pc2(path: str | os.PathLike) -> PointCache:
    """Read a `.pc2` point cache; InputError names the file for a bad header or a short file."""
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise InputError("point cache not found", path)
    with open(path, "rb") as fh:
        raw = fh.read()
    if len(raw) < _PC2_HEADER.size:
        raise InputError(f"file too short for a PC2 header ({len(raw)} bytes)", path)
    magic, version, V, start, rate, T = _PC2_HEADER.unpack_from(raw)
    if magic != PC2_MAGIC:
        raise InputError(f"not a PC2 file (starts with {magic!r})", path, field="header")
    if version != PC2_VERSION:
        raise InputError(f"unsupported PC2 version {version}", path, field="version")
    body = len(raw) - _PC2_HEADER.size
    if V < 0 or T < 0 or body != T * V * 12:
        raise InputError(f"header says {T} samples of {V} points ({T * V * 12} bytes), file holds "
                         f"{body} bytes", path, field="numSamples")
    pts = np.frombuffer(raw, "<f4", offset=_PC2_HEADER.size).reshape(T, V, 3).astype(np.float32)
    return PointCache(frozen_array(pts, np.float32), float(start), float(rate))


# ---------------------------------------------------------------------------------------- USD
def write_usd(data: BakeData, path: str | os.PathLike, muscle_points=None,
              usda: bool | None = None) -> None:
    """Write `data` as a USD stage, atomically; the format follows `path`'s suffix (`.usdc`,
    `.usda`; `.usd` is crate unless usda=True). `usda` True/False forces text/crate and must not
    contradict a `.usda`/`.usdc` suffix.

    The stage: metersPerUnit 1, upAxis Z, timeCodesPerSecond = framesPerSecond = data.fps, time
    code k = frame k (startTimeCode 0, endTimeCode T - 1; data.times[k] is that frame's time in
    the clip). Default prim /jiggle holds /jiggle/skin_static and /jiggle/skin_final, meshes
    (subdivisionScheme none) with time-sampled points, area-weighted vertex normals and extent, and,
    when the skin was merged from several meshes (data.part_names), one face GeomSubset per part
    (family "part", named as the part, its name also in the subset's jiggle:name);
    with muscle_points, /jiggle/muscles/<name> meshes (triangles data.muscle_faces) likewise.
    The root layer's customLayerData holds jiggle:format and jiggle:params (the JSON text).

    muscle_points : (T, M, P, 3) float32 metres, each muscle's lofted surface per frame
        (MuscleRig.surface of the dynamic CVs), or None for no muscle meshes.
    """
    from pxr import Sdf, Tf, Usd, UsdGeom

    path = os.fspath(path)
    fmt = _usd_format(path, usda)
    T = data.num_frames
    muscles = None
    if muscle_points is not None:
        muscles = np.asarray(muscle_points, dtype=np.float32)
        M = len(data.muscle_names)
        if muscles.ndim != 4 or muscles.shape[:2] != (T, M) or muscles.shape[3] != 3:
            raise InputError(f"expected shape ({T}, {M}, P, 3), got {muscles.shape}",
                             field="muscle_points")
        if data.muscle_faces.size and data.muscle_faces.max() >= muscles.shape[2]:
            raise InputError(f"muscle_faces index {data.muscle_faces.max()} but only "
                             f"{muscles.shape[2]} points per muscle", field="muscle_points")
        require_finite("muscle_points", muscles.reshape(T, -1, 3), "point")

    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    stage.SetTimeCodesPerSecond(data.fps)
    stage.SetFramesPerSecond(data.fps)
    stage.SetStartTimeCode(0)
    stage.SetEndTimeCode(T - 1)
    root = UsdGeom.Xform.Define(stage, "/jiggle")
    stage.SetDefaultPrim(root.GetPrim())
    stage.GetRootLayer().customLayerData = {"jiggle:format": FORMAT, "jiggle:params": data.params}
    for name in ("skin_static", "skin_final"):
        mesh = _define_mesh(stage, f"/jiggle/{name}", getattr(data, name), data.faces)
        if data.part_names is not None:
            _part_subsets(mesh, data)
    if muscles is not None:
        UsdGeom.Scope.Define(stage, "/jiggle/muscles")
        used = set()
        for m, name in enumerate(data.muscle_names):
            ident = Tf.MakeValidIdentifier(name)
            base, k = ident, 1
            while ident in used:
                ident, k = f"{base}_{k}", k + 1
            used.add(ident)
            mesh = _define_mesh(stage, f"/jiggle/muscles/{ident}", muscles[:, m], data.muscle_faces)
            mesh.GetPrim().CreateAttribute("jiggle:name", Sdf.ValueTypeNames.String,
                                           custom=True).Set(name)
    with _writing(path) as tmp:
        _export(stage.GetRootLayer(), tmp, fmt)


def _part_subsets(mesh, data: BakeData) -> None:
    """One face GeomSubset per part of the skin (family "part"): a face belongs to the part of its
    first vertex (the reader never joins two meshes in one face)."""
    from pxr import Sdf, Tf, UsdGeom, Vt
    part = np.searchsorted(data.part_offsets, data.faces[:, 0], side="right") - 1
    used = set()
    for p, name in enumerate(data.part_names):
        ident, k = Tf.MakeValidIdentifier(name), 1
        base = ident
        while ident in used:
            ident, k = f"{base}_{k}", k + 1
        used.add(ident)
        faces = np.flatnonzero(part == p).astype(np.int32)
        subset = UsdGeom.Subset.CreateGeomSubset(mesh, ident, UsdGeom.Tokens.face, Vt.IntArray.FromNumpy(faces),
                                                 "part", UsdGeom.Tokens.partition)
        subset.GetPrim().CreateAttribute("jiggle:name", Sdf.ValueTypeNames.String, custom=True).Set(name)


def _usd_format(path: str, usda: bool | None) -> str:
    """'usda' or 'usdc' for `path` (suffix .usd, .usda or .usdc) and the caller's wish."""
    ext = os.path.splitext(path)[1].lower()
    if ext not in (".usd", ".usda", ".usdc"):
        raise InputError(f"expected a .usd, .usda or .usdc file, got suffix {ext!r}", path)
    if ext == ".usd":
        return "usda" if usda else "usdc"
    fmt = ext[1:]
    if usda is not None and (fmt == "usda") != bool(usda):
        raise InputError(f"usda={usda} contradicts the suffix {ext}", path)
    return fmt


def _define_mesh(stage, prim_path: str, points: np.ndarray, faces: np.ndarray):
    """A UsdGeom.Mesh at prim_path: triangles faces (F, 3), points (T, V, 3) float32 metres
    sampled at time codes 0..T-1, with vertex normals and extent per sample."""
    from pxr import UsdGeom, Vt

    mesh = UsdGeom.Mesh.Define(stage, prim_path)
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    mesh.CreateOrientationAttr(UsdGeom.Tokens.rightHanded)
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(faces), 3, np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(
        np.ascontiguousarray(faces, dtype=np.int32).reshape(-1)))
    normals = VertexNormals(faces, points.shape[1]).batch(np.asarray(points, dtype=np.float32))
    pts_attr, n_attr, ext_attr = (mesh.CreatePointsAttr(), mesh.CreateNormalsAttr(),
                                  mesh.CreateExtentAttr())
    mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    points = np.ascontiguousarray(points, dtype=np.float32)
    extent = np.stack([points.min(axis=1), points.max(axis=1)], axis=1) if points.shape[1] else None
    for k in range(points.shape[0]):
        pts_attr.Set(Vt.Vec3fArray.FromNumpy(points[k]), k)
        n_attr.Set(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(normals[k])), k)
        if extent is not None:
            ext_attr.Set(Vt.Vec3fArray.FromNumpy(extent[k]), k)
    return mesh


def _export(layer, tmp: str, fmt: str) -> None:
    """Export `layer` to the file `tmp` in format fmt ('usda' or 'usdc'); raise OSError on failure."""
    from pxr import Tf

    try:
        ok = layer.Export(tmp, args={"format": fmt})
    except Tf.ErrorException as e:
        raise OSError(f"USD export failed: {e}") from None
    if not ok:
        raise OSError("USD export failed")


# ------------------------------------------------------------------------------------- shared
@contextlib.contextmanager
def _writing(path):
    """atomic_path(path), with an OSError (unwritable folder, disk full, failed export) turned into
    an InputError naming `path`; on any failure nothing new is left at `path`."""
    path = os.fspath(path)
    try:
        with atomic_path(path) as tmp:
            yield tmp
    except OSError as e:
        raise InputError(f"cannot write the file: {e.strerror or e}", path) from None
