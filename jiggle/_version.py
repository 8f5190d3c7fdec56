"""jiggle's version, in one place: pyproject.toml reads it (dynamic version), as do `jiggle --version` and
`jiggle.__version__`."""
__version__ = "0.1.0"
