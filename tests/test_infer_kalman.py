"""The Kalman kernel against textbook formulas, and the shared covariance graph against the kernel."""

import types

import numpy as np
import pytest
from infer_models import random_model
from scipy.stats import multivariate_normal

from jmlgdsl.infer import kalman
from jmlgdsl.infer.covariances import CovarianceGraph, Representatives


def random_spd(rng, n):
    M = rng.normal(size=(n, n))
    return M @ M.T + n * np.eye(n)


def test_step_matches_textbook_formulas():
    rng = np.random.default_rng(0)
    nx, ny = 3, 2
    A, C = rng.normal(size=(nx, nx)), rng.normal(size=(ny, nx))
    Q, R, Sig = random_spd(rng, nx), random_spd(rng, ny), random_spd(rng, nx)
    mu, b, c, y = rng.normal(size=nx), rng.normal(size=nx), rng.normal(size=ny), rng.normal(size=ny)
    mu_f, Sig_f, ll, y_pred, S = kalman.step(mu, Sig, A, b, Q, C, c, R, y)
    mp, Pp = A @ mu + b, A @ Sig @ A.T + Q
    S_ref = C @ Pp @ C.T + R
    gain = Pp @ C.T @ np.linalg.inv(S_ref)
    np.testing.assert_allclose(y_pred, C @ mp + c)
    np.testing.assert_allclose(S, S_ref)
    np.testing.assert_allclose(mu_f, mp + gain @ (y - C @ mp - c))
    np.testing.assert_allclose(Sig_f, (np.eye(nx) - gain @ C) @ Pp, atol=1e-12)
    assert np.array_equal(Sig_f, Sig_f.T)
    assert ll == pytest.approx(multivariate_normal(C @ mp + c, S_ref).logpdf(y))


def test_partial_observation_uses_only_measured_rows():
    rng = np.random.default_rng(1)
    A, C = rng.normal(size=(2, 2)), rng.normal(size=(3, 2))
    Q, R, Sig = random_spd(rng, 2), random_spd(rng, 3), random_spd(rng, 2)
    mu, y = rng.normal(size=2), np.array([0.3, np.nan, -1.2])
    keep = [0, 2]
    got = kalman.step(mu, Sig, A, 0.0, Q, C, 0.0, R, y)
    ref = kalman.step(mu, Sig, A, 0.0, Q, C[keep], 0.0, R[np.ix_(keep, keep)], y[keep])
    for a, b in zip(got[:3], ref[:3]):
        np.testing.assert_allclose(a, b)
    assert got[3].shape == (3,)


def test_log_density_is_finite_and_equal_for_absurd_distances():
    # an overflowing squared distance is capped: tiny but finite, the same under every hypothesis
    ll = kalman.log_density(np.array([np.inf, 1e305, kalman.MAX_QUAD]), 0.0, 1)
    assert np.isfinite(ll).all() and ll[0] == ll[1] == ll[2]


def test_graph_rows_equal_the_kernel():
    model = random_model(np.random.default_rng(2), K=3, nx=2, ny=2)
    graph = CovarianceGraph(model)
    root = graph.add(model.Sigma0[None])
    mask = np.array([True, False])
    rows = graph.rows(mask)
    y = np.array([0.7, np.nan])
    for k in range(model.K):
        _, Sig_f, ll, y_pred, _ = kalman.step(np.zeros(2), model.Sigma0, model.A[k], 0.0, model.Q[k],
                                              model.C[k], 0.0, model.R[k], y)
        Linv, logdet, _, Sig_f_k = (a[0] for a in rows.at((root[:1], np.array([k]))))
        np.testing.assert_allclose(Sig_f_k, Sig_f)
        # With a zero mean the innovation is the observation itself.
        z = Linv @ y[:1]
        assert -0.5 * (z @ z + logdet + np.log(2 * np.pi)) == pytest.approx(ll)


def test_graph_keeps_covariances_exactly_and_each_engine_its_first_of_a_class():
    model = random_model(np.random.default_rng(3), K=2, nx=2, ny=1)
    graph = CovarianceGraph(model, rtol=1e-10)
    S = np.array([[2.0, 0.3], [0.3, 1.0]])
    ids = graph.add(np.stack([S, S * (1 + 1e-14), S * 1.01, S]))
    assert ids[0] == ids[3] and len(set(ids[:3])) == 3 and graph.size == 3
    classes = graph.classes.data[ids]
    assert classes[0] == classes[1] != classes[2]
    # two engines meet the two near-equal covariances in opposite orders: each keeps the one it met
    # first, whatever the other met, as a graph of its own would
    first, second = Representatives(graph, ids[[0]]), Representatives(graph, ids[[1]])
    np.testing.assert_array_equal(first.pick(graph, ids[[1, 2, 0]]), ids[[0, 2, 0]])
    np.testing.assert_array_equal(second.pick(graph, ids[[0, 2, 1]]), ids[[1, 2, 1]])
    assert first.held == second.held == 2
    rows = graph.rows(np.array([True]))
    child = graph.children(rows, ids[[0, 0, 2]], np.array([1, 1, 0]))
    assert child[0] == child[1] and graph.size == 5
    expected = rows.Sig_f(ids[[2, 0]], np.array([0, 1]))
    np.testing.assert_array_equal(graph.Sig[child[2]], expected[0])
    engine = types.SimpleNamespace(node=child[[2, 0]], reps=first)
    first.keep(graph, first.pick(graph, engine.node))
    assert first.held == 2  # the classes of its particles' nodes: S's is forgotten
    graph.compact([engine])
    assert graph.size == 2
    np.testing.assert_array_equal(graph.Sig[engine.node], expected)
    np.testing.assert_array_equal(first.pick(graph, engine.node), engine.node)


def test_graph_keeps_a_small_variance_apart_from_a_large_one():
    model = random_model(np.random.default_rng(3), K=2, nx=2, ny=1)
    graph = CovarianceGraph(model, rtol=1e-10)
    # A temperature (variance 1) beside a concentration (variance 1e-8): 1 % apart in the
    # concentration is a different covariance, though far below 1e-10 of the largest variance.
    ids = graph.add(np.stack([np.diag([1.0, 1e-8]), np.diag([1.0, 1.01e-8]), np.diag([1.0, 1e-8 * (1 + 1e-14)])]))
    classes = graph.classes.data[ids]
    assert classes[0] != classes[1] and classes[0] == classes[2]


@pytest.mark.parametrize("n", [1, 4, 16])  # a square root, numpy's batch, BLAS matrix by matrix
def test_whiten_solves_lower_triangular_systems_with_broadcasting(n):
    rng = np.random.default_rng(n)
    L = np.linalg.cholesky(np.stack([random_spd(rng, n) for _ in range(3)]))
    M = rng.normal(size=(2, 3, n, 5))
    r = rng.normal(size=(n, 1))
    # r gets a batch axis for the reference: numpy before 2.0 reads an (n, 1) b beside a stack of (n, n)
    # matrices as a stack of n-vectors, not as one column
    for got, want in zip(kalman.whiten(L, M, r), (np.linalg.solve(L, M), np.linalg.solve(L, r[None]))):
        np.testing.assert_allclose(got, np.broadcast_to(want, got.shape), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(kalman.whiten(L[0], M)[0], np.linalg.solve(L[0], M), rtol=1e-12, atol=1e-12)
    Linv, logdet = kalman.inverse_cholesky(L @ kalman.transpose(L))
    np.testing.assert_allclose(Linv @ L, np.broadcast_to(np.eye(n), L.shape), atol=1e-12)
    np.testing.assert_allclose(logdet, np.linalg.slogdet(L @ kalman.transpose(L))[1], rtol=1e-12)


def test_outputs_that_read_a_run_of_states_filter_as_their_matrices():
    """IMM on a bank whose outputs read states 2..13 directly (taken as views) agrees with the same bank
    with its states reordered so that C must be multiplied out."""
    from jmlgdsl import Model
    from jmlgdsl.infer import filter as run_filter
    from jmlgdsl.simulation.linear import simulate

    rng = np.random.default_rng(5)
    K, nx, ny = 3, 14, 12
    A = np.stack([0.8 * np.linalg.qr(rng.normal(size=(nx, nx)))[0] for _ in range(K)])
    C = np.eye(nx)[2:2 + ny]
    model = Model.from_arrays(A=A, B=0.3 * rng.normal(size=(K, nx, nx)), C=C, D=0.2 * np.eye(ny),
                              f=rng.normal(size=(K, nx)), P=np.full((K, K), 0.05) + 0.85 * np.eye(K),
                              p0=np.full(K, 1 / K), mu0=np.zeros(nx), Sigma0=np.eye(nx))
    order = rng.permutation(nx)  # x_new = x[order]
    shuffled = model.replace(A=model.A[:, order][:, :, order], B=model.B[:, order], C=model.C[:, :, order],
                             f=model.f[:, order], mu0=model.mu0[:, order], Sigma0=model.Sigma0[order][:, order])
    assert model.output_states == slice(2, 2 + ny) and shuffled.output_states is None
    y = simulate(model, 40, seed=1).y
    y[7, 3] = np.nan  # a partial reading takes the masked path
    a, b = run_filter(model, y, algorithm="imm"), run_filter(shuffled, y, algorithm="imm")
    np.testing.assert_allclose(a.mode_posterior, b.mode_posterior, atol=1e-10)
    np.testing.assert_allclose(a.loglik_steps, b.loglik_steps, rtol=1e-10)
    np.testing.assert_allclose(a.state_mean[:, order], b.state_mean, atol=1e-9)


def test_settled_holds_each_entry_to_its_own_scale():
    """A covariance of states in units a million apart: a change in the small state's variance
    counts, however small beside the large state's, and rounding-sized changes do not."""
    Sig = np.array([[1e12, 1e5], [1e5, 1.0]])
    assert kalman.settled(Sig, Sig * (1 + 1e-15))
    assert not kalman.settled(Sig, Sig + np.array([[0.0, 0.0], [0.0, 1e-3]]))
    assert not kalman.settled(Sig, Sig + np.array([[0.0, 1e-3], [1e-3, 0.0]]))
    assert list(kalman.settled(np.stack([Sig, Sig]), np.stack([Sig, 2 * Sig]))) == [True, False]


@pytest.mark.parametrize("n", [2, 3, 4, 5, 7])
def test_a_triangular_factor_inverts_alike_alone_and_in_a_stack(n):
    from jmlgdsl.infer.kalman import triangular_inverse

    rng = np.random.default_rng(n)
    A = rng.normal(size=(50, n, n))
    L = np.linalg.cholesky(A @ np.swapaxes(A, -1, -2) + n * np.eye(n))
    stacked = triangular_inverse(L)
    np.testing.assert_allclose(stacked @ L, np.broadcast_to(np.eye(n), L.shape), atol=1e-13)
    np.testing.assert_allclose(stacked, np.linalg.inv(L), rtol=1e-12, atol=1e-14)
    assert np.all(np.triu(stacked, 1) == 0)
    for one, alone in zip(L, stacked):  # a fleet's units get what each would alone, bit for bit
        assert np.array_equal(triangular_inverse(one), alone)


def test_the_filtered_covariance_stays_positive_when_outputs_are_read_almost_exactly():
    # a wide start (sd about 300) and measurement noise 1e-11: Sig_p - K C Sig_p cancels to rounding
    # (eps * 1e5 = 2e-11, as large as the answer: the short form gives eigenvalues from -4e-11 to 6e-11)
    rng = np.random.default_rng(2)
    n = 12
    M = rng.standard_normal((n, n))
    Sig = 1e5 * (M @ M.T / n + np.eye(n))
    R = 1e-11 * np.eye(n)
    *_, filtered = kalman.covariance_step(Sig, 0.9 * np.eye(n), np.eye(n), slice(0, n), R, np.ones(n, bool))
    # every output read directly: the posterior is R - R S^-1 R, R to 1e-15 relative
    assert np.linalg.eigvalsh(filtered) == pytest.approx(np.full(n, 1e-11), rel=1e-6)
    # the same with C as a matrix and some outputs missing
    C = np.eye(n)
    mask = np.arange(n) % 3 > 0
    *_, filtered = kalman.covariance_step(Sig, 0.9 * np.eye(n), np.eye(n), C, R, mask)
    assert np.linalg.eigvalsh(filtered).min() > 0


def test_a_diagonal_noise_of_many_outputs_gives_the_products_numbers():
    """K R K' in the Joseph update: with a diagonal R of many outputs (a learned bank's) the columns of
    K are scaled instead of multiplied out, to the same bits, K laid out as the step has it (a view)."""
    rng = np.random.default_rng(3)
    K = kalman.transpose(rng.normal(size=(4, 20, 30)))
    R = np.stack([np.diag(rng.uniform(1e-9, 10.0, 20)) for _ in range(4)])
    assert (kalman.times(K, R) @ kalman.transpose(K)).tobytes() == ((K @ R) @ kalman.transpose(K)).tobytes()
    R[2, 0, 5] = R[2, 5, 0] = 1e-3  # not diagonal: the product
    assert kalman.times(K, R).tobytes() == (K @ R).tobytes()


def test_the_settled_tolerance_is_the_steps_rounding_in_any_units():
    """Given the step's inverse Cholesky factor, covariances count as settled to eps * kappa, kappa =
    max_i (S^-1)_ii L_ii^2: SETTLED for a well-conditioned S, the same bits as without the factor;
    for six sensors sharing all but 1e-6 of their noise, (S^-1)_11 L_11^2 = (1 - 1/6) * 1e6, whatever
    units the sensors read in."""
    rng = np.random.default_rng(4)
    Sig = random_spd(rng, 6)
    Linv, _ = kalman.inverse_cholesky(random_spd(rng, 6) + 6 * np.eye(6))
    assert kalman.tolerance(Sig, Linv).tobytes() == kalman.tolerance(Sig).tobytes()
    shared = (1 - 1e-6) * np.ones((6, 6)) + 1e-6 * np.eye(6)
    Linv, _ = kalman.inverse_cholesky(shared)
    relative = kalman.tolerance(Sig, Linv) / kalman.tolerance(Sig)
    assert np.allclose(relative, kalman.EPS * (1 - 1 / 6) * 1e6 / kalman.SETTLED, rtol=1e-3)
    units = np.diag(10.0 ** np.arange(6))
    Linv_units, _ = kalman.inverse_cholesky(units @ shared @ units)
    np.testing.assert_allclose(kalman.tolerance(Sig, Linv_units), kalman.tolerance(Sig, Linv), rtol=1e-6)
