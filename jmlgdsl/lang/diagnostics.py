"""Where a spec says something, and what the checker and the compiler say about it: a source position
(Pos) and the Report that collects a file's located diagnostics (errors, at most MAX_ERRORS of them
shown, and warnings) and raises or issues them. The syntax tree, every checking step and the compiler
report through it; it knows nothing of the plant."""

from __future__ import annotations

import warnings
from contextlib import contextmanager
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
        self.held: list[tuple[str, Pos | None]] = []  # errors held back (holding()) until release()
        self._holding = False

    def _diagnostic(self, message: str, pos: Pos | None, severity: str) -> Diagnostic:
        pos = pos or Pos()
        src = self.lines[pos.line - 1] if 0 < pos.line <= len(self.lines) else None
        return Diagnostic(message, self.path, pos.line, pos.column, src, severity)

    def error(self, message: str, pos: Pos | None = None):
        """Record an error; a repeat of one already recorded is dropped."""
        if self._holding:
            self.held.append((message, pos))
            return
        d = self._diagnostic(message, pos, "error")
        if d not in self._seen:
            self._seen.add(d)
            if len(self.errors) < MAX_ERRORS:
                self.errors.append(d)

    @contextmanager
    def holding(self):
        """Hold back the errors reported inside, until release(): the checker's, in the values the compiler
        applies last, so that one that fails before it gets there (a mode without a steady state)
        reports that alone."""
        self._holding = True
        try:
            yield
        finally:
            self._holding = False

    def release(self):
        """Record the errors held back."""
        held, self.held = self.held, []
        for message, pos in held:
            self.error(message, pos)

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
