"""Where a bus source's (or sink's) URL points: host, port and path, with no credentials in it."""

from __future__ import annotations

from urllib.parse import urlsplit

from ...errors import JmlgError


def address(url: str, default_port: int, option: str = "--source"):
    """(host, port, path) of the URL of a source (or of another `option`, e.g. --publish, whose
    credentials are given as {option}-username ...); a URL with a user name or password in it is refused."""
    parts = urlsplit(url)
    if parts.username or parts.password:
        given = "--" if option == "--source" else f"{option}-"
        raise JmlgError(f"{option}: put no user name or password in the URL (they would show in the process "
                        f"list and the store); use {given}username with {given}password-env or {given}password-file")
    if not parts.hostname:
        raise JmlgError(f"{option} {url}: no host")
    try:
        port = parts.port or default_port
    except ValueError:
        raise JmlgError(f"{option} {url}: the port is not a number from 1 to 65535") from None
    return parts.hostname, port, parts.path.strip("/")
