"""EM for linear-Gaussian state space: the E-step against the joint Gaussian, the whole algorithm
against pykalman, monotone log-likelihood, the safeguard, missing outputs, invariances."""


import numpy as np
import pytest
from scipy.stats import multivariate_normal

from jmlgdsl.infer import kalman
from jmlgdsl.learn import em as em_module
from jmlgdsl.learn.em import em, forward, smooth
from jmlgdsl.learn.statespace import StateSpace

RNG_SEED = 11


def two_state_model(nu=1):
    return StateSpace(A=np.array([[0.9, 0.2], [-0.1, 0.7]]), F=np.array([[0.5], [0.1]])[:, :nu],
                      f=np.array([0.2, -0.1]), C=np.array([[1.0, 0.5], [0.2, 1.0]]),
                      G=np.array([[0.1], [0.0]])[:, :nu], g=np.array([0.3, 0.0]),
                      Q=np.array([[0.09, 0.02], [0.02, 0.04]]), R=np.array([[0.04, 0.01], [0.01, 0.03]]),
                      mu0=np.array([1.0, -1.0]), Sigma0=np.array([[0.5, 0.1], [0.1, 0.3]]))


def simulate(ss, u, rng):
    """Draw y_1..y_T from the state-space model (x_0 from its prior)."""
    x = rng.multivariate_normal(ss.mu0, ss.Sigma0)
    y = np.empty((len(u), ss.C.shape[0]))
    for t, ut in enumerate(u):
        x = ss.A @ x + ss.F @ ut + ss.f + rng.multivariate_normal(np.zeros(ss.nx), ss.Q)
        y[t] = ss.C @ x + ss.G @ ut + ss.g + rng.multivariate_normal(np.zeros(len(y[t])), ss.R)
    return y


def joint_gaussian(ss, u):
    """Mean and covariance of the stacked (x_0..x_T, y_1..y_T), built directly from the model."""
    T, nx, ny = len(u), ss.nx, ss.C.shape[0]
    mx = [ss.mu0]
    for t in range(T):
        mx.append(ss.A @ mx[-1] + ss.F @ u[t] + ss.f)
    P = np.zeros(((T + 1) * nx, (T + 1) * nx))
    var = ss.Sigma0
    for t in range(T + 1):
        if t:
            var = ss.A @ var @ ss.A.T + ss.Q
        block = var
        for s in range(t, T + 1):  # Cov(x_s, x_t) = A^(s-t) Var(x_t)
            P[s * nx:(s + 1) * nx, t * nx:(t + 1) * nx] = block
            P[t * nx:(t + 1) * nx, s * nx:(s + 1) * nx] = block.T
            block = ss.A @ block
    Cb = np.zeros((T * ny, (T + 1) * nx))
    for t in range(T):
        Cb[t * ny:(t + 1) * ny, (t + 1) * nx:(t + 2) * nx] = ss.C
    my = Cb @ np.concatenate(mx) + np.concatenate([ss.G @ ut + ss.g for ut in u])
    Syy = Cb @ P @ Cb.T + np.kron(np.eye(T), ss.R)
    return np.concatenate(mx), P, my, Syy, P @ Cb.T


def test_e_step_equals_conditioning_the_joint_gaussian():
    ss, rng = two_state_model(), np.random.default_rng(RNG_SEED)
    T = 6
    u = rng.standard_normal((T, 1))
    y = simulate(ss, u, rng)
    y[2, 1] = np.nan  # a partly measured step
    y[4] = np.nan     # an unmeasured step
    mx, P, my, Syy, Sxy = joint_gaussian(ss, u)
    o = ~np.isnan(y.ravel())
    K = np.linalg.solve(Syy[np.ix_(o, o)], Sxy[:, o].T).T
    post_mean = mx + K @ (y.ravel()[o] - my[o])
    post_cov = P - K @ Sxy[:, o].T
    e = smooth(ss, y, u)
    assert e.loglik == pytest.approx(multivariate_normal(my[o], Syy[np.ix_(o, o)]).logpdf(y.ravel()[o]), rel=1e-12)
    assert np.allclose(e.mean.ravel(), post_mean, atol=1e-10)
    for t in range(T + 1):
        assert np.allclose(e.cov[t], post_cov[2 * t:2 * t + 2, 2 * t:2 * t + 2], atol=1e-10)
    for t in range(1, T + 1):
        assert np.allclose(e.cross[t - 1], post_cov[2 * t:2 * t + 2, 2 * t - 2:2 * t], atol=1e-10)


def test_em_agrees_with_pykalman_without_inputs():
    """pykalman's EM (no inputs, offsets held at zero) from the same start reaches the same
    parameters. Its first observation belongs to its initial state, so it is given as masked: then
    its initial state is our x_0 and its later observations are our y_1..y_T."""
    pykalman = pytest.importorskip("pykalman")
    rng = np.random.default_rng(RNG_SEED)
    truth = two_state_model(nu=0).replace(f=np.zeros(2), g=np.zeros(2))
    y = simulate(truth, np.zeros((300, 0)), rng)
    y[[40, 41, 150]] = np.nan
    start = truth.replace(A=0.5 * np.eye(2), C=np.eye(2), Q=0.1 * np.eye(2), R=0.1 * np.eye(2),
                          mu0=np.zeros(2), Sigma0=np.eye(2))
    ours = em(start, y, None, max_iter=8, tol=0.0, offset=False)
    observations = np.ma.masked_invalid(np.vstack([np.full((1, 2), np.nan), y]))
    kf = pykalman.KalmanFilter(transition_matrices=start.A, observation_matrices=start.C,
                               transition_covariance=start.Q, observation_covariance=start.R,
                               initial_state_mean=start.mu0, initial_state_covariance=start.Sigma0,
                               transition_offsets=np.zeros(2), observation_offsets=np.zeros(2))
    assert kf.loglikelihood(observations) == pytest.approx(ours.loglik[0], rel=1e-12)
    kf = kf.em(observations, n_iter=8, em_vars=["transition_matrices", "observation_matrices",
                                                "transition_covariance", "observation_covariance",
                                                "initial_state_mean", "initial_state_covariance"])
    m = ours.model
    for theirs, mine in [(kf.transition_matrices, m.A), (kf.observation_matrices, m.C),
                         (kf.transition_covariance, m.Q), (kf.observation_covariance, m.R),
                         (kf.initial_state_mean, m.mu0), (kf.initial_state_covariance, m.Sigma0)]:
        assert np.allclose(theirs, mine, rtol=1e-9, atol=1e-12)
    assert kf.loglikelihood(observations) == pytest.approx(ours.loglik[-1], rel=1e-12)
    assert_non_decreasing(ours.loglik)


def assert_non_decreasing(loglik):
    assert np.all(np.diff(loglik) >= -1e-9 * np.abs(loglik[:-1])), np.diff(loglik)


def test_em_with_inputs_and_missing_outputs_is_monotone_and_keeps_covariances_spd():
    rng = np.random.default_rng(RNG_SEED + 1)
    truth = two_state_model()
    u = rng.choice([-1.0, 1.0], size=(400, 1))
    y = simulate(truth, u, rng)
    y[rng.random(400) < 0.2] = np.nan
    y[rng.random(400) < 0.1, 0] = np.nan
    start = truth.replace(A=0.5 * np.eye(2), F=np.zeros((2, 1)), C=np.eye(2), Q=np.eye(2), R=np.eye(2))
    result = em(start, y, u, max_iter=30, tol=0.0)
    assert result.iterations == 30 and not result.converged
    assert_non_decreasing(result.loglik)
    assert result.loglik[-1] > result.loglik[0] + 100
    for S in (result.model.Q, result.model.R, result.model.Sigma0):
        assert np.array_equal(S, S.T) and np.linalg.eigvalsh(S).min() > 0


def test_stops_on_relative_tolerance():
    """The tolerance is relative to the log-likelihood's scale: the larger of |log-lik| and the
    number of measured values (600 here, where |log-lik| is about 127)."""
    rng = np.random.default_rng(RNG_SEED + 2)
    truth = two_state_model()
    u = rng.standard_normal((300, 1))
    y = simulate(truth, u, rng)
    result = em(truth, y, u, max_iter=500, tol=1e-6)
    assert result.converged and result.iterations < 500
    assert_non_decreasing(result.loglik)
    gains = np.diff(result.loglik)
    scale = [max(abs(ll), y.size) for ll in result.loglik]
    assert gains[-1] < 1e-6 * scale[-2] and gains[-2] >= 1e-6 * scale[-3]
    assert result.tolerance == pytest.approx(1e-6 * scale[-1])


def test_an_unfinished_run_projects_what_is_left():
    """Stopped by the cap, EM reports its last gain and projects the rest from the shrinking gains
    (Aitken): within a factor of two of what running on to 400 iterations gains (0.15 projected
    against 0.19 after 40 iterations, 1.08 against 0.86 after 30). While the gains still grow
    (after 15 here) there is no projection."""
    rng = np.random.default_rng(RNG_SEED + 3)
    truth = two_state_model()
    u = rng.standard_normal((300, 1))
    y = simulate(truth, u, rng)
    start = truth.replace(Q=4 * truth.Q, R=0.25 * truth.R)
    final = em(start, y, u, max_iter=400, tol=0.0).loglik[-1]
    assert em(start, y, u, max_iter=15, tol=0.0).remaining == np.inf
    for cap in (30, 40):
        short = em(start, y, u, max_iter=cap, tol=0.0)
        assert not short.converged and not short.fell and short.gain == short.loglik[-1] - short.loglik[-2]
        assert 0.5 < short.remaining / (final - short.loglik[-1]) < 2


def test_a_falling_likelihood_keeps_the_last_good_parameters(monkeypatch):
    rng = np.random.default_rng(RNG_SEED + 3)
    truth = two_state_model()
    u = rng.standard_normal((200, 1))
    y = simulate(truth, u, rng)
    good_step = em_module.m_step
    calls = []

    def spoiled(ss, *args):
        calls.append(1)
        new = good_step(ss, *args)
        return new if len(calls) < 3 else new.replace(R=100 * new.R)

    monkeypatch.setattr(em_module, "m_step", spoiled)
    with pytest.warns(RuntimeWarning, match="log-likelihood fell"):
        result = em(truth, y, u, max_iter=10, tol=0.0)
    assert result.iterations == 2 and not result.converged
    assert_non_decreasing(result.loglik)
    assert result.loglik[-1] == pytest.approx(forward(result.model, y, u).loglik, rel=1e-12)


def test_reusing_settled_covariances_changes_nothing_but_rounding(monkeypatch):
    """With missing outputs in the middle the covariances settle, unsettle and settle again; the
    smoother's output equals the full recursion's (SETTLED below zero: never reuse) to rounding."""
    rng = np.random.default_rng(RNG_SEED + 5)
    truth = two_state_model()
    u = rng.standard_normal((600, 1))
    y = simulate(truth, u, rng)
    y[300:305] = np.nan
    y[400, 0] = np.nan
    fast = smooth(truth, y, u)
    assert forward(truth, y, u).settled.sum() > 500
    monkeypatch.setattr(kalman, "SETTLED", -1.0)
    assert not forward(truth, y, u).settled.any()
    full = smooth(truth, y, u)
    assert np.allclose(fast.mean, full.mean, rtol=1e-9, atol=1e-12)
    for name in ("cov", "cross"):  # every step's matrix, read through the runs
        assert np.allclose(getattr(fast, name)[:], getattr(full, name)[:], rtol=1e-9, atol=1e-12), name
    assert fast.loglik == pytest.approx(full.loglik, rel=1e-12)
    # settled stretches are stored once: about a hundred distinct covariances for 601 steps
    assert len(fast.cov.distinct) < 120 and len(full.cov.distinct) == 601


def test_step_matrices_store_repeated_ones_once():
    a, b, c = (np.full((2, 2), v) for v in (1.0, 2.0, 3.0))
    steps = em_module.StepMatrices.of([a, b, c], np.array([True, False, False, True, True, False]))
    assert np.array_equal(steps.index, [0, 0, 0, 1, 2, 2])
    assert np.array_equal(steps[:], [a, a, a, b, c, c]) and np.array_equal(steps[3], b)
    assert np.array_equal(steps.sum(), 3 * a + b + 2 * c)
    assert np.array_equal(steps.sum(where=np.array([1, 0, 0, 1, 0, 1], bool)), a + b + c)
    tail = steps.part(slice(2, None))
    both = em_module.StepMatrices.concatenate([tail, steps.part(slice(None, 1))])
    assert np.array_equal(both[:], [a, b, c, c, a]) and np.array_equal(both.sum(), 2 * a + b + 2 * c)
