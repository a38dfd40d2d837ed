"""What the operator's page shows, as JSON built from a monitor's store: the run, a window of rows,
the alarms with their ISA-18.2 states, the evidence behind an alarm, and a fleet's units worst first.

Every number comes through the store's queries (jmlgdsl.monitor.store): a window of rows costs one
query, its vectors (float64s) read back as they were computed and written as JSON numbers in their
shortest round-trip digits, null for NaN (a reading not measured).
"""

from __future__ import annotations

import json
import math
from typing import NamedTuple

from ..monitor.store import Finished, Run, Store

LIVE_ROWS = 300  # rows a page shows when it follows the live end of the data
MAX_ROWS = 5_000  # rows one request may return; a wider window is thinned to fit


def run_info(store: Store, run: Run, token_required: bool) -> dict:
    """The run's names, units, mode descriptions and alarm rule, whether actions need a token, and the
    run's unit with every unit of the store's fleet (none for one plant)."""
    return {"id": run.id, "plant": run.plant, "modes": run.modes, "outputs": run.outputs, "inputs": run.inputs,
            "descriptions": run.descriptions, "units": run.engineering_units, "healthy": run.options.get("healthy", []),
            "filter": run.options.get("algorithm"), "lag": run.options.get("lag", 0),
            "source": run.options.get("source"), "token_required": token_required, "unit": run.unit,
            "fleet": store.units()}


class Rows(NamedTuple):
    """A window of rows as the page's JSON, with how many rows it holds and the last one's t."""

    json: str
    count: int
    last: int | None


def rows(store: Store, run: Run, *, after: int | None = None, first: int | None = None, last: int | None = None,
         limit: int = MAX_ROWS) -> Rows:
    """A window of finished rows as JSON columns (t, time, map_mode, alarm, posterior, y, y_pred,
    y_sd, evidence_mode, evidence): the rows after t = `after` (the live feed, at most `limit`), or
    those with `first` <= t <= `last`, thinned to at most `limit` by taking every k-th; with none of
    them, the last LIVE_ROWS rows. Rows of a damaged store that cannot be read are left out."""
    limit = max(1, min(int(limit), MAX_ROWS))
    if after is not None:
        found = store.results(run, int(after) + 1, limit=limit)
    elif first is not None or last is not None:
        low, high = int(first or 1), int(last) if last is not None else store.last_t(run.id)
        found = store.results(run, low, high, every=max(1, -(-(high - low + 1) // limit)))
    else:
        found = store.results(run, store.last_t(run.id) - LIVE_ROWS + 1)
    return Rows(_columns(found), len(found), found[-1].t if found else None)


VECTORS = ("posterior", "y", "y_pred", "y_sd", "evidence")  # the columns that hold vectors


def _columns(found: list[Finished]) -> str:
    """Finished rows as the page's JSON columns (a vector's NaN as null)."""
    columns = list(zip(*found)) or [()] * len(Finished._fields)
    return "{" + ",".join(
        f'"{name}":' + (json.dumps(list(column), separators=(",", ":")).replace("NaN", "null")
                        if name in VECTORS else json.dumps(list(column)))
        for name, column in zip(Finished._fields, columns)) + "}"


def alarms(store: Store, run: Run) -> list[dict]:
    """The run's alarms, newest first, with their state, who acknowledged or shelved them, and why."""
    return [{"id": a.id, "raised_t": a.raised_t, "raised_time": a.raised_time, "cleared_t": a.cleared_t,
             "cleared_time": a.cleared_time, "mode": a.mode, "state": a.state,
             "acknowledged": None if a.acknowledged is None else dict(zip(("who", "at"), a.acknowledged)),
             "shelved": None if a.shelved is None else dict(zip(("who", "at", "reason"), a.shelved))}
            for a in reversed(store.alarms(run.id))]


def evidence(store: Store, run: Run, alarm: int) -> dict:
    """The evidence behind an alarm: each output's share of the log-likelihood ratio of the alarm's
    mode against the healthy modes, summed over the alarm's rows (up to its clearing or the last row),
    with the row count; outputs without evidence kept are left out."""
    found = {a.id: a for a in store.alarms(run.id)}.get(alarm)
    if found is None:
        return {"alarm": alarm, "rows": 0, "outputs": []}
    end = found.cleared_t - 1 if found.cleared_t is not None else store.last_t(run.id)
    total, rows = {}, 0
    for _, mode, terms in store.evidence(run, found.raised_t, end):  # a damaged store's rows that do not read: left out
        if mode != found.mode or terms is None:
            continue
        rows += 1
        for name, value in zip(run.outputs, terms):
            if not math.isnan(value):
                total[name] = total.get(name, 0.0) + value
    outputs = sorted(({"name": n, "nats": v} for n, v in total.items()), key=lambda o: -o["nats"])
    return {"alarm": alarm, "mode": found.mode, "rows": rows, "outputs": outputs}


# What makes a unit need an operator, worst first (the overview's order): an alarm state, or a fault
# mode the alarm rule has not (yet) raised an alarm for.
ATTENTION = ("active, unacknowledged", "active, acknowledged", "fault mode", "cleared, unacknowledged")


def fleet(store: Store, opened: str | None) -> dict:
    """Every unit of a fleet's store, worst first, as an operator of many units scans them: each
    unit's latest run's modes and healthy modes, its newest row (t, time, the most probable mode and
    its probability), its open alarms (active, or cleared and not yet acknowledged;
    newest first) and how many are shelved, and what it needs attention for (the first of ATTENTION
    that applies, or None). Worst first: by ATTENTION, then by how many alarms in that state, then in
    the fleet's order. `opened` is the unit the page was started on (None: the overview is the page's
    first view)."""
    ranked = []
    for order, name in enumerate(store.units()):
        run = store.run(unit=name)
        newest = store.newest(run)
        t, time, mode = (None, None, None) if newest is None else newest[:3]
        healthy = run.options.get("healthy", [])
        listed = alarms(store, run)
        open_ = [a for a in listed if a["state"] in ATTENTION]
        states = [a["state"] for a in open_] + ([] if mode is None or mode in healthy else ["fault mode"])
        attention = next((s for s in ATTENTION if s in states), None)
        rank = (ATTENTION.index(attention) if attention else len(ATTENTION), -states.count(attention), order)
        ranked.append((rank, {"unit": name, "plant": run.plant, "modes": run.modes, "healthy": healthy, "t": t,
                              "time": time, "mode": mode, "attention": attention, "alarms": open_,
                              "probability": None if mode is None else newest.posterior[run.modes.index(mode)],
                              "shelved": sum(a["state"] == "shelved" for a in listed)}))
    return {"opened": opened, "units": [unit for _, unit in sorted(ranked, key=lambda pair: pair[0])]}
