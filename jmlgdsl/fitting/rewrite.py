"""The fitted spec: the user's own text with each prior replaced by its fitted value and a comment
that keeps the estimate's standard error and the prior it came from, so the file reads as before.
A line of one unknown keeps its comment at its end; a line of several, or one that would grow past
WIDTH characters, has a comment line of its own below it for each."""

from __future__ import annotations

import math

from ..lang.syntax import Pos, Spec

WIDTH = 100  # characters a line of the fitted spec with its comment at its end may take


def fitted_text(spec: Spec, unknowns, estimate, se, header: str = "") -> str:
    """The spec's text with `U ~ Prior(...)` written `U = value  # fitted U = value ± se, prior Prior(...)`
    (a noise level `measurement value`); `header` lines go first, as comments."""
    text = "\n".join(spec.lines) + "\n"
    starts = [0]
    for line in spec.lines:
        starts.append(starts[-1] + len(line) + 1)

    def offset(pos: Pos) -> int:
        return starts[pos.line - 1] + pos.column - 1

    edits, comments = [], {}
    for u, value, error in zip(unknowns, estimate, se):
        a, b = offset(u.pos), offset(u.end)
        prior = " ".join(text[a:b].split("~", 1)[1].split())
        name = u.name.rsplit(".", 1)[-1]
        edits.append((a, b, f"{name} {value:.10g}" if ".noise." in f".{u.name}" else f"{name} = {value:.10g}"))
        shown = "se unknown" if not math.isfinite(error) else f"± {error:.2g}"
        comments.setdefault(u.end.line - 1, []).append(f"fitted {u.name} = {value:.4g} {shown}, prior {prior}")
    for line, notes in comments.items():
        original, end = spec.lines[line], starts[line] + len(spec.lines[line])
        hash_at = _comment_column(original)
        grown = sum(len(new) - (b - a) for a, b, new in edits if starts[line] <= a and b <= end)
        if len(notes) > 1 or len(original) + grown + len(notes[0]) + 4 > WIDTH:
            indent = original[:len(original) - len(original.lstrip())] + "    "
            edits.append((end, end, "".join(f"\n{indent}# {note}" for note in notes)))
        elif hash_at is None:
            edits.append((end, end, f"  # {notes[0]}"))
        else:
            edits.append((starts[line] + hash_at, starts[line] + hash_at + 1, f"# {notes[0]};"))
    for a, b, new in sorted(edits, reverse=True):
        text = text[:a] + new + text[b:]
    lead = "".join(f"# {line}\n" if line else "#\n" for line in header.splitlines())
    return lead + text


def _comment_column(line: str) -> int | None:
    """Where a line's `#` comment starts (outside a quoted description), or None."""
    quoted = False
    for i, ch in enumerate(line):
        if ch == '"':
            quoted = not quoted
        elif ch == "#" and not quoted:
            return i
    return None
