"""jmlgdsl.smooth and Filter(lag=L): lag 0 is the filter byte for byte; the on-line fixed-lag
records equal the whole-sequence smoothers; the particle smoothers reach exact as N grows."""

import numpy as np
import pytest
from infer_models import random_model

import jmlgdsl
from jmlgdsl.infer import ALGORITHMS, FilterError
from jmlgdsl.infer.smooth import smooth_exact, smooth_imm
from jmlgdsl.simulation.linear import simulate

FIELDS = ("mode_posterior", "state_mean", "state_cov", "y_pred", "residuals", "loglik_steps")


@pytest.fixture(scope="module")
def case():
    rng = np.random.default_rng(11)
    model = random_model(rng, K=3, nx=2, ny=2, nu=1)
    sim = simulate(model, 6, seed=3)
    y = sim.y.copy()
    y[2, 1] = np.nan
    return model, y, sim.u


@pytest.mark.parametrize("algorithm", sorted(ALGORITHMS))
def test_lag_zero_is_the_filter_byte_for_byte(case, algorithm):
    model, y, u = case
    a = jmlgdsl.smooth(model, y, u, algorithm=algorithm, lag=0, particles=7, seed=2)
    b = jmlgdsl.filter(model, y, u, algorithm=algorithm, particles=7, seed=2)
    for name in FIELDS:
        assert getattr(a, name).tobytes() == getattr(b, name).tobytes(), name


def online(model, y, u, lag, **kw):
    """Every record of an on-line fixed-lag run, checking what step() gives out and when."""
    f = jmlgdsl.Filter(model, lag=lag, **kw)
    given = [f.step(y_t, u_t) for y_t, u_t in zip(y, u)]
    held = min(lag, len(y)) if lag is not None else len(y)
    assert given[:held] == [None] * held and None not in given[held:]
    records = given[held:] + f.flush()
    assert [r.t for r in records] == list(range(1, len(y) + 1)) and f.flush() == []
    return np.array([r.mode_posterior for r in records]), np.array([r.state_mean for r in records])


@pytest.mark.parametrize("lag", [1, 3, 10, None])
def test_online_imm_equals_kims_smoother_of_the_same_lag(case, lag):
    model, y, u = case
    post, mean = online(model, y, u, lag, algorithm="imm")
    expected = smooth_imm(model, y, u, lag)
    np.testing.assert_allclose(post, expected.mode_posterior, atol=1e-10)
    np.testing.assert_allclose(mean, expected.state_mean, atol=1e-10)


@pytest.mark.parametrize("algorithm, particles", [("exact", None), ("fc-rbpf", 3 ** 7)])
@pytest.mark.parametrize("lag", [1, 2, 5, None])
def test_tracing_every_history_back_is_the_exact_smoother(case, algorithm, particles, lag):
    model, y, u = case  # 3^7 candidates at most: fc-rbpf with that many particles keeps them all
    post, _ = online(model, y, u, lag, algorithm=algorithm, particles=particles, seed=1)
    np.testing.assert_allclose(post, smooth_exact(model, y, u, lag).mode_posterior, atol=1e-10)


@pytest.mark.parametrize("algorithm", ["exact", "imm"])
@pytest.mark.parametrize("lag", [2, None])
def test_smooth_gives_the_state_moments_of_the_deterministic_smoothers(case, algorithm, lag):
    model, y, u = case
    result = jmlgdsl.smooth(model, y, u, algorithm=algorithm, lag=lag)
    expected = (smooth_exact if algorithm == "exact" else smooth_imm)(model, y, u, lag)
    np.testing.assert_allclose(result.state_cov, expected.state_cov, atol=1e-10)
    assert result.lag == lag
    np.testing.assert_array_equal(result.y_pred, jmlgdsl.filter(model, y, u, algorithm=algorithm).y_pred)


@pytest.mark.parametrize("algorithm", ["pf", "rbpf", "la-rbpf"])
def test_particle_smoothers_reach_exact_as_particles_grow(case, algorithm):
    model, y, u = case
    exact = smooth_exact(model, y, u, None).mode_posterior
    errors = []
    for n in (50, 5000):
        result = jmlgdsl.smooth(model, y, u, algorithm=algorithm, particles=n, seed=5)
        errors.append(np.abs(result.mode_posterior - exact).max())
    # A posterior estimated from n weighted lines has a standard deviation of at most 1 / (2 sqrt(n_eff));
    # resampling and the bootstrap filter's sampled states leave n_eff well above n / 20 on six steps.
    assert errors[1] < 5 / (2 * np.sqrt(5000 / 20))
    assert errors[1] < errors[0]


def test_a_bad_lag_is_refused(case):
    model, _, _ = case
    for lag in (-1, 1.5, True):
        with pytest.raises(FilterError, match="the lag must be a whole number of steps"):
            jmlgdsl.Filter(model, lag=lag)


@pytest.mark.parametrize("options, lag", [(["--lag", "3"], 3), (["--smooth"], None)])
def test_run_writes_the_smoothed_table_and_says_so(tmp_path, capsys, options, lag):
    from jmlgdsl.cli import main
    from jmlgdsl.data import read_csv, write_columns
    from jmlgdsl.infer.table import read_table

    model = jmlgdsl.load("specs/dryer.jmlg")
    data = tmp_path / "seq.csv"
    write_columns(data, simulate(model, modes="1-30:normal,31-60:grill", seed=4).columns())
    out = tmp_path / "out.csv"
    assert main(["run", "specs/dryer.jmlg", str(data), "-o", str(out), *options]) == 0
    said = "smoothed off-line" if lag is None else "smoothed with a lag of 3 steps"
    assert f"dryer: 60 steps, filter imm, {said}" in capsys.readouterr().out
    assert out.read_text().startswith("# smoothed: p_<mode>, <state>_mean given ")
    table = read_table(out)
    d = read_csv(data, model)
    expected = jmlgdsl.smooth(model, d.y, d.u, lag=lag)
    np.testing.assert_allclose(table.mode_posterior, expected.mode_posterior, atol=1e-9)
    assert table.given == ("all the data" if lag is None else "the data up to 3 rows later")
