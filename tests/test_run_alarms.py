"""`jmlgdsl run` alarms and detection metrics: the alarm column follows the rule, and the summary's
figures are those of the metrics module on the same series."""

import csv

import numpy as np
import pytest
from conftest import dryer_files

from jmlgdsl.diagnosis import metrics
from jmlgdsl.diagnosis.alarms import AlarmRule
from jmlgdsl.cli import main

SCHEDULE = "1-60:normal,61-120:fan,121-150:normal,151-200:grill"
MODES = ["normal", "fan", "grill", "fan_grill"]


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    return dryer_files(tmp_path_factory.mktemp("alarms"), SCHEDULE, 4)


def _table(path):
    rows = list(csv.DictReader(path.open()))
    posterior = np.array([[float(r[f"p_{m}"]) for m in MODES] for r in rows])
    return posterior, np.array([int(r["alarm"]) for r in rows]), np.array([float(r["time"]) for r in rows])


@pytest.mark.parametrize("options, rule", [
    ([], AlarmRule(("normal",))),
    (["--healthy", "normal,fan", "--threshold", "0.9", "--persistence", "3"], AlarmRule(("normal", "fan"), 0.9, 3)),
])
def test_the_alarm_column_is_the_rule_applied_to_the_posterior(files, tmp_path, capsys, options, rule):
    spec, data = files
    out = tmp_path / "out.csv"
    assert main(["run", str(spec), str(data), "-o", str(out), *options]) == 0
    posterior, alarm, _ = _table(out)
    np.testing.assert_array_equal(alarm, rule.alarms(posterior, MODES))
    healthy = ", ".join(rule.healthy)
    assert f"alarms (healthy: {healthy}; P(not healthy) > {rule.threshold:g}" in capsys.readouterr().out


def test_the_summary_reports_the_metrics_of_the_alarms_against_the_true_modes(files, tmp_path, capsys):
    spec, data = files
    out = tmp_path / "out.csv"
    assert main(["run", str(spec), str(data), "-o", str(out)]) == 0
    text = capsys.readouterr().out
    _, alarm, time = _table(out)
    truth = np.array([0] * 60 + [1] * 60 + [0] * 30 + [1] * 50)  # every mode but normal is a fault
    scores = metrics.score(alarm, truth, time, metrics.changepoints(truth))
    e, o = scores.events, scores.outlier
    assert e.episodes == 2 and scores.nab.windows == 3  # rises at 61 and 151, a fall at 121
    assert (f"detection: {e.detected} of 2 anomaly episodes ({e.detection_rate:.1f} %), delay mean "
            f"{e.mean_delay:.1f} s") in text
    assert f"rows: F1 {o.f1:.3f}, false-alarm rate {o.far:.2f} %, missed-alarm rate {o.mar:.2f} %" in text
    assert f"NAB (3 change points): standard {scores.nab.score('standard'):.2f}" in text


def test_the_confusion_matrix_counts_every_labelled_step(files, capsys):
    spec, data = files
    assert main(["run", str(spec), str(data)]) == 0
    lines = capsys.readouterr().out.splitlines()
    start = lines.index("confusion (rows: true mode, columns: diagnosed mode, steps):")
    counts = np.array([[int(c) for c in line.split()[1:]] for line in lines[start + 2:start + 6]])
    assert counts.sum() == 200 and counts.sum(axis=1).tolist() == [90, 60, 50, 0]
    wrong = float(next(line for line in lines if line.startswith("diagnosis error")).split()[2])
    assert wrong == pytest.approx(100 * (200 - np.trace(counts)) / 200, abs=0.005)


def test_labels_in_anomaly_and_changepoint_columns_are_scored(files, tmp_path, capsys):
    spec, data = files
    rows = list(csv.DictReader(data.open()))
    labelled = tmp_path / "labelled.csv"
    with labelled.open("w", newline="") as stream:
        writer = csv.writer(stream)
        writer.writerow(["time", "temp", "anomaly", "changepoint"])
        for i, r in enumerate(rows):  # labels that say only steps 100-109 were anomalous
            writer.writerow([r["time"], r["temp"], int(100 <= i < 110), int(i in (100, 110))])
    out = tmp_path / "out.csv"
    assert main(["run", str(spec), str(labelled), "-o", str(out)]) == 0
    _, alarm, time = _table(out)
    anomaly = (np.arange(200) >= 100) & (np.arange(200) < 110)
    changepoint = np.isin(np.arange(200), (100, 110))
    scores = metrics.score(alarm, anomaly.astype(int), time, changepoint.astype(int))
    text = capsys.readouterr().out
    assert f"rows: F1 {scores.outlier.f1:.3f}" in text and "NAB (2 change points)" in text
    assert "confusion" not in text  # no true modes, no confusion matrix


def test_an_unknown_healthy_mode_is_a_clear_error(files, capsys):
    spec, data = files
    assert main(["run", str(spec), str(data), "--healthy", "normall"]) == 2
    assert "unknown healthy mode 'normall'; did you mean 'normal'?" in capsys.readouterr().err
