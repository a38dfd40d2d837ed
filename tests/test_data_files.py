"""Data files as loggers and old machines write them: time stamps that step by other than the sample
time, a time axis that goes backwards, CR-only line endings, and cells that only look like numbers."""

import subprocess
import threading
import warnings
from pathlib import Path

import numpy as np
import pytest
from conftest import jmlgdsl_command
from infer_models import dryer

import jmlgdsl
from jmlgdsl import Model
from jmlgdsl.cli import main
from jmlgdsl.data import DataWarning, read_csv
from jmlgdsl.errors import DataError

ROOT = Path(__file__).resolve().parent.parent
SPEC = ROOT / "specs" / "dryer.jmlg"  # sample 1 s, input current, output temp
EXAMPLE = ROOT / "examples" / "dryer_seq1.csv"


def stamps(seconds):
    return [f"2020-03-09 10:{s // 60:02d}:{s % 60:02d}" for s in seconds]


def written(tmp_path, text, name="d.csv", newline="\n"):
    path = tmp_path / name
    path.write_bytes(text.replace("\n", newline).encode())
    return path


def data_warnings(path, model=None):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        warnings.simplefilter("ignore", ResourceWarning)  # a file another test left open, collected now
        read_csv(path, model or dryer())
    return [str(w.message) for w in caught if issubclass(w.category, DataWarning)]


# A time column that steps by other than the sample time ------------------------------------------

def test_time_stamps_two_seconds_apart_are_warned_about_like_a_time_column(tmp_path):
    rows = "".join(f"{s},1,50\n" for s in stamps(range(0, 20, 2)))
    path = written(tmp_path, "datetime,one,temp\n" + rows)
    assert data_warnings(path) == [
        f"{path}:3: column 'datetime' steps by 2 s but the model's sample time is 1 s"]
    numbers = written(tmp_path, "time,one,temp\n" + "".join(f"{s},1,50\n" for s in range(0, 20, 2)), "n.csv")
    assert data_warnings(numbers) == [f"{numbers}:3: column 'time' steps by 2 s but the model's sample time is 1 s"]


def test_a_gap_in_time_stamps_names_the_datetime_column(tmp_path):
    rows = "".join(f"{s},1,50\n" for s in stamps([0, 1, 2, 62, 63]))
    path = written(tmp_path, "datetime,one,temp\n" + rows)
    assert data_warnings(path) == [
        f"{path}:5: column 'datetime' steps by 60 s but the model's sample time is 1 s"]


def test_time_stamps_in_step_raise_no_warning(tmp_path):
    rows = "".join(f"{s},1,50\n" for s in stamps(range(100)))
    assert data_warnings(written(tmp_path, "datetime,one,temp\n" + rows)) == []
    tenths = "".join(f"2020-03-09T10:00:{i // 10:02d}.{i % 10}Z,1,50\n" for i in range(300))
    tenth = Model.from_arrays(A=[[0.9]], B=0.1, C=[[1.0]], D=0.1, F=[[1.0]], P=[[1.0]], p0=[1.0], mu0=[0.0],
                              Sigma0=0.0, inputs=("one",), outputs=("temp",), input_defaults=[1.0],
                              modes=("ok",), dt=0.1)
    assert data_warnings(written(tmp_path, "datetime,one,temp\n" + tenths), tenth) == []


def test_a_numeric_time_column_of_epoch_seconds_is_checked_too(tmp_path):
    rows = "".join(f"{1583748873 + s},1,50\n" for s in range(0, 10, 2))
    path = written(tmp_path, "time,one,temp\n" + rows)
    assert data_warnings(path) == [f"{path}:3: column 'time' steps by 2 s but the model's sample time is 1 s"]


def test_a_repeated_time_stamp_is_shown_as_written(tmp_path):
    rows = "".join(f"{s},1,50\n" for s in stamps([0, 1, 1, 2]))
    path = written(tmp_path, "datetime,one,temp\n" + rows)
    assert data_warnings(path) == [f"{path}:4: column 'datetime' repeats 2020-03-09 10:00:01"]


# A time axis that goes backwards -------------------------------------------------------------------

@pytest.mark.parametrize("header, times, message", [
    ("time", ["1", "2", "1.5", "3"], "d.csv:4: column 'time' goes backwards (2 then 1.5)"),
    ("datetime", stamps([0, 1, 2, 1]),
     "d.csv:5: column 'datetime' goes backwards (2020-03-09 10:00:02 then 2020-03-09 10:00:01)"),
    ("time", ["1", "2", "", "1"], "d.csv:5: column 'time' goes backwards (2 then 1)"),  # across a missing time
])
def test_a_time_axis_that_goes_backwards_is_an_error_at_its_row(tmp_path, header, times, message):
    path = written(tmp_path, f"{header},one,temp\n" + "".join(f"{t},1,50\n" for t in times))
    with pytest.raises(DataError) as err:
        read_csv(path, dryer())
    assert str(err.value) == f"{tmp_path}/{message}; the rows must be in time order"


def test_run_stops_at_the_row_where_time_goes_backwards_and_writes_nothing(tmp_path, capsys):
    lines = EXAMPLE.read_text().splitlines()
    lines[500], lines[501] = lines[501], lines[500]  # rows 500 and 501 swapped: CSV lines 501 and 502
    data = written(tmp_path, "\n".join(lines) + "\n")
    fresh, kept = tmp_path / "fresh.csv", tmp_path / "kept.csv"
    kept.write_text("an earlier table\n")
    for out in (fresh, kept):
        assert main(["run", str(SPEC), str(data), "-o", str(out)]) == 2
        err = capsys.readouterr().err
        errors = [line for line in err.splitlines() if line.startswith("error: ")]
        assert errors == [f"error: {data}:502: column 'time' goes backwards (501 then 500); "
                          "the rows must be in time order"], err
        assert err.splitlines()[-1] == errors[0]
    assert not fresh.exists() and kept.read_text() == "an earlier table\n"
    assert not list(tmp_path.glob(".*"))  # no temporary file left behind


def test_a_time_axis_given_to_the_metrics_that_goes_backwards_is_located():
    from jmlgdsl.diagnosis.metrics import seconds

    with pytest.raises(DataError) as err:
        seconds([0.0, 1.0, 2.0, 1.5], 4)
    assert str(err.value) == "the time axis goes backwards at row 4 of 4 (2 s then 1.5 s)"


# CR-only line endings (old Mac files) --------------------------------------------------------------

def test_a_file_with_cr_line_endings_reads_as_its_lf_twin(tmp_path):
    text = EXAMPLE.read_text()
    model = jmlgdsl.load(SPEC)
    lf = read_csv(EXAMPLE, model)
    for newline in ("\r", "\r\n"):
        twin = read_csv(written(tmp_path, text, newline=newline), model)
        for name in ("time", "y", "u", "modes"):
            np.testing.assert_array_equal(getattr(twin, name), getattr(lf, name))


def test_lines_of_a_cr_file_are_numbered_as_an_editor_shows_them(tmp_path):
    path = written(tmp_path, "time,one,temp\n1,1,50\n\n2,1,5x\n", newline="\r")
    with pytest.raises(DataError, match=r"d.csv:4: column 'temp': '5x' is not a number$"):
        read_csv(path, dryer())


def test_a_crlf_cut_between_reads_is_one_line_end(tmp_path):
    # Long files are read in pieces: a "\r\n" that straddles two of them still ends one line.
    row = "1,1,50.000000\r\n"
    for pad in range(0, 40):
        head = "time,one,temp" + " " * pad + "\r\n"
        count = (1 << 16) // len(row) + 2
        text = head + "".join(f"{i + 1}" + row[1:] for i in range(count)) + "x,1,50\r\n"
        path = tmp_path / "long.csv"
        path.write_bytes(text.encode())
        with pytest.raises(DataError, match=rf"long.csv:{count + 2}: column 'time': 'x' is not a number$"):
            read_csv(path, dryer())


def test_standard_input_with_cr_line_endings_is_read_row_by_row(tmp_path):
    proc = subprocess.Popen([*jmlgdsl_command(), "run", str(SPEC), "-", "-o", "-", "--seed", "2"],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    timer = threading.Timer(60, proc.kill)  # never hang the test run
    timer.start()
    try:
        proc.stdin.write(b"temp\r50.5\r")
        proc.stdin.flush()
        # The row is filtered while standard input is still open: a CR ends a line as it arrives.
        assert proc.stdout.readline().startswith(b"t,map_mode,p_normal")
        assert proc.stdout.readline().startswith(b"1,normal,")
        proc.stdin.write(b"\n50.4\r\n50.3\r")  # a CR LF cut between two writes is one line end
        proc.stdin.close()
        assert proc.stdout.readline().startswith(b"2,normal,")
        assert proc.stdout.readline().startswith(b"3,normal,")
        assert proc.wait() == 0, proc.stderr.read()
    finally:
        timer.cancel()
        proc.kill()


def test_standard_input_with_cr_line_endings_gives_the_table_of_its_lf_twin(tmp_path):
    text = EXAMPLE.read_bytes()[:20000].rsplit(b"\n", 1)[0] + b"\n"
    tables = [subprocess.run([*jmlgdsl_command(), "run", str(SPEC), "-", "--seed", "1"], input=data,
                             capture_output=True, check=True).stdout
              for data in (text, text.replace(b"\n", b"\r"))]
    assert tables[0] == tables[1] and tables[0].count(b"\n") > 300


# Cells that only look like numbers -----------------------------------------------------------------

@pytest.mark.parametrize("cell", ["5_0.1", "1_000", "_5", "\uff15\uff10", "\u0665\u0660", "1e1_0"])
def test_cells_float_reads_but_no_logger_writes_are_refused(tmp_path, cell):
    path = written(tmp_path, f"time,one,temp\n1,1,50\n2,1,{cell}\n")
    with pytest.raises(DataError) as err:
        read_csv(path, dryer())
    assert str(err.value) == f"{path}:3: column 'temp': {cell!r} is not a number"


@pytest.mark.parametrize("column", ["time", "one", "anomaly"])
def test_digit_separators_are_refused_in_every_numeric_column(tmp_path, column):
    cells = {"time": "1", "one": "1", "temp": "50", "anomaly": "0"}
    cells[column] = "1_0"
    path = written(tmp_path, ",".join(cells) + "\n" + ",".join(cells.values()) + "\n")
    with pytest.raises(DataError, match=rf"d.csv:2: column '{column}': '1_0' is not a number$"):
        read_csv(path, dryer())


@pytest.mark.parametrize("cell, value", [
    ("", None), ("NA", None), ("na", None), ("NaN", None), ("nan", None), ("n/a", None), ("-nan", None),
    ("50", 50.0), (" 50.5 ", 50.5), ("+5", 5.0), ("-5.", -5.0), (".5", 0.5), ("5e1", 50.0), ("5E-1", 0.5),
])
def test_the_cells_loggers_write_still_read(tmp_path, cell, value):
    data = read_csv(written(tmp_path, f"time,one,temp\n1,1,50\n2,1,{cell}\n"), dryer())
    assert np.isnan(data.y[1, 0]) if value is None else data.y[1, 0] == value


@pytest.mark.parametrize("cell", ["inf", "-inf", "Infinity", "iNfInItY", "1e309"])
def test_infinite_cells_stay_refused(tmp_path, cell):
    path = written(tmp_path, f"time,one,temp\n1,1,{cell}\n")
    with pytest.raises(DataError, match=rf"d.csv:2: column 'temp': '{cell}' is not a finite number$"):
        read_csv(path, dryer())
