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
        read_csv(path, model or dryer())
    return [str(w.message) for w in caught if issubclass(w.category, DataWarning)]


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
