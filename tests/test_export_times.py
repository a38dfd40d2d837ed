"""`jmlgdsl export --samples` writes the rows' times as the source wrote them: seconds as seconds
('1', not '1.0'), a logger's clock times as it writes them ('2020-03-09 11:14:34', as SKAB's files
do), and the ISO stamps of readings from a data bus as ISO stamps; `jmlgdsl run` on what it writes
diagnoses the same rows."""

import csv
import datetime

import pytest
from conftest import ROOT
from monitor_servers import DATA, SPEC

import jmlgdsl
from jmlgdsl.cli import main
from jmlgdsl.data import TimeFormat
from jmlgdsl.monitor import Monitor, MonitorOptions, Store, read_tags
from jmlgdsl.monitor.sources.contract import End, Readings

MODEL = jmlgdsl.load(ROOT / "specs" / "dryer.jmlg")
START = datetime.datetime(2020, 3, 9, 11, 14, 33, tzinfo=datetime.timezone.utc)


def recording():
    with open(DATA) as stream:
        return list(csv.DictReader(stream))


def logged(path, written):
    """The dryer recording with its times as clock times that `written` writes, semicolons between
    the cells (as SKAB's files have them)."""
    rows = [f"{written(START + datetime.timedelta(seconds=float(r['time'])))};{r['current']};{r['temp']}\n"
            for r in recording()[:200]]
    path.write_text("datetime;current;temp\n" + "".join(rows))
    return path


def exported_samples(tmp_path, store):
    samples, table = tmp_path / "samples.csv", tmp_path / "table.csv"
    assert main(["export", store, "-o", str(table), "--samples", str(samples)]) == 0
    again = tmp_path / "again.csv"
    assert main(["run", SPEC, str(samples), "-o", str(again)]) == 0
    assert again.read_text() == table.read_text()  # the rows written are the rows diagnosed
    return list(csv.reader(samples.open()))


@pytest.mark.parametrize("written", [
    lambda t: t.strftime("%Y-%m-%d %H:%M:%S"),
    lambda t: t.isoformat().replace("+00:00", "Z"),
    lambda t: t.astimezone(datetime.timezone(datetime.timedelta(hours=1))).isoformat(timespec="milliseconds"),
], ids=["skab", "iso-z", "offset-ms"])
def test_a_files_clock_times_come_back_as_it_wrote_them(tmp_path, written):
    data, store = logged(tmp_path / "logged.csv", written), str(tmp_path / "dryer.db")
    assert main(["monitor", SPEC, "--source", str(data), "--store", store, "--no-follow"]) == 0
    rows = exported_samples(tmp_path, store)
    source = [line.split(";") for line in data.read_text().splitlines()]
    assert rows[0] == ["datetime", "temp", "current"]
    assert [row[0] for row in rows[1:]] == [cells[0] for cells in source[1:]]


def test_seconds_come_back_as_the_file_wrote_them(tmp_path):
    store = str(tmp_path / "dryer.db")
    assert main(["monitor", SPEC, "--source", str(DATA), "--store", store, "--no-follow"]) == 0
    rows = exported_samples(tmp_path, store)
    assert rows[0][0] == "time" and [row[0] for row in rows[1:]] == [r["time"] for r in recording()]


class Stamped:
    """The dryer recording as a data bus hands it over, each sample one message stamped with an ISO
    time (as an MQTT source decodes {"t": "2020-03-09T11:14:34Z", ...})."""

    rows, name = False, "test://stamped"

    def start(self, put, position):
        for token, r in enumerate(recording()[:200]):
            stamp = START + datetime.timedelta(seconds=float(r["time"]))
            put(Readings([("temp", float(r["temp"]), stamp), ("current", float(r["current"]), stamp)],
                 stamp.timestamp(), token))
        put(End())

    def acknowledge(self, tokens):
        pass

    def stop(self):
        pass


def test_iso_stamps_of_a_data_bus_come_back_as_iso_stamps(tmp_path):
    store = str(tmp_path / "dryer.db")
    with Store(store) as opened:
        Monitor(MODEL, opened, Stamped(), spec=None, options=MonitorOptions(), tags=read_tags(None, MODEL)).run()
        assert opened.run().times == TimeFormat("datetime", "T", "Z", 0)
    rows = exported_samples(tmp_path, store)
    assert rows[0][0] == "datetime"
    assert rows[1][0] == "2020-03-09T11:14:34Z" and rows[-1][0] == "2020-03-09T11:17:53Z"


@pytest.mark.parametrize("text, seconds, back", [
    ("2020-03-09 11:14:34", 1583752474.0, "2020-03-09 11:14:34"),
    ("2020-03-09T11:14:34.5", 1583752474.5, "2020-03-09T11:14:34.5"),
    ("2020-03-09 12:14:34+01:00", 1583752474.25, "2020-03-09 12:14:34.250+01:00"),  # more digits where needed
    ("2020-03-09T11:14:34Z", 1583752474.000001, "2020-03-09T11:14:34.000001Z"),
])
def test_a_clock_time_is_written_in_its_source_format_and_nothing_is_rounded_away(text, seconds, back):
    written = TimeFormat.of_stamp(text)
    assert written.write(seconds) == back
    stamp = datetime.datetime.fromisoformat(back)  # as the data reader reads it: no zone is UTC
    assert (stamp if stamp.tzinfo else stamp.replace(tzinfo=datetime.timezone.utc)).timestamp() == seconds
    assert TimeFormat.from_json(written.as_json()) == written
