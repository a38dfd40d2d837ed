"""Diagnosis error and detection delay against the smoothing lag on every published plant
(docs/studies.md, "Smoothing"): a table in benchmarks/studies/results/smoothing/ and a figure in
docs/figures/smoothing.png.

    python benchmarks/studies/smoothing.py               # 25 runs a plant (about 10 minutes on 2 cores)
    python benchmarks/studies/smoothing.py --runs 5

Each run simulates the plant through its study schedule (sequence No. 1 for the dryer) with its own
seed; every filter and lag sees the same data. The error is the % of steps whose smoothed MAP mode
is wrong; the detection delay is, for each true switch, the number of steps from the switch to the
first row whose MAP mode is the new mode (the whole segment if none is), counting the lag itself:
a row smoothed with lag L is only known L steps after it.
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
from jmlgdsl import plots
from jmlgdsl.simulate import simulate

sys.path.insert(0, str(Path(__file__).resolve().parent))
from studies import DRYER, FIGURES, RESULTS, SCHEDULES, SPECS  # noqa: E402

PLANTS = {"dryer": DRYER["seq1"], **{k: SCHEDULES[k] for k in
                                     ("level_tank4", "level_tank5", "heat_exchanger", "robot_smooth", "robot8")}}
FILTERS = (("imm", None), ("fc-rbpf", 4), ("la-rbpf", 10))
LAGS = (0, 1, 2, 5, 10, 20, None)


def delay(map_modes, modes, lag):
    """Mean steps from each true switch to the first row diagnosed as the new mode (plus the lag)."""
    switches = np.flatnonzero(modes[1:] != modes[:-1]) + 1
    ends = np.r_[switches[1:], len(modes)]
    delays = []
    for start, end in zip(switches, ends):
        found = np.flatnonzero(map_modes[start:end] == modes[start])
        delays.append((found[0] if len(found) else end - start) + (lag or 0))
    return float(np.mean(delays))


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
                    (result.diagnosis_error(sim.modes), delay(result.map_modes, sim.modes, lag)))
    return name, out


def lag_label(lag):
    return "off-line" if lag is None else str(lag)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=25)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--workers", type=int, default=os.cpu_count())
    args = parser.parse_args()
    start = time.perf_counter()
    with ProcessPoolExecutor(args.workers) as pool:
        results = dict(pool.map(plant_runs, PLANTS, [args.runs] * len(PLANTS), [args.seed] * len(PLANTS)))
    lines = [f"Machine: {platform.machine()}, Python {platform.python_version()}, numpy {np.__version__}; "
             f"{time.strftime('%Y-%m-%d')}; {args.runs} runs a plant, seed {args.seed}, "
             f"{time.perf_counter() - start:.0f} s.", "",
             "Diagnosis error % (mean over runs) / detection delay in steps (mean over switches and runs, "
             "lag included), by lag:", "",
             "| plant | filter | " + " | ".join(lag_label(lag) for lag in LAGS) + " |",
             "|---|---|" + "---|" * len(LAGS)]
    for name, out in results.items():
        for algorithm, n in FILTERS:
            cells = []
            for lag in LAGS:
                values = np.array(out[algorithm, n, lag])
                cells.append(f"{values[:, 0].mean():.2f} / {values[:, 1].mean():.1f}")
            lines.append(f"| {name} | {algorithm}{f' N={n}' if n else ''} | " + " | ".join(cells) + " |")
    folder = RESULTS / "smoothing"
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "table.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))

    fig = plots.figure(figsize=(12, 6.5), layout="constrained")
    axes = fig.subplots(2, len(PLANTS), sharex=True, squeeze=False)
    positions = np.arange(len(LAGS))
    for j, (name, out) in enumerate(results.items()):
        for algorithm, n in FILTERS:
            errors = [np.mean([e for e, _ in out[algorithm, n, lag]]) for lag in LAGS]
            delays = [np.mean([d for _, d in out[algorithm, n, lag]]) for lag in LAGS]
            color, marker = plots.style(algorithm)
            axes[0, j].plot(positions, errors, color=color, marker=marker or "*", label=algorithm)
            axes[1, j].plot(positions, delays, color=color, marker=marker or "*", label=algorithm)
        axes[0, j].set_title(name, fontsize="small")
        axes[1, j].set_xticks(positions, [lag_label(lag) for lag in LAGS], rotation=90, fontsize="small")
        axes[1, j].set_xlabel("lag (steps)")
    axes[0, 0].set_ylabel("diagnosis error (% of steps)")
    axes[1, 0].set_ylabel("detection delay (steps,\nlag included)")
    axes[0, -1].legend(fontsize="small")
    fig.suptitle(f"Smoothing: error and delay against the lag ({args.runs} runs a plant)")
    plots.save(fig, FIGURES / "smoothing.png")
    print(f"figure: {FIGURES / 'smoothing.png'}")


if __name__ == "__main__":
    main()
