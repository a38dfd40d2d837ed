"""The page's door, with a real server on 127.0.0.1 and raw HTTP: a Host that is not the page's own
address (DNS rebinding) is refused, and every odd request (a body that is not a JSON object, fields
of the wrong type or size, NaN, nesting, numbers past 2^63, control characters) gets a 400 that says
why, never a traceback, a dropped connection or a row in the store."""

import json
import socket
import sqlite3

import pytest
from monitor_servers import WAIT


def raw(page, method, path, body=b"", host=None, headers=()):
    """(status, the answer's JSON or None) of one request written byte for byte; (None, None) when
    the server closed the connection without an answer."""
    port = page.server.server_address[1]
    lines = [f"{method} {path} HTTP/1.1", f"Host: {f'127.0.0.1:{port}' if host is None else host}", "Connection: close", *headers]
    if method == "POST" and not any(h.lower().startswith("content-length") for h in headers):
        lines.append(f"Content-Length: {len(body)}")
    if method == "POST" and not any(h.lower().startswith("content-type") for h in headers):
        lines.append("Content-Type: application/json")
    with socket.create_connection(("127.0.0.1", port), timeout=WAIT) as connection:
        connection.sendall("\r\n".join(lines).encode("latin-1") + b"\r\n\r\n" + body)
        connection.shutdown(socket.SHUT_WR)
        answer = b""
        while chunk := connection.recv(65536):
            answer += chunk
    if not answer:
        return None, None
    head, _, content = answer.partition(b"\r\n\r\n")
    status = int(head.split()[1])
    return status, json.loads(content) if b"application/json" in head else None


def actions(store):
    with sqlite3.connect(store) as db:
        return db.execute("SELECT count(*) FROM action").fetchone()[0]


def test_a_host_that_is_not_the_pages_own_address_is_refused(page, store):
    port = page.server.server_address[1]
    evil = f"evil.example:{port}"
    status, answer = raw(page, "POST", "/api/alarms/3/acknowledge", b'{"who": "mallory"}', host=evil,
                         headers=[f"Origin: http://{evil}"])
    assert status == 421 and answer["error"].startswith(f"this page answers to 127.0.0.1:{port} (or localhost at "
                                                        f"its port), not to 'evil.example:{port}'")
    assert raw(page, "GET", "/api/run", host=evil)[0] == 421  # nor read through such a name
    assert raw(page, "GET", "/", host=f"127.0.0.1:{port + 1 if port < 65535 else 1}")[0] == 421
    for host in ("127.0.0.1@evil.example", "", "[::1", f"localhost:{port}/x", f"127.0.0.1:{port}:{port}"):
        assert raw(page, "GET", "/api/run", host=host)[0] == 421, host
    assert actions(store) == 0
    for host in (f"127.0.0.1:{port}", f"localhost:{port}", f"LOCALHOST:{port}"):
        assert raw(page, "GET", "/api/run", host=host)[0] == 200, host
    status, answer = raw(page, "POST", "/api/alarms/3/acknowledge", b'{"who": "ann"}', host=f"localhost:{port}",
                         headers=[f"Origin: http://localhost:{port}"])
    assert status == 200 and answer[0]["acknowledged"]["who"] == "ann" and actions(store) == 1


ODD_ACTIONS = [
    (b"[1, 2]", "an action's body is a JSON object, not list"),
    (b'"ann"', "an action's body is a JSON object, not str"),
    (b"null", "an action's body is a JSON object, not NoneType"),
    (b'{"who": "ann", "reason": 5}', "an action's reason is a string, not int"),
    (b'{"who": {"name": "ann"}}', "an action's who is a string, not dict"),
    (b'{"who": ["ann"]}', "an action's who is a string, not list"),
    (b'{"who": NaN}', "an action's body is not JSON (NaN is not a value an action takes)"),
    (b'{"who": "ann", "reason": Infinity}', "an action's body is not JSON (Infinity is not a value"),
    (b"[" * 100_000 + b"]" * 100_000, "an action's body is at most 65536 bytes, not 200000"),
    (b'{"who": ' + b"[" * 30_000 + b"]" * 30_000 + b"}", "an action's body is a JSON object of strings, not nested"),
    (b'{"who": "' + b"a" * 60_000 + b'"}', "who acts is one line of at most 100 printable characters"),
    (b'{"who": "ann\\u0000"}', "who acts is one line of at most 100 printable characters"),
    (b'{"who": "ann", "reason": "a\\nb"}', "the reason is one line of at most 1000 printable characters"),
    (b'{"who": "ann", "reason": "' + b"r" * 1001 + b'"}', "the reason is one line of at most 1000 printable"),
    (b'{"who": "ann", "x": 1}', "an action's body holds only who and reason, not 'x'"),
    (b"\xff\xfe{", "an action's body is not JSON"),
    (b'{"who": "ann"', "an action's body is not JSON"),
]


@pytest.mark.parametrize("body, message", ODD_ACTIONS, ids=range(len(ODD_ACTIONS)))
def test_an_odd_action_is_a_400_that_says_why(page, store, body, message):
    status, answer = raw(page, "POST", "/api/alarms/2/shelve", body)
    assert status == 400 and answer["error"].startswith(message), answer
    assert actions(store) == 0


@pytest.mark.parametrize("method, path, headers, status, message", [
    ("POST", "/api/alarms/3/acknowledge", ["Content-Length: -5"], 400, "an action needs its Content-Length"),
    ("POST", "/api/alarms/3/acknowledge", ["Content-Length: 1" + "0" * 30], 400, "an action needs its Content"),
    ("POST", "/api/alarms/3/acknowledge", ["Content-Length: ²"], 400, "an action needs its Content-Length"),
    ("POST", "/api/alarms/9223372036854775807/acknowledge", [], 400, "run 1 has no alarm 9223372036854775807"),
    ("POST", "/api/alarms/9223372036854775808/acknowledge", [], 400, "run 1 has no alarm 9223372036854775808"),
    ("POST", "/api/alarms/99999999999999999999/acknowledge", [], 404, "no action"),
    ("POST", "/api/alarms/%D9%A1/acknowledge", [], 404, "no action"),
    ("GET", "/api/rows?after=9223372036854775808", [], 400, "after must be a whole number of at most 19 digits, "
                                                            "not '9223372036854775808'"),
    ("GET", "/api/rows?first=-99999999999999999999", [], 400, "first must be a whole number"),
    ("GET", "/api/rows?after=1e5", [], 400, "after must be a whole number of at most 19 digits, not '1e5'"),
    ("GET", "/api/rows?limit=%D9%A1%D9%A2", [], 400, "limit must be a whole number"),
    ("GET", "/api/rows?first=1&last=9223372036854775807&limit=5", [], 200, None),
    ("GET", "/api/evidence?alarm=99999999999999999999", [], 400, "alarm must be a whole number"),
    ("GET", "/api/stream", ["Last-Event-ID: 9223372036854775808"], 400, "Last-Event-ID must be a whole number"),
    ("GET", "/api/run?unit=%00", [], 400, "the query's 'unit' is not a short printable text"),
    ("GET", "/api/run?unit=%FF", [], 400, "the query is not UTF-8 text"),
    ("GET", "/api/run?unit=" + "u" * 60_000, [], 400, "the query's 'unit' is not a short printable text"),
])
def test_every_field_of_a_request_is_checked(page, store, method, path, headers, status, message):
    body = b'{"who": "ann"}' if method == "POST" else b""
    if any(h.startswith("Content-Length") for h in headers):
        body = b""
    found, answer = raw(page, method, path, body, headers=headers)
    assert found == status, (found, answer)
    assert message is None or answer["error"].startswith(message), answer
    assert actions(store) == 0
