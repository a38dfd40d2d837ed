"""How messages word names and counts: did-you-mean suggestions for misspelt names, shared by the
language and the data readers, and plurals."""

from __future__ import annotations

import difflib


def suggest(name: str, candidates) -> str:
    """'; did you mean 'x'?' for the closest candidate, or '' when none is close."""
    close = difflib.get_close_matches(name, list(candidates), n=1, cutoff=0.6)
    return f"; did you mean {close[0]!r}?" if close else ""


def plural(count: int, noun: str) -> str:
    """'1 step', '2 steps'."""
    return f"{count} {noun}{'' if count == 1 else 's'}"
