"""Unknowns with priors in a spec, and `fit`: the language, the exact labelled likelihood, the
curvature, the estimates on simulated data and the fitted spec written back."""

import math
import warnings

import numpy as np
import pytest
from scipy.stats import multivariate_normal
from conftest import ROOT
from test_language_gaps import TANK  # a one-tank ODE plant with a sag mode that sets its own input

import jmlgdsl
from jmlgdsl.cli import main
from jmlgdsl.compile import compile_text
from jmlgdsl.data import Data
from jmlgdsl.errors import SpecError, SpecWarning
from jmlgdsl.fitting import Family, FitError, fit
from jmlgdsl.fitting.estimate import _covariance, _look_alike, hessian
from jmlgdsl.fitting.rewrite import fitted_text
from jmlgdsl.fitting.likelihood import labelled_loglik
from jmlgdsl.infer import filter as run_filter
from jmlgdsl.infer.engine import FilterError
from jmlgdsl.lang.check import check
from jmlgdsl.lang.parse import parse_text

DRYER = """plant dryer
sample 1 s
input  current [%] = 15
output temp [degC]                 # air temperature
param g ~ LogNormal(log(2), 0.3), tau ~ LogNormal(log(30), 0.3)   # unknown gain and time constant
modes normal, fan: g ~ Normal(1.5, 0.3)
initial     normal 0.9, otherwise uniform
transitions stay 0.99, otherwise uniform
noise process 0.05, measurement ~ HalfNormal(0.1)
mode normal: temp ~ fopdt(current, gain g, tau tau s, at current 15 -> 50)
mode fan:    temp ~ fopdt(current, gain g, tau tau s, at current 15 -> 44)
"""
TRUTH = {"g": 1.94, "tau": 30.45, "fan.g": 1.44, "noise.measurement": 0.05}


def quiet(function, *args, **kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SpecWarning)
        return function(*args, **kwargs)


def truth_model():
    plant_text = DRYER
    for name, value in {"g ~ LogNormal(log(2), 0.3)": "g = 1.94", "tau ~ LogNormal(log(30), 0.3)": "tau = 30.45",
                        "g ~ Normal(1.5, 0.3)": "g = 1.44", "measurement ~ HalfNormal(0.1)": "measurement 0.05"}.items():
        plant_text = plant_text.replace(name, value)
    return compile_text(plant_text)


def simulated(T=600, seed=1, labelled=True):
    rng = np.random.default_rng(seed)
    u = 15 + 3 * np.sign(np.sin(np.arange(T) * 2 * np.pi / 80))[:, None]  # a square wave: gains and lags show
    sim = jmlgdsl.simulate(truth_model(), seed=rng, modes=f"1-{T // 2}:normal,{T // 2 + 1}-{T}:fan", u=u)
    return Data(time=None, y=sim.y, u=sim.u, modes=sim.modes if labelled else None, source="sim.csv")


# ------------------------------------------------------------------ the language

def test_each_unknown_is_named_for_where_it_is_written_and_runs_at_its_prior_median():
    with pytest.warns(SpecWarning) as caught:
        model = compile_text(DRYER, "dryer.jmlg")
    messages = [str(w.message) for w in caught]
    assert [m.split(": warning: ")[1].split(" is unknown")[0] for m in messages] == \
        ["g", "tau", "fan.g", "noise.measurement"]
    assert messages[0].startswith("dryer.jmlg:5:7: warning: g is unknown: the spec runs with its prior's median 2 "
                                  "(LogNormal(0.693147, 0.3)); fit it to data with 'jmlgdsl fit'")
    a = math.exp(-1 / 30)  # tau at its median 30 s
    np.testing.assert_allclose(model.A[:, 0, 0], [a, a])
    np.testing.assert_allclose(model.F[:, 0, 0], [2 * (1 - a), 1.5 * (1 - a)])  # gains at their medians
    np.testing.assert_allclose(model.D[:, 0, 0], 0.1 * 0.6744897501960817)  # HalfNormal's median


def test_values_for_the_unknowns_give_the_model_with_those_numbers():
    plant, report = check(parse_text(DRYER), TRUTH)
    assert not report.warnings and not report.errors
    assert [u.name for u in plant.unknowns] == list(TRUTH)
    np.testing.assert_allclose(Family(parse_text(DRYER)).model(list(TRUTH.values())).F, truth_model().F)
    with pytest.raises(ValueError, match="no unknown named 'gg'; did you mean 'g'"):
        check(parse_text(DRYER), {**TRUTH, "gg": 1.0})
    with pytest.raises(ValueError, match="no value given for the unknown 'tau'"):
        check(parse_text(DRYER), {"g": 1.0})


@pytest.mark.parametrize("written, message, column", [
    ("param g ~ LogNormall(0, 1)", "unknown prior 'LogNormall': a parameter or noise level takes one of Normal, "
                                   "LogNormal, HalfNormal, Uniform; did you mean 'LogNormal'?", 11),
    ("param g ~ Normal(1, -2)", "the sd of Normal must be positive (got -2)", 11),
    ("param g ~ Uniform(low 1, high 2)", "Uniform takes its arguments in order: Uniform(low, high)", 11),
    ("param g ~ Normal(1, nope)", "unknown name 'nope' in an argument of Normal", 21),
])
def test_a_prior_that_makes_no_distribution_is_located(written, message, column):
    text = DRYER.replace("param g ~ LogNormal(log(2), 0.3)", written)
    with pytest.raises(SpecError) as info:
        compile_text(text, "dryer.jmlg")
    d = info.value.diagnostics[0]
    assert (d.line, d.column) == (5, column) and d.message.startswith(message)


def test_an_unknown_given_two_priors_is_an_error():
    text = DRYER + "mode fan { g ~ Normal(1.5, 0.3) }\n"
    with pytest.raises(SpecError) as info:
        quiet(compile_text, text.replace("mode fan:    temp ~ fopdt(current, gain g, tau tau s, at current 15 -> 44)\n",
                                         ""), "dryer.jmlg")
    assert "fan.g already has a prior at line 6" in [d.message for d in info.value.diagnostics]


def test_a_mode_block_may_give_an_override_a_prior_and_a_like_mode_shares_it():
    text = """plant p
sample 1 s
output y
state x
param a ~ Uniform(0, 1)
modes normal, slow, slower
transitions stay 0.99, otherwise uniform
noise process 0.1, measurement 0.1
mode normal { x[t] ~ Normal(a * x[t-1], 0.1); y ~ Normal(x[t], 0.1) }
mode slow like normal { a ~ Uniform(0.5, 1) }
mode slower like slow
"""
    plant, report = check(parse_text(text), {"a": 0.3, "slow.a": 0.8})
    assert not report.errors
    assert [u.name for u in plant.unknowns] == ["a", "slow.a"]
    assert [m.params["a"] for m in plant.modes] == [0.3, 0.8, 0.8]
    np.testing.assert_allclose(Family(parse_text(text)).model([0.3, 0.8]).A[:, 0, 0], [0.3, 0.8, 0.8])


def test_a_variable_defined_twice_in_one_block_is_an_error():
    text = DRYER.replace("mode fan:    temp ~", "mode fan { temp ~ Normal(50, 1)\n temp ~") + "}\n"
    with pytest.raises(SpecError) as info:
        quiet(compile_text, text, "dup.jmlg")
    d = info.value.diagnostics[0]
    assert d.message == "temp is already defined in mode 'fan' at line 11; a mode block defines each variable once"
    assert (d.line, d.column) == (12, 2)


# ------------------------------------------------------------------ the likelihood

def test_the_labelled_likelihood_is_the_joint_gaussian_density_of_the_outputs():
    """With the modes known, y_1:T is jointly Gaussian: its density, computed from the stacked mean and
    covariance of the whole record, must equal the Kalman filter's through the labelled modes."""
    model = quiet(Family(parse_text(DRYER)).model, [1.9, 25.0, 1.4, 0.2]).replace(Sigma0=np.array([[0.3]]))
    T, rng = 6, np.random.default_rng(0)
    modes = np.array([0, 0, 1, 1, 1, 0])
    u = rng.uniform(12, 18, (T, 1))
    y = rng.normal(50, 1, (T, 1))
    y[3] = np.nan  # one reading missing
    # x_t = a_k x_{t-1} + b_t + w_t: mean and covariance of x_1..x_T, then y = x + v
    A, Q, R = model.A[modes, 0, 0], model.Q[modes, 0, 0], model.R[modes, 0, 0]
    b = model.F[modes, 0, 0] * u[:, 0] + model.f[modes, 0]
    mean, var0 = model.mu0[modes[0], 0], model.Sigma0[0, 0]
    M = np.zeros((T, T + 1))  # x_t as a combination of x_0 and w_1..w_T
    m = np.zeros(T)
    prev_row, prev_mean = np.eye(T + 1)[0], mean
    for t in range(T):
        prev_row = A[t] * prev_row + np.eye(T + 1)[t + 1]
        prev_mean = A[t] * prev_mean + b[t]
        M[t], m[t] = prev_row, prev_mean
    assert (model.C == 1).all() and (model.G == 0).all()  # the block's output reads its state
    cov = M @ np.diag(np.r_[var0, Q]) @ M.T + np.diag(R)
    measured = ~np.isnan(y[:, 0])
    mean_y = m + model.g[modes, 0]
    expected = multivariate_normal(mean_y[measured], cov[np.ix_(measured, measured)]).logpdf(y[measured, 0])
    chain = math.log((model.p0 @ model.P)[0]) + sum(math.log(model.P[i, j]) for i, j in zip(modes[:-1], modes[1:]))
    assert labelled_loglik(model, y, u, modes) == pytest.approx(expected + chain, rel=1e-12)


def test_on_a_long_labelled_record_the_settled_gain_changes_nothing():
    """Past the first steps the filter keeps its settled gain: the likelihood must still be that of an
    IMM with one mode (exactly a Kalman filter) on the same record."""
    model = quiet(Family(parse_text(DRYER)).model, list(TRUTH.values()))
    single = model.replace(A=model.A[:1], B=model.B[:1], C=model.C[:1], D=model.D[:1], F=model.F[:1],
                           G=model.G[:1], f=model.f[:1], g=model.g[:1], mu0=model.mu0[:1], P=np.ones((1, 1)),
                           p0=np.ones(1), modes=["normal"], outlier_gate=np.full(1, np.inf), descriptions={})
    data = simulated(400)
    y = data.y.copy()
    y[200] = np.nan
    kalman = run_filter(single, y, data.u).loglik
    assert labelled_loglik(single, y, data.u, np.zeros(400, int)) == pytest.approx(kalman, rel=1e-12)


# ------------------------------------------------------------------ the estimate

def test_the_curvature_of_a_quadratic_is_found_exactly():
    H_true = np.array([[4.0, 1.0, 0.5], [1.0, 3.0, -0.2], [0.5, -0.2, 0.1]])
    centre = np.array([0.3, -1.0, 2.0])

    def f(z):
        d = z - centre
        return 0.5 * d @ H_true @ d

    H, gradient = hessian(f, centre, f(centre))
    np.testing.assert_allclose(H, H_true, rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(gradient, 0, atol=1e-9)


def test_modes_alike_where_the_fit_starts_are_named_for_unlabelled_data():
    text = DRYER.replace("fan: g ~ Normal(1.5, 0.3)", "fan: g ~ LogNormal(log(2), 0.3)") \
        .replace("at current 15 -> 44", "at current 15 -> 50")
    family = Family(parse_text(text))
    assert _look_alike(family.model(family.medians())) == [
        "at the priors' medians modes 'normal' and 'fan' are the same model: data without a mode column cannot say "
        "which is which, and the fit may swap or merge them; give their unknowns priors with different medians, "
        "or label some of the data"]
    assert _look_alike(Family(parse_text(DRYER)).model(Family(parse_text(DRYER)).medians())) == []


def test_a_flat_or_failed_curvature_leaves_those_unknowns_without_a_standard_error():
    flat = np.array([[1.0, 1.0, 0.0], [1.0, 1.0, 0.0], [0.0, 0.0, 4.0]])  # only a + b is determined
    cov, notes = _covariance(flat, ["a", "b", "c"])
    assert notes == ["the data do not determine a and b: the posterior is flat along a combination of them "
                     "(fix one, or give it a narrower prior)"]
    assert np.isnan(cov[:2]).all() and cov[2, 2] == pytest.approx(0.25)
    failed = np.array([[4.0, np.nan], [np.nan, 1.0]])
    cov, notes = _covariance(failed, ["a", "b"])
    assert notes == ["no standard error for a, b: the model cannot be built just beside the estimate"]
    assert np.isnan(cov).all()


@pytest.fixture(scope="module")
def fitted():
    return fit(parse_text(DRYER, "dryer.jmlg"), simulated())


def test_the_fit_recovers_every_unknown_within_three_standard_errors(fitted):
    for name, true in TRUTH.items():
        i = fitted.names.index(name)
        assert abs(fitted.estimate[i] - true) < 3 * fitted.se[i], name
    assert fitted.loglik > fitted.loglik_start
    assert not fitted.notes


def test_the_fitted_spec_keeps_the_text_and_compiles_to_the_fitted_model(fitted):
    text = fitted.text
    assert text.startswith("# Fitted by 'jmlgdsl fit' to sim.csv: log-likelihood ")
    g, tau = fitted.estimate[:2]
    assert f"param g = {g:.10g}, tau = {tau:.10g}   # unknown gain and time constant\n" \
           f"    # fitted g = {g:.4g} ± {fitted.se[0]:.2g}, prior LogNormal(log(2), 0.3)\n" \
           f"    # fitted tau = {tau:.4g} ± {fitted.se[1]:.2g}, prior LogNormal(log(30), 0.3)\n" in text
    assert "output temp [degC]                 # air temperature" in text
    assert f"noise process 0.05, measurement {fitted.estimate[3]:.10g}\n    # fitted noise.measurement" in text
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no unknowns are left: no warnings
        model = compile_text(text)
    for name in ("A", "F", "f", "D", "mu0"):
        np.testing.assert_allclose(getattr(model, name), getattr(fitted.model, name), rtol=1e-9)


def test_a_line_of_many_unknowns_is_written_back_readably_and_reads_back_as_fitted():
    """Four priors on one line had come back as one line of about 400 characters: each fitted value's
    comment now has a line of its own, and the spec reads back with the fitted values."""
    path = ROOT / "examples" / "fit" / "dryer_physical.jmlg"
    spec = parse_text(path.read_text(), str(path))
    family = Family(spec)
    estimate = np.linspace(44.0, 56.0, len(family.unknowns))
    text = fitted_text(spec, family.unknowns, estimate, np.full(len(estimate), 0.05))
    assert {line for line in text.splitlines() if len(line) > 100} <= set(spec.lines)  # only the user's own
    assert ("param T_normal = 44, T_fan = 45.71428571, T_grill = 47.42857143, T_both = 49.14285714\n"
            "    # fitted T_normal = 44 ± 0.05, prior Normal(50, 5)\n"
            "    # fitted T_fan = 45.71 ± 0.05, prior Normal(50, 5)\n") in text
    again = parse_text(text, "fitted.jmlg")
    with pytest.raises(FitError, match="no unknowns"):
        Family(again)  # every prior became its value
    model, expected = compile_text(text), family.model(estimate)
    for name in ("A", "F", "f", "mu0", "D"):
        np.testing.assert_allclose(getattr(model, name), getattr(expected, name), rtol=1e-9)


def test_unknowns_the_data_cannot_tell_apart_or_do_not_inform_are_named():
    text = DRYER.replace("param g ~ LogNormal(log(2), 0.3)", "let gh = g * h\n"
                                                             "param h ~ LogNormal(0, 1), g ~ LogNormal(log(2), 0.3)") \
        .replace("gain g, tau tau s, at current 15 -> 50", "gain gh, tau tau s, at current 15 -> 50") \
        + "param spare ~ Normal(3, 1)   # nothing uses it\n"
    result = fit(parse_text(text), simulated(300))
    assert [note for note in result.notes if note.startswith("h and g are strongly correlated (-0.9")] != []
    assert "the data say little about spare: its estimate and standard error are mostly its prior's" in result.notes
    i = result.names.index("spare")
    assert result.estimate[i] == pytest.approx(3, abs=1e-3) and result.se[i] == pytest.approx(1, rel=1e-3)


def test_an_ode_plant_is_re_linearised_at_each_try_and_its_parameter_recovered(tmp_path):
    """Data from the integrated equations (k = 0.5); the spec with k unknown is fitted through its
    bank, re-linearised at each mode's steady state for every value tried."""
    truth = tmp_path / "tank.jmlg"
    truth.write_text(TANK)
    sim = quiet(jmlgdsl.simulate_nonlinear, str(truth), modes="1-300:normal,301-600:sag,601-900:normal", seed=2)
    data = Data(time=None, y=sim.y, u=sim.u, modes=sim.modes, source="tank.csv")
    result = fit(parse_text(TANK.replace("param  k = 0.5", "param  k ~ LogNormal(log(0.4), 0.3)")), data)
    (k,), (se,) = result.estimate, result.se
    assert abs(k - 0.5) < 3 * se and se < 0.01
    steady = (1.5 / k) ** 2  # the sag mode's level, where its bank was linearised: sqrt(h) = q / k
    assert result.model.mu0[1, 0] == pytest.approx(steady, rel=1e-9)


@pytest.mark.parametrize("name, unknowns, alike", [
    # the three fouling fractions share one prior: unfitted, the fouling modes are one model
    ("cstr10_unknown", ["k0", "U", "f1", "f2", "f3"], ["fouling2", "fouling3"]),
    ("dryer_unknown", [f"{kind}_{mode}" for mode in ("normal", "fan", "grill", "both") for kind in ("g", "tau")], []),
    ("dryer_physical", [f"T_{mode}" for mode in ("normal", "fan", "grill", "both")]
     + [f"tau_{mode}" for mode in ("normal", "fan", "grill", "both")], []),
])
def test_the_bundled_specs_with_unknowns_compile_warning_of_them(name, unknowns, alike):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        warnings.simplefilter("ignore", ResourceWarning)  # a file another test left open, collected now
        jmlgdsl.load(f"examples/fit/{name}.jmlg")
    messages = [str(w.message).split("warning: ")[1] for w in caught]
    assert [m.split(" is unknown")[0] for m in messages if " is unknown: " in m] == unknowns
    assert [m.split("'")[1] for m in messages if " is unknown: " not in m] == alike
    assert all("compiles to exactly the same model as mode 'fouling1'" in m for m in messages
               if " is unknown: " not in m)


def test_a_spec_without_unknowns_or_an_unknown_filter_cannot_be_fitted():
    with pytest.raises(FitError, match="the spec has no unknowns to fit; give a parameter or a noise level a prior"):
        jmlgdsl.fit("specs/dryer.jmlg", "examples/dryer_seq1.csv")  # the package's own name for fitting.fit
    with pytest.raises(FilterError, match="unknown filter 'kalman'; choose from pf, rbpf"):
        jmlgdsl.fit("examples/fit/dryer_physical.jmlg", "examples/dryer_seq1.csv", algorithm="kalman")


def test_more_starts_keep_the_highest_peak_and_repeat_with_the_seed():
    data = simulated(300)
    one = fit(parse_text(DRYER), data)
    three = fit(parse_text(DRYER), data, starts=3, seed=5, jobs=2)  # two starts at a time, in processes
    again = fit(parse_text(DRYER), data, starts=3, seed=5, jobs=1)  # one after the other, here
    np.testing.assert_array_equal(three.estimate, again.estimate)
    assert three.notes == again.notes
    best = [n for n in three.notes if n.startswith("the best of 3 starts (their log posteriors: ")]
    assert len(best) == 1
    peaks = [float(v) for v in best[0].split(": ")[1].rstrip(")").split(", ")]
    assert len(peaks) == 3 and peaks[0] == pytest.approx(one.loglik + sum(
        p.logpdf(v) for p, v in zip(one.priors, one.estimate)), rel=1e-7)
    assert three.loglik + sum(p.logpdf(v) for p, v in zip(three.priors, three.estimate)) == \
        pytest.approx(max(peaks), rel=1e-7)
    with pytest.raises(FitError, match="samples must be 0 or more and starts 1 or more, got 0 and 0"):
        fit(parse_text(DRYER), data, starts=0)
    with pytest.raises(FitError, match="jobs must be 1 or more, got 0"):
        fit(parse_text(DRYER), data, starts=2, jobs=0)


def test_posterior_draws_stay_in_the_support_and_repeat_with_the_seed():
    text = DRYER.replace("measurement ~ HalfNormal(0.1)", "measurement 0.05") \
        .replace("modes normal, fan: g ~ Normal(1.5, 0.3)", "modes normal, fan: g = 1.44")
    data = simulated(300)
    first = fit(parse_text(text), data, samples=60, seed=4)
    again = fit(parse_text(text), data, samples=60, seed=4)
    np.testing.assert_array_equal(first.samples, again.samples)
    assert first.samples.shape == (60, 2) and (first.samples > 0).all()
    assert 0.05 < first.acceptance < 0.95
    assert "posterior mean" in first.report()


# ------------------------------------------------------------------ the command

def test_the_command_writes_a_spec_that_checks_and_runs(tmp_path, capsys):
    spec, data, out = tmp_path / "dryer.jmlg", tmp_path / "data.csv", tmp_path / "fitted.jmlg"
    spec.write_text(DRYER)
    sim = simulated(300)
    data.write_text("current,temp,mode\n" + "".join(
        f"{u:g},{float(y)!r},{['normal', 'fan'][k]}\n" for u, y, k in zip(sim.u[:, 0], sim.y[:, 0], sim.modes)))
    assert main(["fit", str(spec), str(data), "-o", str(out), "-q"]) == 0
    err = capsys.readouterr().err
    assert err.splitlines()[0].split() == ["unknown", "prior", "estimate", "se", "prior", "median"]
    assert f"wrote {out}" in err
    assert main(["check", str(out)]) == 0
    assert main(["run", str(out), str(data)]) == 0
    assert main(["fit", str(spec), str(data), "--samples", "-1"]) == 2
    capsys.readouterr()
    assert main(["fit", str(spec), str(data), "-o", str(spec)]) == 2  # refused before any work
    assert "is also an input" in capsys.readouterr().err and spec.read_text() == DRYER
