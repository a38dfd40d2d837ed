"""A store of schema 4, which kept every vector as JSON text, brought to the packed layout when it is
opened: its rows converted in place to the bit, so `export` writes what `run -o` writes and the page
shows what a store written in the new layout shows; a cell that was not a JSON vector stays a row
that does not read, as it was."""

import json
import sqlite3

from monitor_servers import LINES, SPEC

from jmlgdsl.cli import main
from jmlgdsl.monitor import Store
from jmlgdsl.monitor.store.databases import SQLite
from jmlgdsl.monitor.store.schema import SCHEMA, VECTORS
from jmlgdsl.page import views

UNMEASURED = range(100, 104)  # rows whose temperature is not measured (a NaN, JSON's null)


def json_vector(values) -> str:
    """A vector as schema 4 wrote it: shortest round-trip digits, NaN as null."""
    return "[" + ", ".join("null" if v != v else json.dumps(v) for v in values) + "]"


def as_schema_4(store):
    """Rewrite a store as schema 4 kept it: the same tables with TEXT columns, every vector JSON text."""
    with sqlite3.connect(store) as db:
        for table, columns in VECTORS.items():
            names = [row[1] for row in db.execute(f"PRAGMA table_info({table})")]
            rows = db.execute(f"SELECT * FROM {table}").fetchall()
            db.execute(f"DROP TABLE {table}")
            db.execute(next(s for s in SCHEMA.split(";") if f"EXISTS {table} (" in s).replace("VECTOR", "TEXT"))
            db.executemany(f"INSERT INTO {table} VALUES ({','.join('?' * len(names))})", [
                tuple(json_vector(SQLite.unvector(cell, len(cell) // 8)) if name in columns and cell is not None
                      else cell for name, cell in zip(names, row)) for row in rows])
        db.execute("UPDATE meta SET value = '4' WHERE key = 'schema'")
    db.close()


def cells(store, sql):
    with sqlite3.connect(store) as db:
        found = db.execute(sql).fetchall()
    db.close()
    return found


def written(command, tmp_path, name):
    out = tmp_path / name
    assert main([*command, "-o", str(out)]) == 0
    return out.read_text()


def test_a_store_of_json_vectors_upgrades_in_place_and_exports_as_before(tmp_path, capsys):
    data, first = tmp_path / "data.csv", tmp_path / "first.csv"
    lines = [",".join(line.split(",")[:2] + [""] + line.split(",")[3:]) if t in UNMEASURED else line
             for t, line in enumerate(LINES)]
    data.write_text("".join(lines))
    first.write_text("".join(lines[:501]))
    fresh, old = str(tmp_path / "fresh.db"), str(tmp_path / "old.db")
    assert main(["monitor", SPEC, "--source", str(data), "--store", fresh, "--no-follow"]) == 0
    assert main(["monitor", SPEC, "--source", str(first), "--store", old, "--no-follow"]) == 0
    as_schema_4(old)
    assert cells(old, "SELECT y FROM sample WHERE t = 100") == [("[null]",)]
    assert cells(old, "SELECT typeof(posterior), typeof(y_sd), typeof(evidence) FROM result WHERE t = 1") == [
        ("text", "text", "text")]

    # the monitor opens the old store, converts it and resumes where it stopped
    with open(first, "a") as out:
        out.writelines(lines[501:])
    assert main(["monitor", SPEC, "--source", str(first), "--store", old, "--no-follow"]) == 0
    assert cells(old, "SELECT value FROM meta WHERE key = 'schema'") == [("5",)]
    assert cells(old, "SELECT DISTINCT typeof(y), typeof(u) FROM sample") == [("blob", "blob")]
    assert cells(old, "SELECT DISTINCT typeof(posterior), typeof(state_mean), typeof(y_pred), typeof(residual), "
                      "typeof(y_sd), typeof(evidence) FROM result WHERE evidence IS NOT NULL") == [("blob",) * 6]
    expected = written(["run", SPEC, str(data)], tmp_path, "run.csv")
    assert written(["export", old], tmp_path, "old.csv") == expected == written(["export", fresh], tmp_path, "new.csv")
    assert main(["export", old, "-o", str(tmp_path / "table.csv"), "--samples", str(tmp_path / "old-rows.csv")]) == 0
    assert main(["export", fresh, "-o", str(tmp_path / "table.csv"), "--samples", str(tmp_path / "rows.csv")]) == 0
    assert (tmp_path / "old-rows.csv").read_text() == (tmp_path / "rows.csv").read_text()
    with Store(old) as upgraded, Store(fresh) as new:
        shown = views.rows(upgraded, upgraded.run(), first=1, last=1000)
        assert shown == views.rows(new, new.run(), first=1, last=1000) and shown.count == 1000
        assert json.loads(shown.json)["y"][100] == [None]
        assert views.fleet(upgraded, None) == views.fleet(new, None)
    assert "warning" not in capsys.readouterr().err


def test_a_cell_that_was_not_json_stays_a_row_that_does_not_read(tmp_path, capsys):
    first = tmp_path / "first.csv"
    first.write_text("".join(LINES[:201]))
    store = str(tmp_path / "old.db")
    assert main(["monitor", SPEC, "--source", str(first), "--store", store, "--no-follow"]) == 0
    as_schema_4(store)
    with sqlite3.connect(store) as db:
        db.execute("UPDATE result SET posterior = '[0.5, 0.2' WHERE t = 7")
    db.close()
    capsys.readouterr()
    assert main(["export", store, "-o", str(tmp_path / "table.csv")]) == 0
    assert "1 row could not be read and is left out (t 7)" in capsys.readouterr().err
    assert cells(store, "SELECT posterior FROM result WHERE t = 7") == [("[0.5, 0.2",)]
    expected = written(["run", SPEC, str(first)], tmp_path, "run.csv").splitlines(keepends=True)
    assert (tmp_path / "table.csv").read_text() == "".join(line for t, line in enumerate(expected) if t != 7)
