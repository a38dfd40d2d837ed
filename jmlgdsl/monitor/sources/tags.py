"""The tag file (TOML): how each spec input and output is found on a data bus and turned into the
spec's unit.

    [tags.temp]
    topic = "line4/dryer/temp_C"      # MQTT topic (default PREFIX/temp)
    node = "ns=2;s=Dryer.Temp"        # OPC UA node id (an OPC UA source needs one per name)
    metric = "Dryer/Air temperature"  # Sparkplug B metric name (default temp)
    scale = 1.0                       # value in the spec's unit = scale * reading + offset
    offset = 0.0
    time = "source"                   # the reading's own time stamp ("source", the default) or its
                                      # arrival time ("arrival")
    stale = 30                        # seconds without a reading before the tag is stale

Every spec name is a tag, with the defaults above, whether the file names it or not; a name the spec
does not have, or a key the table does not know, is an error naming the file and the tag.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass

from ...errors import JmlgError
from ...names import suggest

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - the Python 3.10 backport
    import tomli as tomllib

KEYS = {"topic", "node", "metric", "scale", "offset", "time", "stale"}
TIMES = ("source", "arrival")


class TagError(JmlgError):
    """A tag file that cannot be used: not TOML, an unknown name or key, a value of the wrong kind."""


@dataclass(frozen=True)
class Tag:
    """One spec name on the bus: where it is read, how its value is scaled, which time it carries."""

    name: str
    output: bool  # an output (a measurement); else an input
    topic: str | None = None
    node: str | None = None
    metric: str | None = None  # None: the spec name
    scale: float = 1.0
    offset: float = 0.0
    time: str = "source"
    stale: float | None = None  # None: the monitor's --stale

    def value(self, reading: float) -> float:
        """A reading in the spec's unit."""
        return self.scale * reading + self.offset


def read_tags(path, model) -> dict[str, Tag]:
    """{name: Tag} for every output and input of the model, from a tag file (None: all defaults)."""
    table = {}
    if path is not None:
        try:
            with open(path, "rb") as stream:
                table = tomllib.load(stream)
        except OSError as exc:
            raise TagError(f"--tags: cannot read {path}: {exc.strerror}") from None
        except tomllib.TOMLDecodeError as exc:
            raise TagError(f"{path}: not a TOML tag file ({exc})") from None
        unknown = set(table) - {"tags"}
        if unknown:
            raise TagError(f"{path}: unknown table {sorted(unknown)[0]!r}; tags go under [tags.NAME]")
        table = table.get("tags", {})
    names = list(model.outputs) + list(model.inputs)
    for name in table:
        if name not in names:
            raise TagError(f"{path}: [tags.{name}]: the spec has no input or output {name!r}"
                           f"{suggest(name, names)}")
    return {name: _tag(path, name, name in model.outputs, table.get(name, {})) for name in names}


def _tag(path, name, output, entry) -> Tag:
    where = f"{path}: [tags.{name}]"
    if not isinstance(entry, dict):
        raise TagError(f"{where}: expected a table of keys ({', '.join(sorted(KEYS))})")
    for key in entry:
        if key not in KEYS:
            raise TagError(f"{where}: unknown key {key!r}{suggest(key, sorted(KEYS))}")
    for key in ("topic", "node", "metric"):
        if key in entry and not isinstance(entry[key], str):
            raise TagError(f"{where}: {key} must be a string")
    for key in ("scale", "offset", "stale"):
        value = entry.get(key)
        if value is not None and (isinstance(value, bool) or not isinstance(value, (int, float))
                                  or not math.isfinite(value)):
            raise TagError(f"{where}: {key} must be a finite number, got {value!r}")
    if entry.get("scale") == 0:
        raise TagError(f"{where}: scale 0 would make every reading the offset")
    if entry.get("stale") is not None and entry["stale"] <= 0:
        raise TagError(f"{where}: stale must be a positive number of seconds")
    if entry.get("time", "source") not in TIMES:
        raise TagError(f"{where}: time must be \"source\" or \"arrival\", got {entry['time']!r}")
    return Tag(name, output, entry.get("topic"), entry.get("node"), entry.get("metric"),
               float(entry.get("scale", 1.0)), float(entry.get("offset", 0.0)), entry.get("time", "source"),
               None if entry.get("stale") is None else float(entry["stale"]))
