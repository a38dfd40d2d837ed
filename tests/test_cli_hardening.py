"""The command line against careless use (issue 14, items 12-18): no output ever costs data, bad
data and bad options get one clear located message and exit 2 before any work starts, and data
that read but look wrong are warned about by column."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import dryer_files, jmlgdsl_command
from infer_models import dryer

from jmlgdsl import output
from jmlgdsl.cli import main
from jmlgdsl.data import Columns, DataWarning, iter_rows, read_csv, write_columns
from jmlgdsl.errors import DataError, JmlgError
from jmlgdsl.diagnosis.prefilter import parse

ROOT = Path(__file__).resolve().parents[1]
SPEC = ROOT / "specs" / "dryer.jmlg"


@pytest.fixture()
def files(tmp_path):
    """A dryer model file, ten simulated rows and a run's result table, in a fresh folder."""
    spec, data = dryer_files(tmp_path, "1-5:normal,6-10:fan", 1, "d.csv")
    result = tmp_path / "result.csv"
    assert main(["run", str(spec), str(data), "-o", str(result)]) == 0
    return spec, data, result


def fails(capsys, argv, message):
    """The command exits 2 with one `error:` line containing `message`, and no traceback."""
    assert main([str(a) for a in argv]) == 2
    err = capsys.readouterr().err
    assert message in err and err.startswith("error: ") and "Traceback" not in err, err
    return err


# item 12: no data loss

def test_an_output_replaces_its_target_only_when_complete(tmp_path):
    target = tmp_path / "table.csv"
    target.write_text("old\n")
    with pytest.raises(RuntimeError), output.replacing(target) as temporary:
        temporary.write_text("half")
        raise RuntimeError("interrupted")
    assert target.read_text() == "old\n" and os.listdir(tmp_path) == ["table.csv"]
    with output.replacing(target) as temporary:
        assert temporary.parent == tmp_path and temporary.suffix == ".csv"
        temporary.write_text("new\n")
    assert target.read_text() == "new\n" and os.listdir(tmp_path) == ["table.csv"]


def test_an_interrupted_table_leaves_the_old_file(tmp_path):
    target = tmp_path / "sim.csv"
    target.write_text("time\n1\n")

    def rows():
        yield 1.0
        raise RuntimeError("interrupted")

    with pytest.raises(RuntimeError):
        write_columns(target, {"time": rows()})
    assert target.read_text() == "time\n1\n" and os.listdir(tmp_path) == ["sim.csv"]


def test_a_table_whose_writing_fails_is_not_written(tmp_path):
    target = tmp_path / "t.csv"
    with pytest.raises(RuntimeError), output.writing(target) as stream:
        stream.write("half")
        raise RuntimeError("interrupted")
    assert os.listdir(tmp_path) == []


def test_written_files_get_ordinary_permissions(tmp_path):
    new, kept = tmp_path / "new.csv", tmp_path / "kept.csv"
    kept.write_text("x\n")
    kept.chmod(0o640)
    write_columns(new, {"a": [1]})
    write_columns(kept, {"a": [1]})
    umask = os.umask(0)
    os.umask(umask)
    assert new.stat().st_mode & 0o777 == 0o666 & ~umask and kept.stat().st_mode & 0o777 == 0o640


def test_run_does_not_write_over_its_own_data(files, capsys):
    spec, data, _ = files
    before = data.read_bytes()
    fails(capsys, ["run", spec, data, "-o", data], "is also an input")
    assert data.read_bytes() == before


@pytest.mark.parametrize("command", [
    lambda spec, data: ["simulate", spec, "--steps", "3", "-o", spec],
    lambda spec, data: ["simulate", spec, "--inputs", data, "-o", data],
    lambda spec, data: ["compile", spec, "-o", spec],
    lambda spec, data: ["bench", spec, spec.parent / "runs.csv", "-o", spec.parent],
])
def test_outputs_that_are_inputs_are_refused(files, capsys, command):
    spec, data, _ = files
    (spec.parent / "runs.csv").write_bytes(data.read_bytes())
    kept = {p: p.read_bytes() for p in spec.parent.iterdir()}
    fails(capsys, command(spec, data), "is also an input")
    assert {p: p.read_bytes() for p in spec.parent.iterdir()} == kept


# item 13: data that are not UTF-8 text, over-long cells, a closed standard input

@pytest.mark.parametrize("content, message", [
    ("time,temp\n1,50\n2,5\xb00\n".encode("latin-1"), "d.csv:3:4: byte 0xb0 is not UTF-8 text"),
    ("time,temp\n1,50\n".encode("utf-16"), "d.csv:1: the file is UTF-16 text"),
    (b"\x89PNG\r\n\x1a\n", "d.csv:1:1: byte 0x89 is not UTF-8 text"),
    (b"time,temp\n\x00\x01\x02\x03\n", "d.csv:2: binary data"),
    (b"time,temp\n1," + b"5" * 200_000 + b"\n", "d.csv:2: a cell longer than 131,072 characters"),
], ids=["latin-1", "utf-16", "png", "binary", "long cell"])
def test_undecodable_or_oversized_data_is_located(files, capsys, content, message):
    spec, data, _ = files
    data.write_bytes(content)
    with pytest.raises(DataError, match=message):
        read_csv(data, dryer())
    fails(capsys, ["run", spec, data], message)


def test_plot_reads_only_text_result_tables(files, capsys):
    _, _, result = files
    lines = result.read_bytes().splitlines(keepends=True)
    result.write_bytes(b"".join(lines[:3]) + b"\xe9" + b"".join(lines[3:]))
    fails(capsys, ["plot", result, "-o", result.with_suffix(".png")], "result.csv:4:1: byte 0xe9 is not UTF-8")
    result.write_bytes(b"".join(lines[:3]) + b"x" * 200_000 + b"\n")
    fails(capsys, ["plot", result, "-o", result.with_suffix(".png")], "result.csv: not a result table")
    assert not result.with_suffix(".png").exists()


def test_a_closed_standard_input_is_a_clear_error(files, capsys, monkeypatch):
    spec, _, _ = files
    monkeypatch.setattr(sys, "stdin", None)
    fails(capsys, ["run", spec, "-"], "<stdin>: standard input is closed")
    command = " ".join(f'"{part}"' for part in jmlgdsl_command())
    done = subprocess.run(f'{command} run "{spec}" - <&-', shell=True, cwd=ROOT,
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and done.stderr == "error: <stdin>: standard input is closed\n"


# item 15: values out of range are refused, saying what they would cost

def test_an_enormous_moving_average_is_a_located_error(files, capsys):
    with pytest.raises(DataError, match=r"pre-filter 'ma:99999999999999999999': the window is at most 10,000"):
        parse("ma:99999999999999999999")
    spec, data, _ = files
    fails(capsys, ["bench", spec, data, "--prefilter", "ma:99999999999999999999", "-o", spec.parent / "b"],
          "the window is at most 10,000 readings")


def test_requests_too_large_for_memory_say_what_they_need(files, capsys, monkeypatch):
    monkeypatch.setattr(output, "physical_memory", lambda: 16 << 30)
    spec, data, _ = files
    fails(capsys, ["simulate", spec, "--steps", "1000000000"],
          "--steps 1,000,000,000 would need about 119.2 GiB of memory; this machine has 16.0 GiB")
    fails(capsys, ["simulate", spec, "--modes", "1-5:normal,6-99999999999:fan"], "--modes 99,999,999,999 would need")
    fails(capsys, ["bench", spec, data, "--particles", "1000000000", "-o", spec.parent / "b"],
          "particle count 1,000,000,000 would need about")
    fails(capsys, ["bench", spec, data, "--runs", "1000000000", "-o", spec.parent / "b"], "--runs 1,000,000,000 would need")


# item 16: output paths and formats are checked before the work starts

@pytest.mark.parametrize("command, message", [
    (lambda d: ["plot", d / "missing.csv", "-o", d / "p.txt"], "the file name must end in .png, .pdf, .svg, .eps, .ps"),
    (lambda d: ["compile", SPEC, "-o", d / "model.txt"], "the file name must end in .json, .npz, .mat"),
    (lambda d: ["plot", d / "missing.csv", "-o", d / "no" / "p.png"], "No such file or directory (no folder"),
    (lambda d: ["simulate", d / "missing.jmlg", "-o", d / "no" / "s.csv"], "No such file or directory (no folder"),
    (lambda d: ["compile", SPEC, "-o", d / "dryer.json" / "m.json"], "Not a directory"),
    (lambda d: ["bench", d / "missing.jmlg", "--simulate", "5", "-o", d / "dryer.json"], "is a file, not a folder"),
    (lambda d: ["bench", d / "missing.jmlg", "--simulate", "5", "-o", d / "dryer.json" / "b"], "Not a directory"),
])
def test_bad_outputs_are_refused_before_any_work(files, capsys, command, message):
    fails(capsys, command(files[0].parent), message)


def test_a_folder_that_cannot_be_written_is_refused(files, capsys, monkeypatch):
    monkeypatch.setattr(output.os, "access", lambda path, mode: False)
    spec, data, _ = files
    for argv in (["simulate", spec, "--steps", "3", "-o", spec.parent / "s.csv"],
                 ["bench", spec, data, "-o", spec.parent / "b"],
                 ["plot", spec.parent / "result.csv", "-o", spec.parent / "p.png"]):
        fails(capsys, argv, "Permission denied (folder")


NO_FILES = Path("/proc")  # a folder that takes no new files, whatever its permissions say to a superuser


@pytest.mark.skipif(not (NO_FILES / "self").is_dir(), reason="needs the /proc of Linux")
@pytest.mark.parametrize("command", [
    lambda d: ["bench", d / "missing.jmlg", "--simulate", "30", "--filters", "imm", "--runs", "1", "--workers", "1",
               "--no-figures", "-o", NO_FILES / "forbidden"],
    lambda d: ["learn", "--mode", f"normal={d / 'missing.csv'}", "--output", "temp", "-o", d / "l.jmlg",
               "--figures", NO_FILES / "nofigs"],
    lambda d: ["learn", "--mode", f"normal={d / 'missing.csv'}", "--output", "temp", "-o", NO_FILES / "l.jmlg"],
    lambda d: ["simulate", d / "missing.jmlg", "--steps", "3", "-o", NO_FILES / "s.csv"],
    lambda d: ["compile", d / "missing.jmlg", "-o", NO_FILES / "m.json"],
    lambda d: ["fit", d / "missing.jmlg", d / "missing.csv", "-o", NO_FILES / "f.jmlg"],
    lambda d: ["prbs", "--cells", "3", "-o", NO_FILES / "u.csv"],
    lambda d: ["plot", d / "missing.csv", "-o", NO_FILES / "p.png"],
    lambda d: ["run", d / "missing.jmlg", d / "missing.csv", "-o", NO_FILES / "r.csv"],
])
def test_a_folder_that_takes_no_files_is_refused_before_any_work(tmp_path, capsys, command):
    """Every command that writes tries its output folder before it starts: the inputs here do not
    exist, so a command that began its work would fail on them (or, for prbs, on the write) instead."""
    err = fails(capsys, command(tmp_path), "takes no new files")
    assert err.count("\n") == 1 and "missing" not in err, err


def test_a_table_that_cannot_be_made_is_one_error(tmp_path, monkeypatch):
    """A pending table whose temporary file cannot be made raises a user error and nothing else
    (no 'Exception ignored' report from the half-made object as it goes)."""
    ignored = []
    monkeypatch.setattr(sys, "unraisablehook", ignored.append)
    try:
        with output.writing(tmp_path / "no" / "t.csv"):
            pass
    except JmlgError as exc:
        assert "cannot write" in str(exc)
    else:
        raise AssertionError("no error")
    assert ignored == []


# item 17: files of the wrong kind are named as such

def test_simulate_inputs_must_be_a_csv_with_the_right_rows(files, capsys):
    spec, data, _ = files
    fails(capsys, ["simulate", spec, "--inputs", SPEC], "--inputs " + str(SPEC) + ": a spec or model file, not a CSV")
    fails(capsys, ["simulate", spec, "--inputs", data, "--modes", "1-4:normal"],
          f"{data} has 10 rows, more than the 4 steps of --modes")
    assert main(["simulate", str(spec), "--inputs", str(data), "--steps", "4"]) == 0
    assert f"warning: {data}: 10 rows; --steps 4 uses the first 4 rows" in capsys.readouterr().err


def test_a_mat_model_cannot_be_read_back(files, capsys):
    mat = files[0].with_suffix(".mat")
    assert main(["compile", str(SPEC), "-o", str(mat)]) == 0
    capsys.readouterr()
    fails(capsys, ["run", mat, files[1]], ".mat cannot be read back; use .json or .npz")
    assert main(["check", str(mat)]) == 2
    assert ".mat cannot be read back; use .json or .npz" in capsys.readouterr().err


# item 18: data that read but look wrong

def rows(text, model=None):
    from io import StringIO

    return list(iter_rows(StringIO(text), model or dryer(), "d.csv"))


@pytest.mark.parametrize("text, message", [
    ("temp\n50\n51\n", "d.csv: no column 'one': input one took its default 1 throughout"),
    ("time,one,temp\n1,1,50\n1,1,51\n", "d.csv:3: column 'time' repeats 1"),
    ("time,one,temp\n0,1,50\n60,1,51\n", "d.csv:3: column 'time' steps by 60 s but the model's sample time is 1 s"),
    ("time,one,temp\n1,1,\n2,1,NA\n", "d.csv: column 'temp' has no values: output temp was never measured"),
])
def test_suspect_data_are_warned_about_by_column(text, message):
    with pytest.warns(DataWarning, match=message.replace("(", r"\(").replace(")", r"\)")):
        assert len(rows(text)) >= 1


def test_clean_data_raise_no_warning(recwarn):
    rows("time,one,temp,mode\n1,1,50,normal\n2,1,51,fan\n")
    assert not [w for w in recwarn if issubclass(w.category, DataWarning)]


def test_the_command_line_shows_data_warnings(files, capsys):
    spec, data, _ = files
    data.write_text("time,temp\n1,50\n2,51\n")
    assert main(["run", str(spec), str(data)]) == 0
    assert "warning: " + str(data) + ": no column 'one'" in capsys.readouterr().err


@pytest.mark.parametrize("text, message", [
    ("time,one,temp,mode\n1,1,50\n", "d.csv:2: 3 cells, but the header has 4 columns"),
    ("time,one,temp\n1,1,50,5\n", "d.csv:2: 4 cells, but the header has 3 columns; decimal commas (1,5)"),
    ("time;one;temp\n1;1;50,5\n", "d.csv:2: column 'temp': '50,5' is not a number; write decimal points"),
    ("time,one,temp\n1,1,50\n2,1,51\n1,1,52\n", "d.csv:4: column 'time' goes backwards (2 then 1); the rows must be in time order"),
])
def test_ragged_rows_and_decimal_commas_are_named(text, message):
    with pytest.raises(DataError) as err:
        rows(text)
    assert str(err.value).startswith(message)


def test_trailing_empty_cells_are_not_ragged():
    assert rows("one,temp\n1,50,\n")[0].y[0] == 50.0


def test_a_blank_mode_cell_is_a_missing_label(files, capsys, tmp_path):
    got = rows("one,temp,mode\n1,50,\n1,51,fan\n")
    assert [r.mode for r in got] == [None, 1]
    path = tmp_path / "labels.csv"
    path.write_text("one,temp,mode\n1,50,\n1,51,fan\n1,52,\n")
    np.testing.assert_array_equal(read_csv(path, dryer()).modes, [-1, 1, -1])
    assert read_csv(path, Columns(outputs=("temp",), modes=("fan",))).modes.tolist() == [-1, 0, -1]
    spec = files[0]
    assert main(["run", str(spec), str(path)]) == 0
    assert " of 1 step)" in capsys.readouterr().out
    fails(capsys, ["bench", spec, path, "-o", tmp_path / "b"], "data row 1 has no true mode")


def test_output_checks_pass_standard_output_through(monkeypatch):
    output.check_file("-")
    monkeypatch.setattr(sys, "stdout", None)
    with pytest.raises(JmlgError, match="standard output is closed"):
        output.check_file("-")
