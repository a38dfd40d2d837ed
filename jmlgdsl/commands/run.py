"""`jmlgdsl run SPEC DATA`: diagnose which mode the plant is in at every time step.

Rows are filtered one at a time as they are read, so a file and a live stream (DATA = '-') take
the same path; with a stream every output row is flushed as soon as it is computed.
"""

from __future__ import annotations

import sys

from . import add_alarm_options, add_filter_options, check_particles, diagnosis_options


def register(subparsers):
    p = subparsers.add_parser(
        "run", help="diagnose the mode of a plant from measured data",
        description="Filter measured data through a plant model: the most probable mode and the "
                    "probability of every mode at each time step, state estimates, predicted "
                    "outputs and residuals. Data columns are bound to the spec's inputs and outputs "
                    "by name. Every row also gets an alarm (0/1) from the alarm rule: P(not healthy) "
                    "above --threshold for --persistence steps in a row. When the data carry the "
                    "truth (a 'mode' column of true mode names, or 0/1 'anomaly' and 'changepoint' "
                    "columns) the summary adds the diagnosis error, the confusion matrix and the "
                    "detection metrics: detection rate, FAR, MAR, F1, detection delay, false alarms "
                    "per hour and the NAB scores. On a terminal a run of more than a second shows "
                    "its count of rows and their rate on standard error as it goes.")
    p.add_argument("spec", help="plant spec (.jmlg) or compiled model (.json/.npz)")
    p.add_argument("data", nargs="+",
                   help="CSV data file, or - to read rows from standard input as they arrive (each row's "
                        "results are then written to standard output at once, the summary to standard error "
                        "at the end). Several files are several units of the same plant (a fleet: "
                        "run SPEC units/*.csv -o OUTDIR/): each is diagnosed as it would be alone, with its "
                        "own alarms and truth, and the imm filter steps all of them at once")
    add_filter_options(p)
    p.add_argument("-o", "--output", help="write one CSV row per time step here (- = standard output, "
                                          "the default when the data come from standard input); with "
                                          "several data files, a folder: OUTDIR/NAME.csv for each NAME.csv "
                                          "given, every table written only once all of them are done")
    p.add_argument("--plot", metavar="FILE.png",
                   help="draw the mode posterior over time, the MAP and true modes, measured vs predicted "
                        "outputs, and the residuals over their predicted sd, with the file's anomaly labels")
    add_alarm_options(p)
    p.add_argument("--cluster", metavar="auto|HOST:PORT",
                   help="with several data files: diagnose them on a Ray cluster, the files split into as many "
                        "chunks as the cluster has CPUs, each chunk a task that steps its units together; the "
                        "tables are the same as without it (auto: a Ray on this machine for this command, "
                        "reachable from 127.0.0.1 only; HOST:PORT: a cluster started with ray start --head, "
                        "whose machines all see the data files at the same paths). Needs pip install "
                        "'jmlgdsl[cluster]'")
    p.add_argument("--unit-specs", metavar="DIR",
                   help="with several data files: diagnose each unit with its own spec DIR/NAME.jmlg for NAME.csv "
                        "(the spec fitted to that unit: jmlgdsl fit SPEC units/*.csv -o DIR/), SPEC for a unit "
                        "without one; units of one shape still step together, each under its own numbers")
    when = p.add_mutually_exclusive_group()
    when.add_argument("--lag", type=int, metavar="L",
                      help="fixed-lag smoothing: report each row once L more rows have arrived, with "
                           "p(mode | data up to L rows later); fewer false alarms and errors around "
                           "switches, L samples late (also on a stream)")
    when.add_argument("--smooth", action="store_true",
                      help="off-line smoothing: every row with p(mode | all the data), written at the end")
    p.add_argument("--prefilter", metavar="ma:K",
                   help="causal moving average over the last K readings before filtering, for very noisy "
                        "signals (the filter then predicts the averaged signal)")
    p.add_argument("--explain", action="store_true",
                   help="the evidence per sensor: after the summary, for each alarm raised, the mode it points "
                        "at and the outputs that carry it (their share of the log-likelihood ratio of that mode "
                        "against the healthy ones, in nats; with several data files, under each unit's line); with -o "
                        "the table gains the columns evidence_mode and evidence_<output>")
    split = p.add_argument_group("detect, then name (one data file; the table holds the detector's columns)")
    split.add_argument("--detect", metavar="MODE,MODE[,...]", type=mode_list,
                       help="the alarm from these modes alone (the healthy ones and a catch-all, e.g. "
                            "normal,anomaly). Default: when the bank has fault modes and a catch-all of a "
                            "healthy mode (that mode with every noise scaled up, 'like normal { noise scale S }', "
                            "as 'jmlgdsl learn' writes one), the healthy modes and the catch-all, without "
                            "--prefilter or --explain; otherwise the whole bank")
    split.add_argument("--name", metavar="MODE,MODE[,...]", type=mode_list,
                       help="while the alarm is up, name each row by the most probable of these modes (the "
                            "fault modes, filtered on their own; default: the modes outside --detect). With the "
                            "true mode in the data the summary adds, per fault, the share of its rows named right "
                            "and the confusion among the faults")
    p.set_defaults(func=main)


def mode_list(text: str) -> tuple[str, ...]:
    """Mode names from comma-separated text."""
    return tuple(m.strip() for m in text.split(",") if m.strip())


def main(args) -> int:
    """Run the command on parsed arguments; returns the exit status."""
    import jmlgdsl

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
    options = diagnosis_options(args)
    model = jmlgdsl.load(args.spec)
    check_particles(args, model)
    ran = diagnose_file(model, data, options, output=output, kept=args.plot is not None, detect=args.detect,
                        name=args.name, progress=None if output == "-" else sys.stderr)
    out = sys.stderr if output == "-" else sys.stdout
    print(ran.report(), file=out)
    if args.plot:
        ran.draw(args.plot)
        print(f"figure: {args.plot}", file=out)
    return 0


def fleet(args) -> int:
    """`run` on several data files, one unit of the plant each (jmlgdsl.diagnosis.fleet.diagnose_files)."""
    from pathlib import Path

    import jmlgdsl

    from ..cluster import joined
    from ..diagnosis.fleet import diagnose_files, table_names, unit_banks
    from ..errors import JmlgError
    from ..names import plural
    from ..output import check_folder

    if args.plot is not None:
        raise JmlgError(f"--plot takes one data file, not {len(args.data)}")
    names = table_names(args.data)
    if args.output is not None:
        if args.output == "-":
            raise JmlgError("-o -: several data files write a table each; give a folder")
        check_folder(args.output, names, inputs=[args.spec, *args.data])
    options = diagnosis_options(args)
    model = jmlgdsl.load(args.spec)
    check_particles(args, model)
    models = None
    if args.unit_specs is not None:
        models, missing = unit_banks(model, args.unit_specs, [Path(path).stem for path in args.data])
        print(f"unit specs: {len(args.data) - len(missing)} of {plural(len(args.data), 'unit')} from {args.unit_specs}"
              + (f"; {', '.join(missing)} with {args.spec}" if missing else ""), file=sys.stderr)
    with joined(args.cluster):  # refused here, before any work, when no cluster answers
        history = diagnose_files(model, args.data, options, tables=args.output is not None, cluster=args.cluster,
                                 models=models, progress=sys.stderr if sys.stderr.isatty() else None)
    if args.output is not None:
        history.write(args.output)
    print(history.report(model, args.filter))
    if args.output is not None:
        print(f"tables: {args.output}")
    return 0
