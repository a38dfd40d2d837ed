"""Shared checks for the spec-error tests."""

import pytest

from jmlgdsl.compile.lower import compile_text
from jmlgdsl.errors import SpecError


def errors_of(text, path):
    """The diagnostics of a spec that must fail to compile."""
    with pytest.raises(SpecError) as info:
        compile_text(text, path)
    return info.value.diagnostics


def assert_located(text, path, line, column, fragment):
    """Compiling `text` reports `fragment` at path:line:column, shown with its source line and a caret."""
    diagnostics = errors_of(text, path)
    found = [d for d in diagnostics if fragment in d.message]
    assert found, f"no diagnostic containing {fragment!r} in {[d.format() for d in diagnostics]}"
    d = found[0]
    assert (d.file, d.line, d.column) == (path, line, column), d.format()
    shown = d.format().splitlines()
    assert shown[0].startswith(f"{path}:{line}:{column}: ")
    assert shown[1].strip() == text.splitlines()[line - 1].strip()
    assert shown[2].index("^") - 4 == column - 1
