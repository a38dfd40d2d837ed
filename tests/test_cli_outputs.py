"""run, learn and prbs check their outputs and numbers before any work (issue 14, items 12, 15-17)."""

import os
import stat
import subprocess
import threading
from pathlib import Path

import pytest
from conftest import dryer_files, jmlgdsl_command

from jmlgdsl.cli import main
from jmlgdsl.data import write_columns


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    return dryer_files(tmp_path_factory.mktemp("outputs"), "1-20:normal,21-40:fan", 1)


def refused(argv, capsys, message):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err


def test_run_refuses_to_write_over_its_data(files, capsys):
    spec, data = files
    before = data.read_bytes()
    refused(["run", str(spec), str(data), "-o", str(data)], capsys, "")
    assert data.read_bytes() == before


@pytest.mark.parametrize("plot, message", [("fig.txt", "--plot"), ("missing/fig.png", "missing")])
def test_run_checks_the_figure_path_before_filtering(files, capsys, tmp_path, plot, message):
    spec, data = files
    refused(["run", str(spec), str(data), "--plot", str(tmp_path / plot)], capsys, message)


def test_run_refuses_zero_particles(files, capsys):
    spec, data = files
    refused(["run", str(spec), str(data), "--filter", "la-rbpf", "--particles", "0"], capsys, "--particles")


def test_learn_checks_its_output_and_sample_time(files, capsys, tmp_path):
    _, data = files
    refused(["learn", "--mode", f"normal={data}", "--output", "temp", "--dt", "1", "-o", str(data)], capsys, "")
    with pytest.raises(SystemExit):
        main(["learn", "--mode", f"normal={data}", "--output", "temp", "--dt", "inf", "-o", str(tmp_path / "s.jmlg")])
    assert capsys.readouterr().err.endswith("error: argument --dt: expected a finite number, not 'inf'\n")
    assert not (tmp_path / "s.jmlg").exists()


@pytest.mark.parametrize("extra, message", [
    (["--amplitude", "nan"], "argument --amplitude: expected a finite number, not 'nan'"),
    (["--around", "inf"], "argument --around: expected a finite number, not 'inf'"),
    (["--dt", "inf"], "argument --dt: expected a finite number, not 'inf'"),
    (["--dt", "0"], "argument --dt: must be positive, not 0"),
    (["--settling", "-5"], "argument --settling: must be positive, not -5"),
])
def test_prbs_refuses_unusable_numbers_as_it_reads_them(capsys, tmp_path, extra, message):
    with pytest.raises(SystemExit) as done:
        main(["prbs", "--cells", "5", "-o", str(tmp_path / "u.csv"), *extra])
    assert done.value.code == 2 and capsys.readouterr().err.endswith(f"error: {message}\n")
    assert not (tmp_path / "u.csv").exists()


def test_prbs_refuses_a_sequence_too_long_to_write(capsys, tmp_path):
    refused(["prbs", "--cells", "20", "--periods", "1000", "-o", str(tmp_path / "u.csv")], capsys, "GiB")


def test_run_warns_about_an_output_in_another_unit(files, capsys, tmp_path):
    import csv

    spec, data = files
    rows = list(csv.DictReader(data.open()))
    scaled = tmp_path / "centi.csv"
    write_columns(scaled, {"temp": [100 * float(r["temp"]) for r in rows]})  # degC written as centi-degC
    assert main(["run", str(spec), str(scaled)]) == 0
    err = capsys.readouterr().err
    assert "warning: output 'temp': its residuals are about" in err and "times the model's noise" in err
    assert main(["run", str(spec), str(data)]) == 0
    assert "residuals are about" not in capsys.readouterr().err  # data in the spec's unit: no warning


def test_simulate_says_what_it_wrote_as_compile_does(files, capsys, tmp_path):
    spec, _ = files
    out = tmp_path / "sim.csv"
    assert main(["simulate", str(spec), "--steps", "7", "--seed", "1", "-o", str(out)]) == 0
    assert capsys.readouterr().out == f"wrote {out} (7 rows, 4 modes)\n"
    assert main(["compile", str(spec), "-o", str(tmp_path / "m.npz")]) == 0
    assert capsys.readouterr().out.startswith(f"wrote {tmp_path / 'm.npz'} (4 modes")
    assert main(["simulate", str(spec), "--steps", "7", "--seed", "1"]) == 0
    assert capsys.readouterr().out.startswith("time,")  # to standard output: the data alone


@pytest.fixture(scope="module")
def tables(files, tmp_path_factory):
    """The argument lists of `run` and of `export` of a monitor's store of the same rows, and the table
    both write."""
    spec, data = files
    folder = tmp_path_factory.mktemp("tables")
    store = str(folder / "plant.db")
    assert main(["monitor", str(spec), "--source", str(data), "--store", store, "--no-follow"]) == 0
    assert main(["run", str(spec), str(data), "-o", str(folder / "expected.csv")]) == 0
    expected = (folder / "expected.csv").read_text()
    assert expected.count("\n") == 41
    return {"run": ["run", str(spec), str(data)], "export": ["export", store]}, expected


@pytest.mark.parametrize("command", ["run", "export"])
def test_an_output_through_a_link_writes_the_file_it_names(tables, tmp_path, command):
    argv, expected = tables
    target, link = tmp_path / "real.csv", tmp_path / "link.csv"
    target.write_text("old\n")
    link.symlink_to(target.name)  # relative, as `ln -s real.csv link.csv` makes it
    assert main([*argv[command], "-o", str(link)]) == 0
    assert link.is_symlink() and os.readlink(link) == "real.csv" and target.read_text() == expected
    assert sorted(os.listdir(tmp_path)) == ["link.csv", "real.csv"]


@pytest.mark.parametrize("command", ["run", "export"])
def test_an_output_onto_a_pipe_streams_into_it(tables, tmp_path, command):
    argv, expected = tables
    fifo = tmp_path / "pipe.csv"
    os.mkfifo(fifo)
    received = []
    reader = threading.Thread(target=lambda: received.append(fifo.read_text()), daemon=True)  # as `cat pipe`
    reader.start()
    assert main([*argv[command], "-o", str(fifo)]) == 0
    reader.join(10)
    assert stat.S_ISFIFO(os.stat(fifo).st_mode) and received == [expected]


@pytest.mark.parametrize("command", ["run", "export"])
def test_an_output_onto_a_device_leaves_the_device(tables, tmp_path, command):
    """A character device receives the table and stays a device. A superuser's test makes its own
    null device (the system's one, replaced by a file, would be every process's loss); others write
    /dev/null, whose folder they cannot write in."""
    argv, _ = tables
    device = Path("/dev/null")
    if os.geteuid() == 0:
        device = tmp_path / "null"
        os.mknod(device, stat.S_IFCHR | 0o666, os.makedev(1, 3))
    before = os.stat(device)
    assert main([*argv[command], "-o", str(device)]) == 0
    after = os.stat(device)
    assert stat.S_ISCHR(after.st_mode) and (after.st_ino, after.st_rdev) == (before.st_ino, before.st_rdev)


def test_an_output_onto_a_descriptor_link_is_written_there(tables, tmp_path):
    """A link to an open descriptor, as /dev/stdout is (made here in the test's folder, so that no
    version of the command can replace the system's): the file behind it receives the table after
    what it holds, never replaced."""
    argv, expected = tables
    out, link = tmp_path / "out.csv", tmp_path / "stdout"
    link.symlink_to("/proc/self/fd/1")
    out.write_text("old\n")
    with open(out, "a") as stream:  # `>> out.csv`: the old line stays, the table follows it
        done = subprocess.run([*jmlgdsl_command(), *argv["export"], "-o", str(link)], stdout=stream,
                              stderr=subprocess.PIPE, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert out.read_text() == "old\n" + expected and link.is_symlink()


def test_an_output_onto_a_socket_is_refused_by_name(tables, tmp_path, capsys):
    import socket

    argv, _ = tables
    path = tmp_path / "s.csv"
    with socket.socket(socket.AF_UNIX) as server:
        server.bind(str(path))
        refused([*argv["export"], "-o", str(path)], capsys, "it is a socket")
