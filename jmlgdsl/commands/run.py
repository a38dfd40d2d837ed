"""`jmlgdsl run SPEC DATA`: diagnose which mode the plant is in at every time step.

Rows are filtered one at a time as they are read, so a file and a live stream (DATA = '-') take
the same path; with a stream every output row is flushed as soon as it is computed.
"""

from __future__ import annotations

import sys
import time

MAX_SEGMENTS = 30


def register(subparsers):
    from ..infer.online import ALGORITHMS, DEFAULT_ALGORITHM
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


def columns(model, with_time):
    """Header of the per-step output table."""
    return (["t"] + (["time"] if with_time else []) + ["map_mode"] + [f"p_{m}" for m in model.modes]
            + [f"{s}_mean" for s in model.states] + [f"{o}_pred" for o in model.outputs]
            + [f"{o}_resid" for o in model.outputs] + ["ess"])


def table_row(model, step, row):
    """One output row for a filter step and the data row it came from."""
    return ([step.t] + ([row.time] if row.time is not None else []) + [model.modes[step.map_mode]]
            + list(step.mode_posterior) + list(step.state_mean) + list(step.y_pred) + list(step.residual)
            + [step.ess])


def diagnose(args):
    """Filter the data named in args, writing the output table if asked; returns (Result, true modes or None)."""
    import jmlgdsl

    from ..data import CsvWriter, iter_rows, open_source, open_target
    from ..errors import DataError
    from ..infer import Filter, Result
    from ..prefilter import MovingAverage, parse

    window = parse(args.prefilter)
    smooth = MovingAverage(window) if window else None
    model = jmlgdsl.load(args.spec)
    streaming = args.data == "-"
    source = "<stdin>" if streaming else args.data
    f = Filter(model, algorithm=args.filter, particles=args.particles, seed=args.seed,
               resampling=args.resampling, ess_threshold=args.ess_threshold)
    stream = open_source(args.data)
    out = None
    steps, truth, writer, seconds = [], [], None, 0.0
    try:
        if args.output is not None:
            out = open_target(args.output)
        for row in iter_rows(stream, model, source):
            y = row.y if smooth is None else smooth(row.y)
            start = time.perf_counter()
            step = f.step(y, row.u)
            seconds += time.perf_counter() - start
            steps.append(step)
            truth.append(row.mode)
            if out is not None:
                if writer is None:
                    writer = CsvWriter(out, columns(model, row.time is not None), flush=streaming)
                writer.write(table_row(model, step, row))
    finally:
        if stream is not sys.stdin:
            stream.close()
        if out not in (None, sys.stdout):
            out.close()
    if not steps:
        raise DataError(f"{source}: no data rows")
    result = Result.from_steps(model, args.filter, f.particles, steps, seconds)
    return result, None if truth[0] is None else truth


def segments(result):
    """(first t, last t, mode index, mean posterior of that mode) for each run of one MAP mode."""
    modes = result.map_modes
    starts = [0] + [t for t in range(1, len(modes)) if modes[t] != modes[t - 1]]
    ends = starts[1:] + [len(modes)]
    return [(a + 1, b, int(modes[a]), float(result.mode_posterior[a:b, modes[a]].mean()))
            for a, b in zip(starts, ends)]


def summary(result, truth) -> str:
    """The terminal report: mode segments, the diagnosis error when the truth is known, fit and speed."""
    model = result.model
    who = f"{result.algorithm}" + (f" with {result.particles} particles" if result.particles else "")
    lines = [f"{model.name}: {result.T} steps, filter {who}", "mode segments (most probable mode):"]
    segs = segments(result)
    for a, b, k, p in segs[:MAX_SEGMENTS]:
        span = f"{a}" if a == b else f"{a}\u2013{b}"
        lines.append(f"  t {span}: {model.modes[k]} (p\u0304 {p:.2f})")
    if len(segs) > MAX_SEGMENTS:
        lines.append(f"  \u2026 {len(segs) - MAX_SEGMENTS} more segments (see the output CSV)")
    if truth is not None:
        wrong = int((result.map_modes != truth).sum())
        lines.append(f"diagnosis error: {100.0 * wrong / result.T:.2f} % ({wrong} of {result.T} steps)")
    lines.append(f"log-likelihood: {result.loglik:.2f}")
    lines.append(f"time per step: {1e3 * result.seconds / result.T:.3f} ms")
    return "\n".join(lines)


def main(args) -> int:
    import numpy as np

    result, truth = diagnose(args)
    truth = None if truth is None else np.array(truth)
    report = sys.stderr if args.output == "-" else sys.stdout
    print(summary(result, truth), file=report)
    if args.plot:
        from ..plots import result_figure

        result_figure(result, args.plot, true_modes=truth)
        print(f"figure: {args.plot}", file=report)
    return 0
