"""FOPDT step-test fit: exact recovery without noise, tolerance with noise, lagged form, errors."""

from dataclasses import replace

import numpy as np
import pytest

from jmlgdsl.errors import DataError
from jmlgdsl.learn import steptest


def step_data(gain=1.94, tau=30.45, delay=3, dt=1.0, T=300, at=50, noise=0.0, seed=0):
    """A sampled FOPDT step response from 50.52 at input 15 to input 20, simulated recursively."""
    a = np.exp(-dt / tau)
    u = np.full(T, 15.0)
    u[at:] = 20.0
    y, prev = np.empty(T), 50.52
    for t in range(T):
        prev = a * prev + gain * (1 - a) * u[max(t - delay, 0)] + (1 - a) * (50.52 - gain * 15.0)
        y[t] = prev
    return y + noise * np.random.default_rng(seed).standard_normal(T), u


def test_noise_free_step_is_recovered_exactly():
    y, u = step_data()
    fit = steptest.fit_fopdt(y, u, dt=1.0, max_delay=10)
    assert fit.delay == 3 and fit.step == 50
    assert fit.gain == pytest.approx(1.94, rel=1e-7)
    assert fit.tau == pytest.approx(30.45, rel=1e-6)
    assert fit.y0 == pytest.approx(50.52, rel=1e-9)
    assert np.allclose(fit.response(len(y)), y, atol=1e-6)


def test_noisy_step_within_its_standard_errors():
    """With noise sd s over N samples after the step, the gain's standard error is about
    s / (du sqrt(N)); the fit must land within a few of them (the time constant likewise)."""
    s, T, at = 0.05, 400, 50
    y, u = step_data(noise=s, T=T, at=at, seed=3)
    fit = steptest.fit_fopdt(y, u, dt=1.0)
    assert fit.delay == 3
    assert abs(fit.gain - 1.94) < 6 * s / (5.0 * np.sqrt(T - at))
    assert abs(fit.tau - 30.45) / 30.45 < 0.03


def test_lagged_form_reproduces_the_fitted_response():
    """The fit in the lagged basis is the FOPDT itself: one output lag and the input at the dead
    time, order delay + 1, with the same response, gain and pole (and nothing else free for EM)."""
    y, u = step_data(delay=2, noise=0.02)
    fit = steptest.fit_fopdt(y, u, max_delay=6)
    mode = fit.lagged()
    assert mode.n == fit.delay + 1 and mode.lags.free(1, 1).sum() == 3
    ss = replace(mode, mu0=np.full(mode.n, fit.y0), Sigma0=np.zeros((mode.n, mode.n))).statespace([u[0]])
    assert np.allclose(ss.free_run(u[:, None])[:, 0], fit.response(len(y)), atol=1e-9)
    assert ss.gain()[0, 0] == pytest.approx(fit.gain)
    assert mode.poles()[0] == pytest.approx(np.exp(-1.0 / fit.tau))


def test_input_must_change_exactly_once():
    y, u = step_data()
    u[200:] = 15.0
    with pytest.raises(DataError, match="changes exactly once; this one changes 2 times"):
        steptest.fit_fopdt(y, u)
    with pytest.raises(DataError, match="changes 0 times"):
        steptest.fit_fopdt(y, np.full_like(u, 15.0))


def test_a_step_the_output_does_not_answer_is_refused():
    """An output that stays at its level, plus noise, is no step response: refused before the
    search over every dead time, which found a gain of about zero and a dead time of minutes."""
    y, u = step_data(noise=0.1, seed=4)
    flat = y[0] + 0.1 * np.random.default_rng(4).standard_normal(len(y))
    with pytest.raises(DataError, match="does not respond to the input step at row 51 of the experiment"):
        steptest.fit_fopdt(flat, u)
    assert steptest.fit_fopdt(y, u, max_delay=5).delay == 3  # the same noise on a real response still fits


def test_learn_names_the_file_and_the_step_without_a_response(tmp_path, capsys):
    """examples/learning/step.csv with the output held at its level plus noise: learn --fopdt stops
    with one error naming the file and the step, in well under the 20 s the fit took."""
    import csv
    import time
    from pathlib import Path

    from jmlgdsl.cli import main

    rows = list(csv.DictReader(open(Path(__file__).resolve().parents[1] / "examples" / "learning" / "step.csv")))
    noise = np.random.default_rng(0).normal(0, 0.1, len(rows))
    data = tmp_path / "flat.csv"
    data.write_text("time,current,temp\n" + "".join(f"{r['time']},{r['current']},{50.5 + e:.4f}\n"
                                                    for r, e in zip(rows, noise)))
    start = time.perf_counter()
    assert main(["learn", "--fopdt", "--mode", f"normal={data}", "--input", "current", "--output", "temp",
                 "-o", str(tmp_path / "flat.jmlg")]) == 2
    assert time.perf_counter() - start < 5
    err = capsys.readouterr().err
    assert err.startswith(f"error: {data}: the output does not respond to the input step at row 51") and \
        err.count("\n") == 1, err
    assert not (tmp_path / "flat.jmlg").exists()
