"""A monitor's store that was damaged or written by someone else: a checkpoint that is a pickle (as
earlier versions wrote them, or crafted to run code), a checkpoint with a byte flipped, damaged
pages, a cell edited by hand, a file of 0 bytes. Nothing here ends in a traceback: the monitor
refuses to resume from state that does not verify and says what to do; `export` writes what is
readable and says what is not."""

import json
import pickle
import random
import shutil
import sqlite3
import subprocess
import urllib.request

import pytest
from conftest import jmlgdsl_command
from monitor_servers import DATA, LINES, SPEC, WAIT

import jmlgdsl
from jmlgdsl.cli import main
from jmlgdsl.diagnosis import fingerprint
from jmlgdsl.page import Page


def monitored(tmp_path, lines=301):
    """A store of the first `lines` - 1 rows of the dryer recording, diagnosed by `monitor`."""
    data, store = tmp_path / "part.csv", str(tmp_path / "dryer.db")
    data.write_text("".join(LINES[:lines]))
    assert main(["monitor", SPEC, "--source", str(data), "--store", store, "--no-follow"]) == 0
    return data, store


def resume(data, store, *more):
    return main(["monitor", SPEC, "--source", str(data), "--store", store, "--no-follow", *more])


def set_state(store, column, value):
    with sqlite3.connect(store) as db:
        db.execute(f"UPDATE state SET {column} = ? WHERE run = 1", (value,))
    db.close()


def test_a_pickled_checkpoint_in_the_store_is_refused_unread(tmp_path, capsys):
    data, store = monitored(tmp_path)
    marker = tmp_path / "ran"

    class Payload:
        def __reduce__(self):
            return (open, (str(marker), "w"))

    identity = {"format": 2, "version": jmlgdsl.__version__, "plant": "dryer",
                "model": fingerprint(jmlgdsl.load(SPEC))}
    set_state(store, "checkpoint", b"jmlgdsl-checkpoint\n" + json.dumps(identity).encode() + b"\n"
              + pickle.dumps({"filter": Payload()}))
    set_state(store, "monitor", pickle.dumps({"assembler": Payload()}))
    capsys.readouterr()
    assert resume(data, store) == 2
    err = capsys.readouterr().err
    assert (f"error: the store {store} cannot resume run 1 from its saved state (after row 300, saved " in err
            and "a checkpoint of an earlier jmlgdsl, saved as a Python pickle: it is not read" in err
            and "Start a new run with --new-run" in err and "Traceback" not in err)
    assert not marker.exists()
    assert resume(data, store, "--new-run") == 0  # the way on that the message gives
    assert "300 rows diagnosed in run 2" in capsys.readouterr().err


@pytest.mark.parametrize("column", ["checkpoint", "monitor"])
def test_a_checkpoint_with_a_byte_flipped_is_refused_by_name(tmp_path, capsys, column):
    data, store = monitored(tmp_path)
    with sqlite3.connect(store) as db:
        blob = bytearray(db.execute(f"SELECT {column} FROM state").fetchone()[0])
    db.close()
    blob[len(blob) // 2] ^= 0x10
    set_state(store, column, bytes(blob))
    capsys.readouterr()
    assert resume(data, store) == 2
    err = capsys.readouterr().err
    assert f"error: the store {store} cannot resume run 1 from its saved state (after row 300" in err
    assert "checksum does not match its contents" in err and "there is no earlier one to go back to" in err
    assert "Traceback" not in err
    assert main(["export", store, "-o", str(tmp_path / "out.csv")]) == 0  # its rows stay readable
    assert len((tmp_path / "out.csv").read_text().splitlines()) == 301


def settled(store):
    """The store's file with its write-ahead log folded in, as a copy or a backup would take it."""
    with sqlite3.connect(store) as db:
        db.execute("PRAGMA wal_checkpoint(TRUNCATE)")
    db.close()


def edit(store, sql, *params):
    with sqlite3.connect(store) as db:
        db.execute(sql, params)
    db.close()


def damaged_cells(tmp_path):
    """A store of 300 rows with three cells damaged: the posterior of row 17 a byte short (not the
    float64s of every mode), the y of row 40 and the residual of row 41 edited by hand as text."""
    data, store = monitored(tmp_path)
    settled(store)
    shutil.copy(store, tmp_path / "whole.db")
    edit(store, "UPDATE result SET posterior = substr(posterior, 2) WHERE t = 17")
    edit(store, "UPDATE sample SET y = '[50.1' WHERE t = 40")
    edit(store, "UPDATE result SET residual = '{\"temp\": 1}' WHERE t = 41")
    return data, store


def test_export_writes_the_rows_that_read_and_names_the_others(tmp_path, capsys):
    data, store = damaged_cells(tmp_path)
    capsys.readouterr()
    table, rows = tmp_path / "table.csv", tmp_path / "rows.csv"
    assert main(["export", store, "-o", str(table), "--samples", str(rows)]) == 0
    err = capsys.readouterr().err
    assert (f"warning: {store}: run 1: 2 rows could not be read and are left out (t 17, 41) of {table}; 298 rows "
            "exported") in err
    assert (f"warning: {store}: run 1: 1 row could not be read and is left out (t 40) of {rows}; 299 rows "
            "exported") in err
    whole_table, whole_rows = tmp_path / "whole.csv", tmp_path / "whole-rows.csv"
    assert main(["export", str(tmp_path / "whole.db"), "-o", str(whole_table), "--samples", str(whole_rows)]) == 0
    lines = whole_table.read_text().splitlines(True)  # the header, then row t on line t
    assert table.read_text() == "".join(line for t, line in enumerate(lines) if t not in (17, 41))
    lines = whole_rows.read_text().splitlines(True)
    assert rows.read_text() == "".join(line for t, line in enumerate(lines) if t != 40)


def test_the_page_shows_the_rows_that_read(tmp_path):
    _, store = damaged_cells(tmp_path)
    page = Page(store, "127.0.0.1", 0).start()
    try:
        for path in ("api/rows?first=1&last=300", "api/rows?after=10&limit=20", "api/rows"):
            with urllib.request.urlopen(page.url + path, timeout=WAIT) as answer:
                found = json.load(answer)
            assert 17 not in found["t"] and 40 not in found["t"] and len(found["t"]) == len(found["posterior"])
        assert found["t"] == [t for t in range(1, 301) if t not in (17, 40)]  # the page shows no residual: 41 reads
        with urllib.request.urlopen(page.url + "api/alarms", timeout=WAIT) as answer:
            assert answer.status == 200
    finally:
        page.stop()


@pytest.mark.parametrize("sql, message", [
    ("UPDATE state SET position = '{\"offset\": 1' WHERE run = 1",
     "the saved state of run 1 cannot be read, the store is damaged (Expecting"),
    ("UPDATE state SET rows = 280 WHERE run = 1",
     "the saved state of run 1 cannot be read, the store is damaged (it counts 280 rows diagnosed where the "
     "run's rows end at 300)"),
    ("UPDATE run SET outputs = '[\"temp\"' WHERE id = 1",
     "the record of the latest run cannot be read, the store is damaged (Expecting ',' delimiter"),
])
def test_a_monitor_refuses_to_resume_from_a_state_that_does_not_read(tmp_path, capsys, sql, message):
    data, store = monitored(tmp_path)
    edit(store, sql)
    capsys.readouterr()
    assert resume(data, store) == 2
    err = capsys.readouterr().err
    assert f"error: {store}: {message}" in err and "Traceback" not in err


def test_a_store_whose_run_record_does_not_read_names_the_runs_that_do(tmp_path, capsys):
    data, store = monitored(tmp_path)
    assert resume(data, store, "--new-run", "--threshold", "0.7") == 0
    edit(store, "UPDATE run SET modes = '[1, 2]' WHERE id = 2")
    capsys.readouterr()
    assert main(["export", store, "-o", str(tmp_path / "out.csv")]) == 2
    assert (f"error: {store}: the record of the latest run cannot be read, the store is damaged (its lists of names "
            "are not lists of names); runs that read: 1 (--run N)") in capsys.readouterr().err
    assert main(["export", store, "--run", "1", "-o", str(tmp_path / "out.csv")]) == 0


def test_an_empty_store_file_is_refused_not_started_again(tmp_path, capsys):
    store = tmp_path / "dryer.db"
    store.write_bytes(b"")
    assert main(["monitor", SPEC, "--source", str(DATA), "--store", str(store), "--no-follow"]) == 2
    assert (f"error: {store}: an empty file (0 bytes), not a store: if it held one, that store was lost (the file "
            "was cut to nothing); restore it from a backup, or remove the file to start a new store there"
            ) in capsys.readouterr().err
    assert store.read_bytes() == b""


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("flips", [50, 5000])
def test_bytes_flipped_anywhere_end_in_a_message_not_a_traceback(tmp_path, seed, flips):
    data, store = monitored(tmp_path)
    settled(store)
    raw = bytearray(open(store, "rb").read())
    rng = random.Random(seed)
    for _ in range(flips):
        at = rng.randrange(100, len(raw))  # the first page's header left whole: the file is SQLite's still
        raw[at] ^= 1 << rng.randrange(8)
    open(store, "wb").write(raw)
    for command in (["export", store, "-o", str(tmp_path / "out.csv"), "--samples", str(tmp_path / "rows.csv")],
                    ["monitor", SPEC, "--source", str(data), "--store", store, "--no-follow"]):
        done = subprocess.run([*jmlgdsl_command(), *command], capture_output=True, text=True, timeout=WAIT)
        assert "Traceback" not in done.stderr and done.returncode in (0, 2), done.stderr
        assert done.returncode == 0 or "damaged" in done.stderr or "another" in done.stderr, done.stderr
