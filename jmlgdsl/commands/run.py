"""`jmlgdsl run SPEC DATA`: diagnose which mode the plant is in at every time step.

Rows are filtered one at a time as they are read, so a file and a live stream (DATA = '-') take
the same path; with a stream every output row is flushed as soon as it is computed.
"""

from __future__ import annotations

import sys

MAX_SEGMENTS = 30


def register(subparsers):
    from ..infer import ALGORITHMS, DEFAULT_ALGORITHM
    from ..infer.resample import SCHEMES

    p = subparsers.add_parser(
        "run", help="diagnose the mode of a plant from measured data",
        description="Filter measured data through a plant model: the most probable mode and the "
                    "probability of every mode at each time step, state estimates, predicted "
                    "outputs and residuals. Data columns are bound to the spec's inputs and outputs "
                    "by name; an optional 'mode' column with the true mode names adds the diagnosis "
                    "error to the summary.")
    p.add_argument("spec", help="plant spec (.jmlg) or compiled model (.json/.npz)")
    p.add_argument("data", help="CSV data file, or - to read rows from standard input as they arrive")
    p.add_argument("--filter", default=DEFAULT_ALGORITHM, choices=list(ALGORITHMS),
                   help=f"filtering algorithm (default {DEFAULT_ALGORITHM})")
    p.add_argument("--particles", type=int, help="number of particles (default depends on the filter)")
    p.add_argument("--seed", type=int, help="random seed (the same seed gives the same output)")
    p.add_argument("--resampling", default="systematic", choices=list(SCHEMES), help="resampling scheme")
    p.add_argument("--ess-threshold", type=float, default=1.0,
                   help="resample when ESS < this fraction of the particles (1 = every step)")
    p.add_argument("-o", "--output", help="write one CSV row per time step here (- = standard output)")
    p.add_argument("--plot", metavar="FILE.png",
                   help="draw the mode posterior over time, the MAP and true modes, and measured vs "
                        "predicted outputs with residuals")
    p.add_argument("--prefilter", metavar="ma:K",
                   help="causal moving average over the last K readings before filtering, for very noisy "
                        "signals (the filter then predicts the averaged signal)")
    p.set_defaults(func=main)


def diagnose(args, on_step=None):
    """Filter the data named in args row by row, writing the result table if asked.

    Returns the Summary and the Filter; `on_step(step, row)` sees every step (to keep them for a figure).
    """
    import jmlgdsl

    from ..data import iter_rows, open_source, open_target
    from ..errors import DataError
    from ..infer import Filter
    from ..infer.result import Summary
    from ..infer.table import TableWriter
    from ..prefilter import MovingAverage, parse

    window = parse(args.prefilter)
    smooth = MovingAverage(window) if window else None
    model = jmlgdsl.load(args.spec)
    streaming = args.data == "-"
    source = "<stdin>" if streaming else args.data
    f = Filter(model, algorithm=args.filter, particles=args.particles, seed=args.seed,
               resampling=args.resampling, ess_threshold=args.ess_threshold)
    summary = Summary(max_segments=MAX_SEGMENTS)
    stream = open_source(args.data)
    out = writer = None
    try:
        if args.output is not None:
            out = open_target(args.output)
        for row in iter_rows(stream, model, source):
            step = f.step(row.y if smooth is None else smooth(row.y), row.u)
            summary.add(step, row.mode)
            if on_step is not None:
                on_step(step, row)
            if out is not None:
                writer = writer or TableWriter(out, model, row.time is not None, flush=streaming)
                writer.write(step, row.time)
    finally:
        if stream is not sys.stdin:
            stream.close()
        if out not in (None, sys.stdout):
            out.close()
    if not summary.T:
        raise DataError(f"{source}: no data rows")
    return summary, f


def report(summary, f) -> str:
    """The terminal report: mode segments, the diagnosis error when the truth is known, fit and speed."""
    model = f.model
    who = f"{f.algorithm}" + (f" with {f.particles} particles" if f.particles else "")
    lines = [f"{model.name}: {summary.T} steps, filter {who}", "mode segments (most probable mode):"]
    for a, b, k, total in summary.segments:
        span = f"{a}" if a == b else f"{a}\u2013{b}"
        lines.append(f"  t {span}: {model.modes[k]} (p\u0304 {total / (b - a + 1):.2f})")
    if summary.more_segments:
        lines.append(f"  \u2026 {summary.more_segments} more segments (see the output CSV)")
    if summary.labelled:
        lines.append(f"diagnosis error: {summary.diagnosis_error:.2f} % ({summary.wrong} of {summary.labelled} steps)")
    lines.append(f"log-likelihood: {summary.loglik:.2f}")
    lines.append(f"time per step: {1e3 * f.seconds / summary.T:.3f} ms")
    return "\n".join(lines)


def main(args) -> int:
    import numpy as np

    steps, truth = [], []
    summary, f = diagnose(args, (lambda step, row: (steps.append(step), truth.append(row.mode)))
                          if args.plot else None)
    out = sys.stderr if args.output == "-" else sys.stdout
    print(report(summary, f), file=out)
    if args.plot:
        from ..infer import Result
        from ..plots import result_figure

        result = Result.from_steps(f.model, f.algorithm, f.particles, steps, f.seconds)
        result_figure(result, args.plot, true_modes=None if truth[0] is None else np.array(truth))
        print(f"figure: {args.plot}", file=out)
    return 0
