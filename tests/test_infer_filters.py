"""Filters against exact answers: Kalman for one mode, enumeration of every history for several."""

import itertools

import numpy as np
import pytest
from infer_models import random_model

import jmlgdsl
from jmlgdsl import DataError, Model
from jmlgdsl.infer import ALGORITHMS, Filter, FilterError, kalman
from jmlgdsl.infer.rbpf import Exact, RaoBlackwellised

RAO_BLACKWELLISED = ("rbpf", "la-rbpf", "fc-rbpf", "imm", "exact")


def simulate_data(model, T, seed):
    """A short trajectory drawn from the model (independent of jmlgdsl.simulate)."""
    rng = np.random.default_rng(seed)
    z = rng.choice(model.K, p=model.p0)
    x = rng.multivariate_normal(model.mu0[z], model.Sigma0)
    u = model.resolve_inputs(None, T)
    ys = []
    for t in range(T):
        z = rng.choice(model.K, p=model.P[z])
        x = model.A[z] @ x + model.F[z] @ u[t] + model.f[z] + model.B[z] @ rng.normal(size=model.B.shape[2])
        ys.append(model.C[z] @ x + model.G[z] @ u[t] + model.g[z] + model.D[z] @ rng.normal(size=model.D.shape[2]))
    return np.array(ys)


def enumerate_histories(model, y):
    """Mode posteriors (T, K) and log p(y_1:T) by running one Kalman filter per full mode history."""
    T, K = len(y), model.K
    u = model.resolve_inputs(None, T)
    post, logp = np.zeros((T, K)), []
    for hist in itertools.product(range(K), repeat=T + 1):
        lw = np.log(model.p0[hist[0]])
        mu, Sig = model.mu0[hist[0]], model.Sigma0
        lws = []
        for t in range(T):
            k = hist[t + 1]
            lw += np.log(model.P[hist[t], k])
            mu, Sig, ll, _, _ = kalman.step(mu, Sig, model.A[k], model.F[k] @ u[t] + model.f[k], model.Q[k],
                                            model.C[k], model.G[k] @ u[t] + model.g[k], model.R[k], y[t])
            lw += ll
            lws.append(lw)
        logp.append(lws)
    logp = np.array(logp)  # (histories, T): log p(z_0:t, y_1:t)
    hists = np.array(list(itertools.product(range(K), repeat=T + 1)))
    for t in range(T):
        # Marginalise over the future modes too: sum p(z_0:t, y_1:t) once per distinct prefix.
        prefix_first = np.all(hists[:, t + 2:] == 0, axis=1)
        lw = logp[prefix_first, t]
        w = np.exp(lw - lw.max())
        post[t] = np.bincount(hists[prefix_first, t + 1], weights=w, minlength=K) / w.sum()
    top = logp[:, -1].max()
    return post, top + np.log(np.exp(logp[:, -1] - top).sum())


@pytest.fixture(scope="module")
def small():
    model = random_model(np.random.default_rng(7), K=2, nx=2, ny=2)
    y = simulate_data(model, 5, seed=1)
    return model, y, enumerate_histories(model, y)


def one_mode_model():
    rng = np.random.default_rng(2)
    m = random_model(rng, K=2, nx=2, ny=2)
    return Model.from_arrays(A=m.A[:1], B=m.B[:1], C=m.C[:1], D=m.D[:1], F=m.F[:1], G=m.G[:1], f=m.f[:1],
                             g=m.g[:1], P=[[1.0]], p0=[1.0], mu0=m.mu0[:1], Sigma0=m.Sigma0,
                             input_defaults=m.input_defaults)


@pytest.mark.parametrize("algorithm", RAO_BLACKWELLISED)
def test_one_mode_equals_kalman_filter(algorithm):
    model = one_mode_model()
    y = simulate_data(model, 30, seed=3)
    y[4, 1] = np.nan
    y[9] = np.nan
    u = model.resolve_inputs(None, 30)
    mu, Sig, loglik, means = model.mu0[0], model.Sigma0, 0.0, []
    for t in range(30):
        mu, Sig, ll, _, _ = kalman.step(mu, Sig, model.A[0], model.F[0] @ u[t] + model.f[0], model.Q[0],
                                        model.C[0], model.G[0] @ u[t] + model.g[0], model.R[0], y[t])
        loglik += ll
        means.append(mu)
    res = jmlgdsl.filter(model, y, algorithm=algorithm, particles=3, seed=0)
    np.testing.assert_allclose(res.state_mean, means, atol=1e-8)
    np.testing.assert_allclose(res.state_cov[-1], Sig, atol=1e-8)
    assert res.loglik == pytest.approx(loglik, abs=1e-8)


def test_states_in_different_units_keep_their_own_precision():
    # A temperature (variance ~1) beside a concentration (variance ~1e-8) in one mode: every shared
    # covariance entry must match the Kalman filter relative to its own state's variance.
    model = Model.from_arrays(A=np.diag([0.9, 0.999]), B=np.diag([1.0, 1e-5]), C=np.eye(2), D=np.diag([1.0, 1e-4]),
                              P=[[1.0]], p0=[1.0], mu0=[0.0, 0.0], Sigma0=np.diag([1.0, 1e-6]))
    y = np.random.default_rng(0).normal(size=(200, 2)) * [1.0, 1e-4]
    mu, Sig, variances = model.mu0[0], model.Sigma0, []
    for t in range(len(y)):
        mu, Sig, _, _, _ = kalman.step(mu, Sig, model.A[0], 0.0, model.Q[0], model.C[0], 0.0, model.R[0], y[t])
        variances.append(np.diag(Sig))
    res = jmlgdsl.filter(model, y, algorithm="la-rbpf", particles=2, seed=0)
    np.testing.assert_allclose(np.diagonal(res.state_cov, axis1=1, axis2=2), variances, rtol=1e-8)


def test_exact_equals_enumeration(small):
    model, y, (post, loglik) = small
    res = jmlgdsl.filter(model, y, algorithm="exact")
    np.testing.assert_allclose(res.mode_posterior, post, atol=1e-10)
    assert res.loglik == pytest.approx(loglik, abs=1e-9)


def test_fc_rbpf_is_exact_while_particles_cover_every_history(small):
    model, y, (post, loglik) = small
    # K = 2 atoms at t = 0, so 2^(t+1) histories at step t: 32 particles cover all five steps.
    res = jmlgdsl.filter(model, y, algorithm="fc-rbpf", particles=32, seed=0)
    np.testing.assert_allclose(res.mode_posterior, post, atol=1e-10)
    assert res.loglik == pytest.approx(loglik, abs=1e-9)
    partial = jmlgdsl.filter(model, y, algorithm="fc-rbpf", particles=8, seed=0)
    np.testing.assert_allclose(partial.mode_posterior[:3], post[:3], atol=1e-10)


@pytest.mark.parametrize("algorithm, particles, threshold", [
    ("pf", 4000, 1.0), ("rbpf", 1000, 1.0), ("rbpf", 1000, 0.5), ("la-rbpf", 300, 1.0), ("la-rbpf", 300, 0.5),
    ("fc-rbpf", 12, 1.0)])
def test_posteriors_converge_to_exact(small, algorithm, particles, threshold):
    model, y, (post, _) = small
    runs = np.array([jmlgdsl.filter(model, y, algorithm=algorithm, particles=particles, seed=s,
                                    ess_threshold=threshold).mode_posterior for s in range(8)])
    se = runs.std(axis=0) / np.sqrt(len(runs))
    # Monte Carlo error of the average of 8 runs (5 standard errors) plus the O(1/N) bias of a
    # self-normalised estimate, bounded generously by 2/N.
    assert np.all(np.abs(runs.mean(axis=0) - post) <= 5 * se + 2.0 / particles)
    # And one run alone is within a few of its own standard deviations.
    assert np.all(np.abs(runs[0] - post) <= 5 * runs.std(axis=0) + 2.0 / particles)


def test_la_rbpf_likelihood_is_unbiased(small):
    model, y, (_, loglik) = small
    ratios = np.array([np.exp(jmlgdsl.filter(model, y, algorithm="la-rbpf", particles=2, seed=s).loglik - loglik)
                       for s in range(1500)])
    assert abs(ratios.mean() - 1.0) <= 4 * ratios.std() / np.sqrt(len(ratios))


def test_fully_missing_row_only_predicts(small):
    model, y, _ = small
    y = y.copy()
    y[3] = np.nan
    res = jmlgdsl.filter(model, y, algorithm="exact")
    np.testing.assert_allclose(res.mode_posterior[3], res.mode_posterior[2] @ model.P, atol=1e-12)
    assert res.loglik_steps[3] == pytest.approx(0.0, abs=1e-12)
    imm = jmlgdsl.filter(model, y, algorithm="imm")
    np.testing.assert_allclose(imm.mode_posterior[3], imm.mode_posterior[2] @ model.P, atol=1e-12)
    assert np.isnan(res.residuals[3]).all() and np.isfinite(res.y_pred[3]).all()


@pytest.mark.parametrize("algorithm", ["exact", "imm", "la-rbpf", "pf"])
def test_partial_rows_equal_the_model_without_that_output(small, algorithm):
    model, y, _ = small
    y = y.copy()
    y[:, 1] = np.nan
    reduced = model.replace(C=model.C[:, :1], D=model.D[:, :1], G=model.G[:, :1], g=model.g[:, :1],
                            outputs=model.outputs[:1])
    full = jmlgdsl.filter(model, y, algorithm=algorithm, particles=20, seed=4)
    alone = jmlgdsl.filter(reduced, y[:, :1], algorithm=algorithm, particles=20, seed=4)
    np.testing.assert_allclose(full.mode_posterior, alone.mode_posterior, atol=1e-9)
    assert full.loglik == pytest.approx(alone.loglik, abs=1e-9)


@pytest.mark.parametrize("algorithm", sorted(ALGORITHMS))
def test_extreme_outlier_stays_finite(small, algorithm):
    model, y, _ = small
    y = y.copy()
    y[2, 0] = 1e12
    res = jmlgdsl.filter(model, y, algorithm=algorithm, particles=10, seed=0)
    np.testing.assert_allclose(res.mode_posterior.sum(axis=1), 1.0)
    assert not np.isnan(res.mode_posterior).any() and np.isfinite(res.loglik_steps).all()
    assert np.isfinite(res.state_cov).all()


@pytest.mark.parametrize("reading", [np.inf, -1e200])
def test_impossible_readings_count_as_missing(small, reading):
    model, y, _ = small
    y = y.copy()
    y[2, 0] = np.nan
    missing = jmlgdsl.filter(model, y, algorithm="la-rbpf", particles=10, seed=0)
    y[2, 0] = reading
    absurd = jmlgdsl.filter(model, y, algorithm="la-rbpf", particles=10, seed=0)
    np.testing.assert_array_equal(absurd.mode_posterior, missing.mode_posterior)
    assert np.isnan(absurd.residuals[2, 0])


@pytest.mark.parametrize("algorithm", ["pf", "rbpf", "la-rbpf", "fc-rbpf"])
def test_same_seed_same_bytes(algorithm):
    model = random_model(np.random.default_rng(9), K=3)
    y = simulate_data(model, 40, seed=2)
    a, b, c = (jmlgdsl.filter(model, y, algorithm=algorithm, particles=15, seed=s) for s in (5, 5, 6))
    for field in ("mode_posterior", "state_mean", "state_cov", "y_pred", "loglik_steps", "ess"):
        assert getattr(a, field).tobytes() == getattr(b, field).tobytes()
    assert a.mode_posterior.tobytes() != c.mode_posterior.tobytes()


def test_streaming_steps_equal_the_batch_call(small):
    model, y, _ = small
    f = Filter(model, algorithm="la-rbpf", particles=6, seed=3)
    steps = [f.step(row) for row in y]
    batch = jmlgdsl.filter(model, y, algorithm="la-rbpf", particles=6, seed=3)
    np.testing.assert_array_equal([s.mode_posterior for s in steps], batch.mode_posterior)
    assert f.loglik == batch.loglik and [s.map_mode for s in steps] == list(batch.map_modes)


def test_state_moments_match_the_mixture_of_histories(small):
    model, y, _ = small
    fc = jmlgdsl.filter(model, y, algorithm="fc-rbpf", particles=64, seed=0)
    imm = jmlgdsl.filter(model, y, algorithm="imm")
    exact = jmlgdsl.filter(model, y, algorithm="exact")
    np.testing.assert_allclose(fc.state_mean, exact.state_mean, atol=1e-10)
    np.testing.assert_allclose(fc.state_cov, exact.state_cov, atol=1e-10)
    # IMM collapses the mixture, so it is close to but not the exact answer.
    assert np.abs(imm.state_mean - exact.state_mean).max() < 0.5
    assert np.all(np.linalg.eigvalsh(exact.state_cov) > 0)


def test_user_errors_are_clear(small):
    model, y, _ = small
    with pytest.raises(FilterError, match="unknown filter 'kalman'; choose from pf, rbpf"):
        Filter(model, algorithm="kalman")
    with pytest.raises(FilterError, match="positive whole number"):
        Filter(model, algorithm="pf", particles=0)
    with pytest.raises(FilterError, match="unknown resampling scheme"):
        Filter(model, resampling="best")
    for u in ([np.nan], None):
        with pytest.raises(DataError, match="t=1: no value and no default for input u1"):
            Filter(model.replace(input_defaults=[np.nan])).step(y[0], u)
    with pytest.raises(DataError, match=r"t=1: 3 outputs given, expected 2 \(y1, y2\)"):
        Filter(model).step([1.0, 2.0, 3.0])
    with pytest.raises(DataError, match=r"t=1: 2 inputs given, expected 1 \(u1\)"):
        Filter(model).step(y[0], [1.0, 2.0])
    with pytest.raises(DataError, match=r"y must have shape \(T, 2\)"):
        jmlgdsl.filter(model, np.zeros((4, 3)))
    # a whole record is checked at once, and the error names the first row without an input
    u = np.ones((len(y), 1))
    u[[2, 4]] = np.nan
    with pytest.raises(DataError, match="t=3: no value and no default for input u1"):
        jmlgdsl.filter(model.replace(input_defaults=[np.nan]), y, u)


@pytest.mark.parametrize("algorithm", ["imm", "la-rbpf"])
def test_a_whole_record_filters_as_its_rows_do_one_at_a_time(small, algorithm):
    # unmeasured (NaN), infinite and absurd readings, and inputs left to the spec's default
    model, y, _ = small
    y, u = y.copy(), np.full((len(y), 1), 0.3)
    y[1, 0], y[2, 1], y[3] = np.nan, np.inf, [1e120, 0.5]
    u[[0, 4]] = np.nan
    model = model.replace(input_defaults=[0.3])
    whole = jmlgdsl.filter(model, y, u, algorithm=algorithm, seed=4)
    f = Filter(model, algorithm, seed=4)
    rows = [f.step(y_t, u_t) for y_t, u_t in zip(y, u)]
    np.testing.assert_array_equal(whole.mode_posterior, [r.mode_posterior for r in rows])
    np.testing.assert_array_equal(whole.state_mean, [r.state_mean for r in rows])
    np.testing.assert_array_equal(whole.residuals, [r.residual for r in rows])
    assert np.isnan(whole.residuals[[1, 2, 3], [0, 1, 0]]).all()
    np.testing.assert_array_equal(whole.loglik_steps,
                                  jmlgdsl.filter(model, y, np.full_like(u, 0.3), algorithm=algorithm, seed=4).loglik_steps)


def test_exact_refuses_too_many_gaussians(small, monkeypatch):
    model, y, _ = small
    monkeypatch.setattr(Exact, "max_gaussians", 20)
    with pytest.raises(FilterError, match="exact filtering would need 32 Gaussians.*limit of 20"):
        jmlgdsl.filter(model, y, algorithm="exact")
    # two initial modes: three steps end with 16 histories; the 32 Gaussians a fourth step would need
    # are never asked for (the old check refused at the third step already)
    assert jmlgdsl.filter(model, y[:3], algorithm="exact").T == 3


def test_result_shapes_and_deterministic_filters_have_no_particles(small):
    model, y, _ = small
    res = jmlgdsl.filter(model, y, algorithm="imm", particles=50)
    assert res.particles is None and np.isnan(res.ess).all()
    assert res.mode_posterior.shape == (5, 2) and res.state_cov.shape == (5, 2, 2) and res.T == 5
    empty = jmlgdsl.filter(model, np.zeros((0, 2)))
    assert empty.mode_posterior.shape == (0, 2) and empty.state_cov.shape == (0, 2, 2) and empty.loglik == 0.0


@pytest.mark.parametrize("algorithm", ["la-rbpf", "fc-rbpf", "rbpf"])
def test_compacting_the_covariance_graph_changes_nothing(monkeypatch, algorithm):
    model = random_model(np.random.default_rng(4), K=3)
    y = simulate_data(model, 30, seed=5)
    kept = jmlgdsl.filter(model, y, algorithm=algorithm, particles=20, seed=1)
    monkeypatch.setattr(RaoBlackwellised, "spare_nodes", -10**9)  # compact after every step
    compacted = jmlgdsl.filter(model, y, algorithm=algorithm, particles=20, seed=1)
    np.testing.assert_allclose(compacted.mode_posterior, kept.mode_posterior, atol=1e-9)
    np.testing.assert_allclose(compacted.state_mean, kept.state_mean, atol=1e-9)


def test_imm_keeps_settled_kalman_pieces_without_changing_the_result(monkeypatch):
    """Once the posterior sits on one mode the mixed covariances repeat and IMM keeps each mode's
    Kalman pieces; the result equals recomputing them at every step (SURE < 0: never sure) to
    rounding, through switches and partly and fully missing readings."""
    from jmlgdsl.infer import imm
    from jmlgdsl.simulation.linear import simulate

    model = random_model(np.random.default_rng(8), K=3, nx=3, ny=6, stay=0.98)
    sim = simulate(model, modes=np.repeat([0, 1, 2, 0], 60), seed=4)
    y = sim.y.copy()
    y[100, :2] = np.nan
    y[170] = np.nan
    calls = []
    step = kalman.covariance_step
    monkeypatch.setattr(kalman, "covariance_step", lambda *a: calls.append(len(a[0])) or step(*a))
    kept = jmlgdsl.filter(model, y, sim.u, algorithm="imm")
    assert sum(calls) < 0.5 * 3 * len(y)  # most steps computed no mode's pieces
    monkeypatch.setattr(imm, "SURE", -1.0)
    calls.clear()
    fresh = jmlgdsl.filter(model, y, sim.u, algorithm="imm")
    assert sum(calls) == 3 * len(y)
    np.testing.assert_allclose(kept.mode_posterior, fresh.mode_posterior, atol=1e-9)
    np.testing.assert_allclose(kept.state_mean, fresh.state_mean, atol=1e-9)
    np.testing.assert_allclose(kept.loglik_steps, fresh.loglik_steps, rtol=1e-9)
    assert kept.diagnosis_error(sim.modes) < 5.0


def wandering_bank(n=16, seed=0):
    """Many sensors, each reading its state, in units 10^6 apart, with nearly one shared noise and
    dynamics whose products cancel: the Kalman covariances reach their fixed point only to rounding,
    1e-12 relative from step to step, and to kalman.SETTLED late if ever. Two modes, healthy and a
    bias. (*) Eigenvectors conditioned near 1e3: at 1e4 the rounding of V^-1 grows the filter's
    transient past float range on some BLAS kernels."""
    rng = np.random.default_rng(seed)
    s = 10.0 ** np.linspace(-3, 3, n)
    V = rng.normal(size=(n, n)) @ np.diag(10.0 ** np.linspace(0, -3, n)) @ rng.normal(size=(n, n))  # (*)
    A = (V @ np.diag(rng.uniform(-0.9, 0.9, n)) @ np.linalg.inv(V)) * s[:, None] / s[None, :]
    B = np.linalg.cholesky((1 - 1e-6) * np.ones((n, n)) + 1e-6 * np.eye(n)) * s[:, None]
    return Model.from_arrays(A=np.stack([A, A]), B=np.stack([B, B]), C=np.eye(n), D=1e-6 * np.diag(s),
                             f=np.stack([np.zeros(n), 10 * s]), P=[[0.99, 0.01], [0.01, 0.99]], p0=[1.0, 0.0],
                             mu0=np.zeros((2, n)), Sigma0=np.diag(s ** 2))


def test_imm_keeps_kalman_pieces_that_settle_only_to_their_rounding(monkeypatch):
    """A bank whose covariances wander by their rounding (innovation covariance conditioned near 1e6
    once scaled) settles to the covariance step's own rounding error, eps * kappa, and keeps its
    pieces while the posterior is sure. The result is recomputing them at every step to what that
    tolerance allows: its densities go through S^-1, which moves kappa times as much (relative),
    so the log-likelihoods agree to 1e-5 (eps * kappa^2 bounds it; the recomputed ones wander too)."""
    from jmlgdsl.infer import imm
    from jmlgdsl.simulation.linear import simulate

    model = wandering_bank()
    sim = simulate(model, modes=np.zeros(200, dtype=int), seed=3)
    calls = []
    step = kalman.covariance_step
    monkeypatch.setattr(kalman, "covariance_step", lambda *a: calls.append(len(a[0])) or step(*a))
    kept = jmlgdsl.filter(model, sim.y, algorithm="imm")
    assert (kept.mode_posterior[20:, 0] > 1 - 1e-12).all()
    assert sum(calls) < 0.05 * 2 * len(sim.y)  # few steps computed a mode's pieces (SETTLED alone: 38 of 400)
    monkeypatch.setattr(imm, "SURE", -1.0)
    calls.clear()
    fresh = jmlgdsl.filter(model, sim.y, algorithm="imm")
    assert sum(calls) == 2 * len(sim.y)
    np.testing.assert_allclose(kept.mode_posterior, fresh.mode_posterior, atol=1e-9)
    np.testing.assert_allclose(kept.loglik_steps, fresh.loglik_steps, rtol=1e-5)
    np.testing.assert_allclose(kept.state_mean, fresh.state_mean, rtol=1e-9, atol=1e-12)
