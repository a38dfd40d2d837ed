"""One source per unit of a fleet, as one source (a file or an OPC UA session per unit)."""

from __future__ import annotations

import dataclasses
import threading

from .contract import End, Readings, Unreadable


class UnitSources:
    """One source per unit, as one source of a fleet: each unit's items handed over as (unit index,
    item), its acknowledgement tokens as (unit index, token), its position as the list of the
    units' positions; the data end once every unit's have."""

    def __init__(self, sources, name: str):
        self.sources, self.name = list(sources), name
        self.rows = self.sources[0].rows
        self._ended, self._lock = 0, threading.Lock()

    def start(self, put, positions):
        def unit_put(i):
            def handed(item):
                if isinstance(item, (Readings, Unreadable)):
                    item = dataclasses.replace(item, token=(i, item.token))
                if isinstance(item, End):
                    with self._lock:  # the sources' threads end at their own moments
                        self._ended += 1
                        last = self._ended == len(self.sources)
                    if last:
                        put((None, item))
                    return
                put((i, item))
            return handed

        for i, (source, position) in enumerate(zip(self.sources, positions)):
            source.start(unit_put(i), position)

    def acknowledge(self, tokens):
        mine = [[] for _ in self.sources]
        for i, token in tokens:
            mine[i].append(token)
        for source, given in zip(self.sources, mine):
            if given:
                source.acknowledge(given)

    def stop(self):
        for source in self.sources:
            source.stop()
