"""Atomic file writes: a reader never sees a half-written file under the final name."""
from __future__ import annotations

import contextlib
import os
import tempfile


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike):
    """Yield a temporary path beside `path` (same extension, so writers pick the right format);
    rename it onto `path` when the block succeeds, delete it when the block fails.

    The temporary file gets the mode of the file it replaces, else rw-r--r-- (mkstemp makes it
    private, and a renamed cache or picture should be as readable as any file the user writes)."""
    path = os.fspath(path)
    folder = os.path.dirname(os.path.abspath(path))
    os.makedirs(folder, exist_ok=True)
    stem, ext = os.path.splitext(os.path.basename(path))
    fd, tmp = tempfile.mkstemp(prefix=f".{stem}.", suffix=f".tmp{ext}", dir=folder)
    os.fchmod(fd, os.stat(path).st_mode & 0o777 if os.path.exists(path) else 0o644)
    os.close(fd)
    try:
        yield tmp
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.remove(tmp)
        raise
