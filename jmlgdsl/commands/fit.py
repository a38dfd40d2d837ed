"""`jmlgdsl fit SPEC DATA.csv [MORE.csv ...] -o FITTED.jmlg`: fit a spec's unknowns to recorded data;
`jmlgdsl fit SPEC u1.csv u2.csv ... -o DIR/`: each file a unit of the plant, fitted on its own."""

from __future__ import annotations

import sys

from ..infer.algorithms import ALGORITHMS


def register(subparsers):
    p = subparsers.add_parser(
        "fit", help="fit the unknowns of a spec (parameters and noise levels with priors) to data",
        description="Gray-box identification. A spec may give a parameter, a mode's override or a noise level a prior "
                    "instead of a value ('param U ~ LogNormal(log(1.2), 0.3)'). 'fit' finds their maximum a posteriori "
                    "values given the data: log p(data | values) + log p(values) is maximised over the compiled bank "
                    "(nonlinear plants are re-linearised at each try). Data whose every row names its mode in a 'mode' "
                    "column have an exact likelihood (a Kalman filter through the labelled modes); other files use a "
                    "filter's (--filter). Unlabelled data first go through rounds of labelling by their most probable "
                    "modes. Prints each estimate with its standard error from the curvature (Laplace), names unknowns "
                    "the data cannot tell apart, warns when the fit did not converge or its curvature cannot be "
                    "trusted, and writes the spec with the fitted values.")
    p.add_argument("spec", help="plant spec (.jmlg) with unknowns")
    p.add_argument("data", nargs="+", metavar="DATA",
                   help="CSV recordings of the plant (several: one likelihood; with -o DIR/, one unit each)")
    p.add_argument("-o", "--output", default="-", metavar="FITTED.jmlg|DIR/",
                   help="where to write the fitted spec (default: standard output; the report goes to standard "
                        "error). A folder (ending in / or existing) fits each data file as a unit of the plant on its "
                        "own, in parallel: DIR/NAME.jmlg for each NAME.csv, and DIR/units.csv, every unit's values and "
                        "standard errors side by side (for run --unit-specs DIR/)")
    p.add_argument("--jobs", type=int, metavar="N", help="processes: with -o DIR/ the units fitted at a time, else the "
                                                          "--starts searched at a time (default: one per core)")
    p.add_argument("--filter", default="imm", choices=list(ALGORITHMS),
                   help="the filter whose likelihood is used for unlabelled data (default imm: deterministic and "
                        "smooth in the unknowns; a particle filter's likelihood is noisy)")
    p.add_argument("--samples", type=int, default=0, metavar="N",
                   help="also draw N values from the posterior by random-walk Metropolis (one likelihood evaluation "
                        "each) and report their means and 95 %% intervals")
    p.add_argument("--starts", type=int, metavar="N",
                   help="searches to start, keeping the highest peak: from the priors' medians; for data without a "
                        "mode column also there with every row first taken for the spec's first mode; the others "
                        "from draws of the priors. A guard against local optima, run side by side on the cores "
                        "(--jobs). Default 1 with labelled data, 2 without")
    p.add_argument("--seed", type=int, help="random seed for --samples and --starts (the same seed gives the same "
                                            "result)")
    p.add_argument("--no-label-rounds", dest="label_rounds", action="store_false",
                   help="for data without a mode column, climb the filter's likelihood from the start directly instead "
                        "of first labelling the rows by their most probable modes and fitting to those labels (faster "
                        "where the priors are already close; far from the truth it stays there)")
    p.add_argument("--strict", action="store_true",
                   help="exit with status 1 when the fit cannot be trusted (it did not converge, or its curvature is "
                        "noise: the warnings of the report); the fitted spec is written all the same")
    p.add_argument("-q", "--quiet", action="store_true", help="do not show the optimiser's progress")
    p.set_defaults(func=main)


def main(args) -> int:
    """Run the command on parsed arguments; returns the exit status."""
    from ..errors import JmlgError
    from ..fitting import fit
    from ..output import check_file, is_folder

    if args.jobs is not None and args.jobs < 1:
        raise JmlgError(f"--jobs must be 1 or more, got {args.jobs}")
    if is_folder(args.output):
        return units(args)
    check_file(args.output, inputs=[args.spec, *args.data])  # before the work: never over an input
    progress = None if args.quiet else (lambda text: print(text, file=sys.stderr, flush=True))
    result = fit(args.spec, args.data, algorithm=args.filter, samples=args.samples, starts=args.starts,
                 seed=args.seed, label_rounds=args.label_rounds, progress=progress, jobs=args.jobs)
    print(result.report(), file=sys.stderr)
    result.write(args.output)
    if args.output != "-":
        print(f"wrote {args.output}", file=sys.stderr)
    return 1 if args.strict and result.warnings else 0


def units(args) -> int:
    """Each data file a unit, fitted on its own: DIR/NAME.jmlg per NAME.csv and DIR/units.csv."""
    from pathlib import Path

    from ..fitting import check_units, fit_units, write_units
    from ..names import plural

    check_units(args.output, args.data, inputs=[args.spec])
    done = None if args.quiet else (lambda i, result: print(f"{args.data[i]}: {result.status()}", file=sys.stderr,
                                                             flush=True))
    fits = fit_units(args.spec, args.data, jobs=args.jobs, done=done, algorithm=args.filter, samples=args.samples,
                     starts=args.starts, seed=args.seed, label_rounds=args.label_rounds)
    for path, result in zip(args.data, fits):
        print(f"== {path}\n{result.report()}", file=sys.stderr)
    write_units(args.output, args.data, fits)
    flagged = [Path(path).stem for path, result in zip(args.data, fits) if result.warnings]
    print(f"wrote {plural(len(fits), 'unit spec')} and units.csv to {Path(args.output)}"
          + (f"; the fits of {', '.join(flagged)} cannot be trusted (their warnings above)" if flagged else ""),
          file=sys.stderr)
    return 1 if args.strict and flagged else 0
