"""PRBS: maximal length for every register size, clocking, levels, the settling-time warning, CLI."""

import csv

import numpy as np
import pytest

from jmlgdsl.cli import main
from jmlgdsl.errors import JmlgError
from jmlgdsl.learn.prbs import TAPS, longest_pulse, mls, period, prbs, warn_if_short


@pytest.mark.parametrize("cells", sorted(TAPS))
def test_every_register_is_maximal_length(cells):
    """A maximal-length sequence shows every non-zero pattern of `cells` bits exactly once per period."""
    bits = mls(cells).astype(np.int64)
    n = period(cells)
    assert len(bits) == n == 2 ** cells - 1
    wrapped = np.concatenate([bits, bits[:cells - 1]])
    windows = sum(wrapped[i:i + n] << i for i in range(cells))
    assert np.array_equal(np.sort(windows), np.arange(1, 2 ** cells))


def test_five_cells_with_taps_three_and_five_give_period_31():
    assert TAPS[5] == (5, 3)
    bits = mls(5)
    assert len(bits) == 31 and bits.sum() == 16  # one more 1 than 0 in an m-sequence
    # Runs: the longest run of ones is 5 cells long, of zeros 4.
    runs = np.diff(np.flatnonzero(np.diff(np.r_[-1, bits, -1])))
    assert runs.max() == 5 == longest_pulse(5)


def test_clock_levels_and_whole_periods():
    u = prbs(5, clock=3, amplitude=2.0, around=15.0, periods=2)
    assert len(u) == 2 * 31 * 3
    assert set(np.unique(u)) == {13.0, 17.0}
    expected = np.repeat(np.where(mls(5) == 1, 17.0, 13.0), 3)
    assert np.array_equal(u, np.tile(expected, 2))


def test_exact_sample_count_cuts_or_repeats():
    assert np.array_equal(prbs(4, samples=20), np.resize(prbs(4), 20))


def test_bad_arguments_are_user_errors():
    with pytest.raises(JmlgError, match="between 2 and 20"):
        mls(21)
    with pytest.raises(JmlgError, match="at least 1"):
        prbs(5, clock=0)


def test_warns_when_no_pulse_lasts_the_settling_time():
    with pytest.warns(UserWarning, match="longest pulse lasts 9 s"):
        assert warn_if_short(9, 1, 1.0, 120.0)
    assert not warn_if_short(9, 4, 10.0, 120.0)  # 9 bits x 4 samples x 10 s = 360 s


def test_cli_writes_time_and_input_columns(tmp_path, capsys):
    out = tmp_path / "u.csv"
    assert main(["prbs", "--cells", "5", "--clock", "2", "--amplitude", "3", "--around", "15",
                 "--dt", "0.5", "--name", "current", "--settling", "100", "-o", str(out)]) == 0
    assert "shorter than the settling time" in capsys.readouterr().err
    rows = list(csv.DictReader(out.open()))
    assert len(rows) == 62
    assert float(rows[1]["time"]) == 1.0
    assert np.array_equal([float(r["current"]) for r in rows], prbs(5, 2, 3.0, 15.0))


def test_cli_reports_bad_register_length(capsys):
    assert main(["prbs", "--cells", "30"]) == 2
    assert "between 2 and 20" in capsys.readouterr().err


def test_cli_reports_a_sample_time_that_is_not_positive(capsys):
    with pytest.raises(SystemExit) as done:
        main(["prbs", "--dt", "0"])
    assert done.value.code == 2 and "argument --dt: must be positive, not 0" in capsys.readouterr().err
