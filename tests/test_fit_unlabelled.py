"""Fits to data without a mode column that start far from the truth, and fits that say they cannot be
trusted: the labelling rounds, the checks on the peak and its curvature, and `fit --strict`."""

import warnings
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
from test_fit import DRYER, simulated

import jmlgdsl
from jmlgdsl.cli import main
from jmlgdsl.compile import compile_text
from jmlgdsl.data import write_columns
from jmlgdsl.errors import SpecWarning
from jmlgdsl.fitting import Family
from jmlgdsl.fitting import labels as labels_module
from jmlgdsl.fitting.convergence import misfit, not_at_peak, unmoved
from jmlgdsl.fitting.estimate import released
from jmlgdsl.fitting.labels import label_rounds
from jmlgdsl.fitting.posterior import Cached, Posterior, bfgs
from jmlgdsl.fitting.likelihood import loglik
from jmlgdsl.lang.parse import parse_text
from jmlgdsl.lang.priors import Prior

# Three tanks in a cascade with a leak, a clog and a biased sensor (examples/fit/tanks.jmlg, sampled
# every 10 s so that a short record holds whole episodes); the unknowns' priors have medians 25 % and
# 50 % off the truth.
TANKS = open("examples/fit/tanks.jmlg").read().replace("sample 5 s", "sample 10 s")
UNKNOWN = TANKS.replace("param  k12 = 0.02, k3 = 0.012, kl = 0.004",
                        "param  k12 ~ LogNormal(log(0.025), 0.5), k3 ~ LogNormal(log(0.018), 0.5), kl ~ Uniform(0, 0.01)")
TRUTH = {"k12": 0.02, "k3": 0.012, "kl": 0.004}


def tank_record(path, T=300, seed=3):
    """A CSV of the three tanks under a random binary pump flow, with a leak and a clog episode, and
    no mode column."""
    rng = np.random.default_rng(seed)
    q = 0.015 + 0.002 * np.repeat(rng.choice([-1, 1], T // 10 + 1), 10)[:T, None]
    a, b, c, d = T // 4, T // 4 + T // 8, T // 2 + T // 8, T // 2 + T // 4
    schedule = f"1-{a}:normal,{a + 1}-{b}:leak,{b + 1}-{c}:normal,{c + 1}-{d}:clog,{d + 1}-{T}:normal"
    sim = jmlgdsl.simulate(compile_text(TANKS), seed=rng, modes=schedule, u=q)
    write_columns(path, {"q": sim.u[:, 0], "l1": sim.y[:, 0], "l3": sim.y[:, 1]})


def test_an_unlabelled_fit_from_priors_far_off_lands_within_three_standard_errors(tmp_path, capsys):
    """Without labels the filter's likelihood at the priors' medians is too rough for BFGS (it used to
    stop where it started, with standard errors of one part in a million); the labelling rounds bring
    it to the data's peak, and every check passes, so --strict exits 0."""
    spec, data, out = tmp_path / "tanks.jmlg", tmp_path / "tanks.csv", tmp_path / "fitted.jmlg"
    spec.write_text(UNKNOWN)
    tank_record(data)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SpecWarning)
        assert main(["fit", str(spec), str(data), "-o", str(out), "--strict"]) == 0
    err = capsys.readouterr().err
    assert "labelling round 2: " in err and "warning" not in err
    rows = {line.split()[0]: line.split() for line in err.splitlines() if line.split()[:1] in (["k12"], ["k3"], ["kl"])}
    for name, true in TRUTH.items():
        estimate, se = float(rows[name][-3]), float(rows[name][-2])
        assert abs(estimate - true) < 3 * se and 1e-4 * true < se < 0.05 * true, name
    assert out.read_text().startswith("# Fitted by 'jmlgdsl fit' to tanks.csv: log-likelihood ")


def test_a_fit_that_does_not_converge_says_so_and_strict_exits_non_zero(tmp_path, capsys):
    """Without the labelling rounds the search climbs the filter's likelihood from the prior's median,
    where every mode misses the readings by many standard deviations and the likelihood jumps between
    neighbouring values: BFGS stops where it started. The report and the fitted spec say so, and
    --strict makes the command fail (the spec is written all the same)."""
    spec, data, out = tmp_path / "tanks.jmlg", tmp_path / "tanks.csv", tmp_path / "fitted.jmlg"
    spec.write_text(TANKS.replace("k3 = 0.012", "k3 ~ LogNormal(log(0.018), 0.5)"))
    tank_record(data)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SpecWarning)
        assert main(["fit", str(spec), str(data), "--no-label-rounds", "--strict", "-o", str(out), "-q"]) == 1
    err = capsys.readouterr().err
    assert "warning: k3 did not move from where the search started, though the data bear on it: " in err
    assert "warning: the fitted model explains the data far worse than it expects to: log-likelihood " in err
    header = out.read_text().split("plant tanks")[0]
    assert "\n# warning: the fitted model explains the data far worse than it expects to: " in header
    assert main(["check", str(out)]) == 0


def test_the_checks_name_a_search_that_stopped_short_or_never_moved():
    """The checks one by one, on numbers whose verdict is known."""
    cov = np.diag([0.01, 4.0])  # standard errors 0.1 and 2
    assert not_at_peak(cov, np.array([10.0, 0.1]), ["a", "b"]) == [
        "the search did not reach the peak: the log posterior still rises from the estimate (a Newton step would "
        "move a by 1 standard errors)"]
    assert not_at_peak(cov, np.array([0.1, 0.1]), ["a", "b"]) == []  # 0.1 and 0.2 standard errors: at the peak

    family = Family(parse_text(UNKNOWN))
    start = np.array([p.to_z(p.median) for p in family.priors])
    touched = np.array([True, True, False])  # the data bear on k12 and k3, not on kl
    assert unmoved(start + [1e-5, 0.2, 0.0], start, touched, family) == [
        "k12 did not move from where the search started, though the data bear on it: the search did not find a peak"]
    assert unmoved(start + [0.1, 0.2, 0.0], start, touched, family) == []


def test_a_model_far_worse_on_the_data_than_on_its_own_simulations_is_named():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SpecWarning)
        model = compile_text(DRYER)
    data = simulated(200, labelled=False)
    fitted = loglik(model, data)
    assert misfit(model, [data], "imm", fitted) == []  # the medians are near the truth: residuals as expected
    noisy = replace(data, y=data.y + np.random.default_rng(0).normal(0, 0.5, data.y.shape))  # 7 times the noise
    (warning,) = misfit(model, [noisy], "imm", loglik(model, noisy))
    assert warning.startswith("the fitted model explains the data far worse than it expects to: log-likelihood ")


class _Bowl(Posterior):
    """A posterior with a known peak (a = 0.5, b = 0.3, both Uniform(0, 1)): the log-likelihood a bowl
    in theta, so far out in z (b pushed against an edge) b's gradient vanishes as exp(-|z|)."""

    def __init__(self):
        priors = [Prior("Uniform", (0.0, 1.0)), Prior("Uniform", (0.0, 1.0))]
        super().__init__(SimpleNamespace(priors=priors, names=["a", "b"]), [], "imm")

    def loglik(self, theta):
        self.evaluations += 1
        return -1e3 * ((theta[0] - 0.5) ** 2 + (theta[1] - 0.3) ** 2)

    def many(self, zs):
        return np.array([self(z) for z in zs])


def test_an_unknown_pushed_against_an_edge_is_searched_again_from_its_median():
    """BFGS from b at z = -30 fits a and leaves b where it is (no gradient there); `released` starts b
    again at its median and climbs to the peak. A fit of three tanks' labelled record lost its leak
    coefficient this way: pushed to zero while the flow coefficients were far off, it stayed there."""
    objective = Cached(_Bowl())
    stuck = bfgs(objective, np.array([0.0, -30.0]))
    a, b = objective.post.theta(stuck.x)
    assert abs(a - 0.5) < 1e-3 and b < 1e-9  # a fitted, b still at the edge
    said = []
    result = released(objective, stuck, said.append)
    assert np.allclose(objective.post.theta(result.x), [0.5, 0.3], atol=1e-3)
    assert said == ["b at an edge of its prior: searching again from its median"]
    assert released(objective, result, said.append) is result and len(said) == 1  # nothing at an edge: as it was


def test_labelling_rounds_that_cycle_stop_and_keep_the_best_round(tmp_path, monkeypatch):
    """Labels that wander (modes at random, then 'normal' for every row, then other modes at random,
    and others) stop the rounds once STALE_ROUNDS rounds in a row fit no better than the best, and the
    start is the best round's fit, not the last one's."""
    data_path = tmp_path / "tanks.csv"
    tank_record(data_path)
    family = Family(parse_text(UNKNOWN))
    data = jmlgdsl.data.read_csv(data_path, family.model(family.medians()))
    rng = np.random.default_rng(0)
    normal = np.zeros(len(data.y), dtype=int)
    flips = iter([rng.integers(0, 4, len(data.y)), normal] + [rng.integers(0, 4, len(data.y)) for _ in range(10)])
    monkeypatch.setattr(labels_module, "most_probable_modes", lambda model, d: next(flips))
    said = []
    z = label_rounds(Posterior(family, [data], "imm"), np.array([p.to_z(p.median) for p in family.priors]),
                     said.append)
    assert [line.split(":")[0] for line in said] == [f"labelling round {k}" for k in range(1, 5)] + [
        "the labels cycle"]
    assert said[-1] == "the labels cycle: the start is round 2's"
    values = [float(line.rsplit(" ", 1)[-1]) for line in said[:4]]
    assert values[1] > max(values[0], values[2], values[3]) + 1
    fitted_to_normal = -Cached(Posterior(family, [replace(data, modes=normal)], "imm"))(z)
    assert f"{fitted_to_normal:.8g}" == said[1].rsplit(" ", 1)[-1]
