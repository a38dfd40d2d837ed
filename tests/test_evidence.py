"""The evidence per sensor: chain-rule terms of hand-computed Gaussians and mixtures, adding up to the
log-likelihood ratio; against the posterior odds of every filter and against the exact filter; kept
with a lag; and `run --explain` with its report lines and table columns."""

from types import SimpleNamespace

import numpy as np
import pytest
from conftest import ROOT
from infer_models import random_model
from scipy.stats import multivariate_normal, norm

import jmlgdsl
from jmlgdsl import Model
from jmlgdsl.cli import main
from jmlgdsl.data import iter_rows, open_source
from jmlgdsl.diagnosis import Diagnosed, Diagnosis, Evidence, Kept, Options, Raised
from jmlgdsl.diagnosis.report import evidence_report
from jmlgdsl.diagnosis.evidence import chain_terms, mode_terms
from jmlgdsl.infer import ALGORITHMS, Filter
from jmlgdsl.infer.result import Predictive

LOG_2PI = np.log(2 * np.pi)
S = np.array([[4.0, 2.0], [2.0, 5.0]])  # Cholesky factor [[2, 0], [1, 2]]
LINV = np.array([[0.5, 0.0], [-0.25, 0.5]])


def test_the_terms_of_a_two_output_gaussian_are_its_chain_rule():
    # r = (2, 1): z = L^-1 r = (1, 0); y1 ~ N(0, 4), and y2 | y1 = 2 ~ N(2 * 2/4, 5 - 2 * 2/4) = N(1, 4)
    terms = chain_terms(np.array([2.0, 1.0]), LINV)
    assert terms == pytest.approx([-0.5 * (1 + LOG_2PI) - np.log(2), -0.5 * LOG_2PI - np.log(2)], abs=1e-15)
    assert terms[0] == pytest.approx(norm.logpdf(2.0, 0, 2)) and terms[1] == pytest.approx(norm.logpdf(1.0, 1, 2))
    assert terms.sum() == pytest.approx(multivariate_normal.logpdf([2.0, 1.0], cov=S), abs=1e-14)


def test_the_order_of_the_outputs_splits_the_same_total_differently():
    swapped = S[::-1, ::-1]
    first, second = chain_terms(np.array([2.0, 1.0]), LINV), chain_terms(np.array([1.0, 2.0]),
                                                                        np.linalg.inv(np.linalg.cholesky(swapped)))
    assert first.sum() == pytest.approx(second.sum(), abs=1e-14)
    assert second[0] == pytest.approx(norm.logpdf(1.0, 0, np.sqrt(5)))  # y2 first: given nothing
    assert not np.allclose(first, second[::-1])


def one_gaussian_per_mode(residuals, covariances, mask=(True, True, True)):
    """The Predictive of an imm-like step: mode k predicts the measured readings with residual
    residuals[k] and covariance covariances[k]; all modes equally likely before the row."""
    Linv = np.linalg.inv(np.linalg.cholesky(covariances))
    return Predictive(np.arange(len(residuals)), np.zeros(len(residuals)), np.array(residuals, float), Linv,
                      np.array(mask))


def test_the_evidence_adds_up_to_the_log_likelihood_ratio_against_the_best_healthy_mode():
    # modes: 0 and 1 healthy, 2 and 3 faulty; the middle output is not measured
    covs = np.array([S, 2 * S, S, np.diag([1.0, 9.0])])
    residuals = [[2.0, 1.0], [1.0, 1.0], [0.5, -0.5], [0.1, 3.0]]
    e = Evidence.of(one_gaussian_per_mode(residuals, covs, (True, False, True)), [False, False, True, True])
    density = [multivariate_normal.logpdf(r, cov=c) for r, c in zip(residuals, covs)]
    assert (e.mode, e.healthy) == (int(np.argmax(density[2:])) + 2, int(np.argmax(density[:2])))
    assert np.isnan(e.terms[1])
    assert e.total == np.nansum(e.terms)
    assert e.total == pytest.approx(density[e.mode] - density[e.healthy], abs=1e-13)
    assert e.terms[[0, 2]] == pytest.approx(chain_terms(np.array(residuals[e.mode]), np.linalg.inv(
        np.linalg.cholesky(covs[e.mode]))) - chain_terms(np.array(residuals[e.healthy]), np.linalg.inv(
            np.linalg.cholesky(covs[e.healthy]))), abs=1e-14)


def test_a_mixture_splits_by_the_chain_rule_of_the_mixture():
    # mode 1 holds two hypotheses weighing 1/4 and 3/4, with identity covariances
    residuals = np.array([[0.0, 0.0], [1.0, 2.0], [-1.0, 0.5]])
    predictive = Predictive(np.array([0, 1, 1]), np.log([1.0, 0.25, 0.75]), residuals, np.broadcast_to(np.eye(2),
                                                                                                   (3, 2, 2)),
                            np.array([True, True]))
    prior, terms = mode_terms(predictive, 2)
    assert prior == pytest.approx([0.0, 0.0], abs=1e-15)
    first = np.log(0.25 * norm.pdf(1.0) + 0.75 * norm.pdf(-1.0))
    both = np.log(0.25 * norm.pdf(1.0) * norm.pdf(2.0) + 0.75 * norm.pdf(-1.0) * norm.pdf(0.5))
    assert terms[1] == pytest.approx([first, both - first], abs=1e-14)
    assert terms[0] == pytest.approx([norm.logpdf(0.0)] * 2, abs=1e-15)


def test_a_mode_without_hypotheses_has_no_evidence():
    predictive = Predictive(np.array([1, 1]), np.zeros(2), np.zeros((2, 1)), np.ones((2, 1, 1)), np.array([True]))
    assert Evidence.of(predictive, [False, True]) is None  # no particle in the healthy mode
    assert Evidence.of(predictive, [True, False]) is None  # none in a faulty one


@pytest.mark.parametrize("algorithm", sorted(ALGORITHMS))
def test_the_evidence_is_the_factor_by_which_the_row_moved_the_odds_in_every_filter(algorithm):
    """log p(y_t | k) - log p(y_t | h) = log posterior odds of k against h - their log odds before the row."""
    rng = np.random.default_rng(4)
    model = random_model(rng, K=3, nx=2, ny=3)
    y = rng.normal(size=(6, 3))
    y[2, 1] = np.nan
    f = Filter(model, algorithm, seed=1)
    checked = 0
    for row in y:
        step = f.step(row, [1.0])
        prior, _ = mode_terms(f.engine.predictive, 3)
        e = Evidence.of(f.engine.predictive, [False, True, True])
        if e is None:  # a particle filter without a particle in the healthy mode
            continue
        odds = np.log(step.mode_posterior[e.mode] / step.mode_posterior[e.healthy])
        assert e.total == pytest.approx(odds - (prior[e.mode] - prior[e.healthy]), abs=1e-9)
        assert list(np.isnan(e.terms)) == list(np.isnan(row))
        checked += 1
    assert checked >= 4


def memoryless_model():
    """Three modes with A = 0: y_t under mode k is N(C_k f_k + g_k, C_k Q_k C_k' + R_k) whatever the
    past, so every filter's mode-conditional predictive is that Gaussian exactly."""
    rng = np.random.default_rng(8)
    K, nx, ny = 3, 2, 3
    P = np.full((K, K), 0.1) + 0.7 * np.eye(K)
    return Model.from_arrays(A=np.zeros((K, nx, nx)), B=0.5 * rng.normal(size=(K, nx, nx)),
                             C=rng.normal(size=(K, ny, nx)), D=0.3 * np.eye(ny) + 0.1 * rng.normal(size=(K, ny, ny)),
                             f=rng.normal(size=(K, nx)), g=rng.normal(size=(K, ny)), P=P, p0=np.full(K, 1 / K),
                             mu0=np.zeros((K, nx)), Sigma0=np.eye(nx), modes=("ok", "leak", "drift"))


def test_imm_and_the_exact_filter_give_the_evidence_of_the_true_predictive():
    model = memoryless_model()
    mean = (model.C @ model.f[:, :, None])[:, :, 0] + model.g
    cov = model.C @ model.Q @ np.swapaxes(model.C, 1, 2) + model.R
    rng = np.random.default_rng(9)
    y = mean[rng.integers(0, 3, size=7)] + rng.normal(size=(7, 3))
    imm, exact = Filter(model, "imm"), Filter(model, "exact")
    for row in y:
        imm.step(row)
        exact.step(row)
        a = Evidence.of(imm.engine.predictive, [False, True, True])
        b = Evidence.of(exact.engine.predictive, [False, True, True])
        density = [multivariate_normal.logpdf(row, mean[k], cov[k]) for k in range(3)]
        assert a.healthy == b.healthy == 0 and a.mode == b.mode
        assert a.total == pytest.approx(density[a.mode] - density[0], abs=1e-10)
        assert b.terms == pytest.approx(a.terms, abs=1e-10)
        # the first output's term is its own marginal: the ratio of two one-dimensional normals
        assert a.terms[0] == pytest.approx(norm.logpdf(row[0], mean[a.mode, 0], np.sqrt(cov[a.mode, 0, 0]))
                                           - norm.logpdf(row[0], mean[0, 0], np.sqrt(cov[0, 0, 0])), abs=1e-10)


DRYER = ROOT / "specs" / "dryer.jmlg"
DRYER_DATA = ROOT / "examples" / "dryer_seq1.csv"


def dryer_rows(model, count):
    with open_source(DRYER_DATA) as source:
        return [row for row, _ in zip(iter_rows(source, model, source.name), range(count))]


def test_a_row_smoothed_with_a_lag_keeps_the_evidence_of_its_filtering():
    model = jmlgdsl.load(DRYER)
    rows = dryer_rows(model, 120)
    runs = {}
    for lag in (0, 5):
        kept = Kept()
        Diagnosis(model, Options(lag=lag, explain=True), sinks=[kept]).run(rows)
        runs[lag] = kept.rows
    assert [d.step.t for d in runs[5]] == list(range(1, 121))
    for now, later in zip(runs[0], runs[5]):
        assert (now.evidence.mode, now.evidence.healthy, now.evidence.total) == \
            (later.evidence.mode, later.evidence.healthy, later.evidence.total)
    assert max(d.evidence.total for d in runs[0]) > 5  # the fan fault from row 71
    kept = Kept()
    Diagnosis(model, sinks=[kept]).run(rows[:3])
    assert [d.evidence for d in kept.rows] == [None] * 3


def test_run_explain_names_the_sensors_behind_each_alarm_and_adds_their_columns(tmp_path, capsys):
    plain, explained = tmp_path / "plain.csv", tmp_path / "explained.csv"
    assert main(["run", str(DRYER), str(DRYER_DATA), "-o", str(plain)]) == 0
    report = capsys.readouterr().out
    assert main(["run", str(DRYER), str(DRYER_DATA), "-o", str(explained), "--explain"]) == 0
    out = capsys.readouterr().out
    assert out.startswith(report.rsplit("time per step", 1)[0])
    lines = out.split("evidence behind the alarms raised")[1].splitlines()[1:]
    raised = int(report.split("): ")[1].split(" raised")[0])
    assert len(lines) == raised > 0
    first = lines[0]
    assert first.startswith("  t 72 (time 72): fan against normal, ") and first.endswith(" (100 %)")
    table = explained.read_text().splitlines()
    for a, b in zip(plain.read_text().splitlines(), table):  # the plain table, with two columns more
        assert b.startswith(a + ",") and b.count(",") == a.count(",") + 2
    assert table[0].endswith(",alarm,evidence_mode,evidence_temp")
    row = table[72].split(",")
    assert row[0] == "72" and row[-2] == "fan" and first.split(": temp ")[1].split(" ")[0] == f"{float(row[-1]):.2f}"


def test_the_report_lists_the_fewest_sensors_that_carry_the_total_largest_first():
    model = memoryless_model()
    raised = Raised(most=1)
    evidence = Evidence(2, 0, np.array([6.0, -1.0, 1.5]), 6.5)
    for t, alarm in enumerate([0, 1, 1, 0, 1], start=1):
        raised.collect(Diagnosed(SimpleNamespace(t=t), SimpleNamespace(time=t / 10), alarm, evidence))
    assert [d.step.t for d in raised.rows] == [2] and raised.more == 1
    assert evidence.carriers() == [(0, 6.0), (2, 1.5)]
    assert evidence_report(model, raised)[1:] == [
        "  t 2 (time 0.2): drift against ok, 6.50: y1 6.00 (92 %), y3 1.50 (23 %), 1 other output -1.00",
        "  \u2026 1 more alarm (see the evidence columns of the output CSV)"]


@pytest.mark.parametrize("spec", ["dryer", "cstr10"])
def test_the_evidence_of_many_units_at_once_is_each_unit_s_own_bit_for_bit(spec):
    from jmlgdsl.diagnosis import AlarmRule
    from jmlgdsl.diagnosis.prediction import predictive_sd

    model = jmlgdsl.load(str(ROOT / "specs" / f"{spec}.jmlg"))
    faulty = AlarmRule((model.modes[0],)).faulty_modes(model.modes)
    predictives, steps, inputs = [], [], []
    for seed in range(5):
        sim = jmlgdsl.simulate(model, 40, seed=seed)
        f = Filter(model, "imm")
        for t in range(39):
            step = f.step(sim.y[t], sim.u[t])
        steps.append(step)
        inputs.append(sim.u[39])
        predictives.append(f.engine.predictive)
    stacked = Predictive(predictives[0].mode, *(np.array([getattr(p, name) for p in predictives])
                                                 for name in ("log_weight", "residual", "Linv")), predictives[0].mask)
    for alone, together in zip((Evidence.of(p, faulty) for p in predictives), Evidence.of_units(stacked, faulty)):
        assert (alone.mode, alone.healthy, alone.total) == (together.mode, together.healthy, together.total)
        np.testing.assert_array_equal(alone.terms, together.terms)
    # the predictive band of many units at once: each unit's, to rounding (stacked products sum in another order)
    each = np.array([predictive_sd(model, s.mode_posterior, s.state_mean, s.state_cov, u) for s, u in zip(steps, inputs)])
    many = predictive_sd(model, np.array([s.mode_posterior for s in steps]), np.array([s.state_mean for s in steps]),
                         np.array([s.state_cov for s in steps]), np.array(inputs))
    np.testing.assert_allclose(many, each, rtol=1e-12, atol=0)
