"""`jmlgdsl run SPEC DATA`: diagnose which mode the plant is in at every time step.

Rows are filtered one at a time as they are read, so a file and a live stream (DATA = '-') take
the same path; with a stream every output row is flushed as soon as it is computed.
"""

from __future__ import annotations

import sys

from . import add_alarm_options, add_filter_options, check_particles, healthy_modes


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
    import contextlib

    import jmlgdsl

    from ..data import iter_rows, open_source, open_target
    from ..diagnosis import AlarmRule, Diagnosis, Kept, Raised, TableSink
    from ..diagnosis.alarms import DetectThenName, catch_alls
    from ..diagnosis.prefilter import parse
    from ..diagnosis.report import evidence_report, naming_report
    from ..errors import DataError, JmlgError
    from ..output import FIGURE, check_file
    from ..progress import Progress

    if len(args.data) > 1:
        if args.detect or args.name:
            raise JmlgError(f"--detect and --name take one data file, not {len(args.data)}")
        return fleet(args)
    if args.cluster:
        raise JmlgError("--cluster spreads several data files over a Ray cluster; with one file, leave it out")
    if args.unit_specs:
        raise JmlgError("--unit-specs gives each of several data files its unit's spec; with one file, give its "
                        "unit's spec as SPEC")
    args.data = args.data[0]
    streaming = args.data == "-"
    if streaming and args.output is None:
        args.output = "-"  # a stream's results come out row by row as its rows arrive
    check_file(args.output, inputs=[args.spec, args.data])
    check_file(args.plot, inputs=[args.spec, args.data], suffixes=FIGURE, option="--plot")
    window = parse(args.prefilter)
    model = jmlgdsl.load(args.spec)
    check_particles(args, model)
    healthy = healthy_modes(args) or model.modes[:1]
    naming = None
    detect, name = args.detect, args.name
    if not (detect or name or args.prefilter or args.explain) and set(healthy) <= set(model.modes):
        # a bank with a catch-all of its healthy modes and fault modes: detect with those, name with the rest
        found = catch_alls(model, healthy)
        if found and len(model.modes) > len(healthy) + len(found):
            detect = list(healthy) + found
    if detect or name:
        for given, option in ((args.prefilter, "--prefilter"), (args.explain or None, "--explain")):
            if given is not None:
                raise JmlgError(f"--detect and --name take no {option}: the namer filters the rows as they are")
        naming = DetectThenName(model, detect, name, healthy,
                                algorithm=args.filter, particles=args.particles, seed=args.seed,
                                resampling=args.resampling, ess_threshold=args.ess_threshold)
        model = naming.detector
    kept = Kept() if args.plot else None
    raised = Raised() if args.explain else None
    # a running count on a terminal, unless the table itself is streaming to the screen
    ticker = Progress(None, None if args.output == "-" else sys.stderr, "rows")
    diagnosis = Diagnosis(model, algorithm=args.filter, particles=args.particles, seed=args.seed,
                          resampling=args.resampling, ess_threshold=args.ess_threshold,
                          lag=None if args.smooth else args.lag or 0, prefilter=window,
                          rule=AlarmRule(tuple(healthy), args.threshold, args.persistence), sinks=[ticker],
                          explain=args.explain)
    with contextlib.ExitStack() as stack, open_source(args.data) as source:
        stack.callback(ticker.close)
        if args.output is not None:  # the table appears whole when the run ends, or not at all
            out = stack.enter_context(open_target(args.output))
            diagnosis.sinks.append(TableSink(out, model, diagnosis.filter.lag, flush=streaming, explain=args.explain))
        diagnosis.sinks += [sink for sink in (kept, raised, naming) if sink is not None]
        rows = iter_rows(source, model if naming is None else naming.whole, source.name)
        diagnosis.run(rows if naming is None else naming.rows(rows))
        if not diagnosis.summary.T:
            raise DataError(f"{source.name}: no data rows")
    out = sys.stderr if args.output == "-" else sys.stdout
    if naming is not None and not (args.detect or args.name):
        print(f"detect, then name: the alarm from {', '.join(naming.detector.modes)} (a healthy mode and its "
              f"catch-all), the fault named by {', '.join(naming.namer.modes)}; --detect with every mode gives the "
              "whole bank's alarm", file=out)
    print(diagnosis.report(), file=out)
    counts = None if naming is None else naming.counts()
    if counts is not None:
        print("\n".join(naming_report(naming.namer.modes, counts)), file=out)
    if raised is not None:
        print("\n".join(evidence_report(model, raised)), file=out)
    if args.plot:
        kept.draw(diagnosis, args.plot)
        print(f"figure: {args.plot}", file=out)
    return 0


def fleet(args) -> int:
    """`run` on several data files, one unit of the plant each: a table per unit in the folder -o
    (none unless every unit is diagnosed) and a line per unit on standard output; with --cluster,
    chunks of the files in Ray tasks (jmlgdsl.diagnosis.fleet.diagnose_files)."""
    from pathlib import Path

    import jmlgdsl

    from ..cluster import joined
    from ..data import open_target
    from ..diagnosis import AlarmRule
    from ..diagnosis.fleet import diagnose_files, unit_banks
    from ..diagnosis.prefilter import parse
    from ..errors import JmlgError
    from ..output import check_folder
    from ..names import plural

    if args.plot is not None:
        raise JmlgError(f"--plot takes one data file, not {len(args.data)}")
    if "-" in args.data:
        raise JmlgError("standard input (-) cannot be one of several data files")
    names = [Path(path).stem + ".csv" for path in args.data]
    twice = sorted({name for name in names if names.count(name) > 1})
    if twice:
        raise JmlgError(f"two data files would write the same table {twice[0]}; give files with different names")
    if args.output is not None:
        if args.output == "-":
            raise JmlgError("-o -: several data files write a table each; give a folder")
        check_folder(args.output, names, inputs=[args.spec, *args.data])
    window = parse(args.prefilter)
    model = jmlgdsl.load(args.spec)
    check_particles(args, model)
    models = None
    if args.unit_specs is not None:
        models, missing = unit_banks(model, args.unit_specs, [Path(path).stem for path in args.data])
        print(f"unit specs: {len(args.data) - len(missing)} of {plural(len(args.data), 'unit')} from {args.unit_specs}"
              + (f"; {', '.join(missing)} with {args.spec}" if missing else ""), file=sys.stderr)
    with joined(args.cluster):  # refused here, before any work, when no cluster answers
        history = diagnose_files(
            model, args.data, tables=args.output is not None, cluster=args.cluster, models=models,
            progress=sys.stderr if sys.stderr.isatty() else None, algorithm=args.filter, particles=args.particles,
            seed=args.seed, resampling=args.resampling, ess_threshold=args.ess_threshold,
            lag=None if args.smooth else args.lag or 0, prefilter=window, explain=args.explain,
            rule=AlarmRule(tuple(healthy_modes(args) or model.modes[:1]), args.threshold, args.persistence))
    if args.output is not None:
        Path(args.output).mkdir(parents=True, exist_ok=True)
        for name, unit in zip(names, history.units):
            with open_target(Path(args.output) / name) as out:
                out.write(unit.table)
    for unit in history.units:
        line = (f"{unit.path}: {plural(unit.steps, 'step')}, last mode {unit.last_mode}, "
                f"{plural(unit.alarms, 'alarm')} raised")
        if unit.error is not None:
            line += f", diagnosis error {unit.error:.2f} %"
        print(line)
        for evidence in unit.evidence or ():
            print("  " + evidence)
    steps = sum(unit.steps for unit in history.units)
    how = "the units stepped together" if history.batched else "unit after unit"
    print(f"{model.name}: {plural(len(history.units), 'unit')}, filter {args.filter} ({how}), "
          f"{1e6 * history.seconds / max(steps, 1):.2f} us per unit-step")
    if args.output is not None:
        print(f"tables: {args.output}")
    return 0
