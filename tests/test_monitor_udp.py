"""`jmlgdsl monitor --source udp://HOST:PORT`: the dryer recording sent as one datagram per sample to
a monitor listening on 127.0.0.1 is diagnosed into the store and exported as the very table
`jmlgdsl run -o` writes for it, a datagram that is no sample being a malformed event; and the
source is found by its scheme, refusing what it does not take."""

import socket
import sqlite3
import subprocess

import pytest
from conftest import jmlgdsl_command
from monitor_servers import SPEC, exported, expected_table, free_port, query, samples, stop, until

import jmlgdsl
from jmlgdsl.errors import JmlgError
from jmlgdsl.monitor import read_tags
from jmlgdsl.monitor.units import FleetError
from jmlgdsl.monitor.sources import Connection, open_source
from jmlgdsl.monitor.sources.udp import UdpSource


def test_datagrams_are_diagnosed_as_run_diagnoses_them(tmp_path):
    port, store = free_port(), str(tmp_path / "dryer.db")
    process = subprocess.Popen([*jmlgdsl_command(), "monitor", SPEC, "--source", f"udp://127.0.0.1:{port}",
                                "--store", store], stderr=subprocess.PIPE, text=True)
    try:
        until(lambda: query(store, "SELECT count(*) FROM event WHERE kind = 'connect'") == 1, "the monitor to listen",
              process)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sender:
            for k, payload in enumerate(samples() + ["hot"]):
                sender.sendto(payload.encode(), ("127.0.0.1", port))
                if k % 50 == 49:  # UDP drops what overflows the receiver's buffer: a chunk at a time
                    until(lambda: query(store, "SELECT count(*) FROM sample") == k + 1, f"row {k + 1}", process)
        until(lambda: query(store, "SELECT count(*) FROM event WHERE kind = 'malformed'") == 1,
              "the malformed datagram", process)
        err = stop(process)
    finally:
        process.kill()
    assert exported(tmp_path, store) == expected_table(tmp_path)
    kinds = dict(sqlite3.connect(store).execute("SELECT kind, count(*) FROM event GROUP BY kind"))
    assert kinds == {"start": 1, "connect": 1, "malformed": 1}
    assert "monitor: malformed: datagram from 127.0.0.1: sample: payload 'hot' is neither a number nor JSON" in err


MODEL = jmlgdsl.load(SPEC)
TAGS = read_tags(None, MODEL)


def test_the_scheme_names_the_source_and_it_refuses_what_it_does_not_take():
    source = open_source(Connection("udp://127.0.0.1:9999"), MODEL, TAGS)
    assert isinstance(source, UdpSource) and source.name == "udp://127.0.0.1:9999" and not source.rows
    for connection, message in [(Connection("udp://127.0.0.1:9999", client_id="x"), "a UDP source takes no --client-id"),
                                (Connection("udp://127.0.0.1"), "give the host and port to listen on"),
                                (Connection("udp://127.0.0.1:9999/path"), "give the host and port to listen on"),
                                (Connection("tcp://127.0.0.1:9999"), "or udp://")]:
        with pytest.raises(JmlgError, match=message):
            open_source(connection, MODEL, TAGS)
    with pytest.raises(FleetError, match="--units with a UDP source: not supported"):
        open_source(Connection("udp://127.0.0.1:9999"), MODEL, TAGS, ["a", "b"])


def test_a_port_taken_is_refused_by_name():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as taken:
        taken.bind(("127.0.0.1", 0))
        source = open_source(Connection(f"udp://127.0.0.1:{taken.getsockname()[1]}"), MODEL, TAGS)
        with pytest.raises(JmlgError, match=r"--source udp://127\.0\.0\.1:\d+: cannot listen there \(Address already"):
            source.start(lambda item: None, None)
