"""`jmlgdsl run SPEC DATA`: diagnose which mode the plant is in at every time step (one data file or
a stream: jmlgdsl.diagnosis.files.diagnose_file; several, a fleet: jmlgdsl.diagnosis.fleet.diagnose_files)."""

from __future__ import annotations

import sys

from . import (add_alarm_options, add_cluster_option, add_filter_options, add_smoothing_options, add_split_options,
               add_unit_specs_option, model_and_options)


def register(subparsers):
    p = subparsers.add_parser(
        "run", help="diagnose the mode of a plant from measured data",
        description="Filter measured data through a plant model: the most probable mode and the probability of every "
                    "mode at each time step, state estimates, predicted outputs and residuals. Data columns are bound "
                    "to the spec's inputs and outputs by name. Every row also gets an alarm (0/1) from the alarm "
                    "rule: P(not healthy) above --threshold for --persistence steps in a row. When the data carry "
                    "the truth (a 'mode' column of true mode names, or 0/1 'anomaly' and 'changepoint' columns) the "
                    "summary adds the diagnosis error, the confusion matrix and the detection metrics: detection "
                    "rate, FAR, MAR, F1, detection delay, false alarms per hour and the NAB scores. On a terminal a "
                    "run of more than a second shows its count of rows and their rate on standard error as it goes.")
    p.add_argument("spec", help="plant spec (.jmlg) or compiled model (.json/.npz)")
    p.add_argument("data", nargs="+",
                   help="CSV data file, or - to read rows from standard input as they arrive (each row's results are "
                        "then written to standard output at once, the summary to standard error at the end). Several "
                        "files are several units of the same plant (a fleet: run SPEC units/*.csv -o OUTDIR/): each "
                        "is diagnosed as it would be alone, with its own alarms and truth, and the imm filter steps "
                        "all of them at once")
    add_filter_options(p)
    p.add_argument("-o", "--output", help="write one CSV row per time step here (- = standard output, the default "
                                          "when the data come from standard input); with several data files, a "
                                          "folder: OUTDIR/NAME.csv for each NAME.csv given, every table written only "
                                          "once all of them are done")
    p.add_argument("--plot", metavar="FILE.png",
                   help="draw the mode posterior over time, the MAP and true modes, measured vs predicted outputs, "
                        "and the residuals over their predicted sd, with the file's anomaly labels")
    add_alarm_options(p)
    add_cluster_option(p, "with several data files: diagnose them on a Ray cluster, the files split into as many "
                          "chunks as the cluster has CPUs, each chunk a task that steps its units together; the "
                          "tables are the same as without it", ", whose machines all see the data files at the same paths")
    add_unit_specs_option(p, "with several data files", "DIR/NAME.jmlg for NAME.csv",
                          "units of one shape still step together, each under its own numbers")
    add_smoothing_options(p)
    add_split_options(p)
    p.set_defaults(func=main)


def main(args) -> int:
    """Run the command on parsed arguments; returns the exit status."""
    from ..diagnosis.files import diagnose_file
    from ..errors import JmlgError
    from ..output import FIGURE, check_file

    if len(args.data) > 1:
        if args.detect or args.name:
            raise JmlgError(f"--detect and --name take one data file, not {len(args.data)}")
        return fleet(args)
    if args.cluster:
        raise JmlgError("--cluster spreads several data files over a Ray cluster; with one file, leave it out")
    if args.unit_specs:
        raise JmlgError("--unit-specs gives each of several data files its unit's spec; with one file, give its "
                        "unit's spec as SPEC")
    data = args.data[0]
    output = "-" if data == "-" and args.output is None else args.output  # a stream's rows come out as they arrive
    check_file(output, inputs=[args.spec, data])
    check_file(args.plot, inputs=[args.spec, data], suffixes=FIGURE, option="--plot")
    model, options = model_and_options(args)
    ran = diagnose_file(model, data, options, output=output, kept=args.plot is not None, detect=args.detect,
                        name=args.name, progress=None if output == "-" else sys.stderr)
    out = sys.stderr if output == "-" else sys.stdout
    print(ran.report(), file=out)
    if args.plot:
        ran.draw(args.plot)
        print(f"figure: {args.plot}", file=out)
    return 0


def fleet(args) -> int:
    """`run` on several data files, one unit of the plant each."""
    from ..diagnosis.cluster import joined
    from ..diagnosis.fleet import check_tables, diagnose_files, file_banks
    from ..errors import JmlgError

    if args.plot is not None:
        raise JmlgError(f"--plot takes one data file, not {len(args.data)}")
    check_tables(args.output, args.data, inputs=[args.spec])
    model, options = model_and_options(args)
    models = None
    if args.unit_specs is not None:
        models, said = file_banks(model, args.unit_specs, args.data, args.spec)
        print(said, file=sys.stderr)
    with joined(args.cluster):  # refused here, before any work, when no cluster answers
        history = diagnose_files(model, args.data, options, tables=args.output is not None, cluster=args.cluster,
                                 models=models, progress=sys.stderr if sys.stderr.isatty() else None)
    if args.output is not None:
        history.write(args.output)
    print(history.report(model, args.filter) + ("" if args.output is None else f"\ntables: {args.output}"))
    return 0
