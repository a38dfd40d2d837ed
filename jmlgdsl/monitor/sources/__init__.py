"""Which source a --source URL names, and the password a source uses (never from the command line).

    path/to/data.csv, -              CsvSource (jmlgdsl.monitor.sources.files)
    mqtt://HOST:PORT/PREFIX          MqttSource (jmlgdsl.monitor.sources.mqtt); mqtts:// over TLS
    opc.tcp://HOST:PORT/PATH         OpcuaSource (jmlgdsl.monitor.sources.opcua)
    sparkplug://HOST:PORT/GROUP/...  SparkplugSource (jmlgdsl.monitor.sources.sparkplug); sparkplugs:// over TLS

and, for the units of a fleet, the same with {unit} in them (jmlgdsl.monitor.fleet).
"""

from __future__ import annotations

import os
from urllib.parse import urlsplit

from ...errors import JmlgError
from ..fleet import PLACEHOLDER, FleetError, UnitSources, for_unit, unit_tags
from .files import CsvSource


def credentials(username: str | None, env: str | None, path: str | None,
                options: str = "--") -> tuple[str, str] | None:
    """(user name, password) from --username and the password's environment variable or file (or the
    options that begin with `options` instead, e.g. --publish-username); None without a user name.
    The password is read here and never shown."""
    password = secret(f"{options[2:]}password", env, path)
    if username is None:
        if password is not None:
            raise JmlgError(f"{options}password-{'env' if env else 'file'}: a password needs {options}username")
        return None
    return username, password or ""


def secret(what: str, env: str | None, path: str | None) -> str | None:
    """A secret from the environment variable --WHAT-env names or the first line of the file --WHAT-file
    names (never from the command line, where the process list shows it); None without either."""
    if env and path:
        raise JmlgError(f"--{what}-env and --{what}-file: give one of them")
    if env:
        if env not in os.environ:
            raise JmlgError(f"--{what}-env: the environment variable {env} is not set")
        return os.environ[env]
    if path:
        try:
            with open(path, encoding="utf-8") as stream:
                return stream.readline().rstrip("\r\n")
        except OSError as exc:
            raise JmlgError(f"--{what}-file: cannot read {path}: {exc.strerror}") from None
        except UnicodeDecodeError:
            raise JmlgError(f"--{what}-file: {path} is not UTF-8 text") from None
    return None


def open_bus(url: str, model, tags, *, follow: bool = True, client_id: str | None = None, credentials=None,
             ca_file: str | None = None, security: str | None = None, certificate: str | None = None,
             private_key: str | None = None, reorder: float | None = None, units=None):
    """The source a --source URL names (not yet started), of the named `units` of a fleet when given;
    an option its kind does not take is refused."""
    scheme = urlsplit(url).scheme if "://" in url else ""
    given = {"--username": credentials is not None, "--client-id": client_id, "--ca-file": ca_file,
             "--security": security, "--certificate": certificate, "--private-key": private_key,
             "--reorder-timeout": reorder is not None}
    if scheme in ("mqtt", "mqtts"):
        from .mqtt import MqttSource

        _refuse(url, "an MQTT source", given, "--security", "--certificate", "--private-key", "--reorder-timeout")
        return MqttSource(url, model, tags, client_id=client_id or f"jmlgdsl-{model.name}",
                          credentials=credentials, ca_file=ca_file, units=units)
    if scheme == "opc.tcp":
        from .opcua import OpcuaSource

        _refuse(url, "an OPC UA source", given, "--client-id", "--ca-file", "--reorder-timeout")
        if units is not None:
            plain = sorted(name for name, tag in tags.items() if PLACEHOLDER not in (tag.node or ""))
            if plain:
                raise FleetError(f"--units with an OPC UA source: the tag file's node id of {plain[0]} holds no "
                                 f"{PLACEHOLDER}, so every unit would read the same node")
            return UnitSources([OpcuaSource(url, model, unit_tags(tags, unit), credentials=credentials,
                                            security=security, certificate=certificate, private_key=private_key)
                                for unit in units], url)
        return OpcuaSource(url, model, tags, credentials=credentials, security=security, certificate=certificate,
                           private_key=private_key)
    if scheme in ("sparkplug", "sparkplugs"):
        try:
            from .sparkplug import REORDER, SparkplugSource
        except ModuleNotFoundError as exc:
            if not (exc.name or "").startswith("google"):
                raise
            raise JmlgError(f"--source {url}: a Sparkplug B source needs the protobuf package: pip install "
                            "'jmlgdsl[sparkplug]'") from None
        _refuse(url, "a Sparkplug B source", given, "--security", "--certificate", "--private-key")
        if units is not None:
            raise FleetError("--units with a Sparkplug B source: not supported; run a monitor for each edge node "
                             "or device (--source sparkplug://HOST:PORT/GROUP/EDGE_NODE/DEVICE)")
        return SparkplugSource(url, model, tags, host_id=client_id or f"jmlgdsl-{model.name}",
                               credentials=credentials, ca_file=ca_file,
                               reorder=REORDER if reorder is None else reorder)
    if scheme:
        raise JmlgError(f"--source {url}: unknown scheme {scheme!r}; use a CSV file, -, mqtt://, mqtts://, "
                        "opc.tcp://, sparkplug:// or sparkplugs://")
    _refuse(url, "a CSV source", given, *given)
    if units is not None:
        if PLACEHOLDER not in url:
            raise FleetError(f"--units with a CSV source: give the files as a template with {PLACEHOLDER} in it, "
                             f"e.g. data/{PLACEHOLDER}.csv, not {url}")
        return UnitSources([CsvSource(for_unit(url, unit), model, follow) for unit in units], url)
    return CsvSource(url, model, follow)


def _refuse(url, kind, given, *options):
    """An error naming the first of `options` given for a source that does not take it."""
    for option in options:
        if given[option]:
            raise JmlgError(f"--source {url}: {kind} takes no {option}")
