"""`jmlgdsl monitor --units`: one monitor for a fleet of units of one spec.

- `unit_names` reads ranges with their digits' width kept (pump01..pump12, pump001..pump120, a9..a11),
  lists and both mixed, and refuses a backwards range, a bad name and a name given twice, each with
  its message.
- Over a CSV file per unit (`--source DIR/{unit}.csv`, files of different lengths, one with a missing
  reading) every unit has its own run in the store, its `unit` column set, and `jmlgdsl export
  --unit U` writes, byte for byte, the table `jmlgdsl run` writes for U's file; `export` of a fleet's
  store without --unit, or with a unit it does not hold, is refused naming the units.
- Under la-rbpf (the units' own filters stepped together), a fleet stopped part way and started
  again gives each unit the table `jmlgdsl run` writes for its file with the same filter and seed.
- Following growing files, the monitor killed with SIGKILL mid-file and started again with the same
  command loses and repeats no row of any unit: each run's rows are t = 1..N once each, and each
  unit's table is the uninterrupted `jmlgdsl run` table (--lag 0: nothing held back).
- A fleet's files are read in one thread, not one a unit; a bad line in one unit's file is that
  unit's malformed event naming its file and line, and its rows after it are read on; started again
  from saved positions, each unit reads on at its offset with the same line numbers.
- Stopped while each unit's file holds more rows than its queue, the monitor returns, the units'
  reader thread ends, and started again it diagnoses every unit's rows once each.
- Over MQTT (a mosquitto started here on 127.0.0.1), topics PREFIX/UNIT/NAME and JSON objects of
  several names on PREFIX/UNIT land in each unit's run; killed mid-stream, the persistent session
  delivers what was not acknowledged to the restarted monitor, and each unit's table is the one
  `jmlgdsl run` writes for the same rows.
- Refusals, each by its message and before a store is made where the source is at fault: a CSV
  source without {unit}, an OPC UA tag file with a node id without {unit}, a bad --units; a
  monitor of one plant on a fleet's store, and a fleet's monitor on a store of one plant, unless
  --new-run.
- The operator's page (`jmlgdsl dashboard STORE --unit U`, in headless chromium) shows U's plant,
  rows and alarms, and its unit list holds every unit; choosing another unit reloads the page with
  ?unit=NAME on that unit's rows and alarms, as the store holds them. A screenshot goes to the test's
  folder (JMLGDSL_SCREENSHOTS names another).
"""

import csv
import io
import json
import os
import re
import shutil
import signal
import sqlite3
import subprocess
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import jmlgdsl_command
from monitor_servers import LINES, MOSQUITTO, NO_MOSQUITTO, SPEC, WAIT, free_port, publish, query

from jmlgdsl.cli import main
from jmlgdsl.monitor.store.databases import SQLite
from jmlgdsl.monitor.units import FleetError, unit_names

UNITS = ["pump01", "pump02", "pump03"]
# each unit's rows, cut from the dryer recording (LINES[0] is the header): pump01 the first 400 rows,
# pump02 rows 301-1000 (its clock starts at 301 s), pump03 all 1000 with no temp reading at 250 s
MISSING = 250


def without_temp(line):
    cells = line.split(",")
    cells[2] = ""  # time,current,temp,mode,temp_true
    return ",".join(cells)


ROWS = {"pump01": LINES[1:401], "pump02": LINES[301:1001],
        "pump03": [without_temp(line) if line.startswith(f"{MISSING},") else line for line in LINES[1:1001]]}


def write_files(folder, rows=ROWS):
    """Each unit's rows as folder/UNIT.csv (with the header)."""
    folder.mkdir(exist_ok=True)
    for unit, lines in rows.items():
        (folder / f"{unit}.csv").write_text(LINES[0] + "".join(lines))
    return str(folder / "{unit}.csv")


def table(*args, out):
    assert main([*args, "-o", str(out)]) == 0
    return out.read_bytes()


def run_table(path, out):
    """What `jmlgdsl run` writes for a data file."""
    return table("run", SPEC, str(path), out=out)


def per_run(store, table_name):
    """{unit: (rows, distinct t, min t, max t)} of a table of the store."""
    with sqlite3.connect(store) as db:
        return {unit: tuple(rest) for unit, *rest in db.execute(
            f"SELECT r.unit, count(*), count(DISTINCT x.t), min(x.t), max(x.t) FROM {table_name} x "
            "JOIN run r ON r.id = x.run GROUP BY r.unit")}


def counted(n):
    """A unit's n rows stored once each, t = 1..n (as per_run gives them)."""
    return (n, n, 1, n)


class Running:
    """A `jmlgdsl monitor` command running, its standard error going to a file: a pipe read only at the
    end fills up with a restart's log (a line for each message the broker delivers again, up to a
    batch of them) and then blocks the monitor."""

    def __init__(self, command, log):
        self.log = log
        with open(log, "w") as out:
            self.process = subprocess.Popen(command, stderr=out, text=True)

    def until(self, condition, what):
        deadline = time.monotonic() + WAIT
        while not condition():
            if self.process.poll() is not None:
                pytest.fail(f"the monitor stopped while waiting for {what}: {self.log.read_text()}")
            assert time.monotonic() < deadline, f"gave up waiting for {what}"
            time.sleep(0.02)

    def kill(self):
        self.process.send_signal(signal.SIGKILL)
        self.process.wait(WAIT)

    def stop(self) -> str:
        """Stop it as an operator does (SIGTERM): its standard error."""
        self.process.send_signal(signal.SIGTERM)
        self.process.wait(WAIT)
        err = self.log.read_text()
        assert self.process.returncode == 0, err
        return err


def ended(*monitors):
    for monitor in monitors:
        if monitor is not None and monitor.process.poll() is None:
            monitor.process.kill()
            monitor.process.wait(WAIT)


# ---------------------------------------------------------------------------------------------- unit names
@pytest.mark.parametrize("text, names", [
    ("pump01..pump12", [f"pump{n:02d}" for n in range(1, 13)]),
    ("pump001..pump120", [f"pump{n:03d}" for n in range(1, 121)]),
    ("a9..a11", ["a9", "a10", "a11"]),
    ("pump1..pump3", ["pump1", "pump2", "pump3"]),
    ("pump08..pump10", ["pump08", "pump09", "pump10"]),
    ("line2.pump7..line2.pump7", ["line2.pump7"]),
    ("north,south-1,spare_2", ["north", "south-1", "spare_2"]),
    ("pump01..pump03,spare, a9..a10", ["pump01", "pump02", "pump03", "spare", "a9", "a10"]),
])
def test_unit_names(text, names):
    assert unit_names(text) == names


@pytest.mark.parametrize("text, message", [
    ("pump05..pump01", "--units pump05..pump01: the range runs backwards"),
    ("x,pump12..pump3", "--units pump12..pump3: the range runs backwards"),  # the range named
    ("pump01,pump 02", "--units pump01,pump 02: 'pump 02' is not a unit name (letters, digits, _ . -) nor a "
                       "range such as pump01..pump20"),
    ("a..d", "--units a..d: 'a..d' is not a unit name"),
    ("pump01..tank03", "--units pump01..tank03: 'pump01..tank03' is not a unit name"),
    ("a,,b", "--units a,,b: '' is not a unit name"),
    ("{unit}", "--units {unit}: '{unit}' is not a unit name"),
    ("pump01..pump03,pump02", "--units pump01..pump03,pump02: unit pump02 is named twice"),
    ("b,a,b,a", "--units b,a,b,a: unit a is named twice"),
])
def test_unit_names_refused(text, message):
    with pytest.raises(FleetError) as info:
        unit_names(text)
    assert str(info.value).startswith(message)


# ---------------------------------------------------------------------------------------------- CSV files
@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    """A fleet's store from a CSV file per unit, diagnosed to their ends: (files' folder, store)."""
    folder = tmp_path_factory.mktemp("fleet")
    source = write_files(folder / "data")
    store = str(folder / "fleet.db")
    assert main(["monitor", SPEC, "--source", source, "--units", "pump01..pump03", "--store", store,
                 "--no-follow"]) == 0
    return folder / "data", store


def test_each_unit_exports_as_run_writes_its_file(fleet, tmp_path, capsys):
    data, store = fleet
    for unit in UNITS:
        exported = table("export", store, "--unit", unit, out=tmp_path / f"{unit}-export.csv")
        expected = run_table(data / f"{unit}.csv", tmp_path / f"{unit}-run.csv")
        assert exported == expected, unit
        assert len(exported.splitlines()) == 1 + len(ROWS[unit])
    capsys.readouterr()
    with sqlite3.connect(store) as db:
        assert db.execute("SELECT id, unit, plant FROM run ORDER BY id").fetchall() == [
            (1, "pump01", "dryer"), (2, "pump02", "dryer"), (3, "pump03", "dryer")]
        assert np.isnan(SQLite.unvector(db.execute("SELECT y FROM sample WHERE run = 3 AND time = ?",
                                                   (MISSING,)).fetchone()[0], 1)).all()
        assert db.execute("SELECT min(time), max(time) FROM sample WHERE run = 2").fetchone() == (301.0, 1000.0)
    assert per_run(store, "sample") == per_run(store, "result") == {
        unit: counted(len(ROWS[unit])) for unit in UNITS}

    assert main(["export", store, "-o", str(tmp_path / "all.csv")]) == 2
    assert (f"error: {store}: a fleet's store; say which unit with --unit (one of pump01, pump02, pump03)"
            in capsys.readouterr().err)
    assert main(["export", store, "--unit", "nosuch", "-o", str(tmp_path / "nosuch.csv")]) == 2
    assert (f"error: {store}: the store holds no run of unit nosuch; its units: pump01, pump02, pump03"
            in capsys.readouterr().err)
    assert not (tmp_path / "all.csv").exists() and not (tmp_path / "nosuch.csv").exists()


def test_a_rao_blackwellised_fleet_stopped_and_resumed_gives_each_unit_its_run_table(tmp_path, capsys):
    """Under la-rbpf the units' own filters step together (each unit's Diagnosis saves its own): a
    fleet stopped part way through its files and started again gives each unit, byte for byte, the
    table `jmlgdsl run` writes for its file with the same filter and seed."""
    import jmlgdsl
    from jmlgdsl.diagnosis import Options
    from jmlgdsl.monitor import Monitor, MonitorOptions, Store, read_tags
    from jmlgdsl.monitor.sources import Connection, open_source

    data, store = tmp_path / "data", str(tmp_path / "fleet.db")
    source = write_files(data)
    options = ["--filter", "la-rbpf", "--particles", "5", "--seed", "3"]
    model = jmlgdsl.load(SPEC)
    tags = read_tags(None, model)  # as the command reads them
    stop = threading.Event()

    def watch():  # stop the first monitor once a third of the rows are stored
        while not stop.is_set() and (query(store, "SELECT count(*) FROM result") or 0) < 700:
            time.sleep(0.01)
        stop.set()

    threading.Thread(target=watch, daemon=True).start()
    with Store(store) as opened:
        monitor = Monitor(model, opened, open_source(Connection(source, follow=False), model, tags, UNITS),
                          spec=SPEC, options=MonitorOptions(Options(algorithm="la-rbpf", particles=5, seed=3)),
                          tags=tags, units=UNITS)
        assert monitor.fleet is not None and monitor.fleet.filter.algorithm == "la-rbpf"
        first = monitor.run(stop)
    assert not first.ended and 0 < first.rows < sum(map(len, ROWS.values()))
    assert main(["monitor", SPEC, "--source", source, "--units", ",".join(UNITS), "--store", store, "--no-follow",
                 *options]) == 0
    for unit in UNITS:
        exported = table("export", store, "--unit", unit, out=tmp_path / f"{unit}-export.csv")
        assert exported == table("run", SPEC, str(data / f"{unit}.csv"), *options, out=tmp_path / f"{unit}-run.csv")
    capsys.readouterr()


def test_killed_mid_file_and_restarted_loses_and_repeats_no_row(tmp_path):
    """Three growing files (700, 1000 and 500 rows), the monitor killed while each is part written."""
    lengths = {"pump01": 700, "pump02": 1000, "pump03": 500}
    rows = {unit: LINES[1:n + 1] for unit, n in lengths.items()}
    data, store = tmp_path / "data", str(tmp_path / "fleet.db")
    source = write_files(data, {unit: lines[:200] for unit, lines in rows.items()})
    command = [*jmlgdsl_command(), "monitor", SPEC, "--source", source, "--units", ",".join(lengths),
               "--store", store, "--lag", "0"]
    killed, done = threading.Event(), threading.Event()

    def stored():
        return query(store, "SELECT count(*) FROM result") or 0

    def grow():  # each unit's logger: ten rows every 10 ms, going on through the kill and the restart
        files = {unit: open(data / f"{unit}.csv", "a") for unit in rows}
        try:
            for first in range(200, 1000, 10):
                if first == 400:
                    killed.wait(WAIT)
                for unit, out in files.items():
                    out.writelines(rows[unit][first:first + 10])
                    out.flush()
                if done.wait(0.01):
                    return
        finally:
            for out in files.values():
                out.close()

    writer = threading.Thread(target=grow)
    first, second = Running(command, tmp_path / "first.log"), None
    try:
        first.until(lambda: stored() >= 600, "the first monitor to store each unit's first 200 rows")
        writer.start()
        first.until(lambda: stored() >= 900, "the first monitor to store 900 rows")
        first.kill()
        at_kill = per_run(store, "result")
        assert sum(n for n, *_ in at_kill.values()) <= 1200  # mid-file: no unit past its row 400
        killed.set()
        second = Running(command, tmp_path / "second.log")
        second.until(lambda: stored() == sum(lengths.values()), "the restarted monitor to store every row")
        err = second.stop()
        writer.join(WAIT)
    finally:
        killed.set()
        done.set()
        ended(first, second)
    for i, unit in enumerate(lengths, 1):
        assert f"monitor: {unit}: resume: run {i} resumed after row {at_kill[unit][0]}" in err
    assert per_run(store, "sample") == per_run(store, "result") == {
        unit: counted(n) for unit, n in lengths.items()}
    for unit in lengths:
        exported = table("export", store, "--unit", unit, out=tmp_path / f"{unit}-export.csv")
        assert exported == run_table(data / f"{unit}.csv", tmp_path / f"{unit}-run.csv"), unit
    with sqlite3.connect(store) as db:
        events = db.execute("SELECT r.unit, e.kind, count(*) FROM event e JOIN run r ON r.id = e.run "
                            "GROUP BY r.unit, e.kind").fetchall()
    assert sorted(events) == sorted((unit, kind, 1) for unit in lengths for kind in ("resume", "start"))


# ---------------------------------------------------------------------------------------------- MQTT
def readings(unit, lines, kind):
    """A unit's rows as MQTT messages: `names`, {"t", "v"} on plant/UNIT/current and plant/UNIT/temp
    for each row; `objects`, one {"t", "temp", "current"} on plant/UNIT a row (a missing temp as null)."""
    messages = []
    for row in csv.DictReader(io.StringIO(LINES[0] + "".join(lines))):
        t, current = float(row["time"]), float(row["current"])
        temp = float(row["temp"]) if row["temp"] else None
        if kind == "names":
            messages.append([(f"plant/{unit}/current", json.dumps({"t": t, "v": current})),
                             (f"plant/{unit}/temp", json.dumps({"t": t, "v": temp}))])
        else:
            messages.append([(f"plant/{unit}", json.dumps({"t": t, "temp": temp, "current": current}))])
    return messages


def test_a_fleets_files_are_read_in_one_thread_a_bad_line_is_its_units_event_and_a_restart_reads_on(tmp_path):
    """50 units' files are read by one thread, not a thread a unit. A bad line in one unit's file is a
    malformed event of that unit naming its file and line, and the unit's rows after it are read on.
    Started again from the positions saved with each unit's 5th row (the bad line is after it), each
    unit reads on from its 6th row with the same line numbers, and the same event names the same line."""
    import jmlgdsl
    from jmlgdsl.monitor.sources import Connection, open_source
    from jmlgdsl.monitor.sources.contract import End, Event, WholeRow

    units, bad, rows = [f"u{k:02d}" for k in range(50)], "u07", 20
    folder = tmp_path / "units"
    folder.mkdir()
    for unit in units:
        lines = [f"{t},15,50.5\n" if unit != bad or t != 9 else "9,15,hot\n" for t in range(1, rows + 1)]
        (folder / f"{unit}.csv").write_text("# a logger's comment\ntime,current,temp\n" + "".join(lines))
    model = jmlgdsl.load(SPEC)

    def read(positions):
        """Each unit's items, in order, and the threads the source started."""
        source = open_source(Connection(str(folder / "{unit}.csv"), follow=False), model, {}, units)
        items, ended, before = {unit: [] for unit in units}, threading.Event(), threading.active_count()
        counted = threading.Event()  # the readers wait with their first items until their threads are counted

        def put(handed):
            assert counted.wait(WAIT)
            for unit, item in handed if isinstance(handed, list) else [handed]:  # a round of items, or one
                if unit is None:
                    assert isinstance(item, End)
                    ended.set()
                else:
                    items[units[unit]].append(item)

        source.start(put, positions)
        started = threading.active_count() - before
        counted.set()
        assert ended.wait(WAIT)
        source.stop()
        return items, started

    items, started = read([None] * len(units))
    assert started <= 1
    for unit in units:
        whole = [item for item in items[unit] if isinstance(item, WholeRow)]
        kept = [t for t in range(1, rows + 1) if unit != bad or t != 9]
        assert [row.row.time for row in whole] == kept and [row.row.line for row in whole] == [t + 2 for t in kept]
        events = [item for item in items[unit] if isinstance(item, Event)]
        assert [(e.kind, e.detail.split(": ")[0]) for e in events] == (
            [("malformed", f"{folder / bad}.csv:11")] if unit == bad else [])
    saved = [next(item for item in items[unit] if isinstance(item, WholeRow) and item.row.time == 5).position
             for unit in units]
    again, _ = read(saved)
    for unit in units:
        whole = [item for item in again[unit] if isinstance(item, WholeRow)]
        assert whole[0].row.time == 6 and whole[0].row.line == 8 and len(whole) == rows - 5 - (unit == bad)
        assert [e.detail for e in again[unit] if isinstance(e, Event)] == [
            e.detail for e in items[unit] if isinstance(e, Event)]


@pytest.mark.filterwarnings("ignore::jmlgdsl.data.DataWarning")  # a time that repeats, on purpose
def test_a_fleets_reader_reads_plain_lines_in_one_pass_and_gives_the_rows_a_files_reader_gives(tmp_path):
    """A unit's lines of plain numbers are read a block at a time in one pass (no line split as CSV on
    its own but the header; a block with any other line is read line by line), and every unit's items are, bit for bit, those a CsvSource of its file
    alone gives: files over several blocks, with missing readings, a file without the current column
    (its default), a bad line, a time that goes backwards and a time that repeats among plain lines,
    CR LF line ends, comments, blank lines and a last line without its line end."""
    import jmlgdsl
    from jmlgdsl.monitor.sources import Connection, files, open_source
    from jmlgdsl.monitor.sources.contract import End, Event, WholeRow

    def lines(n, bad=()):
        return [bad[t] if t in bad else f"{t},{15 + t % 3},{50.5 + 0.001 * t!r}\n" if t % 7 else f"{t},15,\n"
                for t in range(1, n + 1)]

    texts = {"plain": "time,current,temp\n" + "".join(lines(2000)),
             "bad": "time,current,temp\n" + "".join(lines(1500, {500: "500,15,hot\n", 900: "100,15,50\n",
                                                                    1200: "1199,15,50\n"})),
             "default": "time,temp\n" + "".join(f"{t},{50 + t % 5}\n" for t in range(1, 800)),
             "mixed": "# logger 7\r\ntime,current,temp\r\n" + "".join(line.replace("\n", "\r\n") for line in lines(300))
                      + "\n# restarted\n" + "".join(lines(400)[300:]) + "401,15,50.5"}
    folder = tmp_path / "units"
    folder.mkdir()
    for unit, text in texts.items():
        (folder / f"{unit}.csv").write_text(text, newline="")
    model = jmlgdsl.load(SPEC)

    def read(source, fleet):
        got, ended = [], threading.Event()

        def put(handed):
            for unit, item in handed if isinstance(handed, list) else [handed if fleet else (0, handed)]:
                if isinstance(item, End):
                    ended.set()
                else:
                    got.append((unit, item))

        source.start(put, [None] * len(texts) if fleet else None)
        assert ended.wait(WAIT)
        source.stop()
        return got

    def plain(item):
        if isinstance(item, WholeRow):
            row = item.row
            return (row.line, repr(row.time), type(row.time), row.y.tobytes(), row.u.tobytes(), row.mode,
                    row.anomaly, row.changepoint, item.position)
        return item

    split = []
    cells_of = files.cells_of
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(files, "cells_of", lambda line, delimiter, where: split.append(where.rsplit(":", 1)[0])
                      or cells_of(line, delimiter, where))
        fleet = read(open_source(Connection(str(folder / "{unit}.csv"), follow=False), model, {}, list(texts)), True)
    for i, unit in enumerate(texts):
        alone = read(files.CsvSource(str(folder / f"{unit}.csv"), model, follow=False), False)
        assert [plain(item) for k, item in fleet if k == i] == [plain(item) for _, item in alone], unit
    assert sum(isinstance(item, WholeRow) for _, item in fleet) == 2000 + 1500 - 2 + 799 + 401
    assert [item.detail.split(": ")[0] for _, item in fleet if isinstance(item, Event)] == [
        f"{folder / 'bad.csv'}:{line}" for line in (501, 901)]
    for unit in ("plain", "default"):  # their headers only: a block with a bad line, or CR LF, is read line by line
        assert split.count(str(folder / f"{unit}.csv")) == 1


def test_a_fleets_reader_reads_a_line_longer_than_many_blocks(tmp_path, monkeypatch):
    """A line far longer than the reader's block (here a comment of 6,000 blocks) is read whole and
    skipped, and the rows around it are read."""
    import jmlgdsl
    from jmlgdsl.monitor.sources import Connection, files, open_source
    from jmlgdsl.monitor.sources.contract import End, WholeRow

    monkeypatch.setattr(files, "BLOCK", 16)
    (tmp_path / "a.csv").write_text("time,current,temp\n1,15,50.5\n# " + "x" * 96_000 + "\n2,15,50.6\n")
    source = open_source(Connection(str(tmp_path / "{unit}.csv"), follow=False), jmlgdsl.load(SPEC), {}, ["a"])
    got, ended = [], threading.Event()

    def put(handed):
        for _, item in handed if isinstance(handed, list) else [handed]:
            if isinstance(item, End):
                ended.set()
            else:
                got.append(item)

    source.start(put, [None])
    assert ended.wait(WAIT)
    assert [(item.row.line, item.row.time) for item in got if isinstance(item, WholeRow)] == [(2, 1.0), (4, 2.0)]


def test_stopped_while_its_files_run_far_ahead_it_lets_their_readers_go_and_resumes(tmp_path):
    """Stopped while each unit's file holds far more rows than the monitor's queue, the monitor
    returns, the units' reader thread ends (not left waiting to hand over rows no one takes), and
    the same monitor started again diagnoses every unit's rows t = 1..N once each."""
    import jmlgdsl
    from jmlgdsl.monitor import Monitor, MonitorOptions, Store
    from jmlgdsl.monitor.live import QUEUE
    from jmlgdsl.monitor.sources import Connection, open_source

    rows = QUEUE  # per unit: three units' rows are three queues' worth
    folder = tmp_path / "units"
    folder.mkdir()
    for unit in UNITS:
        (folder / f"{unit}.csv").write_text("time,current,temp\n" + "".join(f"{t},15,50.5\n" for t in range(1, rows + 1)))
    model = jmlgdsl.load(SPEC)

    def monitor(stop=None):
        source = open_source(Connection(str(folder / "{unit}.csv"), follow=False), model, {}, UNITS)
        with Store(str(tmp_path / "fleet.db")) as store:
            stopped = Monitor(model, store, source, spec=SPEC, options=MonitorOptions(), tags={},
                              units=UNITS).run(stop)
        return stopped, source

    stop = threading.Event()
    threading.Timer(1.0, stop.set).start()
    stopped, source = monitor(stop)
    assert not stopped.ended and 0 < stopped.rows < len(UNITS) * rows
    source._thread.join(WAIT)
    assert not source._thread.is_alive()
    stopped, _ = monitor()
    assert stopped.ended and stopped.stored == len(UNITS) * rows
    with sqlite3.connect(tmp_path / "fleet.db") as db:
        for unit in UNITS:
            ts = [t for t, in db.execute("SELECT t FROM result JOIN run ON run.id = result.run WHERE run.unit = ? "
                                         "ORDER BY t", (unit,))]
            assert ts == list(range(1, rows + 1))


@pytest.mark.skipif(MOSQUITTO is None, reason=NO_MOSQUITTO)
def test_mqtt_units_on_one_connection_resume_after_a_kill(broker, tmp_path):
    pytest.importorskip("paho.mqtt.client")
    port, store = broker(), str(tmp_path / "fleet.db")
    # rows 1-400; rows 1-600 without a temp reading at 250 s (null); rows 301-1000
    rows = {"pump01": LINES[1:401], "pump02": ROWS["pump03"][:600], "pump03": LINES[301:1001]}
    by_row = {"pump01": readings("pump01", rows["pump01"], "names"),  # each name on its own topic
              "pump02": readings("pump02", rows["pump02"], "objects"),  # an object of both on plant/pump02
              "pump03": (readings("pump03", rows["pump03"][:350], "names")  # both, one after the other
                         + readings("pump03", rows["pump03"][350:], "objects"))}
    # the units' rows interleaved, as the plant publishes them
    messages = [m for i in range(max(map(len, by_row.values())))
                for unit in UNITS if i < len(by_row[unit]) for m in by_row[unit][i]]
    half = len(messages) // 2
    command = [*jmlgdsl_command(), "monitor", SPEC, "--source", f"mqtt://127.0.0.1:{port}/plant",
               "--units", "pump01..pump03", "--store", store]

    def connected(times):
        return lambda: (query(store, "SELECT count(*) FROM event WHERE kind = 'connect'") or 0) >= times

    def stored():
        return query(store, "SELECT count(*) FROM result") or 0

    first, second = Running(command, tmp_path / "first.log"), None
    try:
        first.until(connected(3), "the monitor to connect (an event in each unit's run)")
        publish(port, messages[:half])
        first.until(lambda: stored() >= 600, "600 rows stored")
        first.kill()
        at_kill = stored()
        publish(port, messages[half:])  # while the monitor is down: the broker keeps them for its session
        second = Running(command, tmp_path / "second.log")
        total = sum(map(len, rows.values()))
        second.until(lambda: stored() == total, "every unit's every row stored")
        err = second.stop()
    finally:
        ended(first, second)
    assert at_kill >= 600 and "resumed its session" in err
    # the one connection is one line (each unit's run keeps its event): it had been a line per unit
    assert re.findall(r"^monitor: .*connect: .*$", err, re.M) == [
        f"monitor: connect: connected to 127.0.0.1:{port} (as jmlgdsl-dryer, resumed its session)"]
    for i, unit in enumerate(UNITS, 1):  # the first half of the messages: 245 rows of each unit
        resumed = re.search(rf"^monitor: {unit}: resume: run {i} resumed after row (\d+)$", err, re.M)
        assert resumed and 0 < int(resumed[1]) < len(rows[unit]), err
    assert per_run(store, "sample") == per_run(store, "result") == {
        unit: counted(len(lines)) for unit, lines in rows.items()}
    with sqlite3.connect(store) as db:
        assert db.execute("SELECT id, unit FROM run ORDER BY id").fetchall() == list(enumerate(UNITS, 1))
        assert np.isnan(SQLite.unvector(db.execute("SELECT y FROM sample WHERE run = 2 AND time = ?",
                                                   (MISSING,)).fetchone()[0], 1)).all()
        assert db.execute("SELECT count(*) FROM event WHERE kind = 'malformed'").fetchone() == (0,)
    write_files(tmp_path / "data", rows)
    for unit in UNITS:
        exported = table("export", store, "--unit", unit, out=tmp_path / f"{unit}-export.csv")
        assert exported == run_table(tmp_path / "data" / f"{unit}.csv", tmp_path / f"{unit}-run.csv"), unit


# ---------------------------------------------------------------------------------------------- refusals
def test_a_source_that_cannot_name_each_unit_is_refused_before_the_store_is_made(tmp_path, capsys):
    store = tmp_path / "fleet.db"
    one = str(tmp_path / "dryer.csv")
    assert main(["monitor", SPEC, "--source", one, "--units", "pump01..pump03", "--store", str(store),
                 "--no-follow"]) == 2
    assert capsys.readouterr().err == (f"error: --units with a CSV source: give the files as a template with "
                                       f"{{unit}} in it, e.g. data/{{unit}}.csv, not {one}\n")
    tags = tmp_path / "tags.toml"
    tags.write_text('[tags.temp]\nnode = "ns=2;s={unit}.Temp"\n[tags.current]\nnode = "ns=2;s=Dryer.Current"\n')
    url = f"opc.tcp://127.0.0.1:{free_port()}/plant"  # nothing listens there: refused before connecting
    assert main(["monitor", SPEC, "--source", url, "--tags", str(tags), "--units", "pump01..pump03",
                 "--store", str(store)]) == 2
    assert capsys.readouterr().err == ("error: --units with an OPC UA source: the tag file's node id of current "
                                       "holds no {unit}, so every unit would read the same node\n")
    assert main(["monitor", SPEC, "--source", str(tmp_path / "{unit}.csv"), "--units", "pump03..pump01",
                 "--store", str(store), "--no-follow"]) == 2
    assert capsys.readouterr().err == "error: --units pump03..pump01: the range runs backwards\n"
    assert list(tmp_path.iterdir()) == [tags]


def short_files(folder):
    """Each unit's first 50 rows."""
    return write_files(folder, {unit: LINES[1:51] for unit in UNITS})


def test_a_monitor_of_one_plant_on_a_fleets_store_is_refused_unless_new_run(tmp_path, capsys):
    source, store = short_files(tmp_path / "data"), str(tmp_path / "fleet.db")
    one = str(tmp_path / "data" / "pump01.csv")
    assert main(["monitor", SPEC, "--source", source, "--units", "pump01..pump03", "--store", store,
                 "--no-follow"]) == 0
    capsys.readouterr()
    assert main(["monitor", SPEC, "--source", one, "--store", store, "--no-follow"]) == 2
    assert capsys.readouterr().err == (f"error: the store {store} holds the runs of a fleet, not of one plant; "
                                       "give another store, or --new-run to start a new run in the store\n")
    assert main(["monitor", SPEC, "--source", one, "--store", store, "--no-follow", "--new-run"]) == 0
    assert "50 rows diagnosed in run 4 of" in capsys.readouterr().err
    with sqlite3.connect(store) as db:
        assert db.execute("SELECT id, unit FROM run ORDER BY id").fetchall() == [
            (1, "pump01"), (2, "pump02"), (3, "pump03"), (4, None)]


def test_a_fleets_monitor_on_a_store_of_one_plant_is_refused_unless_new_run(tmp_path, capsys):
    source, store = short_files(tmp_path / "data"), str(tmp_path / "dryer.db")
    assert main(["monitor", SPEC, "--source", str(tmp_path / "data" / "pump01.csv"), "--store", store,
                 "--no-follow"]) == 0
    capsys.readouterr()
    refused = main(["monitor", SPEC, "--source", source, "--units", "pump01..pump03", "--store", store,
                    "--no-follow"])
    err = capsys.readouterr().err
    with sqlite3.connect(store) as db:
        runs = db.execute("SELECT id, unit FROM run ORDER BY id").fetchall()
    assert (refused, err, runs) == (2, f"error: the store {store} holds the runs of one plant, not of a fleet; "
                                       "give another store, or --new-run to start a new run in the store\n",
                                    [(1, None)])
    assert main(["monitor", SPEC, "--source", source, "--units", "pump01..pump03", "--store", store,
                 "--no-follow", "--new-run"]) == 0
    with sqlite3.connect(store) as db:
        assert db.execute("SELECT id, unit FROM run ORDER BY id").fetchall() == [
            (1, None), (2, "pump01"), (3, "pump02"), (4, "pump03")]


# ---------------------------------------------------------------------------------------------- the page
CHROMIUM = shutil.which("chromium") or next((p for p in ("/usr/bin/chromium",) if os.access(p, os.X_OK)), None)
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync"]


@pytest.mark.skipif(CHROMIUM is None, reason="no chromium browser on PATH (.ci/run installs it: apt-get install "
                                             "chromium)")
def test_the_page_shows_a_unit_and_switches_to_another(fleet, tmp_path):
    sync_api = pytest.importorskip("playwright.sync_api", reason="Playwright is not installed (pip install "
                                                                 "'.[test]')")
    _, store = fleet

    def in_store(unit):
        """(rows, last row's mode, the alarms newest first as (id, raised t, cleared t)) of a unit's run."""
        with sqlite3.connect(store) as db:
            run = db.execute("SELECT id FROM run WHERE unit = ?", (unit,)).fetchone()[0]
            rows, mode = db.execute("SELECT count(*), (SELECT map_mode FROM result WHERE run = ? ORDER BY t DESC "
                                    "LIMIT 1) FROM result WHERE run = ?", (run, run)).fetchone()
            alarms = db.execute("SELECT id, raised_t, cleared_t FROM alarm WHERE run = ? ORDER BY id DESC",
                                (run,)).fetchall()
        return rows, mode, alarms

    def shown(tab, unit):
        rows, mode, alarms = in_store(unit)
        assert alarms  # each unit's run has its own alarms, to tell them apart
        sync_api.expect(tab.locator("#status")).to_have_text(re.compile(rf"^row {rows}\b"), timeout=WAIT * 1000)
        assert tab.text_content("#plant") == "dryer" and tab.text_content("#mode") == mode
        assert tab.input_value("#unit") == unit and tab.is_visible("#unit")
        assert tab.locator("#unit option").all_text_contents() == UNITS
        listed = tab.locator("#alarmlist tr")
        # the list comes by its own fetch, which may land after the status line
        sync_api.expect(listed).to_have_count(len(alarms), timeout=WAIT * 1000)
        sync_api.expect(listed.first).to_have_attribute("data-alarm", str(alarms[0][0]), timeout=WAIT * 1000)
        assert [(int(listed.nth(i).get_attribute("data-alarm")),
                 listed.nth(i).locator("td").nth(1).text_content(), listed.nth(i).locator("td").nth(2).text_content())
                for i in range(listed.count())] == [
            (id, f"t {raised}", "–" if cleared is None else f"t {cleared}") for id, raised, cleared in alarms]

    port = free_port()
    process = subprocess.Popen([*jmlgdsl_command(), "dashboard", store, "--unit", "pump02", "--http",
                                f"127.0.0.1:{port}"], stderr=subprocess.PIPE, text=True)
    try:
        assert process.stderr.readline().startswith("the operator's page: ")
        with sync_api.sync_playwright() as playwright:
            browser = playwright.chromium.launch(executable_path=CHROMIUM, args=FLAGS)
            try:
                tab = browser.new_page(viewport={"width": 1400, "height": 900})
                errors = []
                tab.on("pageerror", lambda error: errors.append(str(error)))
                tab.goto(f"http://127.0.0.1:{port}/")
                shown(tab, "pump02")
                folder = Path(os.environ.get("JMLGDSL_SCREENSHOTS") or tmp_path)
                folder.mkdir(parents=True, exist_ok=True)
                tab.screenshot(path=str(folder / "page-fleet-pump02.png"), full_page=True)
                with tab.expect_navigation():
                    tab.select_option("#unit", "pump03")
                assert tab.url == f"http://127.0.0.1:{port}/?unit=pump03"
                shown(tab, "pump03")
                tab.screenshot(path=str(folder / "page-fleet-pump03.png"), full_page=True)
                assert in_store("pump03")[2] != in_store("pump02")[2]
                assert errors == []
            finally:
                browser.close()
    finally:
        process.terminate()
        process.wait(WAIT)


class Rounds:
    """A source of `units` units' rows t = 1..`rounds`, round after round, handed over before the
    monitor takes any, then the data end."""

    name, rows = "rows", True

    def __init__(self, units, rounds):
        self.units, self.rounds = units, rounds

    def round(self, t):
        """Every unit's row t, as (unit index, WholeRow) pairs."""
        from jmlgdsl.data import Row
        from jmlgdsl.monitor.sources.contract import WholeRow
        return [(i, WholeRow(Row(t, float(t), np.array([50.5 + 20 * (t > 8)]), np.array([15.0]), None), {"t": t}))
                for i in range(len(self.units))]

    def start(self, put, positions):
        from jmlgdsl.monitor.sources.contract import End
        for t in range(1, self.rounds + 1):
            for pair in self.round(t):
                put(pair)
        put((None, End()))

    def acknowledge(self, tokens):
        pass

    def stop(self):
        pass


def test_a_fleets_commit_writes_every_units_rows_with_a_statement_a_table(tmp_path):
    """A fleet's commit writes its units' samples, results, events and states with one statement a
    table and looks at the open alarms once, however many units it holds: beside a statement for each
    alarm raised (every unit raises one here) and the run's record read and its time format written
    (once a run), a commit of 100 units' rows makes no more statements than one of 2 units'."""
    import jmlgdsl
    from jmlgdsl.monitor import Monitor, MonitorOptions, Store

    def statements(count):
        units = [f"u{k:03d}" for k in range(count)]
        said = []  # the statements of each commit

        class Counted(Store):
            def save(self, commits, marks=()):
                made = []
                for name in ("execute", "executemany", "insert"):  # the store's calls to its database
                    def call(*args, method=getattr(self.db, name)):
                        if not args[0].startswith(("INSERT INTO alarm", "UPDATE run")) and "FROM run" not in args[0]:
                            made.append(args[0])
                        return method(*args)
                    setattr(self.db, name, call)
                super().save(commits, marks)
                for name in ("execute", "executemany", "insert"):
                    delattr(self.db, name)
                said.append((sum(len(c.results) for c in commits), len(made)))

        with Counted(str(tmp_path / f"fleet{count}.db")) as store:
            stopped = Monitor(jmlgdsl.load(SPEC), store, Rounds(units, 12), spec=SPEC, options=MonitorOptions(),
                              tags={}, units=units).run()
        assert stopped.ended and stopped.stored == 12 * count
        with sqlite3.connect(tmp_path / f"fleet{count}.db") as db:
            assert db.execute("SELECT count(DISTINCT run) FROM alarm").fetchone()[0] == count
            assert db.execute("SELECT count(*) FROM state WHERE rows = 12").fetchone()[0] == count
        return max(made for rows, made in said if rows == 12 * count)

    assert statements(100) <= statements(2)


def test_a_fleets_source_hands_over_a_round_of_its_units_items_at_once_and_waits_for_the_monitor(tmp_path):
    """A source of 100 units that hands over each round of their rows as one list: every row is
    diagnosed once, and the source's hand-over waits while ROUNDS_AHEAD rounds are not yet taken."""
    import jmlgdsl
    from jmlgdsl.monitor import Monitor, MonitorOptions, Store, live
    from jmlgdsl.monitor.sources.contract import End

    units, handed, ahead = [f"u{k:03d}" for k in range(100)], [0], []

    class Lists(Rounds):
        def start(self, put, positions):
            def hand():
                for t in range(1, self.rounds + 1):
                    put(self.round(t))
                    handed[0] += 1
                put((None, End()))
            threading.Thread(target=hand, daemon=True).start()

    class Watched(Monitor):
        def _handle(self, unit, item):
            if unit == 0:  # the first item of a round: rounds handed over beyond those taken
                ahead.append(handed[0] - self.units[0].rows)
            return super()._handle(unit, item)

    stop = threading.Event()
    threading.Timer(WAIT, stop.set).start()
    with Store(str(tmp_path / "fleet.db")) as store:
        stopped = Watched(jmlgdsl.load(SPEC), store, Lists(units, 40), spec=SPEC, options=MonitorOptions(), tags={},
                          units=units).run(stop)
    stop.set()
    assert stopped.ended and stopped.stored == 40 * len(units)
    assert per_run(tmp_path / "fleet.db", "result") == {unit: counted(40) for unit in units}
    assert len(ahead) == 40 and max(ahead) <= live.ROUNDS_AHEAD + 1  # the queue's and the one being taken


def test_a_large_fleets_commit_holds_many_rows_of_each_unit(tmp_path):
    """A unit's part of a commit (its saved state) costs as much as many of its rows, so while input keeps
    coming a fleet's commit waits for ROUNDS rows of each unit, however many units: 100 units handing
    over ROUNDS rows each (more than BATCH in all) are committed once each with all their rows."""
    import jmlgdsl
    from jmlgdsl.data import Row
    from jmlgdsl.monitor import Monitor, MonitorOptions, Store
    from jmlgdsl.monitor.live import BATCH, ROUNDS
    from jmlgdsl.monitor.sources.contract import End, WholeRow

    units = [f"u{k:03d}" for k in range(100)]
    assert ROUNDS * len(units) > BATCH

    class Rows:
        """Every unit's ROUNDS rows, round after round, handed over before the monitor takes any."""
        name, rows = "rows", True

        def start(self, put, positions):
            for t in range(1, ROUNDS + 1):
                for i in range(len(units)):
                    put((i, WholeRow(Row(t, float(t), np.array([50.5]), np.array([15.0]), None), {"t": t})))
            put((None, End()))

        def acknowledge(self, tokens):
            pass

        def stop(self):
            pass

    held = []  # the rows of each unit's part of each commit

    class Counted(Store):
        def save(self, commits, marks=()):
            held.extend(len(commit.results) for commit in commits)
            super().save(commits, marks)

    with Counted(str(tmp_path / "fleet.db")) as store:
        stopped = Monitor(jmlgdsl.load(SPEC), store, Rows(), spec=SPEC, options=MonitorOptions(), tags={},
                          units=units).run()
    assert stopped.ended and stopped.stored == ROUNDS * len(units)
    assert sorted(set(held) - {0}) == [ROUNDS] and held.count(ROUNDS) == len(units)
