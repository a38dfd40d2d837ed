"""The command line as a whole: no command at all, counts in messages, and the SKAB script's data folder."""

import importlib.util
import subprocess
from pathlib import Path

import pytest
from conftest import jmlgdsl_command

from jmlgdsl.cli import ORDER, main

ROOT = Path(__file__).resolve().parents[1]
ONE_MODE = """plant one
sample 1 s
input  current [%] = 15
output temp [degC]
modes
  normal "Normal operation"
noise process 0.05, measurement 0.05
mode normal: temp ~ fopdt(current, gain 1.94, tau 30.45 s, delay 0 s, at current 15 -> 50.52)
"""


def test_no_command_prints_every_command_and_exits_2(capsys):
    assert main([]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    lines = captured.err.splitlines()
    for name in ORDER:  # each command on a line of its own, with what it does beside it or just below
        at = next(i for i, line in enumerate(lines) if line.split()[:1] == [name])
        assert len(lines[at].split()) > 1 or lines[at + 1].startswith(" " * 10), name
    assert "Run 'jmlgdsl COMMAND --help' for the options of one command." in captured.err


def test_no_command_from_the_shell():
    done = subprocess.run(jmlgdsl_command(), cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and "simulate a plant and write its data as CSV" in done.stderr


def test_counts_of_one_are_singular(tmp_path, capsys):
    spec = tmp_path / "one.jmlg"
    spec.write_text(ONE_MODE)
    assert main(["check", str(spec)]) == 0
    assert "plant one: 1 mode (normal)" in capsys.readouterr().out
    assert main(["compile", str(spec), "-o", str(tmp_path / "one.json")]) == 0
    assert "(1 mode, nx=1" in capsys.readouterr().out
    data = tmp_path / "one.csv"
    assert main(["simulate", str(spec), "--steps", "1", "-o", str(data)]) == 0
    assert main(["simulate", str(spec), "--modes", "1-2:normal", "--inputs", str(data)]) == 2
    assert f"{data} has 1 row, fewer than the 2 steps of --modes" in capsys.readouterr().err


@pytest.fixture(scope="module")
def skab():
    """benchmarks/skab/run.py as a module."""
    spec = importlib.util.spec_from_file_location("skab_run", ROOT / "benchmarks" / "skab" / "run.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_skab_benchmark_needs_its_data_folder_named(skab, tmp_path, capsys):
    """No folder found by guessing: without --data, or with a folder that is not SKAB's, a usage error."""
    with pytest.raises(SystemExit) as stop:
        skab.main(["--out", str(tmp_path)])
    assert stop.value.code == 2 and "the following arguments are required: --data" in capsys.readouterr().err
    with pytest.raises(SystemExit) as stop:
        skab.main(["--data", str(tmp_path), "--out", str(tmp_path)])
    assert stop.value.code == 2
    assert f"--data {tmp_path}: no valve1/, valve2/, other/ folder" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        skab.main(["--help"])
    assert "--data DIR" in capsys.readouterr().out
