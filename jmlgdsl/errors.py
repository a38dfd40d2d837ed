"""User-facing errors: located diagnostics for specs and data, printed without a traceback."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Diagnostic:
    """One message tied to a place in a source file (line and column are 1-based; 0 = unknown)."""

    message: str
    file: str = "<spec>"
    line: int = 0
    column: int = 0
    source_line: str | None = None
    severity: str = "error"

    def format(self) -> str:
        where = self.file
        if self.line:
            where += f":{self.line}"
            if self.column:
                where += f":{self.column}"
        label = "" if self.severity == "error" else f"{self.severity}: "
        text = f"{where}: {label}{self.message}"
        if self.source_line is not None and self.line:
            text += "\n    " + self.source_line.rstrip("\n")
            if self.column:
                text += "\n    " + " " * (self.column - 1) + "^"
        return text


class JmlgError(Exception):
    """Base for every error a user can cause; the command line prints it and exits with status 2."""


class SpecError(JmlgError):
    """A .jmlg spec that does not parse, check or compile; carries every diagnostic found."""

    def __init__(self, diagnostics):
        self.diagnostics = list(diagnostics)
        super().__init__("\n".join(d.format() for d in self.diagnostics))


class DataError(JmlgError):
    """Bad input data (a CSV with a missing column, a non-numeric cell, an unknown mode name, ...)."""


class SpecWarning(UserWarning):
    """Something in a spec that compiles but deserves a look (a renormalised row, an unstable mode)."""

    def __init__(self, diagnostic: Diagnostic):
        self.diagnostic = diagnostic
        super().__init__(diagnostic.format())
