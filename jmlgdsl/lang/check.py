"""Check a spec: parse it (lang.parse), check its declarations (lang.declarations), then evaluate every
mode's values (lang.values) into the checked Plant (lang.plant) that the compiler lowers. These are
the checker's entry points, from a parsed spec, a file or text."""

from __future__ import annotations

from ..errors import Diagnostic, SpecError
from . import syntax as S
from .declarations import declare
from .parse import parse_file, parse_text
from .plant import Equations, Plant
from .diagnostics import Report
from .values import evaluate


def check_spec_file(path, values: dict | None = None) -> tuple[Plant, Report]:
    """Parse and check a .jmlg spec file (check())."""
    return check(parse_file(path), values)


def check_text(text: str, path: str = "<spec>") -> tuple[Plant, Report]:
    """Parse and check spec text (check()); `path` is only used in messages."""
    return check(parse_text(text, path))


def check_ode_file(path, purpose: str) -> tuple[Plant, Report]:
    """Parse and check a spec file that must describe an ODE plant, for `purpose` (SpecError otherwise,
    once its declarations are checked)."""
    declared, report = declare(parse_file(path))
    if not declared.spec.ode:
        raise SpecError([Diagnostic(f"{purpose} needs a nonlinear plant, and this spec has no 'ode' block",
                                    str(path))])
    return evaluate(declared, report), report


def check(spec: S.Spec, values: dict | None = None, ode: Equations | None = None) -> tuple[Plant, Report]:
    """Resolve a parsed spec into a Plant: its declarations (declare()), then the values of its modes
    (evaluate()). Unknowns (priors) take `values` by name, or their priors' medians with a warning each
    (lang.unknowns); `ode` is evaluate()'s."""
    declared, report = declare(spec, values)
    return evaluate(declared, report, ode), report
