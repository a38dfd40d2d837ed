"""The options of a store and its operator's page (`monitor`, `dashboard`, `export`): where the store
is, its password and the page's address and token (secrets never on the command line)."""

from __future__ import annotations

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
