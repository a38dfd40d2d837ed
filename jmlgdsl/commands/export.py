"""`jmlgdsl export STORE`: the result table of a monitor's store, as `jmlgdsl run -o` writes it."""

from __future__ import annotations

from . import STORE_HELP, add_store_password_options, store_password


def register(subparsers):
    p = subparsers.add_parser(
        "export", help="write the result table of a monitor's store",
        description="Write the result table of a run in a store that 'jmlgdsl monitor' keeps: the same "
                    "table, byte for byte, that 'jmlgdsl run -o' writes for the same rows. --samples also "
                    "writes the rows themselves as a data file, so 'jmlgdsl run' can diagnose them again.")
    p.add_argument("store", help=STORE_HELP)
    p.add_argument("-o", "--output", default="-", help="the result table (default - : standard output)")
    p.add_argument("--samples", metavar="FILE.csv", help="also write the rows diagnosed, as a data file")
    which = p.add_mutually_exclusive_group()
    which.add_argument("--run", type=int, metavar="N", help="which run of the store (default the latest)")
    which.add_argument("--unit", metavar="NAME", help="a fleet's store: the latest run of this unit")
    add_store_password_options(p)
    p.set_defaults(func=main)


def main(args) -> int:
    import sys

    from ..data import open_target
    from ..errors import DataError
    from ..monitor.store import Store, damaged, write_samples, write_table
    from ..output import check_file

    check_file(args.output, inputs=[args.store])
    check_file(args.samples, inputs=[args.store, args.output], option="--samples")
    with Store(args.store, create=False, password=store_password(args)) as store:
        damage = store.damage()
        if damage:
            print(f"warning: {damaged(args.store, damage)}; the rows that can be read are exported", file=sys.stderr)
        run = store.run(args.run, unit=args.unit)
        if run is None:
            raise DataError(f"{args.store}: the store holds no run " + (f"of unit {args.unit}; its units: "
                            f"{', '.join(store.units()) or 'none'}" if args.unit else "yet"))
        if run.unit is not None and args.unit is None and args.run is None:
            raise DataError(f"{args.store}: a fleet's store; say which unit with --unit (one of "
                            f"{', '.join(store.units())})")
        for path, write in ((args.output, write_table), (args.samples, write_samples)):
            if path is None:
                continue
            with open_target(path) as out:  # whole, or not at all
                written = write(store, run, out)
                if not written.rows:
                    raise DataError(f"{args.store}: run {run.id} holds no diagnosed rows yet" if not written.damaged
                                    else f"{args.store}: no row of run {run.id} can be read: {written.left_out()}")
            if written.damaged:
                print(f"warning: {args.store}: run {run.id}: {written.left_out()} of {path}; {written.rows} rows "
                      "exported", file=sys.stderr)
    return 0
