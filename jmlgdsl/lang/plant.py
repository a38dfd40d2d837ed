"""The checked plant: what the checker (jmlgdsl.lang.check) hands to the compiler (jmlgdsl.compile).
So far the positions and the report that located diagnostics go to, while checking and compiling:
the compiler reports what it finds through them."""

from __future__ import annotations

import warnings
from dataclasses import dataclass

from ..errors import Diagnostic, SpecError, SpecWarning
from .limits import MAX_ERRORS


@dataclass(frozen=True)
class Pos:
    """A 1-based line and column in the source file."""

    line: int = 0
    column: int = 0


class Report:
    """Diagnostics for one source file."""

    def __init__(self, path: str, lines: list[str]):
        self.path = path
        self.lines = lines
        self.errors: list[Diagnostic] = []  # the first MAX_ERRORS distinct errors, in the order reported
        self.warnings: list[Diagnostic] = []
        self._seen: set[Diagnostic] = set()  # every distinct error: repeats are dropped in constant time

    def _diagnostic(self, message: str, pos: Pos | None, severity: str) -> Diagnostic:
        pos = pos or Pos()
        src = self.lines[pos.line - 1] if 0 < pos.line <= len(self.lines) else None
        return Diagnostic(message, self.path, pos.line, pos.column, src, severity)

    def error(self, message: str, pos: Pos | None = None):
        """Record an error; a repeat of one already recorded is dropped."""
        d = self._diagnostic(message, pos, "error")
        if d not in self._seen:
            self._seen.add(d)
            if len(self.errors) < MAX_ERRORS:
                self.errors.append(d)

    @property
    def error_count(self) -> int:
        """How many distinct errors have been reported, shown or not."""
        return len(self._seen)

    def warn(self, message: str, pos: Pos | None = None):
        self.warnings.append(self._diagnostic(message, pos, "warning"))

    def raise_errors(self):
        """Raise SpecError holding the errors reported so far, in source order: at most MAX_ERRORS of
        them, and a last line that counts the others."""
        if self.errors:
            shown = sorted(self.errors, key=lambda d: (d.line, d.column))
            more = self.error_count - len(self.errors)
            if more:
                shown.append(Diagnostic(f"... and {more:,} more error{'s' if more > 1 else ''}", self.path))
            raise SpecError(shown)

    def finish(self):
        """Raise the errors, if any; otherwise issue the warnings as SpecWarning."""
        self.raise_errors()
        for w in self.warnings:
            warnings.warn(SpecWarning(w), stacklevel=3)
