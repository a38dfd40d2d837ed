"""Durations: the language writes times in s, min or h; the model keeps seconds."""

from __future__ import annotations

from ..names import suggest
from .diagnostics import Report
from .syntax import Name

SECONDS = {"s": 1.0, "sec": 1.0, "min": 60.0, "h": 3600.0, "hr": 3600.0}


def time_in_seconds(value: float, unit: Name, report: Report) -> float:
    """value × unit in seconds; an unknown unit is reported at its position (and taken as seconds)."""
    if unit.text not in SECONDS:
        report.error(f"unknown time unit {unit.text!r}; use s, min or h{suggest(unit.text, SECONDS)}", unit.pos)
        return value
    return value * SECONDS[unit.text]
