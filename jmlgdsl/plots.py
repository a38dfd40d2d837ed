"""Figures for diagnosis studies and single runs, written as PNG files.

Study figures take the summaries and run records of `jmlgdsl.bench`; the diagnosis figure shows one
run: the mode posterior over time with the MAP and true modes, measured vs predicted outputs and the
residuals. Figures are built with matplotlib's object API (no pyplot), so importing this module
never changes a notebook's backend and no figure outlives its file.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib
import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import FuncFormatter

STYLE = {"pf": ("tab:red", "v"), "rbpf": ("tab:orange", "s"), "la-rbpf": ("tab:blue", "o"),
         "fc-rbpf": ("tab:green", "D"), "imm": ("tab:purple", None), "exact": ("black", None)}
DPI = 100


def style(name):
    """(colour, marker) of a filter; marker None for the filters without particles."""
    return STYLE.get(name, ("tab:gray", "x"))


def _by_filter(summary):
    """{filter: rows sorted by particle count}, in order of first appearance."""
    groups = {}
    for row in summary:
        groups.setdefault(row["filter"], []).append(row)
    return {f: sorted(rows, key=lambda r: r["particles"] or 0) for f, rows in groups.items()}


def figure(**kwargs) -> Figure:
    """A new figure, not registered with pyplot (keyword arguments as for matplotlib's Figure)."""
    return Figure(**kwargs)


def save(fig, path, dpi=DPI) -> Figure:
    """Write the figure as a PNG and return it (for a caller that wants to look at or reuse it)."""
    fig.savefig(path, dpi=dpi)
    return fig


def error_vs_particles(summary, path, title="", reference=None):
    """Diagnosis error (mean ± SD over runs) against the number of particles on a log axis; filters
    without particles (imm, exact) are horizontal lines. `reference` adds published points:
    {filter: [(N, mean, sd), ...]} drawn hollow and dashed."""
    fig = figure(figsize=(8.5, 4.5))
    ax = fig.subplots()
    for name, rows in _by_filter(summary).items():
        color, marker = style(name)
        if rows[0]["particles"] is None:
            ax.axhline(rows[0]["error_mean"], color=color, ls="--", label=f"{name} (no particles)")
            continue
        n = [r["particles"] for r in rows]
        ax.errorbar(n, [r["error_mean"] for r in rows], yerr=np.nan_to_num([r["error_sd"] for r in rows]),
                    color=color, marker=marker, capsize=3, label=name)
    for name, points in (reference or {}).items():
        color, marker = style(name)
        n, mean, sd = np.array(points, dtype=float).T
        ax.errorbar(n * 1.08, mean, yerr=sd, color=color, marker=marker or "o", mfc="none", ls=":", capsize=2,
                    alpha=0.8, label=f"{name}, published (real data)")
    ax.set_xscale("log")
    counts = sorted({r["particles"] for r in summary if r["particles"] is not None})
    ax.set_xticks(counts, [str(n) for n in counts])
    ax.minorticks_off()
    ax.set_xlabel("number of particles N (log scale)")
    ax.set_ylabel("diagnosis error (% of steps)")
    ax.set_ylim(bottom=0)
    ax.grid(True, which="both", alpha=0.3)
    ax.set_title(title or "Diagnosis error against particles (mean ± SD over runs)")
    ax.legend(fontsize="small", loc="upper left", bbox_to_anchor=(1.01, 1))
    fig.tight_layout()
    return save(fig, path)


def error_vs_time(summary, path, sample_time, title=""):
    """Diagnosis error (mean ± SD) against the mean computing time per step (log axis), one curve per
    filter through its particle counts. The axis spans the measured times only: the sample time (the
    real-time limit, in seconds) is a dashed line where it falls among them, else a note with an
    arrow at the right edge, so that points far faster than real time are not squeezed against the
    left edge of an axis running out to the sample time."""
    fig = figure(figsize=(8, 4.5))
    ax = fig.subplots()
    for name, rows in _by_filter(summary).items():
        color, marker = style(name)
        ax.errorbar([r["ms_per_step_mean"] for r in rows], [r["error_mean"] for r in rows],
                    yerr=np.nan_to_num([r["error_sd"] for r in rows]), color=color, marker=marker or "*",
                    ms=9 if marker is None else 6, capsize=3, label=name)
    ax.set_xscale("log")
    plain = FuncFormatter(lambda x, _: f"{x:g}")  # 0.3, not 3×10⁻¹
    ax.xaxis.set_major_formatter(plain)
    low, high = ax.get_xlim()
    if high < 10 * low:  # short of a decade there may be no power of ten to label: label the minor ticks
        ax.xaxis.set_minor_formatter(plain)
    limit = 1e3 * sample_time
    if limit <= high:
        ax.axvline(limit, color="black", ls="--", lw=1)
        ax.text(limit, 0.98, f" sample time\n {_duration(sample_time)}\n (real-time limit)",
                transform=ax.get_xaxis_transform(), va="top", ha="right", fontsize="small")
    else:
        slowest = max(r["ms_per_step_mean"] for r in summary)
        ax.annotate(f"sample time {_duration(sample_time)} (real-time limit), off the axis:\n"
                    f"the slowest setting takes {slowest:.3g} ms a step", xy=(1, 0.92), xytext=(0.97, 0.92),
                    xycoords="axes fraction", textcoords="axes fraction", ha="right", va="center",
                    fontsize="small", arrowprops={"arrowstyle": "-|>", "color": "black"})
    ax.set_xlabel("computing time per step (ms, log scale)")
    ax.set_ylabel("diagnosis error (% of steps)")
    ax.set_ylim(bottom=0)
    ax.grid(True, which="both", alpha=0.3)
    ax.set_title(title or "Diagnosis error against computing time")
    ax.legend(fontsize="small", loc="upper left", bbox_to_anchor=(1.01, 1), title="filter\n(N increases\nto the right)",
              title_fontsize="small")
    fig.tight_layout()
    return save(fig, path)


def _duration(seconds):
    """A sample time as text in s, or in ms below one second."""
    return f"{seconds:g} s" if seconds >= 1 else f"{1e3 * seconds:g} ms"


def error_boxplots(records, path, title=""):
    """Box plots of the per-run diagnosis error for each particle count, one panel per particle filter."""
    groups = {}
    for r in records:
        if r["particles"] is not None:
            groups.setdefault(r["filter"], {}).setdefault(r["particles"], []).append(r["error"])
    if not groups:
        raise ValueError("no particle-filter runs to draw")
    fig = figure(figsize=(3.2 * len(groups) + 0.8, 4.2))
    axes = fig.subplots(1, len(groups), sharey=True, squeeze=False)
    for ax, (name, by_n) in zip(axes[0], groups.items()):
        counts = sorted(by_n)
        ax.boxplot([by_n[n] for n in counts], tick_labels=[str(n) for n in counts], widths=0.6,
                   flierprops={"marker": "+", "markersize": 4})
        ax.set_title(name, color=style(name)[0])
        ax.set_xlabel("particles N")
        ax.tick_params(axis="x", labelrotation=90, labelsize="small")
        ax.grid(True, axis="y", alpha=0.3)
    axes[0, 0].set_ylabel("diagnosis error (% of steps)")
    fig.suptitle(title or "Diagnosis error per run")
    fig.tight_layout()
    return save(fig, path)


def error_vs_lag(summary, path, title="") -> Path:
    """Diagnosis error and detection delay (mean over runs) against the smoothing lag, one curve per
    filter and particle count; the off-line point stands last. Returns the path written."""
    lags = list(dict.fromkeys(r["lag"] for r in summary))
    lags = sorted(lag for lag in lags if lag is not None) + ([None] if None in lags else [])
    fig = figure(figsize=(9, 4.2), layout="constrained")
    axes = fig.subplots(1, 2, sharex=True)
    settings = dict.fromkeys((r["filter"], r["particles"]) for r in summary)
    for name, n in settings:
        rows = {r["lag"]: r for r in summary if (r["filter"], r["particles"]) == (name, n)}
        color, marker = style(name)
        x = [i for i, lag in enumerate(lags) if lag in rows]
        label = name + (f", N = {n}" if n else "")
        for ax, key in zip(axes, ("error_mean", "delay_mean")):
            ax.plot(x, [rows[lags[i]][key] for i in x], color=color, marker=marker or "*", label=label)
    for ax, label in zip(axes, ("diagnosis error (% of steps)", "detection delay (steps, lag included)")):
        ax.set_xticks(range(len(lags)), ["off-line" if lag is None else str(lag) for lag in lags])
        ax.set_xlabel("smoothing lag (steps)")
        ax.set_ylabel(label)
        ax.set_ylim(bottom=0)
        ax.grid(True, alpha=0.3)
    axes[1].legend(fontsize="small")
    fig.suptitle(title + ": error and delay against the smoothing lag" if title else "Smoothing lag")
    save(fig, path)
    return path


def study_figures(folder, prefix, title, sample_time, summary, records, reference=None) -> list:
    """The three study figures of one sweep as folder/prefix-{error-vs-particles,error-vs-time,boxplots}.png
    (no box plots when no particle filter ran); returns the paths written."""
    paths = [folder / f"{prefix}-{kind}.png" for kind in ("error-vs-particles", "error-vs-time", "boxplots")]
    error_vs_particles(summary, paths[0], f"{title}\ndiagnosis error against particles (mean ± SD over runs)",
                       reference)
    error_vs_time(summary, paths[1], sample_time, f"{title}\ndiagnosis error against computing time")
    if not any(r["particles"] is not None for r in records):
        return paths[:2]
    error_boxplots(records, paths[2], f"{title}: diagnosis error per run")
    return paths


def _mode_colors(K):
    """One RGBA colour per mode (tab10, or tab20 beyond ten modes)."""
    return matplotlib.colormaps["tab10" if K <= 10 else "tab20"](np.arange(K) % 20)


def diagnosis_figure(path, mode_names, posterior, time, y, y_pred, output_names, true_modes=None,
                     time_label="time (s)", output_units=None, title="", given="the data so far"):
    """One run at a glance: MAP (and true) mode over time, the mode posterior as a heat map, then for
    each output the measured and predicted values, and the residuals.

    posterior (T, K); time (T,); y, y_pred (T, ny) with NaN where not measured; true_modes (T,) indices
    or None; output_units maps output names to unit text; `given` says what the posterior is
    conditioned on (the filter's data so far, or a smoother's).
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
    for j in range(ny):
        ax.plot(time, residuals[:, j], lw=0.7, label=output_names[j])
    ax.axhline(0, color="black", lw=0.6)
    ax.set_ylabel("residual\n(measured −\npredicted)")
    if ny > 1:
        ax.legend(loc="upper right", fontsize="small", ncol=min(ny, 4))
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


def result_figure(result, path, true_modes=None, title=""):
    """The diagnosis figure of a filter Result; the outputs drawn are those it filtered (prediction +
    residual), so a pre-filtered run shows the pre-filtered signal."""
    from .diagnosis.report import plural
    from .infer.table import given

    model = result.model
    time = model.dt * np.arange(1, result.T + 1)
    who = result.algorithm + (f", {plural(result.particles, 'particle')}" if result.particles else "")
    who += "" if result.lag == 0 else ", smoothed"
    return diagnosis_figure(path, model.modes, result.mode_posterior, time, result.y_pred + result.residuals,
                            result.y_pred, model.outputs, true_modes=true_modes, output_units=model.units,
                            title=title or f"{model.name}: mode diagnosis ({who})",
                            given=given(result.lag))
