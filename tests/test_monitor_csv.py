"""`jmlgdsl monitor` on a CSV source: the exported table equals `jmlgdsl run -o` on the same rows, a
monitor killed with SIGKILL mid-stream and started again with the same command loses and repeats no
row, a bad line is an event and not the end, and a store of another run is refused by name."""

import os
import sqlite3
import subprocess

import pytest
from conftest import ROOT, jmlgdsl_command
from monitor_servers import DATA, LINES, SPEC, WAIT, killed_mid_file

from jmlgdsl.cli import main


def table(*args, tmp_path, name="table.csv"):
    out = tmp_path / name
    assert main([*args, "-o", str(out)]) == 0
    return out.read_text()


def stored(store):
    """Rows with results committed in the store (0 before it exists)."""
    if not os.path.exists(store):
        return 0
    with sqlite3.connect(store) as db:
        try:
            return db.execute("SELECT count(*) FROM result").fetchone()[0]
        except sqlite3.OperationalError:
            return 0


@pytest.mark.parametrize("lag", [0, 3])
def test_export_equals_run(tmp_path, lag):
    store = str(tmp_path / "dryer.db")
    assert main(["monitor", SPEC, "--source", str(DATA), "--store", store, "--no-follow", "--lag", str(lag),
                 "--filter", "rbpf", "--seed", "3"]) == 0
    exported = table("export", store, "--samples", str(tmp_path / "rows.csv"), tmp_path=tmp_path)
    expected = table("run", SPEC, str(DATA), "--lag", str(lag), "--filter", "rbpf", "--seed", "3",
                     tmp_path=tmp_path, name="run.csv")
    assert exported == expected and len(exported.splitlines()) == 1001 + (lag > 0)
    # the rows the store kept are the rows: run on them writes the same table again
    again = table("run", SPEC, str(tmp_path / "rows.csv"), "--lag", str(lag), "--filter", "rbpf", "--seed", "3",
                  tmp_path=tmp_path, name="again.csv")
    assert again == expected


def test_killed_and_restarted_loses_and_repeats_nothing(tmp_path):
    data, store = tmp_path / "growing.csv", str(tmp_path / "dryer.db")
    command = [*jmlgdsl_command(), "monitor", SPEC, "--source", str(data), "--store", store, "--lag", "2"]
    err = killed_mid_file(command, data, lambda: stored(store))
    assert "resume: run 1 resumed after row" in err
    expected = table("run", SPEC, str(DATA), "--lag", "2", tmp_path=tmp_path, name="run.csv").splitlines(True)
    exported = table("export", store, tmp_path=tmp_path)
    assert exported == "".join(expected[:-2])  # the last 2 rows wait for the 2 rows after them
    with sqlite3.connect(store) as db:
        assert db.execute("SELECT count(*), min(t), max(t) FROM sample").fetchone() == (1000, 1, 1000)
        kinds = dict(db.execute("SELECT kind, count(*) FROM event GROUP BY kind"))
    assert kinds == {"start": 1, "resume": 1}


def test_bad_line_is_an_event(tmp_path, capsys):
    data, store = tmp_path / "bad.csv", str(tmp_path / "dryer.db")
    data.write_text("".join(LINES[:101] + ["101,15,hot,fan,50\n"] + LINES[101:]))
    assert main(["monitor", SPEC, "--source", str(data), "--store", store, "--no-follow"]) == 0
    err = capsys.readouterr().err
    assert f"monitor: malformed: {data}:102: column 'temp': 'hot' is not a number" in err
    assert "1000 rows diagnosed in run 1" in err and "malformed 1" in err
    assert table("export", store, tmp_path=tmp_path) == table("run", SPEC, str(DATA), tmp_path=tmp_path, name="r.csv")


def test_a_restarted_monitor_names_bad_lines_by_their_line_in_the_file(tmp_path, capsys):
    data, store = tmp_path / "bad.csv", str(tmp_path / "dryer.db")
    bad = "99,15,hot,fan,50\n"
    lines = ["# two comment lines\n", "#\n"] + LINES[:101] + [bad] + LINES[101:]  # bad: line 104
    data.write_text("".join(lines[:151]))
    assert main(["monitor", SPEC, "--source", str(data), "--store", store, "--no-follow"]) == 0
    assert f"monitor: malformed: {data}:104: column 'temp'" in capsys.readouterr().err
    with open(data, "a") as out:  # read on from the saved offset: a header, then line 152 on
        out.writelines(lines[151:301] + [bad] + lines[301:])  # bad: line 302
    assert main(["monitor", SPEC, "--source", str(data), "--store", store, "--no-follow"]) == 0
    err = capsys.readouterr().err
    assert f"monitor: malformed: {data}:302: column 'temp'" in err and "resumed after row 147" in err
    assert table("export", store, tmp_path=tmp_path) == table("run", SPEC, str(DATA), tmp_path=tmp_path, name="r.csv")


def test_store_of_another_run_is_refused(tmp_path, capsys):
    store = str(tmp_path / "dryer.db")
    assert main(["monitor", SPEC, "--source", str(DATA), "--store", store, "--no-follow"]) == 0
    other = str(ROOT / "specs" / "cstr4.jmlg")
    assert main(["monitor", other, "--source", str(DATA), "--store", store, "--no-follow"]) == 2
    err = capsys.readouterr().err
    assert f"error: the store {store} holds a run of another model (plant 'dryer'" in err and "--new-run" in err
    assert main(["monitor", SPEC, "--source", str(DATA), "--store", store, "--no-follow", "--threshold", "0.7"]) == 2
    assert "holds a run started with threshold 0.5, not 0.7" in capsys.readouterr().err
    assert main(["monitor", SPEC, "--source", str(DATA), "--store", store, "--no-follow", "--threshold", "0.7",
                 "--new-run"]) == 0
    assert main(["export", store, "--run", "3"]) == 2
    assert f"error: {store}: no run 3" in capsys.readouterr().err


def test_standard_input(tmp_path):
    store = str(tmp_path / "dryer.db")
    done = subprocess.run([*jmlgdsl_command(), "monitor", SPEC, "--source", "-", "--store", store],
                          input="".join(LINES), capture_output=True, text=True, timeout=WAIT)
    assert done.returncode == 0, done.stderr
    assert table("export", store, tmp_path=tmp_path) == table("run", SPEC, str(DATA), tmp_path=tmp_path, name="r.csv")


def test_package_example(monkeypatch):
    import doctest

    import jmlgdsl.monitor

    monkeypatch.chdir(ROOT)
    assert doctest.testmod(jmlgdsl.monitor).failed == 0


def test_particles_for_a_filter_without_particles_are_refused_before_the_store_is_made(tmp_path, capsys):
    assert main(["monitor", str(SPEC), "--source", str(DATA), "--no-follow", "--store", str(tmp_path / "s.db"),
                 "--filter", "imm", "--particles", "5"]) == 2
    assert capsys.readouterr().err.startswith("error: --particles: the imm filter uses no particles")
    assert list(tmp_path.iterdir()) == []


def test_a_store_that_fails_while_saving_says_so_and_keeps_nothing_of_the_batch(tmp_path):
    import numpy as np

    import jmlgdsl
    from jmlgdsl.data import Row
    from jmlgdsl.diagnosis import fingerprint
    from jmlgdsl.monitor import Store, StoreError
    from jmlgdsl.monitor.store import Commit

    model, path = jmlgdsl.load(SPEC), tmp_path / "dryer.db"
    with Store(path) as store:
        run = store.begin_run(None, model, fingerprint(model), {})
        with sqlite3.connect(path) as other:  # the store's rows table gone from under it
            other.execute("DROP TABLE result")
        row = Row(2, 1.0, np.array([50.5]), np.array([15.0]), None)
        with pytest.raises(StoreError, match=r"the store failed while saving \(no such table: result\); nothing of "
                                             r"this batch was kept"):
            store.save([Commit(run.id, [(1, row)], [], [], 1, b"state", None, None)])
        assert store.db.execute("SELECT count(*) FROM sample").fetchone()[0] == 0
        assert store.saved(run.id) is None
