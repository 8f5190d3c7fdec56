"""Painted shell deformer weights (Pratscher et al. 2005, section 4.2): the per-vertex weight w_i in
[0, 1] that scales each muscle's deformer on each skin vertex (0: the vertex ignores that muscle).

They belong to a character, not to a template (a template serves characters of any mesh), so they
live in a weight file beside the character's file, ``<dir>/<stem>.shell_weights.npz``
(:func:`sidecar_path`), which a user may edit with any tool that writes NumPy arrays:

- ``format`` : 0-d str, :data:`FORMAT` (``"jiggle.shell_weights/1"``).
- ``muscle_names`` : (M,) unicode, the muscles the columns belong to (matched by name, so the file
  survives a template that gains, loses or reorders muscles).
- ``weights`` : (V, M) float32 in [0, 1], row i for skin vertex i of the character.
- ``num_vertices`` : 0-d int, V again (a check that the file was painted on this mesh).

:func:`load_weights` returns the (V, M) table in the rig's muscle order: muscles of the file the rig
lacks are ignored and muscles it lacks get weight 1 (the deformer as the template sets it), each
with a JiggleWarning. :func:`pair_weights` gathers w_i for the deformer's culled (vertex, muscle)
pairs (CSR by vertex).
"""
from __future__ import annotations

import os
import warnings
import zipfile
import zlib
from pathlib import Path

import numpy as np

from jiggle.rig.base.atomic import atomic_path
from jiggle.rig.base.errors import InputError, JiggleWarning, require_file

FORMAT = "jiggle.shell_weights/1"
SUFFIX = ".shell_weights.npz"
KEYS = ("format", "muscle_names", "weights", "num_vertices")

_SHOWN = 8  # names listed in a warning before "and N more"


def sidecar_path(character_path: str | os.PathLike) -> Path:
    """Where the weights of the character in `character_path` live: ``<dir>/<stem>.shell_weights.npz``
    (``body.glb`` -> ``body.shell_weights.npz``)."""
    p = Path(character_path)
    return p.with_name(p.stem + SUFFIX)


def find_weights(character_path: str | os.PathLike) -> Path | None:
    """The character's weight file when it exists (:func:`sidecar_path`), else None."""
    p = sidecar_path(character_path)
    return p if p.is_file() else None


def _names(muscle_names, what: str) -> list[str]:
    """`muscle_names` as a list of unique non-empty str; InputError naming `what` otherwise."""
    names = [n for n in muscle_names]
    bad = [n for n in names if not isinstance(n, str) or not n]
    if bad:
        raise InputError(f"muscle names must be non-empty strings, got {bad[0]!r}", field=what)
    seen: set[str] = set()
    dup = [n for n in names if n in seen or seen.add(n)]
    if dup:
        raise InputError(f"muscle name {dup[0]!r} is given twice", field=what)
    return names


def _listed(names) -> str:
    names = list(names)
    head = ", ".join(names[:_SHOWN])
    return head + (f" and {len(names) - _SHOWN} more" if len(names) > _SHOWN else "")


def _check_range(weights: np.ndarray, names: list[str], path) -> None:
    """InputError naming the muscle and the first vertex whose weight is NaN or outside [0, 1]."""
    bad = ~((weights >= 0.0) & (weights <= 1.0))  # NaN compares False both ways, so it is caught
    if not bad.any():
        return
    v, m = np.argwhere(bad)[0]  # row-major: the lowest vertex first
    raise InputError(f"muscle {names[m]!r}, vertex {v}: weight {weights[v, m]!r}; expected values in [0, 1] "
                     f"({int(bad.sum())} bad value(s) in all)", path, field=f"weights.{names[m]}")


def save_weights(path: str | os.PathLike, muscle_names, weights) -> Path:
    """Write a weight file atomically (a temporary file in the same folder, then os.replace, so a
    reader never finds a half-written file and a failed write leaves any old file as it was).

    Parameters
    ----------
    path : the file (by convention :func:`sidecar_path` of the character).
    muscle_names : (M,) str, unique, naming the columns.
    weights : (V, M) numbers in [0, 1]; stored as float32.

    Returns the path. InputError for names that are not unique, a shape that does not match the
    names, or a weight that is NaN or outside [0, 1].
    """
    names = _names(muscle_names, "muscle_names")
    w = np.asarray(weights)
    if w.ndim != 2 or w.shape[1] != len(names):
        raise InputError(f"expected weights of shape (V, {len(names)}) (one column per muscle name), got "
                         f"{w.shape}", field="weights")
    if not (np.issubdtype(w.dtype, np.floating) or np.issubdtype(w.dtype, np.integer)):
        raise InputError(f"expected numeric weights, got dtype {w.dtype}", field="weights")
    w = w.astype(np.float32)
    _check_range(w, names, None)
    arrays = {"format": np.array(FORMAT), "muscle_names": np.array(names, dtype=np.str_),
              "weights": w, "num_vertices": np.array(w.shape[0], dtype=np.int64)}
    p = Path(path)
    # a file object: savez would append ".npz" to a name; fsync so a crash cannot leave a torn file
    with atomic_path(p) as tmp, open(tmp, "wb") as fh:
        np.savez_compressed(fh, **arrays)
        fh.flush()
        os.fsync(fh.fileno())
    return p


def _read(path: str) -> dict[str, np.ndarray]:
    """The arrays of an .npz weight file (pickles refused); InputError when it is not one."""
    try:
        data = np.load(path, allow_pickle=False)
        if not isinstance(data, np.lib.npyio.NpzFile):
            raise InputError("not an .npz archive (a single .npy array); expected a shell weight file "
                             f"with the keys {', '.join(KEYS)}", path)
        with data:
            missing = [k for k in KEYS if k not in data.files]
            if missing:
                raise InputError(f"missing key(s) {', '.join(map(repr, missing))}; a shell weight file holds "
                                 f"{', '.join(KEYS)}", path, field=missing[0])
            return {k: data[k] for k in KEYS}
    except InputError:
        raise
    except (ValueError, OSError, EOFError, zipfile.BadZipFile, zlib.error) as e:
        # ValueError: neither .npz nor .npy (numpy refuses to try it as a pickle), or a pickled member
        raise InputError(f"not a readable .npz shell weight file ({type(e).__name__}: {e})", path) from None


def load_weights(path: str | os.PathLike, muscle_names, num_vertices: int) -> np.ndarray:
    """The painted weights for the rig's muscles, read from a weight file.

    Parameters
    ----------
    path : the weight file.
    muscle_names : (M,) str, the rig's muscles in rig order.
    num_vertices : V, the character's skin vertex count.

    Returns
    -------
    (V, M) float32 in [0, 1], column m for ``muscle_names[m]``. Muscles the file has and the rig
    lacks are ignored, muscles the rig has and the file lacks get 1, each with a JiggleWarning.

    InputError naming the file and the key or muscle for: a missing file, a file that is not .npz,
    missing keys, a wrong format tag, a vertex count other than the character's, malformed names or
    shapes, a weight that is NaN or outside [0, 1] (naming the muscle and the first bad vertex).
    """
    names = _names(muscle_names, "muscle_names")
    p = require_file(path, "shell weight file")
    d = _read(p)
    tag = d["format"]
    if tag.shape != () or tag.dtype.kind != "U" or str(tag) != FORMAT:
        raise InputError(f"format tag {tag.tolist()!r}; expected {FORMAT!r}", p, field="format")
    file_names = d["muscle_names"]
    if file_names.ndim != 1 or file_names.dtype.kind != "U":
        raise InputError(f"expected a 1-D array of strings, got {file_names.dtype} of shape {file_names.shape}",
                         p, field="muscle_names")
    try:
        file_names = _names(file_names.tolist(), "muscle_names")
    except InputError as e:
        raise InputError(e.message, p, field=e.field) from None
    n = d["num_vertices"]
    if n.shape != () or n.dtype.kind not in "iu":
        raise InputError(f"expected an integer, got {n.dtype} of shape {n.shape}", p, field="num_vertices")
    n = int(n)
    w = d["weights"]
    if w.dtype.kind not in "fiu":
        raise InputError(f"expected numeric weights, got dtype {w.dtype}", p, field="weights")
    if w.ndim != 2 or w.shape != (n, len(file_names)):
        raise InputError(f"expected shape ({n}, {len(file_names)}) (num_vertices, len(muscle_names)), got "
                         f"{w.shape}", p, field="weights")
    if n != num_vertices:
        raise InputError(f"the weights were painted on a mesh of {n} vertices; the character has "
                         f"{num_vertices} (paint them again, or remove the file to use weight 1)", p,
                         field="num_vertices")
    w = w.astype(np.float32, copy=False)
    _check_range(w, file_names, p)

    column = {name: i for i, name in enumerate(file_names)}
    rig_set = set(names)
    extra = [name for name in file_names if name not in rig_set]
    if extra:
        warnings.warn(f"{p}: ignoring the weights of muscle(s) the rig does not have: {_listed(extra)}",
                      JiggleWarning, stacklevel=2)
    missing = [name for name in names if name not in column]
    if missing:
        warnings.warn(f"{p}: no weights for muscle(s) {_listed(missing)}; they get weight 1", JiggleWarning,
                      stacklevel=2)
    out = np.ones((n, len(names)), dtype=np.float32)
    rig_cols = np.array([m for m, name in enumerate(names) if name in column], dtype=np.intp)
    file_cols = np.array([column[names[m]] for m in rig_cols], dtype=np.intp)
    out[:, rig_cols] = w[:, file_cols]
    return out


def pair_weights(weights, pair_offsets, pair_muscle) -> np.ndarray:
    """w_i of every culled (vertex, muscle) pair.

    Parameters
    ----------
    weights : (V, M) float, the rig-ordered table of :func:`load_weights` (or ones).
    pair_offsets : (V+1,) int, CSR: vertex v's pairs are pair_offsets[v]:pair_offsets[v+1].
    pair_muscle : (P,) int, the muscle of each pair.

    Returns (P,) float32: ``weights[v, pair_muscle[k]]`` for pair k of vertex v.
    """
    w = np.asarray(weights)
    off = np.asarray(pair_offsets)
    mus = np.asarray(pair_muscle)
    if w.ndim != 2:
        raise ValueError(f"weights: expected (V, M), got shape {w.shape}")
    if off.shape != (w.shape[0] + 1,) or mus.ndim != 1:
        raise ValueError(f"pair_offsets: expected ({w.shape[0] + 1},), got {off.shape}; pair_muscle: expected "
                         f"(P,), got {mus.shape}")
    counts = np.diff(off)
    if off[0] != 0 or off[-1] != mus.shape[0] or (counts < 0).any():
        raise ValueError(f"pair_offsets: expected non-decreasing offsets from 0 to P = {mus.shape[0]}")
    if mus.size and (mus.min() < 0 or mus.max() >= w.shape[1]):
        raise ValueError(f"pair_muscle: expected muscle indices in [0, {w.shape[1]})")
    vertex = np.repeat(np.arange(w.shape[0]), counts)
    return w[vertex, mus].astype(np.float32)


__all__ = ["FORMAT", "SUFFIX", "KEYS", "sidecar_path", "find_weights", "save_weights", "load_weights",
           "pair_weights"]
