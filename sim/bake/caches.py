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
chain_names            (Jc,) str                   the joints the swung chains move (sim.chain);
                                                   optional, with the four below
chain_world            (T, Jc, 4, 4) float32       their swung world transforms, metres (the
                                                   animated ones are the character's: joint_world
                                                   or the drive's)
chain_tip_names        (C,) str                    the chains (their root joints' names)
chain_tips_static      (T, C, 3) float32           each chain's tip where the animation puts it, m
chain_tips_final       (T, C, 3) float32           and where it swung to; metres
chain_vertices         (Vc,) int64                 the skin vertices the chains move
chain_weight           (Vc,) float32               their skin weight on chain joints (below 1: a
                                                   chain's root, where it blends into the body)
chain_delta            (T, Vc, 3) float32          what the swing adds to them (skin_final holds
                                                   it: skin_static + chain_delta is the skin that
                                                   follows the swung chains without tissue jiggle)
activation             (T, M) float32              each muscle's activation in [0, 1], from the
                                                   clip's joint torques (--activation on; fat 0);
                                                   optional
=====================  ==========================  ============================================
"""
from __future__ import annotations

import contextlib
import io
import json
import os
import struct
import zipfile
import zlib
from dataclasses import dataclass, fields

import numpy as np

from jiggle.rig.base.atomic import atomic_path
from jiggle.rig.base.errors import InputError
from jiggle.rig.base.frozen import frozen_array
from jiggle.rig.character.normals import VertexNormals

FORMAT = "jiggle.bake/1"
PC2_MAGIC = b"POINTCACHE2\0"
PC2_VERSION = 1
_PC2_HEADER = struct.Struct("<12siiffi")  # magic, version, numPoints, startFrame, sampleRate, numSamples
PC2_HEADER_BYTES = _PC2_HEADER.size


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
    chain_names, chain_world : the joints the swung chains move (Jc,) and their world transforms (T, Jc, 4, 4)
        float32 metres; chain_tip_names (C,) the chains, chain_tips_static and chain_tips_final (T, C, 3) float32
        metres their tips animated and swung; chain_vertices (Vc,) int64 the skin vertices they move, chain_weight
        (Vc,) their skin weight on chain joints and chain_delta (T, Vc, 3) float32 metres what the swing adds to
        them (in skin_final); all None without chains.
    activation : (T, M) float32 in [0, 1], each muscle's activation from the clip's own joint torques
        (sim.jiggle.activation, `--activation on`), or None.
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
    chain_names: tuple | None = None
    chain_world: np.ndarray | None = None
    chain_tip_names: tuple | None = None
    chain_tips_static: np.ndarray | None = None
    chain_tips_final: np.ndarray | None = None
    chain_vertices: np.ndarray | None = None
    chain_delta: np.ndarray | None = None
    chain_weight: np.ndarray | None = None
    activation: np.ndarray | None = None

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
        chain = ("chain_names", "chain_world", "chain_tip_names", "chain_tips_static", "chain_tips_final",
                 "chain_vertices", "chain_delta")
        given = [getattr(self, k) is not None for k in chain]
        if any(given) and not all(given):
            raise InputError(f"{', '.join(chain)} come together", field=chain[given.index(False)])
        if all(given):
            put("chain_names", self._names("chain_names"))
            put("chain_tip_names", self._names("chain_tip_names"))
            self._shape("chain_world", array("chain_world", np.float32, 4), (T, len(self.chain_names), 4, 4))
            for k in chain[3:5]:
                self._shape(k, array(k, np.float32, 3), (T, len(self.chain_tip_names), 3))
            cv = array("chain_vertices", np.int64, 1)
            if cv.size and (cv.min() < 0 or cv.max() >= V):
                raise InputError(f"indices must lie in [0, {V})", field="chain_vertices")
            self._shape("chain_delta", array("chain_delta", np.float32, 3), (T, len(cv), 3))
        if self.chain_weight is not None:           # optional within the chains' arrays (bakes before it lack it)
            if self.chain_vertices is None:
                raise InputError("comes with chain_vertices", field="chain_weight")
            self._shape("chain_weight", array("chain_weight", np.float32, 1), (len(self.chain_vertices),))
        if self.activation is not None:
            a = array("activation", np.float32, 2)
            self._shape("activation", a, (T, len(self.muscle_names)))
            if a.size and np.isfinite(a).all() and (a.min() < 0.0 or a.max() > 1.0):
                raise InputError(f"activations must lie in [0, 1], got {a.min():g} to {a.max():g}", field="activation")
        for name, item in (("skin_static", "vertex"), ("skin_final", "vertex"), ("skin_lbs", "vertex"),
                           ("times", None), ("joint_world", "joint"), ("chain_world", "joint"),
                           ("chain_tips_static", "chain"), ("chain_tips_final", "chain"), ("chain_delta", "vertex"),
                           ("muscle_cvs_static", "CV"), ("muscle_cvs_dynamic", "CV"), ("activation", "muscle")):
            require_finite(name, getattr(self, name), item)

    def skin_swung(self) -> np.ndarray:
        """(T, V, 3) float32 metres: the skin that follows the swung chains without tissue jiggle (skin_static plus
        chain_delta; skin_static itself without chains). What the tissue's jiggle is measured from."""
        if self.chain_vertices is None or not len(self.chain_vertices):
            return self.skin_static
        out = np.array(self.skin_static)
        out[:, self.chain_vertices] += self.chain_delta
        return out

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


def require_finite(name: str, a: np.ndarray | None, item: str | None, first: int = 0) -> None:
    """Raise InputError naming `name`, the frame (a's axis 0 counted from `first`) and the `item`
    (vertex, joint, CV) of the first non-finite number in `a` (frame-major: axis 1 is the item);
    None passes."""
    if a is None:
        return
    bad = ~np.isfinite(a)
    if not bad.any():
        return
    where = np.argwhere(bad)[0]
    value = a[tuple(where)]
    at = f"frame {first + where[0]}" + (f", {item} {where[1]}" if item and len(where) > 1 else "")
    raise InputError(f"not finite ({value}) at {at}; nothing was written", field=name)


# ---------------------------------------------------------------------------------------- npz
NPZ_KEYS = tuple(f.name for f in fields(BakeData))
_OPTIONAL_KEYS = ("skin_lbs", "skin_rest", "part_names", "part_offsets", "chain_names", "chain_world", "chain_tip_names",
                  "chain_tips_static", "chain_tips_final", "chain_vertices", "chain_delta", "chain_weight", "activation")
FRAME_KEYS = {"skin_static": "vertex", "skin_final": "vertex", "skin_lbs": "vertex", "joint_world": "joint",
              "muscle_cvs_static": "CV", "muscle_cvs_dynamic": "CV", "times": None, "chain_world": "joint",
              "chain_tips_static": "chain", "chain_tips_final": "chain", "chain_delta": "vertex", "activation": "muscle"}
"""The npz keys with one row per frame (a bake writes them chunk by chunk), and what their axis 1 counts."""


def npz_arrays(data: BakeData) -> dict:
    """BakeData's npz members (format first, then NPZ_KEYS, optional ones only when set)."""
    arrays = {"format": np.array(FORMAT)}
    for name in NPZ_KEYS:
        value = getattr(data, name)
        if value is None:
            continue
        if name in ("joint_names", "muscle_names", "part_names", "chain_names", "chain_tip_names"):
            value = np.array(value, dtype=str).reshape(-1)
        elif name in ("fps", "params"):
            value = np.array(value)
        arrays[name] = value
    return arrays


def write_npz(data: BakeData, path: str | os.PathLike, compress: bool = True) -> None:
    """Write `data` to `path` as a `.npz` (the keys in the module docstring), atomically; compress
    False stores the arrays as they are (faster to write and read; skin positions shrink only ~10%).
    A bake writes its npz chunk by chunk instead (NpzInPlace)."""
    with _writing(path) as tmp:
        with open(tmp, "wb") as fh:  # a file object: savez would append ".npz" to other names
            (np.savez_compressed if compress else np.savez)(fh, **npz_arrays(data))


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
    missing = [k for k in NPZ_KEYS if k not in stored and k not in _OPTIONAL_KEYS]
    if missing:
        raise InputError(f"missing key (the file lacks {', '.join(missing)})", path, field=missing[0])
    values = {k: stored[k] for k in NPZ_KEYS if k in stored}
    values["fps"] = values["fps"].item() if values["fps"].shape == () else values["fps"]
    values["params"] = str(values["params"]) if values["params"].shape == () else values["params"]
    for k in ("joint_names", "muscle_names", "part_names", "chain_names", "chain_tip_names"):
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
    and Blender are both Z-up metres (3ds Max too, in its system units set to metres). A bake
    writes its pc2 chunk by chunk instead, each frame at its offset (sim/bake/writer.py).
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
    header = pc2_header(p.shape[1], p.shape[0], fps, start_time)
    with _writing(path) as tmp:
        with open(tmp, "wb") as fh:
            fh.write(header)
            _write_frames(fh, p)


def pc2_header(V: int, T: int, fps: float, start_time: float) -> bytes:
    """The 32-byte `.pc2` header of T samples of V points at fps, the first at start_time seconds."""
    return _PC2_HEADER.pack(PC2_MAGIC, PC2_VERSION, int(V), float(start_time) * float(fps), 1.0, int(T))


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
    path = os.fspath(path)
    fmt = _usd_format(path, usda)
    T = data.num_frames
    block = {"skin_static": data.skin_static, "skin_final": data.skin_final}
    if muscle_points is not None:
        block["muscles"] = np.asarray(muscle_points, dtype=np.float32)
        require_finite("muscle_points", block["muscles"], "muscle")
    with _writing(path) as tmp:
        usd = UsdAppender(tmp, data, T, None if muscle_points is None else block["muscles"].shape, fmt)
        usd.append(0, block)
        usd.finish()


class UsdAppender:
    """A bake's USD stage (see write_usd) written block by block into the file `path` (the caller's
    temporary name; its suffix must be a USD one).

    A crate file (fmt "usdc") is authored through the Sdf layer API (each block's time samples in one
    change block, `Vt.Vec3fArray.FromNumpy`) and saved after every block: the crate writer appends the
    new samples and drops them from memory, so memory holds one block whatever the clip's length.
    A text file ("usda") is exported whole by `finish` (text cannot be appended; it is meant for small
    clips and for reading).

    head : a BakeData for the stage's faces, parts, names, fps and params (its frames are not written).
    T : frames in all. muscles : (T, M, P, 3), the shape of the muscle meshes' points, or None for none.
    """

    def __init__(self, path: str, head: BakeData, T: int, muscles: tuple | None, fmt: str):
        from pxr import Sdf, Usd, UsdGeom

        self.path, self.fmt, self.T = path, fmt, int(T)
        M = len(head.muscle_names)
        if muscles is not None:
            if len(muscles) != 4 or tuple(muscles[:2]) != (T, M) or muscles[3] != 3:
                raise InputError(f"expected shape ({T}, {M}, P, 3), got {tuple(muscles)}", field="muscle_points")
            if head.muscle_faces.size and head.muscle_faces.max() >= muscles[2]:
                raise InputError(f"muscle_faces index {head.muscle_faces.max()} but only "
                                 f"{muscles[2]} points per muscle", field="muscle_points")
        self.layer = layer = Sdf.Layer.CreateNew(path) if fmt == "usdc" else Sdf.Layer.CreateAnonymous(".usda")
        stage = Usd.Stage.Open(layer)
        UsdGeom.SetStageMetersPerUnit(stage, 1.0)
        UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
        stage.SetTimeCodesPerSecond(head.fps)
        stage.SetFramesPerSecond(head.fps)
        stage.SetStartTimeCode(0)
        stage.SetEndTimeCode(T - 1)
        root = UsdGeom.Xform.Define(stage, "/jiggle")
        stage.SetDefaultPrim(root.GetPrim())
        layer.customLayerData = {"jiggle:format": FORMAT, "jiggle:params": head.params}
        self.targets = []                  # (prim path, key of its block, muscle or None)
        for name in ("skin_static", "skin_final"):
            mesh = _define_mesh_prim(stage, f"/jiggle/{name}", head.faces)
            if head.part_names is not None:
                _part_subsets(mesh, head)
            self.targets.append((f"/jiggle/{name}", name, None))
        if muscles is not None:
            UsdGeom.Scope.Define(stage, "/jiggle/muscles")
            for m, (name, ident) in enumerate(zip(head.muscle_names, _identifiers(head.muscle_names))):
                mesh = _define_mesh_prim(stage, f"/jiggle/muscles/{ident}", head.muscle_faces)
                mesh.GetPrim().CreateAttribute("jiggle:name", Sdf.ValueTypeNames.String, custom=True).Set(name)
                self.targets.append((f"/jiggle/muscles/{ident}", "muscles", m))
        del stage                          # from here on samples go straight into the layer
        self.skin_normals = VertexNormals(head.faces, len(head.skin_static[0]))
        self.muscle_normals = VertexNormals(head.muscle_faces, muscles[2]) if muscles is not None else None
        self.done = 0

    def append(self, k0: int, block: dict) -> None:
        """Frames k0, k0 + 1, ... (they must go on from the frames so far): block {"skin_static": (t, V, 3),
        "skin_final": (t, V, 3), "muscles": (t, M, P, 3) when the stage has muscles} float32 metres."""
        from pxr import Sdf

        t = len(block["skin_static"])
        if k0 != self.done or any(len(b) != t for b in block.values()) or k0 + t > self.T:
            raise InputError(f"frames {k0}..{k0 + t - 1} do not go on from frame {self.done} (of {self.T}), or the "
                             "meshes' blocks hold different frames", field="meshes")
        if self.muscle_normals is not None:    # every muscle's normals in one batch (t * M meshes)
            mp = np.ascontiguousarray(block["muscles"], dtype=np.float32)
            mn = self.muscle_normals.batch(mp.reshape((-1,) + mp.shape[2:])).reshape(mp.shape)
        with Sdf.ChangeBlock():
            for prim, key, m in self.targets:
                if m is None:
                    pts = np.ascontiguousarray(block[key], dtype=np.float32)
                    _author_samples(self.layer, prim, pts, self.skin_normals.batch(pts), k0)
                else:
                    _author_samples(self.layer, prim, mp[:, m], mn[:, m], k0)
        if self.fmt == "usdc":
            _save_layer(self.layer)
        self.done = k0 + t

    def finish(self) -> None:
        """Check every frame is there and write what is left (the text file)."""
        if self.done != self.T:
            raise InputError(f"holds {self.done} of {self.T} frames", self.path, field="meshes")
        if self.fmt == "usda":
            _export(self.layer, self.path, self.fmt)
        self.layer = None


def _identifiers(names) -> list[str]:
    """Valid, distinct USD prim names for `names` (a clash gets _1, _2, ...)."""
    from pxr import Tf
    used, out = set(), []
    for name in names:
        ident = base = Tf.MakeValidIdentifier(name)
        k = 1
        while ident in used:
            ident, k = f"{base}_{k}", k + 1
        used.add(ident)
        out.append(ident)
    return out


def _part_subsets(mesh, data: BakeData) -> None:
    """One face GeomSubset per part of the skin (family "part"): a face belongs to the part of its
    first vertex (the reader never joins two meshes in one face)."""
    from pxr import Sdf, UsdGeom, Vt
    part = np.searchsorted(data.part_offsets, data.faces[:, 0], side="right") - 1
    for p, (name, ident) in enumerate(zip(data.part_names, _identifiers(data.part_names))):
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


def _define_mesh_prim(stage, prim_path: str, faces: np.ndarray):
    """A UsdGeom.Mesh at prim_path with triangles faces (F, 3) and its points, normals (vertex
    interpolation) and extent attributes created, to be time-sampled (_author_samples)."""
    from pxr import UsdGeom, Vt

    mesh = UsdGeom.Mesh.Define(stage, prim_path)
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    mesh.CreateOrientationAttr(UsdGeom.Tokens.rightHanded)
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(faces), 3, np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(
        np.ascontiguousarray(faces, dtype=np.int32).reshape(-1)))
    mesh.CreatePointsAttr()
    mesh.CreateNormalsAttr()
    mesh.CreateExtentAttr()
    mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    return mesh


def _author_samples(layer, prim_path: str, points: np.ndarray, normals: np.ndarray, k0: int) -> None:
    """Time samples k0, k0 + 1, ... of a mesh's points and vertex normals (t, V, 3) float32 and its
    extent, written into `layer` at the Sdf level (no stage change processing)."""
    from pxr import Sdf, Vt

    points = np.ascontiguousarray(points, dtype=np.float32)
    normals = np.ascontiguousarray(normals, dtype=np.float32)
    pts_path, n_path, ext_path = (Sdf.Path(f"{prim_path}.{a}") for a in ("points", "normals", "extent"))
    extent = np.stack([points.min(axis=1), points.max(axis=1)], axis=1) if points.shape[1] else None
    for k in range(points.shape[0]):
        layer.SetTimeSample(pts_path, k0 + k, Vt.Vec3fArray.FromNumpy(points[k]))
        layer.SetTimeSample(n_path, k0 + k, Vt.Vec3fArray.FromNumpy(normals[k]))
        if extent is not None:
            layer.SetTimeSample(ext_path, k0 + k, Vt.Vec3fArray.FromNumpy(extent[k]))


def _save_layer(layer) -> None:
    """Save a crate layer to its file (appending what changed); raise OSError on failure."""
    from pxr import Tf

    try:
        ok = layer.Save()
    except Tf.ErrorException as e:
        raise OSError(f"USD save failed: {e}") from None
    if not ok:
        raise OSError("USD save failed")


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


# --------------------------------------------------------------------------- npz filled in place
_ZIP_LOCAL = struct.Struct("<IHHHHHIIIHH")
_ZIP_CENTRAL = struct.Struct("<IHHHHHHIIIHHHHHII")
_ZIP64_END = struct.Struct("<IQHHIIQQQQ")
_ZIP64_LOCATOR = struct.Struct("<IIQI")
_ZIP_END = struct.Struct("<IHHHHIIH")
_ZIP_VERSION = 45                      # zip64
_ZIP_TIME, _ZIP_DATE = 0, (2020 - 1980) << 9 | 1 << 5 | 1      # a fixed stamp: the same bake, the same bytes


class NpzInPlace:
    """A `.npz` whose layout is fixed when it is created (every member's shape known) and whose frame
    members are then filled block by block at their offsets: a bake writes each chunk once, straight
    into its cache, and can go on after an interruption (`open` an existing file and the CRCs so far).

    members : {name: array (written at once) or (shape, dtype) (a frame member, filled by `write`)}, in
        order. Every member is stored uncompressed with zip64 sizes, so np.load and any zip tool read it.
    crcs, frames : None for a new file; else each frame member's CRC-32 and frames written so far
        (from `progress()` of the run that was interrupted), to go on with the file at `path`.
    """

    def __init__(self, path: str, members: dict, crcs: dict | None = None, frames: dict | None = None):
        self.path = path
        self.entries = []               # (name, header offset, data offset, size, npy header bytes | array bytes)
        self.frame_shape, self.frame_bytes, self.crc, self.done = {}, {}, {}, {}
        offset = 0
        for name, value in members.items():
            fname = f"{name}.npy".encode()
            if isinstance(value, tuple):
                shape, dtype = tuple(int(n) for n in value[0]), np.dtype(value[1])
                buf = io.BytesIO()
                np.lib.format.write_array_header_1_0(buf, {"descr": np.lib.format.dtype_to_descr(dtype),
                                                           "fortran_order": False, "shape": shape})
                head = buf.getvalue()
                size = len(head) + int(np.prod(shape)) * dtype.itemsize
                self.frame_shape[name], self.frame_bytes[name] = (shape, dtype), int(np.prod(shape[1:])) * dtype.itemsize
                self.crc[name], self.done[name] = zlib.crc32(head), 0
            else:
                buf = io.BytesIO()
                np.lib.format.write_array(buf, np.asanyarray(value), allow_pickle=False)
                head = buf.getvalue()
                size = len(head)
            data = offset + _ZIP_LOCAL.size + len(fname) + 20
            self.entries.append((name, fname, offset, data, size, head))
            offset = data + size
        self.end = offset
        if crcs is None:
            with open(path, "wb") as fh:
                for name, fname, at, data, size, head in self.entries:
                    fh.seek(at)
                    fh.write(self._local(fname, zlib.crc32(head) if name not in self.frame_shape else 0, size))
                    fh.write(head)
                fh.truncate(self.end)
        else:
            if os.path.getsize(path) < self.end:
                raise InputError("the unfinished cache is shorter than its layout", path)
            for name in self.frame_shape:
                self.crc[name], self.done[name] = int(crcs[name]), int(frames[name])
        self._fh = open(path, "r+b")

    @staticmethod
    def _local(fname: bytes, crc: int, size: int) -> bytes:
        return (_ZIP_LOCAL.pack(0x04034B50, _ZIP_VERSION, 0, 0, _ZIP_TIME, _ZIP_DATE, crc, 0xFFFFFFFF, 0xFFFFFFFF,
                                len(fname), 20) + fname + struct.pack("<HHQQ", 1, 16, size, size))

    def write(self, name: str, first: int, block: np.ndarray) -> None:
        """Frames first, first + 1, ... of frame member `name` (they must go on from the frames written)."""
        shape, dtype = self.frame_shape[name]
        b = np.ascontiguousarray(block, dtype=dtype)
        if b.shape[1:] != shape[1:] or first != self.done[name] or first + len(b) > shape[0]:
            raise InputError(f"block {b.shape} at frame {first} does not continue {shape} after frame "
                             f"{self.done[name]}", self.path, field=name)
        entry = next(e for e in self.entries if e[0] == name)
        raw = memoryview(b).cast("B")
        self._fh.seek(entry[3] + len(entry[5]) + first * self.frame_bytes[name])
        self._fh.write(raw)
        self.crc[name] = zlib.crc32(raw, self.crc[name])
        self.done[name] = first + len(b)

    def progress(self) -> tuple[dict, dict]:
        """({member: CRC-32 so far}, {member: frames written}), to go on later (see the class)."""
        self._fh.flush()
        return dict(self.crc), dict(self.done)

    def read(self, name: str, f0: int, f1: int) -> np.ndarray:
        """Frames [f0, f1) of frame member `name` as written so far."""
        shape, dtype = self.frame_shape[name]
        entry = next(e for e in self.entries if e[0] == name)
        self._fh.flush()
        self._fh.seek(entry[3] + len(entry[5]) + f0 * self.frame_bytes[name])
        raw = self._fh.read((f1 - f0) * self.frame_bytes[name])
        return np.frombuffer(raw, dtype).reshape((f1 - f0,) + shape[1:])

    def finish(self) -> None:
        """Check every frame member is full, put the CRCs in, write the central directory; close."""
        fh = self._fh
        for name, (shape, _) in self.frame_shape.items():
            if self.done[name] != shape[0]:
                raise InputError(f"holds {self.done[name]} of {shape[0]} frames", self.path, field=name)
        central = io.BytesIO()
        for name, fname, at, data, size, head in self.entries:
            crc = self.crc[name] if name in self.frame_shape else zlib.crc32(head)
            fh.seek(at)
            fh.write(self._local(fname, crc, size))
            central.write(_ZIP_CENTRAL.pack(0x02014B50, _ZIP_VERSION | 3 << 8, _ZIP_VERSION, 0, 0, _ZIP_TIME,
                                            _ZIP_DATE, crc, 0xFFFFFFFF, 0xFFFFFFFF, len(fname), 28, 0, 0, 0,
                                            0o644 << 16, 0xFFFFFFFF))
            central.write(fname + struct.pack("<HHQQQ", 1, 24, size, size, at))
        cd = central.getvalue()
        n = len(self.entries)
        fh.seek(self.end)
        fh.write(cd)
        fh.write(_ZIP64_END.pack(0x06064B50, 44, _ZIP_VERSION, _ZIP_VERSION, 0, 0, n, n, len(cd), self.end))
        fh.write(_ZIP64_LOCATOR.pack(0x07064B50, 0, self.end + len(cd), 1))
        fh.write(_ZIP_END.pack(0x06054B50, 0, 0, min(n, 0xFFFF), min(n, 0xFFFF), 0xFFFFFFFF, 0xFFFFFFFF, 0))
        fh.truncate()
        self.close()

    def close(self) -> None:
        if not self._fh.closed:
            self._fh.close()
