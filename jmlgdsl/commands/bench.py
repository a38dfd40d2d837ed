"""`jmlgdsl bench SPEC [DATA ...]`: diagnosis error of every filter at every particle count over many runs."""

from __future__ import annotations

import sys

from . import add_cluster_option, healthy_modes, lags, listed


def register(subparsers):
    from ..studies.sweep import DEFAULT_FILTERS, DEFAULT_PARTICLES

    p = subparsers.add_parser(
        "bench", help="compare filters and particle counts: diagnosis error, naming, time per step",
        description="Run every filter at every particle count on data whose true mode is known (a "
                    "'mode' column) or on freshly simulated sequences, --runs times each with seeds "
                    "derived from --seed. Prints the diagnosis error (% of steps whose most probable "
                    "mode is wrong), the detection delay of the mode switches, the alarms' F1, FAR, MAR "
                    "and NAB score (alarm: P(not healthy) > 0.5), the naming (% of the faulty rows "
                    "named right: while the alarm is up, by the most probable non-healthy mode; the "
                    "runs' counts pooled), time per step and log-likelihood as Markdown tables, then "
                    "per fault the share of its rows named right and the confusion among the faults "
                    "for the setting that names best; writes "
                    "the tables (Markdown, CSV), every run (CSV) and figures to the output folder.")
    p.add_argument("spec", help="plant spec (.jmlg) or compiled model (.json/.npz)")
    p.add_argument("data", nargs="*", help="CSV data files with a 'mode' column (or use --simulate)")
    p.add_argument("--filters", type=listed(str), default=DEFAULT_FILTERS,
                   help=f"comma-separated filters (default {','.join(DEFAULT_FILTERS)})")
    p.add_argument("--particles", type=listed(int), default=DEFAULT_PARTICLES,
                   help=f"comma-separated particle counts (default {','.join(map(str, DEFAULT_PARTICLES))})")
    p.add_argument("--runs", type=int, default=25, help="independent runs per setting (default 25)")
    p.add_argument("--seed", type=int, default=0, help="root seed; the same seed repeats the sweep exactly")
    p.add_argument("--simulate", type=int, metavar="T", help="simulate a fresh sequence of T steps for each run")
    p.add_argument("--modes", metavar="SCHEDULE",
                   help='with --simulate: a fixed mode schedule instead of the Markov chain, e.g. "1-70:normal,71-238:fan"')
    p.add_argument("--nonlinear", action="store_true",
                   help="with --simulate/--modes: simulate the spec's ODEs, not its linearised modes")
    p.add_argument("--prefilter", metavar="ma:K", help="moving average over K readings before filtering")
    p.add_argument("--lag", type=lags, default=(0,), metavar="L,...",
                   help="smoothing lags to compare, e.g. 0,5,10,offline (0 is the filter; default 0): adds "
                        "tables and a figure of error and detection delay against the lag")
    p.add_argument("--healthy", metavar="MODE[,MODE...]",
                   help="the modes that raise no alarm, as in run (default: the first mode of the spec); "
                        "the others are the faults to name")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int, help="processes (default: every core; 1 runs in this process)")
    add_cluster_option(where, "instead of --workers: every run a Ray task on a cluster, the same records as on this "
                              "machine")
    p.add_argument("-o", "--output", default="bench", help="folder for tables and figures (default ./bench)")
    p.add_argument("--no-figures", action="store_true", help="write the tables only")
    p.set_defaults(func=main)


def main(args) -> int:
    """Run the command on parsed arguments; returns the exit status."""
    from pathlib import Path

    import jmlgdsl

    from ..diagnosis.cluster import disconnect
    from ..diagnosis.prefilter import parse
    from ..output import check_folder
    from ..studies.study import sources, study

    stems = [Path(p).stem for p in args.data] or ["simulated"]
    check_folder(args.output, ["runs.csv"] + [f"{s}-table.{x}" for s in stems for x in ("md", "csv")],
                 inputs=[args.spec, *args.data])
    model = jmlgdsl.load(args.spec)
    window = parse(args.prefilter)
    data = sources(model, args.data, args.simulate, args.modes, args.spec if args.nonlinear else None)
    try:  # the sweep joins the cluster once its settings are checked, before any run
        done = study(model, data, args.runs, filters=args.filters, particles=args.particles, seed=args.seed,
                     prefilter=window, workers=args.workers, cluster=args.cluster, progress=sys.stderr,
                     lags=args.lag, healthy=healthy_modes(args))
    finally:
        disconnect()
    print(done.report())
    written = done.write(args.output, figures_too=not args.no_figures)
    print("wrote " + ", ".join(str(p) for p in written))
    return 0
