"""Detection metrics against small cases worked by hand from the SKAB leaderboard's definitions
(shared/reference/skab-scoring.md): F1 / FAR / MAR, the NAB windows, sigmoid and pooling.

Times are seconds; unless said otherwise a file has one row per second, t = 0, 1, 2, ...
Constants used by hand: tanh(pi/2) = 0.9171523; the standard profile is (A_tp, A_fp, A_fn) =
(1, -0.11, -1), LowFP (1, -0.22, -1), LowFN (1, -0.11, -2); half = (A_tp - A_fp) / 2.
"""

import numpy as np
import pytest

from jmlgdsl.errors import DataError
from jmlgdsl.diagnosis.metrics import (PROFILES, EventCounts, NabCounts, OutlierCounts, Scores, changepoints, confusion,
                             event_counts, monitored, nab_counts, nab_windows, outlier_counts, score,
                             switch_delays)

HAND = 1e-3  # tolerance on NAB scores worked out by hand from sigmoid values carried to 6 digits
ROUNDING = 1e-12  # tolerance where the maths is exact but floating sums round (e.g. 0.555 + 0.555 - 0.11)


def points(T, *rows):
    """A 0/1 series of T rows with 1 at the given rows."""
    series = np.zeros(T, dtype=int)
    series[list(rows)] = 1
    return series


# --- outlier problem -----------------------------------------------------------------------------------

def test_counts_f1_far_mar_by_hand():
    alarm = [1, 1, 0, 0, 1, 0]
    truth = [1, 0, 0, 1, 1, 0]
    c = outlier_counts(alarm, truth)
    # TP rows 0, 4; FP row 1; TN rows 2, 5; FN row 3.
    assert c == OutlierCounts(tp=2, fp=1, tn=2, fn=1)
    assert c.f1 == 2 / 3          # 2 / (2 + (1 + 1) / 2)
    assert c.far == 100 / 3       # 100 * 1 / (1 + 2)
    assert c.mar == 100 / 3       # 100 * 1 / (1 + 2)


def test_perfect_and_null_detectors():
    truth = [0, 1, 1, 0, 1]
    perfect = outlier_counts(truth, truth)
    assert (perfect.f1, perfect.far, perfect.mar) == (1.0, 0.0, 0.0)   # 3 / (3 + 0); 0 / 2; 0 / 3
    null = outlier_counts([0] * 5, truth)
    assert (null.f1, null.far, null.mar) == (0.0, 0.0, 100.0)        # 0 / (0 + 3/2); 0 / 2; 100 * 3 / 3


def test_scores_undefined_without_their_rows_are_nan():
    c = outlier_counts([0, 0], [0, 0])  # no anomalies, no alarms: F1 = 0 / 0, MAR = 0 / 0
    assert np.isnan(c.f1) and np.isnan(c.mar) and c.far == 0.0


def test_pooling_sums_counts_instead_of_averaging_scores():
    a = outlier_counts([1], [1])               # TP 1: F1 1
    b = outlier_counts([0, 0, 0], [1, 1, 1])   # FN 3: F1 0
    pooled = OutlierCounts.pool([a, b])
    assert pooled == OutlierCounts(tp=1, fp=0, tn=0, fn=3)
    assert pooled.f1 == 0.4                    # 1 / (1 + 3 / 2), not the mean 0.5 of the file F1s
    assert pooled.mar == 75.0                  # 100 * 3 / 4


def test_labels_must_be_zero_or_one():
    with pytest.raises(DataError, match="anomaly must be a 1-D series of 0 and 1"):
        outlier_counts([0, 1], [0, 2])
    with pytest.raises(ValueError, match="alarm has 2 rows, anomaly 3"):
        outlier_counts([0, 1], [0, 1, 1])


# --- predicted change points ---------------------------------------------------------------------------

def test_change_points_are_every_edge_and_the_first_row_when_alarmed():
    assert changepoints([1, 1, 0, 0, 1]).tolist() == [1, 0, 1, 0, 1]   # a[0]; |0-1| at 2; |1-0| at 4
    assert changepoints([0, 0, 1, 1]).tolist() == [0, 0, 1, 0]
    assert changepoints([0.0, 1.0]).tolist() == [0, 1]                 # labels read as floats


# --- episodes, delays, false alarms per hour -------------------------------------------------------------

def test_episode_detection_delay_and_false_alarms_by_hand():
    truth = [0, 0, 1, 1, 1, 0, 0, 1, 1, 0]
    alarm = [0, 1, 0, 0, 1, 1, 0, 0, 0, 1]
    e = event_counts(alarm, truth, 2.0)  # sample time 2 s
    # Episodes rows 2-4 and 7-8. The first is alarmed first at row 4: delay (4 - 2) * 2 s = 4 s; the
    # second is never alarmed. Alarm runs: row 1 (no anomalous row: false), rows 4-5 (touch row 4: not
    # false), row 9 (false). Monitored 10 rows * 2 s = 20 s, so 2 false alarms / (20 / 3600 h) = 360 / h.
    assert e == EventCounts(episodes=2, detected=1, false_alarms=2, duration=20.0, delays=(4.0,))
    assert e.detection_rate == 50.0
    assert e.false_alarms_per_hour == 360.0
    assert e.mean_delay == e.median_delay == 4.0


def test_an_alarm_already_on_detects_with_no_delay():
    e = event_counts([1, 1, 1, 0], [0, 1, 1, 0], 1.0)
    assert (e.detected, e.delays, e.false_alarms) == (1, (0.0,), 0)


def test_pooled_delays_take_the_median_over_all_files():
    a = event_counts([0, 0, 1], [0, 1, 1], 1.0)          # delay 1 s (row 2 - row 1)
    b = event_counts([0, 0, 0, 0, 1], [1, 1, 1, 1, 1], 1.0)  # delay 4 s
    c = event_counts([0, 0, 0, 1, 1], [0, 1, 1, 1, 1], 1.0)  # delay 2 s (row 3 - row 1)
    pooled = EventCounts.pool([a, b, c])
    assert pooled.delays == (1.0, 4.0, 2.0)
    assert (pooled.median_delay, pooled.mean_delay) == (2.0, 7 / 3)
    assert pooled.duration == 13.0                       # 3 + 5 + 5 rows of 1 s


def test_monitored_time_of_an_irregular_axis_and_of_datetimes():
    # Span 6 - 0 plus the median step of (1, 1, 3, 1), which is 1: 7 s.
    assert monitored([0.0, 1.0, 2.0, 5.0, 6.0], 5) == 7.0
    stamps = np.array(["2020-03-09T10:14:33", "2020-03-09T10:14:34", "2020-03-09T10:14:36"], dtype="datetime64[s]")
    assert monitored(stamps, 3) == 4.5   # span 3 s plus the median of (1, 2) = 1.5 s
    assert monitored(2.0, 3) == 6.0      # a sample time: 3 rows * 2 s


def test_a_time_axis_that_goes_backwards_is_refused():
    with pytest.raises(DataError, match="goes backwards"):
        event_counts([0, 0, 0], [0, 0, 0], [0.0, 2.0, 1.0])


# --- NAB -----------------------------------------------------------------------------------------------

def nab(T, cps, preds, time=None):
    """NAB counts of predicted change points at rows `preds` against true ones at rows `cps`."""
    return nab_counts(points(T, *preds), points(T, *cps), np.arange(T, dtype=float) if time is None else time)


def test_sigmoid_runs_from_a_tp_at_the_left_end_to_a_fp_at_the_right():
    for w in PROFILES.values():
        assert w.sigmoid(0) == pytest.approx(w.a_tp, abs=ROUNDING)     # x = -pi/2: -tanh(x)/tanh(pi/2) = 1
        assert w.sigmoid(999) == pytest.approx(w.a_fp, abs=ROUNDING)   # x = pi/2: the ratio is -1


def test_perfect_and_null_detectors_score_100_and_0():
    perfect = nab(200, [50], [50])   # p = c = l: event 0, S = A_tp
    assert perfect == NabCounts(windows=1, fp=0, events=(0,), delays=(0.0,))
    for name, w in PROFILES.items():
        assert perfect.score(name) == pytest.approx(100.0, abs=ROUNDING)   # 100 (A_tp - A_fn) / (A_tp - A_fn)
        assert nab(200, [50], []).score(name) == 0.0                       # S = A_fn = S_null


def test_a_late_detection_inside_the_window():
    # Window [50, 110]; p = 80: e = floor(30 / 60 * 1000) = 500, x = -pi/2 + 500 pi / 999 = pi / 1998,
    # tanh(x) / tanh(pi/2) = 0.0015724 / 0.917152 = 0.0017144.
    n = nab(200, [50], [80])
    assert (n.events, n.delays, n.missed, n.fp) == ((500,), (30.0,), 0, 0)
    # standard: y = 0.555 * (-0.0017144) + 0.555 - 0.11 = 0.444049; NAB = 100 (0.444049 + 1) / 2
    assert n.score("standard") == pytest.approx(72.2024, abs=HAND)
    # LowFP: half 0.61, y = 0.61 * (-0.0017144) + 0.61 - 0.22 = 0.388954; NAB = 100 (0.388954 + 1) / 2
    assert n.score("lowfp") == pytest.approx(69.4477, abs=HAND)
    # LowFN: y as standard; NAB = 100 (0.444049 + 2) / 3
    assert n.score("lowfn") == pytest.approx(81.4683, abs=HAND)


def test_early_and_too_late_detections_are_a_false_positive_and_a_miss():
    for p in (49, 111):   # before the window [50, 110], and after it
        n = nab(200, [50], [p])
        assert (n.events, n.missed, n.fp) == ((), 1, 1)
        assert n.score("standard") == pytest.approx(-5.5, abs=ROUNDING)      # 100 (-0.11 - 1 + 1) / 2
        assert n.score("lowfp") == pytest.approx(-11.0, abs=ROUNDING)        # 100 (-0.22 - 1 + 1) / 2
        assert n.score("lowfn") == pytest.approx(-11 / 3, abs=ROUNDING)      # 100 (-0.11 - 2 + 2) / 3


def test_the_right_end_is_inclusive_and_scores_a_fp():
    n = nab(200, [50], [110])   # e = floor(60 / 60 * 1000) = 1000, capped at 999: y = A_fp
    assert (n.events, n.fp) == ((999,), 0)
    assert n.score("standard") == pytest.approx(44.5, abs=ROUNDING)   # 100 (-0.11 + 1) / 2


def test_only_the_earliest_point_in_a_window_counts():
    n = nab(200, [10], [20, 30, 69])   # window [10, 70]; 30 and 69 count for nothing (not FPs)
    assert (n.events, n.fp) == ((166,), 0)    # floor(10 / 60 * 1000) = 166


def test_an_alarm_on_the_first_scored_row_detects_a_change_point_there():
    s = score([1, 1, 1, 0, 0], [1, 1, 0, 0, 0], 1.0, changepoint=[1, 0, 0, 0, 0])
    # cp_pred = [1, 0, 0, 1, 0]: p = 0 detects [0, 60] at its left end; p = 3 is inside it too.
    assert s.nab == NabCounts(windows=1, fp=0, events=(0,), delays=(0.0,))


def test_a_window_running_past_the_end_of_the_file_is_not_clipped():
    n = nab(200, [190], [199])   # window [190, 250]: e = floor(9 / 60 * 1000) = 150 (clipped: 999)
    assert n.events == (150,)
    # y_150: x = -pi/2 + 150 pi / 999 = -1.099086, tanh(x) = -0.800170, -tanh(x)/tanh(pi/2) = 0.872452;
    # y = 0.555 * 0.872452 + 0.555 - 0.11 = 0.929211; NAB = 100 (0.929211 + 1) / 2
    assert n.score() == pytest.approx(96.4605, abs=HAND)


def test_overlapping_windows_are_cut_at_the_previous_right_end():
    windows = nab_windows(points(200, 10, 40, 150), np.arange(200.0))
    assert windows.tolist() == [[10, 70], [70, 100], [150, 210]]   # l_2 = max(40, 10 + 60) = 70


def test_a_point_on_a_shared_boundary_detects_both_windows():
    # Windows [10, 70] and [70, 100]: p = 70 is window 1's right end (e 999) and window 2's left (e 0).
    n = nab(200, [10, 40], [70])
    assert (n.events, n.delays, n.missed, n.fp) == ((999, 0), (60.0, 0.0), 0, 0)
    assert n.mean_delay == 30.0
    # S = -0.11 + 1 = 0.89; S_perfect = 2, S_null = -2: NAB = 100 (0.89 + 2) / 4 = 72.25
    assert n.score() == pytest.approx(72.25, abs=ROUNDING)
    # Change points exactly 60 s apart (the reference's example): p on the second detects both.
    assert nab(200, [10, 70], [70]).events == (999, 0)


def test_a_point_at_the_next_change_point_inside_the_previous_window_cannot_detect_it():
    n = nab(200, [10, 40], [40])   # windows [10, 70], [70, 100]: 40 is in window 1 only
    assert (n.events, n.missed, n.fp) == ((500,), 1, 0)   # floor(30 / 60 * 1000) = 500


def test_two_change_points_on_one_time_stamp_give_a_window_of_one_instant():
    time = np.array([0.0, 10.0, 10.0, 11.0, 70.0])   # rows 1 and 2 share t = 10
    assert nab_windows(points(5, 1, 2), time).tolist() == [[10, 70], [70, 70]]
    n = nab(5, [1, 2], [4], time)   # p = 70: window 1 at e 999, the one-instant window at its left end
    assert (n.events, n.missed, n.fp) == ((999, 0), 0, 0)


def test_windows_are_in_time_not_rows():
    time = np.array([0.0, 1.0, 2.0, 3.0, 100.0, 101.0])   # a 97 s gap after row 3
    n = nab(6, [1], [4], time)   # window [1, 61]; row 4 is at t = 100, outside it
    assert (n.events, n.missed, n.fp) == ((), 1, 1)


def test_a_file_without_change_points_adds_only_its_false_positives():
    b = nab(100, [], [20, 40])
    assert (b.windows, b.fp) == (0, 2) and np.isnan(b.score())   # no windows: 0 / 0
    pooled = NabCounts.pool([nab(200, [50], [50]), b])
    # S = 1 + 2 (-0.11) = 0.78, S_perfect = 1, S_null = -1: NAB = 100 (0.78 + 1) / 2 = 89
    assert pooled.score() == pytest.approx(89.0, abs=ROUNDING)


def test_nab_pools_sums_not_per_file_scores():
    a = nab(200, [50], [50])               # NAB 100
    b = nab(400, [50, 150, 250], [])       # NAB 0
    # S = 1 - 3 = -2, S_perfect = 4, S_null = -4: NAB = 100 (-2 + 4) / 8 = 25, not the mean 50
    assert NabCounts.pool([a, b]).score() == pytest.approx(25.0, abs=ROUNDING)


# --- everything for a file, pooled -----------------------------------------------------------------------

def test_score_pools_every_part_and_names_the_summary():
    a = score(points(200, *range(50, 61)), points(200, *range(50, 90)), 1.0, points(200, 50))
    b = score(np.zeros(100), np.zeros(100), 1.0, np.zeros(100))
    pooled = Scores.pool([a, b])
    # Alarm rows 50-60 inside the anomaly 50-89: TP 11, FN 29, TN 160 + 100. cp_pred at 50 and 61, both in
    # the window [50, 110]: one TP at e = 0.
    assert pooled.outlier == OutlierCounts(tp=11, fp=0, tn=260, fn=29)
    assert pooled.nab == NabCounts(windows=1, fp=0, events=(0,), delays=(0.0,))
    assert pooled.events.duration == 300.0
    s = pooled.summary()
    assert s["f1"] == 11 / 25.5 and s["far"] == 0.0 and s["missed_cp"] == 0 and s["fp"] == 0
    assert s["nab_standard"] == pytest.approx(100.0, abs=ROUNDING)
    assert (s["detection_rate"], s["mean_delay"], s["false_alarms_per_hour"]) == (100.0, 0.0, 0.0)
    assert np.isnan(score([0], [0], 1.0).summary()["nab_standard"])   # no change-point labels


# --- diagnosed vs true modes -----------------------------------------------------------------------------

def test_confusion_matrix_counts_true_rows_against_diagnosed_columns():
    c = confusion([0, 0, 1, 1, 2], [0, 1, 1, 1, 0], 3)
    assert c.tolist() == [[1, 1, 0], [0, 2, 0], [1, 0, 0]]
    assert (c + c).sum() == 10   # files pool by adding their matrices
    with pytest.raises(ValueError, match="mode indices must lie in 0..2"):
        confusion([0, 3], [0, 0], 3)


def test_switch_delays_count_from_each_switch_to_the_first_right_row_plus_the_lag():
    true = np.array([0, 0, 0, 1, 1, 1, 1, 2, 2, 0])
    seen = np.array([0, 0, 0, 0, 1, 0, 1, 2, 2, 2])
    # switch to 1 at row 3, first right at row 4: 1; to 2 at row 7: 0; to 0 at row 9, never: 1 (segment)
    np.testing.assert_array_equal(switch_delays(seen, true), [1.0, 0.0, 1.0])
    np.testing.assert_array_equal(switch_delays(seen, true, lag=5), [6.0, 5.0, 6.0])
    assert switch_delays(np.zeros(4), np.zeros(4)).size == 0  # no switch, no delay
