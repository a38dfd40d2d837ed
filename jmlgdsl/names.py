"""How messages word names and counts: did-you-mean suggestions for misspelt names, shared by the
language and the data readers, plurals, and runs of row numbers."""

from __future__ import annotations

import difflib


def suggest(name: str, candidates) -> str:
    """'; did you mean 'x'?' for the closest candidate, or '' when none is close."""
    close = difflib.get_close_matches(name, list(candidates), n=1, cutoff=0.6)
    return f"; did you mean {close[0]!r}?" if close else ""


def plural(count: int, noun: str) -> str:
    """'1 step', '2 steps'."""
    return f"{count} {noun}{'' if count == 1 else 's'}"


def spans(numbers, shown: int = 10) -> str:
    """'3, 7-9, 12' for increasing whole numbers, the first `shown` runs of them and how many more."""
    runs = []
    for n in numbers:
        if runs and n == runs[-1][1] + 1:
            runs[-1][1] = n
        else:
            runs.append([n, n])
    text = ", ".join(f"{a}" if a == b else f"{a}-{b}" for a, b in runs[:shown])
    return text + (f" and {plural(len(runs) - shown, 'more run')}" if len(runs) > shown else "")
