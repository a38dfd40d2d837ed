"""`jmlgdsl run SPEC DATA`: diagnose which mode the plant is in at every time step.

Rows are filtered one at a time as they are read, so a file and a live stream (DATA = '-') take
the same path; with a stream every output row is flushed as soon as it is computed.
"""

from __future__ import annotations

import sys
import warnings
from array import array
from collections import deque

import numpy as np

from ..data import DataWarning

MAX_SEGMENTS = 30


def register(subparsers):
    from ..infer import ALGORITHMS, DEFAULT_ALGORITHM
    from ..infer.resample import SCHEMES

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
    p.add_argument("data", help="CSV data file, or - to read rows from standard input as they arrive "
                                "(each row's results are then written to standard output at once, "
                                "the summary to standard error at the end)")
    p.add_argument("--filter", default=DEFAULT_ALGORITHM, choices=list(ALGORITHMS),
                   help=f"filtering algorithm (default {DEFAULT_ALGORITHM})")
    p.add_argument("--particles", type=int, help="number of particles (default depends on the filter)")
    p.add_argument("--seed", type=int, help="random seed (the same seed gives the same output)")
    p.add_argument("--resampling", default="systematic", choices=list(SCHEMES), help="resampling scheme")
    p.add_argument("--ess-threshold", type=float, default=1.0,
                   help="resample when ESS < this fraction of the particles (1 = every step)")
    p.add_argument("-o", "--output", help="write one CSV row per time step here (- = standard output, "
                                          "the default when the data come from standard input)")
    p.add_argument("--plot", metavar="FILE.png",
                   help="draw the mode posterior over time, the MAP and true modes, and measured vs "
                        "predicted outputs with residuals")
    alarm = p.add_argument_group("alarm rule")
    alarm.add_argument("--healthy", metavar="MODE[,MODE...]",
                       help="the modes that raise no alarm (default: the first mode of the spec)")
    alarm.add_argument("--threshold", type=float, default=0.5,
                       help="alarm when P(not healthy) is above this (default 0.5)")
    alarm.add_argument("--persistence", type=int, default=1, metavar="K",
                       help="... at K consecutive steps; the alarm starts on the K-th (default 1)")
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
    p.set_defaults(func=main)


def alarm_rule(args, model):
    """The alarm rule the options describe; the first mode is the healthy one unless named."""
    from ..alarms import AlarmRule

    healthy = [m.strip() for m in args.healthy.split(",")] if args.healthy else [model.modes[0]]
    rule = AlarmRule(tuple(healthy), args.threshold, args.persistence)
    rule.faulty_modes(model.modes)  # unknown names are an error before any data are read
    return rule


class Labelled:
    """What the detection metrics need, kept row by row at a few bytes a row: the alarms, the 0/1
    truth (from an 'anomaly' column, else from the true mode), the true change points and the time."""

    def __init__(self, rule, model):
        self.model = model
        self.faulty = rule.faulty_modes(model.modes)  # (K,) which true modes are anomalies
        self.alarm, self.anomaly, self.changepoint = bytearray(), bytearray(), bytearray()
        self.time = array("d")
        self.has_anomaly = self.has_changepoint = True

    def add(self, row, alarm, t):
        """Keep one row's alarm, time and truth."""
        self.alarm.append(alarm)
        self.time.append(row.time if row.time is not None else t * self.model.dt)
        anomaly = row.anomaly
        if anomaly is None and row.mode is not None:
            anomaly = int(self.faulty[row.mode])
        self.has_anomaly &= anomaly is not None
        self.has_changepoint &= row.changepoint is not None
        self.anomaly.append(anomaly or 0)
        self.changepoint.append(row.changepoint or 0)

    def scores(self):
        """The detection scores, or None when the data carry no truth."""
        from .. import metrics

        if not self.has_anomaly or not self.alarm:
            return None
        anomaly = np.frombuffer(self.anomaly, dtype=np.uint8)
        changepoint = (np.frombuffer(self.changepoint, dtype=np.uint8) if self.has_changepoint
                       else metrics.changepoints(anomaly))
        return metrics.score(np.frombuffer(self.alarm, dtype=np.uint8), anomaly, np.array(self.time), changepoint)


class ScaleCheck:
    """Warns, once, about an output whose residuals over the first rows are orders of magnitude
    beyond the model's measurement noise: most often a column in another unit than the spec's."""

    rows, factor = 50, 100.0

    def __init__(self, model):
        self.model = model
        self.sd = np.sqrt(np.diagonal(model.R, axis1=1, axis2=2).mean(axis=0))  # (ny,)
        self.seen, self.done = [], False

    def add(self, step):
        """Note one step's residuals in units of the noise; judge once `rows` steps are in."""
        if not self.done:
            self.seen.append(np.abs(step.residual) / self.sd)
            if len(self.seen) == self.rows:
                self.finish()

    def finish(self):
        """Judge now (also at the end of a file shorter than the check's rows); only once."""
        if self.done or not self.seen:
            return
        self.done = True
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # an output never measured: all NaN
            typical = np.nanmedian(np.array(self.seen), axis=0)
        for name, size in zip(self.model.outputs, typical):
            if size > self.factor:
                unit = self.model.units.get(name)
                warnings.warn(DataWarning(
                    f"output {name!r}: its residuals are about {size:.3g} times the model's measurement noise; "
                    f"is the column in the spec's unit{f' [{unit}]' if unit else ''}?"), stacklevel=2)


def diagnose(args, on_step=None):
    """Filter the data named in args row by row, writing the result table if asked.

    Returns the Summary, the Filter, the alarm rule and the labels; `on_step(step, row)` sees every
    step (to keep them for a figure).
    """
    import jmlgdsl

    from ..data import iter_rows, open_source, open_target
    from ..errors import DataError, JmlgError
    from ..infer import Filter
    from ..infer.result import Summary
    from ..infer.table import TableWriter
    from ..output import FIGURE, check_count, check_file
    from ..prefilter import MovingAverage, parse
    from ..progress import Progress

    streaming = args.data == "-"
    if streaming and args.output is None:
        args.output = "-"  # a stream's results come out row by row as its rows arrive
    check_file(args.output, inputs=[args.spec, args.data])
    check_file(args.plot, inputs=[args.spec, args.data], suffixes=FIGURE, option="--plot")
    window = parse(args.prefilter)
    smooth = MovingAverage(window) if window else None
    model = jmlgdsl.load(args.spec)
    if args.particles is not None:
        from ..bench import particle_bytes
        from ..infer import ALGORITHMS

        if not ALGORITHMS[args.filter].uses_particles:
            raise JmlgError(f"--particles: the {args.filter} filter uses no particles (the particle filters "
                             f"are {', '.join(n for n, a in ALGORITHMS.items() if a.uses_particles)})")

        check_count("--particles", args.particles, particle_bytes(model))
    rule = alarm_rule(args, model)
    source = "<stdin>" if streaming else args.data
    f = Filter(model, algorithm=args.filter, particles=args.particles, seed=args.seed,
               resampling=args.resampling, ess_threshold=args.ess_threshold, lag=None if args.smooth else args.lag or 0)
    summary, alarms, labelled = Summary(max_segments=MAX_SEGMENTS), rule.stream(model.modes), Labelled(rule, model)
    scale = ScaleCheck(model)
    stream = open_source(args.data)
    out = writer = None
    rows = deque()  # data rows whose records the filter still holds back (with a lag)
    # a running count on a terminal, unless the table itself is streaming to the screen
    ticker = Progress(None, None if args.output == "-" else sys.stderr, "rows")

    def record(step):
        """Everything that happens to one finished record: alarm, summary, labels, table row."""
        nonlocal writer
        row = rows.popleft()
        alarm = alarms.step(step.mode_posterior)
        summary.add(step, row.mode)
        labelled.add(row, alarm, step.t)
        scale.add(step)
        if on_step is not None:
            on_step(step, row)
        if out is not None:
            if writer is None:
                writer = TableWriter(out, model, row.time is not None, flush=streaming, lag=f.lag)
            writer.write(step, row.time, alarm)

    try:
        if args.output is not None:
            out = open_target(args.output)
        for row in iter_rows(stream, model, source):
            rows.append(row)
            step = f.step(row.y if smooth is None else smooth(row.y), row.u)
            if step is not None:
                record(step)
            ticker.update()
        for step in f.flush():
            record(step)
        scale.finish()
    except Exception:
        if out not in (None, sys.stdout):
            out.discard()  # a run stopped by an error leaves the old table as it was
        raise
    finally:
        ticker.close()
        if stream is not sys.stdin:
            stream.close()
        if out not in (None, sys.stdout):
            out.close()
    if not summary.T:
        raise DataError(f"{source}: no data rows")
    return summary, f, rule, labelled


def smoothing(lag) -> str:
    """How the reported posteriors were conditioned, for the summary's first line."""
    return "" if lag == 0 else ", smoothed off-line" if lag is None else f", smoothed with a lag of {lag} steps"


def report(summary, f, rule=None, labelled=None) -> str:
    """The terminal report: mode segments, the diagnosis error when the truth is known, the alarms and
    their detection metrics, fit and speed."""
    model = f.model
    who = f"{f.algorithm}" + (f" with {f.particles} particles" if f.particles else "")
    lines = [f"{model.name}: {summary.T} steps, filter {who}" + smoothing(f.lag),
             "mode segments (most probable mode):"]
    for a, b, k, total in summary.segments:
        span = f"{a}" if a == b else f"{a}\u2013{b}"
        lines.append(f"  t {span}: {model.modes[k]} (p\u0304 {total / (b - a + 1):.2f})")
    if summary.more_segments:
        lines.append(f"  \u2026 {summary.more_segments} more segments (see the output CSV)")
    if summary.labelled:
        lines.append(f"diagnosis error: {summary.diagnosis_error:.2f} % ({summary.wrong} of {summary.labelled} steps)")
        lines += confusion_report(model.modes, summary.confusion)
    if rule is not None:
        lines += alarm_report(rule, labelled, f.lag)
    lines.append(f"log-likelihood: {summary.loglik:.2f}")
    lines.append(f"time per step: {1e3 * f.seconds / summary.T:.3f} ms")
    return "\n".join(lines)


def confusion_report(modes, confusion) -> list[str]:
    """The confusion matrix as text: a row per true mode, a column per diagnosed mode (steps)."""
    width = max(6, *(len(m) for m in modes), len(str(int(confusion.max()))))
    lines = ["confusion (rows: true mode, columns: diagnosed mode, steps):",
             "  " + " " * width + " " + " ".join(f"{m:>{width}}" for m in modes)]
    lines += [f"  {m:>{width}} " + " ".join(f"{int(c):>{width}}" for c in row) for m, row in zip(modes, confusion)]
    return lines


def alarm_report(rule, labelled, lag=0) -> list[str]:
    """Lines on the alarms raised and, against the truth in the data, how well they detect."""
    from ..metrics import runs

    raised = runs(np.frombuffer(labelled.alarm, dtype=np.uint8))
    lines = [f"alarms (healthy: {', '.join(rule.healthy)}; P(not healthy) > {rule.threshold:g} for "
             f"{rule.persistence} step{'s' if rule.persistence > 1 else ''}): {len(raised)} raised"]
    if lag:
        lines[0] += f"; each is known {lag} steps after its row, later than the delays below"
    scores = labelled.scores()
    if scores is None:
        return lines
    o, e, nab = scores.outlier, scores.events, scores.nab
    lines += [
        f"detection: {e.detected} of {e.episodes} anomaly episodes ({e.detection_rate:.1f} %), delay mean "
        f"{e.mean_delay:.1f} s, median {e.median_delay:.1f} s; {e.false_alarms} false alarms "
        f"({e.false_alarms_per_hour:.2f} per hour)",
        f"rows: F1 {o.f1:.3f}, false-alarm rate {o.far:.2f} %, missed-alarm rate {o.mar:.2f} %",
        f"NAB ({nab.windows} change point{'' if nab.windows == 1 else 's'}): standard {nab.score('standard'):.2f}, low FP "
        f"{nab.score('lowfp'):.2f}, low FN {nab.score('lowfn'):.2f}"]
    return lines


def main(args) -> int:
    """Run the command on parsed arguments; returns the exit status."""
    import dataclasses

    steps, truth = [], []
    summary, f, rule, labelled = diagnose(args, (lambda step, row: (steps.append(step), truth.append(row.mode)))
                                          if args.plot else None)
    out = sys.stderr if args.output == "-" else sys.stdout
    print(report(summary, f, rule, labelled), file=out)
    if args.plot:
        from ..infer import Result
        from ..plots import result_figure

        from ..output import replacing

        result = dataclasses.replace(Result.from_steps(f.model, f.algorithm, f.particles, steps, f.seconds), lag=f.lag)
        labelled = all(t is not None for t in truth)
        with replacing(args.plot) as temporary:
            result_figure(result, temporary, true_modes=np.array(truth) if labelled else None)
        print(f"figure: {args.plot}", file=out)
    return 0
