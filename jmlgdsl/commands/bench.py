"""`jmlgdsl bench SPEC [DATA ...]`: diagnosis error of every filter at every particle count over many runs."""

from __future__ import annotations

import sys


def _list(kind):
    """An argparse type for a comma-separated list of `kind`."""
    def parse(text):
        try:
            return tuple(kind(item) for item in text.split(",") if item.strip())
        except ValueError:
            raise ValueError(text) from None
    parse.__name__ = f"comma-separated {kind.__name__} list"
    return parse


def _lags(text):
    """Smoothing lags from 'L,L,...': whole numbers >= 0, or 'offline'."""
    lags = []
    for item in (i.strip() for i in text.split(",") if i.strip()):
        if item.lower() in ("offline", "off-line", "none"):
            lags.append(None)
        elif item.isdigit():
            lags.append(int(item))
        else:
            raise ValueError(text)
    return tuple(dict.fromkeys(lags))


_lags.__name__ = "comma-separated list of lags (whole numbers or 'offline')"


def register(subparsers):
    from ..bench import DEFAULT_FILTERS, DEFAULT_PARTICLES

    p = subparsers.add_parser(
        "bench", help="compare filters and particle counts: diagnosis error, time per step",
        description="Run every filter at every particle count on data whose true mode is known (a "
                    "'mode' column) or on freshly simulated sequences, --runs times each with seeds "
                    "derived from --seed. Prints the diagnosis error (% of steps whose most probable "
                    "mode is wrong), the detection delay of the mode switches, the alarms' F1, FAR, MAR "
                    "and NAB score (the spec's first mode taken as healthy), time per step and "
                    "log-likelihood as Markdown tables, and writes "
                    "the tables (Markdown, CSV), every run (CSV) and figures to the output folder.")
    p.add_argument("spec", help="plant spec (.jmlg) or compiled model (.json/.npz)")
    p.add_argument("data", nargs="*", help="CSV data files with a 'mode' column (or use --simulate)")
    p.add_argument("--filters", type=_list(str), default=DEFAULT_FILTERS,
                   help=f"comma-separated filters (default {','.join(DEFAULT_FILTERS)})")
    p.add_argument("--particles", type=_list(int), default=DEFAULT_PARTICLES,
                   help=f"comma-separated particle counts (default {','.join(map(str, DEFAULT_PARTICLES))})")
    p.add_argument("--runs", type=int, default=25, help="independent runs per setting (default 25)")
    p.add_argument("--seed", type=int, default=0, help="root seed; the same seed repeats the sweep exactly")
    p.add_argument("--simulate", type=int, metavar="T", help="simulate a fresh sequence of T steps for each run")
    p.add_argument("--modes", metavar="SCHEDULE",
                   help='with --simulate: a fixed mode schedule instead of the Markov chain, e.g. "1-70:normal,71-238:fan"')
    p.add_argument("--nonlinear", action="store_true",
                   help="with --simulate/--modes: simulate the spec's ODEs, not its linearised modes")
    p.add_argument("--prefilter", metavar="ma:K", help="moving average over K readings before filtering")
    p.add_argument("--lag", type=_lags, default=(0,), metavar="L,...",
                   help="smoothing lags to compare, e.g. 0,5,10,offline (0 is the filter; default 0): adds "
                        "tables and a figure of error and detection delay against the lag")
    p.add_argument("--workers", type=int, help="processes (default: every core; 1 runs in this process)")
    p.add_argument("--scheduler", metavar="ADDRESS", help="run on this Dask scheduler (needs the dask extra)")
    p.add_argument("-o", "--output", default="bench", help="folder for tables and figures (default ./bench)")
    p.add_argument("--no-figures", action="store_true", help="write the tables only")
    p.set_defaults(func=main)


def sources(args, model):
    """The data sources named on the command line: the files, or one simulated source."""
    from pathlib import Path

    from ..bench import Sequence, Simulated, nonlinear_plant
    from ..data import read_csv
    from ..errors import DataError
    from ..output import check_count
    from .simulate import step_bytes

    if args.data and (args.simulate or args.modes or args.nonlinear):
        raise DataError("give data files or --simulate, not both")
    if not args.data:
        if args.simulate is None and args.modes is None:
            raise DataError("give data files with a 'mode' column, or --simulate T for simulated sequences")
        if args.simulate is not None:
            check_count("--simulate", args.simulate, step_bytes(model), "steps")
        if args.nonlinear:
            if Path(args.spec).suffix.lower() != ".jmlg":
                raise DataError("--nonlinear needs a .jmlg spec with an 'ode' block")
            nonlinear_plant(args.spec)  # a spec without equations fails here, before any run starts
        return [Simulated(args.simulate, args.modes, plant=args.spec if args.nonlinear else None)]
    stems = [Path(p).stem for p in args.data]
    if len(set(stems)) < len(stems):
        raise DataError(f"data files need different names (their tables are named after them): {', '.join(args.data)}")
    found = []
    for path in args.data:
        data = read_csv(path, model)
        if data.modes is None:
            raise DataError(f"{path}: no 'mode' column, so the diagnosis error cannot be measured")
        if (data.modes < 0).any():
            raise DataError(f"{path}: data row {int((data.modes < 0).argmax()) + 1} has no true mode, so "
                            "the diagnosis error cannot be measured on it")
        found.append(Sequence(Path(path).stem, data.y, data.u, data.modes))
    return found


def write_outputs(folder, model, records, by_source, figures=True) -> list:
    """Every run, and each data source's tables and figures from its (records, summary) in
    `by_source`; returns the paths written."""
    from pathlib import Path

    from .. import bench, plots
    from ..output import replacing

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)

    def put(file, write):
        """Write one table through a temporary file, so an interrupted sweep leaves the old one."""
        with replacing(folder / file) as temporary:
            write(temporary)
        return folder / file

    written = [put("runs.csv", lambda path: bench.write_records_csv(path, records))]
    for name, (mine, summary) in by_source.items():
        written += [put(f"{name}-table.md", lambda path: path.write_text(bench.report(summary))),
                    put(f"{name}-table.csv", lambda path: bench.write_table_csv(path, summary))]
        if figures:
            first = mine[0].get("lag", 0)  # the study figures of the first lag asked for
            written += plots.study_figures(folder, name, f"{model.name}, {name}", model.dt,
                                           [r for r in summary if r.get("lag", 0) == first],
                                           [r for r in mine if r.get("lag", 0) == first])
            if len({r.get("lag", 0) for r in mine}) > 1:
                written.append(plots.error_vs_lag(summary, folder / f"{name}-error-vs-lag.png",
                                                  f"{model.name}, {name}"))
    return written


def main(args) -> int:
    """Run the command on parsed arguments; returns the exit status."""
    from pathlib import Path

    import jmlgdsl

    from .. import bench, prefilter
    from ..diagnosis.report import plural
    from ..output import check_folder

    stems = [Path(p).stem for p in args.data] or ["simulated"]
    check_folder(args.output, ["runs.csv"] + [f"{s}-table.{x}" for s in stems for x in ("md", "csv")],
                 inputs=[args.spec, *args.data])
    model = jmlgdsl.load(args.spec)
    window = prefilter.parse(args.prefilter)
    records = bench.sweep(model, sources(args, model), args.filters, args.particles, args.runs, args.seed,
                          window, args.workers, args.scheduler, progress=sys.stderr, lags=args.lag)
    by_source = {}
    for name in dict.fromkeys(r["data"] for r in records):
        mine = [r for r in records if r["data"] == name]
        by_source[name] = mine, bench.summarise(mine)
        print(f"## {model.name}, {name}: {plural(args.runs, 'run')} per setting\n")
        print(bench.report(by_source[name][1]))
    written = write_outputs(args.output, model, records, by_source, figures=not args.no_figures)
    print("wrote " + ", ".join(str(p) for p in written))
    return 0
