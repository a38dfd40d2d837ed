"""One bad message on a data bus costs nothing but itself: injected once into the dryer recording
published one object per sample, a stamp far in the future, one far ahead of the stream, a bare
value stamped on arrival in a stream of stamped readings, or a payload that no parser should try
(brackets nested 5,000 deep, a 400-digit time) is one event, and every other row is stored and
diagnosed as `jmlgdsl run -o` diagnoses the recording. (The same through a real broker:
test_monitor_mqtt.py.)"""

import datetime
import sqlite3
import time

import pytest
from conftest import ROOT
from monitor_servers import expected_table, exported, samples

import jmlgdsl
from jmlgdsl.monitor import Monitor, MonitorOptions, Store, read_tags
from jmlgdsl.monitor.sources.contract import End, Readings, Unreadable
from jmlgdsl.monitor.sources.payload import Malformed, decode

MODEL = jmlgdsl.load(ROOT / "specs" / "dryer.jmlg")
NAMES = ["temp", "current"]


def soon(seconds):
    """An ISO time stamp `seconds` past now."""
    return (datetime.datetime.now(datetime.timezone.utc) + datetime.timedelta(seconds=seconds)).isoformat()


class Published:
    """The recording as an MQTT source hands it over: each message decoded as MqttSource decodes it,
    at its arrival, with `injected` (topic, payload) pairs after the 500th sample."""

    rows, name = False, "test://published"

    def __init__(self, injected):
        messages = [("dryer", payload) for payload in samples()]
        self.messages = messages[:500] + injected + messages[500:]

    def start(self, put, position):
        for token, (topic, payload) in enumerate(self.messages):
            name = None if topic == "dryer" else topic.removeprefix("dryer/")
            try:
                put(Readings(decode(payload.encode(), name, NAMES), time.time(), token))
            except Malformed as exc:
                put(Unreadable(f"topic {topic}: {exc}", token))
        put(End())

    def acknowledge(self, tokens):
        pass

    def stop(self):
        pass


@pytest.fixture(scope="module")
def expected(tmp_path_factory):
    return expected_table(tmp_path_factory.mktemp("run"))


@pytest.mark.parametrize("injected, kind", [
    ([("dryer", '{"t": "9999-12-31T23:59:59Z", "temp": 50.0}')], "future"),
    ([("dryer", '{"t": 10000000000, "temp": 50.0, "current": 15}')], "future"),
    ([("dryer/temp", '{"t": "SOON", "v": 50.1}')], "future"),  # SOON: 4.6 minutes ahead of the clock when it runs
    ([("dryer", '{"t": 100000, "temp": 50.0, "current": 15}')], "ahead"),  # ahead of the stream, not of the clock
    ([("dryer/temp", "50.6")], "malformed"),  # stamped on arrival: ahead of the stream's own times
    ([("dryer", "[" * 5000)], "malformed"),
    ([("dryer", '{"t": 1' + "0" * 399 + ', "temp": 50.0}')], "malformed"),
], ids=["year-9999", "t-1e10", "4.6-min-ahead", "ahead-of-stream", "bare-value", "nested", "400-digits"])
def test_one_bad_message_is_one_event_and_costs_no_row(tmp_path, expected, injected, kind):
    store = str(tmp_path / "dryer.db")
    injected = [(topic, payload.replace("SOON", soon(276))) for topic, payload in injected]  # not at collection
    with Store(store) as opened:
        stopped = Monitor(MODEL, opened, Published(injected), spec=None, options=MonitorOptions(),
                          tags=read_tags(None, MODEL)).run()
    assert stopped.rows == 1000
    assert exported(tmp_path, store) == expected
    kinds = dict(sqlite3.connect(store).execute("SELECT kind, count(*) FROM event GROUP BY kind"))
    assert kinds == {"start": 1, kind: 1}
