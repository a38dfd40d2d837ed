"""`jmlgdsl simulate --nonlinear` integrates the ODEs with the linear simulation's modes and noise."""

import csv
import pathlib

import numpy as np

from jmlgdsl.cli import main

CSTR = str(pathlib.Path(__file__).resolve().parents[1] / "specs" / "cstr4.jmlg")
DRYER = str(pathlib.Path(__file__).resolve().parents[1] / "specs" / "dryer.jmlg")


def read(path):
    """The rows of a CSV file as dictionaries keyed by column."""
    with open(path) as fh:
        return list(csv.DictReader(fh))


def test_nonlinear_and_linear_runs_share_columns_and_modes_but_not_values(tmp_path):
    args = ["simulate", CSTR, "--modes", "1-20:normal,21-40:fouling3", "--seed", "4"]
    assert main(args + ["--nonlinear", "-o", str(tmp_path / "nl.csv")]) == 0
    assert main(args + ["-o", str(tmp_path / "lin.csv")]) == 0
    nl, lin = read(tmp_path / "nl.csv"), read(tmp_path / "lin.csv")
    assert list(nl[0]) == list(lin[0])
    assert [r["mode"] for r in nl] == [r["mode"] for r in lin]
    diff = np.array([[float(a[c]) - float(b[c]) for c in ("CA", "Tr", "Tjo")] for a, b in zip(nl, lin)])
    # The linearisation is good near the operating point: the two plants stay close, yet are not equal.
    assert 0 < np.abs(diff).max() < 0.5


def test_nonlinear_simulation_of_a_linear_spec_is_a_clear_error(capsys):
    assert main(["simulate", DRYER, "--nonlinear", "--steps", "3"]) == 2
    err = capsys.readouterr().err
    assert "needs a nonlinear plant" in err and "Traceback" not in err
