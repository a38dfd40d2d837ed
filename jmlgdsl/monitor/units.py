"""The units of a fleet: many units of one plant (pumps, dryers, gearboxes of one design) watched by one monitor
with one spec. `--units pump01..pump200` names the units; `{unit}` in the source and in the tag
file stands for each unit's name:

    mqtt://HOST:PORT/PREFIX          topics PREFIX/{unit}/NAME (and PREFIX/{unit} for objects of
                                     several names), on one connection; or a tag file's topics
                                     with {unit} in them
    data/{unit}.csv                  a file per unit, each followed as it grows
    opc.tcp://HOST:PORT/PATH         a tag file whose node ids hold {unit}: a session per unit

Each unit has its run in the store (the run's `unit` column names it) and every commit holds the
rows and state of every unit that moved (jmlgdsl.monitor.live). A source that reads each unit on
a connection of its own is one source of them all (jmlgdsl.monitor.sources.units).

    >>> unit_names("pump01..pump03,spare")
    ['pump01', 'pump02', 'pump03', 'spare']
"""

from __future__ import annotations

import dataclasses
import re

from ..errors import JmlgError

PLACEHOLDER = "{unit}"
RANGE = re.compile(r"^(?P<stem>.*?)(?P<first>\d+)\.\.(?P=stem)(?P<last>\d+)$")
NAME = re.compile(r"^[A-Za-z0-9_.-]+$")  # a unit's name goes into topics, file names and SQL values


# the fleet's options on the command line (flag -> argparse's keywords); --shards is the command's own
COMMAND_LINE = {
    "--units": dict(metavar="NAMES", help="watch the units of a fleet with one spec: names and ranges such as "
                    "pump01..pump200,spare; {unit} in --source and in the tag file stands for each one's name (a CSV "
                    "file per unit, data/{unit}.csv; MQTT topics PREFIX/{unit}/NAME on one connection; OPC UA node "
                    "ids). Each unit has its own run in the store, named by its unit column (docs/fleet.md)"),
    "--unit-specs": dict(metavar="DIR", help="with --units: diagnose each unit with its own spec DIR/UNIT.jmlg (the "
                         "spec fitted to that unit: jmlgdsl fit SPEC units/*.csv -o DIR/), SPEC for a unit without "
                         "one; its run records its spec, and the units still step together, each under its own "
                         "numbers"),
    "--cluster": dict(metavar="auto|HOST:PORT", help="with --units: spread the units over a Ray cluster, a shard of "
                      "units per actor, each with its own connection to the source and the store (auto: a Ray on this "
                      "machine for this command, reachable from 127.0.0.1 only; HOST:PORT: a cluster started with ray "
                      "start --head). A shard whose process dies is started again and resumes from its last commit. "
                      "Needs pip install 'jmlgdsl[cluster]'"),
}


class FleetError(JmlgError):
    """A unit list or a template that cannot name a fleet's units."""


def unit_names(text: str) -> list[str]:
    """The unit names of `--units`: comma-separated names and ranges STEM01..STEM20 (the digits'
    width kept, as in pump001..pump120), each name once."""
    names = []
    for item in (part.strip() for part in text.split(",")):
        found = RANGE.match(item)
        if found:
            first, last = found["first"], found["last"]
            if int(last) < int(first):
                raise FleetError(f"--units {item}: the range runs backwards")
            width = len(first) if first.startswith("0") or len(first) == len(last) else 0
            names += [f"{found['stem']}{n:0{width}d}" for n in range(int(first), int(last) + 1)]
        elif NAME.match(item) and ".." not in item:
            names.append(item)
        else:
            raise FleetError(f"--units {text}: {item!r} is not a unit name (letters, digits, _ . -) nor a range "
                             "such as pump01..pump20")
    twice = sorted({name for name in names if names.count(name) > 1})
    if twice:
        raise FleetError(f"--units {text}: unit {twice[0]} is named twice")
    return names


def for_unit(template: str | None, unit: str) -> str | None:
    """A template with {unit} replaced by a unit's name."""
    return None if template is None else template.replace(PLACEHOLDER, unit)


def unit_tags(tags: dict, unit: str) -> dict:
    """A tag file's tags for one unit (its topics and node ids with {unit} replaced)."""
    return {name: dataclasses.replace(tag, topic=for_unit(tag.topic, unit), node=for_unit(tag.node, unit))
            for name, tag in tags.items()}
