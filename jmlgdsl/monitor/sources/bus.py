"""What the data-bus sources (MQTT, OPC UA) and the sinks of the conclusions share: the events of
their connection, the growing delay between attempts to connect, the credentials they log in with
and the message of a refused password, and the draining of what their threads hand over.
"""

from __future__ import annotations

import os
import queue
import ssl

from ...errors import JmlgError
from .contract import Event

FIRST_RETRY, LAST_RETRY = 1.0, 30.0  # seconds between connection attempts: doubling from the first to the last


def delays():
    """The delays between attempts to connect: 1, 2, 4, ... seconds, then 30 s for ever."""
    delay = FIRST_RETRY
    while True:
        yield delay
        delay = min(2 * delay, LAST_RETRY)


def drained(waiting: queue.Queue | queue.SimpleQueue) -> list:
    """Everything a queue holds now, oldest first, without waiting for more (what a connection's
    thread or a sink's worker put there for the monitor's thread)."""
    items = []
    while True:
        try:
            items.append(waiting.get_nowait())
        except queue.Empty:
            return items


def connected(where: str, detail: str) -> Event:
    return Event("connect", None, f"connected to {where} ({detail})")


def unreachable(where: str, why, delay: float) -> Event:
    """A connection attempt that failed; the next one is `delay` seconds later."""
    return Event("disconnect", None, f"cannot reach {where} ({why}); trying again in {delay:g} s")


def lost(where: str, why, delay: float) -> Event:
    """A connection that was up and is lost; the first attempt to connect again is `delay` seconds later."""
    again = "reconnecting now" if delay == 0 else f"reconnecting in {delay:g} s"
    return Event("disconnect", None, f"lost the connection to {where} ({why}); {again}")


def refused(source: str, who: str, why, options: str = "--") -> str:
    """The message of a source (or of a sink whose options begin with `options`, e.g. --publish-) whose
    user name, password or certificate was refused."""
    return (f"{source}: the {who} refused the connection ({why}); check {options}username and the password "
            f"({options}password-env, {options}password-file)")


def untrusted(where: str, port: int, error, option: str = "--ca-file") -> str | None:
    """The message of a TLS connection to `where` that failed, which trying again cannot mend (a
    certificate the certificate authority of `option`, or the system's, does not trust; a port that
    speaks no TLS); None for another failure."""
    if isinstance(error, ssl.SSLCertVerificationError):
        return (f"{where}: the broker's certificate is not trusted ({error.verify_message}); give the certificate "
                f"authority that signed it with {option}")
    if isinstance(error, ssl.SSLError):
        return f"{where}: no TLS connection ({error.reason or error}): is {port} the broker's TLS port?"
    return None


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
