"""`jmlgdsl dashboard STORE`: the operator's page of a monitor's store, finished or still running."""

from __future__ import annotations

import sys

from . import STORE_HELP, add_page_options, add_store_password_options, start_page, store_password


def register(subparsers):
    p = subparsers.add_parser(
        "dashboard", help="serve the operator's page of a monitor's store",
        description="Serve the operator's page of a run in a store that 'jmlgdsl monitor' keeps (the latest "
                    "run unless --run is given), whether the monitor is still running or has finished: the "
                    "most probable mode, every mode's probability over time, each sensor against what the "
                    "model expected, and the alarms to acknowledge or shelve with the evidence behind them. "
                    "Runs until stopped (Ctrl-C, SIGTERM). 'jmlgdsl monitor --http' serves the same page "
                    "from the monitor itself.")
    p.add_argument("store", help=STORE_HELP)
    which = p.add_mutually_exclusive_group()
    which.add_argument("--run", type=int, metavar="N", help="which run of the store (default the latest)")
    which.add_argument("--unit", metavar="NAME", help="a fleet's store: open on the latest run of this unit "
                                                      "(without it, a fleet's page opens on every unit, worst "
                                                      "first)")
    add_store_password_options(p)
    add_page_options(p, default="127.0.0.1:8050")
    p.set_defaults(func=main)


def main(args) -> int:
    import signal
    import threading

    from ..monitor import Store, StoreError
    from ..monitor.store import damaged

    password = store_password(args)
    with Store(args.store, create=False, password=password) as store:
        damage = store.damage()
        if damage:
            print(f"warning: {damaged(args.store, damage)}; the page shows the rows that can be read",
                  file=sys.stderr)
        if store.run(args.run, unit=args.unit) is None:
            raise StoreError(f"{args.store}: the store holds no run " + (f"of unit {args.unit}; its units: "
                             f"{', '.join(store.units()) or 'none'}" if args.unit else "yet"))
    stop = threading.Event()
    for signum in (signal.SIGTERM, signal.SIGINT):
        signal.signal(signum, lambda *_: stop.set())
    page = start_page(args, args.store, args.run, password, args.unit)
    stop.wait()
    page.stop()
    print("the page is stopped", file=sys.stderr)
    return 0
