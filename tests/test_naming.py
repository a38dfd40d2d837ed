"""Naming faults: modes learned relative to normal, the detect-then-name run and its naming scores."""

import numpy as np
import pytest

import jmlgdsl
from jmlgdsl.cli import main as cli
from jmlgdsl.diagnosis.alarms import DetectThenName, sub_bank
from jmlgdsl.diagnosis.metrics import naming_counts
from jmlgdsl.learn import learn
from jmlgdsl.learn.bank import Experiment

NY = 4
PHI = np.array([[0.8, 0.1, 0, 0], [0, 0.7, 0.2, 0], [0, 0, 0.9, 0], [0.1, 0, 0, 0.6]])
LEVEL = np.array([10.0, 200.0, 3.0, 50.0])


def recording(rng, T, fault=None, onset=0):
    """A 4-sensor VAR(1) plant: normal, or from `onset` a bias of +2 on s2 ('bias'), s3 stuck at its
    reading ('stuck') or the noise of s4 times 4 ('noisy')."""
    x, y = np.zeros(NY), np.empty((T, NY))
    stuck = None
    for t in range(T):
        x = PHI @ x + rng.standard_normal(NY)
        y[t] = x + 0.1 * rng.standard_normal(NY) + LEVEL
        if fault and t >= onset:
            if fault == "bias":
                y[t, 1] += 2.0
            elif fault == "stuck":
                stuck = y[t, 2] if stuck is None else stuck
                y[t, 2] = stuck
            else:
                y[t, 3] += 4 * rng.standard_normal()
    return np.round(y, 3)


@pytest.fixture(scope="module")
def banks():
    rng = np.random.default_rng(7)
    train = {mode: Experiment(recording(rng, 300, None if mode == "normal" else mode), np.empty((300, 0)), mode)
             for mode in ("normal", "bias", "stuck", "noisy")}
    relative = learn(train, outputs=[f"s{j + 1}" for j in range(NY)], order=1, relative_to="normal",
                     catch_all=("anomaly", 3.0))
    return train, relative


def test_relative_modes_keep_normal_dynamics_and_learn_offset_scale_and_stuck_sensor(banks):
    train, bank = banks
    model, learned = bank.model, {lm.name: lm for lm in bank.learned}
    assert model.modes == ("normal", "bias", "stuck", "noisy", "anomaly")
    assert learned["normal"].relative is None and "least squares" in learned["normal"].summary()  # the reference
    k = model.mode_index
    # a bias changes no dynamics: cross-validation keeps them close to normal's, the offset moves s2 by ~2
    bias = learned["bias"]
    assert bias.relative.shrinkage >= 1 and "relative to normal" in bias.summary()
    steady = np.linalg.solve(np.eye(NY) - bias.mode.Phi, bias.mode.c)
    assert steady[1] - LEVEL[1] == pytest.approx(2.0, abs=0.4)
    assert np.abs(np.delete(steady - LEVEL, 1)).max() < 1.0  # the sample mean of 300 rows of a slow plant
    # the stuck sensor reads its last value, at the rounding floor, whatever value it stuck at
    stuck = learned["stuck"].mode
    assert stuck.Phi[2] == pytest.approx(np.eye(NY)[2] * stuck.Phi[2, 2]) and stuck.Phi[2, 2] > 0.99
    assert np.sqrt(stuck.Q[2, 2]) < 1e-3
    # the noisy sensor's variance is its own
    assert learned["noisy"].mode.Q[3, 3] > 8 * learned["bias"].mode.Q[3, 3]
    # the catch-all is the normal mode with every noise sd times 3
    assert np.allclose(model.B[k("anomaly")], 3 * model.B[k("normal")])
    assert np.allclose(model.D[k("anomaly")], 3 * model.D[k("normal")])
    assert np.array_equal(model.A[k("anomaly")], model.A[k("normal")])


def test_sub_bank_renormalises_transitions_and_prior(banks):
    model = banks[1].model
    part = sub_bank(model, ["anomaly", "normal"])
    assert part.modes == ("normal", "anomaly")
    assert np.allclose(part.P.sum(axis=1), 1) and np.allclose(part.p0.sum(), 1)
    assert part.P[0, 0] == pytest.approx(model.P[0, 0] / (model.P[0, 0] + model.P[0, -1]))
    assert np.array_equal(part.B[1], model.B[-1])


def test_naming_counts_by_hand():
    # true faults (-1: a normal row, left out) against names (-1: no alarm)
    counts = naming_counts([0, 0, 0, 1, 1, -1, 2], [0, 1, -1, 1, 1, 0, -1], 3)
    assert counts.confusion.tolist() == [[1, 1, 0, 1], [0, 2, 0, 0], [0, 0, 0, 1]]
    assert counts.accuracy[:2].tolist() == pytest.approx([100 / 3, 100])
    assert counts.alarmed_accuracy[0] == pytest.approx(50) and np.isnan(counts.alarmed_accuracy[2])
    assert counts.overall == pytest.approx(100 * 3 / 6)
    assert (counts + counts).confusion.sum() == 12


def test_detect_then_name_names_each_fault(banks):
    model = banks[1].model
    rng = np.random.default_rng(11)
    for fault in ("bias", "stuck", "noisy"):
        y = recording(rng, 400, fault, onset=100)
        options = jmlgdsl.diagnosis.Options(healthy=("normal",), threshold=0.99, persistence=5)
        naming = DetectThenName(model, None, ["bias", "stuck", "noisy"], options)
        rows = [jmlgdsl.data.Row(i + 1, None, y[i], np.empty(0), model.mode_index("normal" if i < 100 else fault))
                for i in range(len(y))]
        diagnosis = jmlgdsl.diagnosis.Diagnosis(naming.detector, options, sinks=[naming])
        diagnosis.run(naming.rows(rows))
        counts = naming.counts()
        f = naming.namer.modes.index(fault)
        named = counts.confusion[f, :-1].sum()
        assert named > 0 and counts.right[f] / named > 0.9, (fault, counts.confusion[f])
        assert diagnosis.truth.scores().outlier.far < 10  # the alarm mostly stays down in the normal part


def test_cli_learn_relative_and_run_detect(tmp_path, capsys, banks):
    rng = np.random.default_rng(5)
    header = ",".join(f"s{j + 1}" for j in range(NY))
    args = []
    for mode in ("normal", "bias", "stuck", "noisy"):
        np.savetxt(tmp_path / f"{mode}.csv", recording(rng, 300, None if mode == "normal" else mode),
                   delimiter=",", header=header, comments="")
        args += ["--mode", f"{mode}={tmp_path / f'{mode}.csv'}"]
    spec = tmp_path / "bank.jmlg"
    assert cli(["learn", "--output", header, *args, "--order", "1", "--relative-to", "normal",
                "--catch-all", "anomaly=3", "-q", "-o", str(spec)]) == 0
    assert "relative to normal" in spec.read_text()
    y = recording(rng, 300, "bias", onset=100)
    with open(tmp_path / "test.csv", "w") as out:
        out.write(header + ",mode\n")
        for i, row in enumerate(y):
            out.write(",".join(map(str, row.tolist())) + ("," + ("normal" if i < 100 else "bias")) + "\n")
    capsys.readouterr()
    assert cli(["run", str(spec), str(tmp_path / "test.csv"), "--name", "bias,stuck,noisy", "--persistence", "3"]) == 0
    text = capsys.readouterr().out
    assert "naming:" in text and "naming confusion" in text
    share = float(text.split("  bias: ")[1].split(" %")[0])
    assert share > 60  # of every faulty row, the ones before the alarm included
    with pytest.raises(SystemExit):
        cli(["learn", "--output", header, *args, "--catch-all", "anomaly=0.5"])


def test_the_namer_follows_the_rows_around_alarms_only_and_starts_from_the_rows_before(banks):
    """Normal rows, a bias, normal rows long enough for the namer to rest, the bias again: the namer
    steps only from WARM_UP rows before each alarm to WARM_UP rows after it, and each alarmed row is
    named as a namer started from its prior at the first of those rows names it, bit for bit."""
    from jmlgdsl.diagnosis.alarms import WARM_UP

    model = banks[1].model
    y = recording(np.random.default_rng(7), 360)
    y[100:130, 1] += 4.0
    y[280:310, 1] += 4.0
    options = jmlgdsl.diagnosis.Options(healthy=("normal",), threshold=0.9, persistence=2)
    naming = DetectThenName(model, None, ["bias", "stuck", "noisy"], options)
    rows = [jmlgdsl.data.Row(i + 1, None, y[i], np.empty(0), None) for i in range(len(y))]
    diagnosis = jmlgdsl.diagnosis.Diagnosis(naming.detector, options, sinks=[naming])
    alarm = []
    diagnosis.sinks.append(type("Alarms", (), {"collect": lambda self, done: alarm.append(done.alarm)})())
    diagnosis.run(naming.rows(rows))
    alarm = np.array(alarm, dtype=bool)
    spans, start = [], None  # the rows the namer follows: WARM_UP before an alarm to WARM_UP after it
    for t in range(len(y)):
        if alarm[t] and start is None:
            start = max(t - WARM_UP + 1, 0)
        if start is not None and not alarm[max(t - WARM_UP + 1, 0):t + 1].any():
            spans.append((start, t + 1))
            start = None
    if start is not None:
        spans.append((start, len(y)))
    assert [a <= 100 < b for a, b in spans] == [True, False] and spans[1][0] <= 280 < spans[1][1]  # one per bias
    assert naming.steps == sum(b - a for a, b in spans) < len(y) // 2
    expected = np.full(len(y), -1)
    namer = naming.namer
    for a, b in spans:
        alone = jmlgdsl.filter(namer, y[a:b], np.empty((b - a, 0)), algorithm="mmae").mode_posterior.argmax(axis=1)
        expected[a:b] = np.where(alarm[a:b], alone, -1)
    assert naming.named == expected.tolist()
    assert (expected[alarm] == namer.modes.index("bias")).mean() > 0.9
