"""Learning several sensors at once, from several runs of a mode and from rows labelled by a
`mode` column, through the library and through `jmlgdsl learn`."""

import numpy as np
import pytest

import jmlgdsl
from jmlgdsl import Model
from jmlgdsl.cli import main
from jmlgdsl.data import write_columns
from jmlgdsl.learn import bank
from jmlgdsl.learn.prbs import prbs

UNITS = np.array([1e-3, 1e3])  # a sensor in volts beside one in litres per hour


def plant() -> Model:
    """Two modes over two coupled sensors in very different units, one input."""
    A = np.array([[[0.8, 0.1], [0.05, 0.7]], [[0.9, 0.0], [0.1, 0.6]]])
    A = UNITS[:, None] * A / UNITS
    F = UNITS[:, None] * np.array([[[0.5], [0.2]], [[0.3], [0.4]]])
    return Model.from_arrays(A=A, F=F, f=UNITS * np.array([[1.0, 2.0], [1.5, 1.0]]), C=np.eye(2),
                             B=0.05 * np.diag(UNITS) @ np.linalg.cholesky([[1.0, 0.5], [0.5, 1.0]]),
                             D=0.03 * np.diag(UNITS), P=bank.default_transitions(2, 0.99), p0=[0.99, 0.01],
                             mu0=UNITS * 5, Sigma0=np.diag(UNITS ** 2), modes=("normal", "fault"),
                             outputs=("volts", "flow"), inputs=("valve",), input_defaults=[0.0])


@pytest.fixture(scope="module")
def runs():
    model = plant()
    u = prbs(6, clock=4, samples=200)[:, None]
    return model, {name: [jmlgdsl.simulate(model, modes=[name] * len(u), u=u, seed=10 * k + j) for j in range(2)]
                   for k, name in enumerate(model.modes)}


def test_several_runs_of_a_mode_are_pooled(runs):
    """Two runs of each mode learned together: the sensors' cross-coupling and gains come back
    within a few standard errors (about 0.03 in the scaled units, for 400 samples), in each sensor's
    own units, and the noise covariances are full (the process noise is correlated)."""
    model, sims = runs
    exps = {name: [bank.Experiment(s.y, s.u, f"{name}{j}") for j, s in enumerate(ss)] for name, ss in sims.items()}
    learned = bank.learn_modes(exps, order=(1, 1, 0))
    for k, lm in enumerate(learned):
        assert len(lm.experiments) == 2
        scaled_A = lm.mode.Phi * UNITS / UNITS[:, None]
        true_A = model.A[k] * UNITS / UNITS[:, None]
        assert np.allclose(scaled_A, true_A, atol=0.12), lm.name
        gain = lm.model.gain() / UNITS[:, None]
        true_gain = np.linalg.solve(np.eye(2) - model.A[k], model.F[k]) / UNITS[:, None]
        assert np.allclose(gain, true_gain, rtol=0.15), lm.name
        corr = lm.mode.Q[0, 1] / np.sqrt(lm.mode.Q[0, 0] * lm.mode.Q[1, 1])
        assert 0.2 < corr < 0.8  # the true correlation is 0.5


def test_cli_learns_several_sensors_from_rows_labelled_by_mode(runs, tmp_path, capsys):
    """One file holds both modes, labelled in its `mode` column, and another holds a second run of
    each; the written spec has both sensors, the lagged state names, and loads, checks and runs."""
    model, sims = runs
    for j in range(2):
        y = np.vstack([sims["normal"][j].y, sims["fault"][j].y])
        u = np.vstack([sims["normal"][j].u, sims["fault"][j].u])
        write_columns(tmp_path / f"run{j}.csv", {"mode": ["normal"] * 200 + ["fault"] * 200, "valve": u[:, 0],
                                                "volts": y[:, 0], "flow": y[:, 1]})
    spec = tmp_path / "two.jmlg"
    argv = ["learn", "--output", "volts,flow", "--input", "valve", "--order", "1", "--catch-all", "none", "-o", str(spec)]
    for name in model.modes:
        argv += ["--mode", f"{name}={tmp_path / 'run0.csv'}", "--mode", f"{name}={tmp_path / 'run1.csv'}"]
    assert main(argv) == 0
    progress = [line for line in capsys.readouterr().err.splitlines() if line.startswith("learned mode")]
    assert [line.split(" iterations")[0].rsplit(" ", 1)[0] for line in progress] == [
        "learned mode 1 of 2, normal: ARX(1,1,0), EM", "learned mode 2 of 2, fault: ARX(1,1,0), EM"]
    assert main(argv + ["--quiet", "--max-iter", "2"]) == 0 and "learned mode" not in capsys.readouterr().err
    learned = jmlgdsl.load(spec)
    assert learned.outputs == ("volts", "flow") and learned.states == ("volts_lag1", "flow_lag1")
    assert learned.modes == ("normal", "fault") and np.allclose(learned.p0, [0.99, 0.01])
    assert main(["check", str(spec)]) == 0
    capsys.readouterr()
    assert main(["run", str(spec), str(tmp_path / "run0.csv"), "--filter", "imm"]) == 0
    out = capsys.readouterr().out
    error = float(out.split("diagnosis error: ")[1].split(" %")[0])
    assert error < 5  # the two modes differ by far more than the noise


def test_a_file_without_rows_of_the_mode_is_refused(runs, tmp_path, capsys):
    model, sims = runs
    s = sims["normal"][0]
    write_columns(tmp_path / "n.csv", {"mode": ["normal"] * 200, "valve": s.u[:, 0], "volts": s.y[:, 0],
                                       "flow": s.y[:, 1]})
    assert main(["learn", "--output", "volts,flow", "--input", "valve", "--order", "1",
                 "--mode", f"normal={tmp_path / 'n.csv'}", "--mode", f"fault={tmp_path / 'n.csv'}"]) == 2
    assert "no rows of mode 'fault'" in capsys.readouterr().err
