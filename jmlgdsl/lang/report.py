"""Collects located diagnostics while checking and compiling a spec, so that every error in a file
is reported at once; warnings are issued as SpecWarning."""

from __future__ import annotations

import warnings

from ..errors import Diagnostic, SpecError, SpecWarning
from .syntax import Pos


class Report:
    """Diagnostics for one source file."""

    def __init__(self, path: str, lines: list[str]):
        self.path = path
        self.lines = lines
        self.errors: list[Diagnostic] = []
        self.warnings: list[Diagnostic] = []

    def _diagnostic(self, message: str, pos: Pos | None, severity: str) -> Diagnostic:
        pos = pos or Pos()
        src = self.lines[pos.line - 1] if 0 < pos.line <= len(self.lines) else None
        return Diagnostic(message, self.path, pos.line, pos.column, src, severity)

    def error(self, message: str, pos: Pos | None = None):
        d = self._diagnostic(message, pos, "error")
        if d not in self.errors:
            self.errors.append(d)

    def warn(self, message: str, pos: Pos | None = None):
        self.warnings.append(self._diagnostic(message, pos, "warning"))

    def raise_errors(self):
        """Raise SpecError holding every error reported so far, in source order."""
        if self.errors:
            raise SpecError(sorted(self.errors, key=lambda d: (d.line, d.column)))

    def finish(self):
        """Raise the errors, if any; otherwise issue the warnings as SpecWarning."""
        self.raise_errors()
        for w in self.warnings:
            warnings.warn(SpecWarning(w), stacklevel=3)
