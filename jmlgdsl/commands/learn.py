"""`jmlgdsl learn`: fit a mode bank to experiments of every mode and write it as a .jmlg spec."""

from __future__ import annotations

import math

import numpy as np


def register(subparsers):
    p = subparsers.add_parser(
        "learn", help="learn a mode bank from experiments of every mode and write a .jmlg spec",
        description="Fit one linear-Gaussian model per mode: an ARX least-squares fit (or an FOPDT "
                    "fit of a step test) gives the structure and the start for EM, which learns the "
                    "coefficients and both noise levels. Every mode is written over one shared state "
                    "basis, the recent noise-free outputs and inputs, so the bank stays right when the "
                    "plant switches. Every mode is validated (residual whiteness and input-residual "
                    "correlation up to lag 25 with 99 % bands, free-run fit) and the bank is written as "
                    "a readable, commented spec that 'jmlgdsl run' accepts. Without --template the "
                    "first --mode is the healthy one: the prior is 'initial FIRST 0.99, otherwise "
                    "uniform' (--initial) and the transitions 'stay 0.99, otherwise uniform' (--stay).")
    p.add_argument("--mode", action="append", required=True, metavar="NAME=CSV",
                   help="a mode's experiment (repeat for every mode; repeat a name for several runs of "
                        "one mode). A file with a 'mode' column gives only the rows labelled NAME, each "
                        "unbroken stretch of them a run")
    p.add_argument("--template", metavar="SPEC",
                   help="spec giving names, units, sample time, mode descriptions, transitions and prior")
    structure = p.add_mutually_exclusive_group()
    structure.add_argument("--order", default="auto",
                           help="ARX order: N (na = nb = N), NA,NB,NK, or auto (default: by --criterion)")
    structure.add_argument("--fopdt", action="store_true",
                           help="the experiments are step tests: first order plus dead time")
    p.add_argument("--criterion", choices=("bic", "aic"), default="bic", help="order selection criterion")
    p.add_argument("--max-order", type=int, default=4, help="largest na and nb tried by --order auto")
    p.add_argument("--max-delay", type=int, default=0, help="largest input delay nk tried by --order auto")
    p.add_argument("--input", default="", metavar="NAMES", help="input column names, comma separated (without --template)")
    p.add_argument("--output", dest="outputs", default=None, metavar="NAMES",
                   help="output column names, comma separated (without --template)")
    p.add_argument("--dt", type=float, default=1.0, help="sample time in seconds (without --template)")
    p.add_argument("--name", default="plant", help="plant name (without --template)")
    p.add_argument("--stay", type=float, default=0.99,
                   help="probability of staying in a mode, the rest uniform (without --template)")
    p.add_argument("--initial", type=float, default=0.99, metavar="P",
                   help="prior probability of the first --mode, taken as the healthy one; the rest is "
                        "shared uniformly (without --template; default 0.99)")
    p.add_argument("--max-iter", type=int, default=100, help="EM iteration cap (default 100)")
    p.add_argument("--tol", type=float, default=1e-5, help="EM relative log-likelihood tolerance (default 1e-5)")
    p.add_argument("--figures", metavar="DIR", help="write validation (and step-fit) figures here")
    p.add_argument("-q", "--quiet", action="store_true", help="do not report each mode as it is learned")
    p.add_argument("-o", "--output-spec", dest="spec_out", default="-", metavar="FILE", help="spec file to write (default: standard output)")
    p.set_defaults(func=main)


def parse_order(text: str):
    """'auto', 'N' or 'NA,NB,NK' as the learn pipeline's order argument."""
    from ..errors import JmlgError

    if text == "auto":
        return "auto"
    try:
        parts = [int(v) for v in text.split(",")]
    except ValueError:
        parts = []
    if len(parts) == 1 and parts[0] >= 1:
        return parts[0], parts[0], 0
    if len(parts) == 3 and parts[0] >= 1 and parts[1] >= 1 and parts[2] >= 0:
        return tuple(parts)
    raise JmlgError(f"--order must be auto, N or NA,NB,NK (na, nb >= 1, nk >= 0), not {text!r}")


def check_numbers(args):
    """Refuse option values no fit can use (an empty order grid, a sample time that is not positive)."""
    from ..errors import JmlgError

    for option, value, least in (("--max-order", args.max_order, 1), ("--max-delay", args.max_delay, 0),
                                 ("--max-iter", args.max_iter, 0)):
        if value < least:
            raise JmlgError(f"{option} must be at least {least}, not {value}")
    if not (math.isfinite(args.dt) and args.dt > 0):
        raise JmlgError(f"--dt must be a positive number of seconds, not {args.dt}")


def parse_modes(items):
    """{name: [path, ...]} from NAME=CSV items, modes in the order first given."""
    from ..errors import JmlgError

    modes = {}
    for item in items:
        name, sep, path = item.partition("=")
        if not sep or not name.isidentifier() or not path:
            raise JmlgError(f"--mode takes NAME=CSV, not {item!r}")
        modes.setdefault(name, []).append(path)
    return modes


def runs(data, mode: str, index: int):
    """The Experiments of one mode in a data file: the whole file, or, when it has a `mode` column,
    each unbroken stretch of rows labelled with that mode."""
    from ..errors import DataError
    from ..learn.bank import Experiment

    if data.modes is None:
        return [Experiment(data.y, data.u, data.source)]
    rows = np.flatnonzero(data.modes == index)
    if not len(rows):
        raise DataError(f"{data.source}: no rows of mode {mode!r} in its 'mode' column")
    stretches = np.split(rows, np.flatnonzero(np.diff(rows) > 1) + 1)
    return [Experiment(data.y[r], data.u[r], f"{data.source} (rows of {mode}, {r[0] + 1}-{r[-1] + 1})")
            for r in stretches]


def plant_frame(args, names):
    """(Model fields other than the matrices, mode order) from the template or the options."""
    import jmlgdsl

    from ..errors import JmlgError
    from ..learn.bank import default_transitions

    if args.template:
        t = jmlgdsl.load(args.template)
        if set(names) != set(t.modes):
            raise JmlgError(f"{args.template} has modes {', '.join(t.modes)}; give one experiment for each "
                            f"(got {', '.join(names)})")
        return dict(name=t.name, dt=t.dt, inputs=t.inputs, outputs=t.outputs, units=t.units,
                    input_defaults=t.input_defaults, descriptions=t.descriptions, P=t.P, p0=t.p0), t.modes
    if not args.outputs:
        raise JmlgError("name the output column with --output (or give a --template)")
    for option, value in (("--stay", args.stay), ("--initial", args.initial)):
        if not 0 <= value <= 1:
            raise JmlgError(f"{option} must be a probability, not {value}")
    inputs = tuple(n.strip() for n in args.input.split(",") if n.strip())
    outputs = tuple(n.strip() for n in args.outputs.split(",") if n.strip())
    K = len(names)
    return dict(name=args.name, dt=args.dt, inputs=inputs, outputs=outputs, units={},
                input_defaults=np.full(len(inputs), np.nan), descriptions={}, P=default_transitions(K, args.stay),
                p0=healthy_prior(K, args.initial)), tuple(names)


def healthy_prior(K: int, p: float) -> np.ndarray:
    """The first mode (the healthy one) with probability p, the rest shared evenly: written back as
    `initial NAME p, otherwise uniform`, so the first rows of a run do not alarm."""
    if K == 1:
        return np.ones(1)
    return np.r_[p, np.full(K - 1, (1 - p) / (K - 1))]


def header(args, paths, learned) -> str:
    """The comment block at the top of the written spec: where it came from and how well it fits."""
    from ..names import plural
    from ..learn import validate

    how = ("FOPDT fits of step tests" if args.fopdt else
           f"states chosen by {args.criterion.upper()} of the EM fits, started from ARX" if args.order == "auto"
           else f"ARX order {args.order}")
    lines = [f"Learned by jmlgdsl learn from {', '.join(dict.fromkeys(p for ps in paths.values() for p in ps))}",
             f"Structure: {how}; EM up to {plural(args.max_iter, 'iteration')}, relative tolerance {args.tol:g}.",
             "Every mode shares one state basis: the noise-free outputs of the last steps (NAME_lag1, ...)",
             "and the inputs before this step (NAME_lag1, ...); a mode's coefficients and offset are its",
             "first rows. B, D are Cholesky factors of the learned process and measurement noise",
             "covariances. Each mode starts at its steady state under the operating input (a mode that is",
             "not stable, where its experiment began).",
             f"Validation: residual autocorrelation (lags 1-{validate.MAX_LAG}) and input-residual "
             f"cross-correlation (lags 0-{validate.MAX_LAG}) pass when at most {validate.ALLOWED_OUTSIDE} "
             "lag of each lies outside the 99 % band.",
             ""] + [lm.summary() for lm in learned]
    return "\n".join(lines)


def write_figures(folder, learned, frame, report):
    """Each mode's validation figure, and its step-test fit when it has one."""
    from pathlib import Path

    from ..learn import figures

    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    ylabel, xname = frame["outputs"][0], (frame["inputs"] or ("input",))[0]
    for lm in learned:
        paths = [figures.plot_validation(lm, out / f"validation_{lm.name}.png", frame["dt"], ylabel, xname)]
        if lm.fopdt is not None:
            paths.append(figures.plot_step(lm.fopdt, lm.experiment.y, out / f"step_{lm.name}.png",
                                           f"Step test, mode {lm.name}", ylabel))
        for path in paths:
            print(f"wrote {path}", file=report)


def main(args) -> int:
    """Run the command on parsed arguments; returns the exit status."""
    import sys
    from pathlib import Path

    from ..data import Columns, read_csv
    from ..learn import bank
    from ..learn.writer import write_spec

    from ..output import check_file, check_folder, replacing

    paths = parse_modes(args.mode)
    check_file(args.spec_out, inputs=[p for runs_ in paths.values() for p in runs_] + [args.template])
    if args.figures:
        check_folder(args.figures, option="--figures")
    order = parse_order(args.order)
    check_numbers(args)
    frame, modes = plant_frame(args, list(paths))
    names = Columns(outputs=frame["outputs"], inputs=frame["inputs"], input_defaults=frame["input_defaults"],
                    modes=modes, dt=frame["dt"])
    experiments = {mode: [run for path in paths[mode] for run in runs(read_csv(path, names), mode, k)]
                   for k, mode in enumerate(modes)}
    progress = None if args.quiet else (lambda text: print(text, file=sys.stderr, flush=True))
    learned = bank.learn_modes(experiments, order, args.fopdt, frame["dt"], args.max_order, args.max_delay,
                               args.criterion, args.max_iter, args.tol, progress)
    defaults = frame["input_defaults"]
    model = bank.assemble(learned, operating_input=defaults if np.isfinite(defaults).all() else None, **frame)
    text = write_spec(model, header(args, paths, learned))
    report = sys.stderr if args.spec_out == "-" else sys.stdout
    if args.spec_out == "-":
        sys.stdout.write(text)
    else:
        with replacing(args.spec_out) as temporary:
            Path(temporary).write_text(text)
        print(f"wrote {args.spec_out}", file=report)
    for lm in learned:
        print(lm.summary(), file=report)
    if args.figures:
        write_figures(args.figures, learned, frame, report)
    return 0
