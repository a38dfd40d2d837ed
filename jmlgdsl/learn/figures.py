"""Figures for learning: a step test against its FOPDT fit, and a learned mode's validation
(residual autocorrelation, input-residual cross-correlation, simulated against measured output)."""

from __future__ import annotations

import numpy as np

from ..diagnosis.drawing import figure, save

#: Resolution of the learning figures (dots per inch).
DPI = 110


def plot_step(fit, y, path, title="Step test", ylabel="output"):
    """Measured step response and the fitted FOPDT curve; writes `path`."""
    y = np.asarray(y, float).ravel()
    t = np.arange(len(y)) * fit.dt
    fig = figure(figsize=(7, 3.5))
    ax = fig.subplots()
    ax.plot(t, y, ".", ms=2, color="0.5", label="measured")
    ax.plot(t, fit.response(len(y)), color="C3",
            label=f"FOPDT: K {fit.gain:.3g}, tau {fit.tau:.3g} s, dead time {fit.delay * fit.dt:g} s")
    ax.axvline(fit.step * fit.dt, color="0.8", lw=0.8)
    ax.set(xlabel="time [s]", ylabel=ylabel, title=title)
    ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    save(fig, path, DPI)
    return path


def _stems(ax, lags, values, band, title):
    """Correlations as stems over lags, with the 99 % band shaded."""
    ax.axhspan(-band, band, color="C0", alpha=0.15, label="99 % band")
    ax.vlines(lags, 0, values, color="k", lw=1)
    ax.plot(lags, values, "o", ms=3, color="k")
    ax.axhline(0, color="0.6", lw=0.6)
    ax.set(title=title, xlabel="lag [samples]")


def plot_validation(learned, path, dt=1.0, ylabel="output", input_name="input"):
    """Residual autocorrelation, cross-correlation with the first input and the free-run fit of one
    learned mode (first output); writes `path`."""
    v = learned.validation
    y = learned.experiment.y[:, 0]
    t = np.arange(1, len(y) + 1) * dt
    fig = figure(figsize=(9, 6))
    grid = fig.add_gridspec(2, 2)
    ax = fig.add_subplot(grid[0, 0])
    _stems(ax, np.arange(1, v.autocorr.shape[1] + 1), v.autocorr[0], v.band, "residual autocorrelation")
    ax.legend(loc="upper right", fontsize=8)
    ax = fig.add_subplot(grid[0, 1])
    if v.crosscorr.shape[1]:
        _stems(ax, np.arange(v.crosscorr.shape[2]), v.crosscorr[0, 0], v.band,
               f"{input_name}-residual cross-correlation")
    ax = fig.add_subplot(grid[1, :])
    ax.plot(t, y, color="0.6", lw=0.8, label="measured")
    ax.plot(t, v.simulated[:, 0], color="C3", lw=1, label=f"simulated from the input (fit {v.fit[0]:.1f} %)")
    ax.set(xlabel="time [s]", ylabel=ylabel)
    ax.legend(loc="best", fontsize=8)
    verdict = "pass" if v.passed else "FAIL"
    fig.suptitle(f"Mode {learned.name}: {learned.structure}; residual tests {verdict}")
    fig.tight_layout()
    save(fig, path, DPI)
    return path
