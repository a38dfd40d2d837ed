"""`jmlgdsl monitor SPEC --source URL --store PATH`: diagnose a running plant live into a store that
survives restarts and outages (docs/monitor.md)."""

from __future__ import annotations

import sys

from . import (STORE_HELP, add_alarm_options, add_filter_options, add_page_options, add_store_password_options,
               check_particles, diagnosis_options, start_page, store_password, whole)


def register(subparsers):
    from ..monitor import rows, sinks, sources, units

    p = subparsers.add_parser(
        "monitor", help="diagnose a running plant live, keeping every conclusion in a store",
        description="Diagnose a plant's data as they arrive, from a CSV file followed as it grows, standard "
                    "input (-), an MQTT broker (mqtt://HOST:PORT/PREFIX, mqtts://...), an OPC UA server "
                    "(opc.tcp://HOST:PORT/PATH), Sparkplug B edge nodes (sparkplug://HOST:PORT/GROUP/...) or UDP "
                    "datagrams (udp://HOST:PORT). Readings of tags that arrive at their own moments are put on the "
                    "spec's sample clock. Every row, its mode posterior, alarms and events go to the store (SQLite, "
                    "or PostgreSQL for many monitors), committed with the diagnosis's state, so the monitor killed "
                    "at any moment and started again with the same command resumes where it was. It runs until "
                    "stopped (SIGTERM, Ctrl-C), or to the end of standard input or of an unfollowed file. The units "
                    "of a fleet of one design are watched by one monitor (--units), or by shards of it on a Ray "
                    "cluster (--cluster). 'jmlgdsl export STORE' writes the result table.")
    p.add_argument("spec", help="plant spec (.jmlg) or compiled model (.json/.npz)")
    p.add_argument("--source", required=True, metavar="URL",
                   help="a CSV file (followed as it grows), - (standard input), mqtt://HOST:PORT/PREFIX, "
                        "mqtts://HOST:PORT/PREFIX, opc.tcp://HOST:PORT/PATH, "
                        "sparkplug://HOST:PORT/GROUP[/EDGE_NODE[/DEVICE]] (sparkplugs:// over TLS) or udp://HOST:PORT")
    p.add_argument("--store", required=True, metavar="PATH|URL", help=STORE_HELP + "; made when absent")
    for flag, keywords in units.COMMAND_LINE.items():
        p.add_argument(flag, **keywords)
    p.add_argument("--shards", type=whole(1), metavar="N",
                   help="with --cluster: the number of shards (default one per CPU of the cluster, at most one per "
                        "unit; keep it the same across restarts, as each shard keeps its own MQTT session)")
    p.add_argument("--tags", metavar="FILE.toml", help="per spec name: topic or node id, unit scale and offset, "
                                                       "time stamps of the source or of arrival")
    p.add_argument("--new-run", action="store_true",
                   help="start a new run in a store that holds a run of another spec or other options")
    p.add_argument("--no-follow", action="store_true",
                   help="a CSV source is complete: diagnose it to its end, then stop")
    integrations = "conclusions to the plant's systems (docs/monitor.md, \"Integrations\")"
    for title, options in [("rows from readings", rows.COMMAND_LINE), ("connection", sources.COMMAND_LINE),
                           (integrations, sinks.COMMAND_LINE)]:
        group = p.add_argument_group(title)
        for flag, keywords in options.items():
            group.add_argument(flag, **keywords)
    add_filter_options(p)
    add_alarm_options(p)
    p.add_argument("--lag", type=int, default=0, metavar="L",
                   help="fixed-lag smoothing: store each row once L more rows have arrived, with "
                        "p(mode | data up to L rows later)")
    p.add_argument("--prefilter", metavar="ma:K", help="causal moving average over the last K readings")
    add_store_password_options(p)
    add_page_options(p, default=None)
    p.set_defaults(func=main)


def main(args) -> int:
    import jmlgdsl

    from ..monitor import MonitorOptions, launch, read_tags, sinks, sources
    from ..monitor.units import unit_names

    model = jmlgdsl.load(args.spec)
    check_particles(args, model)
    tags = read_tags(args.tags, model)
    units = None if args.units is None else unit_names(args.units)
    options = MonitorOptions(diagnosis_options(args), args.grace, args.stale, args.max_gap, args.catch_up)
    launch.check_fleet(units, cluster=args.cluster, shards=args.shards, unit_specs=args.unit_specs)
    banks = launch.unit_spec_banks(model, args.spec, args.unit_specs, units, log)
    recipe = sources.connection(vars(args))
    source = sources.open_source(recipe, model, tags, units)  # refuses a bad source before anything starts
    password = store_password(args)
    outlets = sinks.open_sinks(vars(args), client_id=args.client_id or f"jmlgdsl-{model.name}", store=args.store,
                               password=password, units=units, cluster=args.cluster)
    stop = launch.stopped_by_signals()
    page = start_page(args, args.store, password=password, unit=units and units[0])
    try:
        stopped, count = launch.watch(model, args.spec, args.store, password, source, recipe, options=options,
                                      tags=tags, units=units, banks=banks, sinks=outlets, new_run=args.new_run,
                                      cluster=args.cluster, shards=args.shards, stop=stop, log=log)
    finally:
        if page is not None:
            page.stop()
    print(launch.summary(model, stopped, args.store, units, args.cluster, count), file=sys.stderr)
    return 0


def log(text: str):
    """The monitor's log: a line on standard error."""
    print(f"monitor: {text}", file=sys.stderr, flush=True)
