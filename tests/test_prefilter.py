"""The causal moving-average pre-filter: exact averages, missing readings, causality, parsing."""

import numpy as np
import pytest

from jmlgdsl.errors import DataError
from jmlgdsl.diagnosis.prefilter import MovingAverage, moving_average, parse


def test_averages_over_the_readings_so_far_then_the_window():
    y = np.array([1.0, 2.0, 3.0, 4.0, 5.0])
    np.testing.assert_allclose(moving_average(y, 1), y)
    np.testing.assert_allclose(moving_average(y, 2), [1.0, 1.5, 2.5, 3.5, 4.5])
    np.testing.assert_allclose(moving_average(y, 3), [1.0, 1.5, 2.0, 3.0, 4.0])


def test_each_output_is_averaged_on_its_own_and_the_shape_is_kept():
    y = np.array([[1.0, 10.0], [3.0, 30.0], [5.0, 50.0]])
    out = moving_average(y, 2)
    assert out.shape == (3, 2)
    np.testing.assert_allclose(out, [[1.0, 10.0], [2.0, 20.0], [4.0, 40.0]])


def test_missing_readings_are_left_out_and_an_empty_window_stays_missing():
    y = np.array([[1.0], [np.nan], [3.0], [np.nan], [np.nan], [np.nan]])
    out = moving_average(y, 2)[:, 0]
    np.testing.assert_allclose(out[:5], [1.0, 1.0, 3.0, 3.0, np.nan])
    assert np.isnan(out[5])


def test_it_is_causal_so_on_line_rows_match_the_whole_array():
    rng = np.random.default_rng(4)
    y = rng.normal(size=(50, 2))
    online = MovingAverage(5)
    rows = [online(row) for row in y[:30]]
    changed = y.copy()
    changed[30:] += 100.0  # the future must not change the past
    np.testing.assert_array_equal(np.array(rows), moving_average(changed, 5)[:30])


def test_white_noise_variance_drops_by_the_window_length():
    rng = np.random.default_rng(11)
    n, window = 20_000, 4
    out = moving_average(rng.normal(size=n), window)[window:]
    # Overlapping windows are correlated (lag-j correlation (4-j)/4), which inflates the standard
    # error of the sample variance to (1/4) sqrt(2 (1 + 2 sum rho_j^2) / n) ~ 0.0041; allow 5 of them.
    assert out.var() == pytest.approx(1 / window, abs=5 * 0.0041)


def test_parse_reads_ma_k_and_rejects_anything_else():
    assert parse("ma:5") == 5
    assert parse(" ma : 12 ") == 12
    assert parse(None) is None
    assert parse("none") is None
    for bad in ("ma:0", "ma", "avg:3", "ma:-2", "ma:2.5"):
        with pytest.raises(DataError, match="write ma:K"):
            parse(bad)


def test_window_must_be_a_positive_whole_number():
    for bad in (0, -1, 2.5, True):
        with pytest.raises(DataError, match="positive whole number"):
            MovingAverage(bad)
