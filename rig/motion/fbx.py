"""FBX in, through Blender's importer: an FBX file is converted once to a glTF (cached) and read as one.

The FBX readers on PyPI were weighed first and none reads a skinned character reliably today: `ufbx` 0.0.5
(bindings generated from ufbx's header, built wheels) crashes the interpreter when a node it handed out through a
cluster's `bone_node` is freed; `pufbx` 0.1.0 (alpha) has no bind matrices or weights on its clusters; `pyufbx`
0.0.7 covers scenes, nodes, meshes and materials only. Blender's importer is the well-kept one people already
use for FBX from Maya, MotionBuilder, 3ds Max and Mixamo: it applies the file's units (UnitScaleFactor) and axes
(UpAxis), reads the mesh, skin weights, bind pose, skeleton and takes, and its glTF exporter writes them as a
glTF that rig.character.gltf_character and rig.motion.gltf_anim read (units then come out in metres, Z-up).

Blender is found as a Python that imports `bpy` (JIGGLE_BPY_PYTHON, else ./dev.sh's .venv/blender), or the
`blender` program (JIGGLE_BLENDER_EXE, else on PATH). Blender's importer reads binary FBX 7.1 and later; the rest
is brought to it as binary FBX 7.4 first (`binary_for_blender`): ASCII FBX (6.x or 7.x) read by
rig.motion.fbx_tree, FBX 6.x (2006-2010, binary or ASCII) lifted into 7.x's object model by rig.motion.fbx_legacy.
Checked against the authoring tools' own meshes in ufbx's test files: Maya's and 3ds Max's skinned meshes at given
frames from their FBX 6.1 and 7.5 files, binary and ASCII, match within 3e-8 m (2e-7 of the height); FBX 5 and
earlier are refused saying so. Converted files live in the user's cache
(~/.cache/jiggle/fbx, JIGGLE_CACHE), named for the FBX's contents and this converter's version, written
atomically: the user's folder is never written to.
"""
from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from jiggle.rig.base.errors import InputError, require_file

CONVERTER_VERSION = 3
"""Bump when the conversion changes: cached files of another version are made again."""
TIMEOUT_S = 600
SCRIPT = r'''
import sys
import bpy
src, out = sys.argv[-2], sys.argv[-1]
bpy.ops.wm.read_factory_settings(use_empty=True)
try:  # Blender 5.0's importer still sets lamp.cycles.cast_shadow, which Cycles no longer has, and stops on any
    # file with a light; a character needs no light, so lights are read as plain point lights
    import io_scene_fbx.import_fbx as _reader
    _reader.blen_read_light = lambda tmpl, obj, settings: bpy.data.lights.new(
        name=_reader.elem_name_ensure_class(obj, b"NodeAttribute"), type="POINT")
except (ImportError, AttributeError):  # another Blender, laid out otherwise: its importer as it is
    _reader = None
try:
    bpy.ops.import_scene.fbx(filepath=src, anim_offset=0.0)   # FBX time t at glTF time t (the default offset is a frame)
except Exception as e:  # the importer's own reason, one line, for the user: a traceback's last line
    lines = [ln.strip() for ln in str(e).splitlines() if ln.strip()]
    print("JIGGLE_FBX_ERROR " + ((lines[-1] if "Traceback" in str(e) else " ".join(lines)) or type(e).__name__)[:400])
    sys.exit(3)
if not bpy.data.objects:
    print("JIGGLE_FBX_ERROR the file holds no object Blender can import")
    sys.exit(3)
bpy.ops.export_scene.gltf(filepath=out, export_format="GLB", export_animations=True, export_skins=True,
                          export_force_sampling=True)
'''


def is_fbx(path) -> bool:
    return str(path).lower().endswith(".fbx")


def fbx_version(path: str) -> tuple[str, int]:
    """("binary" or "ascii", version, e.g. 7400) from the file's header (an ASCII file's FBXVersion, else its first
    comment line, else 0); InputError for a file that is not FBX."""
    import re
    with open(path, "rb") as fh:
        head = fh.read(4096)
    if head.startswith(b"Kaydara FBX Binary  \x00") and len(head) >= 27:
        return "binary", int.from_bytes(head[23:27], "little")
    if head.lstrip().startswith(b";") or b"FBXHeaderExtension" in head:
        m = re.search(rb"FBXVersion:\s*(\d+)", head)
        if m:
            return "ascii", int(m.group(1))
        m = re.match(rb"\s*;\s*FBX (\d+)\.(\d+)", head)
        return "ascii", int(m.group(1)) * 1000 + int(m.group(2)) * 100 if m else 0
    raise InputError("not an FBX file (no 'Kaydara FBX Binary' header, and not FBX text)", path)


def blender_command(script: str) -> list[str] | None:
    """The command that runs `script` (a .py file) in Blender, its two last arguments passed on; None when no
    Blender is found."""
    py = os.environ.get("JIGGLE_BPY_PYTHON")
    root = Path(__file__).resolve().parents[2]
    candidates = [py] if py else [str(root / ".venv" / "blender" / "bin" / "python")]
    for c in candidates:
        if c and os.path.isfile(c) and os.access(c, os.X_OK):
            return [c, script]
    exe = os.environ.get("JIGGLE_BLENDER_EXE") or shutil.which("blender")
    if exe:
        return [exe, "--background", "--factory-startup", "--python-exit-code", "3", "--python", script, "--"]
    return None


def cache_dir() -> Path:
    base = os.environ.get("JIGGLE_CACHE") or os.path.join(os.environ.get("XDG_CACHE_HOME") or
                                                          os.path.expanduser("~/.cache"), "jiggle")
    return Path(base) / "fbx"


def fbx_to_gltf(path: str | os.PathLike) -> str:
    """The glTF (.glb) Blender makes of an FBX file, from the cache when it was made before; InputError (the
    file, what failed, what to do) when Blender is missing, the file is ASCII or older than FBX 7.1, or
    Blender's importer refuses it."""
    p = require_file(path)
    fbx_version(p)                                  # not FBX at all: refused before anything else
    digest = hashlib.sha256()
    with open(p, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    out = cache_dir() / f"{Path(p).stem}-{digest.hexdigest()[:16]}-v{CONVERTER_VERSION}.glb"
    if out.is_file() and out.stat().st_size > 0:
        return str(out)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise InputError(f"cannot make the cache of converted FBX files {out.parent}: {e.strerror or e}; set "
                         f"JIGGLE_CACHE to a writable folder", p) from None
    with tempfile.TemporaryDirectory(prefix="jiggle_fbx_") as tmp:
        src = binary_for_blender(p, tmp)
        script = os.path.join(tmp, "fbx_to_gltf.py")
        with open(script, "w", encoding="utf-8") as fh:
            fh.write(SCRIPT)
        cmd = blender_command(script)
        if cmd is None:
            raise InputError("reading FBX needs Blender: install it (blender on PATH, or JIGGLE_BLENDER_EXE), or the "
                             "bpy module (./dev.sh install puts it in .venv/blender; JIGGLE_BPY_PYTHON names "
                             "another Python with bpy); or export the character as glTF", p)
        glb = os.path.join(tmp, "out.glb")
        try:
            r = subprocess.run(cmd + [os.path.abspath(src), glb], capture_output=True, text=True, timeout=TIMEOUT_S)
        except subprocess.TimeoutExpired:
            raise InputError(f"Blender took over {TIMEOUT_S} s to import it", p) from None
        why = [ln[len("JIGGLE_FBX_ERROR "):] for ln in r.stdout.splitlines() if ln.startswith("JIGGLE_FBX_ERROR ")]
        if r.returncode != 0 or not os.path.isfile(glb):
            reason = why[0] if why else ((r.stderr.strip().splitlines() or r.stdout.strip().splitlines() or
                                          [f"exit {r.returncode}"])[-1])[:400]
            raise InputError(f"Blender's FBX importer could not read it: {reason}", p)
        part = out.with_name(out.name + f".{os.getpid()}.tmp")
        try:
            shutil.copyfile(glb, part)
            os.replace(part, out)           # atomic: a batch's workers converting one file at once both land whole
        except OSError as e:
            raise InputError(f"cannot write the converted FBX into {out.parent}: {e.strerror or e}; set JIGGLE_CACHE "
                             f"to a writable folder", p) from None
    return str(out)


def binary_for_blender(path: str, tmp: str) -> str:
    """`path` itself when Blender's importer reads it (binary FBX 7.1+); else the same scene written as binary FBX
    7.4 into the folder `tmp`: an ASCII file's tree typed as binary (rig.motion.fbx_tree), an FBX 6.x file's tree
    lifted into 7.x's object model first (rig.motion.fbx_legacy). Either way the file is read here first and
    refused when it is cut short or holds NaN vertices, weights or keys (rig.motion.fbx_tree.check_finite)."""
    from jiggle.rig.motion.fbx_legacy import lift
    from jiggle.rig.motion.fbx_tree import check_finite, read_tree, write_binary
    kind, version = fbx_version(path)
    nodes, version, _ = read_tree(path)
    check_finite(nodes, path)
    if kind == "binary" and version >= 7100:
        return path
    if version < 6000:
        raise InputError(f"FBX {version / 1000:.1f} (before 2006): jiggle reads FBX 6.x and 7.x, binary or ASCII; "
                         f"save it as FBX 7.x (or glTF) in the authoring tool or Autodesk's FBX Converter", path)
    objects = next((n for n in nodes if n.name == "Objects"), None)
    if objects is None or not any(o.name == "Model" for o in objects.children):
        raise InputError("the FBX file holds no models (no Objects section with a Model in it): nothing to read", path)
    if version < 7000:
        nodes = lift(nodes, path)
    out = os.path.join(tmp, "in.fbx")
    with open(out, "wb") as fh:
        fh.write(write_binary(nodes))
    return out


def through_gltf(path, read, *args, **kwargs):
    """read(the FBX's glTF, *args, **kwargs), its InputErrors naming the FBX file (and that Blender read it), its
    result's `source` the FBX file."""
    import dataclasses
    p = os.fspath(path)
    glb = fbx_to_gltf(p)
    try:
        out = read(glb, *args, **kwargs)
    except InputError as e:
        raise InputError(f"{e.message} (read through Blender's importer)", p, field=e.field) from None
    if dataclasses.is_dataclass(out) and hasattr(out, "source"):
        stem = os.path.splitext(os.path.basename(p))[0]
        named = {"name": stem} if getattr(out, "name", None) == Path(glb).stem else {}
        out = dataclasses.replace(out, source=p, **named)
    return out


if __name__ == "__main__":  # python -m rig.motion.fbx FILE.fbx: where its glTF is
    print(fbx_to_gltf(sys.argv[1]))
