"""Argument types of the commands: a value out of range is refused by argparse, naming the option,
before any work starts."""

from __future__ import annotations

import argparse
import math


def whole(least: int):
    """An argparse type: a whole number >= least."""
    def parse(text):
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a whole number, not {text!r}") from None
        if value < least:
            raise argparse.ArgumentTypeError(f"must be at least {least}, not {value}")
        return value
    parse.__name__ = f"whole number >= {least}"
    return parse


def finite(text) -> float:
    """An argparse type: a finite number."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, not {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, not {text!r}")
    return value


def positive(text) -> float:
    """An argparse type: a finite number > 0."""
    value = finite(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be positive, not {text}")
    return value


def probability(text) -> float:
    """An argparse type: a number in [0, 1]."""
    value = finite(text)
    if not 0 <= value <= 1:
        raise argparse.ArgumentTypeError(f"must be a probability (0 to 1), not {text}")
    return value


def names(text: str) -> tuple[str, ...]:
    """An argparse type: names (of modes, of columns) from comma-separated text."""
    return tuple(n.strip() for n in text.split(",") if n.strip())


def listed(kind):
    """An argparse type: a comma-separated list of `kind`."""
    def parse(text):
        try:
            return tuple(kind(item) for item in text.split(",") if item.strip())
        except ValueError:
            raise ValueError(text) from None
    parse.__name__ = f"comma-separated {kind.__name__} list"
    return parse


def lags(text):
    """An argparse type: smoothing lags from 'L,L,...', whole numbers >= 0 or 'offline' (None)."""
    found = []
    for item in (i.strip() for i in text.split(",") if i.strip()):
        if item.lower() in ("offline", "off-line", "none"):
            found.append(None)
        elif item.isdigit():
            found.append(int(item))
        else:
            raise ValueError(text)
    return tuple(dict.fromkeys(found))


lags.__name__ = "comma-separated list of lags (whole numbers or 'offline')"


def catch_all(text: str):
    """An argparse type for `learn --catch-all`: (name, scale) from NAME=SCALE, (name, None) from NAME
    (the scale chosen by cross-validation), None from none, "auto" as it is."""
    if text in ("auto", "none"):
        return None if text == "none" else text
    name, sep, scale = text.partition("=")
    try:
        value = float(scale) if sep else None
    except ValueError:
        value = float("nan")
    if not (name.isidentifier() and (value is None or value > 1)):
        raise argparse.ArgumentTypeError(f"expected NAME, NAME=SCALE with a scale above 1, or none, not {text!r}")
    return name, value
