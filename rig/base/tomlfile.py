"""Reading the TOML files users write (scenes, keyframed clips, joint maps)."""
from __future__ import annotations

import os
import tomllib

from jiggle.rig.base.errors import InputError, require_file


def read_toml(path: str | os.PathLike, what: str = "TOML file") -> tuple[str, dict]:
    """Return (path as str, parsed document); InputError naming the file and line when it is not TOML."""
    p = require_file(path, what)
    try:
        with open(p, "rb") as fh:
            return p, tomllib.load(fh)
    except tomllib.TOMLDecodeError as e:
        raise InputError(f"not valid TOML: {e}", p) from None
    except UnicodeDecodeError:
        raise InputError("not a UTF-8 text file; expected TOML", p) from None
