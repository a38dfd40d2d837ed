"""The package's version: one place, read by the package, its build (pyproject.toml) and the
checkpoints it writes (state saved by one version is not resumed by another)."""

VERSION = "0.1.0"
