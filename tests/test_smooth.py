"""The deterministic smoothers: exact against an independent enumeration of every mode history,
IMM (Kim's smoother) against exact and against the IMM filter, on random models and the dryer."""

import itertools
from pathlib import Path

import numpy as np
import pytest
from infer_models import random_model

import jmlgdsl
from jmlgdsl.data import read_csv
from jmlgdsl.infer.smooth import MAX_HISTORIES, SmoothError, smooth_exact, smooth_imm

ROOT = Path(__file__).resolve().parents[1]
# (K, nx, ny, T): every history z_0..z_T is enumerated, so K^(T+1) stays in the hundreds.
SIZES = [(2, 1, 1, 7), (2, 2, 2, 6), (3, 2, 1, 5), (3, 1, 2, 5)]


def case(K, nx, ny, T, seed=0):
    """A random model with two inputs, random data and missing outputs: one entry and one whole row."""
    rng = np.random.default_rng(seed + 10 * K + nx + 100 * ny)
    model = random_model(rng, K=K, nx=nx, ny=ny, nu=2)
    y, u = rng.normal(size=(T, ny)), rng.normal(size=(T, 2))
    y[1, 0] = np.nan
    y[3] = np.nan
    return model, y, u


def lags(T):
    """Off-line, and every lag from the filter (0) to past the end of the data."""
    return [None, *range(T + 1)]


# ----------------------------------------------------------------------------- brute force
def kalman_history(model, y, u, modes):
    """A plain Kalman filter along one mode history z_0..z_T, then a Rauch-Tung-Striebel pass back
    from every end s: (log p(y_1:s | history) for s = 1..T, E[x_t | y_1:s] and Cov as [s][t])."""
    m, P = model.mu0[modes[0]], model.Sigma0
    loglik, filt, pred, total = [], [], [], 0.0
    for t, k in enumerate(modes[1:]):
        A, C = model.A[k], model.C[k]
        mp, Pp = A @ m + model.F[k] @ u[t] + model.f[k], A @ P @ A.T + model.Q[k]
        seen = ~np.isnan(y[t])
        m, P = mp, Pp
        if seen.any():
            Co = C[seen]
            S = Co @ Pp @ Co.T + model.R[k][np.ix_(seen, seen)]
            r = y[t][seen] - Co @ mp - (model.G[k] @ u[t] + model.g[k])[seen]
            total -= 0.5 * (r @ np.linalg.solve(S, r) + np.linalg.slogdet(2 * np.pi * S)[1])
            gain = Pp @ Co.T @ np.linalg.inv(S)
            m, P = mp + gain @ r, Pp - gain @ Co @ Pp
        loglik.append(total)
        filt.append((m, P))
        pred.append((mp, Pp, A))
    smoothed = []
    for s in range(len(filt)):
        ms, Ps = filt[s]
        back = {s: (ms, Ps)}
        for t in range(s - 1, -1, -1):
            mf, Pf = filt[t]
            mp, Pp, A = pred[t + 1]
            J = Pf @ A.T @ np.linalg.pinv(Pp)
            ms, Ps = mf + J @ (ms - mp), Pf + J @ (Ps - Pp) @ J.T
            back[t] = (ms, Ps)
        smoothed.append(back)
    return np.array(loglik), smoothed


def enumerate_histories(model, y, u):
    """For every history z_0..z_T: its modes, log prior, log-likelihoods and smoothed moments."""
    T = len(y)
    out = []
    for modes in itertools.product(range(model.K), repeat=T + 1):
        with np.errstate(divide="ignore"):
            log_prior = np.log(model.p0[modes[0]]) + sum(np.log(model.P[a, b]) for a, b in zip(modes, modes[1:]))
        out.append((modes[1:], log_prior, *kalman_history(model, y, u, modes)))
    return out


def brute_force(histories, K, nx, ends):
    """p(z_t | y_1:s) and the mixture moments of x_t for each row t (0-based), s = ends[t] (1-based):
    the prior of a whole history times the likelihood of its first s outputs marginalises the
    modes after s."""
    T = len(ends)
    post, mean, cov = np.zeros((T, K)), np.zeros((T, nx)), np.zeros((T, nx, nx))
    for t, s in enumerate(ends):
        logw = np.array([h[1] + h[2][s - 1] for h in histories])
        w = np.exp(logw - logw.max())
        w /= w.sum()
        for wi, (modes, _, _, smoothed) in zip(w, histories):
            post[t, modes[t]] += wi
            mean[t] += wi * smoothed[s - 1][t][0]
        for wi, (_, _, _, smoothed) in zip(w, histories):
            ms, Ps = smoothed[s - 1][t]
            cov[t] += wi * (Ps + np.outer(ms - mean[t], ms - mean[t]))
    return post, mean, cov


def ends_of(T, lag):
    return [T] * T if lag is None else [min(T, t + 1 + lag) for t in range(T)]


def assert_same(a, b, atol, what=""):
    for field in ("mode_posterior", "state_mean", "state_cov"):
        np.testing.assert_allclose(getattr(a, field), getattr(b, field), rtol=0, atol=atol, err_msg=f"{what} {field}")


# ----------------------------------------------------------------------------- exact
@pytest.mark.parametrize("K, nx, ny, T", SIZES)
def test_exact_equals_enumeration_offline_and_at_every_lag(K, nx, ny, T):
    model, y, u = case(K, nx, ny, T)
    histories = enumerate_histories(model, y, u)
    for lag in lags(T):
        got = smooth_exact(model, y, u, lag=lag)
        post, mean, cov = brute_force(histories, K, nx, ends_of(T, lag))
        np.testing.assert_allclose(got.mode_posterior, post, rtol=0, atol=1e-10, err_msg=f"lag {lag}")
        np.testing.assert_allclose(got.state_mean, mean, rtol=0, atol=1e-10, err_msg=f"lag {lag}")
        np.testing.assert_allclose(got.state_cov, cov, rtol=0, atol=1e-10, err_msg=f"lag {lag}")


@pytest.mark.parametrize("K, nx, ny, T", SIZES)
def test_exact_at_lag_zero_is_the_exact_filter(K, nx, ny, T):
    model, y, u = case(K, nx, ny, T)
    assert_same(smooth_exact(model, y, u, lag=0), jmlgdsl.filter(model, y, u, algorithm="exact"), 1e-10)


def test_exact_refuses_too_many_histories():
    model, y, u = case(2, 1, 1, 7)
    T = int(np.log2(MAX_HISTORIES))  # 2^(T+1) histories: over the limit
    with pytest.raises(SmoothError, match="mode histories"):
        smooth_exact(model, np.zeros((T, 1)), np.zeros((T, 2)))


# ----------------------------------------------------------------------------- imm
@pytest.mark.parametrize("K, nx, ny, T", SIZES)
def test_imm_at_lag_zero_is_the_imm_filter(K, nx, ny, T):
    model, y, u = case(K, nx, ny, T)
    assert_same(smooth_imm(model, y, u, lag=0), jmlgdsl.filter(model, y, u, algorithm="imm"), 1e-12)


def test_imm_at_lag_zero_is_the_imm_filter_on_the_dryer():
    model = jmlgdsl.load(ROOT / "specs" / "dryer.jmlg")
    sim = jmlgdsl.simulate(model, 300, seed=4, modes="1-100:normal,101-200:grill,201-300:fan")
    y = sim.y.copy()
    y[50:60] = np.nan
    assert_same(smooth_imm(model, y, sim.u, lag=0), jmlgdsl.filter(model, y, sim.u, algorithm="imm"), 1e-10)


@pytest.mark.parametrize("K, nx, ny, T", SIZES)
def test_imm_is_exact_without_state_memory(K, nx, ny, T):
    """With A = 0 the plant is a hidden Markov model: IMM's collapse loses nothing and Kim's backward
    transition p(z_t | z_t+1, y_1:t) is exact, so the IMM smoother equals the exact one."""
    model, y, u = case(K, nx, ny, T)
    model = model.replace(A=np.zeros_like(model.A))
    for lag in lags(T):
        assert_same(smooth_imm(model, y, u, lag=lag), smooth_exact(model, y, u, lag=lag), 1e-10, f"lag {lag}")


@pytest.mark.parametrize("nx, ny", [(1, 1), (2, 2), (2, 1)])
def test_imm_with_one_mode_is_the_rauch_tung_striebel_smoother(nx, ny):
    model, y, u = case(2, nx, ny, 7)
    one = model.replace(**{k: getattr(model, k)[:1] for k in "ABCDFGfg"}, P=[[1.0]], p0=[1.0],
                        mu0=model.mu0[:1], modes=("only",))
    for lag in lags(7):
        assert_same(smooth_imm(one, y, u, lag=lag), smooth_exact(one, y, u, lag=lag), 1e-10, f"lag {lag}")


@pytest.mark.parametrize("smoother", [smooth_exact, smooth_imm])
def test_fixed_lag_row_is_the_offline_smoother_of_the_data_up_to_its_window(smoother):
    """Row t at lag L sees y_1:t+L and nothing else: the off-line smoother of those rows."""
    model, y, u = case(2, 2, 2, 6)
    for lag in (1, 2, 4):
        got = smoother(model, y, u, lag=lag)
        for t in range(len(y) - lag):
            offline = smoother(model, y[:t + lag + 1], u[:t + lag + 1])
            for field in ("mode_posterior", "state_mean", "state_cov"):
                np.testing.assert_allclose(getattr(got, field)[t], getattr(offline, field)[t], rtol=0, atol=1e-12)


# Kim's smoother takes p(z_t | z_t+1, y_1:T) to be p(z_t | z_t+1, y_1:t): it ignores what later
# outputs say, through x_t+1, about when a switch happened. Its error is largest at a switch.
DRYER_RUNS = [None] * 6 + ["1-1:normal,2-7:fan", "1-2:normal,3-7:grill", "1-3:normal,4-7:fan_grill",
                           "1-4:normal,5-7:fan", "1-5:normal,6-7:grill"]


@pytest.mark.parametrize("seed, schedule", list(enumerate(DRYER_RUNS)))
def test_imm_is_within_tolerance_of_exact_on_the_dryer(seed, schedule):
    """On 7-step dryer runs, with and without a switch, at lags 1, 3 and off-line: the same MAP
    modes; mode posteriors within 0.25 in total variation at every step and 0.07 on average; state
    means within 0.01 degC (a fifth of the sensor noise) and variances within 2e-4 degC^2."""
    model = jmlgdsl.load(ROOT / "specs" / "dryer.jmlg")
    sim = jmlgdsl.simulate(model, 7, seed=seed, modes=schedule)
    for lag in (1, 3, None):
        imm, exact = smooth_imm(model, sim.y, sim.u, lag=lag), smooth_exact(model, sim.y, sim.u, lag=lag)
        tv = 0.5 * np.abs(imm.mode_posterior - exact.mode_posterior).sum(axis=1)
        assert (imm.mode_posterior.argmax(1) == exact.mode_posterior.argmax(1)).all()
        assert tv.max() < 0.25 and tv.mean() < 0.07
        np.testing.assert_allclose(imm.state_mean, exact.state_mean, rtol=0, atol=0.01)
        np.testing.assert_allclose(imm.state_cov, exact.state_cov, rtol=0, atol=2e-4)


def test_imm_smoothing_removes_most_diagnosis_errors_on_dryer_sequence_1():
    """The IMM filter misdiagnoses about 1 % of the steps of sequence No. 1, nearly all right after
    a switch; smoothed with all the data, or 10 steps late, at most 0.3 %."""
    model = jmlgdsl.load(ROOT / "specs" / "dryer.jmlg")
    data = read_csv(ROOT / "examples" / "dryer_seq1.csv", model)
    filtered = jmlgdsl.filter(model, data.y, data.u, algorithm="imm")
    assert filtered.diagnosis_error(data.modes) >= 0.8
    for lag in (10, None):
        smoothed = smooth_imm(model, data.y, data.u, lag=lag)
        assert 100 * np.mean(smoothed.mode_posterior.argmax(1) != data.modes) <= 0.3


# ----------------------------------------------------------------------------- arguments
@pytest.mark.parametrize("smoother", [smooth_exact, smooth_imm])
@pytest.mark.parametrize("lag", [-1, 1.5, True, "2"])
def test_a_lag_that_is_not_a_whole_number_is_refused(smoother, lag):
    model, y, u = case(2, 1, 1, 4)
    with pytest.raises(SmoothError, match="lag"):
        smoother(model, y, u, lag=lag)


@pytest.mark.parametrize("smoother", [smooth_exact, smooth_imm])
def test_arrays_of_the_wrong_size_or_no_steps_are_refused(smoother):
    model, y, u = case(2, 1, 1, 4)
    with pytest.raises(SmoothError, match="must be"):
        smoother(model, y, u[:-1])
    with pytest.raises(SmoothError, match="no time steps"):
        smoother(model, y[:0], u[:0])
