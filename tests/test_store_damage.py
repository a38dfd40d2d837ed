"""A monitor's store that was damaged or written by someone else: a checkpoint that is a pickle (as
earlier versions wrote them, or crafted to run code), a checkpoint with a byte flipped, damaged
pages, a JSON cell edited by hand, a file of 0 bytes. Nothing here ends in a traceback: the monitor
refuses to resume from state that does not verify and says what to do; `export` writes what is
readable and says what is not."""

import json
import pickle
import sqlite3

import pytest
from monitor_servers import LINES, SPEC

import jmlgdsl
from jmlgdsl.cli import main
from jmlgdsl.diagnosis import fingerprint


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
