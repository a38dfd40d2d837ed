"""Regenerate the published studies of docs/studies.md on simulated data: tables in
benchmarks/studies/results/<study>/ and figures in docs/figures/<study>-*.png.

    python benchmarks/studies/studies.py --list
    python benchmarks/studies/studies.py dryer-seq1                 # one study, 25 runs
    python benchmarks/studies/studies.py --runs 5 level-tank4 cstr4 # quicker, noisier
    python benchmarks/studies/studies.py                            # every study, 25 runs (about 35 minutes on 2 cores)
    python benchmarks/studies/studies.py --redraw                   # the figures again from the saved runs

Each study's tables and figures also go into the results ledger (benchmarks/ledger.json) as
`studies/<study>`: its error tables as docs/studies.md quotes them (Markdown), every filter's mean
error and SD at every particle count, and its times per step (recorded, never compared).

Every study draws fresh sequences per run from a fixed mode schedule (the published sequences where
the source study printed them, else a hand-made one that visits every mode along allowed
transitions), so a run's data and filter seeds follow from --seed alone.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

import jmlgdsl
from jmlgdsl.diagnosis import drawing
from jmlgdsl.diagnosis import figure as run_figure
from jmlgdsl.studies import figures, sweep
from jmlgdsl.simulation.linear import parse_schedule

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "benchmarks"))
from ledger import ledger_argument, machine, record  # noqa: E402  (the results ledger)

SPECS, FIGURES, RESULTS = ROOT / "specs", ROOT / "docs" / "figures", Path(__file__).resolve().parent / "results"
REDRAW = False  # --redraw: the sweeps' figures from the runs saved in RESULTS, nothing run and no table written
PARTICLE_FILTERS = ("pf", "rbpf", "la-rbpf", "fc-rbpf")

# Industrial dryer, random sequences No. 1-4 (Tables 5.4, D.1-D.3). Sequence 4's last interval is
# printed as "low fan, closed grill" (a faulty grill) under the fan+grill label; we follow the label.
DRYER = {
    "seq1": "1-70:normal,71-238:fan,239-365:grill,366-513:normal,514-705:grill,706-1000:fan",
    "seq2": "1-204:normal,205-266:fan,267-310:grill,311-334:fan_grill,335-894:grill,895-1000:fan",
    "seq3": "1-421:normal,422-686:grill,687-721:normal,722-846:fan,847-974:normal,975-1000:grill",
    "seq4": ("1-222:normal,223-274:fan,275-475:normal,476-534:fan,535-810:normal,811-876:fan_grill,"
             "877-916:grill,917-936:normal,937-1000:fan_grill"),
}
# Published diagnosis error % (mean, SD) on the real data, by filter and N.
TABLE_5_5 = {
    "pf": [(1, 75.13, 10.20), (4, 77.81, 8.38), (10, 68.35, 16.11), (25, 50.50, 11.04), (50, 40.06, 9.99),
           (100, 24.20, 7.16), (200, 17.02, 5.03), (1600, 13.07, 2.14)],
    "rbpf": [(1, 75.61, 14.17), (4, 57.69, 9.98), (10, 39.07, 12.03), (25, 21.61, 7.18), (50, 14.78, 5.06),
             (100, 10.20, 3.77), (200, 7.99, 0.55), (1600, 7.42, 0.15)],
    "la-rbpf": [(1, 26.02, 7.79), (4, 18.82, 5.74), (10, 13.55, 5.62), (25, 9.08, 3.49), (50, 7.76, 2.16),
                (100, 7.28, 1.15), (200, 6.87, 0.29), (1600, 6.75, 0.10)],
}
_D6_N = (1, 4, 10, 25, 50, 100, 200, 400, 800, 1600)
TABLE_D_6 = {
    name: list(zip(_D6_N, mean, sd)) for name, mean, sd in (
        ("pf", (76.10, 76.62, 69.78, 64.02, 54.81, 49.87, 47.54, 40.49, 30.91, 20.92),
         (17.69, 16.08, 13.23, 14.69, 10.34, 11.91, 8.94, 13.08, 14.75, 16.52)),
        ("rbpf", (64.72, 57.89, 57.15, 49.39, 42.16, 34.13, 31.35, 23.60, 13.32, 8.44),
         (21.08, 23.47, 23.71, 22.89, 23.82, 23.44, 23.73, 22.68, 15.60, 10.57)),
        ("la-rbpf", (37.51, 15.16, 17.49, 7.89, 4.42, 3.19, 2.14, 1.84, 1.81, 1.77),
         (15.09, 15.52, 17.72, 8.62, 2.35, 2.08, 0.95, 0.23, 0.10, 0.06)))
}
SCHEDULES = {
    "level_tank4": ("1-150:low_in,151-300:medium_in,301-450:high_in,451-550:medium_in,551-700:low_in,"
                    "701-850:low_out,851-1000:low_in"),
    "level_tank5": ("1-150:low_in,151-300:medium_in,301-420:medium_in_low_out,421-560:low_in_low_out,"
                    "561-680:low_in,681-820:high_in,821-1000:medium_in"),
    "heat_exchanger": ("1-150:normal_flow,151-300:high_flow,301-430:very_high_flow,431-580:low_flow,"
                       "581-730:very_low_flow,731-850:normal_flow,851-1000:low_flow"),
    "robot_smooth": ("1-150:normal,151-300:low_load,301-450:medium_load,451-600:high_load,601-750:medium_load,"
                     "751-850:normal,851-1000:low_load"),
    "robot8": ("1-130:smooth_normal,131-250:smooth_low,251-380:smooth_medium,381-500:smooth_normal,"
               "501-620:tiled_normal,621-740:tiled_low,741-870:tiled_medium,871-1000:tiled_high"),
    "cstr4": "1-250:normal,251-500:fouling1,501-750:fouling2,751-1000:fouling3",
    "cstr10": "1-200:normal,201-400:fouling2,401-600:concentration1,601-800:water2,801-1000:jacket1",
}
VARIATIONS = (0, 5, 10, 20, 40, 80, 160, 320)  # % change of the transition probabilities (Tables D.4, D.5, D.7)
TABLE_D_4 = [(1, 78.3, 72.8), (4, 66.2, 24.2), (10, 31.7, 17.1), (25, 21.9, 11.0), (50, 19.8, 9.7), (100, 8.5, 8.2),
             (200, 8.2, 8.2)]  # RBPF: N, error at 0 % and at 320 %
TABLE_D_5 = [(1, 27.38, 25.42), (4, 19.12, 9.02), (10, 12.04, 8.58), (25, 7.80, 7.78), (50, 6.80, 7.16),
             (100, 6.86, 7.26), (200, 6.70, 7.20)]  # la-RBPF: N, error at 0 % and at 320 %
TABLE_D_7 = [(1, 38.72, 35.60), (4, 10.40, 9.00), (10, 8.44, 7.86), (25, 5.16, 4.76), (50, 5.48, 5.00),
             (100, 4.06, 4.18), (200, 3.18, 3.22)]  # heat exchanger, la-RBPF, normal-flow row: N, 0 % and 320 %


def check_schedule(model, schedule):
    """Refuse a schedule that takes a transition the model forbids (no filter could follow it)."""
    modes = parse_schedule(schedule, model)
    for a, b in zip(modes[:-1], modes[1:]):
        if model.P[a, b] == 0:
            raise SystemExit(f"{model.name}: the schedule moves {model.modes[a]} -> {model.modes[b]}, "
                             f"which the transition matrix forbids")


def saved_records(name, sources) -> list[dict]:
    """The records an earlier run of this sweep saved (RESULTS/<study>[-<label>]/runs.csv, the rows of
    these sources), for --redraw: a study's sweeps are named '<study>' or '<study> <label>', and the
    perturbation sweeps ('<study> 5 %') share their study's file."""
    study, _, label = name.partition(" ")
    folder = RESULTS / (study if not label or label.endswith("%") else f"{study}-{label}")
    wanted = {source.name for source in sources}
    return [r for r in sweep.read_records_csv(folder / "runs.csv") if r["data"] in wanted]


def one_sweep(args, name, model, sources, filters, particles, **options):
    """Run one sweep with the common options, print its progress, return its records (with --redraw,
    the records it saved before)."""
    if REDRAW:
        return saved_records(name, sources)
    print(f"\n== {name}: {len(filters)} filters, N = {','.join(map(str, particles))}, {args.runs} runs",
          file=sys.stderr)
    return sweep.sweep(model, sources, filters, particles, args.runs, args.seed, workers=args.workers,
                       progress=sys.stderr, **options)


def publish(name, model, records, reference=None, title=None) -> dict:
    """Write a study's tables (results/<name>/) and figures (docs/figures/<name>-*.png); return what
    the ledger records of it (`ledger_figures`, and the table beside the published one when there is
    a `reference`)."""
    summary = sweep.summarise(records)
    figures.study_figures(FIGURES, name, title or model.name, model.dt, summary, records, reference)
    if REDRAW:
        return {}
    folder = RESULTS / name
    folder.mkdir(parents=True, exist_ok=True)
    sweep.write_records_csv(folder / "runs.csv", records)
    sweep.write_table_csv(folder / "table.csv", summary)
    (folder / "table.md").write_text(sweep.report(summary))
    print(sweep.markdown_table(summary))
    found = ledger_figures(summary)
    if reference:
        found["published"] = published_table(summary, reference)
    return found


def ledger_figures(summary) -> dict:
    """What the ledger records of one sweep: each filter's mean error % and its SD at each particle
    count (`<filter>_<N>_error_mean`, `..._sd`; a filter without particles drops the N), its error
    table as docs/studies.md quotes it (`errors`) and its times per step (`ms_per_step`, a table:
    like every table in the ledger, never compared with a re-run's)."""
    found = {}
    for r in summary:
        cell = r["filter"] + ("" if r["particles"] is None else f"_{r['particles']}")
        found[f"{cell}_error_mean"] = round(r["error_mean"], 6)
        found[f"{cell}_error_sd"] = None if np.isnan(r["error_sd"]) else round(r["error_sd"], 6)
    found["errors"] = sweep.markdown_table(summary, titled=False)
    found["ms_per_step"] = sweep.markdown_table(summary, "ms_per_step", titled=False)
    return found


def published_table(summary, reference) -> str:
    """Ours beside the published errors, 'mean (SD)': a column pair for each filter the source
    study published (`reference`: {filter: [(N, mean, SD), ...]}), one column for the others."""
    counts, filters, cells = sweep.wide(summary)
    published = {(name, n): f"{mean:.2f} ({sd:.2f})" for name, rows in reference.items() for n, mean, sd in rows}
    columns = [(f, kind) for f in filters for kind in (("published", "ours") if f in reference else ("ours",))]
    lines = ["| N | " + " | ".join(f"{f} {kind}" if f in reference else f for f, kind in columns) + " |",
             "|---|" + "---|" * len(columns)]
    for n in counts:
        row = [published.get((f, n), "") if kind == "published" else
               sweep.mean_sd(cells[f, n], "error", 2) if (f, n) in cells else "" for f, kind in columns]
        lines.append(f"| {'—' if n is None else n} | " + " | ".join(row) + " |")
    return "\n".join(lines)


def diagnosis_example(name, model, schedule, algorithm, particles, seed, plant=None, prefilter=None, run=0,
                      figure="diagnosis"):
    """The mode-posterior figure of one run (the sweep's run `run`): docs/figures/<name>-<figure>.png
    (not with --redraw, which runs nothing)."""
    if REDRAW:
        return
    source = sweep.Simulated(None, schedule, name, plant)
    jobs = sweep.make_jobs(model, [source], (algorithm,), (particles,), runs=run + 1, seed=seed, prefilter=prefilter)
    data, result = sweep.filter_job(next(job for job in jobs if job.run == run))
    run_figure.result_figure(result, FIGURES / f"{name}-{figure}.png", true_modes=data.modes)


def worst_example(name, model, schedule, records, algorithm, particles, seed):
    """The sweep's worst run of one filter and count, drawn as docs/figures/<name>-worst.png (a
    typical run rarely shows how a filter fails)."""
    runs = [r for r in records if r["filter"] == algorithm and r["particles"] == particles]
    worst = max(runs, key=lambda r: r["error"])
    diagnosis_example(name, model, schedule, algorithm, particles, seed, run=worst["run"], figure="worst")


def linear_study(args, name, spec, schedule, reference=None, model=None, title=None, example=("la-rbpf", 10),
                 worst=False):
    """Every filter at every particle count on fresh simulations of a linear plant through a schedule;
    `worst` also draws the example filter's worst run."""
    model = model or jmlgdsl.load(SPECS / spec)
    check_schedule(model, schedule)
    records = one_sweep(args, name, model, [sweep.Simulated(None, schedule, name)], args.filters, args.particles)
    found = publish(name, model, records, reference, title)
    diagnosis_example(name, model, schedule, *example, args.seed)
    if worst and example[0] in args.filters and example[1] in args.particles:
        worst_example(name, model, schedule, records, *example, args.seed)
    return found


def dryer(args, seq):
    """One of the published dryer sequences; sequence 1 is drawn beside the published Table 5.5."""
    return linear_study(args, f"dryer-{seq}", "dryer.jmlg", DRYER[seq], TABLE_5_5 if seq == "seq1" else None,
                 title=f"Dryer, sequence {seq[-1]}")


def cstr(args, name):
    """The CSTR filtered with its linearised modes on data from its nonlinear equations."""
    spec = str(SPECS / f"{name}.jmlg")
    model = sweep.nonlinear_plant(spec).model
    source = sweep.Simulated(None, SCHEDULES[name], name, plant=spec)
    records = one_sweep(args, name, model, [source], args.filters, args.particles)
    found = publish(name, model, records, title=f"{name.upper()} ({model.K} modes, nonlinear data)")
    diagnosis_example(name, model, SCHEDULES[name], "la-rbpf", 10, args.seed, plant=spec)
    return found


def with_measurement_noise(model, level):
    """The 8-mode robot with measurement noise n_m = level * n_p (n_p = its process noise)."""
    return model.replace(D=level * model.B, name=f"robot8, n_m = {level} n_p")


def robot8(args, level):
    """The 8-mode robot with measurement noise `level` times its process noise."""
    name = f"robot8-noise{level}"
    model = with_measurement_noise(jmlgdsl.load(SPECS / "robot8.jmlg"), level)
    return linear_study(args, name, None, SCHEDULES["robot8"], model=model, title=f"Robot, 8 modes, n_m = {level} n_p")


def perturbed(model, percent, rows=None):
    """The transition matrix with every off-diagonal probability (of the given rows, default all) grown
    by `percent` %, the diagonal shrunk to keep each row summing to one."""
    P = model.P.copy()
    for i in range(model.K) if rows is None else rows:
        off = np.arange(model.K) != i
        P[i, off] *= 1 + percent / 100
        P[i, i] = 1 - P[i, off].sum()
    return model.replace(P=P, name=f"{model.name}, P {percent:+d} %")


def robustness(args, name, spec, schedule, filters, published, rows=None) -> dict:
    """Filters built on a perturbed transition matrix, data from the published one (paired runs);
    `published`: {filter: [(N, error at 0 %, error at 320 %), ...]} of the source study's table."""
    true = jmlgdsl.load(SPECS / spec)
    particles = tuple(n for n in args.particles if n <= 200)
    records = []
    for percent in VARIATIONS:
        source = sweep.Simulated(None, schedule, f"{percent}%", plant=true)
        records += one_sweep(args, f"{name} {percent} %", perturbed(true, percent, rows), [source], filters, particles)
    summary = sweep.summarise(records)
    if not REDRAW:
        folder = RESULTS / name
        folder.mkdir(parents=True, exist_ok=True)
        sweep.write_records_csv(folder / "runs.csv", records)
        text = "\n\n".join(variation_table(summary, f) for f in filters) + "\n"
        (folder / "table.md").write_text(text)
        print(text)
    variation_figure(summary, filters, FIGURES / f"{name}.png",
                     f"{true.name}: the filters' transition matrix perturbed,\ndata from the published one")
    if REDRAW:
        return {}
    found = {f"{r['filter']}_{r['particles']}_{r['data'].rstrip('%')}pct_error_mean": round(r["error_mean"], 6)
             for r in summary}
    found |= {f"{f}_errors": variation_table(summary, f) for f in filters}
    found["published"] = published_variation_table(summary, published)
    return found


def published_variation_table(summary, published) -> str:
    """The published errors at 0 % and at the largest perturbation beside ours, by N and filter."""
    top = f"{VARIATIONS[-1]}%"
    cells = {(r["filter"], r["particles"], r["data"]): r["error_mean"] for r in summary}
    filters = list(published)
    lines = ["| N | " + " | ".join(f"{f} published 0 % → {VARIATIONS[-1]} % | {f} ours" for f in filters) + " |",
             "|---|" + "---|---|" * len(filters)]
    counts = sorted({n for rows in published.values() for n, _, _ in rows})
    for n in counts:
        row = []
        for f in filters:
            at = {m: (a, b) for m, a, b in published[f]}
            row.append(f"{at[n][0]:.2f} → {at[n][1]:.2f}" if n in at else "")
            row.append(f"{cells[f, n, '0%']:.2f} → {cells[f, n, top]:.2f}" if (f, n, "0%") in cells else "")
        lines.append(f"| {n} | " + " | ".join(row) + " |")
    return "\n".join(lines)


def variation_table(summary, name):
    """Mean diagnosis error by particle count (rows) and perturbation (columns), like Tables D.4/D.5."""
    cells = {(r["particles"], r["data"]): r["error_mean"] for r in summary if r["filter"] == name}
    counts = sorted({n for n, _ in cells})
    lines = [f"{name}: diagnosis error %, mean over runs", "",
             "| N | " + " | ".join(f"{v} %" for v in VARIATIONS) + " |", "|---|" + "---|" * len(VARIATIONS)]
    lines += [f"| {n} | " + " | ".join(f"{cells[n, f'{v}%']:.2f}" for v in VARIATIONS) + " |" for n in counts]
    return "\n".join(lines)


def variation_figure(summary, filters, path, title):
    """Error against the perturbation, one line per particle count, one panel per filter."""
    fig = drawing.figure(figsize=(4.2 * len(filters) + 2, 4.2))
    axes = fig.subplots(1, len(filters), sharey=True, squeeze=False)
    for ax, name in zip(axes[0], filters):
        rows = [r for r in summary if r["filter"] == name]
        for n in sorted({r["particles"] for r in rows}):
            error = {r["data"]: r["error_mean"] for r in rows if r["particles"] == n}
            ax.plot(range(len(VARIATIONS)), [error[f"{v}%"] for v in VARIATIONS], marker="o", ms=3, label=f"N = {n}")
        ax.set_xticks(range(len(VARIATIONS)), [f"{v}" for v in VARIATIONS])
        ax.set_xlabel("off-diagonal transition\nprobabilities raised by (%)")
        ax.set_title(name)
        ax.grid(True, alpha=0.3)
    axes[0, 0].set_ylabel("diagnosis error (% of steps, mean over runs)")
    axes[0, -1].legend(fontsize="small", loc="upper left", bbox_to_anchor=(1.02, 1), title="particles")
    fig.suptitle(title)
    fig.tight_layout()
    drawing.save(fig, path)


def prefilter(args, name, model_level, data_level=None):
    """The 8-mode robot with and without a causal moving average before the filters. The data have
    measurement noise `data_level` n_p (default: as the filters' model, `model_level` n_p)."""
    robot = jmlgdsl.load(SPECS / "robot8.jmlg")
    model = with_measurement_noise(robot, model_level)
    plant = None if data_level is None else with_measurement_noise(robot, data_level)
    noise = f"n_m = {model_level} n_p" + ("" if data_level is None else f", data n_m = {data_level} n_p")
    schedule = SCHEDULES["robot8"]
    filters = ("rbpf", "la-rbpf", "fc-rbpf")
    particles = tuple(n for n in args.particles if n <= 400)
    found, means = {}, {}
    for window in (None, 3, 5):
        label = "raw" if window is None else f"ma{window}"
        source = sweep.Simulated(None, schedule, label, plant)
        records = one_sweep(args, f"{name} {label}", model, [source], filters, particles, prefilter=window)
        title = f"Robot, 8 modes, {noise}, {'raw' if window is None else f'moving average of {window}'}"
        found |= {f"{label}_{key}": value for key, value in
                  publish(f"{name}-{label}", model, records, title=title).items()}
        means |= {(r["filter"], label, r["particles"]): r["error_mean"] for r in sweep.summarise(records)}
    diagnosis_example(f"{name}-ma5", model, schedule, "la-rbpf", 10, args.seed, plant=plant, prefilter=5)
    if found:
        labels = ("raw", "ma3", "ma5")
        columns = [(f, label) for f in filters for label in labels]
        lines = ["| N | " + " | ".join(f"{f} {label.replace('ma', 'ma:')}" for f, label in columns) + " |",
                 "|---|" + "---|" * len(columns)]
        lines += [f"| {n} | " + " | ".join(f"{means[f, label, n]:.2f}" for f, label in columns) + " |"
                  for n in particles]
        found["errors"] = "\n".join(lines)
    return found


STUDIES = {
    **{f"dryer-{seq}": (lambda args, seq=seq: dryer(args, seq)) for seq in DRYER},
    "dryer-transitions": lambda args: robustness(args, "dryer-transitions", "dryer.jmlg", DRYER["seq1"],
                                                 ("rbpf", "la-rbpf"), {"rbpf": TABLE_D_4, "la-rbpf": TABLE_D_5}),
    "level-tank4": lambda args: linear_study(args, "level-tank4", "level_tank4.jmlg", SCHEDULES["level_tank4"],
                                             TABLE_D_6, title="Level tank, 4 modes", worst=True),
    "level-tank5": lambda args: linear_study(args, "level-tank5", "level_tank5.jmlg", SCHEDULES["level_tank5"],
                                             title="Level tank, 5 modes"),
    "heat-exchanger": lambda args: linear_study(args, "heat-exchanger", "heat_exchanger.jmlg",
                                                SCHEDULES["heat_exchanger"], title="Heat exchanger"),
    "heat-exchanger-transitions": lambda args: robustness(args, "heat-exchanger-transitions", "heat_exchanger.jmlg",
                                                          SCHEDULES["heat_exchanger"], ("la-rbpf",),
                                                          {"la-rbpf": TABLE_D_7}, rows=[2]),
    "robot-smooth": lambda args: linear_study(args, "robot-smooth", "robot_smooth.jmlg", SCHEDULES["robot_smooth"],
                                              title="Robot, smooth floor"),
    **{f"robot8-noise{level}": (lambda args, level=level: robot8(args, level)) for level in (1, 2, 4)},
    "robot8-prefilter": lambda args: prefilter(args, "robot8-noise4", 4),
    "robot8-prefilter-mismatch": lambda args: prefilter(args, "robot8-mismatch", 1, data_level=4),
    "cstr4": lambda args: cstr(args, "cstr4"),
    "cstr10": lambda args: cstr(args, "cstr10"),
}


def main(argv=None):
    """Run the named studies (default: all) and log each one's time, seed and machine."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("studies", nargs="*", help="studies to run (default: all)")
    parser.add_argument("--list", action="store_true", help="list the studies and stop")
    parser.add_argument("--runs", type=int, default=25)
    parser.add_argument("--seed", type=int, default=2001)
    parser.add_argument("--workers", type=int, help="processes (default: every core)")
    parser.add_argument("--filters", default=",".join(sweep.DEFAULT_FILTERS))
    parser.add_argument("--particles", default=",".join(map(str, sweep.DEFAULT_PARTICLES)))
    parser.add_argument("--redraw", action="store_true",
                        help="draw the sweeps' figures again from the runs saved in the results folder (after the "
                             "figure code changed); nothing is run and no table is written")
    parser.add_argument("--out", type=Path, help="write to OUT/figures, OUT/results and OUT/ledger.json instead "
                                                  "(to compare first)")
    ledger_argument(parser)
    args = parser.parse_args(argv)
    global FIGURES, RESULTS, REDRAW
    REDRAW = args.redraw
    if args.out:
        FIGURES, RESULTS = args.out / "figures", args.out / "results"
        if "--ledger" not in " ".join(sys.argv if argv is None else argv):
            args.ledger = args.out / "ledger.json"
    if args.list:
        print("\n".join(STUDIES))
        return
    args.filters = tuple(args.filters.split(","))
    args.particles = tuple(int(n) for n in args.particles.split(","))
    unknown = set(args.studies) - set(STUDIES)
    if unknown:
        parser.error(f"unknown studies {', '.join(sorted(unknown))}; see --list")
    FIGURES.mkdir(parents=True, exist_ok=True)
    for name in args.studies or STUDIES:
        start = time.perf_counter()
        found = STUDIES[name](args)
        if REDRAW:
            continue
        seconds = time.perf_counter() - start
        log = RESULTS / name / "run.json"
        log.parent.mkdir(parents=True, exist_ok=True)
        log.write_text(json.dumps({"study": name, "seconds": round(seconds, 1), "runs": args.runs,
                                   "seed": args.seed, "command": " ".join(["python", *sys.argv]),
                                   "machine": machine()}, indent=1) + "\n")
        command = f"python benchmarks/studies/studies.py --runs {args.runs} --seed {args.seed} {name}"
        record(f"studies/{name}", found, command, timings={"seconds": round(seconds, 1)}, path=args.ledger)
        print(f"{name}: {seconds:.0f} s", file=sys.stderr)


if __name__ == "__main__":
    main()
