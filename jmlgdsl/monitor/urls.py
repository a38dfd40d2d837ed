"""Where a bus source's URL points: host, port and path, with no credentials in it."""

from __future__ import annotations

from urllib.parse import urlsplit

from ..errors import JmlgError


def address(url: str, default_port: int):
    """(host, port, path) of a source URL; a URL with a user name or password in it is refused."""
    parts = urlsplit(url)
    if parts.username or parts.password:
        raise JmlgError("--source: put no user name or password in the URL (they would show in the process "
                        "list and the store); use --username with --password-env or --password-file")
    if not parts.hostname:
        raise JmlgError(f"--source {url}: no host")
    try:
        port = parts.port or default_port
    except ValueError:
        raise JmlgError(f"--source {url}: the port is not a number from 1 to 65535") from None
    return parts.hostname, port, parts.path.strip("/")
