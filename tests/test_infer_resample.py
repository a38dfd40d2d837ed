"""Resampling schemes and Fearnhead-Clifford selection: unbiasedness, structure, log-space weights."""

import numpy as np
import pytest

from jmlgdsl.infer import FilterError
from jmlgdsl.infer.engine import Resampler, cdf_drawn, cumulated, rows_drawn, sample_rows, systematic_rows
from jmlgdsl.infer.resample import SCHEMES, ess, fearnhead_clifford, normalize

W = np.array([0.005, 0.3, 0.0, 0.12, 0.375, 0.2])
N = 7
REPEATS = 4000


@pytest.mark.parametrize("name", sorted(SCHEMES))
def test_expected_copies_equal_n_times_weight(name):
    rng = np.random.default_rng(11)
    counts = np.array([np.bincount(SCHEMES[name](W, N, rng), minlength=len(W)) for _ in range(REPEATS)])
    assert (counts.sum(axis=1) == N).all()
    assert (counts[:, W == 0] == 0).all()
    se = counts.std(axis=0) / np.sqrt(REPEATS)
    # 4.5 standard errors per particle: a false alarm over the six particles has probability < 1e-4.
    assert np.all(np.abs(counts.mean(axis=0) - N * W) <= 4.5 * se + 1e-12)


@pytest.mark.parametrize("name", sorted(SCHEMES))
def test_indices_sorted_and_in_range(name):
    idx = SCHEMES[name](W, 50, np.random.default_rng(0))
    assert len(idx) == 50 and (np.diff(idx) >= 0).all() and idx.min() >= 0 and idx.max() < len(W)


def test_systematic_gives_floor_or_ceil_copies():
    rng = np.random.default_rng(3)
    for _ in range(200):
        counts = np.bincount(SCHEMES["systematic"](W, N, rng), minlength=len(W))
        assert (counts >= np.floor(N * W)).all() and (counts <= np.ceil(N * W)).all()


def test_residual_keeps_the_integer_part():
    rng = np.random.default_rng(4)
    for _ in range(100):
        counts = np.bincount(SCHEMES["residual"](W, N, rng), minlength=len(W))
        assert (counts >= np.floor(N * W)).all()


def test_normalize_is_log_space_safe():
    w, total = normalize(np.array([-1e4, -1e4 + np.log(3.0), -np.inf]))
    np.testing.assert_allclose(w, [0.25, 0.75, 0.0])
    assert total == pytest.approx(-1e4 + np.log(4.0))
    assert ess(np.full(8, 1 / 8)) == pytest.approx(8.0)


def test_fearnhead_clifford_keeps_everything_when_few_candidates():
    q = np.array([0.0, 0.5, 0.2, 0.0, 0.3])
    idx, w = fearnhead_clifford(q, 3, np.random.default_rng(0))
    assert list(idx) == [1, 2, 4]
    np.testing.assert_array_equal(w, q[[1, 2, 4]])


def test_fearnhead_clifford_distinct_and_unbiased():
    rng = np.random.default_rng(5)
    q = rng.dirichlet(np.full(12, 0.4))
    q[[3, 8]] = [0.0, 0.0]
    q /= q.sum()
    n = 5
    total = np.zeros((REPEATS, len(q)))
    for r in range(REPEATS):
        idx, w = fearnhead_clifford(q, n, rng)
        assert len(idx) == n and len(set(idx)) == n
        assert w.sum() == pytest.approx(1.0)
        total[r, idx] = w
    # sum_j min(c q_j, 1) = n forces c >= n, so a weight of at least 1/n is always kept as it is.
    big = q >= 1.0 / n
    assert big.any()
    assert (total[:, big] == q[big]).all()
    se = total.std(axis=0) / np.sqrt(REPEATS)
    assert np.all(np.abs(total.mean(axis=0) - q) <= 4.5 * se + 1e-12)


def test_resampler_counts_copies_in_the_ess_and_honours_the_threshold():
    rng = np.random.default_rng(0)
    lazy = Resampler(SCHEMES["systematic"], 4, rng, threshold=0.5)
    # Particle 0 stands for 3 equal copies of weight 1/6 each, particle 1 for one of weight 1/2.
    ancestors, logw, size = lazy(np.array([0.5, 0.5]), np.array([3, 1]))
    assert size == pytest.approx(3.0)
    # 3 >= 0.5 * 4, so no resampling: every copy comes back with its share of the weight.
    assert list(ancestors) == [0, 0, 0, 1]
    np.testing.assert_allclose(np.exp(logw), [1 / 6, 1 / 6, 1 / 6, 1 / 2])
    ancestors, logw, size = lazy(np.array([0.9, 0.1]))
    assert len(ancestors) == 4 and np.allclose(logw, -np.log(4))
    # Two atoms (the initial modes) are not the 4 particles asked for: resampled whatever the ESS.
    ancestors, logw, size = lazy(np.array([0.5, 0.5]))
    assert size == pytest.approx(2.0) and len(ancestors) == 4 and np.allclose(logw, -np.log(4))
    with pytest.raises(FilterError, match="ESS threshold must be in"):
        Resampler(SCHEMES["systematic"], 4, rng, threshold=0.0)


def test_sample_rows_never_draws_a_zero_probability_category():
    class Edges:
        """A generator whose uniforms are the ends of [0, 1)."""

        def __init__(self, value):
            self.value = value

        def random(self, n):
            return np.full(n, self.value)

    probs = np.array([[0.0, 0.25, 0.0, 0.75, 0.0], [0.0, 0.0, 2.0, 0.0, 0.0]])
    assert list(sample_rows(probs, Edges(0.0))) == [1, 2]
    assert list(sample_rows(probs, Edges(np.nextafter(1.0, 0.0)))) == [3, 2]
    rng = np.random.default_rng(8)
    draws = sample_rows(np.repeat(probs[:1], REPEATS, axis=0), rng)
    # Binomial standard error of the frequency of category 1 (probability 1/4).
    assert abs(np.mean(draws == 1) - 0.25) <= 4.5 * np.sqrt(0.25 * 0.75 / REPEATS)
    assert set(draws) == {1, 3}


@pytest.mark.parametrize("rows, J, n", [(6, 10, 10), (5, 200, 200), (1200, 3, 10)])  # every comparison at once; a
# search a row; the weights of many rows cumulated column by column
def test_systematic_rows_resample_each_row_as_the_scheme_alone(rows, J, n):
    rng = np.random.default_rng(J)
    w = rng.random((rows, J)) ** 6
    w[:, ::3] = 0.0
    w /= w.sum(axis=1, keepdims=True)
    offsets = rng.random(rows)

    class Drawn:  # gives the scheme its one number, as each row's Generator would
        def __init__(self, offset):
            self.random = lambda: offset

    alone = [SCHEMES["systematic"](row, n, Drawn(offset)) for row, offset in zip(w, offsets)]
    assert np.array_equal(systematic_rows(w, n, offsets), np.array(alone))


@pytest.mark.parametrize("shape", [(2, 1500, 4), (3000, 2), (50, 4), (2000, 12)])  # many short rows column by column
def test_cumulated_rows_are_numpys_cumulative_sums_bit_for_bit(shape):
    rng = np.random.default_rng(len(shape))
    a = rng.random(shape) * 10.0 ** rng.integers(-8, 8, shape)  # magnitudes far apart: every sum rounds
    a = a[..., ::-1]  # a view, as callers may give
    assert np.array_equal(cumulated(a), a.cumsum(axis=-1))
    assert not np.shares_memory(cumulated(a), a)


@pytest.mark.parametrize("K, rows", [(4, 2000), (4, 50), (12, 2000)])  # many short rows column by column
def test_draws_from_rows_cumulated_once_are_those_of_each_row(K, rows):
    rng = np.random.default_rng(K)
    P = rng.random((K, K)) ** 4
    P[:, 1] = 0.0
    z = rng.integers(0, K, (2, rows))
    uniforms = rng.random((2, rows))
    drawn = cdf_drawn(P.cumsum(axis=-1)[z], uniforms)
    assert np.array_equal(drawn, rows_drawn(P[z], uniforms))
    assert np.array_equal(drawn, (P[z].cumsum(axis=-1) > (uniforms * P[z].sum(axis=-1))[..., None]).argmax(axis=-1))
    assert not (drawn == 1).any()
