"""The subcommands of `jmlgdsl`, one module each (see jmlgdsl/cli.py), and what they share: argument
types (a value out of range is refused by argparse, naming the option, before any work starts) and
the options of a diagnosis (`run` and `monitor`)."""

from __future__ import annotations

import argparse
import math


def whole(least: int):
    """An argparse type: a whole number >= least."""
    def parse(text):
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a whole number, not {text!r}") from None
        if value < least:
            raise argparse.ArgumentTypeError(f"must be at least {least}, not {value}")
        return value
    parse.__name__ = f"whole number >= {least}"
    return parse


def finite(text) -> float:
    """An argparse type: a finite number."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, not {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, not {text!r}")
    return value


def positive(text) -> float:
    """An argparse type: a finite number > 0."""
    value = finite(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be positive, not {text}")
    return value


def probability(text) -> float:
    """An argparse type: a number in [0, 1]."""
    value = finite(text)
    if not 0 <= value <= 1:
        raise argparse.ArgumentTypeError(f"must be a probability (0 to 1), not {text}")
    return value


def add_filter_options(p):
    """The filter's options: --filter, --particles, --seed, --resampling, --ess-threshold."""
    from ..infer import ALGORITHMS, DEFAULT_ALGORITHM
    from ..infer.resample import SCHEMES

    p.add_argument("--filter", default=DEFAULT_ALGORITHM, choices=list(ALGORITHMS),
                   help=f"filtering algorithm (default {DEFAULT_ALGORITHM})")
    p.add_argument("--particles", type=int, help="number of particles (default depends on the filter)")
    p.add_argument("--seed", type=int, help="random seed (the same seed gives the same output)")
    p.add_argument("--resampling", default="systematic", choices=list(SCHEMES), help="resampling scheme")
    p.add_argument("--ess-threshold", type=float, default=1.0,
                   help="resample when ESS < this fraction of the particles (1 = every step)")


def add_alarm_options(p):
    """The alarm rule's options: --healthy, --threshold, --persistence."""
    alarm = p.add_argument_group("alarm rule")
    alarm.add_argument("--healthy", metavar="MODE[,MODE...]",
                       help="the modes that raise no alarm (default: the first mode of the spec)")
    alarm.add_argument("--threshold", type=float, default=0.5,
                       help="alarm when P(not healthy) is above this (default 0.5)")
    alarm.add_argument("--persistence", type=int, default=1, metavar="K",
                       help="... at K consecutive steps; the alarm starts on the K-th (default 1)")


def check_particles(args, model):
    """Refuse --particles for a filter without particles, or a count beyond this machine's memory."""
    from ..errors import JmlgError
    from ..infer import ALGORITHMS, particle_bytes
    from ..output import check_count

    if args.particles is None:
        return
    if not ALGORITHMS[args.filter].uses_particles:
        raise JmlgError(f"--particles: the {args.filter} filter uses no particles (the particle filters "
                        f"are {', '.join(n for n, a in ALGORITHMS.items() if a.uses_particles)})")
    check_count("--particles", args.particles, particle_bytes(model))


def healthy_modes(args) -> list[str] | None:
    """The modes --healthy names (None: the spec's first mode)."""
    return [m.strip() for m in args.healthy.split(",")] if args.healthy else None


def diagnosis_options(args):
    """The diagnosis's Options from the flags of `run` or `monitor` (the monitor has no --smooth or
    --explain: it always explains)."""
    from ..diagnosis import Options
    from ..diagnosis.prefilter import parse

    healthy = healthy_modes(args)
    return Options(args.filter, args.particles, args.seed, args.resampling, args.ess_threshold,
                   None if getattr(args, "smooth", False) else args.lag or 0, parse(args.prefilter),
                   None if healthy is None else tuple(healthy), args.threshold, args.persistence,
                   getattr(args, "explain", False))


STORE_HELP = "the store: an SQLite database's path, or postgresql://USER@HOST:PORT/DBNAME (no password in it)"


def add_store_password_options(p):
    """A PostgreSQL store's password: --store-password-env VAR or --store-password-file FILE (never on
    the command line; without either, libpq's PGPASSFILE or ~/.pgpass)."""
    store = p.add_argument_group("a PostgreSQL store's password (default: PGPASSFILE or ~/.pgpass)")
    store.add_argument("--store-password-env", metavar="VAR", help="the environment variable that holds it")
    store.add_argument("--store-password-file", metavar="FILE", help="the file that holds it (its first line)")


def store_password(args) -> str | None:
    """The password --store-password-env or --store-password-file gives (None without either)."""
    from ..monitor.sources.bus import secret

    return secret("store-password", args.store_password_env, args.store_password_file)


def add_page_options(p, default: str | None):
    """The operator's page: --http HOST:PORT and its token (never on the command line)."""
    page = p.add_argument_group("the operator's page")
    page.add_argument("--http", metavar="HOST:PORT", default=default,
                      help="serve the page there (127.0.0.1 keeps it to this machine; any other address needs a "
                           "token)" + (f" (default {default})" if default else ""))
    page.add_argument("--http-token-env", metavar="VAR",
                      help="the environment variable holding the page's token: with a token, acknowledging and "
                           "shelving alarms needs it")
    page.add_argument("--http-token-file", metavar="FILE", help="the file holding the page's token (its first line)")


def start_page(args, store_path, run: int | None = None, password: str | None = None, unit: str | None = None):
    """The page --http asks for, serving (None without --http), reading the store with its password;
    says where on standard error."""
    import sys

    from ..monitor.sources.bus import secret
    from ..page import Page, parse_address

    if args.http is None:
        return None
    host, port = parse_address(args.http)
    page = Page(store_path, host, port, token=secret("http-token", args.http_token_env, args.http_token_file),
                run=run, unit=unit, store_password=password).start()
    print(f"the operator's page: {page.url}", file=sys.stderr, flush=True)
    return page

