"""The operator's page: one run of a monitor's store, live, in a browser (`jmlgdsl monitor --http`,
`jmlgdsl dashboard STORE`; docs/monitor.md, "The operator's page").

It shows the most probable mode and how sure the model is, a strip of every mode's probability over
time, each sensor's reading against the filter's one-step prediction with a band of two standard
deviations, and the alarms to deal with in their ISA-18.2 states (acknowledge, shelve with a reason),
with the evidence per sensor behind the selected one; clock times in the browser's local time. Any
past window of the store can be shown (scroll to zoom, drag to pan); new rows arrive within a
quarter of a second of their commit. A fleet's page opens on every unit, worst first.

    >>> import jmlgdsl, json, os, tempfile, urllib.request
    >>> from jmlgdsl.monitor import CsvSource, Monitor, MonitorOptions, Store
    >>> from jmlgdsl.page import Page
    >>> model = jmlgdsl.load("specs/dryer.jmlg")
    >>> path = os.path.join(tempfile.mkdtemp(), "dryer.db")
    >>> with Store(path) as store:
    ...     source = CsvSource("examples/dryer_seq1.csv", model, follow=False)
    ...     _ = Monitor(model, store, source, spec=None, options=MonitorOptions(), tags={}).run()
    >>> page = Page(path, "127.0.0.1", 0).start()      # port 0: any free one
    >>> [(a["id"], a["mode"], a["state"]) for a in json.load(urllib.request.urlopen(page.url + "api/alarms"))]
    [(3, 'grill', 'active, unacknowledged'), (2, 'grill', 'cleared, unacknowledged'), (1, 'fan', 'cleared, unacknowledged')]
    >>> page.stop()
"""

from .server import Page, PageError, loopback, parse_address

__all__ = ["Page", "PageError", "loopback", "parse_address"]
