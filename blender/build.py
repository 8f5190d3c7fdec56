"""Build the Blender extension: `python blender/build.py [--out DIR]` writes DIR/jiggle_blender-VERSION.zip
(default DIR: dist/), the zip Blender's Preferences > Get Extensions > Install from Disk takes (Blender 4.2+).
The version is the manifest's, kept equal to the project's (pyproject.toml) by a test."""
from __future__ import annotations

import argparse
import os
import sys
import tomllib
import zipfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
SOURCE = HERE / "jiggle_blender"


def build(out_dir: str | os.PathLike) -> Path:
    manifest = tomllib.loads((SOURCE / "blender_manifest.toml").read_text())
    out = Path(out_dir) / f"{manifest['id']}-{manifest['version']}.zip"
    out.parent.mkdir(parents=True, exist_ok=True)
    part = out.with_name(out.name + ".part")
    with zipfile.ZipFile(part, "w", zipfile.ZIP_DEFLATED) as z:
        for f in sorted(SOURCE.iterdir()):
            if f.is_file() and f.suffix in (".py", ".toml"):
                z.write(f, f.name)
    os.replace(part, out)
    return out


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(HERE.parent / "dist"), help="folder for the zip (default: dist/)")
    print(build(ap.parse_args(sys.argv[1:]).out))
