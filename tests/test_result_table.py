"""The result table from Python: write_result writes what `run -o` writes, and read_table reads it back."""

import csv
import io
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import jmlgdsl
from jmlgdsl.cli import main
from jmlgdsl.data import format_cell, joined_numbers, read_csv, write_columns
from jmlgdsl.diagnosis.evidence import Evidence
from jmlgdsl.infer.result import Step
from jmlgdsl.infer.table import TableWriter, read_table, write_result
from jmlgdsl.simulation.linear import simulate


def test_a_result_written_from_python_is_the_run_table(tmp_path, capsys):
    model = jmlgdsl.load("specs/dryer.jmlg")
    data = tmp_path / "seq.csv"
    write_columns(data, simulate(model, modes="1-20:normal,21-40:fan", seed=3).columns())
    ran = tmp_path / "from_run.csv"
    assert main(["run", "specs/dryer.jmlg", str(data), "-o", str(ran)]) == 0
    capsys.readouterr()
    alarm = [int(row["alarm"]) for row in csv.DictReader(ran.open())]

    d = read_csv(data, model)
    result = jmlgdsl.filter(model, d.y, d.u)
    out = tmp_path / "from_python.csv"
    write_result(out, result, time=d.time, alarm=alarm)
    assert out.read_text() == ran.read_text()  # the same columns and numbers, byte for byte

    table = read_table(out)
    assert table.modes == list(model.modes) and table.outputs == list(model.outputs)
    assert table.given == "the data so far"
    np.testing.assert_array_equal(table.t, np.arange(1, 41))
    np.testing.assert_array_equal(table.time, d.time)
    np.testing.assert_allclose(table.mode_posterior, result.mode_posterior, rtol=1e-9)
    np.testing.assert_allclose(table.residuals, result.residuals, rtol=1e-9)


def test_a_result_table_that_fails_part_way_is_not_written(tmp_path):
    model = jmlgdsl.load("specs/dryer.jmlg")
    result = jmlgdsl.filter(model, simulate(model, 20, seed=1).y)
    out = tmp_path / "result.csv"
    out.write_text("the old table\n")
    with pytest.raises(ValueError):
        write_result(out, result, time=np.arange(10.0))  # the times end at row 10 of 20
    assert out.read_text() == "the old table\n" and [p.name for p in tmp_path.iterdir()] == ["result.csv"]


@given(st.lists(st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-10**12, 10**12)),
                min_size=1, max_size=20))
def test_a_rows_numbers_are_joined_in_one_format_as_cell_by_cell(values):
    """A table's line formats its numbers with one format of them all (joined_numbers): the cells
    format_cell makes, NaN an empty cell, -0.0 '-0', infinities 'inf'."""
    assert joined_numbers(values) == ",".join(format_cell(float(v)) for v in values)


def test_a_table_row_is_the_line_a_csv_writer_writes_of_its_cells():
    """A result table's row, made in one pass, is byte for byte the line csv.writer makes of its cells:
    a mode's name that needs quoting quoted, a missing number an empty cell, the evidence after."""
    names = SimpleNamespace(modes=("normal", 'fan, "off"'), states=("x",), outputs=("a", "b"), ny=2)
    step = Step(7, np.array([0.25, 0.75]), np.array([-0.0]), None, np.array([1e-320, 2.5]),
                np.array([np.nan, 123456789012.0]), -1.5, 3.0)
    out = io.StringIO()
    writer = TableWriter(out, names, True, explain=True)
    writer.write(step, 1583752474.5, 1, Evidence(1, 0, np.array([0.5, np.inf]), np.inf))
    writer.write(step, np.nan, 0, None)
    expected = io.StringIO()
    lines = csv.writer(expected, lineterminator="\n")
    numbers = [0.25, 0.75, -0.0, 1e-320, 2.5, np.nan, 123456789012.0, 3.0]
    lines.writerow([format_cell(v) for v in [7, 1583752474.5, 'fan, "off"', *numbers, 1, 'fan, "off"', 0.5, np.inf]])
    lines.writerow([format_cell(v) for v in [7, np.nan, 'fan, "off"', *numbers, 0, "", "", ""]])
    assert out.getvalue().split("\n", 1)[1] == expected.getvalue()


@pytest.mark.parametrize("with_time", [True, False])
def test_many_rows_written_at_once_are_the_rows_written_one_at_a_time(with_time):
    """`write_rows` (a Result's table, a fleet's whole files) writes the bytes `write` writes row by
    row: a NaN an empty cell, a mode's name holding 'nan' or '%' as it is, quoted where it needs."""
    names = SimpleNamespace(modes=("banana", '50%, "off"', "nan"), states=("x", "v"), outputs=("a",))
    rng = np.random.default_rng(5)
    T = 6
    posterior = rng.dirichlet(np.ones(3), T)
    posterior[2] = [0.1, 0.2, 0.7]  # the mode named nan
    mean, y_pred, residuals = rng.normal(size=(T, 2)) * 1e5, rng.normal(size=(T, 1)), rng.normal(size=(T, 1))
    residuals[1, 0] = np.nan
    ess, time, alarm = np.full(T, np.nan), np.arange(T) * 1.5 + 1e9, np.array([0, 1, 1, 0, 1, 0])
    time[3] = np.nan
    one, many = io.StringIO(), io.StringIO()
    writer = TableWriter(one, names, with_time)
    for i in range(T):
        writer.write(Step(i + 1, posterior[i], mean[i], None, y_pred[i], residuals[i], 0.0, ess[i]),
                     time[i] if with_time else None, int(alarm[i]))
    TableWriter(many, names, with_time).write_rows(np.arange(1, T + 1), posterior, mean, y_pred, residuals, ess,
                                                   time if with_time else None, alarm)
    assert many.getvalue() == one.getvalue()
    lines = one.getvalue().splitlines()
    assert lines[2].split(",")[-3] == "" and ",nan," in lines[3] and '"50%, ""off"""' in one.getvalue()
