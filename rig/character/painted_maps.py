"""Painted maps on a character's skin: where jiggle shows, and where each muscle's shell reaches.

Two kinds of per-vertex scalar in [0, 1], painted by a user (e.g. in Blender) on the character:

- the jiggle map J (V,): how much of the jiggle each vertex shows. The skin stage makes
  ``final = static + J (final - static)`` per vertex (rig.skin.muscle_skin.skin_frames): 0 shows no
  jiggle, 1 (the default) all of it.
- influence maps I_m (V,), one per muscle m: the weight of muscle m's shell deformer on each vertex,
  replacing the one computed at bind (rig.skin.muscle_skin: the envelope that fades each muscle's
  pull out at its culled region's edge). 0 removes a vertex from the muscle's region, a value
  between 0 and 1 softens the fall-off, a value > 0 outside the computed region adds the vertex.
  A vertex the map does not cover (NaN here: a primitive of the file without the attribute) keeps
  the computed weight.

Where they are read from, in this order (:func:`read_maps`, called by rig.character.load):

1. the character's own glTF file: vertex attributes of every skinned primitive,
   ``_JIGGLE`` (SCALAR; FLOAT, or UNSIGNED_BYTE / UNSIGNED_SHORT with ``normalized``: true) and
   ``_SHELL_<MUSCLE>`` (the same; the muscle's name in capitals, matched without regard to case, as
   Blender's exporter writes every custom attribute's name in capitals). The jiggle map may also come
   from one channel of a vertex colour, ``jiggle_attribute="COLOR_0.r"`` (r, g, b or a).
2. a sidecar file beside the character, for any character file (glTF, OBJ, PLY, ...):
   ``<stem>.jiggle_map.npz`` (:func:`save_maps`: ``jiggle`` (V,), ``influence`` (V, M) with
   ``influence_names`` (M,), optional ``format`` and ``num_vertices``) or ``<stem>.jiggle_map.ply``
   (vertex properties ``jiggle`` (or ``quality``, what MeshLab paints) and ``shell_<muscle>``).
   Both are keyed by vertex count: row i is the character's vertex i, in the order it reads them.
   A map the file itself has wins over the sidecar's (with a warning naming what was ignored).

A bad map (wrong count, a value outside [0, 1] or NaN, an accessor of another type) is an InputError
naming the file, the attribute or key, and what was expected.
"""
from __future__ import annotations

import os
import warnings
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType

import numpy as np

from jiggle.rig.base.atomic import atomic_path
from jiggle.rig.base.errors import InputError, JiggleWarning
from jiggle.rig.base.frozen import frozen_array

JIGGLE_ATTRIBUTE = "_JIGGLE"
SHELL_PREFIX = "_SHELL_"
SIDECAR = ".jiggle_map"
FORMAT = "jiggle.maps/1"
PLY_JIGGLE = ("jiggle", "quality")
PLY_SHELL_PREFIX = "shell_"
_SCALAR_TYPES = {5126: "FLOAT", 5121: "UNSIGNED_BYTE", 5123: "UNSIGNED_SHORT"}
_CHANNELS = "rgba"


@dataclass(frozen=True, eq=False)
class PaintedMaps:
    """A character's painted maps (module docstring). Arrays are read-only.

    jiggle : (V,) float32 in [0, 1], or None (1 everywhere).
    influence : {muscle name, lower case: (V,) float32 in [0, 1], NaN where not painted}.
    source : where they were read from, e.g. "CesiumMan.glb: _JIGGLE, 27 _SHELL_ attributes".
    """

    jiggle: np.ndarray | None = None
    influence: dict = field(default_factory=dict)
    source: str = ""

    def __post_init__(self):
        if self.jiggle is not None:
            object.__setattr__(self, "jiggle", frozen_array(self.jiggle, np.float32))
        inf = {str(k).lower(): frozen_array(v, np.float32) for k, v in self.influence.items()}
        object.__setattr__(self, "influence", MappingProxyType(inf))

    @property
    def num_vertices(self) -> int | None:
        for a in ([self.jiggle] if self.jiggle is not None else []) + list(self.influence.values()):
            return len(a)
        return None

    @property
    def empty(self) -> bool:
        return self.jiggle is None and not self.influence

    def influence_table(self, names) -> np.ndarray | None:
        """(V, M) float32 of the muscles `names` (rig order), NaN where not painted (a muscle without
        a map: all NaN), or None when none of them has a map."""
        cols = [self.influence.get(str(n).lower()) for n in names]
        if all(c is None for c in cols):
            return None
        V = self.num_vertices
        return np.stack([np.full(V, np.nan, np.float32) if c is None else c for c in cols], axis=1)


def check_map(values, n: int, path, what: str) -> np.ndarray:
    """`values` as (n,) float32 in [0, 1]; InputError naming `path` and `what` (the attribute or key)
    for another length, NaN or a value outside [0, 1]."""
    a = np.asarray(values)
    if a.dtype.kind not in "fiub":
        raise InputError(f"expected numbers in [0, 1], got dtype {a.dtype}", path, field=what)
    a = a.astype(np.float64).reshape(-1) if a.ndim == 2 and a.shape[1] == 1 else a.astype(np.float64)
    if a.ndim != 1 or len(a) != n:
        raise InputError(f"expected one value per vertex, {n} values (the character's vertex count), got shape "
                         f"{a.shape}", path, field=what)
    bad = ~((a >= 0.0) & (a <= 1.0))    # NaN compares False both ways
    if bad.any():
        v = int(np.argmax(bad))
        raise InputError(f"vertex {v}: {a[v]!r}; expected values in [0, 1] ({int(bad.sum())} bad value(s) in all)",
                         path, field=what)
    return a.astype(np.float32)


# ---------------------------------------------------------------------------------- glTF
def gltf_scalar(doc, index: int, nv: int, what: str) -> np.ndarray:
    """(nv,) float64 of a SCALAR accessor of FLOAT or normalized UNSIGNED_BYTE / UNSIGNED_SHORT
    components (rig.motion.gltf_io.GltfDocument `doc`); InputError naming `what` otherwise."""
    a = doc.gltf.accessors[index] if 0 <= index < len(doc.gltf.accessors) else None
    if a is None:
        raise InputError(f"accessor {index} does not exist", doc.path, field=what)
    kind = _SCALAR_TYPES.get(a.componentType)
    if a.type != "SCALAR" or kind is None or (kind != "FLOAT" and not a.normalized):
        got = f"{a.type} of componentType {a.componentType}{' (normalized)' if a.normalized else ''}"
        raise InputError(f"expected a SCALAR accessor of FLOAT, or of UNSIGNED_BYTE / UNSIGNED_SHORT with "
                         f"normalized: true; got {got}", doc.path, field=what)
    v = doc.accessor(index, what)[:, 0]
    if len(v) != nv:
        raise InputError(f"{len(v)} values; expected one per vertex of the primitive ({nv})", doc.path, field=what)
    return v


def gltf_color_channel(doc, attrs, spec: str, nv: int, what: str) -> np.ndarray | None:
    """(nv,) float64: channel `spec` ("COLOR_n.c", c in r, g, b, a) of a primitive's vertex colours,
    or None when the primitive has no such attribute."""
    name, _, ch = spec.partition(".")
    index = getattr(attrs, name, None)
    if index is None:
        return None
    a = doc.gltf.accessors[index]
    if a.componentType != 5126 and not a.normalized:
        raise InputError(f"expected FLOAT or normalized integer colours, got componentType {a.componentType}",
                         doc.path, field=what)
    v = doc.accessor(index, what)
    c = _CHANNELS.index(ch)
    if c >= v.shape[1]:
        raise InputError(f"channel {ch!r} asked for, the colours have {v.shape[1]} components", doc.path, field=what)
    return v[:, c]


def parse_jiggle_attribute(spec: str | None) -> str:
    """The glTF attribute the jiggle map is read from: "_JIGGLE" (default) or any custom "_NAME", or
    a vertex colour's channel "COLOR_n.c"; InputError otherwise."""
    spec = JIGGLE_ATTRIBUTE if spec is None else str(spec)
    name, dot, ch = spec.partition(".")
    if spec.startswith("_") and not dot:
        return spec
    if name.startswith("COLOR_") and name[6:].isdigit() and dot and ch in _CHANNELS and len(ch) == 1:
        return spec
    raise InputError(f"expected a custom attribute '_NAME' (default {JIGGLE_ATTRIBUTE}) or a vertex colour's "
                     f"channel 'COLOR_n.c' with c one of r, g, b, a; got {spec!r}", field="jiggle_attribute")


def primitive_maps(doc, attrs, nv: int, what: str, jiggle_attribute: str = JIGGLE_ATTRIBUTE) -> dict:
    """The maps one glTF primitive carries: {"jiggle": (nv,), "shell:<muscle lower>": (nv,)} float64,
    each checked in [0, 1] (InputError naming the primitive's attribute)."""
    out = {}
    names = {k: v for k, v in vars(attrs).items() if k.startswith("_") and v is not None}
    if jiggle_attribute.startswith("COLOR_"):
        v = gltf_color_channel(doc, attrs, jiggle_attribute, nv, f"{what}.attributes.{jiggle_attribute}")
    else:
        index = next((i for k, i in names.items() if k.upper() == jiggle_attribute.upper()), None)
        v = None if index is None else gltf_scalar(doc, index, nv, f"{what}.attributes.{jiggle_attribute}")
    if v is not None:
        out["jiggle"] = check_map(v, nv, doc.path, f"{what}.attributes.{jiggle_attribute}")
    for k, i in names.items():
        if k.upper().startswith(SHELL_PREFIX) and len(k) > len(SHELL_PREFIX):
            f = f"{what}.attributes.{k}"
            out["shell:" + k[len(SHELL_PREFIX):].lower()] = check_map(gltf_scalar(doc, i, nv, f), nv, doc.path, f)
    return out


def assemble(parts: list[tuple[int, int, dict]], V: int, source: str) -> PaintedMaps | None:
    """PaintedMaps of V vertices from each primitive's maps (first vertex, count, primitive_maps):
    jiggle 1 and influence NaN (computed) on primitives without the map; None when none has any."""
    keys = sorted({k for _, _, d in parts for k in d})
    if not keys:
        return None
    jiggle = None
    influence = {}
    for key in keys:
        full = np.full(V, 1.0 if key == "jiggle" else np.nan, np.float32)
        for first, n, d in parts:
            if key in d:
                full[first:first + n] = d[key]
        if key == "jiggle":
            jiggle = full
        else:
            influence[key[len("shell:"):]] = full
    what = ([JIGGLE_ATTRIBUTE] if jiggle is not None else []) + \
        ([f"{len(influence)} {SHELL_PREFIX} attributes"] if influence else [])
    return PaintedMaps(jiggle=jiggle, influence=influence, source=f"{source}: {', '.join(what)}")


# ---------------------------------------------------------------------------------- sidecars
def sidecar_paths(character_path: str | os.PathLike) -> tuple[Path, Path]:
    """``<dir>/<stem>.jiggle_map.npz`` and ``.ply`` beside the character file."""
    p = Path(character_path)
    return p.with_name(p.stem + SIDECAR + ".npz"), p.with_name(p.stem + SIDECAR + ".ply")


def find_sidecar(character_path: str | os.PathLike) -> Path | None:
    """The character's map sidecar that exists (npz first), or None."""
    return next((p for p in sidecar_paths(character_path) if p.is_file()), None)


def save_maps(path: str | os.PathLike, maps: PaintedMaps, num_vertices: int) -> Path:
    """Write `maps` as an npz sidecar (module docstring), atomically. NaN (not painted) influence
    values are written as they are and read back as "computed"."""
    arrays = {"format": np.array(FORMAT), "num_vertices": np.array(num_vertices, np.int64)}
    if maps.jiggle is not None:
        arrays["jiggle"] = np.asarray(maps.jiggle, np.float32)
    if maps.influence:
        names = list(maps.influence)
        arrays["influence_names"] = np.array(names, dtype=np.str_)
        arrays["influence"] = np.stack([maps.influence[n] for n in names], axis=1).astype(np.float32)
    p = Path(path)
    with atomic_path(p) as tmp, open(tmp, "wb") as fh:
        np.savez_compressed(fh, **arrays)
    return p


def read_npz_maps(path: str | os.PathLike, V: int) -> PaintedMaps:
    """The maps of an npz sidecar for a character of V vertices (InputError naming the key)."""
    p = os.fspath(path)
    try:
        data = np.load(p, allow_pickle=False)
        if not isinstance(data, np.lib.npyio.NpzFile):
            raise InputError("not an .npz archive; expected keys jiggle and/or influence, influence_names", p)
        with data:
            d = {k: data[k] for k in data.files}
    except InputError:
        raise
    except (ValueError, OSError, EOFError, zipfile.BadZipFile, zlib.error) as e:   # torn, pickled, not NumPy
        raise InputError(f"not a readable .npz map file ({type(e).__name__}: {e})", p) from None
    if "format" in d and str(d["format"]) != FORMAT:
        raise InputError(f"format tag {str(d['format'])!r}; expected {FORMAT!r}", p, field="format")
    if "num_vertices" in d and int(d["num_vertices"]) != V:
        raise InputError(f"painted on a mesh of {int(d['num_vertices'])} vertices; the character has {V}", p,
                         field="num_vertices")
    if "jiggle" not in d and "influence" not in d:
        raise InputError("no map: expected a key 'jiggle' (V,) and/or 'influence' (V, M) with 'influence_names'",
                         p, field="jiggle")
    jiggle = check_map(d["jiggle"], V, p, "jiggle") if "jiggle" in d else None
    influence = {}
    if "influence" in d:
        inf, names = d["influence"], d.get("influence_names")
        if names is None or names.ndim != 1 or names.dtype.kind != "U":
            raise InputError("expected a 1-D array of muscle names beside 'influence'", p, field="influence_names")
        if inf.ndim != 2 or inf.shape != (V, len(names)):
            raise InputError(f"expected shape ({V}, {len(names)}) (vertices, influence_names), got {inf.shape}", p,
                             field="influence")
        for m, n in enumerate(names.tolist()):
            col = inf[:, m].astype(np.float64)
            painted = ~np.isnan(col)        # NaN: not painted there, the computed weight (save_maps)
            influence[n] = np.where(painted, 0.0, np.nan).astype(np.float32)
            influence[n][painted] = check_map(col[painted], int(painted.sum()), p, f"influence.{n}")
    return PaintedMaps(jiggle=jiggle, influence=influence, source=os.path.basename(p))


def read_ply_maps(path: str | os.PathLike, V: int) -> PaintedMaps:
    """The maps of a PLY sidecar: vertex properties ``jiggle`` (or ``quality``) and ``shell_<muscle>``."""
    from trimesh.exchange.ply import load_ply  # the parser itself: a file of points only keeps its properties
    p = os.fspath(path)
    try:
        with open(p, "rb") as fh:
            raw = load_ply(fh)["metadata"]["_ply_raw"]["vertex"]["data"]
    except (ValueError, KeyError, IndexError, TypeError, OSError, UnicodeDecodeError) as e:
        raise InputError(f"not a readable PLY file with vertex properties ({type(e).__name__}: {e})", p) from None
    props = list(raw) if isinstance(raw, dict) else list(raw.dtype.names or ())
    col = lambda k: np.asarray(raw[k]).reshape(len(np.asarray(raw[k])), -1)[:, 0]
    jk = next((k for k in PLY_JIGGLE if k in props), None)
    jiggle = check_map(col(jk), V, p, f"vertex.{jk}") if jk else None
    influence = {k[len(PLY_SHELL_PREFIX):]: check_map(col(k), V, p, f"vertex.{k}")
                 for k in props if k.lower().startswith(PLY_SHELL_PREFIX) and len(k) > len(PLY_SHELL_PREFIX)}
    if jiggle is None and not influence:
        raise InputError(f"no map: expected a vertex property {' or '.join(PLY_JIGGLE)} or shell_<muscle>; the "
                         f"file has {', '.join(props)}", p, field="vertex")
    return PaintedMaps(jiggle=jiggle, influence=influence, source=os.path.basename(p))


def read_sidecar(path: str | os.PathLike, V: int) -> PaintedMaps:
    return read_npz_maps(path, V) if str(path).lower().endswith(".npz") else read_ply_maps(path, V)


def merge(own: PaintedMaps | None, side: PaintedMaps | None, side_path=None) -> PaintedMaps | None:
    """The file's own maps, completed by the sidecar's; a map both give is the file's, and the
    sidecar's is ignored with a JiggleWarning naming it."""
    if side is None:
        return own
    if own is None or own.empty:
        return side
    clash = (["jiggle"] if own.jiggle is not None and side.jiggle is not None else []) + \
        [n for n in side.influence if n in own.influence]
    if clash:
        warnings.warn(f"{side_path}: the character file has its own map(s) {', '.join(clash[:6])}"
                      f"{' ...' if len(clash) > 6 else ''}; those of the sidecar are ignored", JiggleWarning,
                      stacklevel=3)
    return PaintedMaps(jiggle=own.jiggle if own.jiggle is not None else side.jiggle,
                       influence={**side.influence, **own.influence}, source=f"{own.source}; {side.source}")


def read_maps(character_path: str | os.PathLike, V: int, own: PaintedMaps | None = None) -> PaintedMaps | None:
    """The character's maps: `own` (read from its file by the glTF reader) completed by its sidecar."""
    side_path = find_sidecar(character_path)
    side = read_sidecar(side_path, V) if side_path is not None else None
    return merge(own, side, side_path)
