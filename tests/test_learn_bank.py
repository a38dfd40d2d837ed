"""Spec -> simulate each mode under a PRBS -> learn -> the learned bank matches the truth within
its standard errors and diagnoses nearly as well as the true bank; the `jmlgdsl learn` command."""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import jmlgdsl
from jmlgdsl.cli import main
from jmlgdsl.data import write_columns
from jmlgdsl.errors import JmlgError
from jmlgdsl.infer import filter as run_filter
from jmlgdsl.learn import bank, figures, learn
from jmlgdsl.learn.em import forward
from jmlgdsl.learn.prbs import prbs
from jmlgdsl.learn.statespace import StateSpace
from jmlgdsl.simulation.linear import simulate

DRYER = Path(__file__).resolve().parents[1] / "specs" / "dryer.jmlg"
SEQUENCE_1 = "1-70:normal,71-238:fan,239-365:grill,366-513:normal,514-705:grill,706-1000:fan"


@pytest.fixture(scope="module")
def dryer():
    return jmlgdsl.load(DRYER)


@pytest.fixture(scope="module")
def experiments(dryer):
    """One PRBS experiment per mode: 5 cells clocked every 16 samples (longest pulse 80 s, two to
    three time constants), 15 +- 5 %, 496 samples."""
    u = prbs(5, clock=16, amplitude=5.0, around=15.0)[:, None]
    return {name: bank.Experiment(simulate(dryer, modes=[name] * len(u), u=u, seed=20 + k).y, u, name)
            for k, name in enumerate(dryer.modes)}


@pytest.fixture(scope="module")
def learned(experiments):
    # At this tolerance EM's remaining steps move the estimates by under 2 % of their standard
    # errors (checked against tol 1e-9, about 950 iterations, when the test was written).
    return bank.learn_modes(experiments, order=(1, 1, 0), max_iter=500, tol=1e-6)


def first_order(theta, mode: StateSpace) -> StateSpace:
    """The first-order mode for (pole, gain, offset, log process sd, log measurement sd)."""
    a, k, c, log_w, log_v = theta
    return mode.replace(A=np.array([[a]]), F=np.array([[k * (1 - a)]]), f=np.array([c]),
                        Q=np.array([[np.exp(2 * log_w)]]), R=np.array([[np.exp(2 * log_v)]]))


def standard_errors(mode: StateSpace, y, u) -> np.ndarray:
    """Standard errors of (pole, gain, offset, log sd_w, log sd_v) from the observed information:
    the inverse of minus the log-likelihood's Hessian (central differences) at the estimate."""
    theta = np.array([mode.A[0, 0], mode.gain()[0, 0], mode.f[0], 0.5 * np.log(mode.Q[0, 0]),
                      0.5 * np.log(mode.R[0, 0])])
    h = 1e-4 * np.maximum(np.abs(theta), 0.1)

    def ll(step):
        return forward(first_order(theta + step, mode), y, u).loglik

    n = len(theta)
    H = np.empty((n, n))
    for i in range(n):
        for j in range(i, n):
            ei, ej = np.eye(n)[i] * h[i], np.eye(n)[j] * h[j]
            H[i, j] = H[j, i] = (ll(ei + ej) - ll(ei - ej) - ll(ej - ei) + ll(-ei - ej)) / (4 * h[i] * h[j])
    return np.sqrt(np.diag(np.linalg.inv(-H)))


def test_em_likelihood_never_decreases(learned):
    for lm in learned:
        assert lm.em.converged
        assert np.all(np.diff(lm.em.loglik) >= -1e-9 * np.abs(lm.em.loglik[:-1]))


def test_learned_modes_match_the_truth_within_their_standard_errors(dryer, learned):
    """Pole, steady-state gain and both noise sds of every mode within 4 standard errors of the
    truth (16 comparisons: a 4-sigma miss has probability about 1e-3 in all)."""
    for k, lm in enumerate(learned):
        m = lm.model
        assert np.array_equal(m.C, [[1.0]])
        se = standard_errors(m, lm.experiment.y, lm.experiment.u)
        true_gain = dryer.F[k, 0, 0] / (1 - dryer.A[k, 0, 0])
        assert abs(m.A[0, 0] - dryer.A[k, 0, 0]) < 4 * se[0], lm.name
        assert abs(m.gain()[0, 0] - true_gain) < 4 * se[1], lm.name
        assert abs(0.5 * np.log(m.Q[0, 0]) - np.log(dryer.B[k, 0, 0])) < 4 * se[3], lm.name
        assert abs(0.5 * np.log(m.R[0, 0]) - np.log(dryer.D[k, 0, 0])) < 4 * se[4], lm.name
        assert se[1] < 0.05 * true_gain  # the experiment is informative: gains known to 5 %


def test_validation_of_the_true_structure(learned):
    """Free run misses only the process-noise drift (sd about 0.2 degC) and the 0.05 degC sensor
    noise against an output swinging several degrees: a fit near 95 %. With the true structure a
    mode fails the residual tests about 5 % of the time, so two failures in four happen about 1 %."""
    for lm in learned:
        assert lm.validation.fit[0] > 90
        assert lm.validation.autocorr.shape == (1, 25) and lm.validation.crosscorr.shape == (1, 1, 26)
    assert sum(lm.validation.passed for lm in learned) >= 3


def test_learned_bank_diagnoses_nearly_as_well_as_the_true_bank(dryer, learned):
    model = bank.assemble(learned, P=dryer.P, p0=dryer.p0, operating_input=dryer.input_defaults,
                          name="dryer", dt=dryer.dt, inputs=dryer.inputs, outputs=dryer.outputs,
                          input_defaults=dryer.input_defaults)
    sim = simulate(dryer, modes=SEQUENCE_1, seed=7)
    true_error = run_filter(dryer, sim.y, sim.u, algorithm="imm").diagnosis_error(sim.modes)
    learned_error = run_filter(model, sim.y, sim.u, algorithm="imm").diagnosis_error(sim.modes)
    assert true_error < 5
    assert learned_error <= true_error + 2


def test_assembled_modes_start_at_their_steady_state_unless_they_integrate(learned):
    stable = learned[0]
    integrating = replace(stable, name="tank", mode=replace(stable.mode, Phi=np.ones((1, 1))))
    model = bank.assemble([stable, integrating], P=np.eye(2), p0=[0.5, 0.5], operating_input=[15.0])
    assert model.mu0[0] == pytest.approx(stable.model.steady_state([15.0]))
    assert model.mu0[1] == stable.mode.mu0
    m = stable.model
    stationary = m.Q[0, 0] / (1 - m.A[0, 0] ** 2)
    assert model.Sigma0[0, 0] == pytest.approx(stationary)  # the stable mode's spread is the wider
    assert np.allclose(model.B[:, 0, 0], np.sqrt(m.Q[0, 0])) and np.allclose(model.D[:, 0, 0], np.sqrt(m.R[0, 0]))
    assert model.states == ("y1_lag1",)


def test_default_transitions_stay_and_share_the_rest():
    P = bank.default_transitions(4, 0.97)
    assert np.allclose(P, [[0.97, 0.01, 0.01, 0.01], [0.01, 0.97, 0.01, 0.01],
                           [0.01, 0.01, 0.97, 0.01], [0.01, 0.01, 0.01, 0.97]])
    assert np.array_equal(bank.default_transitions(1, 0.9), [[1.0]])


def test_fopdt_structure_from_step_tests(dryer, tmp_path):
    u = np.full((400, 1), 15.0)
    u[40:] = 20.0
    exps = {name: bank.Experiment(simulate(dryer, modes=[name] * 400, u=u, seed=40 + k).y, u, name)
            for k, name in enumerate(dryer.modes[:2])}
    learned = bank.learn_modes(exps, fopdt=True, max_iter=50)
    # One 5 % step with the process noise drifting about 0.2 degC pins the gain to a standard error
    # of about 0.05 degC/% (observed information, computed as in the test above): allow 4 of them.
    for k, lm in enumerate(learned):
        assert lm.fopdt.delay == 0 and lm.structure.startswith("FOPDT gain")
        assert np.all(np.diff(lm.em.loglik) >= -1e-9 * np.abs(lm.em.loglik[:-1]))
        true_gain = dryer.F[k, 0, 0] / (1 - dryer.A[k, 0, 0])
        assert lm.fopdt.gain == pytest.approx(true_gain, abs=0.2)
        assert lm.model.gain()[0, 0] == pytest.approx(true_gain, abs=0.2)
    png = figures.plot_step(learned[0].fopdt, learned[0].experiment.y, tmp_path / "step.png")
    assert png.read_bytes().startswith(b"\x89PNG")


def test_missing_outputs_are_allowed(dryer, experiments):
    e = experiments["fan"]
    y = e.y.copy()
    y[np.random.default_rng(3).random(len(y)) < 0.1] = np.nan
    y[0] = np.nan
    (lm,) = bank.learn_modes({"fan": bank.Experiment(y, e.u, "fan.csv")}, order=(1, 1, 0))
    assert np.all(np.diff(lm.em.loglik) >= -1e-9 * np.abs(lm.em.loglik[:-1]))
    true_gain = dryer.F[1, 0, 0] / (1 - dryer.A[1, 0, 0])
    # The full experiment gives this gain a standard error of about 0.016; 4 of them, a little wider.
    assert lm.model.gain()[0, 0] == pytest.approx(true_gain, abs=0.07)
    assert np.isnan(lm.validation.residuals[0, 0]) and lm.validation.fit[0] > 75


def test_modes_without_inputs_are_autoregressive():
    """Two level regimes, x_t = a x_{t-1} + (1 - a) level + w_t seen through sensor noise. An AR(1)
    pole from N samples has standard error about sqrt((1 - a^2) / N), 0.02 here; sensor noise
    widens it a little, so 0.1 allows about four."""
    rng = np.random.default_rng(8)
    exps = {}
    for name, a, level in (("low", 0.9, 10.0), ("high", 0.7, 20.0)):
        x, y = level, np.empty((400, 1))
        for t in range(400):
            x = a * x + (1 - a) * level + 0.1 * rng.standard_normal()
            y[t] = x + 0.05 * rng.standard_normal()
        exps[name] = bank.Experiment(y, np.zeros((400, 0)), name)
    low, high = bank.learn_modes(exps, order=(1, 1, 0))
    assert low.structure == "AR(1)" and "gain" not in low.summary()
    assert low.model.poles()[0] == pytest.approx(0.9, abs=0.1)
    assert high.model.poles()[0] == pytest.approx(0.7, abs=0.1)
    model = bank.assemble([low, high], P=np.eye(2), p0=[0.5, 0.5])
    assert model.nu == 0 and model.mu0[:, 0] == pytest.approx([10.0, 20.0], abs=0.5)


def test_step_fit_errors_name_the_experiment(experiments):
    with pytest.raises(jmlgdsl.DataError, match="^fan: a step test needs an input that changes exactly once"):
        bank.learn_modes({"fan": experiments["fan"]}, fopdt=True)


def test_an_input_that_never_changes_is_refused(experiments):
    fan = experiments["fan"]
    still = bank.Experiment(fan.y, np.full_like(fan.u, 15.0), "still.csv")
    with pytest.raises(jmlgdsl.DataError, match="^still.csv: input 1 never changes"):
        bank.learn_modes({"fan": fan, "still": still}, order=(1, 1, 0))


def write_experiments(dryer, experiments, folder):
    paths = {}
    for name, e in experiments.items():
        paths[name] = folder / f"{name}.csv"
        write_columns(paths[name], {"time": np.arange(1, len(e.u) + 1.0), "current": e.u[:, 0],
                                    "temp": e.y[:, 0]})
    return paths


def test_cli_learn_writes_a_spec_that_loads_checks_and_runs(dryer, experiments, tmp_path, capsys):
    paths = write_experiments(dryer, experiments, tmp_path)
    spec = tmp_path / "learned.jmlg"
    figures = tmp_path / "figures"
    argv = ["learn", "--template", str(DRYER), "--order", "1", "-o", str(spec), "--figures", str(figures)]
    for name in reversed(dryer.modes):  # the template's order wins
        argv += ["--mode", f"{name}={paths[name]}"]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "normal: ARX(1,1,0), EM" in out and "fan_grill:" in out
    text = spec.read_text()
    assert text.startswith("# Learned by jmlgdsl learn from ")
    model = jmlgdsl.load(spec)
    assert model.modes == dryer.modes and model.descriptions == dryer.descriptions
    assert np.array_equal(model.P, dryer.P)
    assert model.engineering_units == dryer.engineering_units
    assert sorted(p.name for p in figures.iterdir()) == sorted(f"validation_{m}.png" for m in dryer.modes)
    assert main(["check", str(spec)]) == 0
    assert main(["run", str(spec), str(paths["fan"]), "--filter", "imm"]) == 0


def test_cli_learn_without_template_writes_the_spec_to_standard_output(dryer, experiments, tmp_path, capsys):
    paths = write_experiments(dryer, dict(list(experiments.items())[:2]), tmp_path)
    assert main(["learn", "--output", "temp", "--input", "current", "--order", "auto", "--max-order", "2",
                 "--stay", "0.95", "--name", "dryer2"] + [f"--mode={n}={p}" for n, p in paths.items()]) == 0
    captured = capsys.readouterr()
    err = captured.err.splitlines()
    # what cross-validation chose, each mode as learned, the catch-all's scale; then the summary
    assert err[0].startswith("the other modes relative to normal, or each on its own") and "so each on its own" in err[0]
    assert [line.split(":")[0] for line in err[1:3]] == ["learned mode 1 of 2, normal", "learned mode 2 of 2, fan"]
    assert err[3].startswith("catch-all noise scale ")
    assert err[4].startswith("normal: ARX(1,1,0)")  # the summary goes beside the spec
    spec = tmp_path / "two.jmlg"
    spec.write_text(captured.out)
    model = jmlgdsl.load(spec)
    assert model.nx == 1  # first order, as the plant is
    assert model.name == "dryer2" and model.modes == tuple(paths) + ("anomaly",) and model.states == ("temp_lag1",)
    assert np.allclose(model.P, [[0.95, 0.025, 0.025], [0.025, 0.95, 0.025], [0.025, 0.025, 0.95]])
    assert np.allclose(model.p0, [0.99, 0.005, 0.005])  # the first mode is the healthy one
    assert "initial     normal 0.99, otherwise uniform" in captured.out


@pytest.mark.parametrize("argv, message", [
    (["--mode", "normal"], "--mode takes NAME=CSV"),
    (["--mode", "a=x.csv", "--order", "0"], "order must be auto, N or NA,NB,NK"),
    (["--mode", "a=x.csv"], "name the outputs (the output columns), or give a template"),
    (["--mode", "normal=x.csv", "--template", str(DRYER)], "give one experiment for each"),
])
def test_cli_learn_user_errors(argv, message, capsys):
    assert main(["learn"] + argv) == 2
    assert message in capsys.readouterr().err


@pytest.mark.parametrize("argv, message", [
    (["--max-order", "0"], "argument --max-order: must be at least 1, not 0"),
    (["--max-delay", "-1"], "argument --max-delay: must be at least 0, not -1"),
    (["--max-iter", "-1"], "argument --max-iter: must be at least 0, not -1"),
    (["--dt", "0"], "argument --dt: must be positive, not 0"),
    (["--dt", "nan"], "argument --dt: expected a finite number, not 'nan'"),
    (["--stay", "2"], "argument --stay: must be a probability (0 to 1), not 2"),
    (["--initial", "x"], "argument --initial: expected a number, not 'x'"),
])
def test_cli_learn_refuses_options_out_of_range_by_name(argv, message, capsys):
    with pytest.raises(SystemExit) as done:
        main(["learn", "--mode", "a=x.csv", "--output", "y"] + argv)
    assert done.value.code == 2 and capsys.readouterr().err.endswith(f"error: {message}\n")


@pytest.mark.parametrize("options, message", [
    (dict(max_order=0), "max_order must be at least 1, not 0"),
    (dict(max_delay=-1), "max_delay must be at least 0, not -1"),
    (dict(max_iter=-1), "max_iter must be at least 0, not -1"),
    (dict(dt=0.0), "dt must be a positive number of seconds, not 0.0"),
    (dict(stay=2.0), "stay must be a probability, not 2.0"),
])
def test_learn_refuses_values_out_of_range_by_keyword(options, message):
    with pytest.raises(JmlgError, match=f"^{message}$"):
        learn({"a": "x.csv"}, outputs=("y",), **options)


def test_learn_is_the_command_as_a_library(dryer, experiments, tmp_path, capsys):
    """`learn` returns the spec `jmlgdsl learn` writes and the report it prints, and draws its figures."""
    paths = write_experiments(dryer, experiments, tmp_path)
    spec = tmp_path / "command.jmlg"
    assert main(["learn", "--template", str(DRYER), "--order", "1", "--max-iter", "5", "-q", "-o", str(spec)]
                + [f"--mode={n}={p}" for n, p in paths.items()]) == 0
    printed = capsys.readouterr().out
    learned = learn({n: str(p) for n, p in paths.items()}, dryer, order=1, max_iter=5)
    assert learned.text == spec.read_text() and printed == f"wrote {spec}\n{learned.report()}\n"
    learned.write(tmp_path / "library.jmlg")
    assert (tmp_path / "library.jmlg").read_text() == learned.text
    drawn = learned.write_figures(tmp_path / "figures")
    assert [p.name for p in drawn] == [f"validation_{m}.png" for m in dryer.modes]
    assert all(p.read_bytes().startswith(b"\x89PNG") for p in drawn)


def test_learn_takes_experiments_as_arrays(dryer, experiments):
    learned = learn(experiments, dryer, order=(1, 1, 0), max_iter=5)
    assert learned.text.startswith("# Learned by jmlgdsl learn from normal, fan, grill, fan_grill\n"
                                   "# Structure: ARX order 1,1,0; EM up to 5 iterations")
    direct = bank.learn_modes(experiments, order=(1, 1, 0), max_iter=5)
    assert learned.report().splitlines() == [lm.summary() for lm in direct]
    with pytest.raises(jmlgdsl.JmlgError, match="plant dryer has modes normal, fan, grill, fan_grill; give one "
                                               "experiment for each"):
        learn({"normal": experiments["normal"]}, dryer)
