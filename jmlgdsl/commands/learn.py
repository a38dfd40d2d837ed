"""`jmlgdsl learn`: fit a mode bank to experiments of every mode and write it as a .jmlg spec."""

from __future__ import annotations

import sys

from . import catch_all, names, positive, probability, whole


def register(subparsers):
    p = subparsers.add_parser(
        "learn", help="learn a mode bank from experiments of every mode and write a .jmlg spec",
        description="Fit one linear-Gaussian model per mode: an ARX least-squares fit (or an FOPDT fit of a step "
                    "test) gives the structure and the start for EM, which learns the coefficients and both noise "
                    "levels. Every mode is written over one shared state basis, the recent noise-free outputs and "
                    "inputs, so the bank stays right when the plant switches. Every mode is validated (residual "
                    "whiteness and input-residual correlation up to lag 25 with 99 % bands, free-run fit) and the "
                    "bank is written as a readable, commented spec that 'jmlgdsl run' accepts. A sensor that is "
                    "constant in a mode's data (stuck) or sensors that move together exactly (collinear) are modelled"
                    " with noise at the rounding of their resolution and reported, per mode and sensor, before any "
                    "fitting; a mode EM leaves unstable has its poles scaled inside the unit circle, and says so. "
                    "Without --template the first --mode is the healthy one: the prior is 'initial FIRST 0.99, "
                    "otherwise uniform' (--initial) and the transitions 'stay 0.99, otherwise uniform' (--stay). With"
                    " several modes, cross-validation on the recordings chooses whether the others are learned "
                    "relative to the first (few rows over many sensors: its least-squares regression, their changes "
                    "shrunk as far as tells them apart best) or each on its own by EM, and, without --template, the "
                    "noise scale of a catch-all mode 'anomaly' and an inflation of the first mode's noise, the pair "
                    "that stays quiet on held-out normal rows and alarms on the most fault rows: 'jmlgdsl run' then "
                    "raises the alarm from the first mode and 'anomaly' and names the fault with the others. Each "
                    "choice is printed as it is made.")
    p.add_argument("--mode", action="append", required=True, metavar="NAME=CSV",
                   help="a mode's experiment (repeat for every mode; repeat a name for several runs of one mode). A "
                        "file with a 'mode' column gives only the rows labelled NAME, each unbroken stretch of them a "
                        "run")
    p.add_argument("--template", metavar="SPEC",
                   help="spec giving names, units, sample time, mode descriptions, transitions and prior")
    structure = p.add_mutually_exclusive_group()
    structure.add_argument("--order", default="auto",
                           help="ARX order: N (na = nb = N), NA,NB,NK, or auto (default: by --criterion)")
    structure.add_argument("--fopdt", action="store_true",
                           help="the experiments are step tests: first order plus dead time")
    p.add_argument("--criterion", choices=("bic", "aic"), default="bic", help="order selection criterion")
    p.add_argument("--max-order", type=whole(1), default=4, help="largest na and nb tried by --order auto")
    p.add_argument("--max-delay", type=whole(0), default=0, help="largest input delay nk tried by --order auto")
    p.add_argument("--input", dest="inputs", type=names, default=(), metavar="NAMES",
                   help="input column names, comma separated (without --template)")
    p.add_argument("--output", dest="outputs", type=names, default=(), metavar="NAMES",
                   help="output column names, comma separated (without --template)")
    p.add_argument("--dt", type=positive, default=1.0, help="sample time in seconds (without --template)")
    p.add_argument("--name", default="plant", help="plant name (without --template)")
    p.add_argument("--stay", type=probability, default=0.99,
                   help="probability of staying in a mode, the rest uniform (without --template)")
    p.add_argument("--initial", type=probability, default=0.99, metavar="P",
                   help="prior probability of the first --mode, taken as the healthy one; the rest is shared "
                        "uniformly (without --template; default 0.99)")
    p.add_argument("--relative-to", metavar="MODE|auto|none", default="auto",
                   help="learn every other mode relative to this one (the normal one): its dynamics and noise shrunk "
                        "toward MODE's as far as cross-validation on the mode's own rows says, with its own offset "
                        "and noise scale; for short fault recordings over many sensors. auto (the default): relative "
                        "to the first --mode when cross-validation says that beats each mode's own regression; none: "
                        "every mode on its own")
    p.add_argument("--catch-all", metavar="NAME[=SCALE]|none", default="auto", type=catch_all,
                   help="add a mode NAME: the first mode with every noise sd times SCALE (as 'like FIRST { noise "
                        "scale SCALE }'); 'run' then raises the alarm from the first mode and NAME and names the "
                        "fault with the others. Without =SCALE, the scale and an inflation of the first mode's noise "
                        "that alarm on at most 0.5 %% of its rows held out by cross-validation and on the most rows of "
                        "the other modes' recordings (one mode: the smallest quiet scale). Default: 'anomaly' so "
                        "chosen with fault modes besides the first; none (the default for one mode or a --template)")
    p.add_argument("--max-iter", type=whole(0), default=100, help="EM iteration cap (default 100)")
    p.add_argument("--tol", type=float, default=1e-5, help="EM relative log-likelihood tolerance (default 1e-5)")
    p.add_argument("--figures", metavar="DIR", help="write validation (and step-fit) figures here")
    p.add_argument("-q", "--quiet", action="store_true", help="do not report each mode as it is learned")
    p.add_argument("-o", "--output-spec", dest="spec_out", default="-", metavar="FILE",
                   help="spec file to write (default: standard output)")
    p.set_defaults(func=main)


def main(args) -> int:
    """Run the command on parsed arguments; returns the exit status."""
    from .. import load
    from ..learn import learn, mode_files
    from ..output import check_file, check_folder

    paths = mode_files(args.mode)
    check_file(args.spec_out, inputs=[p for given in paths.values() for p in given] + [args.template])
    if args.figures:
        check_folder(args.figures, option="--figures")
    bank = learn(paths, load(args.template) if args.template else None, outputs=args.outputs,
                 inputs=args.inputs, dt=args.dt, name=args.name, stay=args.stay, initial=args.initial, order=args.order,
                 fopdt=args.fopdt, criterion=args.criterion, max_order=args.max_order, max_delay=args.max_delay,
                 max_iter=args.max_iter, tol=args.tol, catch_all=args.catch_all,
                 relative_to=None if args.relative_to == "none" else args.relative_to,
                 progress=None if args.quiet else (lambda text: print(text, file=sys.stderr, flush=True)))
    report = sys.stderr if args.spec_out == "-" else sys.stdout  # the spec alone on standard output
    bank.write(args.spec_out)
    print(("" if args.spec_out == "-" else f"wrote {args.spec_out}\n") + bank.report(), file=report)
    for path in bank.write_figures(args.figures) if args.figures else ():
        print(f"wrote {path}", file=report)
    return 0
