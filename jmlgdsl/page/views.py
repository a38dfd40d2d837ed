"""What the operator's page shows, as JSON built from a monitor's store: the run, a window of rows,
the alarms with their ISA-18.2 states, the evidence behind an alarm, and a fleet's units worst first.

The store keeps vectors as JSON arrays already (finite numbers, null for NaN), so a window of rows is
written by joining the stored texts, not by parsing and writing them again: a page of 1,500 rows
costs one query.
"""

from __future__ import annotations

import json
from typing import NamedTuple

from ..monitor.store import Run, Store

LIVE_ROWS = 300  # rows a page shows when it follows the live end of the data
MAX_ROWS = 5_000  # rows one request may return; a wider window is thinned to fit


def run_info(store: Store, run: Run, token_required: bool) -> dict:
    """The run's names, units, mode descriptions and alarm rule, whether actions need a token, and the
    run's unit with every unit of the store's fleet (none for one plant)."""
    return {"id": run.id, "plant": run.plant, "modes": run.modes, "outputs": run.outputs, "inputs": run.inputs,
            "descriptions": run.descriptions, "units": run.units, "healthy": run.options.get("healthy", []),
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
    them, the last LIVE_ROWS rows."""
    limit = max(1, min(int(limit), MAX_ROWS))
    where, params = "r.run = ?", [run.id]
    if after is not None:
        where += " AND r.t > ?"
        params.append(int(after))
        order = f"ORDER BY r.t LIMIT {limit}"
    elif first is not None or last is not None:
        low, high = int(first or 1), int(last) if last is not None else _last_t(store, run)
        step = max(1, -(-(high - low + 1) // limit))
        where += " AND r.t BETWEEN ? AND ? AND (r.t - ?) % ? = 0"
        params += [low, high, low, step]
        order = "ORDER BY r.t"
    else:
        where += " AND r.t > ?"
        params.append(_last_t(store, run) - LIVE_ROWS)
        order = "ORDER BY r.t"
    found = store.db.execute(
        "SELECT r.t, s.time, r.map_mode, r.alarm, r.posterior, s.y, r.y_pred, r.y_sd, r.evidence_mode, r.evidence "
        f"FROM result r JOIN sample s ON s.run = r.run AND s.t = r.t WHERE {where} {order}", params).fetchall()
    columns = list(zip(*found)) or [()] * 10
    plain = [json.dumps(list(c)) for c in columns[:4]]
    vectors = ["[" + ",".join("null" if v is None else v for v in c) + "]" for c in columns[4:8]]
    names = ("t", "time", "map_mode", "alarm", "posterior", "y", "y_pred", "y_sd")
    parts = [f'"{n}":{v}' for n, v in zip(names, plain + vectors)]
    parts.append(f'"evidence_mode":{json.dumps(list(columns[8]))}')
    parts.append('"evidence":[' + ",".join("null" if v is None else v for v in columns[9]) + "]")
    return Rows("{" + ",".join(parts) + "}", len(found), found[-1][0] if found else None)


def _last_t(store: Store, run: Run) -> int:
    return store.db.execute("SELECT coalesce(max(t), 0) FROM result WHERE run = ?", (run.id,)).fetchone()[0]


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
    end = found.cleared_t - 1 if found.cleared_t is not None else _last_t(store, run)
    total, rows = {}, 0
    for mode, text in store.db.execute("SELECT evidence_mode, evidence FROM result WHERE run = ? AND t BETWEEN ? AND ? "
                                       "AND evidence IS NOT NULL", (run.id, found.raised_t, end)):
        if mode != found.mode:
            continue
        rows += 1
        for name, value in zip(run.outputs, json.loads(text)):
            if value is not None:
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
        newest = store.db.execute("SELECT r.t, s.time, r.map_mode, r.posterior FROM result r JOIN sample s "
                                  "ON s.run = r.run AND s.t = r.t WHERE r.run = ? ORDER BY r.t DESC LIMIT 1",
                                  (run.id,)).fetchone()
        t, time, mode, posterior = newest or (None, None, None, None)
        healthy = run.options.get("healthy", [])
        listed = alarms(store, run)
        open_ = [a for a in listed if a["state"] in ATTENTION]
        states = [a["state"] for a in open_] + ([] if mode is None or mode in healthy else ["fault mode"])
        attention = next((s for s in ATTENTION if s in states), None)
        rank = (ATTENTION.index(attention) if attention else len(ATTENTION), -states.count(attention), order)
        ranked.append((rank, {"unit": name, "plant": run.plant, "modes": run.modes, "healthy": healthy, "t": t,
                              "time": time, "mode": mode, "attention": attention, "alarms": open_,
                              "probability": None if mode is None else json.loads(posterior)[run.modes.index(mode)],
                              "shelved": sum(a["state"] == "shelved" for a in listed)}))
    return {"opened": opened, "units": [unit for _, unit in sorted(ranked, key=lambda pair: pair[0])]}
