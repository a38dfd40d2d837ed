"""`jmlgdsl prbs`: write a pseudo-random binary input sequence for an identification experiment."""

from __future__ import annotations

from . import finite, positive


def register(subparsers):
    p = subparsers.add_parser(
        "prbs", help="write a pseudo-random binary input sequence (PRBS) for an experiment",
        description="Write a maximal-length pseudo-random binary sequence as CSV (time and one input "
                    "column): a shift register of --cells cells (period 2^cells - 1 bits), each bit "
                    "held for --clock samples and mapped to AROUND +- AMPLITUDE. Whole periods by "
                    "default. Warns when no pulse lasts the --settling time, since the data would "
                    "then never show the steady-state gain.")
    p.add_argument("--cells", type=int, default=9, help="shift-register length, 2..20 (default 9: 511 bits)")
    p.add_argument("--clock", type=int, default=1, help="samples per bit (default 1)")
    p.add_argument("--amplitude", type=finite, default=1.0, help="half the distance between the two levels")
    p.add_argument("--around", type=finite, default=0.0, help="operating value the levels surround")
    p.add_argument("--periods", type=int, default=1, help="whole periods to write (default 1)")
    p.add_argument("--samples", type=int, help="exact number of samples instead of whole periods")
    p.add_argument("--dt", type=positive, default=1.0, help="sample time in seconds (default 1)")
    p.add_argument("--settling", type=positive, help="plant settling time in seconds, to check the longest pulse")
    p.add_argument("--name", default="u", help="input column name (default u)")
    p.add_argument("-o", "--output", default="-", help="output CSV (default: standard output)")
    p.set_defaults(func=main)


def main(args) -> int:
    """Run the command on parsed arguments; returns the exit status."""
    import numpy as np

    from ..data import write_columns
    from ..learn.prbs import prbs, warn_if_short
    from ..output import check_count, check_file

    check_file(args.output)
    if 2 <= args.cells <= 20:
        check_count("--samples" if args.samples else "--periods",
                    args.samples or args.periods * (2 ** args.cells - 1) * args.clock, 48)
    u = prbs(args.cells, args.clock, args.amplitude, args.around, args.periods, args.samples)
    if args.settling is not None:
        warn_if_short(args.cells, args.clock, args.dt, args.settling)
    write_columns(args.output, {"time": np.arange(1, len(u) + 1) * args.dt, args.name: u})
    return 0
