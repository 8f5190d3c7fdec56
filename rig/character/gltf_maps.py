"""Writing painted maps into a copy of a character's glTF, ready to paint in Blender and read back.

:func:`write_maps_copy` copies the character's own .glb/.gltf as one GLB (every buffer merged into
the binary chunk, external images embedded, everything else kept as the file has it: nodes,
materials, animations, extensions) and adds to each primitive the character was read from
(``Character.meta["primitives"]``, rig.character.gltf_character) the vertex attributes
rig.character.painted_maps reads: ``_JIGGLE`` and one ``_SHELL_<MUSCLE>`` per muscle, SCALAR FLOAT,
replacing any of the same name. A character that did not come from a skinned glTF (a generated body,
a mesh with automatic weights) is written by rig.character.gltf_write with the attributes instead.

Blender's importer keeps every attribute whose name starts with "_" as a point attribute of the same
name (io_scene_gltf2/blender/imp/mesh.py), and its exporter writes them back with
``export_attributes=True`` (in capitals: io_scene_gltf2/blender/exp/primitive_extract.py), which the
reader matches without regard to case.
"""
from __future__ import annotations

import json
import mimetypes
import os
import struct
import urllib.parse

import numpy as np

from jiggle.rig.base.atomic import atomic_path
from jiggle.rig.base.errors import InputError
from jiggle.rig.character.painted_maps import JIGGLE_ATTRIBUTE, SHELL_PREFIX, PaintedMaps

_FLOAT, _ARRAY_BUFFER = 5126, 34962


def map_attributes(maps: PaintedMaps, V: int) -> dict[str, np.ndarray]:
    """{glTF attribute name: (V,) float32} of `maps`: _JIGGLE (1 without a jiggle map) and
    _SHELL_<MUSCLE> per influence map (NaN, not painted, is an error here: give complete maps)."""
    out = {JIGGLE_ATTRIBUTE: np.ones(V, np.float32) if maps.jiggle is None else np.asarray(maps.jiggle, np.float32)}
    for name, a in maps.influence.items():
        a = np.asarray(a, np.float32)
        if np.isnan(a).any():
            raise ValueError(f"influence map {name!r} has unpainted (NaN) vertices; fill them before writing")
        out[SHELL_PREFIX + name.upper()] = a
    return out


def write_maps_copy(character, path: str | os.PathLike, maps: PaintedMaps) -> str:
    """Write `character` with `maps` as a GLB at `path` (module docstring); returns the path.

    character : rig.character.character.Character; its `source` is the glTF copied when it was read
        from one (``meta["primitives"]``), else the character itself is written.
    maps : complete maps of the character's V vertices (PaintedMaps; influence without NaN).
    """
    p = os.fspath(path)
    if not p.lower().endswith(".glb"):
        raise InputError("expected a .glb path for the painted copy", p, field="path")
    attrs = map_attributes(maps, character.num_vertices)
    prims = character.meta.get("primitives")
    src = character.source
    if not prims or not src or os.path.splitext(src)[1].lower() not in (".glb", ".gltf"):
        from jiggle.rig.character.gltf_write import write_character
        return write_character(character, p, attributes=attrs)
    from jiggle.rig.motion.gltf_io import GltfDocument
    doc = GltfDocument(src)
    with open(doc.path, "rb") as fh:
        data = fh.read()
    raw = json.loads(doc._split_glb(data)[0] if data[:4] == b"glTF" else data.decode("utf-8-sig"))
    blob = bytearray()

    def view(payload: bytes, target: int | None = None) -> int:
        v = {"buffer": 0, "byteOffset": len(blob), "byteLength": len(payload)}
        if target is not None:
            v["target"] = target
        blob.extend(payload + b"\0" * (-len(payload) % 4))
        raw.setdefault("bufferViews", []).append(v)
        return len(raw["bufferViews"]) - 1

    # every buffer into one binary chunk, the views moved along
    starts = []
    for i in range(len(raw.get("buffers", []))):
        starts.append(len(blob))
        b = doc.buffer(i)
        blob.extend(b + b"\0" * (-len(b) % 4))
    for bv in raw.get("bufferViews", []):
        bv["byteOffset"] = bv.get("byteOffset", 0) + starts[bv.get("buffer", 0)]
        bv["buffer"] = 0
    # external images would not be found beside the copy: embed them
    for i, im in enumerate(raw.get("images", [])):
        uri = im.get("uri")
        if uri is None or uri.startswith("data:"):
            continue
        f = os.path.join(os.path.dirname(doc.path), urllib.parse.unquote(uri))
        if os.path.isfile(f):
            with open(f, "rb") as fh:
                im["bufferView"] = view(fh.read())
            im["mimeType"] = im.get("mimeType") or mimetypes.guess_type(f)[0] or "image/png"
            del im["uri"]
    seen = set()
    accessors = raw.setdefault("accessors", [])
    for mesh, prim, first, n in prims:
        if (mesh, prim) in seen:        # one primitive placed twice (a prop on two joints): its first place
            continue
        seen.add((mesh, prim))
        a = raw["meshes"][mesh]["primitives"][prim]["attributes"]
        for k in [k for k in a if k.upper() in attrs]:
            del a[k]
        for name, values in attrs.items():
            part = np.ascontiguousarray(values[first:first + n], dtype="<f4")
            accessors.append({"bufferView": view(part.tobytes(), _ARRAY_BUFFER), "componentType": _FLOAT,
                              "count": int(n), "type": "SCALAR", "min": [float(part.min())],
                              "max": [float(part.max())]})
            a[name] = len(accessors) - 1
    raw["buffers"] = [{"byteLength": len(blob)}]
    raw.setdefault("asset", {}).setdefault("extras", {})
    if isinstance(raw["asset"]["extras"], dict):
        raw["asset"]["extras"]["jiggle"] = {"painted_maps_of": os.path.basename(src)}
    text = json.dumps(raw, allow_nan=False, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)
    total = 12 + 8 + len(text) + 8 + len(blob)
    out = (struct.pack("<4sII", b"glTF", 2, total) + struct.pack("<II", len(text), 0x4E4F534A) + text
           + struct.pack("<II", len(blob), 0x004E4942) + bytes(blob))
    with atomic_path(p) as tmp, open(tmp, "wb") as fh:
        fh.write(out)
    return p
