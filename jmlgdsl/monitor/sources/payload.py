"""Payloads of a data bus read as readings: a number, `{"t": ..., "v": ...}` for one tag, or one
object per sample holding several names, `{"t": ..., "temp": ..., "current": ...}`.

The time `t` is in seconds (since 1970 or since any fixed origin) or an ISO 8601 time stamp (UTC
unless it says otherwise); without it a reading takes its arrival time. JSON `null` is a reading
that says "not measured". Anything else (text, NaN, an infinite or absurdly large number, JSON of
another shape) is `Malformed`, with a message that names the tag and shows the payload.

Every payload is read within bounds, so that none can stop the reader: at most MAX_PAYLOAD bytes,
brackets nested at most MAX_DEPTH deep, numbers of at most MAX_DIGITS characters; beyond them it is
`Malformed` before the JSON parser sees it.
"""

from __future__ import annotations

import json
import math
import re
from datetime import datetime, timezone

from ...infer.online import MAX_READING

SHOWN = 60  # characters of a bad payload quoted in its message
MAX_PAYLOAD = 1 << 16  # bytes: a sample of a thousand names fits many times over
MAX_DEPTH = 8  # brackets within brackets: a reading needs one level, an object of names
MAX_DIGITS = 40  # characters of one number: a double's 17 significant digits with room for zeros and exponent
_STRINGS = re.compile(r'"(?:[^"\\]|\\.)*"')  # JSON strings, whose brackets do not nest
_BRACKETS = re.compile(r"[\[\]{}]")


class Malformed(ValueError):
    """A payload that is not a reading; its message says which tag and shows the payload."""


def decode(payload: bytes, name: str | None, names) -> list[tuple[str, float, float | datetime | None]]:
    """(name, value, time or None) for each reading in a payload: of tag `name`, or with name None an
    object keyed by the spec's `names` (keys it does not know are left alone). A time is seconds, or
    a datetime where the payload writes an ISO 8601 time stamp."""
    who = name or "sample"
    if len(payload) > MAX_PAYLOAD:
        raise Malformed(f"{who}: payload {shown(payload)} of {len(payload):,} bytes is longer than a reading can "
                        f"be ({MAX_PAYLOAD:,} bytes)")
    try:
        text = payload.decode("utf-8").strip()
    except UnicodeDecodeError:
        raise Malformed(f"{who}: payload {shown(payload)} is not UTF-8 text") from None
    if name is not None and _plain_number(text):
        return [(name, number(float(text), name, text), None)]
    if _depth(text) > MAX_DEPTH:
        raise Malformed(f"{who}: payload {shown(text)} nests brackets more than {MAX_DEPTH} deep; a reading is "
                        "a number or one object")
    try:
        data = json.loads(text, parse_constant=lambda constant: constant, parse_int=_bounded(int),
                          parse_float=_bounded(float))
    except _TooLong as exc:
        raise Malformed(f"{who}: payload {shown(text)}: the number {shown(str(exc))} has more than {MAX_DIGITS} "
                        "characters") from None
    except ValueError:
        raise Malformed(f"{who}: payload {shown(text)} is neither a number nor JSON") from None
    if name is not None:
        if isinstance(data, dict) and "v" in data and set(data) <= {"t", "v"}:
            return [(name, number(data["v"], name, text), _time(data.get("t"), name, text))]
        raise Malformed(f"{name}: payload {shown(text)} is not a number or {{\"t\": ..., \"v\": ...}}")
    if not isinstance(data, dict):
        raise Malformed(f"sample: payload {shown(text)} is not a JSON object of names and values")
    time = _time(data.get("t"), "sample", text)
    found = [(key, number(data[key], key, text), time) for key in names if key in data]
    if not found:
        raise Malformed(f"sample: payload {shown(text)} holds none of the names {', '.join(names)}")
    return found


class _TooLong(ValueError):
    """A number in a payload with more than MAX_DIGITS characters (its text the message)."""


def _bounded(kind):
    """The JSON parser's reader of a number's text as `kind`, refusing one of more than MAX_DIGITS
    characters (a 400-digit integer is no measurement, and no float holds it)."""
    def read(text):
        if len(text) > MAX_DIGITS:
            raise _TooLong(text)
        return kind(text)
    return read


def _depth(text: str) -> int:
    """How deep the brackets of a JSON text nest (those in its strings left out)."""
    depth = deepest = 0
    for bracket in _BRACKETS.findall(_STRINGS.sub("", text)):
        depth += 1 if bracket in "[{" else -1
        deepest = max(deepest, depth)
    return deepest


def shown(payload) -> str:
    """A payload as a message quotes it: repr, cut to SHOWN characters."""
    text = repr(payload if isinstance(payload, str) else bytes(payload))
    return text if len(text) <= SHOWN else text[:SHOWN] + "…"


def _plain_number(text: str) -> bool:
    """A number as a logger writes it: ASCII digits with a sign, point and exponent ('nan' and 'inf'
    have no digit, so they are not), of at most MAX_DIGITS characters."""
    try:
        float(text)
    except ValueError:
        return False
    return text.isascii() and "_" not in text and any(c.isdigit() for c in text) and len(text) <= MAX_DIGITS


def number(value, name, text) -> float:
    """A reading's value as a float (None: NaN, not measured); anything else, or a number too large
    to be a measurement, is Malformed, quoting `text` (the payload it came in)."""
    if value is None:
        return math.nan
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise Malformed(f"{name}: payload {shown(text)}: the value {shown(str(value))} is not a number")
    try:
        number = float(value)
    except OverflowError:
        number = math.inf
    if not abs(number) < MAX_READING:
        raise Malformed(f"{name}: payload {shown(text)}: the value {value!r} is not a finite measurement "
                        f"(beyond {MAX_READING:g} in size)")
    return number


def _time(value, name, text) -> float | datetime | None:
    """Seconds from a number, or the time (aware, UTC unless it says otherwise) of an ISO 8601 time
    stamp, so that what is said of it can be written as the source writes it; None when absent."""
    if value is None:
        return None
    if isinstance(value, str):
        try:
            stamp = datetime.fromisoformat(value.replace("Z", "+00:00"))
            stamp = stamp if stamp.tzinfo else stamp.replace(tzinfo=timezone.utc)
            stamp.timestamp()  # one that has no place in seconds since 1970 is no time a reading has
            return stamp
        except (ValueError, OverflowError):
            raise Malformed(f"{name}: payload {shown(text)}: t {shown(value)} is not an ISO 8601 time stamp") \
                from None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not abs(value) <= 1e11:
        raise Malformed(f"{name}: payload {shown(text)}: t {shown(str(value))} is not a time in seconds")
    return float(value)
