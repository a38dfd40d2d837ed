"""Live monitoring: a plant's data diagnosed as it arrives, every conclusion kept in a store that
survives restarts and outages (`jmlgdsl monitor`, `jmlgdsl export`; docs/monitor.md).

A source hands over rows (a CSV file followed as it grows, standard input) or readings of tags at
their own moments (MQTT, OPC UA), which `Assembler` puts on the spec's sample clock; `Monitor`
diagnoses the rows and commits them in batches to a `Store` (SQLite) with the diagnosis's saved
state, and acknowledges them to the source only after that commit.

    >>> import jmlgdsl, io, tempfile, os
    >>> from jmlgdsl.monitor import CsvSource, Monitor, MonitorOptions, Store
    >>> from jmlgdsl.monitor.store import write_table
    >>> model = jmlgdsl.load("specs/dryer.jmlg")
    >>> folder = tempfile.mkdtemp()
    >>> with Store(os.path.join(folder, "dryer.db")) as store:
    ...     source = CsvSource("examples/dryer_seq1.csv", model, follow=False)
    ...     stopped = Monitor(model, store, source, spec=None, options=MonitorOptions(), tags={}).run()
    ...     table = io.StringIO()
    ...     _ = write_table(store, store.run(), table)
    >>> stopped.rows, stopped.ended, table.getvalue().splitlines()[1000][:30]
    (1000, True, '1000,1000,fan,4.15205481e-05,0')
"""

from .rows import Assembler
from .sources.contract import Event
from .sources.files import CsvSource
from .live import Monitor, MonitorError, MonitorOptions, Stopped
from .store import Store, StoreError
from .sources.tags import Tag, TagError, read_tags

__all__ = ["Assembler", "Event", "CsvSource", "Monitor", "MonitorError", "MonitorOptions", "Stopped", "Store",
           "StoreError", "Tag", "TagError", "read_tags"]
