"""A data file's lines read a block at a time in one pass (RowParser.numbers), the `mode` and 0/1 label
columns of simulated and labelled files too: every row, error and warning as the line reader gives it."""

import io
import warnings

import numpy as np
import pytest

import jmlgdsl
from jmlgdsl.data import DataWarning, RowParser, iter_rows, open_source
from jmlgdsl.errors import DataError

SPEC = "specs/dryer.jmlg"
HEADER = "time,current,temp,mode,temp_true,anomaly,changepoint\n"


def lines(n, start=1, bad=None):
    """Lines of a labelled dryer file (a missing reading every 7th, an unlabelled mode every 11th)."""
    bad = bad or {}
    return [bad.get(t, f"{t},{15 + t % 3},{'' if t % 7 == 0 else 50.5 + 0.001 * t},"
                       f"{'' if t % 11 == 0 else ('normal', 'fan')[t // 400 % 2]},50.5,{int(t > 700)},{int(t == 701)}\n")
            for t in range(start, start + n)]


def same(a, b):
    return (a.line, a.time, a.mode, a.anomaly, a.changepoint) == (b.line, b.time, b.mode, b.anomaly, b.changepoint) \
        and np.array_equal(a.y, b.y, equal_nan=True) and np.array_equal(a.u, b.u)


def read(path, model):
    """The rows and warnings of a file, read as a data file (in blocks) and as a stream of its lines."""
    got = []
    for stream in (lambda: open_source(path), lambda: io.StringIO(path.read_text(), newline="")):
        with warnings.catch_warnings(record=True) as said:
            warnings.simplefilter("always", DataWarning)
            with stream() as source:
                try:
                    got.append((list(iter_rows(source, model, str(path))), None))
                except DataError as exc:
                    got.append((None, str(exc)))
        got[-1] += ([str(w.message) for w in said],)
    return got


def test_lines_with_mode_and_label_columns_are_read_in_one_pass_as_the_line_reader_reads_them():
    model = jmlgdsl.load(SPEC)
    text = "".join(lines(900))
    parser, by_line = (RowParser(HEADER.strip().split(","), model, "u.csv") for _ in range(2))
    numbers = parser.numbers(text, ",")
    assert numbers is not None
    rows = [parser.numbered(2 + i, numbers, i) for i in range(900)]
    expected = [by_line.row(2 + i, line.strip().split(",")) for i, line in enumerate(text.splitlines())]
    assert all(same(a, b) for a, b in zip(rows, expected)) and len(rows) == 900
    assert [r.mode for r in rows[398:402]] == [0, 1, 1, 1] and rows[10].mode is None  # line 12: t = 11
    assert (rows[699].anomaly, rows[700].anomaly, rows[700].changepoint, rows[701].changepoint) == (0, 1, 1, 0)


def test_a_data_files_plain_lines_are_not_split_line_by_line(tmp_path, monkeypatch):
    model = jmlgdsl.load(SPEC)
    path = tmp_path / "u.csv"
    path.write_text(HEADER + "".join(lines(3000)))

    def split(*args):
        raise AssertionError("a plain line read on its own")

    monkeypatch.setattr(RowParser, "row", split)
    with open_source(path) as source:
        rows = list(iter_rows(source, model, str(path)))
    assert len(rows) == 3000 and rows[-1].line == 3001 and rows[-1].mode == 1


@pytest.mark.parametrize("bad, message", [
    ({1500: "1500,15,50.5,fann,50.5,1,0\n"}, "u.csv:1501: column 'mode': unknown mode 'fann'"),
    ({2500: "2500,15,50.5,normal,50.5,2,0\n"}, "u.csv:2501: column 'anomaly': '2' is not a 0/1 label"),
    ({40: "40,15,hot,normal,50.5,0,0\n"}, "u.csv:41: column 'temp': 'hot' is not a number"),
    ({3: "3,15,1e999,normal,50.5,0,0\n"}, "u.csv:4: column 'temp': '1e999' is not a finite number"),
    ({1800: "1800,15,50.5,normal,50.5,0\n"}, "u.csv:1801: 6 cells, but the header has 7 columns"),
])
def test_a_bad_line_among_labelled_lines_is_the_error_the_line_reader_gives(tmp_path, bad, message):
    model = jmlgdsl.load(SPEC)
    path = tmp_path / "u.csv"
    path.write_text(HEADER + "".join(lines(3000, bad=bad)))
    (blocks, error, _), (by_line, expected, _) = read(path, model)
    assert blocks is by_line is None and error == expected and error.startswith(f"{path.parent}/{message}")


def test_a_file_of_every_kind_of_line_reads_as_its_stream_of_lines_does(tmp_path):
    """Blocks of plain lines and others over several reads: comments, blank lines, CR LF and CR line
    ends, a mode name with spaces, a time that repeats and one that jumps, a last line without its end."""
    model = jmlgdsl.load(SPEC)
    text = ("# logger 7\r\n" + HEADER.replace("\n", "\r\n") + "".join(line.replace("\n", "\r\n") for line in lines(2000))
            + "\n# restarted\n" + "".join(lines(2000, 2001, {2100: "2100,15,50.5, fan ,50.5,1,0\n"}))
            + "".join(lines(10, 4001)).replace("\n", "\r") + "".join(lines(1000, 4010))
            + "".join(lines(5000, 5020)) + "10020,15,50.5,normal,50.5,1,0")
    path = tmp_path / "u.csv"
    path.write_text(text, newline="")
    (blocks, error, said), (by_line, expected, expected_said) = read(path, model)
    assert error is expected is None and said == expected_said and len(said) == 2  # the repeat and the jump
    assert len(blocks) == len(by_line) == 10011 and all(same(a, b) for a, b in zip(blocks, by_line))
    assert blocks[-1].line == 10015 and (blocks[2099].time, blocks[2099].mode) == (2100, 1)
