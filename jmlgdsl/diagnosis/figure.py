"""The figure of one diagnosis (`jmlgdsl run --plot`, `jmlgdsl plot`): the mode posterior over time
with the MAP and true modes, measured against predicted outputs, and the residuals."""

from __future__ import annotations

import matplotlib
import numpy as np

from .drawing import figure, save
from ..infer.table import given
from ..names import plural


def _mode_colors(K):
    """One RGBA colour per mode (tab10, or tab20 beyond ten modes)."""
    return matplotlib.colormaps["tab10" if K <= 10 else "tab20"](np.arange(K) % 20)


def diagnosis_figure(path, mode_names, posterior, time, y, y_pred, output_names, true_modes=None,
                     time_label="time (s)", output_units=None, title="", given="the data so far", y_sd=None,
                     anomaly=None):
    """One run at a glance: MAP (and true) mode over time, the mode posterior as a heat map, then for
    each output the measured and predicted values, and the residuals: divided by the prediction's
    standard deviation when `y_sd` is given, so that outputs of different units and noise share one
    scale (raw, a voltage's residuals flatten those of the other sensors), else as measured.

    posterior (T, K); time (T,); y, y_pred (T, ny) with NaN where not measured; true_modes (T,) indices
    or None; output_units maps output names to unit text; `given` says what the posterior is
    conditioned on (the filter's data so far, or a smoother's); y_sd (T, ny) the one-step predictive
    standard deviation (NaN where not known); anomaly (T,) the data's 0/1 anomaly labels, shaded under
    the residuals.
    """
    posterior = np.asarray(posterior, dtype=float)
    y, y_pred = np.atleast_2d(np.asarray(y, float).T).T, np.atleast_2d(np.asarray(y_pred, float).T).T
    T, K = posterior.shape
    ny = y.shape[1]
    units = output_units or {}
    heights = [max(1.0, 0.25 * K), max(1.5, 0.3 * K)] + [1.6] * ny + [1.2]
    fig = figure(figsize=(9, 1.0 + sum(heights)), layout="constrained")
    axes = fig.subplots(len(heights), 1, sharex=True, gridspec_kw={"height_ratios": heights})
    colors = _mode_colors(K)
    edges = _edges(time)
    map_modes = posterior.argmax(axis=1)

    ax = axes[0]
    if true_modes is not None:
        ax.step(time, np.asarray(true_modes), where="mid", color="black", lw=4, alpha=0.25, label="true mode")
        wrong = 100.0 * np.mean(map_modes != np.asarray(true_modes))
        ax.set_title(f"diagnosis error {wrong:.1f} % of steps", fontsize="small", loc="right")
    ax.step(time, map_modes, where="mid", color="tab:blue", lw=1.2, label="MAP mode")
    ax.set_ylabel("mode")
    ax.legend(loc="lower left", bbox_to_anchor=(0, 1), fontsize="small", ncol=2, frameon=False, borderaxespad=0)

    ax = axes[1]
    image = ax.pcolormesh(edges, np.arange(K + 1) - 0.5, posterior.T, cmap="Greys", vmin=0, vmax=1,
                          shading="flat", rasterized=True)
    ax.set_ylabel("p(mode | " + given.replace("the data ", "data\n") + ")", fontsize="small")
    fig.colorbar(image, ax=ax, pad=0.01, aspect=10).set_label("probability", fontsize="small")
    for ax in axes[:2]:
        ax.set_yticks(np.arange(K), mode_names, fontsize="small" if K <= 10 else "x-small")
        ax.set_ylim(K - 0.5, -0.5)
        for label, color in zip(ax.get_yticklabels(), colors):
            label.set_color(color)

    for j in range(ny):
        ax = axes[2 + j]
        ax.plot(time, y[:, j], color="0.35", lw=1.6, alpha=0.6, label="measured")
        ax.plot(time, y_pred[:, j], color="tab:blue", lw=0.7, label="predicted (one step ahead)")
        unit = units.get(output_names[j])
        ax.set_ylabel(output_names[j] + (f"\n({unit})" if unit else ""))
        _shade_true_modes(ax, edges, true_modes, colors)
    axes[2].legend(loc="lower right", bbox_to_anchor=(1, 1), fontsize="small", ncol=3, frameon=False,
                   borderaxespad=0, title="background: true mode (colours as the mode names)" if true_modes
                   is not None else None, title_fontsize="x-small")

    ax = axes[-1]
    residuals = y - y_pred
    if y_sd is not None:
        residuals = residuals / np.atleast_2d(np.asarray(y_sd, float).T).T
        for level in (-3, 3):
            ax.axhline(level, color="0.5", lw=0.6, ls=":")
    for j in range(ny):
        ax.plot(time, residuals[:, j], lw=0.7, label=output_names[j])
    ax.axhline(0, color="black", lw=0.6)
    ax.set_ylabel("residual / its\npredicted sd" if y_sd is not None else "residual\n(measured −\npredicted)")
    shaded = _shade_anomaly(ax, edges, anomaly)
    if ny > 1 or shaded:
        ax.legend(loc="upper right", fontsize="small", ncol=min(ny + shaded, 4))
    ax.set_xlabel(time_label)
    ax.set_xlim(edges[0], edges[-1])
    fig.suptitle(title or "Mode diagnosis")
    fig.align_ylabels(axes)
    return save(fig, path)


def _edges(time):
    """Cell edges around sample times, for the heat map."""
    time = np.asarray(time, dtype=float)
    step = np.diff(time).mean() if len(time) > 1 else 1.0
    mids = (time[1:] + time[:-1]) / 2
    return np.concatenate([[time[0] - step / 2], mids, [time[-1] + step / 2]])


def _shade_true_modes(ax, edges, true_modes, colors):
    """Faint background bands in the colour of the true mode, so changes line up across panels."""
    if true_modes is None:
        return
    modes = np.asarray(true_modes)
    starts = np.flatnonzero(np.r_[True, modes[1:] != modes[:-1]])
    ends = np.r_[starts[1:], len(modes)]
    for a, b in zip(starts, ends):
        ax.axvspan(edges[a], edges[b], color=colors[modes[a]], alpha=0.12, lw=0)


def _shade_anomaly(ax, edges, anomaly) -> bool:
    """The rows the data label anomalous (1) as light red bands; whether there are any."""
    if anomaly is None or not np.any(np.asarray(anomaly) == 1):
        return False
    marked = np.r_[False, np.asarray(anomaly) == 1, False]
    starts, ends = np.flatnonzero(marked[1:] & ~marked[:-1]), np.flatnonzero(~marked[1:] & marked[:-1])
    for k, (a, b) in enumerate(zip(starts, ends)):
        ax.axvspan(edges[a], edges[b], color="tab:red", alpha=0.15, lw=0, label="true anomaly" if k == 0 else None)
    return True


def result_figure(result, path, true_modes=None, title="", y_sd=None, anomaly=None):
    """The diagnosis figure of a filter Result; the outputs drawn are those it filtered (prediction +
    residual), so a pre-filtered run shows the pre-filtered signal; `y_sd` and `anomaly` as
    diagnosis_figure takes them."""
    model = result.model
    time = model.dt * np.arange(1, result.T + 1)
    who = result.algorithm + (f", {plural(result.particles, 'particle')}" if result.particles else "")
    who += "" if result.lag == 0 else ", smoothed"
    return diagnosis_figure(path, model.modes, result.mode_posterior, time, result.y_pred + result.residuals,
                            result.y_pred, model.outputs, true_modes=true_modes, output_units=model.engineering_units,
                            title=title or f"{model.name}: mode diagnosis ({who})",
                            given=given(result.lag), y_sd=y_sd, anomaly=anomaly)
