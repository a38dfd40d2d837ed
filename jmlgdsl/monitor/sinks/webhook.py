"""Alarm transitions posted to a webhook (`monitor --notify URL`): a sink of jmlgdsl.monitor.sinks.outbox
that takes the transitions only (raised, cleared, acknowledged, shelved, unshelved).

Each transition is POSTed as its JSON object (`text` in it a line for people, which a chat hook
shows), one at a time and in order, by a thread of its own, so a receiver that is slow or down never
holds the diagnosis up. A failure (no connection, no answer within 10 s, a status that is not 2xx)
is an event of the transition's run, and the same transition is posted again after 1, 2, 4, ... and
at most 30 s; the transitions after it wait in a queue of at most 1,000, the rest in the store. A
transition is delivered once the receiver answers 2xx. With a token (--notify-token-env,
--notify-token-file) each request carries `Authorization: Bearer TOKEN`.
"""

from __future__ import annotations

import hashlib
import queue
import threading
import urllib.error
import urllib.request
from urllib.parse import urlsplit

from ..sources import bus
from ..sources.contract import Event
from ...errors import JmlgError
from ...version import VERSION

QUEUE = 1_000  # transitions waiting for the receiver, at most (the rest wait in the store)
TIMEOUT = 10.0  # seconds a receiver has to answer a request


class Webhook:
    """A sink (jmlgdsl.monitor.sinks.outbox) that posts each alarm transition to a URL. Its name shows the
    URL's scheme and host only, with a digest of the whole (a chat hook's path is its secret)."""

    takes_states = False

    def __init__(self, url: str, token: str | None = None):
        parts = urlsplit(url)
        if parts.scheme not in ("http", "https") or not parts.hostname:
            raise JmlgError(f"--notify {url}: not an http:// or https:// URL")
        if parts.username or parts.password:
            raise JmlgError("--notify: put no user name or password in the URL (they would show in the process "
                            "list); give a token with --notify-token-env or --notify-token-file")
        try:
            parts.port
        except ValueError:
            raise JmlgError(f"--notify {url}: the port is not a number from 1 to 65535") from None
        self.url, self.token = url, token
        self.name = f"{parts.scheme}://{parts.netloc} (URL sha256 {hashlib.sha256(url.encode()).hexdigest()[:12]})"
        self.waiting = queue.Queue()
        self.done = queue.SimpleQueue()
        self.closing = threading.Event()
        self.failing = False
        self.thread = None

    def start(self, report):
        self.thread = threading.Thread(target=self._post_all, args=(report,), name="notify", daemon=True)
        self.thread.start()

    def room(self) -> int:
        return QUEUE - self.waiting.qsize()

    def send(self, conclusion):
        self.waiting.put(conclusion)

    def delivered(self) -> list:
        return bus.drained(self.done)

    def stop(self, wait: float):
        """Let the thread post what waits for up to `wait` seconds (none while the receiver fails), then end it."""
        self.waiting.put(None)
        if self.thread is not None and not self.failing:
            self.thread.join(wait)
        self.closing.set()

    def _post_all(self, report):
        """The thread: post each transition in turn until it is delivered, or the sink is stopped."""
        while True:
            conclusion = self.waiting.get()
            if conclusion is None:
                return
            failures, delays = 0, bus.delays()
            while True:
                why = self._post(conclusion)
                if why is None:
                    break
                failures, delay = failures + 1, next(delays)
                self.failing = True
                report(Event("delivery", None, f"notify {self.name}: alarm {conclusion.body['alarm']} "
                                               f"{conclusion.body['transition']}: {why}; trying again in {delay:g} s"),
                       conclusion.run)
                if self.closing.wait(delay):
                    return
            if failures:
                self.failing = False
                report(Event("delivery", None, f"notify {self.name}: delivered after {failures} failed "
                                               f"attempt{'s' * (failures > 1)}"), conclusion.run)
            self.done.put(conclusion)

    def _post(self, conclusion) -> str | None:
        """POST one transition; None once the receiver took it, else why it did not."""
        headers = {"Content-Type": "application/json", "User-Agent": f"jmlgdsl/{VERSION}"}
        if self.token is not None:
            headers["Authorization"] = f"Bearer {self.token}"
        request = urllib.request.Request(self.url, data=conclusion.json(), headers=headers, method="POST")
        try:
            with urllib.request.urlopen(request, timeout=TIMEOUT) as answer:
                answer.read()
        except urllib.error.HTTPError as exc:
            return f"HTTP {exc.code} {exc.reason}"
        except urllib.error.URLError as exc:
            return f"{exc.reason}"
        except TimeoutError:
            return f"no answer within {TIMEOUT:g} s"
        except OSError as exc:
            return f"{exc}"
        return None
