"""The sources of a live monitor, one module per protocol, each behind the one contract of
`contract` (the items a source hands over, and what the monitor asks of it), found by the scheme
of the --source URL:

    path/to/data.csv, -              files: a CSV file followed as it grows, or standard input
    mqtt://HOST:PORT/PREFIX          mqtt: an MQTT broker's topics; mqtts:// over TLS
    opc.tcp://HOST:PORT/PATH         opcua: an OPC UA server's nodes
    sparkplug://HOST:PORT/GROUP/...  sparkplug: Sparkplug B edge nodes; sparkplugs:// over TLS
    udp://HOST:PORT                  udp: datagrams sent to HOST:PORT

and, for the units of a fleet, the same with {unit} in them (jmlgdsl.monitor.units). A new source
is a module with `open_source(connection, model, tags, units)` and its line in SCHEMES.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from urllib.parse import urlsplit

from ...errors import JmlgError
from .bus import credentials


@dataclass(frozen=True)
class Connection:
    """How to reach a source: its URL (or file, or -) and the connection's options, None where not
    given; `shard`: the index of a fleet's shard that opens it (each shard's session its own)."""

    url: str
    follow: bool = True  # a CSV file: followed as it grows
    client_id: str | None = None
    credentials: tuple[str, str] | None = None  # (user name, password): jmlgdsl.monitor.sources.bus.credentials
    ca_file: str | None = None
    security: str | None = None  # OPC UA's POLICY,MODE, with the client's certificate and private key
    certificate: str | None = None
    private_key: str | None = None
    reorder: float | None = None  # Sparkplug B: seconds a gap in a node's seq numbers waits
    shard: int | None = None


# the connection's options on the command line (flag -> argparse's keywords)
COMMAND_LINE = {
    "--client-id": dict(help="MQTT client id of the persistent session; for Sparkplug B, the host application's id "
                        "(default jmlgdsl-PLANT)"),
    "--username": dict(help="user name at the broker or server"),
    "--password-env": dict(metavar="VAR", help="the environment variable that holds the password"),
    "--password-file": dict(metavar="FILE", help="the file that holds the password (its first line)"),
    "--ca-file": dict(metavar="FILE", help="certificate authority for mqtts:// (default the system's)"),
    "--security": dict(metavar="POLICY,MODE", help="OPC UA security, e.g. Basic256Sha256,SignAndEncrypt (default "
                       "None: no security)"),
    "--certificate": dict(metavar="FILE", help="the client's OPC UA certificate (with --security)"),
    "--private-key": dict(metavar="FILE", help="the client's OPC UA private key (with --security)"),
    "--reorder-timeout": dict(type=float, metavar="SECONDS", help="Sparkplug B: how long a gap in an edge node's seq "
                              "numbers waits for its messages before they are given up and the node is asked for a "
                              "rebirth (default 2)"),
}
# the options a kind of source may refuse -> their field of Connection
OPTIONS = {"--username": "credentials", "--client-id": "client_id", "--ca-file": "ca_file", "--security": "security",
           "--certificate": "certificate", "--private-key": "private_key", "--reorder-timeout": "reorder"}


@dataclass(frozen=True)
class Scheme:
    """A kind of source: the module of this package that opens it, what it is called in messages, the
    connection options (OPTIONS' keys) it takes, and what it needs beyond jmlgdsl's own dependencies:
    (the module it imports, the package that has it, jmlgdsl's extra that installs it)."""

    module: str
    kind: str
    takes: tuple = ()
    needs: tuple | None = None


MQTT = ("--username", "--client-id", "--ca-file")
OPCUA = ("--username", "--security", "--certificate", "--private-key")
SPARKPLUG = ("--username", "--client-id", "--ca-file", "--reorder-timeout")
SCHEMES = {  # a URL's scheme ("" for a file or -) -> its kind of source
    "": Scheme("files", "a CSV source"),
    "mqtt": Scheme("mqtt", "an MQTT source", MQTT), "mqtts": Scheme("mqtt", "an MQTT source", MQTT),
    "opc.tcp": Scheme("opcua", "an OPC UA source", OPCUA),
    "sparkplug": Scheme("sparkplug", "a Sparkplug B source", SPARKPLUG, ("google", "protobuf", "sparkplug")),
    "sparkplugs": Scheme("sparkplug", "a Sparkplug B source", SPARKPLUG, ("google", "protobuf", "sparkplug")),
    "udp": Scheme("udp", "a UDP source"),
}


def connection(given: dict) -> Connection:
    """The Connection the command line gives: `given` holds its options' values by their names, as
    argparse stores them (source, no_follow, client_id, ...); the password is read here."""
    return Connection(given["source"], follow=not given["no_follow"], client_id=given["client_id"],
                      credentials=credentials(given["username"], given["password_env"], given["password_file"]),
                      ca_file=given["ca_file"], security=given["security"], certificate=given["certificate"],
                      private_key=given["private_key"], reorder=given["reorder_timeout"])


def open_source(connection: Connection, model, tags, units=None):
    """The source (not yet started) a connection names, of the named `units` of a fleet when given;
    an option its kind does not take is refused, as is a URL of no known scheme."""
    url = connection.url
    scheme = SCHEMES.get(urlsplit(url).scheme if "://" in url else "")
    if scheme is None:
        known = ["a CSV file", "-"] + [f"{name}://" for name in SCHEMES if name]
        raise JmlgError(f"--source {url}: unknown scheme {urlsplit(url).scheme!r}; use {', '.join(known[:-1])} or "
                        f"{known[-1]}")
    try:
        module = importlib.import_module(f"{__name__}.{scheme.module}")
    except ModuleNotFoundError as exc:
        if scheme.needs is None or not (exc.name or "").startswith(scheme.needs[0]):
            raise
        raise JmlgError(f"--source {url}: {scheme.kind} needs the {scheme.needs[1]} package: pip install "
                        f"'jmlgdsl[{scheme.needs[2]}]'") from None
    for option, field in OPTIONS.items():
        if option not in scheme.takes and getattr(connection, field) not in (None, ""):
            raise JmlgError(f"--source {url}: {scheme.kind} takes no {option}")
    return module.open_source(connection, model, tags, units)
