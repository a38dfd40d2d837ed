"""What the monitor's tests against live servers share: the bundled dryer recording, free ports on
127.0.0.1, bounded waits on a running monitor, queries of its store, and the tables to compare."""

import os
import signal
import socket
import sqlite3
import time

import pytest
from conftest import ROOT

from jmlgdsl.cli import main

SPEC = str(ROOT / "specs" / "dryer.jmlg")
DATA = ROOT / "examples" / "dryer_seq1.csv"
WAIT = 30  # seconds any one wait may take before the test fails


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def query(store, sql):
    if not os.path.exists(store):
        return None
    db = sqlite3.connect(store)
    try:
        return db.execute(sql).fetchone()[0]
    except sqlite3.OperationalError:
        return None
    finally:
        db.close()


def until(condition, what, process):
    deadline = time.monotonic() + WAIT
    while not condition():
        if process.poll() is not None:
            pytest.fail(f"the monitor stopped while waiting for {what}: {process.stderr.read()}")
        assert time.monotonic() < deadline, f"gave up waiting for {what}"
        time.sleep(0.02)


def stop(process):
    process.send_signal(signal.SIGTERM)
    _, err = process.communicate(timeout=WAIT)
    assert process.returncode == 0, err
    return err


def expected_table(tmp_path):
    out = tmp_path / "run.csv"
    assert main(["run", SPEC, str(DATA), "-o", str(out)]) == 0
    return out.read_text()


def exported(tmp_path, store):
    out = tmp_path / "export.csv"
    assert main(["export", store, "-o", str(out)]) == 0
    return out.read_text()
