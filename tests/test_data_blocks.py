"""A data file's lines read a block at a time in one pass (RowParser.numbers), the `mode` and 0/1 label
columns of simulated and labelled files too: every row, error and warning as the line reader gives it."""

import io
import warnings

import numpy as np
import pytest

import jmlgdsl
from jmlgdsl.data import Columns, DataWarning, RowParser, iter_rows, open_source, read_data
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


def whole(path, model):
    """A file read whole into arrays (read_data: its plain blocks taken as they are), its error and warnings."""
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always", DataWarning)
        with open_source(path) as source:
            try:
                data, error = read_data(source, model, str(path)), None
            except DataError as exc:
                data, error = None, str(exc)
    return data, error, [str(w.message) for w in said]


def arrays(data):
    return [None if v is None else np.asarray(v) for v in (data.time, data.y, data.u, data.modes, data.anomaly,
                                                           data.changepoint)]


@pytest.mark.parametrize("bad", [
    {}, {1500: "1500,15,50.5,fann,50.5,1,0\n"}, {40: "40,15,hot,normal,50.5,0,0\n"},
    {2300: "2300,,50.5,normal,50.5,0,0\n"},  # an input without a value, and the dryer's current has no default
    {700: "699.5,15,50.5,normal,50.5,0,0\n"}, {701: "701.5,15,50.5,normal,50.5,0,0\n"},  # off the sample time
    {900: "900,15,50.5,normal,50.5,0,0\n" * 2}, {1900: "1,15,50.5,normal,50.5,0,0\n"},  # a repeat; backwards
    {10: ",15,50.5,normal,50.5,0,0\n"},  # no time
])
@pytest.mark.parametrize("dt", [1.0, None])  # None: no sample time, the times only kept in order
def test_a_file_read_whole_into_arrays_is_its_rows_with_their_errors_and_warnings(tmp_path, bad, dt):
    """read_data takes the blocks of plain lines that need no word whole (no Row a line): the arrays,
    error and warnings are those of the line reader's rows, whatever stops or warns among them."""
    dryer = jmlgdsl.load(SPEC)
    model = Columns(dryer.outputs, dryer.inputs, np.array([np.nan]), dryer.modes, dt)  # current: no default
    path = tmp_path / "u.csv"
    path.write_text(HEADER + "".join(lines(3000, bad=bad)) + "# the end\n" + "".join(lines(500, 3001)))
    data, error, said = whole(path, model)
    (rows, expected, expected_said), _ = read(path, model)
    assert error == expected and said == expected_said
    if rows is not None:
        labels = [[getattr(r, name) for r in rows] for name in ("time", "mode", "anomaly", "changepoint")]
        assert len(data.y) == len(rows) == 3500 + (900 in bad)
        for got, want in zip(arrays(data), [np.array(labels[0]), np.array([r.y for r in rows]),
                                            np.array([r.u for r in rows]),
                                            np.array([-1 if m is None else m for m in labels[1]]),
                                            np.array(labels[2]), np.array(labels[3])]):
            np.testing.assert_array_equal(got, want)


def test_a_file_without_times_or_labels_reads_whole_into_arrays(tmp_path):
    model = jmlgdsl.load(SPEC)
    path = tmp_path / "u.csv"
    path.write_text("current,temp\n" + "".join(f"{15 + t % 2},{50 + 0.01 * t}\n" for t in range(2000)))
    data, error, said = whole(path, model)
    assert error is None and not said and data.time is data.modes is data.anomaly is None
    np.testing.assert_array_equal(data.y[:, 0], [50 + 0.01 * t for t in range(2000)])
    np.testing.assert_array_equal(data.u[:, 0], [15 + t % 2 for t in range(2000)])


def test_plain_blocks_are_read_whole_not_a_row_a_line(tmp_path, monkeypatch):
    model = jmlgdsl.load(SPEC)
    path = tmp_path / "u.csv"
    path.write_text(HEADER + "".join(lines(3000)))
    monkeypatch.setattr(RowParser, "numbered", lambda *args: pytest.fail("a plain line made a Row"))
    data, error, said = whole(path, model)
    assert error is None and not said and len(data.y) == 3000 and data.modes[-1] == 1
