"""Prior distributions: densities, medians and the unconstrained coordinate against scipy.stats."""

import math

import numpy as np
import pytest
from scipy import stats

from jmlgdsl.lang.priors import Prior, PriorError

CASES = [
    (Prior("Normal", (1.5, 0.4)), stats.norm(1.5, 0.4)),
    (Prior("LogNormal", (math.log(1.2), 0.3)), stats.lognorm(s=0.3, scale=1.2)),
    (Prior("HalfNormal", (0.1,)), stats.halfnorm(scale=0.1)),
    (Prior("Uniform", (0.8, 1.0)), stats.uniform(0.8, 0.2)),
]


@pytest.mark.parametrize("prior, reference", CASES, ids=lambda c: getattr(c, "family", ""))
def test_density_and_median_are_those_of_scipy(prior, reference):
    for q in (0.05, 0.3, 0.5, 0.9):
        theta = reference.ppf(q)
        assert prior.logpdf(theta) == pytest.approx(reference.logpdf(theta), rel=1e-12, abs=1e-12)
    assert prior.median == pytest.approx(reference.median(), rel=1e-12)


@pytest.mark.parametrize("prior, reference", CASES, ids=lambda c: getattr(c, "family", ""))
def test_the_unconstrained_coordinate_maps_back_and_has_the_right_derivative(prior, reference):
    for q in (0.1, 0.5, 0.95):
        theta = reference.ppf(q)
        z = prior.to_z(theta)
        assert prior.from_z(z) == pytest.approx(theta, rel=1e-12)
        h = 1e-6
        numeric = (prior.from_z(z + h) - prior.from_z(z - h)) / (2 * h)
        assert prior.dtheta_dz(z) == pytest.approx(numeric, rel=1e-6)
        assert prior.log_jacobian(z) == pytest.approx(math.log(prior.dtheta_dz(z)), rel=1e-12, abs=1e-12)


def test_outside_the_support_the_density_is_zero():
    assert Prior("Uniform", (0.8, 1.0)).logpdf(1.0) == -math.inf
    assert Prior("HalfNormal", (1.0,)).logpdf(-0.1) == -math.inf
    assert Prior("LogNormal", (0.0, 1.0)).logpdf(0.0) == -math.inf


@pytest.mark.parametrize("family, args, message", [
    ("Normal", (0.0, -1.0), "the sd of Normal must be positive (got -1)"),
    ("LogNormal", (0.0, 0.0), "the sigma of LogNormal must be positive (got 0)"),
    ("Uniform", (1.0, 1.0), "Uniform(low, high) needs low < high (got 1, 1)"),
    ("HalfNormal", (1.0, 2.0), "HalfNormal takes 1 argument: HalfNormal(sd)"),
    ("Gamma", (1.0, 2.0), "unknown prior 'Gamma'"),
])
def test_arguments_that_make_no_distribution_are_refused(family, args, message):
    with pytest.raises(PriorError, match=message.replace("(", r"\(").replace(")", r"\)")):
        Prior(family, args)


@pytest.mark.parametrize("prior, reference", CASES, ids=lambda c: getattr(c, "family", ""))
def test_draws_have_the_priors_median(prior, reference):
    """The median of n draws lies within 4 of its standard errors, 1 / (2 f(median) sqrt(n)), of the
    prior's median."""
    rng = np.random.default_rng(11)
    n = 4000
    draws = np.array([prior.draw(rng) for _ in range(n)])
    se = 1 / (2 * reference.pdf(reference.median()) * math.sqrt(n))
    assert abs(np.median(draws) - prior.median) < 4 * se
    assert all(prior.contains(d) for d in draws)
