"""Extreme numbers: an indefinite covariance from rounding is repaired, a run whose arithmetic
overflows stops with an error naming the row, and values beyond 1e150 are refused where written."""

import numpy as np
import pytest
from infer_models import dryer

import jmlgdsl
from jmlgdsl.compile.lower import compile_text
from jmlgdsl.infer import FilterError, kalman


def test_a_covariance_rounding_made_indefinite_is_repaired():
    S = np.array([[1e18, 1e18], [1e18, 1e18 - 1e3]])  # rank one up to rounding: Cholesky refuses it
    with pytest.raises(np.linalg.LinAlgError):
        np.linalg.cholesky(S)
    Linv, logdet = kalman.inverse_cholesky(S)
    assert np.isfinite(Linv).all() and np.isfinite(logdet)
    # S^-1 = Linv' Linv; inverting it back loses about cond(S) * eps = 1e12 * 1e-16 of relative precision
    np.testing.assert_allclose(np.linalg.inv(Linv.T @ Linv), S, rtol=1e-4)


def test_a_run_that_overflows_stops_at_its_row():
    model = dryer().replace(A=np.full((4, 1, 1), 1e9), outlier_gate=np.array([np.inf]))  # wildly unstable, no gate
    with pytest.raises(FilterError, match=r"^t=\d+: the filter's arithmetic overflowed"), np.errstate(all="ignore"):
        jmlgdsl.filter(model, np.full((60, 1), 50.0))


def test_a_value_beyond_the_limit_is_a_located_error():
    text = "plant p\nsample 1 s\noutput y\nstate x\nmode m { x[t] ~ Normal(0.5 * x[t-1] + 1e160, 1); y ~ Normal(x[t], 1) }\n"
    with pytest.raises(jmlgdsl.SpecError, match=r"p.jmlg:5:6: mode .m. has entries larger than 1e\+150 in f, x0"):
        compile_text(text, "p.jmlg")
