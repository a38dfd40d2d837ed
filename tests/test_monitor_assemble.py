"""Rows from readings: complete rows leave at once and in order, a row waits its grace period for
missing readings, and late, duplicate, out-of-order, stale and malformed readings are counted as
events with their tag, never reordered into rows already diagnosed."""

import datetime
import math

import pytest
from conftest import ROOT

import jmlgdsl
from jmlgdsl.monitor import Assembler, TagError, read_tags
from jmlgdsl.monitor.sources.contract import End, Readings
from jmlgdsl.monitor.sources.payload import Malformed, decode

MODEL = jmlgdsl.load(ROOT / "specs" / "dryer.jmlg")  # output temp, input current (default 15), 1 s


def assembler(**options):
    return Assembler(MODEL, read_tags(None, MODEL), **options)


def feed(a, readings):
    """Every row (time, temp, current) and event (kind, tag, time) of a series of readings."""
    rows, events = [], []
    for reading in readings:
        r, e = a.add([reading])
        rows += [(row.time, *row.y.tolist(), *row.u.tolist()) for row in r]
        events += [(event.kind, event.tag, event.time) for event in e]
    return rows, events


def same(a, b):
    return len(a) == len(b) and all(x == y or (math.isnan(x) and math.isnan(y)) for p, q in zip(a, b)
                                    for x, y in zip(p, q))


def test_complete_rows_leave_at_once_in_order_and_late_ones_are_events():
    a = assembler()
    rows, events = feed(a, [("temp", 50.0, 1.0), ("current", 16.0, 1.02), ("temp", 50.5, 2.0),
                            ("current", 16.0, 3.0), ("temp", 51.0, 3.0),
                            ("temp", 50.1, 1.0),  # its row has left: late
                            ("current", 17.0, 4.1), ("current", 17.0, 4.0),  # the second a duplicate
                            ("temp", 52.0, 5.0), ("temp", 51.5, 3.9)])  # out of order, its row still open
    # row 2 waited for 'current' (read every sample so far) until a reading at 4.1 s made it due;
    # row 5 still waits for it
    assert same(rows, [(1.0, 50.0, 16.0), (2.0, 50.5, 16.0), (3.0, 51.0, 16.0), (4.0, 51.5, 17.0)])
    assert events == [("late", "temp", 1.0), ("out_of_order", "current", 4.0), ("duplicate", "current", 4.0),
                      ("out_of_order", "temp", 3.9)]


def test_the_late_readings_of_one_message_are_one_event():
    a = assembler()
    a.add([("temp", 50.0, 1.0), ("current", 16.0, 1.0)])
    a.add([("temp", 50.5, 2.0), ("current", 16.0, 2.0)])
    rows, events = a.add([("temp", 50.0, 1.0), ("current", 16.0, 1.0), ("temp", 50.5, 2.0), ("temp", 51.0, 3.0)])
    assert [(e.kind, e.tag, e.time, e.detail) for e in events] == [
        ("late", None, 1.0, "3 readings (temp, current) for 1 s to 2 s came after their rows were diagnosed")]
    assert a.open == {3: {"temp": 51.0}}  # the reading that was not late is taken
    _, events = a.add([("temp", 50.0, 1.0), ("temp", 50.5, 2.0)])
    assert [(e.tag, e.detail) for e in events] == [("temp", "2 readings (temp) for 1 s to 2 s came after their rows "
                                                            "were diagnosed")]


def test_a_row_waits_its_grace_then_its_missing_readings_are_missing():
    a = assembler(grace=2.0)
    rows, events = feed(a, [("temp", 50.0, 1.0), ("current", 15.5, 1.0), ("temp", 50.2, 3.0), ("temp", 50.3, 4.0)])
    assert same(rows, [(1.0, 50.0, 15.5), (2.0, math.nan, 15.5), (3.0, 50.2, 15.5), (4.0, 50.3, 15.5)])
    assert events == [("gap", None, 2.0)]  # slot 2 had no reading at all; a reading at 4 s made it due


def test_stale_tags_go_missing_and_come_back_fresh():
    a = assembler(stale=3.0)
    readings = [("temp", 50.0, 1.0), ("current", 20.0, 1.0)] + [("temp", 50.0, float(t)) for t in range(2, 8)]
    rows, events = feed(a, readings + [("current", 21.0, 8.0), ("temp", 50.0, 8.0), ("temp", 50.0, 9.0)])
    # held for 3 s, then stale: the default (rows 5-7 waited their grace for it, as row 9 does now)
    assert [r[2] for r in rows] == [20.0, 20.0, 20.0, 20.0, 15.0, 15.0, 15.0, 21.0]
    assert events == [("stale", "current", 5.0), ("fresh", "current", 8.0)]


def test_a_long_gap_is_skipped_not_filled():
    a = assembler(max_gap=10.0)
    rows, events = feed(a, [("temp", 50.0, 1.0), ("current", 15.0, 1.0), ("current", 15.0, 30.0),
                            ("temp", 51.0, 30.0), ("temp", 51.0, 31.0)])
    assert [r[0] for r in rows] == [1.0, 30.0]
    # 29 s ahead of the stream: held until three messages showed it had moved on there
    assert [e[0] for e in events] == ["ahead", "ahead", "jump", "gap"]


def test_the_row_clock_moves_on_evidence_not_on_one_message():
    stream = [[("temp", 50.0 + t, float(t)), ("current", 15.0, float(t))] for t in range(1, 41)]
    now = 1e4  # the wall clock: every stamp here is behind it
    a = assembler()
    alone = [a.add(message, now)[0] for message in stream]
    # one message far ahead of the stream (within the wall clock) is held, then dropped as the stream
    # goes on where it was: the same rows, one event
    a, events = assembler(), []
    rows = []
    for t, message in enumerate(stream, start=1):
        r, e = a.add(message, now)
        rows.append(r)
        events += e
        if t == 20:
            r, e = a.add([("temp", 99.0, 5000.0), ("current", 99.0, 5000.0)], now)
            assert r == []
            events += e
    assert [[row.time for row in r] for r in rows] == [[row.time for row in r] for r in alone]
    assert [(e.kind, e.time) for e in events] == [("ahead", 5000.0)]
    assert "came 4980 s ahead of the stream (its newest reading is for 20 s): held" in events[0].detail
    # the stream that follows it there, three messages in a row, has moved on: they are used
    rows, events = [], []
    for t in (5000.0, 5001.0, 5002.0, 5003.0):
        r, e = a.add([("temp", 50.0, t), ("current", 15.0, t)], now)
        rows += [row.time for row in r]
        events += [e.kind for e in e]
    assert events == ["ahead", "ahead", "jump", "gap"] and rows == [5000.0, 5001.0, 5002.0, 5003.0]


def test_rows_held_while_the_source_catches_up_wait_for_every_reading():
    # a source back from an outage sends the readings of the moment first, then what it kept: held,
    # the rows wait for them, whatever the grace; released, the grace rules again
    stream = {t: [("temp", 50.0 + t, float(t)), ("current", 15.0, float(t))] for t in range(1, 60)}
    a = assembler()
    rows = [row.time for t in range(1, 11) for row in a.add(stream[t])[0]]
    a.hold()
    events = []
    for t in [50, 51, 52, 11, *range(12, 50), 53]:  # three ahead of the stream (a jump), then what was kept
        r, e = a.add(stream[t])
        rows += [row.time for row in r]
        events += [event.kind for event in e]
    assert rows == [float(t) for t in range(1, 54)]
    assert events == ["ahead", "ahead", "jump"] + ["out_of_order"] * 78  # what was kept filled in behind it
    assert a.add([("temp", 50.0, 57.0)]) == ([], [])  # row 54 waits for its readings, far past its grace
    rows, events = a.release()
    assert [row.time for row in rows] == [54.0, 55.0] and events == []  # 56 is within the grace of the newest


def test_a_message_held_ahead_while_the_source_catches_up_is_used_once_the_stream_reaches_it():
    stream = {t: [("temp", 50.0 + t, float(t)), ("current", 15.0, float(t))] for t in range(1, 60)}
    a = assembler()
    for t in range(1, 11):
        a.add(stream[t])
    a.hold()
    rows, events = a.add(stream[50])
    assert rows == [] and "held, and used once the stream catches up with it, or if 2 more" in events[0].detail
    rows = [row.time for t in range(11, 51) for row in a.add(stream[t])[0]]
    assert rows == [float(t) for t in range(11, 51)]  # 50 held ahead, then used; the second 50 a duplicate
    # not held, a message ahead of the stream is dropped by the stream going on where it was
    a = assembler()
    for t in [*range(1, 11), 50, *range(11, 51)]:
        a.add(stream[t])
    assert a.open == {} and a.watermark == 50.0 and a.newest == {"temp": 50.0, "current": 50.0}


def test_a_stream_stamped_on_arrival_is_not_held(tmp_path):
    path = tmp_path / "tags.toml"
    path.write_text('[tags.temp]\ntime = "arrival"\n[tags.current]\ntime = "arrival"\n')
    a = Assembler(MODEL, read_tags(path, MODEL))
    a.add([("temp", 50.0, None), ("current", 15.0, None)], 1000.0)
    a.hold()
    rows, _ = a.advance(1005.0)  # what comes late is stamped late: nothing to wait for
    assert [row.time for row in rows] == [1001.0, 1002.0, 1003.0]


def test_a_reading_stamped_past_the_wall_clock_is_not_used():
    a = assembler()
    a.add([("temp", 50.0, 1000.0), ("current", 15.0, 1000.0)], 1000.0)
    rows, events = a.add([("temp", 50.0, 1061.0), ("current", 15.0, 1061.0)], 1000.5)
    assert rows == [] and [(e.kind, e.tag, e.time) for e in events] == [("future", None, 1061.0)]
    assert "arrived at 1000.5 s, 60.5 s before its own time: not used" in events[0].detail
    assert a.watermark == 1000.0


def test_a_reading_without_its_own_time_in_a_stamped_stream(tmp_path):
    a = assembler()
    a.add([("temp", 50.0, 1.0), ("current", 15.0, 1.0)], 1e9)
    rows, events = a.add([("temp", 50.6, None)], 1e9 + 1)
    assert rows == [] and [(e.kind, e.tag) for e in events] == [("malformed", "temp")]
    assert "without a time of its own, in a stream whose readings carry theirs" in events[0].detail
    # a tag that says it takes its arrival time is read at it; a stream of arrival times throughout too
    path = tmp_path / "tags.toml"
    path.write_text('[tags.current]\ntime = "arrival"\n')
    a = Assembler(MODEL, read_tags(path, MODEL))
    a.add([("temp", 50.0, 100.0)], 100.0)
    rows, events = a.add([("current", 16.0, None)], 100.2)
    assert events == [] and [(row.time, *row.y, *row.u) for row in rows] == [(100.0, 50.0, 16.0)]
    a = assembler()
    a.add([("temp", 50.0, None)], 100.0)
    assert a.add([("temp", 51.0, None)], 101.0)[1] == [] and 101 in a.open


def test_events_write_times_as_the_source_writes_them():
    """ISO 8601 for a source that stamps its readings so, seconds in full for one that writes seconds;
    never a float cut to six digits ('1.79575e+09 s')."""
    iso, seconds = assembler(stale=3.0), assembler(stale=3.0)
    for t in range(1795747080, 1795747090):
        stamp = datetime.datetime.fromtimestamp(t, datetime.timezone.utc)
        iso.add([("temp", 50.0, stamp)] + [("current", 15.0, stamp)] * (t < 1795747082), 1795747100.0)
        _, events = seconds.add([("temp", 50.0, float(t))] + [("current", 15.0, float(t))] * (t < 1795747082),
                                1795747100.0)
        if events:
            stale = events
    assert [e.detail for e in stale] == ["no reading since 1795747081 s; missing from 1795747085 s"]
    assert [e.detail for e in iso.add([("temp", 50.0, 1795747081.5)], 1795747100.0)[1]] == [
        "a reading for 2026-11-27T02:38:01.500Z came after its row was diagnosed"]


def test_readings_older_than_the_first_say_once_why_they_are_late():
    # an OPC UA server's current values on connecting, then the plant's readings stamped before them
    a = assembler()
    a.add([("temp", 50.0, 100.0), ("current", 15.0, 100.0)], 1e4)
    a.add([("temp", 50.0, 101.0), ("current", 15.0, 101.0)], 1e4)
    details = [e.detail for t in (60.0, 61.0) for e in a.add([("temp", 50.0, t), ("current", 15.0, t)], 1e4)[1]]
    assert details[0].startswith("2 readings (temp, current) for 60 s came after their rows were diagnosed; they "
                                 "are older than the first reading of the run (for 100 s), which started its row "
                                 "clock")
    assert 'time = "arrival"' in details[0]
    assert details[1] == "2 readings (temp, current) for 61 s came after their rows were diagnosed"


@pytest.mark.parametrize("payload, name, reason", [
    (b"hot", "temp", "temp: payload 'hot' is neither a number nor JSON"),
    (b"NaN", "temp", "temp: payload 'NaN' is not a number or"),
    (b"1e300", "temp", "temp: payload '1e300': the value 1e+300 is not a finite measurement"),
    (b'{"value": 3}', "temp", "is not a number or {\"t\": ..., \"v\": ...}"),
    (b'{"t": "yesterday", "v": 3}', "temp", "t 'yesterday' is not an ISO 8601 time stamp"),
    (b'{"v": "3"}', "temp", "the value '3' is not a number"),
    (b"\xff", "temp", "is not UTF-8 text"),
    (b"[1, 2]", None, "sample: payload '[1, 2]' is not a JSON object"),
    (b'{"t": 1, "pressure": 3}', None, "holds none of the names temp, current"),
])
def test_malformed_payloads_name_their_tag(payload, name, reason):
    with pytest.raises(Malformed, match=None) as info:
        decode(payload, name, ["temp", "current"])
    assert reason in str(info.value)


def test_payloads():
    names = ["temp", "current"]
    assert decode(b" 50.25 ", "temp", names) == [("temp", 50.25, None)]
    assert decode(b'{"t": 12.5, "v": 50}', "temp", names) == [("temp", 50.0, 12.5)]
    assert decode(b'{"t": "1970-01-01T00:00:10Z", "v": null}', "temp", names)[0][2].timestamp() == 10.0
    assert decode(b'{"t": 3, "current": 15, "temp": 50.1, "other": 1}', None, names) == [
        ("temp", 50.1, 3.0), ("current", 15.0, 3.0)]


def test_tag_file(tmp_path):
    path = tmp_path / "tags.toml"
    path.write_text('[tags.temp]\ntopic = "line4/temp_F"\nscale = 0.5555555555555556\noffset = -17.77777777777778\n'
                    '[tags.current]\ntime = "arrival"\nstale = 60\n')
    tags = read_tags(path, MODEL)
    assert tags["temp"].topic == "line4/temp_F" and abs(tags["temp"].value(212.0) - 100.0) < 1e-12
    assert (tags["current"].time, tags["current"].stale, tags["current"].output) == ("arrival", 60.0, False)
    for text, message in [('[tags.tmep]\n', "[tags.tmep]: the spec has no input or output 'tmep'; did you mean 'temp'?"),
                          ('[tags.temp]\nscael = 2\n', "[tags.temp]: unknown key 'scael'; did you mean 'scale'?"),
                          ('[tags.temp]\ntime = "now"\n', 'time must be "source" or "arrival"'),
                          ('[tags.temp\n', "not a TOML tag file")]:
        path.write_text(text)
        with pytest.raises(TagError) as info:
            read_tags(path, MODEL)
        assert message in str(info.value)


def test_a_monitor_logs_the_first_late_message_of_a_batch_and_counts_the_rest(tmp_path):
    # a broker delivering again what a killed monitor had not acknowledged: every late message is an
    # event in the store, but the log has one line for the first and one line counting the others
    from jmlgdsl.monitor import Monitor, MonitorOptions, Store

    class Redelivered:
        rows, name = False, "test://redelivered"

        def start(self, put, position):
            for t in range(1, 4):
                put(Readings([("temp", 50.0, float(t)), ("current", 15.0, float(t))], 0.0, t))
            for k in range(40):  # the first row's readings again, after it was diagnosed
                put(Readings([("temp", 50.0, 1.0)], 0.0, 100 + k))
            put(End())

        def acknowledge(self, tokens):
            pass

        def stop(self):
            pass

    logged = []
    with Store(tmp_path / "s.db") as store:
        monitor = Monitor(MODEL, store, Redelivered(), spec=None, options=MonitorOptions(), tags=read_tags(None, MODEL),
                          log=logged.append)
        stopped = monitor.run()
        assert stopped.events["late"] == 40 and store.counts(stopped.runs[0])["late"] == 40
    late = [line for line in logged if line.startswith("late:")]
    assert late == ["late: temp: a reading for 1 s came after its row was diagnosed",
                    "late: 39 more messages came after their rows were diagnosed (each an event in the store)"]


def test_a_stalled_diagnosis_is_an_event_once_until_a_row_comes(tmp_path, monkeypatch):
    # messages keep arriving, every one late: no row is diagnosed, and that is said once, with why;
    # a row re-arms it
    import threading
    import time

    from jmlgdsl.monitor import Monitor, MonitorOptions, Store, live

    monkeypatch.setattr(live, "STALL", 0.05)  # sample times: 0.05 s of the dryer's 1 s
    monkeypatch.setattr(live, "STALL_LEAST", 0.0)

    class Stuck:
        rows, name = False, "test://stuck"

        def start(self, put, position):  # a thread of its own, as a bus's client has
            threading.Thread(target=self.publish, args=(put,), daemon=True).start()

        def publish(self, put):
            for t in range(1, 4):
                put(Readings([("temp", 50.0, float(t)), ("current", 15.0, float(t))], 0.0, t))
            for first in (True, False):
                for k in range(20):  # the first row's readings again and again
                    time.sleep(0.01)
                    put(Readings([("temp", 50.0, 1.0)], 0.0, 100 + k))
                if first:
                    put(Readings([("temp", 50.0, 4.0), ("current", 15.0, 4.0)], 0.0, 4))
            put(End())

        def acknowledge(self, tokens):
            pass

        def stop(self):
            pass

    logged = []
    with Store(tmp_path / "s.db") as store:
        stopped = Monitor(MODEL, store, Stuck(), spec=None, options=MonitorOptions(), tags=read_tags(None, MODEL),
                          log=logged.append).run()
        details = [detail for (detail,) in store.db.execute("SELECT detail FROM event WHERE kind = 'stall'")]
    assert stopped.events["stall"] == 2 and len(details) == 2
    assert details[0].startswith("no row diagnosed for 0 s while ") and "messages arrived (late " in details[0]
    assert sum(line.startswith("stall: no row diagnosed") for line in logged) == 2


def test_a_monitor_holds_rows_while_its_source_is_down_and_catching_up(tmp_path):
    # the source's connect and disconnect events hold the rows; its readings of the moment come first
    # after the outage, then what it kept, and every row gets its readings; the catch-up time after the
    # connection passed, the grace rules again
    import threading
    import time

    from jmlgdsl.monitor import Monitor, MonitorOptions, Store
    from jmlgdsl.monitor.sources.contract import Event
    from jmlgdsl.monitor.store.databases import SQLite

    catch_up = 0.3

    def sample(t):
        return Readings([("temp", 50.0 + t, float(t)), ("current", 15.0, float(t))], None, t)

    class Reconnecting:
        rows, name = False, "test://reconnecting"

        def start(self, put, position):  # a thread of its own, as a bus's client has
            threading.Thread(target=self.publish, args=(put,), daemon=True).start()

        def publish(self, put):
            put(Event("connect", None, "connected"))
            for t in range(1, 11):
                put(sample(t))
            put(Event("disconnect", None, "lost"))
            put(Event("connect", None, "connected again"))
            for t in [30, 31, 32, *range(11, 30)]:
                put(sample(t))
            put(Readings([("current", 15.0, 33.0)], None, 33))  # row 33 without its temp
            put(sample(40))  # far past row 33's grace: it is held still
            time.sleep(3 * catch_up)
            put(End())

        def acknowledge(self, tokens):
            pass

        def stop(self):
            pass

    with Store(tmp_path / "s.db") as store:
        stopped = Monitor(MODEL, store, Reconnecting(), spec=None, options=MonitorOptions(catch_up=catch_up),
                          tags=read_tags(None, MODEL)).run()
        temps = [(time, SQLite.unvector(y, 1)[0])
                 for time, y in store.db.execute("SELECT time, y FROM sample ORDER BY t")]
    assert temps[:32] == [(float(t), 50.0 + t) for t in range(1, 33)]
    assert [time for time, _ in temps[32:]] == [33.0, 34.0, 35.0, 36.0, 37.0, 38.0]  # released by the grace
    assert math.isnan(temps[32][1]) and "late" not in stopped.events and stopped.events["jump"] == 1


def test_a_run_records_the_options_its_store_has_always_recorded():
    """A restart compares every recorded key, so the options value records exactly the keys a store's
    earlier runs hold (the diagnosis's but explain, the assembler's, the source and the tags)."""
    from jmlgdsl.diagnosis import Options
    from jmlgdsl.monitor.live import MonitorOptions, recorded_options

    options = MonitorOptions(Options(lag=3, prefilter=2, explain=True), grace=2.0)
    assert recorded_options(MODEL, options, "data.csv", {}) == {
        "algorithm": "imm", "particles": None, "seed": None, "resampling": "systematic", "ess_threshold": 1.0,
        "lag": 3, "prefilter": 2, "healthy": ["normal"], "threshold": 0.5, "persistence": 1, "grace": 2.0,
        "stale": None, "max_gap": 3600.0, "source": "data.csv", "tags": {}}
