"""The command line as a whole: no command at all."""

import subprocess
from pathlib import Path

from conftest import jmlgdsl_command

from jmlgdsl.cli import ORDER, main

ROOT = Path(__file__).resolve().parents[1]


def test_no_command_prints_every_command_and_exits_2(capsys):
    assert main([]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    lines = captured.err.splitlines()
    for name in ORDER:  # each command on a line of its own, with what it does
        assert any(line.split()[:1] == [name] and len(line.split()) > 1 for line in lines), name
    assert "Run 'jmlgdsl COMMAND --help' for the options of one command." in captured.err


def test_no_command_from_the_shell():
    done = subprocess.run(jmlgdsl_command(), cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and "simulate a plant and write its data as CSV" in done.stderr
