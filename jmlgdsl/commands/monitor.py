"""`jmlgdsl monitor SPEC --source URL --store PATH`: diagnose a running plant live into a store that
survives restarts and outages (docs/monitor.md)."""

from __future__ import annotations

import sys

from . import (STORE_HELP, add_alarm_options, add_filter_options, add_page_options, add_store_password_options,
               check_particles, diagnosis_options, start_page, store_password, whole)


def register(subparsers):
    p = subparsers.add_parser(
        "monitor", help="diagnose a running plant live, keeping every conclusion in a store",
        description="Diagnose a plant's data as they arrive, from a CSV file followed as it grows, standard "
                    "input (-), an MQTT broker (mqtt://HOST:PORT/PREFIX, mqtts://...), an OPC UA server "
                    "(opc.tcp://HOST:PORT/PATH) or Sparkplug B edge nodes (sparkplug://HOST:PORT/GROUP/...). "
                    "Readings of tags that arrive at their own moments are put on the spec's sample clock. Every row, its mode posterior, alarms and events go to the "
                    "store (SQLite, or PostgreSQL for many monitors), committed with the diagnosis's state, so "
                    "the monitor killed at any moment and started again with the same command resumes where it "
                    "was. It runs until stopped (SIGTERM, Ctrl-C), or to the end of standard input or of an "
                    "unfollowed file. The units of a fleet of one design are watched by one monitor (--units), "
                    "or by shards of it on a Ray cluster (--cluster). "
                    "'jmlgdsl export STORE' writes the result table.")
    p.add_argument("spec", help="plant spec (.jmlg) or compiled model (.json/.npz)")
    p.add_argument("--source", required=True, metavar="URL",
                   help="a CSV file (followed as it grows), - (standard input), mqtt://HOST:PORT/PREFIX, "
                        "mqtts://HOST:PORT/PREFIX, opc.tcp://HOST:PORT/PATH or "
                        "sparkplug://HOST:PORT/GROUP[/EDGE_NODE[/DEVICE]] (sparkplugs:// over TLS)")
    p.add_argument("--store", required=True, metavar="PATH|URL", help=STORE_HELP + "; made when absent")
    p.add_argument("--units", metavar="NAMES",
                   help="watch the units of a fleet with one spec: names and ranges such as pump01..pump200,spare; "
                        "{unit} in --source and in the tag file stands for each one's name (a CSV file per unit, "
                        "data/{unit}.csv; MQTT topics PREFIX/{unit}/NAME on one connection; OPC UA node ids). "
                        "Each unit has its own run in the store, named by its unit column (docs/fleet.md)")
    p.add_argument("--unit-specs", metavar="DIR",
                   help="with --units: diagnose each unit with its own spec DIR/UNIT.jmlg (the spec fitted to that "
                        "unit: jmlgdsl fit SPEC units/*.csv -o DIR/), SPEC for a unit without one; its run records "
                        "its spec, and the units still step together, each under its own numbers")
    p.add_argument("--cluster", metavar="auto|HOST:PORT",
                   help="with --units: spread the units over a Ray cluster, a shard of units per actor, each with "
                        "its own connection to the source and the store (auto: a Ray on this machine for this "
                        "command, reachable from 127.0.0.1 only; HOST:PORT: a cluster started with ray start "
                        "--head). A shard whose process dies is started again and resumes from its last commit. "
                        "Needs pip install 'jmlgdsl[cluster]'")
    p.add_argument("--shards", type=whole(1), metavar="N",
                   help="with --cluster: the number of shards (default one per CPU of the cluster, at most one per "
                        "unit; keep it the same across restarts, as each shard keeps its own MQTT session)")
    p.add_argument("--tags", metavar="FILE.toml", help="per spec name: topic or node id, unit scale and offset, "
                                                       "time stamps of the source or of arrival")
    p.add_argument("--new-run", action="store_true",
                   help="start a new run in a store that holds a run of another spec or other options")
    p.add_argument("--no-follow", action="store_true",
                   help="a CSV source is complete: diagnose it to its end, then stop")
    clock = p.add_argument_group("rows from readings")
    clock.add_argument("--grace", type=float, metavar="SECONDS",
                       help="a row waits this long (in the readings' time) for its missing readings (default "
                            "2 sample times)")
    clock.add_argument("--stale", type=float, metavar="SECONDS",
                       help="a tag without a reading for this long is stale (default 10 sample times)")
    clock.add_argument("--max-gap", type=float, default=3600.0, metavar="SECONDS",
                       help="a gap without any reading up to this long is diagnosed as rows of missing "
                            "readings; a longer one is skipped (default 3600)")
    bus = p.add_argument_group("connection")
    bus.add_argument("--client-id", help="MQTT client id of the persistent session; for Sparkplug B, the host "
                                          "application's id (default jmlgdsl-PLANT)")
    bus.add_argument("--username", help="user name at the broker or server")
    bus.add_argument("--password-env", metavar="VAR", help="the environment variable that holds the password")
    bus.add_argument("--password-file", metavar="FILE", help="the file that holds the password (its first line)")
    bus.add_argument("--ca-file", metavar="FILE", help="certificate authority for mqtts:// (default the system's)")
    bus.add_argument("--security", metavar="POLICY,MODE",
                     help="OPC UA security, e.g. Basic256Sha256,SignAndEncrypt (default None: no security)")
    bus.add_argument("--certificate", metavar="FILE", help="the client's OPC UA certificate (with --security)")
    bus.add_argument("--private-key", metavar="FILE", help="the client's OPC UA private key (with --security)")
    bus.add_argument("--reorder-timeout", type=float, metavar="SECONDS",
                     help="Sparkplug B: how long a gap in an edge node's seq numbers waits for its messages before "
                          "they are given up and the node is asked for a rebirth (default 2)")
    out = p.add_argument_group("conclusions to the plant's systems (docs/monitor.md, \"Integrations\")")
    out.add_argument("--publish", metavar="URL",
                     help="mqtt://HOST:PORT/PREFIX or mqtts://...: publish each row's state (retained) on PREFIX/state "
                          "and each alarm transition on PREFIX/alarm (PREFIX/UNIT/... for a fleet's units), as JSON "
                          "at QoS 1, once committed to the store")
    out.add_argument("--publish-username", metavar="NAME", help="user name at the --publish broker")
    out.add_argument("--publish-password-env", metavar="VAR", help="the environment variable that holds its password")
    out.add_argument("--publish-password-file", metavar="FILE", help="the file that holds its password (first line)")
    out.add_argument("--publish-ca-file", metavar="FILE",
                     help="certificate authority of an mqtts:// --publish broker (default the system's)")
    out.add_argument("--notify", metavar="URL",
                     help="http(s) webhook: POST each alarm transition (raised, cleared, acknowledged, shelved, "
                          "unshelved) as JSON, retried with back-off, never holding the diagnosis up")
    out.add_argument("--notify-token-env", metavar="VAR",
                     help="the environment variable that holds a token sent as 'Authorization: Bearer TOKEN'")
    out.add_argument("--notify-token-file", metavar="FILE", help="the file that holds that token (first line)")
    out.add_argument("--opcua-server", metavar="URL",
                     help="opc.tcp://HOST:PORT/PATH: serve each plant's (or unit's) most probable mode, every mode's "
                          "probability and the alarm as OPC UA nodes, and each alarm as an Alarms & Conditions "
                          "OffNormalAlarm whose Acknowledge and shelving methods act as the page's buttons do")
    out.add_argument("--opcua-server-username", metavar="NAME",
                     help="the user name the --opcua-server lets in (default: anonymous clients)")
    out.add_argument("--opcua-server-password-env", metavar="VAR",
                     help="the environment variable that holds that user's password")
    out.add_argument("--opcua-server-password-file", metavar="FILE",
                     help="the file that holds that user's password (first line)")
    out.add_argument("--opcua-server-security", metavar="POLICY,MODE",
                     help="the --opcua-server's only endpoint, e.g. Basic256Sha256,SignAndEncrypt (default None: no "
                          "security)")
    out.add_argument("--opcua-server-certificate", metavar="FILE", help="the --opcua-server's certificate")
    out.add_argument("--opcua-server-private-key", metavar="FILE", help="the --opcua-server's private key")
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

    from ..monitor import Monitor, MonitorOptions, Store, read_tags
    from ..monitor.fleet import unit_names
    from ..monitor.outbox import open_sinks
    from ..monitor.sources import credentials, open_bus, secret
    from ..errors import JmlgError
    from ..names import plural

    model = jmlgdsl.load(args.spec)
    check_particles(args, model)
    tags = read_tags(args.tags, model)
    units = None if args.units is None else unit_names(args.units)
    options = MonitorOptions(diagnosis_options(args), args.grace, args.stale, args.max_gap)
    if (args.cluster or args.shards) and units is None:
        raise JmlgError(f"{'--cluster' if args.cluster else '--shards'} spreads the units of a fleet: give --units")
    if args.shards is not None and args.cluster is None:
        raise JmlgError("--shards needs --cluster")
    banks = None
    if args.unit_specs is not None:
        if units is None:
            raise JmlgError("--unit-specs gives each unit of a fleet its own spec: give --units")
        from pathlib import Path

        from ..diagnosis.fleet import unit_banks

        models, missing = unit_banks(model, args.unit_specs, units)
        banks = [(bank, _text(args.spec if unit in missing else Path(args.unit_specs) / f"{unit}.jmlg"))
                 for unit, bank in zip(units, models)]
        print(f"monitor: unit specs for {len(units) - len(missing)} of {plural(len(units), 'unit')} from "
              f"{args.unit_specs}" + (f"; {', '.join(missing)} with {args.spec}" if missing else ""),
              file=sys.stderr, flush=True)
    recipe = dict(url=args.source, follow=not args.no_follow, client_id=args.client_id,
                  credentials=credentials(args.username, args.password_env, args.password_file),
                  ca_file=args.ca_file, security=args.security, certificate=args.certificate,
                  private_key=args.private_key, reorder=args.reorder_timeout)
    source = open_bus(model=model, tags=tags, units=units, **recipe)  # refuses a bad source before anything starts
    for sink, what, companions in (
            ("publish", "the --publish broker",
             ("publish_username", "publish_password_env", "publish_password_file", "publish_ca_file")),
            ("notify", "the --notify webhook", ("notify_token_env", "notify_token_file")),
            ("opcua_server", "the --opcua-server", ("opcua_server_username", "opcua_server_password_env",
                                                    "opcua_server_password_file", "opcua_server_security",
                                                    "opcua_server_certificate", "opcua_server_private_key"))):
        for option in companions:
            if getattr(args, option) is not None and getattr(args, sink) is None:
                raise JmlgError(f"--{option.replace('_', '-')} is for {what}: give --{sink.replace('_', '-')}")
    given = [option for option in ("publish", "notify", "opcua_server") if getattr(args, option)]
    if given and args.cluster:
        raise JmlgError(f"--{given[0].replace('_', '-')} is not yet taken with --cluster; run the fleet's monitor "
                        "without it")
    password = store_password(args)
    sinks = open_sinks(publish=args.publish, notify=args.notify, opcua_server=args.opcua_server,
                       client_id=args.client_id or f"jmlgdsl-{model.name}",
                       credentials=credentials(args.publish_username, args.publish_password_env,
                                               args.publish_password_file, "--publish-"),
                       ca_file=args.publish_ca_file,
                       token=secret("notify-token", args.notify_token_env, args.notify_token_file),
                       server=dict(store=args.store, password=password, units=units,
                                   credentials=credentials(args.opcua_server_username, args.opcua_server_password_env,
                                                           args.opcua_server_password_file, "--opcua-server-"),
                                   security=args.opcua_server_security, certificate=args.opcua_server_certificate,
                                   private_key=args.opcua_server_private_key))
    stop = stopped_by_signals()
    page = start_page(args, args.store, password=password, unit=units and units[0])
    try:
        if args.cluster:
            stopped, count = _sharded(args, model, password, options, tags, units, recipe, stop, banks)
        else:
            with Store(args.store, password=password) as store:
                monitor = Monitor(model, store, source, spec=_text(args.spec), options=options, tags=tags,
                                  units=units, new_run=args.new_run, banks=banks, sinks=sinks, log=_log)
                stopped = monitor.run(stop)
    finally:
        if page is not None:
            page.stop()
    events = ", ".join(f"{kind} {n}" for kind, n in sorted(stopped.events.items()))
    runs = sorted(stopped.runs)
    where = f"run {runs[0]}" if units is None else f"the runs of {plural(len(units), 'unit')} ({runs[0]}..{runs[-1]})"
    shards = f" by {plural(count, 'shard')}" if args.cluster else ""
    print(f"{model.name}: {stopped.rows} rows diagnosed in {where} of {args.store}{shards} "
          f"({stopped.stored} in all){'; events: ' + events if events else ''}", file=sys.stderr)
    return 0


def _log(text: str):
    """The monitor's log: a line on standard error."""
    print(f"monitor: {text}", file=sys.stderr, flush=True)


def _sharded(args, model, password, options, tags, units, recipe, stop, banks):
    """The fleet's units in shards on a Ray cluster: what they did (a Stopped) and how many shards."""
    from ..cluster import joined
    from ..monitor.shards import ray_told, run_shards
    from ..names import plural

    with joined(args.cluster, report=ray_told(_log)) as ray:
        stop = stopped_by_signals(stop)  # Ray puts its own handlers in when it starts
        count = min(len(units), args.shards or max(1, int(ray.cluster_resources().get("CPU", 1))))
        _log(f"{plural(len(units), 'unit')} in {plural(count, 'shard')} on the Ray cluster {args.cluster}")
        return run_shards(ray, model, args.store, password, spec=_text(args.spec), options=options, tags=tags,
                          units=units, count=count, source=recipe, new_run=args.new_run, stop=stop,
                          banks=banks), count


def stopped_by_signals(stop=None):
    """An event (`stop`, or a new one) that SIGTERM and Ctrl-C set."""
    import signal
    import threading

    stop = stop or threading.Event()
    for signum in (signal.SIGTERM, signal.SIGINT):
        signal.signal(signum, lambda *_: stop.set())
    return stop


def _text(path) -> str | None:
    """A spec file's text, to keep with the run (None for a binary compiled model)."""
    try:
        with open(path, encoding="utf-8") as stream:
            return stream.read()
    except UnicodeDecodeError:
        return None
