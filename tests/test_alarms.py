"""Alarm rules: threshold and persistence worked by hand, the stream form equal to the batch form."""

import numpy as np
import pytest

from jmlgdsl.diagnosis.alarms import AlarmRule
from jmlgdsl.errors import DataError

MODES = ("ok", "leak", "stuck")
# Rows whose P(not ok) = leak + stuck is exact in binary: 0.25, 0.75, 0.5, 0.75, 0.75, 0.25, 0.75.
POSTERIOR = np.array([
    [0.75, 0.25, 0.0],
    [0.25, 0.5, 0.25],
    [0.5, 0.25, 0.25],
    [0.25, 0.75, 0.0],
    [0.25, 0.0, 0.75],
    [0.75, 0.125, 0.125],
    [0.25, 0.25, 0.5],
])


def test_fault_probability_is_the_mass_of_the_modes_not_healthy():
    assert AlarmRule(("ok",)).fault_probability(POSTERIOR, MODES).tolist() == [0.25, 0.75, 0.5, 0.75, 0.75, 0.25,
                                                                                 0.75]
    # With leak healthy too, only stuck counts.
    assert AlarmRule(("ok", "leak")).fault_probability(POSTERIOR, MODES).tolist() == [0, 0.25, 0.25, 0, 0.75,
                                                                                        0.125, 0.5]


def test_threshold_alone_is_strict():
    # P > 0.5 at rows 1, 3, 4, 6; row 2 is exactly 0.5, not above.
    assert AlarmRule(("ok",), 0.5).alarms(POSTERIOR, MODES).tolist() == [0, 1, 0, 1, 1, 0, 1]


def test_persistence_starts_the_alarm_on_the_kth_step_above_and_ends_it_on_the_first_below():
    # Above 0.5: F T F T T F T. With k = 2 only row 4 closes a run of two (rows 3, 4).
    assert AlarmRule(("ok",), 0.5, 2).alarms(POSTERIOR, MODES).tolist() == [0, 0, 0, 0, 1, 0, 0]
    # Above 0.2: T T T T T T T (all rows); k = 3 alarms from the third row on.
    assert AlarmRule(("ok",), 0.2, 3).alarms(POSTERIOR, MODES).tolist() == [0, 0, 1, 1, 1, 1, 1]


def test_truth_marks_the_steps_whose_true_mode_is_not_healthy():
    assert AlarmRule(("ok",)).truth([0, 1, 2, 0], MODES).tolist() == [0, 1, 1, 0]


@pytest.mark.parametrize("threshold, persistence", [(0.5, 1), (0.3, 2), (0.7, 4), (0.0, 3)])
def test_the_stream_gives_exactly_the_batch_series(threshold, persistence):
    rng = np.random.default_rng(persistence)
    posterior = rng.dirichlet([0.3, 0.3, 0.3], size=500)
    rule = AlarmRule(("ok",), threshold, persistence)
    stream = rule.stream(MODES)
    online = [stream.step(row) for row in posterior]
    assert online == rule.alarms(posterior, MODES).tolist()
    assert 0 < sum(online) < len(online)


def test_units_side_by_side_each_get_their_own_series_and_the_streams_count():
    """A (T, n, K) posterior (a fleet's units) gives each unit the series of its own (T, K), and the
    runs of 1s in it are the alarms its stream raised."""
    from jmlgdsl.diagnosis.metrics import runs

    rng = np.random.default_rng(4)
    posterior = rng.dirichlet([0.3, 0.3, 0.3], size=(300, 4))
    rule = AlarmRule(("ok",), 0.4, 3)
    together = rule.alarms(posterior, MODES)
    assert together.shape == (300, 4)
    for i in range(4):
        stream = rule.stream(MODES)
        assert [stream.step(row) for row in posterior[:, i]] == together[:, i].tolist()
        assert stream.raised == len(runs(together[:, i])) > 0


def test_an_empty_posterior_gives_no_alarms():
    assert AlarmRule(("ok",)).alarms(np.zeros((0, 3)), MODES).shape == (0,)


def test_an_unknown_healthy_mode_is_named_with_a_suggestion():
    with pytest.raises(DataError, match="unknown healthy mode 'okk'; did you mean 'ok'"):
        AlarmRule(("okk",)).alarms(POSTERIOR, MODES)


@pytest.mark.parametrize("kwargs, message", [
    (dict(healthy=()), "at least one healthy mode"),
    (dict(healthy=("ok",), threshold=1.0), r"threshold 1.0 is not in \[0, 1\)"),
    (dict(healthy=("ok",), persistence=0), "persistence 0"),
    (dict(healthy=("ok",), persistence=1.5), "persistence 1.5"),
])
def test_bad_rules_are_refused(kwargs, message):
    with pytest.raises(DataError, match=message):
        AlarmRule(**kwargs)
