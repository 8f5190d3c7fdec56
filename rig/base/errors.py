"""The one error type for a user's bad input.

Every reader raises :class:`InputError` for a problem in a file or a parameter the user gave, naming
where (file, line, field) and what was expected. The CLI turns it into a one-line message and exit
code 2; anything else escaping a reader is a bug in jiggle, not in the user's data.
"""
from __future__ import annotations

import os


class InputError(ValueError):
    """A user's file or parameter is unusable.

    Parameters
    ----------
    message : what is wrong and what was expected.
    path : the file (or None for a parameter).
    line : 1-based line number in that file, when known.
    field : the field, key, channel or parameter concerned, when known.
    """

    def __init__(self, message: str, path: str | os.PathLike | None = None,
                 line: int | None = None, field: str | None = None):
        self.message = message
        self.path = None if path is None else os.fspath(path)
        self.line = line
        self.field = field
        super().__init__(str(self))

    def __str__(self) -> str:
        where = ""
        if self.path is not None:
            where = self.path
            if self.line is not None:
                where += f":{self.line}"
            where += ": "
        if self.field is not None:
            where += f"{self.field}: "
        return where + self.message

    def __reduce__(self):
        return (type(self), (self.message, self.path, self.line, self.field))


def require_file(path: str | os.PathLike, what: str = "file") -> str:
    """Return `path` as str, or raise InputError if it is not a readable file."""
    p = os.fspath(path)
    if not os.path.exists(p):
        raise InputError(f"{what} not found", p)
    if os.path.isdir(p):
        raise InputError(f"expected a {what}, found a directory", p)
    if not os.access(p, os.R_OK):
        raise InputError(f"{what} is not readable", p)
    return p


class JiggleWarning(UserWarning):
    """Something in the user's input was repaired or looks wrong, and jiggle went on (for example
    weights renormalised, degenerate faces dropped, an implausible height). The CLI prints these as
    one line: ``jiggle: warning: ...``."""
