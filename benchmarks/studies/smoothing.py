"""Diagnosis error and detection delay against the smoothing lag on every published plant
(docs/studies.md, "Smoothing"): a table in benchmarks/studies/results/smoothing/ and a figure in
docs/figures/smoothing.png.

    python benchmarks/studies/smoothing.py               # 25 runs a plant
    python benchmarks/studies/smoothing.py --runs 5      # 18 minutes on 2 cores shared with other work
    python benchmarks/studies/smoothing.py --replot      # redraw the figure from the table only

Each run simulates the plant through its study schedule (sequence No. 1 for the dryer) with its own
seed; every filter and lag sees the same data. The error is the % of steps whose smoothed MAP mode
is wrong; the detection delay is, for each true switch, the number of steps from the switch to the
first row whose MAP mode is the new mode (the whole segment if none is), counting the lag itself:
a row smoothed with lag L is only known L steps after it. The table and every mean go into the
results ledger (benchmarks/ledger.json) as `studies/smoothing`.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

import jmlgdsl
from jmlgdsl.diagnosis import drawing
from jmlgdsl.studies import figures
from jmlgdsl.diagnosis.metrics import switch_delays
from jmlgdsl.simulation.linear import simulate

sys.path.insert(0, str(Path(__file__).resolve().parent))
from studies import DRYER, FIGURES, RESULTS, SCHEDULES, SPECS  # noqa: E402
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from ledger import ledger_argument, record  # noqa: E402

PLANTS = {"dryer": DRYER["seq1"], **{k: SCHEDULES[k] for k in
                                     ("level_tank4", "level_tank5", "heat_exchanger", "robot_smooth", "robot8")}}
FILTERS = (("imm", None), ("fc-rbpf", 4), ("la-rbpf", 10))
LAGS = (0, 1, 2, 5, 10, 20, None)


def plant_runs(name, runs, seed):
    """{(filter, N, lag): [(error %, delay), ...]} over the plant's runs."""
    model = jmlgdsl.load(SPECS / f"{name}.jmlg")
    out = {}
    for run in range(runs):
        sim = simulate(model, modes=PLANTS[name], seed=np.random.SeedSequence(seed, spawn_key=(run,)))
        for algorithm, n in FILTERS:
            for lag in LAGS:
                result = jmlgdsl.smooth(model, sim.y, sim.u, algorithm=algorithm, particles=n, lag=lag,
                                        seed=np.random.SeedSequence(seed, spawn_key=(run, 1)))
                out.setdefault((algorithm, n, lag), []).append(
                    (result.diagnosis_error(sim.modes), switch_delays(result.map_modes, sim.modes, lag).mean()))
    return name, out


def lag_label(lag):
    return "off-line" if lag is None else str(lag)


def filter_label(algorithm, n):
    return f"{algorithm} N={n}" if n else algorithm


TITLES = {"dryer": "dryer (sequence 1)", "level_tank4": "level tank, 4 modes", "level_tank5": "level tank, 5 modes",
          "heat_exchanger": "heat exchanger", "robot_smooth": "robot, smooth floor", "robot8": "robot, 8 modes"}


def read_table(path):
    """{(plant, filter label, lag): (error %, delay)} and the number of runs, from a table.md."""
    means, runs = {}, None
    for line in path.read_text().splitlines():
        if " runs a plant" in line:
            runs = int(line.split(" runs a plant")[0].rsplit(" ", 1)[-1])
        cells = [c.strip() for c in line.strip("|").split("|")]
        if len(cells) == 2 + len(LAGS) and cells[0] in PLANTS:
            for lag, cell in zip(LAGS, cells[2:]):
                error, steps = cell.split(" / ")
                means[cells[0], cells[1], lag] = (float(error), float(steps))
    return means, runs


def draw(means, runs, path):
    """Error (top) and detection delay (bottom) against the lag, one column per plant. The off-line
    point stands apart: its delay has no lag to count (the whole record is waited for)."""
    fig = drawing.figure(figsize=(13, 6.8), layout="constrained")
    axes = fig.subplots(2, len(PLANTS), sharex=True, squeeze=False)
    online = [lag for lag in LAGS if lag is not None]
    positions = np.arange(len(LAGS))
    for j, name in enumerate(PLANTS):
        top, bottom = axes[0, j], axes[1, j]
        bottom.plot(positions[:len(online)], online, color="0.6", ls="--", lw=1, label="the lag alone")
        for algorithm, n in FILTERS:
            label = filter_label(algorithm, n)
            color, marker = figures.style(algorithm)
            for ax, k in ((top, 0), (bottom, 1)):
                values = [means[name, label, lag][k] for lag in LAGS]
                ax.plot(positions[:len(online)], values[:len(online)], color=color, marker=marker or "*", ms=5,
                        label=label)
                ax.plot(positions[-1], values[-1], color=color, marker=marker or "*", ms=5, ls="none")
        for ax in (top, bottom):
            ax.axvline(positions[-1] - 0.5, color="0.8", lw=0.8)
            ax.grid(True, alpha=0.3)
            ax.set_ylim(bottom=0)
        top.set_title(TITLES.get(name, name), fontsize="medium")
        bottom.set_xticks(positions, [lag_label(lag) for lag in LAGS], rotation=45, fontsize="small")
        bottom.set_xlabel("lag (steps)")
    axes[0, 0].set_ylabel("diagnosis error (% of steps)")
    axes[1, 0].set_ylabel("detection delay (steps, lag included;\noff-line: no lag to count)")
    handles, labels = axes[1, -1].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncols=len(handles), fontsize="small")
    fig.suptitle(f"Smoothed MAP mode against the lag: error and detection delay, mean over {runs} runs a plant")
    drawing.save(fig, path)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=25)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--workers", type=int, default=os.cpu_count())
    parser.add_argument("--replot", action="store_true",
                        help="only redraw the figure from results/smoothing/table.md")
    ledger_argument(parser)
    args = parser.parse_args()
    folder = RESULTS / "smoothing"
    if args.replot:
        draw(*read_table(folder / "table.md"), FIGURES / "smoothing.png")
        print(f"figure: {FIGURES / 'smoothing.png'}")
        return
    start = time.perf_counter()
    with ProcessPoolExecutor(args.workers) as pool:
        results = dict(pool.map(plant_runs, PLANTS, [args.runs] * len(PLANTS), [args.seed] * len(PLANTS)))
    seconds = time.perf_counter() - start
    table = ["| plant | filter | " + " | ".join(lag_label(lag) for lag in LAGS) + " |", "|---|---|" + "---|" * len(LAGS)]
    means, figures_found = {}, {}
    for name, out in results.items():
        for algorithm, n in FILTERS:
            cells = []
            for lag in LAGS:
                values = np.array(out[algorithm, n, lag])
                means[name, filter_label(algorithm, n), lag] = tuple(values.mean(axis=0))
                cells.append(f"{values[:, 0].mean():.2f} / {values[:, 1].mean():.1f}")
                cell = f"{name}_{algorithm}{n or ''}_lag{'offline' if lag is None else lag}"
                figures_found[f"{cell}_error"], figures_found[f"{cell}_delay"] = (
                    round(float(v), 6) for v in values.mean(axis=0))
            table.append(f"| {name} | {filter_label(algorithm, n)} | " + " | ".join(cells) + " |")
    lines = [f"Machine: {platform.machine()}, Python {platform.python_version()}, numpy {np.__version__}; "
             f"{time.strftime('%Y-%m-%d')}; {args.runs} runs a plant, seed {args.seed}, {seconds:.0f} s.", "",
             "Diagnosis error % (mean over runs) / detection delay in steps (mean over switches and runs, "
             "lag included), by lag:", "", *table]
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "table.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    record("studies/smoothing", {"table": "\n".join(table), **figures_found},
           f"python benchmarks/studies/smoothing.py --runs {args.runs} --seed {args.seed}",
           timings={"seconds": round(seconds, 1)}, path=args.ledger)
    draw(means, args.runs, FIGURES / "smoothing.png")
    print(f"figure: {FIGURES / 'smoothing.png'}")


if __name__ == "__main__":
    main()
