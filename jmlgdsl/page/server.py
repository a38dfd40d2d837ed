"""The operator's page over HTTP: the page itself (its HTML, script and style ship in jmlgdsl/page/
static), a small JSON API on the store, and a server-sent event stream that pushes each row within
a quarter of a second of its commit.

    GET  /                         the page
    GET  /api/run                  names, units, descriptions, the alarm rule, whether actions need a token
    GET  /api/rows?after=T | ?first=A&last=B&limit=N | (nothing: the live end)
    GET  /api/alarms               the alarms with their ISA-18.2 states
    GET  /api/evidence?alarm=ID    each sensor's share of the evidence behind an alarm
    GET  /api/fleet                a fleet's units worst first: each one's mode now and open alarms
    GET  /api/stream?after=T       server-sent events: `rows` (as /api/rows) and `alarms` (when they change)
    POST /api/alarms/ID/acknowledge | /shelve | /unshelve   JSON {"who": ..., "reason": ...}

The server binds to 127.0.0.1 unless told otherwise, and any other address needs a token (from an
environment variable or a file). With a token, actions need it (`Authorization: Bearer TOKEN`);
reading the page does not. An action must come as JSON from the page's own origin, which a form or
script on another site cannot send without the browser asking first (and the server never agrees),
so a page elsewhere cannot act for an operator whose browser has the page open. A page on the
loopback answers only to its own address (`Host` 127.0.0.1, [::1] or localhost, at its port): a
name of another site that a DNS server points at 127.0.0.1 (DNS rebinding) gets 421, so a page the
operator visits cannot read or act through such a name.

Every request is checked before it is used: the numbers of a query (whole numbers of at most 19
digits), the body of an action (a JSON object of at most 64 KiB with only `who` and `reason`, each a
string or null, no NaN), and what is refused is a 400 with its reason, never a closed connection.
"""

from __future__ import annotations

import contextlib
import functools
import hmac
import ipaddress
import json
import re
import threading
import time
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from urllib.parse import parse_qs, urlsplit

from ..errors import JmlgError
from ..monitor.store import Store, StoreError
from . import views

POLL = 0.25  # seconds between the event stream's looks at the store
HEARTBEAT = 10.0  # seconds between keep-alive comments on a quiet event stream
STREAM_ROWS = 500  # rows one event carries at most (a page that joins a long run catches up in steps)
JSON = "application/json"  # what the API answers with, and what an action comes as
HEADERS = {"Content-Security-Policy": "default-src 'self'; img-src 'self' data:; frame-ancestors 'none'",
           "X-Content-Type-Options": "nosniff", "Referrer-Policy": "no-referrer", "Cache-Control": "no-store"}
ACTION = re.compile(r"/api/alarms/([0-9]{1,19})/(acknowledge|shelve|unshelve)", re.ASCII)
HOST = re.compile(r"[A-Za-z0-9.\-]+(:[0-9]{1,5})?|\[[0-9A-Fa-f:.]+\](:[0-9]{1,5})?", re.ASCII)  # a name or IP, a port
WHOLE = re.compile(r"-?[0-9]{1,19}", re.ASCII)  # a query's number (an SQLite or PostgreSQL BIGINT holds 19 digits)
MAX_BODY = 65536  # bytes of an action's body
BODY_FIELDS = ("who", "reason")  # what an action's body may hold


class PageError(JmlgError):
    """A page that cannot be served: an address it may not bind to, a port in use."""


def parse_address(text: str) -> tuple[str, int]:
    """(host, port) from --http HOST:PORT (or PORT alone: 127.0.0.1)."""
    host, _, port = text.rpartition(":")
    host = host.strip("[]") or "127.0.0.1"
    try:
        number = int(port)
    except ValueError:
        raise PageError(f"--http {text}: expected HOST:PORT, e.g. 127.0.0.1:8050") from None
    if not 0 <= number <= 65535:
        raise PageError(f"--http {text}: no port {number}")
    return host, number


def loopback(host: str) -> bool:
    """Whether an address is this machine's own (only this machine's users can reach it)."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


class Page:
    """The page of a store's run (the latest unless `run` is given, or the latest of a fleet's `unit`;
    the page can switch to any other unit of a fleet), served from a thread once `start`ed, at `url`,
    until `stop` (jmlgdsl.page shows an example)."""

    def __init__(self, store_path, host: str = "127.0.0.1", port: int = 8050, *, token: str | None = None,
                 run: int | None = None, unit: str | None = None, store_password: str | None = None):
        if not loopback(host) and not token:
            raise PageError(f"--http {host}:{port}: the page may be reached from other machines there; give a "
                            "token with --http-token-env or --http-token-file (or bind to 127.0.0.1)")
        self.store_path, self.token, self.run_id, self.unit = str(store_path), token, run, unit
        self.store_password = store_password  # a PostgreSQL store's, for each thread's connection
        self.stopping = threading.Event()
        self._local = threading.local()
        try:
            self.server = ThreadingHTTPServer((host, port), functools.partial(_Handler, page=self))
        except OSError as exc:
            raise PageError(f"--http {host}:{port}: cannot serve the page there ({exc.strerror})") from None
        self.server.daemon_threads = True
        self.thread = None

    @property
    def url(self) -> str:
        host, port = self.server.server_address[:2]
        return f"http://{'[' + host + ']' if ':' in host else host}:{port}/"

    def answers_to(self, host: str) -> bool:
        """Whether a request's Host names this page: on the loopback, only its own address (an IP of
        the loopback, or localhost) at its port; bound elsewhere (with a token), any name, since the
        names the plant's network gives the machine are not known here."""
        bound, port = self.server.server_address[:2]
        if not loopback(bound):
            return True
        if not HOST.fullmatch(host):
            return False
        try:
            found = urlsplit("//" + host)
            return (found.port or 80) == port and loopback(found.hostname or "")
        except ValueError:  # a port out of range, a bracket unclosed
            return False

    def start(self) -> "Page":
        self.thread = threading.Thread(target=self.server.serve_forever, name="page", daemon=True)
        self.thread.start()
        return self

    def stop(self):
        self.stopping.set()
        self.server.shutdown()
        self.server.server_close()

    def store(self) -> Store:
        """This thread's connection to the store (a connection is not shared between threads)."""
        store = getattr(self._local, "store", None)
        if store is None:
            store = self._local.store = Store(self.store_path, create=False, password=self.store_password)
        return store

    def release(self):
        """Close this thread's connection, if it opened one, as its request ends (with its thread):
        closed, not left to the garbage collector, which psycopg warns of."""
        store = getattr(self._local, "store", None)
        if store is not None:
            self._local.store = None
            store.close()

    def run(self, unit: str | None = None):
        """The run the page shows: the one it was started on (default the latest), or a fleet's unit's latest."""
        if unit:
            run = self.store().run(unit=unit)
            if run is None:
                raise StoreError(f"{self.store_path}: the store holds no run of unit {unit}")
            return run
        run = self.store().run(self.run_id, unit=self.unit)
        if run is None:
            raise StoreError(f"{self.store_path}: the store holds no run yet")
        return run


class _Handler(BaseHTTPRequestHandler):
    """One request to a page: a GET answered by its route (ROUTES), a POST by an action on an alarm."""

    server_version = "jmlgdsl"

    def __init__(self, *args, page: Page):
        self.page = page
        super().__init__(*args)

    def log_message(self, format, *args):  # the monitor's log is for the plant, not for page views
        pass

    def finish(self):
        try:
            super().finish()
        finally:
            self.page.release()

    def do_GET(self):
        if not self._own_host():
            return
        parts = urlsplit(self.path)
        try:
            query = _query(parts.query)
            route = ROUTES.get(parts.path)
            if route is None:
                self._error(HTTPStatus.NOT_FOUND, f"no page {parts.path[:200]}")
            else:
                route(self, query)
        except (ValueError, StoreError) as exc:
            self._error(HTTPStatus.BAD_REQUEST, str(exc))
        except Exception as exc:  # a store damaged under the page: an answer that says so, not a dropped line
            self._failed(exc)

    def do_POST(self):
        if not self._own_host():
            return
        page, parts = self.page, urlsplit(self.path)
        found = ACTION.fullmatch(parts.path)
        if found is None:
            return self._error(HTTPStatus.NOT_FOUND, f"no action {parts.path[:200]}")
        if self.headers.get_content_type() != JSON or not self._same_origin():
            return self._error(HTTPStatus.FORBIDDEN, "actions come as JSON from the page itself")
        if page.token is not None and not hmac.compare_digest(
                self.headers.get("Authorization", "").encode(), f"Bearer {page.token}".encode()):
            return self._error(HTTPStatus.UNAUTHORIZED, "this page needs its token to act on alarms")
        try:
            body = _action(self.rfile, self.headers.get("Content-Length"))
            store, run = page.store(), page.run(_query(parts.query).get("unit"))
            store.act(run.id, int(found[1]), found[2], body.get("who") or "", body.get("reason"))
            self.answer_json(views.alarms(store, run))
        except (ValueError, StoreError) as exc:
            self._error(HTTPStatus.BAD_REQUEST, str(exc))
        except Exception as exc:
            self._failed(exc)

    def _own_host(self) -> bool:
        """Whether the request names this page's own address; a 421 when it does not."""
        host = self.headers.get("Host", "")
        if self.page.answers_to(host):
            return True
        self._error(HTTPStatus.MISDIRECTED_REQUEST, f"this page answers to {urlsplit(self.page.url).netloc} (or "
                    f"localhost at its port), not to {host[:100]!r}: a name that points at this machine "
                    "is not this page's own")
        return False

    def _same_origin(self) -> bool:
        origin = self.headers.get("Origin")
        return origin is None or urlsplit(origin).netloc == self.headers.get("Host")

    def stream(self, after: int, unit: str | None):
        """Rows after `after` as they are stored, and the alarms whenever they change, until the
        page goes away or the server stops."""
        page = self.page
        store, run, seen, quiet = page.store(), page.run(unit), None, time.monotonic()
        self.send_response(HTTPStatus.OK)
        self.send_header("Content-Type", "text/event-stream")
        for key, value in HEADERS.items():
            self.send_header(key, value)
        self.end_headers()
        try:
            while not page.stopping.is_set():
                found = views.rows(store, run, after=after, limit=STREAM_ROWS)
                if found.count:
                    after = found.last
                    self._event("rows", found.json, after)
                state = store.alarms_stamp(run.id)
                if state != seen:
                    seen = state
                    self._event("alarms", json.dumps(views.alarms(store, run)))
                    quiet = time.monotonic()
                if found.count:
                    quiet = time.monotonic()
                elif time.monotonic() - quiet > HEARTBEAT:
                    self.wfile.write(b": still here\n\n")
                    self.wfile.flush()
                    quiet = time.monotonic()
                if found.count < STREAM_ROWS:  # caught up: wait for the next commit
                    page.stopping.wait(POLL)
        except (BrokenPipeError, ConnectionResetError):
            pass  # the page was closed
        except Exception as exc:  # the stream ends with why; the browser asks again
            with contextlib.suppress(OSError):
                self._event("failure", json.dumps({"error": _failure(exc)}))

    def _event(self, name: str, data: str, id: int | None = None):
        self.wfile.write((f"event: {name}\n" + (f"id: {id}\n" if id is not None else "")
                          + f"data: {data}\n\n").encode())
        self.wfile.flush()

    def answer_json(self, value):
        """A JSON value as the answer."""
        self.answer(HTTPStatus.OK, json.dumps(value).encode(), JSON)

    def _failed(self, exc: Exception):
        self._error(HTTPStatus.INTERNAL_SERVER_ERROR, _failure(exc))

    def _error(self, status, message: str):
        self.answer(status, json.dumps({"error": message}).encode(), JSON)

    def answer(self, status, body: bytes, kind: str):
        """The answer: its status, its body and the body's content type, with the page's headers."""
        self.send_response(status)
        self.send_header("Content-Type", kind)
        self.send_header("Content-Length", str(len(body)))
        for key, value in HEADERS.items():
            self.send_header(key, value)
        self.end_headers()
        self.wfile.write(body)


def _static(name: str, kind: str):
    """The route of a file of the page's own (static/)."""
    def route(request: _Handler, query: dict):
        request.answer(HTTPStatus.OK, resources.files(__package__).joinpath("static", name).read_bytes(), kind)
    return route


def _run(request: _Handler, query: dict):
    page = request.page
    request.answer_json(views.run_info(page.store(), page.run(query.get("unit")), page.token is not None))


def _rows(request: _Handler, query: dict):
    page = request.page
    found = views.rows(page.store(), page.run(query.get("unit")), **_window(query))
    request.answer(HTTPStatus.OK, found.json.encode(), JSON)


def _alarms(request: _Handler, query: dict):
    page = request.page
    request.answer_json(views.alarms(page.store(), page.run(query.get("unit"))))


def _evidence(request: _Handler, query: dict):
    page = request.page
    request.answer_json(views.evidence(page.store(), page.run(query.get("unit")), _whole(query, "alarm", 0)))


def _fleet(request: _Handler, query: dict):
    request.answer_json(views.fleet(request.page.store(), request.page.unit))


def _stream(request: _Handler, query: dict):
    after = _whole({"Last-Event-ID": request.headers.get("Last-Event-ID")}, "Last-Event-ID", None)
    request.stream(_whole(query, "after", 0) if after is None else after, query.get("unit"))


# The page's GET requests, by path: route(request, query) answers one with its query's parameters. A
# new view of the page is a function of views.py that reads through the store's queries, a route
# that answers with it, and its line here.
ROUTES = {"/": _static("index.html", "text/html; charset=utf-8"),
          "/page.js": _static("page.js", "text/javascript; charset=utf-8"),
          "/page.css": _static("page.css", "text/css; charset=utf-8"),
          "/api/run": _run, "/api/rows": _rows, "/api/alarms": _alarms, "/api/evidence": _evidence,
          "/api/fleet": _fleet, "/api/stream": _stream}


def _failure(exc: Exception) -> str:
    """What a request that failed inside the page says: the store may be damaged."""
    return (f"the page could not answer ({type(exc).__name__}: {exc}): the store may be damaged ('jmlgdsl export' "
            "says which rows are readable)")


def _window(query: dict) -> dict:
    """The rows a query asks for (views.rows's keywords)."""
    return {key: _whole(query, key, None) for key in ("after", "first", "last", "limit") if key in query}


def _query(text: str) -> dict:
    """A query's parameters, the last of each name; a ValueError for one that is not printable text
    of at most 200 characters."""
    try:
        query = {k: v[-1] for k, v in parse_qs(text, errors="strict").items()}
    except UnicodeDecodeError:
        raise ValueError("the query is not UTF-8 text") from None
    for key, value in query.items():
        if len(key) > 200 or len(value) > 200 or not (key + value).isprintable():
            raise ValueError(f"the query's {key[:40]!r} is not a short printable text")
    return query


def _whole(values: dict, key: str, default):
    """values[key] as a whole number (`default` when absent); a ValueError for anything else."""
    text = values.get(key)
    if text is None:
        return default
    if not WHOLE.fullmatch(text) or not -2 ** 63 <= int(text) < 2 ** 63:
        raise ValueError(f"{key} must be a whole number of at most 19 digits, not {text[:40]!r}")
    return int(text)


def _action(stream, length) -> dict:
    """An action's body: a JSON object of at most MAX_BODY bytes holding only BODY_FIELDS, each a
    string or null; a ValueError for anything else."""
    if length is None or not re.fullmatch(r"[0-9]{1,19}", length, re.ASCII):
        raise ValueError("an action needs its Content-Length")
    if int(length) > MAX_BODY:
        raise ValueError(f"an action's body is at most {MAX_BODY} bytes, not {int(length)}")
    raw = stream.read(int(length))
    try:
        body = json.loads(raw or b"{}", parse_constant=_no_constant)
    except RecursionError:
        raise ValueError("an action's body is a JSON object of strings, not nested values") from None
    except ValueError as exc:
        raise ValueError(f"an action's body is not JSON ({exc})") from None
    if not isinstance(body, dict):
        raise ValueError(f"an action's body is a JSON object, not {type(body).__name__}")
    for key, value in body.items():
        if key not in BODY_FIELDS:
            raise ValueError(f"an action's body holds only {' and '.join(BODY_FIELDS)}, not {key[:40]!r}")
        if value is not None and not isinstance(value, str):
            raise ValueError(f"an action's {key} is a string, not {type(value).__name__}")
    return body


def _no_constant(name):
    raise ValueError(f"{name} is not a value an action takes")
