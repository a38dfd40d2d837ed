"""The figures of a diagnosis study (`jmlgdsl bench`): error against particles and against computing
time, per-run box plots, error and delay against the smoothing lag. They take the summaries and run
records of `jmlgdsl.studies.sweep`."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.ticker import FuncFormatter

from ..diagnosis.drawing import figure, save

STYLE = {"pf": ("tab:red", "v"), "rbpf": ("tab:orange", "s"), "la-rbpf": ("tab:blue", "o"),
         "fc-rbpf": ("tab:green", "D"), "imm": ("tab:purple", None), "exact": ("black", None)}
def style(name):
    """(colour, marker) of a filter; marker None for the filters without particles."""
    return STYLE.get(name, ("tab:gray", "x"))


def _by_filter(summary):
    """{filter: rows sorted by particle count}, in order of first appearance."""
    groups = {}
    for row in summary:
        groups.setdefault(row["filter"], []).append(row)
    return {f: sorted(rows, key=lambda r: r["particles"] or 0) for f, rows in groups.items()}


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
