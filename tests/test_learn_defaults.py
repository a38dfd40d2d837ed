"""What plain `learn` chooses by itself, and what `run` does with it: relative learning when
cross-validation prefers it, a catch-all whose scale is chosen on held-out normal rows, every mode
stable, and detect-then-name from the learned spec with no more options."""

import numpy as np
import pytest

import jmlgdsl
from jmlgdsl.cli import main as cli
from jmlgdsl.errors import DataError
from jmlgdsl.diagnosis.alarms import catch_alls, sub_bank
from jmlgdsl.learn import learn
from jmlgdsl.learn.bank import Experiment
from jmlgdsl.learn.detector import QUIET, SCALES, choose_detector
from jmlgdsl.learn.relative import Reference, RelativeFit, relative_wins
from jmlgdsl.learn.basis import Lags


def plant(rng, ny, T, offset=None, level=100.0):
    """A VAR(1) of ny sensors (coupled neighbours, poles about 0.8) read with small noise, each
    sensor at its own level, `offset` (ny,) added from the start (a fault)."""
    Phi = 0.7 * np.eye(ny) + 0.1 * np.eye(ny, k=1)
    x, y = np.zeros(ny), np.empty((T, ny))
    for t in range(T):
        x = Phi @ x + rng.standard_normal(ny)
        y[t] = x + 0.05 * rng.standard_normal(ny)
    y += level * np.arange(1, ny + 1) + (0 if offset is None else offset)
    return np.round(y, 4)


def faults(ny, n):
    """n faults, each an offset of 8 on its own sensor (about 2.4 sd of the one-step residual: the
    normal dynamics follow a level, so an offset shows as (1 - 0.7) of itself at every step)."""
    return {f"f{i}": 8.0 * np.eye(ny)[i] for i in range(n)}


def bank_data(seed, ny, rows_normal, rows_fault, n_faults):
    rng = np.random.default_rng(seed)
    data = {"normal": Experiment(plant(rng, ny, rows_normal), np.empty((rows_normal, 0)), "normal")}
    for name, offset in faults(ny, n_faults).items():
        data[name] = Experiment(plant(rng, ny, rows_fault, offset), np.empty((rows_fault, 0)), name)
    return data


def test_few_rows_over_many_sensors_are_learned_relative_to_the_first_mode():
    said = []
    bank = learn(bank_data(3, 16, 400, 60, 3), outputs=[f"s{j}" for j in range(16)], order=1, progress=said.append)
    learned = {lm.name: lm for lm in bank.learned}
    assert all(learned[k].relative is not None for k in ("f0", "f1", "f2"))
    assert "least squares" in learned["normal"].structure and not learned["normal"].by_em
    assert any("so relative" in line for line in said)
    assert "relative to normal" in bank.text


def test_many_rows_over_few_sensors_are_each_learned_on_their_own():
    said = []
    bank = learn(bank_data(4, 2, 1500, 1500, 2), outputs=["a", "b"], order=1, max_iter=5, progress=said.append)
    assert all(lm.relative is None and lm.by_em for lm in bank.learned)
    assert any("so each on its own" in line for line in said)


def test_relative_wins_is_a_sign_test_over_the_held_out_blocks():
    def fit(diffs):
        d = np.asarray(diffs, float)
        return RelativeFit(1.0, 0.5, 1.0, 0.0, 0.0, 100, np.stack([d, np.zeros_like(d)], axis=1))
    # 9 of 10 blocks better: P(X >= 9 | 10, 1/2) = 11/1024 < 0.05
    assert relative_wins([fit([1, 1, 1, 1, 1]), fit([1, 1, 1, 1, -1e9])]) == (True, 9, 10)
    # 8 of 10: 56/1024 > 0.05, however large the gains; a single huge gain decides nothing
    assert relative_wins([fit([1e9, 1, 1, 1, 1]), fit([1, 1, 1, -1, -1])])[0] is False
    # the own regression chosen everywhere: no block differs
    assert relative_wins([fit([0, 0, 0, 0, 0])]) == (False, 0, 0)


def test_without_fault_rows_the_catch_all_scale_is_the_smallest_quiet_one_on_held_out_normal_rows():
    rng = np.random.default_rng(11)
    y = plant(rng, 8, 2000)
    steps = np.full(8, 1e-4)
    reference = Reference.of([y], [np.empty((2000, 0))], Lags(1), steps)
    P = np.array([[0.999, 0.001], [0.01, 0.99]])
    chosen = choose_detector(reference, [y], [np.empty((2000, 0))], [], P, np.array([0.99, 0.01]))
    shares = chosen.shares[0]  # the healthy mode's noise as fitted
    i = SCALES.index(chosen.scale)
    assert chosen.inflation == 1 and chosen.detected is None
    assert chosen.quiet and shares[i] <= QUIET
    assert all(share > QUIET for share in shares[:i])
    # the shares fall as the scale grows: a wider catch-all explains less of normal operation
    assert shares[-1] <= shares[0]
    # a right model with this much data: the detector alarms on normal rows only at the smallest scales
    assert chosen.scale <= 2.0


def test_fault_recordings_choose_a_detector_that_sees_them_and_stays_quiet_on_fresh_normal_rows():
    # faults of an offset of 4 on one of 8 sensors (about 1.2 sd of the one-step residual): a catch-all
    # wide enough to stay quiet by itself sees few of their rows; a healthy mode whose noise is
    # inflated to its held-out residuals' and a narrow catch-all add them up
    ny, names, rng = 8, [f"s{j}" for j in range(8)], np.random.default_rng(21)
    offsets = {f"f{i}": 4.0 * np.eye(ny)[i] for i in range(3)}
    data = {"normal": Experiment(plant(rng, ny, 400), np.empty((400, 0)), "normal")}
    data.update({name: Experiment(plant(rng, ny, 200, offset), np.empty((200, 0)), name)
                 for name, offset in offsets.items()})
    said = []
    model = learn(data, outputs=names, order=1, progress=said.append).model
    alone = learn({"normal": data["normal"]}, outputs=names, order=1, catch_all=("anomaly", None)).model
    assert catch_alls(model, ["normal"]) == ["anomaly"]
    line = next(text for text in said if text.startswith("catch-all noise scale"))
    assert "over normal's noise x" in line and "detects the most of the fault recordings' rows" in line
    normal, faulty = plant(rng, ny, 2000), [plant(rng, ny, 300, offset) for offset in offsets.values()]

    def alarmed(bank, y):
        return jmlgdsl.filter(sub_bank(bank, ["normal", "anomaly"]), y).mode_posterior[:, 1] > 0.5
    for bank in (model, alone):
        assert alarmed(bank, normal).mean() <= 0.01  # quiet on normal operation it has not seen
    seen = np.mean([alarmed(model, y).mean() for y in faulty])
    assert seen >= 0.4 and seen > 3 * np.mean([alarmed(alone, y).mean() for y in faulty])


def test_plain_learn_adds_a_catch_all_that_run_recognises():
    bank = learn(bank_data(5, 6, 400, 200, 2), outputs=[f"s{j}" for j in range(6)], order=1)
    model = bank.model
    assert model.modes == ("normal", "f0", "f1", "anomaly")
    assert catch_alls(model, ["normal"]) == ["anomaly"]
    assert catch_alls(model, ["f0"]) == []
    scale = model.B[3][0, 0] / model.B[0][0, 0]
    assert scale in SCALES and f"noise x{scale:g}" in bank.text
    # a single mode gets none, nor does a bank learned with catch_all=None
    single = learn({"normal": bank_data(5, 6, 400, 200, 0)["normal"]}, outputs=[f"s{j}" for j in range(6)], order=1,
                   max_iter=3)
    assert single.model.modes == ("normal",)


def test_a_mode_with_other_dynamics_is_no_catch_all(tmp_path):
    spec = tmp_path / "p.jmlg"
    spec.write_text("""plant p
sample 1 s
output y
state x sd 1
modes normal, wide, other
initial normal 0.9, otherwise uniform
transitions stay 0.99, otherwise uniform
mode normal { x[t] ~ Normal(0.9 * x[t-1], 1); y ~ Normal(x[t], 0.1) }
mode wide like normal { noise scale 3 }
mode other { x[t] ~ Normal(0.5 * x[t-1], 3); y ~ Normal(x[t], 0.3) }
""")
    model = jmlgdsl.load(spec)
    assert catch_alls(model, ["normal"]) == ["wide"]


def test_run_detects_then_names_with_a_plainly_learned_spec(tmp_path, capsys):
    ny = 6
    data = bank_data(8, ny, 600, 300, 2)
    names = [f"s{j}" for j in range(ny)]
    paths = []
    for name, e in data.items():
        path = tmp_path / f"{name}.csv"
        np.savetxt(path, e.y, delimiter=",", header=",".join(names), comments="", fmt="%.4f")
        paths += ["--mode", f"{name}={path}"]
    spec = tmp_path / "bank.jmlg"
    assert cli(["learn", *paths, "--output", ",".join(names), "--order", "1", "-q", "-o", str(spec)]) == 0
    rng = np.random.default_rng(9)
    normal, fault = plant(rng, ny, 300), plant(rng, ny, 300, faults(ny, 2)["f1"])
    test = tmp_path / "test.csv"
    with open(test, "w") as f:
        f.write(",".join(names) + ",mode\n")
        for row, mode in zip(np.vstack([normal, fault]), ["normal"] * 300 + ["f1"] * 300):
            f.write(",".join(f"{v:.4f}" for v in row) + f",{mode}\n")
    capsys.readouterr()
    assert cli(["run", str(spec), str(test), "--healthy", "normal", "-o", str(tmp_path / "out.csv")]) == 0
    out = capsys.readouterr()
    report = out.out
    assert "residuals are about" not in out.err  # the sensors' noise is the regression's, not the rounding's
    assert "naming:" in report and "naming confusion" in report
    assert report.startswith("detect, then name: the alarm from normal, anomaly (a healthy mode and its catch-all), "
                             "the fault named by f0, f1;")
    table = np.genfromtxt(tmp_path / "out.csv", delimiter=",", names=True, dtype=None, encoding=None)
    alarm = table["alarm"]
    assert alarm[:300].mean() <= 0.01  # quiet on normal operation
    assert alarm[310:].mean() >= 0.9  # the fault is seen within a few rows, and the alarm stays up
    line = next(ln for ln in report.splitlines() if ln.startswith("naming:"))
    assert float(line.split()[1]) >= 90.0  # f1 named right on at least 90 % of its rows


def test_a_fault_too_short_to_cross_validate_is_learned_on_its_own_unless_relative_is_asked_for():
    rng = np.random.default_rng(6)
    data = {"normal": Experiment(plant(rng, 2, 300), np.empty((300, 0)), "normal.csv"),
            "short": Experiment(plant(rng, 2, 9, np.array([8.0, 0.0])), np.empty((9, 0)), "short.csv"),
            "long": Experiment(plant(rng, 2, 200, np.array([0.0, 8.0])), np.empty((200, 0)), "long.csv")}
    bank = learn(data, outputs=["a", "b"], order=1, max_iter=3)
    assert all(lm.relative is None for lm in bank.learned)
    with pytest.raises(DataError, match="mode short: 8 complete equations, too few to learn it relative"):
        learn(data, outputs=["a", "b"], order=1, relative_to="normal")
